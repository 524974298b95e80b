"""`[pca9533 NAME]`: LEDs kept as colours, see tapcell.extras.led."""

from tapcell.extras.led import load_config_prefix

__all__ = ["load_config_prefix"]
