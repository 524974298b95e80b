"""The nozzle watch: the load cell guards every move that can touch the bed, not only probes.

A probing move is not the only move that can press the nozzle into the bed: travel between mesh
points over a blob, `G1 Z0.1` after `SET_GCODE_OFFSET Z=-1.9`, a `deactivate_gcode` that
moves Z down, a macro. So every toolhead move that ends below `nozzle_watch_height`, or passes
below it, runs with the firmware trigger armed, exactly as a probing move does: tared on the
samples just before the move, triggering on `nozzle_watch_force` over that tare, and with the
raw force window (`force_safety_limit` around the calibration zero, clamped inside the ADC's
range) and the stuck-sensor run on every sample. A force must be there on two samples in a row to
stop the move, as for a probing move: a single corrupted frame (a flipped bit on a long cable) is not
a collision. The firmware's quarantine holds a sample past `nozzle_watch_force` until the next one
(back inside: dropped; past it too: the move halts); a lone sample past the raw force window halts
the move at once and, when the samples on both sides read under `nozzle_watch_force`, the move goes
on to its target (options.CorruptFrameBudget). The
confirmation costs one sample of travel, which the speed cap accounts for (it runs the firmware
trigger with the quarantine). After a real stop the nozzle is lifted straight up (up cannot press
harder) and the command ends with `Load Cell Probe Error: nozzle collision at X,Y,Z (N g)` naming
the command that moved.

G28 X/Y's endstop moves are watched too when the nozzle may be low: Z homed and below
`nozzle_watch_height`, or Z not homed, not lifted by that much first ([safe_z_home] z_hop), on a
bed this session has measured (wants_homing).

Not watched: moves that only rise (the same X/Y, Z up), other moves while Z is not homed (the bed
is not known), and every move before the cell is calibrated (there is no force to watch). The
trigger adds nothing to the firmware's per-sample path: it is the probing trigger, armed for
one more kind of move (docs/safety.md).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from tapcell.extras.load_cell_probe import safety
from tapcell.extras.load_cell_probe.options import (
    CORRUPT_FRAME_WINDOW_S,
    ERROR_PREFIX,
    CorruptFrameBudget,
    robust_tare_counts,
    tare_sample_count,
)
from tapcell.extras.probe.session import ProbeError
from tapcell.mcu.trigger import TriggerError, TriggerParams

# Watched below this much above horizontal_z_clearance (when [bed_mesh] has one), and at least
# DEFAULT_HEIGHT_MM: a first layer, a z_offset gone wrong and the mesh travel all lie below it.
DEFAULT_HEIGHT_MM = 2.0
HEIGHT_ABOVE_CLEARANCE_MM = 1.0
MAX_HEIGHT_MM = 50.0
# The force over the move's tare that stops a watched move. A print puts 0-30 g on the nozzle
# in the virtual printer (bench/print_run.py prints the largest); a collision at travel speed
# ramps past this within a sample or two, well below force_safety_limit (docs/safety.md).
DEFAULT_FORCE_G = 250.0
FORCE_RANGE_G = (50.0, 5000.0)
# The steepest flank assumed for what the nozzle may meet sideways (a blob, a warp, a curled edge):
# rising 1 mm per mm of travel, a watched move loads the nozzle as fast as a Z move would.
WORST_FLANK_SLOPE = 1.0
# Used to cap a watched move's speed when force_safety_limit is 0 (off): the option's default.
CAP_LIMIT_WITHOUT_SAFETY_LIMIT_G = 2000.0
# Samples older than this many periods beyond the tare length are not the state before the move.
FRESH_MARGIN_SAMPLES = 4
SENSOR_TIMEOUT_S = 1.0


@dataclass(frozen=True)
class WatchOptions:
    height_mm: float   # toolhead Z below which moves are watched; 0: the watch is off
    force_g: float     # force over the move's tare that stops it


def read_watch_options(section) -> WatchOptions:
    """`nozzle_watch_height` and `nozzle_watch_force` of [load_cell_probe]."""
    default_height = DEFAULT_HEIGHT_MM
    config = section.config
    if config.has_section("bed_mesh"):
        clearance = config.getsection("bed_mesh").getfloat("horizontal_z_clearance", None, above=0.0,
                                                           maxval=MAX_HEIGHT_MM)
        if clearance is not None:
            default_height = max(default_height, clearance + HEIGHT_ABOVE_CLEARANCE_MM)
    height = section.getfloat("nozzle_watch_height", default_height, minval=0.0, maxval=MAX_HEIGHT_MM)
    force = section.getfloat("nozzle_watch_force", DEFAULT_FORCE_G, minval=FORCE_RANGE_G[0],
                             maxval=FORCE_RANGE_G[1])
    return WatchOptions(height, force)


def is_watched(start_xyz, target_xyz, height_mm: float) -> bool:
    """Whether a straight move from start to target (toolhead frame) needs the watch: it ends or
    starts below `height_mm` (a straight line is lowest at an end) and does not only rise."""
    if height_mm <= 0.0 or min(start_xyz[2], target_xyz[2]) >= height_mm:
        return False
    rises_only = (start_xyz[0] == target_xyz[0] and start_xyz[1] == target_xyz[1]
                  and target_xyz[2] >= start_xyz[2])
    return not rises_only


def collision_message(x_mm: float, y_mm: float, z_mm: float, force_g: float, command: str | None) -> str:
    where = f" during {command}" if command else ""
    return (ERROR_PREFIX + f"nozzle collision at {x_mm:.3f},{y_mm:.3f},{z_mm:.3f} ({force_g:.0f} g){where}: "
            "the move was stopped and the nozzle lifted; check the bed for a blob or a part that came loose, "
            "and the Z offset")


class NozzleWatch:
    """Runs the toolhead's low moves with the probe's firmware trigger armed (see the module doc)."""

    def __init__(self, device, options: WatchOptions):
        self.device = device
        self.options = options
        self.printer = device.printer
        self.backend = device.backend
        self.collisions = 0      # watched moves stopped (status)
        self.watched_moves = 0   # moves run with the watch armed (status)
        self._free_air: tuple[float, float] | None = None  # (tare counts, when) of the last move that started clear
        self._speed_caps: dict[float, float] = {}  # assumed bed stiffness -> speed_cap for a head-on move
        self.largest_force_g = 0.0  # the largest force a watched move that ran to its end saw (status)

    def wants(self, start_xyz, target_xyz) -> bool:
        """Whether this toolhead move runs watched."""
        toolhead = self.device.motion
        return (self.device.load_cell.is_calibrated and toolhead.is_z_homed()
                and is_watched(start_xyz, target_xyz, self.options.height_mm))

    def _trigger(self) -> dict:
        """What a watched move's trigger differs in from a tap's: the config's options (no G-code
        override is running), no filter (the force over the move's tare, as read), trigger at
        nozzle_watch_force and the drift window there too: the firmware quarantines a sample past
        the window until the next, so a force stops the move only when two samples in a row read
        it (the raw force window stays, on every sample)."""
        settings = dataclasses.replace(self.device.config_settings, sos=None)
        return {"settings": settings, "trigger_force_g": self.options.force_g,
                "drift_safety_limit_g": self.options.force_g}

    def trigger_params(self) -> TriggerParams:
        trigger = self._trigger()
        return self.device.trigger.move_params(trigger.pop("settings"), **trigger)

    def speed_cap_mm_s(self, direction_xyz) -> float:
        """The fastest a watched move in this direction may go: the watch must stop the nozzle
        meeting the stiffest bed assumed (the probe's force guard: measured by taps, with a margin,
        else the worst case) head on, or a WORST_FLANK_SLOPE flank sideways, at or below
        force_safety_limit."""
        stiffness_g_um, _ = self.device.speed_guard.assumed_stiffness_g_um()
        if stiffness_g_um not in self._speed_caps:
            params = self.trigger_params()
            limit_g = params.force_safety_limit_g or CAP_LIMIT_WITHOUT_SAFETY_LIMIT_G
            self._speed_caps[stiffness_g_um] = safety.fastest_watched_speed_mm_s(
                params, self.device.stop_timing, stiffness_g_um, limit_g)
        dx, dy, dz = direction_xyz
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        if length == 0.0:
            return self._speed_caps[stiffness_g_um]
        loading = (WORST_FLANK_SLOPE * math.hypot(dx, dy) + abs(dz)) / length  # bed approach per mm moved
        return self._speed_caps[stiffness_g_um] / max(loading, 1e-9)

    def move(self, machine_xyz, speed_mm_s: float, accel_mm_s2: float | None) -> None:
        """Run one move (machine coordinates, None: the axis stays) with the trigger armed, no
        faster than `speed_cap_mm_s` allows."""
        start = self.backend.position
        direction = [0.0 if end is None else end - begin for end, begin in zip(machine_xyz, start)]
        speed_mm_s = min(speed_mm_s, self.speed_cap_mm_s(direction))
        tare_counts = self._move_tare_counts(descends=direction[2] < 0.0)
        x, y, z = machine_xyz
        self._run_armed(tare_counts, lambda firmware: self.backend.watched_move(x, y, z, speed_mm_s, accel_mm_s2,
                                                                                 firmware))

    def wants_homing(self) -> bool:
        """Whether G28 X/Y's endstop moves run watched: the cell is calibrated and the nozzle may be
        low. With Z homed: it starts below nozzle_watch_height. With Z not homed (motors off after
        a print) nobody knows where the bed is: unless the toolhead was lifted (relative, [safe_z_home]
        z_hop) by at least nozzle_watch_height since, the homing move is watched too, when this
        session has measured the bed. On a bed never measured (a fresh start) the watch could keep
        its force bound only by crawling (2 mm/s over the whole axis at 320 sps): there [safe_z_home]
        z_hop is what keeps the nozzle clear (docs/safety.md)."""
        toolhead = self.device.motion
        if self.options.height_mm <= 0.0 or not self.device.load_cell.is_calibrated:
            return False
        if toolhead.is_z_homed():
            return toolhead.get_position()[2] < self.options.height_mm
        _, measured = self.device.speed_guard.assumed_stiffness_g_um()
        return measured and toolhead.z_lift_while_unhomed_mm < self.options.height_mm

    def home_xy(self, axes: str, speed_mm_s: float) -> None:
        """G28's endstop move for `axes` ("x", "y", "xy") with the trigger armed: horizontal, so
        tared on its own samples and no faster than the cap for sideways travel."""
        capped_mm_s = min(speed_mm_s, self.speed_cap_mm_s((1.0, 0.0, 0.0)))
        if capped_mm_s < speed_mm_s:
            z_state = ("Z is low" if self.device.motion.is_z_homed()
                       else "Z is not homed and was not lifted first ([safe_z_home] z_hop)")
            self.printer.gcode.respond_info(
                f"Homing {axes.upper()} at {capped_mm_s:g} mm/s, not {speed_mm_s:g} mm/s, with the nozzle watch: "
                f"{z_state}, and the watch stops the nozzle in time only up to that speed on the bed assumed")
        tare_counts = self._tare_counts()
        self._run_armed(tare_counts, lambda firmware: self.backend.watched_home_xy(axes, capped_mm_s, firmware))

    def _run_armed(self, tare_counts: float, run) -> None:
        """`run(firmware)` makes the move with the trigger armed on `tare_counts`; a stop ends the command."""
        device = self.device
        trigger = self._trigger()
        t_start_s = self.backend.now_s
        firmware = device.trigger.arm(trigger.pop("settings"), tare_counts, **trigger)
        self.watched_moves += 1
        history = device.history
        kept_from_s = history.keep_from_s
        history.keep_from_s = t_start_s if kept_from_s is None else min(kept_from_s, t_start_s)
        try:
            corrupt_frames = CorruptFrameBudget()
            armed_s = t_start_s  # this attempt's arm time: its firmware saw the samples read from here on
            while True:
                result = run(firmware)
                # A lone frame past the raw force window; past nozzle_watch_force the quarantine drops it.
                lone_g = (device.corrupt_frame_that_stopped(firmware.params, result, tare_counts, armed_s)
                          if result.error == TriggerError.FORCE_SAFETY else None)
                if lone_g is None:
                    break
                if not corrupt_frames.allows_another(self.backend.now_s):
                    self._too_many_corrupt_frames(len(corrupt_frames.stops_s), lone_g)
                self.printer.gcode.respond_info(f"Load cell: one sample read {lone_g:.0f}g between samples near 0g "
                                                "(a corrupted frame); the nozzle watch stopped the move, moving on")
                armed_s = self.backend.now_s
                firmware = device.trigger.arm(self._trigger().pop("settings"), tare_counts, **trigger)
            if result.triggered or result.error != TriggerError.NONE:
                self._stopped(result, tare_counts, t_start_s)
            self._note_largest_force(tare_counts, t_start_s)
        finally:
            history.keep_from_s = kept_from_s

    def _too_many_corrupt_frames(self, count: int, last_g: float) -> None:
        """More corrupted frames stopped the move within CORRUPT_FRAME_WINDOW_S than it moves on
        from: lift and end the command naming the sensor (not a collision)."""
        where = self._stop_place()
        self._lift()
        raise ProbeError(ERROR_PREFIX + f"the load cell sent {count} corrupted frames within "
                         f"{CORRUPT_FRAME_WINDOW_S:g} s (single samples past force_safety_limit, the last "
                         f"{last_g:.0f}g): the move was stopped and the nozzle lifted; check the sensor's cable "
                         "and its shielding" + where)

    def _stop_place(self) -> str:
        """' (the nozzle watch stopped the move at X,Y,Z during COMMAND)' for an error message."""
        x_mm, y_mm, z_mm = self.device.motion.get_position()
        during = self._during_command()
        return f" (the nozzle watch stopped the move at {x_mm:.3f},{y_mm:.3f},{z_mm:.3f}" + (
            f" during {during})" if during else ")")

    def _force_since(self, tare_counts: float, t_start_s: float) -> float:
        """The force of largest size the cell read since t_start_s, against the move's tare (g), on
        two samples in a row (the smaller of each pair: a lone corrupted frame is not a force)."""
        device = self.device
        device.load_cell.pump()
        _, counts, _ = device.history.between(t_start_s, self.backend.now_s)
        if not len(counts):
            return 0.0
        force_g = device.grams(counts, tare_counts)
        if len(force_g) > 1:
            pairs = np.stack([force_g[:-1], force_g[1:]])
            force_g = pairs[np.argmin(np.abs(pairs), axis=0), np.arange(pairs.shape[1])]
        return float(force_g[np.argmax(np.abs(force_g))])

    def _note_largest_force(self, tare_counts: float, t_start_s: float) -> None:
        """Keep the largest force a watched move that ran to its end put on the nozzle (status:
        how close printing comes to nozzle_watch_force)."""
        self.largest_force_g = max(self.largest_force_g, abs(self._force_since(tare_counts, t_start_s)))

    def _move_tare_counts(self, descends: bool) -> float:
        """The cell's reading that the move's force is measured from.

        A move that starts at or above nozzle_watch_height starts clear: its own samples are the
        tare, kept as the free-air tare. So are those of a lower move that does not go down (travel
        at layer height): a steady force that is not the bed (a bowden tube pulling, a weight) is
        tared away, and what the move meets on its way is seen. A lower move that goes down may
        start pressing already (a run of small steps down; a move the mesh cut in pieces): it is
        measured from the newest free-air tare (that one, or the probe's last tap tare), so a
        press cannot creep up step by step. Only when neither exists are its own samples used."""
        device = self.device
        if device.motion.get_position()[2] >= self.options.height_mm:
            self._free_air = (self._tare_counts(), self.backend.now_s)
            return self._free_air[0]
        if not descends:
            return self._tare_counts()
        known = [tare for tare in (self._free_air, (device.tare_counts_at_tap, device.tare_time_s))
                 if tare is not None and tare[0] is not None]
        if known:
            return max(known, key=lambda tare: tare[1])[0]
        return self._tare_counts()

    def _tare_counts(self) -> float:
        """The cell at rest before the move: the mean of the newest tare_time of samples."""
        device = self.device
        rate = device.sample_rate_sps
        needed = tare_sample_count(device.options.tare_time_s, rate)
        deadline_s = self.backend.now_s + SENSOR_TIMEOUT_S
        while True:
            device.load_cell.pump()
            now_s = self.backend.now_s
            _, counts, _ = device.history.between(now_s - (needed + FRESH_MARGIN_SAMPLES) / rate, now_s)
            if len(counts) >= needed:
                return robust_tare_counts(counts[-needed:])
            if now_s >= deadline_s:
                raise ProbeError(ERROR_PREFIX + "timed out waiting for sensor data before a watched move"
                                 + self._during())
            self.backend.dwell((needed - len(counts)) / rate)

    def _stopped(self, result, tare_counts: float, t_start_s: float) -> None:
        """The trigger halted the move: measure, lift, and end the command with the collision."""
        device = self.device
        self.collisions += 1
        device._wait_for_samples_to(self.backend.now_s)
        peak_g = self._force_since(tare_counts, t_start_s)
        x_mm, y_mm, z_mm = device.motion.get_position()
        during = self._during_command()
        _, counts, _ = device.history.between(t_start_s, self.backend.now_s)
        saturated = safety.sensor_fault(counts, device.load_cell.counts_range, 0) == "saturated"
        where = self._stop_place()
        self._lift()
        if saturated:
            raise ProbeError(ERROR_PREFIX + f"the load cell reading is at the end of the ADC's range ({int(counts[-1])} "
                             "counts, saturated): no force can be measured; check the sensor wiring, its gain and "
                             "the cell" + where)
        if result.error not in (TriggerError.NONE, TriggerError.FORCE_SAFETY, TriggerError.DRIFT_SAFETY):
            # The sensor itself failed (stuck, gone): say so, not a collision (a drift stop is a
            # force past nozzle_watch_force on two samples in a row).
            raise ProbeError(device.trigger.error_message(result.error, device.options) + where)
        raise ProbeError(collision_message(x_mm, y_mm, z_mm, peak_g, during))

    def _lift(self) -> None:
        """Straight up to nozzle_watch_height, at least sample_retract_dist above the halt (Z not
        homed: nozzle_watch_height above the halt, which is at what it met)."""
        probe_options = self.device.probe.options
        z_now = float(self.backend.position[2])
        if self.device.motion.is_z_homed():
            lowest = self.options.height_mm - self.device.motion.frame_offset_mm["z"]
        else:
            lowest = z_now + self.options.height_mm
        target = max(lowest, z_now + probe_options.sample_retract_dist_mm)
        target = min(target, self.backend.limits["z"][1])
        if target > z_now:
            self.backend.move_to(z=target, speed_mm_s=probe_options.effective_lift_speed_mm_s)

    def _during_command(self) -> str | None:
        return self.printer.gcode.running_command()

    def _during(self) -> str:
        command = self._during_command()
        return f" (before {command})" if command else ""

    def get_status(self) -> dict:
        return {"nozzle_watch_height": self.options.height_mm, "nozzle_watch_force": self.options.force_g,
                "watched_moves": self.watched_moves, "collisions": self.collisions,
                "largest_watched_force": self.largest_force_g}
