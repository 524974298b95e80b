"""The emulator image's scenarios, computed by the host library (cffi), written as C.

`python firmware/port/scenarios.py TICKS_PER_S OUT.c` writes the scenario table for a board whose
time base runs at TICKS_PER_S. Every expected value (filtered force after each sample, the
event, the state, the error code, the glitch count) comes from tapcell.mcu: the same C core
built for the host and driven through cffi. The image runs the same frames through the
unchanged core on the emulated MCU and compares bit for bit (firmware/port/app.c).

A scenario is frames for the software HX71x (soft_hx71x.c): HX717, gain A-128 (25 pulses),
320 sps; the first 4 frames are the chip's settling frames, which the driver discards.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))   # bench/ (the cost case is the bench's own)

from bench.firmware_cost import make_case   # noqa: E402
from tapcell.filters import Q1615_ONE_G, FilterOptions, design_firmware_filter   # noqa: E402
from tapcell.mcu.sensors import (   # noqa: E402
    HX71X_DATA_BITS, HX71X_ERR_DESYNC, SensorFrameError, decode_hx71x_frames, hx71x_pulses,
)
from tapcell.mcu.trigger import FirmwareTrigger, TriggerError, TriggerParams   # noqa: E402
from tapcell.mcu.trigger_model import TriggerModel   # noqa: E402

CHIP, CHIP_CODE, GAIN, GAIN_CODE = "hx717", 1, "A-128", 0
SPS = 320
SETTLING_FRAMES = 4
COUNTS_PER_GRAM = 50.0
REFERENCE_TARE = 150_000
PULSES = hx71x_pulses(CHIP, GAIN)
END_SAMPLE, END_ABORT, END_WATCHDOG = 0, 1, 2
EVENT_NONE, EVENT_TRIGGER, EVENT_RELEASE, EVENT_ERROR = 0, 1, 2, 3
STATE_CODES = {"idle": 0, "armed": 1, "triggered": 2, "error": 3}
CONFIG_FIELDS = ("reference_tare_counts", "force_limit_counts", "drift_limit_counts", "scale", "scale_frac_bits",
                 "trigger_q", "release_q", "sample_period_ticks", "watchdog_periods", "stuck_samples")


@dataclass
class Scenario:
    name: str
    params: TriggerParams
    tare_counts: int
    frames: np.ndarray          # uint32, settling frames first
    end: int
    event: int
    state: int
    error: int
    glitches: int
    filtered_q: np.ndarray      # int32, one per sample fed to the trigger
    watchdog_check_ticks: int
    watchdog_latency_max_ticks: int


def frame_of(counts: np.ndarray, trailing: int | None = None) -> np.ndarray:
    """The bits the chip shifts out: 24-bit two's complement, then the trailing bits (all 1 unless given)."""
    extra = PULSES - HX71X_DATA_BITS
    tail = (1 << extra) - 1 if trailing is None else trailing
    return ((np.asarray(counts, dtype=np.int64) & 0xFFFFFF) << extra | tail).astype(np.uint32)


def _params(ticks_per_s: int, **overrides) -> TriggerParams:
    options = overrides.pop("filter", FilterOptions(SPS, 0.8, 2, 100, 2, (50, 60), 2.0))
    base = dict(counts_per_gram=COUNTS_PER_GRAM, reference_tare_counts=REFERENCE_TARE, trigger_force_g=75.0,
                sample_rate_sps=SPS, clock_hz=float(ticks_per_s), sos=design_firmware_filter(options))
    base.update(overrides)
    return TriggerParams(**base)


def _run_endstop(endstop, name: str, params: TriggerParams, tare: int, frames: np.ndarray) -> tuple:
    """Feed the frames the image will see; (end, event, fed, filtered_q, state, error, glitches)."""
    period_s = 1.0 / SPS
    if endstop.arm(tare, 0.0) != TriggerError.NONE:
        raise RuntimeError(f"{name}: the host refused to arm")
    good = len(frames)
    try:
        decoded = decode_hx71x_frames(frames, PULSES)
    except SensorFrameError as problem:                      # the host decoder sees the desync too
        good = problem.index
        decoded = decode_hx71x_frames(frames[:good], PULSES)
    result = endstop.feed(np.arange(1, good + 1) * period_s, decoded, want_filtered=True)
    filtered = np.round(result.filtered_g * Q1615_ONE_G).astype(np.int32)
    fed = result.consumed
    if result.trigger_index is not None:
        end, event = END_SAMPLE, EVENT_TRIGGER
    elif result.error_index is not None:
        end, event = END_SAMPLE, EVENT_ERROR
    elif good < len(frames):
        endstop.abort(HX71X_ERR_DESYNC, (good + 1) * period_s)
        end, event = END_ABORT, EVENT_ERROR
    else:
        deadline_s = (fed + params.watchdog_periods) * period_s
        if endstop.check_watchdog(deadline_s + 2.0 / params.clock_hz) != TriggerError.WATCHDOG_TIMEOUT:
            raise RuntimeError(f"{name}: the host's watchdog did not fire")
        end, event = END_WATCHDOG, EVENT_ERROR
    return (end, event, fed, filtered[:fed], STATE_CODES[endstop.state], endstop.field("error"), endstop.glitches)


