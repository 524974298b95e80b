"""`python -m bench tap_pool --gap` (bench.tap_pool.pool_gap): where the pool loses to its floor, on
taplab sessions (seed 5, which no other pool test or benchmark reads)."""

import pytest

from bench.tap_pool import GAP_BANDS_UM, pool_gap
from tapcell.tap import analyze_tap, read_tap_file
from tapcell.taplab.benchmark import TapSet, read_labels
from tapcell.taplab.generate import generate_sessions


@pytest.fixture(scope="module")
def hx711_sessions(tmp_path_factory):
    out = tmp_path_factory.mktemp("gap")
    generate_sessions(out, seed=5, sessions_per_scenario=3, taps_per_session=10, scenarios=("hx711_80",))
    generate_sessions(out / "three", seed=5, sessions_per_scenario=2, taps_per_session=3, scenarios=("clean_hx717",))
    return out


def _gap(directory):
    tap_set = TapSet("test", directory, read_labels(directory))
    analyses = {label.file: analyze_tap(read_tap_file(str(directory / label.file))[0]) for label in tap_set.labels}
    return pool_gap(tap_set, analyses)


def test_pools_of_three_taps_alone_read_the_same_at_their_own_and_the_sessions_shared_physics(hx711_sessions):
    row = _gap(hx711_sessions / "three")["clean_hx717"]
    assert row["own"] == row["session"] > 0.0


def test_the_residual_scatters_more_across_the_taps_deep_in_contact_than_near_it(hx711_sessions):
    """HX711 80 sps: the shared physics of 3 taps costs nothing against the session's 10 (measured
    here 0.068 / 0.068 µm; seed 1's 20 sessions 0.067 / 0.068), while deep samples scatter two to
    three times as much across the taps as those near contact (measured 0.72 / 0.25 g; seed 1 0.57 / 0.25)."""
    row = _gap(hx711_sessions)["hx711_80"]
    assert row["own"] == pytest.approx(row["session"], rel=0.15)
    deep, contact, near_air, far_air = (row[band] for band, *_ in GAP_BANDS_UM)
    assert deep > 1.5 * contact
    assert 0.1 < contact < 0.5 and 0.1 < near_air < 0.5
