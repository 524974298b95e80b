"""The klippy-like runtime: printer assembly, config, G-code, toolhead."""
