"""`[virtual_printer]`: scenario, seed and physics overrides read through tapcell.host.config getters.

Every SimParams name is an option (e.g. `bed_x_mm: 300`, `chip: ads1220`, `hum_counts: 800`);
its default is the chosen scenario's value, so a config only lists what differs.
"""

from __future__ import annotations

from tapcell.sim.params import PARAM_FIELDS, make_params
from tapcell.sim.scenarios import SCENARIOS

MAX_SEED = (1 << 32) - 1


def read_virtual_printer_section(section) -> tuple[str, int, dict]:
    """(scenario name, seed, overrides) from a ConfigSection; bad values raise ConfigError."""
    name = section.getchoice("scenario", list(SCENARIOS), default="clean")
    seed = section.getint("seed", 1, minval=0, maxval=MAX_SEED)
    base = make_params(SCENARIOS[name].overrides)
    overrides = {}
    for option, f in PARAM_FIELDS.items():
        if not section.has_option(option):
            continue
        default = getattr(base, option)
        meta = f.metadata
        if meta["choices"] is not None:
            overrides[option] = section.getchoice(option, list(meta["choices"]), default=default)
        elif isinstance(default, int):
            overrides[option] = section.getint(option, default, minval=meta["minval"], maxval=meta["maxval"])
        elif isinstance(default, float):
            overrides[option] = section.getfloat(option, default, minval=meta["minval"], maxval=meta["maxval"])
        else:
            overrides[option] = section.get(option, default)
    return name, seed, overrides
