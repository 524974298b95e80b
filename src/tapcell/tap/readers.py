"""Tap files: tapcell.tap.v1 (.json / .jsonl), CSV, Klipper-family `dump_taps` events and
the older workbench capture. Every problem is a `TapFileError` naming the file and what is wrong.

JSON is read through a compiled kernel when it was built (tapcell.tap.native, c/readers.c): it
decodes the object in one pass, the long number arrays straight into float64 and the rest as
json.loads would; anything unusual in the text makes it give up, and json.loads reads the whole
text and names the problem.
"""

from __future__ import annotations

import itertools
import math
import operator
import os
import sys
from collections.abc import Collection
from typing import Any

import numpy as np

from tapcell.files import FileRefused, read_limited
from tapcell.tap import native
from tapcell.tap.analysis import MIN_SAMPLES  # a file with fewer samples could not be analysed
from tapcell.tap.analysis import NOMINAL_RATE_FACTOR, nominal_rate_agrees, times_rate_sps
from tapcell.tap.model import Move, TapAnalysis, TapData, TapFileError

_C = native.load("readers")

FORMAT = "tapcell.tap.v1"
# The top-level keys whose values are long arrays of numbers: the reader's kernel parses those.
NUMBER_ARRAY_KEYS = ("time", "force", "z")
MOVE_KEYS = ("print_time", "move_t", "start_v", "accel", "start_z", "z_r")
# A log of a few thousand taps is tens of MB; anything far bigger is not a tap file, and reading
# it whole (or an endless device such as /dev/zero) would exhaust memory.
MAX_FILE_BYTES = 256 * 1024 * 1024
# JSON integers longer than this are no measurement (a float64 holds 15-17 digits); refusing them
# at parse time keeps every later float() and isfinite() from overflowing.
MAX_INTEGER_DIGITS = 20
# Integers beyond this (from a caller of tap_from_object, not a file) are beyond a float too:
# they read as infinity.
LARGEST_FLOAT_INT = int(sys.float_info.max)


def read_tap_file(path: str | os.PathLike[str]) -> list[TapData]:
    """All taps in a file (one for .json/.csv, one per line for .jsonl)."""
    path = _file_name(path)
    text = _read_text(path)
    if not text or text.isspace():  # as `not text.strip()`, without copying the whole text
        raise TapFileError(path, "the file is empty")
    suffix = _suffix(path)
    if suffix == ".csv":
        return [_tap_from_csv(path, text)]
    if suffix == ".jsonl":
        taps = []
        for number, line in enumerate(text.splitlines(), start=1):
            if line.strip():
                document, parsed = _load_tap_json(path, line, f"line {number}: ")
                taps.append(tap_from_object(document, path, f"line {number}: ", finite_arrays=parsed))
        return taps
    document, parsed = _load_tap_json(path, text, "")
    if isinstance(document, list):
        raise TapFileError(path, "holds a JSON list; a .json tap file holds one object "
                                 "(write many taps as .jsonl, one object per line)")
    return [tap_from_object(document, path, "", finite_arrays=parsed)]


def _file_name(path: str | os.PathLike[str]) -> str:
    """The path as pathlib spells it (no empty or '.' parts, no trailing '/'), which messages name.
    Most names already are spelled so: only the others import pathlib (~5 ms, a tenth of the
    start-up beyond numpy's of `tapcell analyze`)."""
    name = os.fspath(path)
    if name and "//" not in name and "/./" not in name and not name.startswith("./") and not name.endswith(("/", "/.")):
        return name
    from pathlib import Path

    return str(Path(name))


def _suffix(name: str) -> str:
    """The lower-cased extension, as pathlib's `suffix` finds it ('.json'; none for '.json' alone)."""
    base = name.rpartition("/")[2]
    dot = base.rfind(".")
    return base[dot:].lower() if 0 < dot < len(base) - 1 else ""


