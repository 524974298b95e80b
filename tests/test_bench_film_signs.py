"""`bench film_signs`: what the film-met-above rule and the spike repair's credible noise weigh,
per set and scenario."""

import math

from bench import film_signs
from bench.tap_seeds import seed_tap
from tapcell.tap import AnalysisOptions, analysis
from tapcell.tap.readers import tap_from_object


def _signs_of(seed: int, scenario: str, k: int) -> film_signs.Signs:
    signs = film_signs.Signs()
    tap, _ = seed_tap(seed, scenario, k)
    film_signs.add_tap(signs, tap_from_object(tap), AnalysisOptions().outlier_sigma)
    return signs


def test_the_rule_is_watched_and_left_as_it_was():
    rule = analysis._film_met_above
    signs = _signs_of(388, "heavy_ooze", 27)  # the heavy ooze accepted 21 um high before the rule
    assert analysis._film_met_above is rule
    assert (signs.taps, signs.reached, signs.named) == (1, 1, 1)
    # The message rounds the same rise: "rose off free air 51 um above break contact".
    assert round(signs.highest_rise_um) == 51 and signs.highest_rise_pulling_um == signs.highest_rise_um
    assert 0.0 < signs.most_standing_out < analysis.CREDIBLE_NOISE_SHARE


def test_a_clean_tap_that_does_not_rise_shows_no_rise():
    signs = _signs_of(1, "clean_ads1220_2000", 0)
    assert (signs.reached, signs.named) == (1, 0)
    assert signs.highest_rise_um == signs.highest_rise_pulling_um == -math.inf


def test_the_table_has_a_row_a_set_and_scenario():
    signs = {("taplab 388", "heavy_ooze"): _signs_of(388, "heavy_ooze", 27),
             ("taplab 1", "clean_ads1220_2000"): _signs_of(1, "clean_ads1220_2000", 0)}
    cells = [column._cells for column in film_signs.signs_table(signs).columns]
    assert cells[1] == ["heavy_ooze", "clean_ads1220_2000"]
    assert cells[6] == ["1", "0"]  # named
