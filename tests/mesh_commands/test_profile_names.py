"""Issue 20: a profile name is refused at BED_MESH_PROFILE SAVE= when the config file cannot hold
it, and every name accepted there survives SAVE_CONFIG and the next start."""

from __future__ import annotations

import pytest

from tapcell.host.printer import Printer

from machines import gcode_error
from test_bed_mesh import MESH, TILTED

REFUSED = {
    "a]b": "contains ']', which ends a section header",
    "a[b": "contains '[', which ends a section header",
    "x;y": "contains ';', which starts a comment",
    "x#y": "contains '#', which starts a comment",
    "x" * 5000: "is 5,009 characters long (at most 200)",
    "a\x7fb": "contains a control character (a tab, a line break)",
}
ACCEPTED = ["ünï", "a=b", "a:b", "a\\b", "{x}", "PLA_0.4"]


@pytest.mark.parametrize("name", list(REFUSED))
def test_a_name_the_file_cannot_hold_is_refused_before_anything_is_queued(make_printer, name):
    printer = make_printer(MESH + TILTED)
    printer.gcode.run_script("BED_MESH_PROFILE LOAD=tilted")
    message = gcode_error(printer, f"BED_MESH_PROFILE SAVE=\"{name}\"")  # quoted: ; is no comment
    shown = name[:40]
    assert message.endswith(f"profile name '{shown}': [bed_mesh {shown}] {REFUSED[name]}, so it cannot be "
                            f"saved in the config file; choose another name")
    assert not printer.config.has_pending_changes()


def test_every_accepted_name_survives_save_config_and_the_next_start(make_printer):
    printer = make_printer(MESH + TILTED)
    printer.gcode.run_script("BED_MESH_PROFILE LOAD=tilted")
    for name in ACCEPTED:
        printer.gcode.run_script(f"BED_MESH_PROFILE SAVE={name}")
    printer.gcode.run_script("SAVE_CONFIG")
    restarted = Printer.from_config(str(make_printer.tmp_path / "printer.cfg"), responses=[])
    assert sorted(restarted.get_status()["bed_mesh"]["profiles"]) == sorted([*ACCEPTED, "tilted"])