def _read_text(path: str) -> str:
    try:
        return read_limited(path, MAX_FILE_BYTES).decode("utf-8")
    except FileRefused as problem:
        raise TapFileError(path, f"{problem}, not a tap file") from None
    except (OSError, UnicodeDecodeError) as problem:
        raise TapFileError(path, f"cannot read the file ({problem})") from None


class _HugeInteger(ValueError):
    def __init__(self, digits: int):
        super().__init__(f"an integer with {digits} digits (at most {MAX_INTEGER_DIGITS} allowed)")


def _bounded_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_INTEGER_DIGITS:
        raise _HugeInteger(digits)
    return int(text)


def _load_json(path: str, text: str, where: str) -> Any:
    import json  # here, not at the top: only a file the reader's kernel leaves to json needs it (1.5 ms of start-up)

    try:
        return json.loads(text, parse_int=_bounded_int)
    except json.JSONDecodeError as problem:
        raise TapFileError(path, f"{where}not valid JSON ({problem.msg} at line {problem.lineno} column {problem.colno})") from None
    except _HugeInteger as problem:
        raise TapFileError(path, f"{where}not valid tap data: {problem}") from None
    except RecursionError:  # the json module's own limit on nested arrays/objects
        raise TapFileError(path, f"{where}not valid tap data: JSON nested too deeply") from None


def _load_tap_json(path: str, text: str, where: str) -> tuple[Any, tuple[str, ...]]:
    """The decoded JSON of a tap, and the keys whose number arrays the kernel parsed into float64
    arrays (finite: it refuses anything else)."""
    if _C is not None:
        decoded = _C.decode_tap_json(text, NUMBER_ARRAY_KEYS)
        if decoded is not None:
            document, parsed = decoded
            for key in parsed:
                document[key] = np.frombuffer(document[key])
            return document, parsed
    return _load_json(path, text, where), ()


def _as_float(value: Any) -> float | None:
    """A decoded JSON number as a float (an integer beyond the float range: infinity), else None."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    if isinstance(value, int) and abs(value) > LARGEST_FLOAT_INT:
        return math.inf if value > 0 else -math.inf
    return float(value)


_PLAIN_NUMBER_TYPES = frozenset((float, int))


def _checked_numbers(path: str, where: str, name: str, values: list) -> np.ndarray:
    """Item by item: names what is wrong (nested lists, strings, booleans, null)."""
    if any(isinstance(value, list) for value in values):
        raise TapFileError(path, f"{where}'{name}' must be a flat list of numbers")
    floats = [_as_float(value) for value in values]
    if any(value is None for value in floats):
        raise TapFileError(path, f"{where}'{name}' must be a list of numbers")
    return np.array(floats, dtype=float)


def _numbers(path: str, where: str, name: str, values: Any, known_finite: bool = False) -> np.ndarray:
    if isinstance(values, np.ndarray) and values.dtype == np.float64 and values.ndim == 1:
        array = values  # parsed by the reader's kernel
        if known_finite:
            return array
    else:
        array = _list_numbers(path, where, name, values)
    finite = np.isfinite(array)
    if not finite.all():
        raise TapFileError(path, f"{where}'{name}' holds NaN or infinity (index {int(np.flatnonzero(~finite)[0])})")
    return array


def _list_numbers(path: str, where: str, name: str, values: Any) -> np.ndarray:
    if not isinstance(values, list):
        raise TapFileError(path, f"{where}'{name}' must be a list of numbers")
    types = list(map(type, values))
    # The common case at C speed: every item a float or int (a bool's type is bool, so it is not).
    # All floats (json's type for a number written with a point), the commonest, cannot overflow.
    if types.count(float) == len(types):
        return np.array(values, dtype=float)
    try:
        array = np.array(values, dtype=float) if set(types) <= _PLAIN_NUMBER_TYPES else None
    except OverflowError:  # an integer beyond the float range: the per-item path reads it as infinity
        array = None
    return array if array is not None else _checked_numbers(path, where, name, values)


def _number(path: str, where: str, name: str, value: Any) -> float:
    number = _as_float(value)
    if number is None or not math.isfinite(number):
        raise TapFileError(path, f"{where}'{name}' must be a finite number, got {_shown(value)}")
    return number


def _shown(value: Any, limit: int = 40) -> str:
    """A value as an error message shows it: its repr, cut short (a 1 MB string is not echoed)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


