"""The reader's kernel (c/readers.c) against json.loads: every good file reads the same to the
last bit, every bad one falls back to json and gets the same message."""

from __future__ import annotations

import copy
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


def _decode(text):
    return readers._C.decode_tap_json(text, KEYS)


def _array(text, key="time"):
    """The float64 bytes the kernel parsed for the top-level `key`, or None when it gave up."""
    decoded = _decode(text)
    return None if decoded is None else decoded[0][key]


def _same(a, b):
    """Equal as json.loads's values are, types included (an int is no float, -0.0 is not 0.0)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, float):
        return struct.pack("=d", a) == struct.pack("=d", b)
    return a == b


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
        parsed = _array(f'{{"time": [{text}]}}')
        if parsed is None:  # left to json: an integer beyond a float's exact digits, or rounded to inf
            assert (text.lstrip("-").isdigit() and len(text.lstrip("-")) > 15) or math.isinf(float(text)), text
            continue
        assert parsed == bytearray(struct.pack("=d", float(json.loads(text)))), text
        # outside the arrays: the same int or float as json makes
        assert _same(_decode(f'{{"a": {text}}}')[0]["a"], json.loads(text)), text


@pytest.mark.parametrize("text", [
    "9007199254740992e-22", "9007199254740993e-22", "-9007199254740993.0", "900719925474099.3e7",
    "1844674407370955161.6", "18446744073709551616e-25", "99999999999999999999e-19", "1234567890123456789.0",
    "0.0000000000000000000001", "-0.000", "123456.789e22", "4.9e-324", "1.7976931348623157e308",
    "0.30000000000000004", "-1e-23", "7e22", "7e23"])
def test_numbers_at_the_exact_shortcut_s_edges(text):
    """Around 2^53, at 19 and 20 digits (where the mantissa would wrap) and powers of ten of 22
    and 23: the same double as json reads, whichever way the kernel converts it."""
    assert _array(f'{{"time": [{text}]}}') == bytearray(struct.pack("=d", float(json.loads(text)))), text
    assert _same(_decode(f'{{"a": [{text}]}}')[0]["a"], json.loads(f"[{text}]")), text


def test_integers_read_as_json_reads_them():
    text = '{"time": [0, -0, 7, -123456789012345], "force": [-0.0], "n": [0, -0, 7, -0.0, 123456789012345]}'
    document, parsed = _decode(text)
    assert parsed == ("time", "force")
    assert struct.unpack("=4d", document["time"]) == (0.0, 0.0, 7.0, -123456789012345.0)
    assert math.copysign(1, struct.unpack("=d", document["time"][8:16])[0]) == 1  # json: int("-0") is 0
    assert math.copysign(1, struct.unpack("=d", document["force"])[0]) == -1  # a float -0.0 keeps its sign
    assert _same(document["n"], json.loads(text)["n"])  # ints stay ints, -0.0 a float


def test_only_the_top_level_keys_become_arrays():
    text = '{"meta": {"time": [1], "s": "\\"time\\": [2]"}, "a": "\\"time\\": [3]", "time" : [ 4 , 5e1 ]\n}'
    document, parsed = _decode(text)
    expected = json.loads(text)
    assert parsed == ("time",) and struct.unpack("=2d", document.pop("time")) == (4.0, 50.0)
    assert _same(document, {key: value for key, value in expected.items() if key != "time"})
    assert list(_decode('{"z": [], "a": 1}')[0]) == ["z", "a"]  # json's key order
    assert _decode('{"z": []}') == ({"z": bytearray()}, ("z",))


@pytest.mark.parametrize("text", [
    r'{"a": "caf\u00e9 \\ \" \/ \b\f\n\r\t \ud83d\ude00 \ud800"}',  # every escape, a pair, a lone half
    r'{"ti\u006de": [1, 2]}',  # a key spelled with an escape is still the key
    '{"a": {"b": [true, false, null, [], {}, [[]], "", "x"]}, "a": 2, "b": -1.5E-3}',  # the last of a key wins
    '{"meta": {"s": "é中😀", "k": [1, "é"]}}',  # UTF-8 beyond ASCII
    ' \t\r\n{ "a" : [ 1 , 2 ] , "b" : { } } \n ',
])
def test_the_rest_decodes_as_json_does(text):
    document, parsed = _decode(text)
    expected = json.loads(text)
    for key in parsed:
        assert document.pop(key) == bytearray(np.array(expected.pop(key), dtype=float).tobytes())
    assert _same(document, expected)


@pytest.mark.parametrize("text", [
    '{"time": [1, 2,]}', '{"time": [01]}', '{"time": [1.]}', '{"time": [.5]}', '{"time": [+1]}',
    '{"time": [1e]}', '{"time": [1e+]}', '{"time": [-]}', '{"time": [NaN]}', '{"time": [-Infinity]}',
    '{"time": [1e400]}', '{"time": [1234567890123456]}', '{"time": [1' + "0" * 70 + '.5]}',
    '{"time": [[1]]}', '{"time": ["1"]}', '{"time": [true]}', '{"time": null}', '{"time": [1 2]}',
    '{"time": [1], "time": [2]}', '{"time": [1], "ti\\u006de": [2]}', '[{"time": [1]}]', '{"time": [1]} {}',
    '{"time": [1]', '{"time": [1, 2', '{"a": "time', '', '   ', '{"time": [\u00a01]}', '{"time": [\u0661]}',
    '{"time": [1]}}', '\ufeff{"time": [1]}', '{"time": [1]}\x00', '{"time": [1\x00]}',
    # outside the arrays
    '{"a": NaN}', '{"a": Infinity}', '{"a": -Infinity}', '{"a": 1e400}', '{"a": 1234567890123456}',
    '{"a": 01}', '{"a": tru}', '{"a": nul}', '{"a": True}', '{"a": [1,]}', '{"a": {"b": 1,}}', '{"a": {,}}',
    '{"a" 1}', '{a: 1}', "{'a': 1}", '{"a": 1,}', '{"a": "\t"}', '{"a": "\n"}', '{"a": "x\x00"}',
    '{"a": "\\x"}', '{"a": "\\u12"}', '{"a": "\u00e9\\n"}',  # a bad escape; an escape beyond ASCII text
    '{"a": ' + "[" * 64 + "]" * 64 + "}",  # deeper than MAX_DEPTH: json's own limit, and message
    '{"a": "x}', '{"a": [1, 2}', '{"a": {"b": 1]}', '{"a"', '{"a":', '{',
])
def test_anything_unusual_gives_up(text):
    assert _decode(text) is None


def test_nesting_up_to_the_limit_decodes():
    text = '{"a": ' + "[" * 63 + "]" * 63 + "}"
    assert _same(_decode(text)[0], json.loads(text))


def test_lone_surrogates_give_up():
    assert _decode('{"time": [1], "a": "\ud800"}') is None


@st.composite
def json_values(draw):
    """Any JSON the kernel may meet in a tap's rest: nested objects and lists of every kind of value."""
    leaves = (st.none() | st.booleans() | st.integers(-10**15 + 1, 10**15 - 1)
              | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=8))
    return draw(st.recursive(leaves, lambda inner: st.lists(inner, max_size=4)
                             | st.dictionaries(st.text(max_size=6), inner, max_size=4), max_leaves=20))


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.text(max_size=6).filter(lambda key: key not in KEYS), json_values(), max_size=6),
       st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=5), st.booleans(), st.sampled_from([None, 1]))
