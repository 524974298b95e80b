"""Taps at one spot pooled (tapcell.tap.pool, `tapcell analyze --pool`): the physics they share is
estimated jointly, each tap's Z read with only its own contact and baseline free, and the spread a
user sees in PROBE_ACCURACY falls (issue 21). Sessions of taplab's generator, seed 3 (the benchmark
`python -m bench tap_pool` runs seed 1 and the reference sessions)."""

import dataclasses
import json

import numpy as np
import pytest

from tapcell.tap import analyze_tap, read_tap_file
from tapcell.tap import pool as pool_module
from tapcell.tap.cli import main as analyze_main
from tapcell.tap.model import AnalysisOptions, TapAnalysis
from tapcell.tap.pool import apply_pool, pool_taps
from tapcell.taplab.generate import generate_sessions


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """{session: [(path, truth, analysis)]}: 4 clean HX717 sessions of 10 taps, 3 HX711 (80 sps) sessions,
    one soft-sheet session of 3."""
    out = tmp_path_factory.mktemp("sessions")
    labels = generate_sessions(out, seed=3, sessions_per_scenario=4, taps_per_session=10,
                               scenarios=("clean_hx717",))
    labels += generate_sessions(out, seed=3, sessions_per_scenario=3, taps_per_session=10, scenarios=("hx711_80",))
    labels += generate_sessions(out, seed=3, sessions_per_scenario=1, taps_per_session=3, scenarios=("soft_sheet",))
    by_session = {}
    for label in labels:
        path = out / label["file"]
        by_session.setdefault(label["session"], []).append(
            (path, label["z_contact"], analyze_tap(read_tap_file(str(path))[0])))
    return by_session


def _clean(sessions):
    return [taps for name, taps in sessions.items() if name.startswith("clean_hx717")]


def _probe_accuracy_sd_um(zs_mm):
    """PROBE_ACCURACY's standard deviation: the population sd over the taps."""
    return float(np.std(zs_mm)) * 1000.0


def _rms(values):
    return float(np.sqrt(np.mean(np.square(values))))


def test_pooling_shrinks_the_spread_at_one_spot(sessions):
    single_sd, pooled_sd, errors_um, ratios = [], [], [], []
    for taps in _clean(sessions):
        analyses = [analysis for *_, analysis in taps]
        pooled = pool_taps(analyses)
        assert all(a.valid for a in analyses) and all(p is not None for p in pooled)
        single_sd.append(_probe_accuracy_sd_um([a.z_mm for a in analyses]))
        pooled_sd.append(_probe_accuracy_sd_um([p.z_mm for p in pooled]))
        errors_um += [(p.z_mm - truth) * 1000.0 for p, (_, truth, _) in zip(pooled, taps)]
        ratios += [(p.z_mm - truth) * 1000.0 / p.sigma_um for p, (_, truth, _) in zip(pooled, taps)]
    # Measured here: 0.56 µm alone, 0.051 pooled (bench tap_pool, seed 1, 20 sessions: 0.55 / 0.097,
    # Kalico 0.18); the pooled spread of one session ranges 0.050-0.053.
    assert _rms(pooled_sd) < 0.15 * _rms(single_sd)
    assert max(pooled_sd) < 0.1
    # The level is the toe model's, shared: the sessions' mean errors here -0.38..+0.21 µm.
    assert abs(np.mean(errors_um)) < 0.5
    # The sigma keeps the error the taps share (the level): rms(error / sigma) 0.37 here with the taps'
    # sigma from tapcell.tap.uncertainty (its toe-shape part is shared by every tap at one spot, and
    # stays); a sigma of the spread alone (0.05 µm) would put it near 5.
    assert 0.25 < _rms(ratios) < 1.0


