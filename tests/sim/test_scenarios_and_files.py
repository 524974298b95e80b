"""Determinism, scenarios and their listing, [virtual_printer] config, tap files, ooze."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import tap
from tapcell.host.config import ConfigError, ConfigFile
from tapcell.sim import SCENARIOS, VirtualPrinter
from tapcell.sim.cli import main as scenarios_main


def _session(scenario: str, seed: int, take_every_s: float):
    vp = VirtualPrinter.from_scenario(scenario, seed=seed)
    vp.move_to(x=50.0, y=60.0, speed_mm_s=100.0)
    _, result = tap(vp, speed_mm_s=3.0)
    times, counts = [], []
    end = vp.now_s + 1.0
    while vp.now_s < end:
        vp.dwell(min(take_every_s, end - vp.now_s))
        batch = vp.take_samples()
        times.append(batch.t_s)
        counts.append(batch.counts)
    return result, np.concatenate(times), np.concatenate(counts)


@pytest.mark.parametrize("scenario", ["clean", "oozy", "glitchy"])
def test_same_scenario_and_seed_give_identical_samples_however_they_are_taken(scenario):
    r1, t1, c1 = _session(scenario, 5, 0.013)
    r2, t2, c2 = _session(scenario, 5, 0.25)
    assert r1 == r2
    assert np.array_equal(t1, t2) and np.array_equal(c1, c2)
    _, _, other = _session(scenario, 6, 0.25)
    assert not np.array_equal(c1[:100], other[:100])


def test_every_scenario_runs_a_tap():
    assert set(SCENARIOS) >= {"clean", "fast-adc", "slow-adc", "noisy-mains", "bowden-drift", "soft-sheet",
                              "oozy", "glitchy", "disconnected", "warped-bed", "tilted-bed"}
    for name in SCENARIOS:
        vp = VirtualPrinter.from_scenario(name, seed=1)
        if name == "disconnected":
            continue
        _, result = tap(vp, speed_mm_s=2.0)
        assert result.triggered, name


def test_warped_and_tilted_beds_have_the_configured_shape():
    tilted = VirtualPrinter.from_scenario("tilted-bed").truth
    assert tilted.surface_z(235.0, 117.5) - tilted.surface_z(0.0, 117.5) == pytest.approx(0.4)
    assert tilted.surface_z(117.5, 235.0) - tilted.surface_z(117.5, 0.0) == pytest.approx(-0.25)
    warped = VirtualPrinter.from_scenario("warped-bed", seed=2).truth
    grid = warped.surface_z(*np.meshgrid(np.linspace(0, 235, 30), np.linspace(0, 235, 30)))
    assert 0.1 < np.ptp(grid) < 1.0
    assert np.array_equal(grid, VirtualPrinter.from_scenario("warped-bed", seed=2).truth.surface_z(
        *np.meshgrid(np.linspace(0, 235, 30), np.linspace(0, 235, 30))))


def test_bed_from_csv(tmp_path):
    path = tmp_path / "bed.csv"
    path.write_text("# heights\n0.0,0.1\n0.2,0.3\n")
    truth = VirtualPrinter.from_scenario("clean", bed_shape="csv", bed_csv=str(path)).truth
    assert truth.surface_z(0.0, 0.0) == pytest.approx(0.0)
    assert truth.surface_z(235.0, 235.0) == pytest.approx(0.3)
    assert truth.surface_z(117.5, 117.5) == pytest.approx(0.15)


def test_scenarios_command_lists_every_scenario_with_its_parameters(capsys):
    assert scenarios_main([]) == 0
    out = capsys.readouterr().out
    for name in SCENARIOS:
        assert name in out
    assert "glitch_rate_per_s=0.5" in out
    assert scenarios_main(["slow-adc"]) == 0
    out = capsys.readouterr().out
    assert "chip_rate_error" in out and "0.015" in out and "counts_per_gram" in out
    assert scenarios_main(["nope"]) == 2
    assert "unknown scenario 'nope'; allowed: clean" in capsys.readouterr().out


def _section(tmp_path, body: str):
    path = tmp_path / "printer.cfg"
    path.write_text("[virtual_printer]\n" + body)
    return ConfigFile.read(path).getsection("virtual_printer"), path


def test_virtual_printer_section_reads_scenario_seed_and_overrides(tmp_path):
    section, _ = _section(tmp_path, "scenario: fast-adc\nseed: 7\nbed_x_mm: 300\nhum_counts: 200\nhum_hz: 60\n"
                                    "cell_polarity: -1\n")
    vp = VirtualPrinter.from_config(section)
    assert (vp.scenario, vp.seed) == ("fast-adc", 7)
    assert vp.params.chip == "ads1220" and vp.params.bed_x_mm == 300.0 and vp.params.hum_hz == 60
    assert vp.truth.counts_per_gram == -110.0
    assert VirtualPrinter.from_config(_section(tmp_path, "")[0]).scenario == "clean"


@pytest.mark.parametrize("body, message", [
    ("scenario: dirty\n", "[virtual_printer] scenario = dirty: must be one of: clean, fast-adc"),
    ("seed: -1\n", "[virtual_printer] seed = -1: "),
    ("relax_fraction: 0.9\n", "[virtual_printer] relax_fraction = 0.9: "),
    ("sample_rate_sps: 500\n", "[virtual_printer] sample_rate_sps = 500: virtual printer parameter "
                               "'sample_rate_sps' = 500 is not a hx717 rate; allowed: 10, 20, 80, 320"),
    ("bed_shape: csv\nbed_csv: /no/such.csv\n", "[virtual_printer] bed_csv = /no/such.csv: bed CSV "
                                                "'/no/such.csv': cannot read"),
])
def test_virtual_printer_section_errors_name_file_option_value_and_what_is_allowed(tmp_path, body, message):
    section, path = _section(tmp_path, body)
    with pytest.raises(ConfigError) as info:
        VirtualPrinter.from_config(section)
    assert str(path) in str(info.value) and message in str(info.value)


def test_tap_file_is_tapcell_tap_v1_with_moves_events_and_truth(tmp_path):
    vp = VirtualPrinter.from_scenario("clean", seed=3)
    vp.move_to(x=40.0, y=80.0, speed_mm_s=100.0)
    t0, result = tap(vp, speed_mm_s=3.0)
    probe = {"x": 40.0, "y": 80.0, "speed": 3.0, "pullback_distance": 0.2, "pullback_speed": 0.32,
             "trigger_force": 75.0}
    path = tmp_path / "tap.json"
    vp.write_tap_file(path, t0, vp.now_s, probe, analysis_meta={"note": "test"})
    tap_obj = json.loads(path.read_text())
    assert tap_obj["format"] == "tapcell.tap.v1"
    assert len(tap_obj["time"]) == len(tap_obj["force"]) > 100
    assert np.all(np.diff(tap_obj["time"]) > 0)
    assert tap_obj["truth"] == {"z_contact": pytest.approx(vp.truth.contact_z_at(40.0, 80.0)), "label": "clean"}
    assert tap_obj["events"]["home_end_time"] == result.halt_time_s
    moves = tap_obj["moves"]
    assert tap_obj["events"]["pullback_start_time"] == moves[3]["print_time"]
    assert tap_obj["events"]["pullback_end_time"] == pytest.approx(moves[5]["print_time"] + moves[5]["move_t"])
    assert set(moves[0]) == {"print_time", "move_t", "start_v", "accel", "start_z", "z_r"}
    assert tap_obj["probe"] == probe and tap_obj["sample_rate"] == 320.0
    assert tap_obj["meta"]["scenario"] == "clean" and tap_obj["meta"]["note"] == "test"
    assert max(tap_obj["force"]) == pytest.approx(vp.truth.force_g(t0, vp.now_s)[1].max(), abs=10.0)
    jsonl = tmp_path / "taps.jsonl"
    vp.write_tap_file(jsonl, t0, vp.now_s, probe)
    vp.write_tap_file(jsonl, t0, vp.now_s, probe)
    assert len(jsonl.read_text().splitlines()) == 2


def test_ooze_touches_first_squeezes_out_pulls_on_lift_and_clears_with_taps():
    vp = VirtualPrinter.from_scenario("oozy", seed=1)
    film_before = vp.truth.film_um
    assert film_before == pytest.approx(60.0)
    t0, result = tap(vp, speed_mm_s=2.0, start_above_mm=0.3)
    t, force = vp.truth.force_g(t0, vp.now_s)
    contact_t = t0 + 0.3 / 2.0
    approach = force[(t > t0) & (t < contact_t - 0.005)]
    assert approach.max() > 20.0                    # the film pushes before the nozzle meets the bed
    assert force.min() < -5.0                       # and pulls as the nozzle lifts
    assert vp.truth.film_um < 0.6 * film_before     # squeezed out and torn off
    clean = VirtualPrinter.from_scenario("clean", seed=1)
    t0c, _ = tap(clean, speed_mm_s=2.0, start_above_mm=0.3)
    tc, fc = clean.truth.force_g(t0c, clean.now_s)
    assert fc[(tc > t0c) & (tc < t0c + 0.3 / 2.0 - 0.005)].max() == 0.0 and fc.min() == 0.0
    films = []
    for _ in range(4):
        vp.move_to(x=vp.position[0] + 2.0)  # a fresh spot each time, as NOZZLE_CLEANUP does
        tap(vp, speed_mm_s=2.0, start_above_mm=0.3)
        films.append(vp.truth.film_um)
    # Taps thin the film until squeeze-out balances the regrowth between taps (~0.8 µm/s at 210 °C):
    # it ends near that equilibrium, never back above the first tap's level.
    assert films[-1] < 1.0 and max(films[1:]) <= films[0]
    vp.dwell(30.0)                                  # still at 210 °C: the film grows back
    assert vp.truth.film_um == pytest.approx(films[-1] + 0.02 * 40.0 * 30.0, rel=0.05)


def test_oozy_tap_file_is_labelled_fouled(tmp_path):
    vp = VirtualPrinter.from_scenario("oozy", seed=1)
    t0, _ = tap(vp, speed_mm_s=2.0)
    obj = vp.write_tap_file(tmp_path / "t.json", t0, vp.now_s, {"x": 117.5, "y": 117.5})
    assert obj["truth"]["label"] == "fouled"


def test_ooze_left_on_the_bed_is_met_again_by_a_tap_nearby():
    vp = VirtualPrinter.from_scenario("oozy", seed=1)
    tap(vp, speed_mm_s=2.0, start_above_mm=0.3)
    x, y, _ = vp.position
    film_after_um = vp.truth.film_um
    [spot] = vp.truth.residue
    # Everything that left the nozzle (flowed out, torn off) lies where the tap was: the 60 µm
    # plus what grew since power-on (0.02 µm/s/°C × 40 °C above the ooze point).
    assert (spot.x_mm, spot.y_mm) == (x, y)
    assert spot.thickness_um + film_after_um == pytest.approx(60.0 + 0.8 * vp.now_s, abs=0.05)
    assert spot.thickness_um > 40.0
    # 0.4 mm away (inside the 0.5 mm residue radius) the next tap meets it first: fouled again.
    vp.move_to(x=x + 0.4)
    t0, _ = tap(vp, speed_mm_s=2.0, start_above_mm=0.3)
    t, force = vp.truth.force_g(t0, vp.now_s)
    assert force[(t > t0) & (t < t0 + 0.3 / 2.0 - 0.005)].max() > 20.0   # the film pushes early
    assert vp.truth.film_um > 5.0 and vp.truth.residue[0].thickness_um > 40.0
    # 2 mm away from both spots the bed is clean: the nozzle only carries its own film.
    film_before_um = vp.truth.film_um
    vp.move_to(x=x + 2.4)
    tap(vp, speed_mm_s=2.0, start_above_mm=0.3)
    assert vp.truth.film_um < 0.3 * film_before_um
    assert len(vp.truth.residue) == 2


def test_residue_radius_is_a_parameter():
    vp = VirtualPrinter.from_scenario("oozy", seed=1, ooze_residue_radius_mm=0.0)
    tap(vp, speed_mm_s=2.0, start_above_mm=0.3)
    x = vp.position[0]
    vp.move_to(x=x + 0.4)
    tap(vp, speed_mm_s=2.0, start_above_mm=0.3)
    assert len(vp.truth.residue) == 2 and vp.truth.film_um < 5.0
