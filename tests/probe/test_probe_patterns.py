import numpy as np
import pytest

from tapcell.extras.probe.patterns import (
    MAX_CIRCLE_RETRIES,
    hex_pattern,
    next_clean_spot,
    serpentine_pattern,
)


def test_hex_pattern_rings():
    p = hex_pattern(100.0, 50.0, 2.0)
    assert p.shape == (19, 2)
    assert MAX_CIRCLE_RETRIES == 18
    r = np.linalg.norm(p - [100.0, 50.0], axis=1)
    assert r[0] == 0.0
    np.testing.assert_allclose(r[1:7], 2.0)
    np.testing.assert_allclose(r[7:13], 2.0 * np.sqrt(3.0))
    np.testing.assert_allclose(r[13:19], 4.0)
    # first neighbour straight along +X, hexagonal: neighbours are 2 mm from each other too
    np.testing.assert_allclose(p[1], [102.0, 50.0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(p[1] - p[2]), 2.0)
    # all distinct positions
    assert len({tuple(np.round(q, 6)) for q in p}) == 19


def test_next_clean_spot_avoids_fouled_places():
    assert next_clean_spot(10.0, 10.0, 2.0, np.empty((0, 2))) == (10.0, 10.0)
    spot = next_clean_spot(10.0, 10.0, 2.0, np.array([[10.0, 10.0]]))
    assert spot == pytest.approx((12.0, 10.0))
    spot = next_clean_spot(10.0, 10.0, 2.0, np.array([[10.0, 10.0], [12.0, 10.0]]))
    assert spot == pytest.approx((11.0, 10.0 + np.sqrt(3.0)))
    # a place fouled while probing a neighbouring point (0.4 mm away) is avoided too
    spot = next_clean_spot(10.0, 10.0, 2.0, np.array([[10.4, 10.0]]))
    assert spot == pytest.approx((12.0, 10.0))


def test_next_clean_spot_exhausted():
    fouled = hex_pattern(0.0, 0.0, 2.0)
    assert next_clean_spot(0.0, 0.0, 2.0, fouled) is None
    assert next_clean_spot(0.0, 0.0, 2.0, fouled[:-1]) == pytest.approx(tuple(fouled[-1]))


def test_serpentine_pattern():
    p = serpentine_pattern(5.0, 7.0, 3, 2, 2.0)
    np.testing.assert_allclose(p, [[5, 7], [7, 7], [9, 7], [9, 9], [7, 9], [5, 9]])
    n = serpentine_pattern(5.0, 7.0, -2, -2, 1.0)
    np.testing.assert_allclose(n, [[5, 7], [4, 7], [4, 6], [5, 6]])
    assert serpentine_pattern(0, 0, 10, 4, 2.0).shape == (40, 2)
    # consecutive positions are always one stepover apart
    steps = np.linalg.norm(np.diff(serpentine_pattern(0, 0, 10, 4, 2.0), axis=0), axis=1)
    np.testing.assert_allclose(steps, 2.0)
    with pytest.raises(ValueError):
        serpentine_pattern(0, 0, 0, 4, 2.0)
