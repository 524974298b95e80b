"""The quality classifier's arithmetic, the registry and plugins, options, the CLI, fuzzing."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tapcell.tap import AnalysisOptions, Classification, TapData, analyze_tap, get_classifier, tap_to_json_dict
from tapcell.tap import classifiers
from tapcell.tap.classifiers import UnknownClassifierError, quality_components, quality_score
from tapcell.tap.cli import _parser
from tapcell.tap.cli import main as analyze_main
from tapcell.tap.model import Move
from tapcell.tap.synth import synth_tap

CUTOFFS = {"approach": 50, "departure": 25, "baseline": 25, "dwell_drop": 75, "stiffness": 50, "misfit": 50}


def test_quality_arithmetic_by_hand():
    # Compression 100 g: approach 2 g, departure 1 g, baseline |2-3| = 1... see each ratio below.
    points = [(0, 0.0), (1, 2.0), (2, 102.0), (3, 92.0), (4, 3.0), (5, 4.0)]
    components = quality_components(points, decompression_slope_g_s=-250.0, stiffness_ratio=0.9,
                                    decompression_angle=40.0, noise_to_residual=0.5)
    assert components["approach"] == pytest.approx(0.02)
    assert components["departure"] == pytest.approx(0.01)
    assert components["baseline"] == pytest.approx(0.01)
    assert components["dwell_drop"] == pytest.approx(0.10)
    assert components["angle"] == pytest.approx(abs(45.0 - 40.0) / 40.0)  # atan(250 * 0.004) = 45°
    assert components["stiffness"] == pytest.approx(0.1)
    assert components["misfit"] == pytest.approx(0.375)  # 1 - 1.25 * 0.5
    expected = 100 * 0.98 * 0.99 * 0.99 * 0.90 * 0.875 * 0.9 * 0.625
    assert quality_score(components, CUTOFFS) == pytest.approx(expected)  # 42.47


def test_a_component_over_its_cutoff_zeroes_the_score():
    assert quality_score({"approach": 0.51, "departure": 0.0}, CUTOFFS) == 0.0
    assert quality_score({"approach": 0.50, "departure": 0.0}, CUTOFFS) == pytest.approx(50.0)


def test_stiffness_component_does_not_saturate_where_the_angle_does():
    # Halving a 1466 g/s decompression slope moves the angle only 80.3° -> 71.2°, N = 11 %...
    angle_full = math.degrees(math.atan(1466 * 0.004))
    angle_half = math.degrees(math.atan(733 * 0.004))
    assert abs(angle_half - angle_full) / angle_full == pytest.approx(0.113, abs=0.002)
    # ...while the stiffness ratio reports the 50 % loss as it is.
    components = quality_components([(0, 0.0), (1, 0.0), (2, 100.0), (3, 100.0), (4, 0.0), (5, 0.0)],
                                    -733.0, 0.5, None)
    assert components["stiffness"] == pytest.approx(0.5)


def test_clean_taps_score_high_and_ooze_is_rejected():
    clean = analyze_tap(synth_tap(seed=1))
    assert clean.valid and clean.quality > 85
    # A string pulling 40 g on departure: the toe model (default) sees the force dip below free air
    # above break contact; the sharp model leaves it to the departure component.
    pull_tap = synth_tap(seed=1, pull_force_g=40.0)
    assert analyze_tap(pull_tap).error == "TAP_ADHESION"
    pull = analyze_tap(pull_tap, AnalysisOptions(contact_model="sharp"))
    assert not pull.valid and pull.error == "LOW_TAP_QUALITY"
    assert pull.quality_components["departure"] > 0.25
    film_tap = synth_tap(seed=1, film_um=20.0, film_stiffness_g_um=2.0)
    # A 20 um film is a soft layer pressed before the bed: the toe model sees its stage above the
    # contact (issue 21); the sharp model leaves it to the misfit component.
    assert analyze_tap(film_tap).error == "TAP_TWO_STAGE_CONTACT"
    film = analyze_tap(film_tap, AnalysisOptions(contact_model="sharp"))
    assert not film.valid and film.error == "LOW_TAP_QUALITY"  # Z would be 10.9 µm high
    assert film.quality_components["misfit"] > 0.5
    assert clean.quality_components["misfit"] == 0.0


def test_low_compression_force():
    result = analyze_tap(synth_tap(seed=1), AnalysisOptions(trigger_force_g=500.0))
    assert result.error == "LOW_COMPRESSION_FORCE"
    assert "below the trigger force 500.0 g" in result.message


def test_empty_classifier_accepts_without_score():
    # (The sharp model: the toe model's own TAP_ADHESION check would reject this tap before any classifier.)
    result = analyze_tap(synth_tap(seed=1, pull_force_g=40.0), AnalysisOptions(tap_classifier="empty",
                                                                               contact_model="sharp"))
    assert result.valid and result.quality is None and result.classifier == "empty"


class _FixedLines:
    """A plugin that moves the departure line up by 10 g: break contact moves, Z is recomputed."""

    def __init__(self, options):
        self.options = options

    def classify(self, analysis, context):
        lines = list(analysis.lines)
        lines[4] = (lines[4][0], lines[4][1] + 10.0)
        return Classification(quality=77.0, lines=lines)


class _Rejecting:
    def __init__(self, options):
        pass

    def classify(self, analysis, context):
        raise classifiers.TapRejected("MY_CODE", "no taps on Tuesdays")


class _Broken:
    def __init__(self, options):
        pass

    def classify(self, analysis, context):
        raise KeyError("oops")


@pytest.fixture
def plugins(monkeypatch):
    found = [SimpleNamespace(name=n, load=lambda c=c: c) for n, c in
             (("fixed_lines", _FixedLines), ("rejecting", _Rejecting), ("broken", _Broken))]
    monkeypatch.setattr(classifiers, "entry_points", lambda group: found if group == "tapcell.tap_classifiers" else [])
    classifiers._classifier_factory.cache_clear()
    yield
    classifiers._classifier_factory.cache_clear()


def test_entry_point_plugins(plugins):
    tap = synth_tap(seed=1)
    base = analyze_tap(tap, AnalysisOptions(tap_classifier="empty"))
    moved = analyze_tap(tap, AnalysisOptions(tap_classifier="fixed_lines"))
    assert moved.valid and moved.quality == 77.0 and moved.z_method == "lines"
    # 10 g up on a -3036 g/s decompression line: break 3.29 ms earlier = 2.17 µm lower at 0.66 mm/s
    assert (moved.z_mm - base.z_line_mm) * 1000 == pytest.approx(-10 / 3036 * 660, rel=0.05)
    rejected = analyze_tap(tap, AnalysisOptions(tap_classifier="rejecting"))
    assert (rejected.valid, rejected.error, rejected.message) == (False, "MY_CODE", "no taps on Tuesdays")
    # A plugin's bug is a programming error: it surfaces instead of passing as a bad tap.
    with pytest.raises(KeyError, match="oops"):
        analyze_tap(tap, AnalysisOptions(tap_classifier="broken"))


def test_unknown_classifier_lists_the_available_ones(plugins):
    with pytest.raises(UnknownClassifierError, match="unknown tap_classifier 'nope'; available: broken, empty, "):
        get_classifier("nope")


def test_options_from_strings():
    options = AnalysisOptions().with_overrides({"min_tap_quality": "70", "decompression_angle": "80.5",
                                                "sensor_delay_s": "auto", "fit_contact_onset": "yes"})
    assert (options.min_tap_quality, options.decompression_angle) == (70.0, 80.5)
    assert options.sensor_delay_s == "auto" and options.fit_contact_onset is True
    with pytest.raises(ValueError, match="option 'decompression_angle' = '90': must be between 0 and 90 \\(exclusive\\)"):
        AnalysisOptions().with_overrides({"decompression_angle": "90"})
    assert AnalysisOptions().contact_model == "toe"
    assert AnalysisOptions().with_overrides({"contact_model": "sharp"}).contact_model == "sharp"
    with pytest.raises(ValueError, match="option 'contact_model' = 'hertz': one of sharp, toe"):
        AnalysisOptions().with_overrides({"contact_model": "hertz"})
    with pytest.raises(ValueError, match="unknown option 'min_quality'; allowed: "):
        AnalysisOptions().with_overrides({"min_quality": "1"})
    with pytest.raises(ValueError, match="option 'max_approach_force' = 'lots': expected a number"):
        AnalysisOptions().with_overrides({"max_approach_force": "lots"})


def test_cli_json_and_exit_codes(tmp_path, capsys):
    good = tmp_path / "good.json"
    good.write_text(json.dumps(tap_to_json_dict(synth_tap(seed=3))))
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert analyze_main(["--json", str(good)]) == 0
    (entry,) = json.loads(capsys.readouterr().out)
    assert entry["file"] == str(good) and entry["valid"] is True and entry["error"] is None
    # The toe model reads this toe-less synthetic contact +1.7 µm (over 20 seeds: +0.82 ± 0.39 µm).
    assert abs(entry["z"]) < 0.0025 and len(entry["points"]) == 6 and set(entry["lines"][0]) == {"slope", "intercept"}
    assert analyze_main([str(good), str(bad), "--plot", str(tmp_path / "p.png")]) == 1
    captured = capsys.readouterr()
    assert "missing key 'time', 'force'" in captured.err and "yes" in captured.out
    assert (tmp_path / "p.png").stat().st_size > 10_000
    assert captured.out.splitlines()[-1] == f"plot {tmp_path / 'p.png'}: {good}"
    # Several taps: p.png, p-2.png, p-3.png, as --help says; each file named with its tap.
    three = tmp_path / "three.jsonl"
    three.write_text("\n".join(json.dumps(tap_to_json_dict(synth_tap(seed=s))) for s in (3, 4, 5)) + "\n")
    assert analyze_main(["--json", str(three), "--plot", str(tmp_path / "t.png")]) == 0
    captured = capsys.readouterr()
    assert len(json.loads(captured.out)) == 3
    assert captured.err.splitlines() == [f"plot {tmp_path / name}: {three}#{n}"
                                         for n, name in enumerate(("t.png", "t-2.png", "t-3.png"), start=1)]
    assert all((tmp_path / name).stat().st_size > 10_000 for name in ("t.png", "t-2.png", "t-3.png"))
    help_text = " ".join(_parser().format_help().split())
    assert "the first to OUT.png, the next to OUT-2.png, OUT-3.png" in help_text and "OUT-1.png" not in help_text
    assert analyze_main(["--set", "tap_classifier=nope", str(good)]) == 2
    assert "unknown tap_classifier 'nope'" in capsys.readouterr().err


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=0, max_size=80),
       st.integers(0, 7), st.booleans())
def test_garbage_never_raises(values, n_moves, with_z):
    n = len(values)
    time_s = np.cumsum(np.abs(np.nan_to_num(values, nan=0.001, posinf=1, neginf=1)) + 1e-4) if n else np.array([])
    moves = [Move(float(k), 0.1, abs(v) if math.isfinite(v) else 1.0, 0.0, 1.0 - k * 0.1, (-1) ** k)
             for k, v in enumerate(values[:n_moves])]
    tap = TapData(time_s=time_s, force_g=np.array(values, dtype=float),
                  z_mm=np.array(values[::-1], dtype=float) if with_z else None, moves=moves)
    result = analyze_tap(tap)
    assert result.valid in (True, False)
    assert result.valid or result.error
    json.dumps(result.to_json())


@pytest.mark.parametrize("mangle", ["flat", "spike_train", "no_pullback", "short"])
def test_mangled_real_taps_never_raise(mangle):
    tap = synth_tap(seed=5)
    if mangle == "flat":
        tap.force_g = np.zeros_like(tap.force_g)
    elif mangle == "spike_train":
        tap.force_g[::3] = 1e6
    elif mangle == "no_pullback":
        tap.moves = tap.moves[:3]
        tap.z_mm = None
    else:
        tap.time_s, tap.force_g, tap.z_mm = tap.time_s[:40], tap.force_g[:40], tap.z_mm[:40]
    result = analyze_tap(tap)
    assert not result.valid and result.error


@pytest.mark.parametrize("lines, compression, decompression, expected", [
    (0.9, 2.0, 1.7, 0.9),  # the lines' nearer 1
    (0.8, 2.0, 1.9, 0.95),  # the models' nearer 1
    (0.75, 2.0, 2.5, 0.75),  # a tie (|1 - r| = 0.25 both, exactly): the lines', which come first
    (None, 2.0, 1.5, 0.75),  # no line ratio: the models'
    (0.7, None, 1.5, 0.7),  # no compression stiffness: the lines'
    (0.7, 0.0, 1.5, 0.7),  # a zero stiffness is no ratio
    (None, None, None, None),
    (0.7, 2.0, math.nan, 0.7),  # a NaN model ratio never wins (min's order: only a strictly nearer one)
])
def test_stiffness_ratio_takes_the_estimate_nearer_one(lines, compression, decompression, expected):
    analysis = SimpleNamespace(line_stiffness_ratio=lines, stiffness_compression_g_um=compression,
                               stiffness_decompression_g_um=decompression)
    got = classifiers.stiffness_ratio(analysis)
    reference = [r for r in (lines, decompression / compression if compression and decompression else None)
                 if r is not None]
    assert got == (min(reference, key=lambda r: abs(1.0 - r)) if reference else None)  # the former definition
    assert got == expected if expected is None or got is None else got == pytest.approx(expected, abs=1e-12)
