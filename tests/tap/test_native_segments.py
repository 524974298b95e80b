"""The compiled segments kernel (tapcell.tap._c_segments) against its numpy twin in segments.py.

The kernel repeats the twin's arithmetic per segment, so prefix sums and boundaries must be equal
bit for bit, exact ties included (the first minimum wins in both), and so must whole analyses.
"""

from __future__ import annotations

import collections

import math

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st
from pytest import MonkeyPatch

from native_kernel_inputs import OPTIONS, generated_taps, kernel_functions_used, recorded_calls
from tapcell.tap import analysis, analyze_tap, segments

# Without a C compiler the kernel is not built and the twin is all there is (`make test` requires it).
pytestmark = pytest.mark.skipif(segments._C is None, reason="tapcell.tap._c_segments is not built")


def twin(monkeypatch, function, *args):
    with monkeypatch.context() as patch:
        patch.setattr(segments, "_C", None)
        return function(*args)


def test_the_kernel_is_used(monkeypatch):
    used = kernel_functions_used(segments, OPTIONS["sharp"])
    assert used == ["five_lines"]


def _bits(value):
    """Nested tuples and lists of floats as their bit patterns: equal means bit for bit (NaN == NaN,
    -0.0 != 0.0), where == would call a NaN point of parallel lines unequal to itself."""
    if isinstance(value, (tuple, list)):
        return type(value)(_bits(v) for v in value)
    return np.float64(value).tobytes() if isinstance(value, float) else value


def _five_lines_equal(ours, theirs) -> bool:
    """Prefix sums, answer, boundaries, lines, points and the five lines' stats (`derived`) bit for bit."""
    (ps, *found), (twin_ps, *twin_found) = ours, theirs
    return ((ps.t_ref_s, ps.f_ref_g) == (twin_ps.t_ref_s, twin_ps.f_ref_g) and np.array_equal(ps.sums, twin_ps.sums)
            and _bits(found) == _bits(twin_found)
            and _bits(sorted(ps.derived.items())) == _bits(sorted(twin_ps.derived.items())))


def test_five_lines_equal_the_twin_on_generated_taps(monkeypatch):
    calls = recorded_calls(analysis, "five_lines", [OPTIONS["default"]])
    assert len(calls) >= len(generated_taps())
    found = [segments.five_lines(*args) for args in calls]
    for args, ours in zip(calls, found):
        assert _five_lines_equal(ours, twin(monkeypatch, segments.five_lines, *args))
    assert sum(problem == segments.SPLIT_FOUND for _, problem, *_ in found) >= len(calls) - 2
    # The split leaves its five lines' stats behind, each as segment_stats computes it from the sums.
    for ps, problem, bounds, *_ in found:
        if problem == segments.SPLIT_FOUND:
            edges = [0, *bounds, ps.sums.shape[1] - 1]
            assert sorted(ps.derived) == list(zip(edges, edges[1:]))
            for first, end in zip(edges, edges[1:]):
                assert ps.derived[first, end] == twin(monkeypatch, segments.segment_stats,
                                                      segments.PrefixSums(ps.t_ref_s, ps.f_ref_g, ps.sums), first, end)


def test_prefix_sums_lines_and_search_equal_the_twin_on_generated_taps(monkeypatch):
    # The parts five_lines' twin is made of, each against its own kernel (the ties test below has the search).
    calls = recorded_calls(analysis, "five_lines", [OPTIONS["default"]])
    for time_s, force_g, *_ in calls:
        ours, theirs = segments.prefix_sums(time_s, force_g), twin(monkeypatch, segments.prefix_sums, time_s, force_g)
        assert (ours.t_ref_s, ours.f_ref_g) == (theirs.t_ref_s, theirs.f_ref_g)
        assert np.array_equal(ours.sums, theirs.sums)
    ps, problem, bounds, *_ = segments.five_lines(*calls[0])
    assert problem == segments.SPLIT_FOUND
    edges = [0, *bounds, ps.sums.shape[1] - 1]
    assert segments.segment_lines(ps, edges) == twin(monkeypatch, segments.segment_lines, ps, edges)
    assert segments.segment_lines(ps, edges[:1]) == twin(monkeypatch, segments.segment_lines, ps, edges[:1]) == []
    with pytest.raises(ZeroDivisionError):
        segments.segment_lines(ps, [0, 0])
    with pytest.raises(ValueError, match="outside the"):
        segments.segment_lines(ps, [0, ps.sums.shape[1]])


