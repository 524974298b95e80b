"""tapcell: the open load-cell probing stack for 3D printers."""

__version__ = "0.1.0"
