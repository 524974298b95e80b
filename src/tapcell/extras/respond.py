"""`[respond]`: M118 and RESPOND, messages from G-code to the console (Klipper's prefixes)."""

from __future__ import annotations

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand

PREFIXES = {"echo": "echo:", "command": "//", "error": "!!"}


class Respond:
    def __init__(self, default_prefix: str):
        self.default_prefix = default_prefix

    def cmd_M118(self, gcmd: GCodeCommand) -> None:
        gcmd.respond_raw(f"{self.default_prefix} {gcmd.rawparams}")

    def cmd_RESPOND(self, gcmd: GCodeCommand) -> None:
        prefix = self.default_prefix
        kind = gcmd.get("TYPE", None)
        if kind is not None:
            if kind.lower() not in PREFIXES:
                raise gcmd.error(f"RESPOND TYPE '{kind}' is invalid. Must be one of 'echo', 'command', or 'error'")
            prefix = PREFIXES[kind.lower()]
        prefix = gcmd.get("PREFIX", prefix)
        gcmd.respond_raw(f"{prefix} {gcmd.get('MSG', '')}")


def load_config(section: ConfigSection, printer) -> Respond:
    default_type = section.getchoice("default_type", list(PREFIXES), "echo")
    respond = Respond(section.get("default_prefix", PREFIXES[default_type]))
    printer.gcode.register_command("M118", respond.cmd_M118, desc="Echo a message: M118 <text>")
    printer.gcode.register_command("RESPOND", respond.cmd_RESPOND,
                                   desc="Echo a message: [TYPE=echo|command|error] [PREFIX=] MSG=")
    return None
