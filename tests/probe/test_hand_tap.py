"""LOAD_CELL_TEST_TAP's check of a tap by hand (pure: tapcell.extras.load_cell_probe.hand_tap)."""

import numpy as np

from tapcell.extras.load_cell_probe.hand_tap import check_hand_tap


def press(peak_g: float, samples: int) -> np.ndarray:
    return np.concatenate([np.zeros(5), peak_g * np.sin(np.linspace(0, np.pi, samples + 2)[1:-1]), np.zeros(5)])


def test_a_clean_press_and_release_is_good():
    tap = check_hand_tap(press(300, 40), after_g=0.4, trigger_force_g=75, max_baseline_force_delta=25,
                         sensor_errors=0)
    assert tap.problem is None and tap.describe() == "peak 300g, back to 0.4g: good"


def test_too_short_errors_and_baseline_are_bad():
    short = check_hand_tap(press(300, 2), 0.0, 75, 25, 0)
    assert short.problem.startswith("the tap lasted 2 samples above half the trigger force, too short")
    noisy = check_hand_tap(press(300, 40), 0.0, 75, 25, sensor_errors=3)
    assert noisy.problem.startswith("the sensor reported 3 errors during the tap. Likely cause: wiring or grounding")
    drift = check_hand_tap(press(300, 40), -90.0, 75, 25, 0)  # pulled the other way afterwards
    assert drift.problem.startswith("BASELINE_FORCE_INCONSISTENT - the force came back to -90.0g, 30% of the 300g")
    assert check_hand_tap(press(300, 40), 74.0, 75, 25, 0).problem is None  # 24.7 %: within 25 %