# The keys of the optional objects that tap-format.md gives a number (or null: not known).
EVENT_KEYS = ("home_end_time", "pullback_start_time", "pullback_end_time")
PROBE_KEYS = ("x", "y", "speed", "pullback_distance", "pullback_speed", "trigger_force")


def _known_numbers(path: str, where: str, name: str, values: dict, keys: tuple[str, ...]) -> dict:
    """`values` with each of `keys` it has checked: null or a finite number (a NaN time or a string
    where the format puts a number is the file's error, not a value to carry); other keys kept as they are."""
    for key in keys:
        value = values.get(key)
        # a finite float is kept as it is (the common case, without a call); anything else is checked
        if value is not None and not (type(value) is float and math.isfinite(value)):
            values[key] = _number(path, where, f"{name}.{key}", value)
    return values


def _moves(path: str, where: str, values: Any) -> list[Move]:
    if not isinstance(values, list):
        raise TapFileError(path, f"{where}'moves' must be a list of objects")
    moves = _plain_moves(values)
    if moves is None:  # something is wrong: find it item by item, to name it
        moves = [_checked_move(path, where, k, item) for k, item in enumerate(values)]
    for k, move in enumerate(moves):
        if move.start_v < 0 or move.move_t < 0:
            raise TapFileError(path, f"{where}moves[{k}]: start_v and move_t must be >= 0")
    if any(b.print_time < a.print_time for a, b in zip(moves, moves[1:])):
        raise TapFileError(path, f"{where}moves are not oldest first")
    return moves


_MOVE_FIELDS = operator.itemgetter(*MOVE_KEYS)


def _plain_moves(values: list) -> list[Move] | None:
    """The moves when every item is an object whose tap-format keys hold finite plain numbers, else
    None. In plain Python: a tap has a handful of moves, too few for numpy's per-call cost to pay."""
    try:
        rows = list(map(_MOVE_FIELDS, values))
    except (KeyError, TypeError):  # a missing key, or an item that is not an object
        return None
    numbers = list(itertools.chain.from_iterable(rows))
    if not set(map(type, numbers)) <= _PLAIN_NUMBER_TYPES:
        return None
    try:  # ints among them too (json's type for a number written without a point, e.g. z_r)
        numbers = list(map(float, numbers))
    except OverflowError:  # an integer beyond the float range
        return None
    if not all(map(math.isfinite, numbers)):
        return None
    width = len(MOVE_KEYS)
    return [Move(*numbers[start:start + width]) for start in range(0, len(numbers), width)]


def _checked_move(path: str, where: str, k: int, item: Any) -> Move:
    if not isinstance(item, dict):
        raise TapFileError(path, f"{where}moves[{k}] must be an object")
    missing = [key for key in MOVE_KEYS if key not in item]
    if missing:
        raise TapFileError(path, f"{where}moves[{k}] lacks {', '.join(missing)}")
    return Move(*(_number(path, where, f"moves[{k}].{key}", item[key]) for key in MOVE_KEYS))