def test_the_taps_are_read_with_one_sensor_lag(sessions):
    """At 80 sps each tap's lag from its halt is good to a fraction of a period (here 1.27-2.48 ms
    within a session, 0.08 mm/s pullback): read with their median, the taps' Zs stop carrying it."""
    analyses = [analysis for *_, analysis in sessions["hx711_80-001"]]
    assert np.std([a.pullback_fit.delay_s for a in analyses]) > 3e-4  # measured 0.37 ms
    # Measured 0.056 µm; each tap alone 0.96.
    assert _probe_accuracy_sd_um([p.z_mm for p in pool_taps(analyses)]) < 0.1


def test_a_session_too_short_in_compression_reads_no_lag(sessions):
    """Session hx711_80-002 presses under a period and a window from touch to halt on every tap: no
    lag is read off the halt (tapcell.tap.analysis.compression_places_the_halt). Before, lags of
    0.4-5.5 ms read off P2 spread its taps 0.31 µm (mean error -0.21 µm, pooled -0.48); now 0.26
    (-0.02), pooled 0.078 as before (-0.29)."""
    taps = sessions["hx711_80-002"]
    analyses = [analysis for *_, analysis in taps]
    assert all(a.sensor_delay_s == 0.0 for a in analyses)
    assert _probe_accuracy_sd_um([a.z_mm for a in analyses]) < 0.29  # measured 0.257
    pooled = pool_taps(analyses)
    assert _probe_accuracy_sd_um([p.z_mm for p in pooled]) < 0.1
    assert abs(np.mean([(p.z_mm - truth) * 1000.0 for p, (_, truth, _) in zip(pooled, taps)])) < 0.4


def test_pools_of_two_and_three_taps(sessions):
    for size in (2, 3):
        single_sd, pooled_sd = [], []
        for taps in _clean(sessions):
            analyses = [analysis for *_, analysis in taps[:size]]
            pooled = pool_taps(analyses)
            assert all(p is not None and p.sigma_um > 0 for p in pooled)
            single_sd.append(_probe_accuracy_sd_um([a.z_mm for a in analyses]))
            pooled_sd.append(_probe_accuracy_sd_um([p.z_mm for p in pooled]))
        # Measured: 2 taps 0.25 -> 0.016 µm, 3 taps 0.54 -> 0.051 µm (rms over the 4 sessions).
        assert _rms(pooled_sd) < 0.2 * _rms(single_sd)


def test_a_rejected_tap_is_left_out_and_moves_nothing(sessions):
    analyses = [analysis for *_, analysis in _clean(sessions)[0]]
    alone = pool_taps(analyses[1:])
    rejected = TapAnalysis(valid=False, error="TAP_ADHESION")
    pooled = pool_taps([rejected, *analyses[1:]])
    assert pooled[0] is None
    assert [p.z_mm for p in pooled[1:]] == pytest.approx([p.z_mm for p in alone], abs=1e-12)


def test_a_tap_of_other_physics_keeps_its_own_z(sessions):
    """A soft-sheet tap among HX717 taps (a retried point that is not like the others): pooled
    alone, and the other taps' pooled Zs are those of the pool without it."""
    analyses = [analysis for *_, analysis in _clean(sessions)[0]][:9]
    stranger = next(taps for name, taps in sessions.items() if name.startswith("soft_sheet"))[0][2]
    alone = pool_taps(analyses)
    pooled = pool_taps([*analyses, stranger])
    assert (pooled[-1].z_mm, pooled[-1].sigma_um) == (stranger.z_mm, stranger.z_sigma_um)
    assert [p.z_mm for p in pooled[:-1]] == pytest.approx([p.z_mm for p in alone], abs=1e-12)


