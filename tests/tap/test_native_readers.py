"""The reader's kernel (c/readers.c) against json.loads: every good file reads the same to the
last bit, every bad one falls back to json and gets the same message."""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tapcell.tap import TapFileError, read_tap_file, readers
from native_kernel_inputs import generated_tap_objects

pytestmark = pytest.mark.skipif(readers._C is None, reason="reader kernel not built")
REAL_TAPS = sorted((Path(readers.__file__).parent.parent / "taplab" / "real").glob("*.json"))
KEYS = readers.NUMBER_ARRAY_KEYS


def _split(text):
    return readers._C.split_number_arrays(text, KEYS)


def _bits(array):
    return None if array is None else array.tobytes()


def _outcome(text, path="tap.json"):
    """What reading the text gives: the tap's every field (arrays as bytes), or the error message."""
    try:
        document, parsed = readers._load_tap_json(path, text, "")
        tap = readers.tap_from_object(document, path, "", finite_arrays=parsed)
    except TapFileError as problem:
        return str(problem)
    return (_bits(tap.time_s), _bits(tap.force_g), _bits(tap.z_mm), tap.moves, tap.sample_rate_sps,
            tap.events, tap.probe, tap.truth, tap.meta)


def _both_ways(text):
    """With the kernel and with the plain path (no monkeypatch: hypothesis reruns the test body)."""
    fast = _outcome(text)
    kernel, readers._C = readers._C, None
    try:
        reference = _outcome(text)
    finally:
        readers._C = kernel
    return fast, reference


def _generated_taps():
    return [tap for _, tap in generated_tap_objects(1, 7)]  # one of each scenario


def test_generated_and_real_tap_files_read_the_same_to_the_bit(tmp_path, monkeypatch):
    paths = []
    for k, tap in enumerate(_generated_taps()):
        paths.append(tmp_path / f"tap-{k}.json")
        paths[-1].write_text(json.dumps(tap))
    lines = tmp_path / "taps.jsonl"
    lines.write_text("\n".join(path.read_text() for path in paths) + "\n")
    assert REAL_TAPS
    for path in [*paths, lines, *REAL_TAPS]:
        fast = read_tap_file(path)
        with monkeypatch.context() as plain:
            plain.setattr(readers, "_C", None)
            reference = read_tap_file(path)
        assert len(fast) == len(reference)
        for a, b in zip(fast, reference):
            assert (_bits(a.time_s), _bits(a.force_g), _bits(a.z_mm)) == (_bits(b.time_s), _bits(b.force_g), _bits(b.z_mm))
            assert (a.moves, a.sample_rate_sps, a.events, a.probe, a.truth, a.meta) == \
                   (b.moves, b.sample_rate_sps, b.events, b.probe, b.truth, b.meta)
    # the generated files took the kernel's path: their arrays are views of its buffers
    assert isinstance(read_tap_file(paths[0])[0].time_s.base, memoryview)
    monkeypatch.setattr(readers, "_C", None)
    assert read_tap_file(paths[0])[0].time_s.base is None


@settings(max_examples=150, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False)
       | st.builds(lambda m, e: float(f"{m}e{e}"), st.integers(1, 10**17), st.integers(-340, 290)).filter(math.isfinite))
def test_numbers_convert_as_pythons_float_does(value):
    """Shortest repr, 17-digit, 25-digit and exponent forms: the same double as json (float()) reads."""
    for text in (repr(value), f"{value:.17e}", f"{value:.25g}", f"{value:.3E}", f"{value:.20f}"):
        if "inf" in text or len(text) >= 64:
            continue
        split = _split(f'{{"time": [{text}]}}')
        if split is None:  # left to json: an integer beyond a float's exact digits, or rounded to inf
            assert (text.lstrip("-").isdigit() and len(text.lstrip("-")) > 15) or math.isinf(float(text)), text
            continue
        assert split[1]["time"] == bytearray(struct.pack("=d", float(json.loads(text)))), text


@pytest.mark.parametrize("text", [
    "9007199254740992e-22", "9007199254740993e-22", "-9007199254740993.0", "900719925474099.3e7",
    "1844674407370955161.6", "18446744073709551616e-25", "99999999999999999999e-19", "1234567890123456789.0",
    "0.0000000000000000000001", "-0.000", "123456.789e22", "4.9e-324", "1.7976931348623157e308",
    "0.30000000000000004", "-1e-23", "7e22", "7e23"])
def test_numbers_at_the_exact_shortcut_s_edges(text):
    """Around 2^53, at 19 and 20 digits (where the mantissa would wrap) and powers of ten of 22
    and 23: the same double as json reads, whichever way the kernel converts it."""
    split = _split(f'{{"time": [{text}]}}')
    assert split is not None, text
    assert split[1]["time"] == bytearray(struct.pack("=d", float(json.loads(text)))), text


def test_integers_read_as_json_reads_them():
    rest, arrays, _ = _split('{"time": [0, -0, 7, -123456789012345], "force": [-0.0]}')
    assert rest == '{"time": [], "force": []}'
    assert struct.unpack("=4d", arrays["time"]) == (0.0, 0.0, 7.0, -123456789012345.0)
    assert math.copysign(1, struct.unpack("=d", arrays["time"][8:16])[0]) == 1  # json: int("-0") is 0
    assert math.copysign(1, struct.unpack("=d", arrays["force"])[0]) == -1  # a float -0.0 keeps its sign


