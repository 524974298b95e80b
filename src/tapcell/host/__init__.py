"""The klippy-like host runtime: printer assembly, config, G-code, toolhead, API server."""
