"""Travel height between mesh points (tapcell.mesh.travel), on beds made here, not by the simulator."""

import numpy as np
import pytest

from tapcell.mesh.travel import predicted_bed_height_mm, travel_height_mm


def plane(x, y):
    return 0.3 + 0.01 * x - 0.005 * y  # 2 mm over 200 mm in X, -1 mm in Y


def contacts(points):
    return np.array([(x, y, plane(x, y)) for x, y in points])


def test_a_tilted_plane_is_predicted_exactly_once_two_directions_are_probed():
    probed = contacts([(20, 20), (117.5, 20), (215, 20), (215, 117.5)])
    predicted, misfit = predicted_bed_height_mm(probed, (117.5, 117.5))
    assert predicted == pytest.approx(plane(117.5, 117.5), abs=1e-12)
    assert misfit == pytest.approx(0.0, abs=1e-12)
    # Down hill (X falls): the travel clears the last contact by the clearance.
    assert travel_height_mm(probed, (117.5, 117.5), 0.4, 5.0) == pytest.approx(plane(215, 117.5) + 0.4)
    # Up hill along the first row: it clears the next point, 0.975 mm higher than the last.
    row = contacts([(20, 20), (117.5, 20)])
    assert travel_height_mm(row, (215, 20), 0.4, 5.0) == pytest.approx(plane(215, 20) + 0.4)


def test_along_the_first_row_a_line_predicts_and_across_it_nothing_does():
    row = contacts([(20, 20), (117.5, 20)])
    predicted, _ = predicted_bed_height_mm(row, (215, 20))
    assert predicted == pytest.approx(plane(215, 20))
    assert predicted_bed_height_mm(row, (215, 117.5)) is None  # the Y slope is unknown
    assert travel_height_mm(row, (215, 117.5), 0.4, 5.0) == 5.0  # horizontal_move_z
    assert predicted_bed_height_mm(contacts([(20, 20)]), (117.5, 20)) is None
    assert travel_height_mm(np.zeros((0, 3)), (20, 20), 0.4, 5.0) == 5.0


def test_a_bed_that_is_not_a_plane_adds_the_misfit():
    probed = np.array([(0, 0, 0.0), (100, 0, 0.0), (0, 100, 0.0), (100, 100, 0.2)])  # one corner up
    predicted, misfit = predicted_bed_height_mm(probed, (50, 50))
    assert misfit == pytest.approx(0.05)  # the least-squares plane misses each corner by 0.05 mm
    assert travel_height_mm(probed, (50, 50), 0.4, 5.0) == pytest.approx(max(0.2, predicted + 0.05) + 0.4)
    # Never lower than the safe height when the last contact itself is above it.
    assert travel_height_mm(np.array([(0, 0, 6.0)]), (10, 0), 0.4, 5.0) == pytest.approx(6.4)