def test_five_lines_takes_its_reference_force_as_numpy_sums(monkeypatch):
    # The kernel sums the window's force itself in numpy's pairwise order (blocks of 8 running sums up
    # to 128 values, halves at a multiple of 8 beyond): the same mean to the last bit at every length
    # about those edges and far past them (a tap of 15,000 samples), on forces of mixed sizes.
    rng = np.random.default_rng(11)
    lengths = [*range(1, 40), 127, 128, 129, 135, 136, 255, 256, 257, 1000, 1023, 1031, 8191, 8192, 8193, 15001]
    for n in lengths:
        time_s = np.arange(n) * 0.003
        force_g = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 6, n) + rng.uniform(-500.0, 500.0)
        ps, *_ = segments.five_lines(time_s, force_g, (0.3 * n * 0.003, 0.6 * n * 0.003, 0.62 * n * 0.003), 3, 3)
        assert (ps.t_ref_s, ps.f_ref_g) == (float(time_s[n // 2]), float(force_g.sum()) / n), n
        twin_ps, *_ = twin(monkeypatch, segments.five_lines, time_s, force_g,
                           (0.3 * n * 0.003, 0.6 * n * 0.003, 0.62 * n * 0.003), 3, 3)
        assert (ps.t_ref_s, ps.f_ref_g) == (twin_ps.t_ref_s, twin_ps.f_ref_g), n


def test_a_force_of_negative_zeros_sums_to_numpys_positive_zero():
    # == cannot tell -0.0 from +0.0: the sign is compared. numpy's reduction adds its pairwise sum to
    # +0.0, so a window of -0.0 reads +0.0 at every length (c/sum.h; a kernel sum from -0.0 gave -0.0).
    for n in (3, 9, 130, 300):
        time_s = np.arange(n) * 0.003
        force_g = np.full(n, -0.0)
        ps, *_ = segments.five_lines(time_s, force_g, (0.3 * n * 0.003, 0.6 * n * 0.003, 0.62 * n * 0.003), 3, 3)
        expected = float(force_g.sum()) / n
        assert math.copysign(1.0, ps.f_ref_g) == math.copysign(1.0, expected) == 1.0, n


def test_five_lines_equal_the_twin_on_every_problem(monkeypatch):
    # Short windows with the halt and the pullback anywhere (before, inside, after the samples, in
    # either order): every answer, split or none, and why, the same; forces on a coarse grid tie.
    rng = np.random.default_rng(5)
    problems = set()
    edge_cases = collections.Counter()
    for _ in range(600):
        n = int(rng.integers(4, 30))
        time_s = np.arange(n) * 0.01
        force_g = rng.integers(0, 3, n).astype(float) + (np.arange(n) * 0.5 if rng.random() < 0.5 else 0.0)
        if rng.random() < 0.1:  # a flat force: five parallel lines, no point where two meet
            force_g = np.full(n, 2.0)
        phases_s = tuple(float(v) for v in np.sort(rng.uniform(-0.05, 0.01 * n + 0.05, 3)))
        if rng.random() < 0.2:
            phases_s = phases_s[::-1]
        lag = int(rng.integers(1, 6))
        args = (time_s, force_g, phases_s, lag, lag if rng.random() < 0.5 else int(rng.integers(0, 6)),
                0.0 if rng.random() < 0.5 else float(rng.choice([0.3, 0.5, 0.9])))
        ours = segments.five_lines(*args)
        assert _five_lines_equal(ours, twin(monkeypatch, segments.five_lines, *args))
        problems.add(ours[1])
        if ours[1] == segments.SPLIT_FOUND:  # the edge cases the stats and points meet, counted below
            points, stats = ours[4], list(ours[0].derived.items())
            edge_cases["parallel lines: NaN point"] += any(np.isnan(t) for t, _ in points)
            edge_cases["exact line: no residual"] += any(var == 0.0 for _, (var, _, _) in stats)
            edge_cases["two samples: one degree of freedom"] += any(end - first == 2 for (first, end), _ in stats)
    assert problems == {segments.SPLIT_FOUND, segments.NO_DWELL_SAMPLES, segments.TOO_FEW_AROUND,
                        segments.TOO_FEW_FOR_FIVE}
    assert len(edge_cases) == 3 and min(edge_cases.values()) >= 5, edge_cases


@st.composite
def split_problems(draw):
    """Prefix sums and candidate ranges. Forces of few small integers on a grid of whole times
    make many segments' residuals exactly equal (ties), and ranges may overlap or cross (segments
    too short or reversed: inf, or no split at all)."""
    n = draw(st.integers(4, 40))
    time_s = np.arange(n, dtype=float) * draw(st.sampled_from([1.0, 0.5, 0.003]))
    levels = draw(st.sampled_from([[0.0], [0.0, 1.0], [0.0, 1.0, 2.0, 5.0]]))
    force_g = np.array(draw(st.lists(st.sampled_from(levels), min_size=n, max_size=n)))
    if draw(st.booleans()):
        force_g = force_g + np.arange(n) * draw(st.sampled_from([0.25, 3.0]))  # lines, exactly
    ps = segments.prefix_sums(time_s, force_g)
    start = draw(st.integers(0, n // 4))
    stop = draw(st.integers(3 * n // 4, n))
    ranges = []
    for _ in range(4):
        first = draw(st.integers(0, n))
        ranges.append(range(first, draw(st.integers(first + 1, n + 1))))
    return (ps, start, stop, *ranges)


def _problem(force_g, start, stop, *ranges):
    force_g = np.asarray(force_g, dtype=float)
    return (segments.prefix_sums(np.arange(len(force_g), dtype=float), force_g), start, stop,
            *(range(first, end) for first, end in ranges))


@settings(max_examples=100, deadline=None)
@given(split_problems())
# Every segment residual 0: the first arrangement giving every line two samples wins.
@example(_problem([0.0] * 12, 0, 12, (2, 9), (4, 8), (4, 9), (6, 11)))
# Sums past a double's range: NaN residuals, which win every minimum as numpy's do: no split.
@example(_problem([0.0] * 4 + [1e155, 3e155, 2e155] + [0.0] * 5, 0, 12, (2, 9), (4, 8), (4, 9), (6, 11)))
# No arrangement gives the approach two samples: no split.
@example(_problem([0.0, 1.0, 2.0, 3.0, 3.0, 3.0, 2.0, 1.0, 0.0, 0.0], 0, 10, (0, 2), (3, 5), (5, 7), (7, 9)))
def test_five_segments_equal_the_twin_on_ties_and_crossed_ranges(problem):
    with MonkeyPatch.context() as patch:
        ours = segments.best_five_segments(*problem)
        patch.setattr(segments, "_C", None)
        with np.errstate(over="ignore", invalid="ignore"):  # the overflowing case's sums, by design
            assert ours == segments.best_five_segments(*problem)


def _results(name: str) -> list[dict]:
    """The analyses of the generated taps as JSON, without their (always different) run times."""
    return [{key: value for key, value in analyze_tap(tap, OPTIONS[name]).to_json().items()
             if key not in ("elapsed_ms", "cpu_ms")} for tap in generated_taps()]


def test_whole_analyses_equal_the_twin(monkeypatch):
    for name in ("default", "sharp"):
        ours = _results(name)
        monkeypatch.setattr(segments, "_C", None)
        theirs = _results(name)
        monkeypatch.undo()
        assert ours == theirs
        assert sum(result["valid"] for result in ours) >= len(ours) // 2


def test_search_equals_the_twin_as_its_reciprocal_table_grows_and_is_reused():
    """The kernel keeps 1 / n for every segment length between calls and grows the table when a
    longer window asks: a long window after short ones, and short ones after it, must still pick the
    twin's boundaries (a stale or half-grown table would cost segments with wrong counts)."""
    rng = np.random.default_rng(7)
    for n in (14, 40, 3000, 3500, 5000, 14, 9000, 40):  # 3500 grows the table to 6000: 5000 reuses it
        time_s = np.arange(n, dtype=float) * 0.003
        # A tap's shape: flat, ramp up, dwell, ramp down, flat; noise makes every segment's residual count.
        corners = np.array([0.0, 0.45, 0.6, 0.7, 0.85, 1.0]) * (n - 1)
        force_g = np.interp(np.arange(n), corners, [0.0, 0.0, 100.0, 95.0, 0.0, 0.0]) + rng.normal(0, 1.0, n)
        ps = segments.prefix_sums(time_s, force_g)
        cut = [int(c) for c in corners]
        problem = (ps, 0, n, range(2, cut[2] - 1), range(cut[2] - 2, cut[2] + 3), range(cut[3] - 2, cut[3] + 3),
                   range(cut[3] + 3, n - 1))
        ours = segments.best_five_segments(*problem)
        with MonkeyPatch.context() as patch:
            patch.setattr(segments, "_C", None)
            assert ours == segments.best_five_segments(*problem)
        assert ours is not None and abs(ours[0] - cut[1]) <= max(3, n // 50)  # the contact found