def _check_samples(path: str, where: str, time_s: np.ndarray, force_g: np.ndarray, z_mm: np.ndarray | None) -> None:
    if len(time_s) != len(force_g):
        raise TapFileError(path, f"{where}'time' has {len(time_s)} values but 'force' has {len(force_g)}")
    if z_mm is not None and len(z_mm) != len(time_s):
        raise TapFileError(path, f"{where}'z' has {len(z_mm)} values but 'time' has {len(time_s)}")
    if len(time_s) < MIN_SAMPLES:
        raise TapFileError(path, f"{where}{len(time_s)} samples, at least {MIN_SAMPLES} needed")
    # time_s[k + 1] <= time_s[k] is np.diff(time_s) <= 0 for finite times (a difference of two
    # finite floats is 0 only when they are equal), without diff's and np.any's per-call cost.
    not_after = time_s[1:] <= time_s[:-1]
    if not_after.any():
        k = int(np.flatnonzero(not_after)[0])
        raise TapFileError(path, f"{where}'time' is not strictly increasing (index {k + 1}: {float(time_s[k + 1])!r} after {float(time_s[k])!r})")


def _dict(path: str, where: str, name: str, value: Any) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise TapFileError(path, f"{where}'{name}' must be an object")
    return dict(value)


def _check_sample_rate(path: str, where: str, rate_sps: float, time_s: np.ndarray) -> None:
    """The nominal rate must be positive and agree with the samples' times (analysis.nominal_rate_agrees)."""
    if rate_sps <= 0:
        raise TapFileError(path, f"{where}'sample_rate' must be positive")
    if len(time_s) > 1 and time_s[-1] > time_s[0] and not nominal_rate_agrees(rate_sps, time_s):
        raise TapFileError(path, f"{where}'sample_rate' {rate_sps:g} disagrees with the samples' times "
                                 f"({times_rate_sps(time_s):.4g} sps on average); allowed: within "
                                 f"{NOMINAL_RATE_FACTOR:g}x of that, or leave it out")


# What the kernel's plain_tap_fields checks a tapcell.tap.v1 object against (MOVE_KEYS start
# print_time, move_t, start_v: it checks print_time's order and move_t's and start_v's signs as _moves does).
_PLAIN_TAP_FORM = (FORMAT, MOVE_KEYS, EVENT_KEYS, PROBE_KEYS, MIN_SAMPLES)


def tap_from_object(obj: Any, path: str = "<memory>", where: str = "", *,
                    finite_arrays: Collection[str] = ()) -> TapData:
    """A TapData from one decoded JSON object of any accepted flavour. `finite_arrays`: keys whose
    float64 arrays are known finite (the reader's kernel parsed them: it refuses anything else)."""
    if finite_arrays and _C is not None and isinstance(obj, dict):
        # A plain tapcell.tap.v1 object, checked in one call (c/readers.c); its twin is the rest of this
        # function, which builds the same tap, and names the problem wherever the kernel gives up.
        fields = _C.plain_tap_fields(obj, tuple(finite_arrays), _PLAIN_TAP_FORM)
        if fields is not None:
            time_s, force_g, z_mm, move_rows, sample_rate, events, probe, truth, meta = fields
            if sample_rate is not None:
                _check_sample_rate(path, where, sample_rate, time_s)
            return TapData(time_s=time_s, force_g=force_g, z_mm=z_mm, moves=[Move(*row) for row in move_rows],
                           sample_rate_sps=sample_rate, events=events, probe=probe, truth=truth, meta=meta)
    if not isinstance(obj, dict):
        raise TapFileError(path, f"{where}expected a JSON object with 'time' and 'force'")
    if "tap" in obj and isinstance(obj["tap"], dict):  # Klipper-family dump_taps event
        obj, finite_arrays = obj["tap"], ()
    if "format" in obj and obj["format"] != FORMAT:
        raise TapFileError(path, f"{where}unknown format {obj['format']!r}, expected {FORMAT!r}")
    missing = [key for key in ("time", "force") if key not in obj]
    if missing:
        raise TapFileError(path, f"{where}missing key {', '.join(repr(k) for k in missing)}")
    time_s = _numbers(path, where, "time", obj["time"], "time" in finite_arrays)
    force_g = _numbers(path, where, "force", obj["force"], "force" in finite_arrays)
    z_mm = None
    if "z" in obj:
        z_mm = _numbers(path, where, "z", obj["z"], "z" in finite_arrays)
    elif "position" in obj:  # workbench capture: [x, y, z] per sample
        position = obj["position"]
        if not isinstance(position, list) or not all(isinstance(p, list) and len(p) >= 3 for p in position):
            raise TapFileError(path, f"{where}'position' must be a list of [x, y, z]")
        z_mm = _numbers(path, where, "position z", [p[2] for p in position])
    moves = _moves(path, where, obj["moves"]) if obj.get("moves") else []
    if z_mm is None and not moves:
        raise TapFileError(path, f"{where}needs 'z' or 'moves' (the motion of the tap)")
    _check_samples(path, where, time_s, force_g, z_mm)
    events = _dict(path, where, "events", obj.get("events"))
    for key in EVENT_KEYS:  # dump_taps keeps them on top
        if key in obj and key not in events:
            events[key] = obj[key]
    events = _known_numbers(path, where, "events", events, EVENT_KEYS)
    sample_rate = obj.get("sample_rate")
    if sample_rate is not None:
        _check_sample_rate(path, where, _number(path, where, "sample_rate", sample_rate), time_s)
    return TapData(
        time_s=time_s,
        force_g=force_g,
        z_mm=z_mm,
        moves=moves,
        sample_rate_sps=float(sample_rate) if sample_rate is not None else None,
        events=events,
        probe=_known_numbers(path, where, "probe", _dict(path, where, "probe", obj.get("probe")), PROBE_KEYS),
        truth=_dict(path, where, "truth", obj.get("truth")),
        meta=_dict(path, where, "meta", obj.get("meta")),
    )