def test_any_object_decodes_as_json_does(document, times, ascii_only, indent):
    text = json.dumps({**document, "time": times}, ensure_ascii=ascii_only, indent=indent)
    decoded = _decode(text)
    if decoded is None:  # only an escape in a text beyond ASCII is left to json
        assert not text.isascii() and "\\" in text
        return
    expected = json.loads(text)
    document, parsed = decoded
    for key in parsed:
        assert document.pop(key) == bytearray(np.array(expected.pop(key), dtype=float).tobytes())
    assert _same(document, expected)


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
    """The kernel leaves an integer of more than 15 digits to json: at the reader's bound
    (MAX_INTEGER_DIGITS) and just past it, the same tap or the same message as json.loads reading
    the whole text."""
    document = copy.deepcopy(_generated_taps()[0])  # the generated taps are cached: change a copy
    document["probe"] = {**document.get("probe", {}), "serial": int("9" * digits)}
    fast, reference = _both_ways(json.dumps(document))
    assert fast == reference
    assert isinstance(fast, str) == (digits > readers.MAX_INTEGER_DIGITS)


def _with(change):
    """A generated tap object (moves, no z) with `change` applied: a function of the object."""
    document = copy.deepcopy(_generated_taps()[0])
    document.update(z=[0.5] * len(document["time"]), truth={"z_contact": -0.1, "label": "clean"})
    change(document)
    return document


