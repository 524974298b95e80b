"""`[exclude_object]`: objects a slicer defines, and skipping the moves of an excluded one.

EXCLUDE_OBJECT_DEFINE NAME= [CENTER=x,y] [POLYGON=[[x,y],...]] | RESET=1
EXCLUDE_OBJECT_START NAME= / EXCLUDE_OBJECT_END [NAME=]
EXCLUDE_OBJECT [NAME=] [CURRENT=1] [RESET=1]   (no parameter: list the excluded objects)

Status `exclude_object` has Klipper's fields: `objects` (each {name, center, polygon}),
`excluded_objects` (names) and `current_object`; BED_MESH_CALIBRATE ADAPTIVE=1 reads the
objects from there. Object names are upper case, as in Klipper.

While an excluded object is being printed its moves are not run (the G-code position still
follows them); the first move after it goes straight to where the G-code is.
"""

from __future__ import annotations

import json
import math

from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand
from tapcell.host.limits import MAX_COORDINATE_MM


def _on_a_printer(value) -> bool:
    """A coordinate (JSON also allows Infinity and NaN, and true is an int)."""
    return (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            and abs(value) <= MAX_COORDINATE_MM)


class ExcludeObject:
    def __init__(self, printer):
        self.printer = printer
        self.toolhead = printer.lookup_object("toolhead")
        self.objects: list[dict] = []
        self.excluded: list[str] = []
        self.current_object: str | None = None
        self.next_target = self.toolhead.set_move_transform(self)
        self._skipped_position: tuple[float, float, float] | None = None

    # -- the move transform ------------------------------------------------------------
    def move(self, position_xyz, speed_mm_s: float) -> None:
        if self.current_object in self.excluded:
            self._skipped_position = tuple(position_xyz)
            return
        self._skipped_position = None
        self.next_target.move(position_xyz, speed_mm_s)

    def get_position(self):
        return self._skipped_position if self._skipped_position is not None else self.next_target.get_position()

    # -- commands ----------------------------------------------------------------------
    def _error(self, gcmd: GCodeCommand, problem: str):
        return gcmd.param_error(f"{problem}")

    def _point(self, gcmd: GCodeCommand, text: str, what: str) -> list[float]:
        try:
            values = [float(v) for v in text.strip("[] ").split(",")]
        except ValueError:
            values = []
        if len(values) != 2 or not all(_on_a_printer(v) for v in values):
            raise gcmd.param_error(f"{what} must be x,y within -{MAX_COORDINATE_MM:g}..{MAX_COORDINATE_MM:g} mm "
                                   f"(got '{text}')")
        return values

    def cmd_EXCLUDE_OBJECT_DEFINE(self, gcmd: GCodeCommand) -> None:
        if gcmd.get_int("RESET", 0, minval=0, maxval=1):
            self.objects, self.excluded, self.current_object = [], [], None
            return
        name = gcmd.get("NAME", None)
        if name is None:
            gcmd.respond_info("Known objects: " + (", ".join(o["name"] for o in self.objects) or "none"))
            return
        entry: dict = {"name": name.upper()}
        center = gcmd.get("CENTER", None)
        if center is not None:
            entry["center"] = self._point(gcmd, center, "CENTER")
        polygon = gcmd.get("POLYGON", None)
        if polygon is not None:
            try:
                points = json.loads(polygon)
            except json.JSONDecodeError:
                points = None
            if not (isinstance(points, list) and points and all(
                    isinstance(p, list) and len(p) == 2 and all(_on_a_printer(v) for v in p) for p in points)):
                raise gcmd.param_error(f"POLYGON must be a JSON list of [x,y] points (got '{polygon}')")
            entry["polygon"] = [[float(x), float(y)] for x, y in points]
        self.objects = [o for o in self.objects if o["name"] != entry["name"]] + [entry]
        self.objects.sort(key=lambda o: o["name"])

    def cmd_EXCLUDE_OBJECT_START(self, gcmd: GCodeCommand) -> None:
        name = gcmd.get("NAME").upper()
        if name not in (o["name"] for o in self.objects):
            self.objects.append({"name": name})  # Klipper defines an object it has not seen
            self.objects.sort(key=lambda o: o["name"])
        self.current_object = name

    def cmd_EXCLUDE_OBJECT_END(self, gcmd: GCodeCommand) -> None:
        name = gcmd.get("NAME", None)
        if self.current_object is None:
            gcmd.respond_info("EXCLUDE_OBJECT_END called, but no object is currently active")
            return
        if name is not None and name.upper() != self.current_object:
            gcmd.respond_info(f"EXCLUDE_OBJECT_END NAME={name.upper()} does not match the current object "
                              f"NAME={self.current_object}")
        self.current_object = None

    def cmd_EXCLUDE_OBJECT(self, gcmd: GCodeCommand) -> None:
        if gcmd.get_int("RESET", 0, minval=0, maxval=1):
            name = gcmd.get("NAME", None)
            self.excluded = [] if name is None else [n for n in self.excluded if n != name.upper()]
            return
        name = gcmd.get("NAME", None)
        if gcmd.get_int("CURRENT", 0, minval=0, maxval=1):
            if self.current_object is None:
                raise gcmd.param_error("There is no current object to exclude")
            name = self.current_object
        if name is None:
            gcmd.respond_info("Excluded objects: " + (" ".join(self.excluded) or "none"))
            return
        if name.upper() not in self.excluded:
            self.excluded.append(name.upper())
            gcmd.respond_info(f"Excluding object {name.upper()}")

    def get_status(self, eventtime=None) -> dict:
        return {"objects": [dict(o) for o in self.objects], "excluded_objects": list(self.excluded),
                "current_object": self.current_object}


COMMANDS = ("EXCLUDE_OBJECT_DEFINE", "EXCLUDE_OBJECT_START", "EXCLUDE_OBJECT_END", "EXCLUDE_OBJECT")


def load_config(section: ConfigSection, printer) -> ExcludeObject:
    # The bed mesh transform must sit below this one (skipped moves skip the mesh too).
    printer.load_object("bed_mesh")
    exclude = ExcludeObject(printer)
    for name in COMMANDS:
        printer.gcode.register_command(name, getattr(exclude, f"cmd_{name}"),
                                       desc=f"{name.replace('_', ' ').capitalize()} (slicer object labels)")
    return exclude