def _tap_from_csv(path: str, text: str) -> TapData:
    import csv  # here, not at the top: most tap files are JSON, and `tapcell analyze` starts faster

    try:
        rows = list(csv.reader(text.splitlines()))
    except csv.Error as problem:  # e.g. a NUL byte, or a field beyond the csv module's size limit
        raise TapFileError(path, f"not a valid CSV file ({problem})") from None
    header = [name.strip().lower() for name in rows[0]]
    missing = [name for name in ("time", "force", "z") if name not in header]
    if missing:
        raise TapFileError(path, f"CSV header lacks column(s) {', '.join(missing)} (found: {', '.join(header)})")
    columns = {name: header.index(name) for name in ("time", "force", "z")}
    values: dict[str, list[float]] = {name: [] for name in columns}
    for number, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        for name, index in columns.items():
            cell = row[index] if index < len(row) else "<missing>"
            try:
                values[name].append(float(cell))
            except ValueError:
                raise TapFileError(path, f"CSV line {number}: column '{name}' is not a number ({cell!r})") from None
    return tap_from_object({"time": values["time"], "force": values["force"], "z": values["z"]}, path, "")


def tap_to_json_dict(tap: TapData, analysis: TapAnalysis | None = None) -> dict[str, Any]:
    """The tap as a tapcell.tap.v1 object; with `analysis`, its result under 'analysis'."""
    document: dict[str, Any] = {
        "format": FORMAT,
        "time": [float(t) for t in tap.time_s],
        "force": [float(f) for f in tap.force_g],
    }
    if tap.z_mm is not None:
        document["z"] = [float(z) for z in tap.z_mm]
    if tap.moves:
        document["moves"] = [{key: float(getattr(m, key)) for key in MOVE_KEYS} for m in tap.moves]
    if tap.sample_rate_sps:
        document["sample_rate"] = float(tap.sample_rate_sps)
    for key in ("events", "probe", "truth", "meta"):
        value = getattr(tap, key)
        if value:
            document[key] = _plain(value)
    if analysis is not None:
        document["analysis"] = analysis.to_json()
    return document


def _plain(value: Any) -> Any:
    """numpy scalars and arrays into JSON-ready Python values."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
