"""`tapcell scenarios [NAME]`: list the shipped scenarios, or every parameter of one."""

from __future__ import annotations

import argparse

from rich.console import Console
from rich.table import Table

from tapcell.sim.params import PARAM_FIELDS, make_params
from tapcell.sim.scenarios import SCENARIOS


def _format(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def scenarios_table() -> Table:
    table = Table(title="virtual printer scenarios (tapcell scenarios NAME shows every parameter)")
    table.add_column("scenario", style="bold")
    table.add_column("description")
    table.add_column("parameters (changed from the defaults)")
    for scenario in SCENARIOS.values():
        changed = ", ".join(f"{k}={_format(v)}" for k, v in scenario.overrides.items()) or "(defaults)"
        table.add_row(scenario.name, scenario.description, changed)
    return table


def parameters_table(name: str) -> Table:
    params = make_params(SCENARIOS[name].overrides)
    table = Table(title=f"scenario '{name}': {SCENARIOS[name].description}")
    for column in ("parameter", "value", "unit", "allowed", "meaning"):
        table.add_column(column)
    for option, f in PARAM_FIELDS.items():
        mark = "bold yellow" if option in SCENARIOS[name].overrides else None
        meta = f.metadata
        allowed = (", ".join(str(c) for c in meta["choices"]) if meta["choices"] else
                   f"{_format(meta['minval'])} to {_format(meta['maxval'])}" if meta["minval"] is not None else "")
        table.add_row(option, _format(getattr(params, option)), meta["unit"], allowed, meta["doc"], style=mark)
    return table


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tapcell scenarios", description=__doc__)
    parser.add_argument("name", nargs="?", help="show every parameter of this scenario")
    args = parser.parse_args(argv)
    console = Console()
    if args.name is None:
        console.print(scenarios_table())
        return 0
    if args.name not in SCENARIOS:
        console.print(f"tapcell scenarios: unknown scenario '{args.name}'; allowed: {', '.join(SCENARIOS)}")
        return 2
    console.print(parameters_table(args.name))
    return 0