def test_a_tap_of_a_softer_bed_that_the_shared_physics_places_is_pooled_alone(sessions):
    """A tap whose force reads 10 % low (a bed 10 % softer, a load cell scaled otherwise) among nine
    of its session: placed at the shared physics, but its own stiffness fits it 1.71x better:
    pooled alone, and the nine keep the Zs they pool to without it."""
    taps = _clean(sessions)[0]
    analyses = [analysis for *_, analysis in taps][:9]
    tap = read_tap_file(str(taps[9][0]))[0]
    stranger = analyze_tap(dataclasses.replace(tap, force_g=np.asarray(tap.force_g) * 0.9))
    shared = pool_module.shared_physics([a.pullback_fit for a in [*analyses, stranger]])
    assert pool_module.contact_at_shared(stranger, shared).excess > pool_module.MISFIT_EXCESS
    alone = pool_taps(analyses)
    pooled = pool_taps([*analyses, stranger])
    assert (pooled[-1].z_mm, pooled[-1].sigma_um) == (stranger.z_mm, stranger.z_sigma_um)
    assert [p.z_mm for p in pooled[:-1]] == pytest.approx([p.z_mm for p in alone], abs=1e-12)


def test_the_misfit_rule_leaves_every_clean_tap_in(sessions):
    for taps in _clean(sessions):
        analyses = [analysis for *_, analysis in taps]
        shared = pool_module.shared_physics([a.pullback_fit for a in analyses])
        excess = [pool_module.contact_at_shared(a, shared).excess for a in analyses]
        # Measured here 1.00-1.10 (both benchmark sets: at most 1.33 taplab, 1.47 reference). Never
        # below 1: the tap's own stiffness fits its samples at least as well as any other.
        assert 1.0 - 1e-9 <= min(excess) and max(excess) < 1.2 < pool_module.MISFIT_EXCESS


def test_taps_not_read_by_the_toe_model_are_not_pooled(sessions):
    """The sharp model (or a calibrated onset) has no toe grid for the level: no pooled Z, as the
    probe's PROBE_ACCURACY expects (tests/probe/test_probe_pooling.py)."""
    sharp = AnalysisOptions(contact_model="sharp")
    analyses = [analyze_tap(read_tap_file(str(path))[0], sharp) for path, *_ in _clean(sessions)[0][:4]]
    assert all(a.valid for a in analyses)
    assert pool_taps(analyses) == [None] * 4


def test_one_tap_alone_reads_its_own_toe(sessions):
    path, _, analysis = _clean(sessions)[0][0]
    pooled = pool_taps([analysis])
    # Its shared toe is its own: its pooled Z is within a fraction of a micrometre of its own Z.
    assert pooled[0].z_mm == pytest.approx(analysis.z_mm, abs=0.3e-3)
    assert pooled[0].sigma_um == pytest.approx(analysis.z_sigma_um, rel=1e-9)


def test_apply_pool_and_analyze_pool_write_each_taps_pooled_z(sessions, capsys):
    taps = _clean(sessions)[0][:4]
    analyses = [analysis for *_, analysis in taps]
    apply_pool(analyses)
    assert [a.z_pooled_mm for a in analyses] == [p.z_mm for p in pool_taps(analyses)]
    paths = [str(path) for path, *_ in taps]
    assert analyze_main(["--json", "--pool", *paths]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == len(paths)
    assert [row["z_pooled"] for row in rows] == pytest.approx([a.z_pooled_mm for a in analyses], abs=1e-8)
    assert all(row["z_pooled_sigma_um"] > 0 for row in rows)
    assert analyze_main(["--json", *paths]) == 0
    assert all("z_pooled" not in row for row in json.loads(capsys.readouterr().out))



def test_a_pool_where_no_tap_fits_the_others_leaves_each_its_own_z(sessions, monkeypatch):
    """When every tap is a misfit (none placed at the shared physics, or each fitting its own
    stiffness better: here forced by a rule no tap passes) nothing is shared: each valid tap keeps
    its own Z and sigma, the rejected ones get none (before: a ZeroDivisionError)."""
    monkeypatch.setattr(pool_module, "MISFIT_EXCESS", 0.5)  # every tap's excess is at least 1
    analyses = [analysis for *_, analysis in _clean(sessions)[0]][:3] + [TapAnalysis(valid=False)]
    pooled = pool_taps(analyses)
    assert [(p.z_mm, p.sigma_um) for p in pooled[:3]] == [(a.z_mm, a.z_sigma_um) for a in analyses[:3]]
    assert pooled[3] is None
