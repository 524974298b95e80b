"""`[z_tilt]`: Z_TILT_ADJUST on the virtual printer's single Z motor (tapcell.extras.leveling_standin)."""

from tapcell.extras.leveling_standin import load_standin


def load_config(section, printer):
    return load_standin(section, printer, "Z_TILT_ADJUST", "Adjust the Z tilt (one Z motor here: nothing to adjust)")