def _set(**items):
    return lambda document: document.update(items)


def _drop(*keys):
    return lambda document: [document.pop(key, None) for key in keys]


def _move(k, key, value):
    return lambda document: document["moves"][k].__setitem__(key, value)


def _inside(name, key, value):
    return lambda document: document[name].__setitem__(key, value)


# Every rule of tap_from_object that the kernel's plain path checks, each way it can go.
PLAIN_PATH_CASES = {
    "as written": lambda document: None,
    "no z": _drop("z"), "no moves": _drop("moves"), "neither": _drop("z", "moves"),
    "moves empty, no z": lambda document: document.update(moves=[]) or document.pop("z"),
    "moves false, with z": _set(moves={}), "moves a string": _set(moves="abc"), "moves a number": _set(moves=3),
    "position instead of z": lambda document: document.pop("z") and document.update(
        position=[[0, 0, 0.5]] * len(document["time"])),
    "format other": _set(format="other"), "format a number": _set(format=1), "no format": _drop("format"),
    "a dump_taps event": lambda document: document.update(tap=copy.deepcopy(document)),
    "tap not an object": _set(tap=[1]),
    "sample_rate int": _set(sample_rate=320), "sample_rate null": _set(sample_rate=None),
    "sample_rate true": _set(sample_rate=True), "sample_rate 0": _set(sample_rate=0),
    "sample_rate negative": _set(sample_rate=-320.0), "sample_rate far off": _set(sample_rate=5000.0),
    "sample_rate a string": _set(sample_rate="320"),
    "move missing a key": lambda document: document["moves"][1].pop("accel"),
    "move not an object": lambda document: document["moves"].__setitem__(0, [1, 2]),
    "move with a bool": _move(2, "accel", True), "move with a string": _move(2, "start_z", "0.1"),
    "move with null": _move(0, "z_r", None), "move with an int": _move(1, "start_v", 3),
    "move with an extra key": _move(1, "x_r", 0), "move_t negative": _move(2, "move_t", -0.1),
    "start_v negative": _move(0, "start_v", -1e-9), "moves not oldest first": _move(1, "print_time", 0.0),
    "moves at one time": lambda document: [move.__setitem__("print_time", 7.0) for move in document["moves"]],
    "events null": _set(events=None), "events a list": _set(events=[1]), "no events": _drop("events"),
    "event a string": _inside("events", "home_end_time", "soon"), "event an int": _inside("events", "home_end_time", 4594),
    "event null": _inside("events", "pullback_end_time", None), "event unknown key": _inside("events", "note", "x"),
    "event bool": _inside("events", "home_end_time", False),
    "event on top": lambda document: document["events"].pop("home_end_time") and document.update(home_end_time=4594.3),
    "event on top and inside": _set(pullback_start_time=1.0),
    "event on top a string": lambda document: document["events"].pop("home_end_time") and document.update(home_end_time="x"),
    "probe null": _set(probe=None), "probe a string": _set(probe="p"), "probe x a string": _inside("probe", "x", "a"),
    "probe x an int": _inside("probe", "x", 150), "probe unknown key": _inside("probe", "serial", "A1"),
    "probe x nested": _inside("probe", "x", [1]),
    "truth a list": _set(truth=[1]), "meta a number": _set(meta=2), "meta null": _set(meta=None), "no truth": _drop("truth"),
    "force short": lambda document: document["force"].pop(), "z short": lambda document: document["z"].pop(),
    "too few samples": lambda document: [document[key].__delitem__(slice(11, None)) for key in ("time", "force", "z")],
    "time repeated": lambda document: document["time"].__setitem__(5, document["time"][4]),
    "time backwards": lambda document: document["time"].__setitem__(5, document["time"][4] - 1.0),
    "time a list of strings": _set(time=["1"]),
}


