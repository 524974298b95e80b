"""`[quad_gantry_level]`: QUAD_GANTRY_LEVEL on the virtual printer's single Z motor
(tapcell.extras.leveling_standin)."""

from tapcell.extras.leveling_standin import load_standin


def load_config(section, printer):
    return load_standin(section, printer, "QUAD_GANTRY_LEVEL",
                        "Level a four-motor gantry (one Z motor here: nothing to level)")
