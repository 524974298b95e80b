"""`[gcode_macro NAME]`: new G-code commands written as Jinja2 templates.

    [gcode_macro SHOW_FORCE]
    description: Print the force on the load cell
    variable_limit_g: 500
    gcode:
      {% set grams = printer.load_cell.force_g %}
      {action_respond_info("force: %.1fg (limit %d)" % (grams, limit_g))}

Templates use `{ expression }` and `{% statement %}` (Klipper's delimiters).
While rendering they see:

* `params`: the command's parameters (upper-case names -> text), `rawparams`: the text after the name;
* `printer`: every status object, `printer.load_cell.force_g` or `printer["load_cell probe"]`;
* each `variable_<name>` option as `<name>` (a Python literal; change with SET_GCODE_VARIABLE);
* `action_respond_info(msg)` (prints `// msg`) and `action_raise_error(msg)` (fails the command).

An undefined name is an error (not an empty string), so a typo or a status
field that is not available yet (e.g. force_g before calibration) stops the
macro with a message instead of sending half a command. An unknown command inside a
macro is skipped with a warning, as in Klipper (`// Unknown command:"Z_TILT_ADJUST" in macro
PRINT_START, skipped`), and the next line runs.
"""

from __future__ import annotations

import ast
from typing import Any

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeError
from tapcell.host.templates import StatusView, compile_template

DEFAULT_DESCRIPTION = "G-Code macro"

def parse_variable(text: str) -> Any:
    """A `variable_*` value or SET_GCODE_VARIABLE VALUE: a Python literal."""
    return ast.literal_eval(text.strip())


class GCodeMacro:
    """One `[gcode_macro NAME]` section: a command that renders and runs its template."""

    def __init__(self, section: ConfigSection, printer: Any):
        self.printer = printer
        self.section_name = section.get_name()
        self.command = section.get_instance_name().upper()
        self.description = section.get("description", DEFAULT_DESCRIPTION)
        self.template = compile_template(section, "gcode", f"macro {self.command}")
        self.variables: dict[str, Any] = {}
        for option in section.get_option_names("variable_"):
            text = section.get(option)
            try:
                self.variables[option[len("variable_"):]] = parse_variable(text)
            except (ValueError, SyntaxError):
                raise section.error(option, "must be a Python literal: a number, 'quoted text', "
                                            "a list, a dict, True, False or None") from None
        rename_existing = section.get("rename_existing", None)
        if rename_existing is not None:
            # The command to rename may come from a section further down the file: load those first.
            for name in section.config.sections():
                if not name.startswith("gcode_macro ") and name not in printer.objects:
                    printer.load_object(name)
            printer.gcode.rename_command(self.command, rename_existing)
        printer.gcode.register_command(self.command, self.cmd_macro, desc=self.description)
        printer.gcode.register_mux_command("SET_GCODE_VARIABLE", "MACRO", section.get_instance_name(),
                                           self.cmd_set_variable,
                                           desc="Change a variable_* value of a gcode_macro")

    def get_status(self, eventtime: float) -> dict:
        return dict(self.variables)

    def render(self, gcmd: GCodeCommand) -> str:
        """The G-code the macro expands to for this call."""
        context = {
            **self.variables,
            "params": gcmd.get_command_parameters(),
            "rawparams": gcmd.rawparams,
            "printer": StatusView(self.printer),
            "action_respond_info": self._action_respond_info,
            "action_raise_error": self._action_raise_error,
        }
        return self.template.render(context)

    def cmd_macro(self, gcmd: GCodeCommand) -> None:
        # A macro calling itself (directly or through others) is refused by the dispatcher.
        self.printer.gcode.run_macro_script(self.render(gcmd), self.command)

    def cmd_set_variable(self, gcmd: GCodeCommand) -> None:
        name = gcmd.get("VARIABLE").lower()
        if name not in self.variables:
            known = ", ".join(sorted(self.variables)) or "none"
            raise gcmd.param_error(f"unknown VARIABLE '{name}' "
                                   f"(variables of {self.command}: {known})")
        text = gcmd.get("VALUE")
        try:
            self.variables[name] = parse_variable(text)
        except (ValueError, SyntaxError):
            raise gcmd.param_error(f"unable to parse '{text}' for VALUE "
                                   f"(expected a Python literal)") from None

    def _action_respond_info(self, message: str) -> str:
        self.printer.gcode.respond_info(str(message))
        return ""

    @staticmethod
    def _action_raise_error(message: str) -> str:
        raise GCodeError(str(message))


def load_config_prefix(section: ConfigSection, printer: Any) -> GCodeMacro:
    return GCodeMacro(section, printer)