# The cases the kernel's plain path answers itself (plain_tap_fields returns the fields; the rest it
# leaves to the Python path, which names the problem): without this list the parity test above would
# pass for a case the kernel had quietly stopped taking, comparing the Python path with itself.
PLAIN_PATH_TAKEN = {
    "as written", "no z", "no moves", "moves false, with z", "no format", "sample_rate int", "sample_rate null",
    "sample_rate far off", "move with an int", "move with an extra key", "moves at one time", "events null",
    "no events", "event an int", "event null", "event unknown key", "event on top", "event on top and inside",
    "probe null", "probe x an int", "probe unknown key", "meta null", "no truth",
}


@pytest.mark.parametrize("case", PLAIN_PATH_CASES)
def test_the_plain_path_builds_what_the_python_path_builds(case):
    """tap_from_object's plain path (the kernel's plain_tap_fields) against its Python path, on a
    tap object changed one rule at a time: the same tap, or the same message; and the kernel takes
    exactly the cases listed as taken."""
    text = json.dumps(_with(PLAIN_PATH_CASES[case]))
    fast, reference = _both_ways(text)
    assert fast == reference
    document, parsed = readers._load_tap_json("tap.json", text, "")
    taken = isinstance(document, dict) and readers._C.plain_tap_fields(document, parsed, readers._PLAIN_TAP_FORM) is not None
    assert taken == (case in PLAIN_PATH_TAKEN)


def test_a_caller_s_object_that_is_no_dict_is_named_whatever_it_claims():
    with pytest.raises(TapFileError, match="expected a JSON object"):
        readers.tap_from_object([1], "tap.json", finite_arrays=("time", "force"))


def test_the_plain_path_is_taken_for_a_plain_tap():
    document, parsed = readers._load_tap_json("tap.json", json.dumps(_with(lambda document: None)), "")
    assert readers._C.plain_tap_fields(document, parsed, readers._PLAIN_TAP_FORM) is not None
    document, parsed = readers._load_tap_json("tap.json", json.dumps(_with(_set(sample_rate=True))), "")
    assert readers._C.plain_tap_fields(document, parsed, readers._PLAIN_TAP_FORM) is None


def test_keys_read_again_are_the_same_keys():
    """The kernel keeps keys it has made (a slot per key text): hundreds of keys sharing its 64
    slots, read twice, in objects and nested, decode as json decodes them."""
    keys = [f"k{k}" for k in range(300)] + ["print_time", "", "é", "a\\u0062", "x" * 200]
    document = {"meta": [{key: k for k, key in enumerate(keys)}, dict.fromkeys(reversed(keys), None)]}
    for text in (json.dumps(document), json.dumps(document, ensure_ascii=False).replace("\\", "")) * 2:
        assert _same(_decode(text)[0], json.loads(text))