def test_only_the_top_level_keys_are_cut():
    text = '{"meta": {"time": [1], "s": "\\"time\\": [2]"}, "a": "\\"time\\": [3]", "time" : [ 4 , 5e1 ]\n}'
    rest, arrays, longest_digit_run = _split(text)
    assert rest == '{"meta": {"time": [1], "s": "\\"time\\": [2]"}, "a": "\\"time\\": [3]", "time" : []\n}'
    assert struct.unpack("=2d", arrays["time"]) == (4.0, 50.0)
    assert longest_digit_run == 1
    assert _split(b'{"z": []}') == ('{"z": []}', {"z": bytearray()}, 0)


@pytest.mark.parametrize("text", [
    '{"time": [1, 2,]}', '{"time": [01]}', '{"time": [1.]}', '{"time": [.5]}', '{"time": [+1]}',
    '{"time": [1e]}', '{"time": [1e+]}', '{"time": [-]}', '{"time": [NaN]}', '{"time": [-Infinity]}',
    '{"time": [1e400]}', '{"time": [1234567890123456]}', '{"time": [1' + "0" * 70 + '.5]}',
    '{"time": [[1]]}', '{"time": ["1"]}', '{"time": [true]}', '{"time": null}', '{"time": [1 2]}',
    '{"ti\\u006de": [1]}', '{"time": [1], "time": [2]}', '[{"time": [1]}]', '{"time": [1]} {}',
    '{"time": [1]', '{"time": [1, 2', '{"a": "time', '', '   ', '{"time": [\u00a01]}', '{"time": [\u0661]}',
    '{"time": [1]}}', '\ufeff{"time": [1]}', '{"time": [1]}\x00',
])
def test_anything_unusual_gives_up(text):
    assert _split(text) is None


def test_lone_surrogates_give_up():
    assert _split('{"time": [1], "a": "\ud800"}') is None


_NUMBER_FORMATS = (repr, lambda v: f"{v:.17e}", lambda v: f"{v:.4f}", lambda v: f"{v:E}", lambda v: str(int(v)))
_MUTATION_CHARS = '"\\[]{},:-+.eE0 1\n\tnNa\x00\u00e9x'


@st.composite
def tap_texts(draw):
    """A tap object written in varied but valid JSON, then perhaps broken."""
    count = draw(st.sampled_from([0, 5, 12, 15, 20]))  # 12 samples are the fewest a tap may have
    steps = draw(st.lists(st.floats(1e-4, 10.0), min_size=count, max_size=count))
    time_s = list(np.cumsum(steps) + draw(st.floats(-1e3, 1e3)))
    force = draw(st.lists(st.floats(-1e6, 1e6), min_size=count, max_size=count))
    z = draw(st.lists(st.floats(-5, 5), min_size=count, max_size=count))
    space = draw(st.sampled_from(["", " ", "\n  ", "\t\r\n"]))
    fmt = draw(st.sampled_from(_NUMBER_FORMATS))

    def numbers(values):
        return "[" + space + ("," + space).join(fmt(v) for v in values) + space + "]"

    members = [('"time"', numbers(time_s)), ('"force"', numbers(force))]
    motion = draw(st.sampled_from(["z", "moves", "both", "neither"]))
    if motion in ("z", "both"):
        members.append(('"z"', numbers(z)))
    if motion in ("moves", "both"):
        members.append(('"moves"', json.dumps([dict.fromkeys(readers.MOVE_KEYS, 0.5)])))
    if draw(st.booleans()):
        members.append(('"meta"', json.dumps({"time": [1, 2], "note": '"force": [3]', "x\\y": [None, True]})))
    if draw(st.booleans()):
        members.append(('"format"', json.dumps(draw(st.sampled_from([readers.FORMAT, readers.FORMAT, readers.FORMAT, "other"])))))
    order = draw(st.permutations(members))
    text = "{" + space + ("," + space).join(f"{key}{space}:{space}{value}" for key, value in order) + space + "}"
    for _ in range(draw(st.sampled_from([0, 0, 1, 2, 3]))):
        at = draw(st.integers(0, len(text)))
        kind = draw(st.sampled_from(["truncate", "insert", "delete", "replace"]))
        if kind == "truncate":
            text = text[:at]
        elif kind == "insert":
            text = text[:at] + draw(st.sampled_from(_MUTATION_CHARS)) + text[at:]
        elif kind == "delete":
            text = text[:at] + text[at + 1:]
        else:
            text = text[:at] + draw(st.sampled_from(_MUTATION_CHARS)) + text[at + 1:]
    return text


@settings(max_examples=250, deadline=None)
@given(tap_texts())
def test_fuzzed_tap_texts_read_the_same_either_way(text):
    fast, reference = _both_ways(text)
    assert fast == reference


@pytest.mark.parametrize("digits", [19, 20, 21, 22])
def test_an_integer_in_the_rest_is_bounded_as_the_plain_path_bounds_it(digits):
    """json reads the rest with its own int() only when no run of digits there is too long for an
    integer the reader refuses (MAX_INTEGER_DIGITS): at the bound and just past it, the same tap or
    the same message as json.loads reading the whole text."""
    document = _generated_taps()[0]
    document["probe"] = {**document.get("probe", {}), "serial": int("9" * digits)}
    fast, reference = _both_ways(json.dumps(document))
    assert fast == reference
    assert isinstance(fast, str) == (digits > readers.MAX_INTEGER_DIGITS)
    assert _split(json.dumps(document))[2] >= digits