def _expect(name: str, params: TriggerParams, tare: int, counts: np.ndarray, ticks_per_s: int,
            outcome: tuple[int, int, range], desync_at: int | None = None, silent_after: int | None = None) -> Scenario:
    """What the host library does with the samples the image will see.

    The C library (cffi) gives the expected values; the Python model of the trigger
    (tapcell.mcu.trigger_model, written from the rules, no C) must agree with it, and both
    must give `outcome` = (end, error code, samples fed in this range) as the scenario was built: a bug
    planted in the shared C source changes the host library too, and is caught here."""
    frames = frame_of(counts)
    if desync_at is not None:
        frames[desync_at] &= ~np.uint32(1)                  # the trailing bit reads 0
    delivered = frames if silent_after is None else frames[:silent_after]
    library = _run_endstop(FirmwareTrigger(params), name, params, tare, delivered)
    model = _run_endstop(TriggerModel(params), name, params, tare, delivered)
    if not (library[:3] == model[:3] and np.array_equal(library[3], model[3]) and library[4:] == model[4:]):
        raise RuntimeError(f"{name}: the host library (C) and the trigger model (Python) disagree: "
                           f"end/event/fed/state/error/glitches {library[:3] + library[4:]} vs {model[:3] + model[4:]}")
    end, event, fed, filtered, state, error, glitches = library
    if (end, error) != outcome[:2] or fed not in outcome[2]:
        raise RuntimeError(f"{name}: expected end/error/samples {outcome}, the host library gives {(end, error, fed)}")
    period_ticks = FirmwareTrigger(params).config["sample_period_ticks"]
    check_ticks = period_ticks // 4
    settle = frame_of(np.full(SETTLING_FRAMES, tare))
    return Scenario(name, params, tare, np.concatenate([settle, delivered]), end, event, state, error, glitches,
                    filtered, check_ticks, check_ticks + max(2, check_ticks // 8))


def _exactly(samples: int) -> range:
    return range(samples, samples + 1)


def scenarios(ticks_per_s: int) -> list[Scenario]:
    rng = np.random.default_rng(23)
    tare = REFERENCE_TARE + 400
    noise = lambda n: rng.normal(0, 20, n)   # noqa: E731  (counts RMS; a live HX717 at gain 128)
    out = []

    # A tap: 60 samples in the air, then the nozzle presses 12 g more per sample until the trigger
    # (75 g) fires: after contact, and before the press is 60 samples old.
    grams = np.concatenate([np.zeros(60), np.arange(1, 60) * 12.0])
    counts = np.round(tare + grams * COUNTS_PER_GRAM + noise(grams.size)).astype(np.int64)
    out.append(_expect("tap", _params(ticks_per_s), tare, counts, ticks_per_s, (END_SAMPLE, 0, range(61, 120))))

    # The chip stops converting after 40 samples: the watchdog interrupt ends the move.
    counts = np.round(tare + noise(60)).astype(np.int64)
    out.append(_expect("watchdog", _params(ticks_per_s), tare, counts, ticks_per_s,
                       (END_WATCHDOG, TriggerError.WATCHDOG_TIMEOUT, _exactly(40)), silent_after=40))

    # A trailing bit reads 0 at sample 30 (HX71x desync): the driver's code aborts the move.
    counts = np.round(tare + noise(60)).astype(np.int64)
    out.append(_expect("hx71x_desync", _params(ticks_per_s), tare, counts, ticks_per_s,
                       (END_ABORT, HX71X_ERR_DESYNC, _exactly(30)), desync_at=30))

    # The chip repeats one value from sample 25 on: STUCK_SENSOR on the stuck_samples-th equal one.
    counts = np.round(tare + noise(80)).astype(np.int64)
    counts[25:] = counts[25]
    params = _params(ticks_per_s)
    out.append(_expect("stuck_sensor", params, tare, counts, ticks_per_s,
                       (END_SAMPLE, TriggerError.STUCK_SENSOR, _exactly(25 + params.effective_stuck_samples))))

    # A slow press (0.4 g per sample, 128 g/s) with the drift limit off: the drift high-pass holds the
    # filtered force under the trigger, the raw force window (300 g around the reference and the
    # tare) stops it on the first sample past it.
    grams = np.arange(1, 900) * 0.4
    counts = np.round(tare + grams * COUNTS_PER_GRAM + noise(grams.size)).astype(np.int64)
    params = _params(ticks_per_s, force_safety_limit_g=300.0, drift_safety_limit_g=0.0, trigger_force_g=150.0)
    limit = FirmwareTrigger(params).config["force_limit_counts"]
    first_past = int(np.flatnonzero(counts > min(tare, REFERENCE_TARE) + limit)[0])
    out.append(_expect("force_window_slow_ramp", params, tare, counts, ticks_per_s,
                       (END_SAMPLE, TriggerError.FORCE_SAFETY, _exactly(first_past + 1))))

    # Place for the nozzle watch of the load-cell safety work (its own branch): a scenario
    # here, generated the same way, with the watch's expected verdict from the host library.
    return out


# ------------------------------------------------------------------------------- C output

def _c_array(ctype: str, name: str, values) -> str:
    items = [str(int(v)) + ("u" if ctype.startswith("uint") else "") for v in values]
    rows = [", ".join(items[i:i + 12]) for i in range(0, len(items), 12)]
    return f"static const {ctype} {name}[{max(1, len(items))}] = {{\n    " + ",\n    ".join(rows or ["0"]) + "\n};\n"


def _c_int32(value: int) -> str:
    return f"({value})" if value != -2 ** 31 else "(-2147483647 - 1)"


def _c_config(config: dict) -> str:
    return "{" + ", ".join(f".{field} = {_c_int32(int(config[field]))}" for field in CONFIG_FIELDS) + "}"


def _c_filter(sos) -> tuple[str, int, int]:
    coeff = np.zeros((4, 5), dtype=np.int64)
    n, frac = 0, 30
    if sos is not None:
        coeff[:sos.n_sections] = sos.coeff
        n, frac = sos.n_sections, sos.frac_bits
    text = "{" + ", ".join("{" + ", ".join(_c_int32(int(c)) for c in row) + "}" for row in coeff) + "}"
    return text, n, frac


def write_c(ticks_per_s: int, path: Path) -> None:
    parts = [f"/* Generated by firmware/port/scenarios.py for a {ticks_per_s} Hz time base. Do not edit. */\n",
             '#include "scenario.h"\n\n']
    table = []
    for index, sc in enumerate(scenarios(ticks_per_s)):
        config = FirmwareTrigger(sc.params).config
        parts.append(_c_array("uint32_t", f"frames_{index}", sc.frames))
        parts.append(_c_array("int32_t", f"filtered_{index}", sc.filtered_q))
        coeff, n, frac = _c_filter(sc.params.sos)
        table.append(
            f'    {{.name = "{sc.name}", .config = {_c_config(config)},\n'
            f"     .coeff = {coeff}, .n_sections = {n}, .frac_bits = {frac},\n"
            f"     .chip = {CHIP_CODE}, .gain = {GAIN_CODE}, .sample_rate_sps = {SPS}, .tare_counts = {sc.tare_counts},\n"
            f"     .watchdog_check_ticks = {sc.watchdog_check_ticks}u,"
            f" .watchdog_latency_max_ticks = {sc.watchdog_latency_max_ticks}u,\n"
            f"     .n_frames = {sc.frames.size}, .frames = frames_{index},\n"
            f"     .end = {sc.end}, .event = {sc.event}, .state = {sc.state}, .error = {sc.error},\n"
            f"     .n_fed = {sc.filtered_q.size}, .glitches = {sc.glitches}, .filtered_q = filtered_{index}}},\n")
    parts.append("const struct scenario scenarios[] = {\n" + "".join(table) + "};\n")
    parts.append(f"const unsigned n_scenarios = {len(table)};\n\n")

    case = make_case(4, 200)
    parts.append(_c_array("int32_t", "cost_counts", case.counts))
    parts.append(_c_array("uint32_t", "cost_ticks", case.ticks))
    parts.append(_c_array("int32_t", "cost_filtered", case.expected_q))
    coeff = "{" + ", ".join("{" + ", ".join(_c_int32(int(c)) for c in row) + "}" for row in case.coeff) + "}"
    parts.append(f"const struct cost_case cost_case = {{.config = {_c_config(case.config)},\n"
                 f"    .coeff = {coeff}, .n_sections = {case.n_sections}, .frac_bits = {case.frac_bits},\n"
                 f"    .tare_counts = {case.tare_counts}, .n_samples = {case.counts.size},\n"
                 f"    .counts = cost_counts, .ticks = cost_ticks, .filtered_q = cost_filtered}};\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(parts))


def describe(ticks_per_s: int) -> list[tuple[str, int, int, int]]:
    """(name, samples fed, end, error) per scenario: what the host library expects."""
    return [(sc.name, sc.filtered_q.size, sc.end, sc.error) for sc in scenarios(ticks_per_s)]


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: scenarios.py TICKS_PER_S OUT.c")
    write_c(int(sys.argv[1]), Path(sys.argv[2]))
