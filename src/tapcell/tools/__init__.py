"""Command-line tools: the `tapcell` dispatcher, the demo, the G-code console."""
