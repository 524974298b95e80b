"""The toe fit's fast forms against their textbook forms (tapcell.tap.toe).

The speed pass replaced dense algebra by cheaper exact forms: the candidate grid evaluates only
the samples inside each candidate's toe (prefix sums for the pressed ones), and the walk estimate
takes the detrended variogram's shares in closed form. Each must equal the plain computation,
written out here without the fast form's tricks, to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from tapcell.tap.toe import (SUBSAMPLES, TOE_POWERS, WANDER_LAGS, _detrended_variogram, _Projected,
                             _rss_over_contacts, toe_shape)


def _dense_variogram(covariance: np.ndarray, lags) -> np.ndarray:
    """Mean E[(r[i+L] - r[i])^2] per lag of noise with `covariance` once a least-squares line is removed."""
    n = len(covariance)
    line = np.column_stack((np.ones(n), np.arange(n, dtype=float)))
    residual_maker = np.eye(n) - line @ np.linalg.pinv(line)
    residual_cov = residual_maker @ covariance @ residual_maker.T
    means = []
    for lag in lags:
        d = np.zeros((n - lag, n))
        d[np.arange(n - lag), np.arange(n - lag) + lag] = 1.0
        d[np.arange(n - lag), np.arange(n - lag)] = -1.0
        means.append(np.mean(np.einsum("ij,jk,ik->i", d, residual_cov, d)))
    return np.array(means)


@pytest.mark.parametrize("n", [12, 37, 90])
def test_detrended_variogram_closed_form_equals_the_covariance_algebra(n):
    lags = tuple(lag for lag in WANDER_LAGS if 3 * lag <= n)
    white, walk = np.array(_detrended_variogram(n, lags)).T
    order = np.arange(n, dtype=float)
    assert white == pytest.approx(_dense_variogram(np.eye(n), lags), rel=1e-10)
    assert walk == pytest.approx(_dense_variogram(np.minimum.outer(order, order), lags), rel=1e-10)


def test_toe_grid_equals_a_dense_least_squares_per_candidate():
    # A pullback with jittered 1 um steps, uneven conversion windows and the samples out of time
    # order: every candidate's residual and toe column against a plain fit of baseline + k * toe.
    rng = np.random.default_rng(7)
    x_lo = np.cumsum(rng.uniform(0.7, 1.3, 70)) - 35.0
    x_hi = x_lo + rng.uniform(0.5, 1.5, len(x_lo))
    order = rng.permutation(len(x_lo))
    x_lo, x_hi = x_lo[order], x_hi[order]
    window_um = x_lo[:, None] + (x_hi - x_lo)[:, None] * ((np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES)
    x_mid = 0.5 * (x_lo + x_hi)
    y = 3.0 * toe_shape(1.2 - window_um, 6.0, 0.5).mean(axis=1) + rng.normal(0.0, 0.7, len(x_lo))
    basis = np.full((len(y), 1), 1.0 / np.sqrt(len(y)))
    contacts = np.tile(np.linspace(-3.0, 10.0, 27), 3)
    widths = np.repeat([0.0, 4.5, 16.0], 27)
    rss = _rss_over_contacts(contacts, widths, _Projected.prepare(window_um, x_mid, basis, y))
    for row, power in enumerate(TOE_POWERS):
        for c, w, r in zip(contacts, widths, rss[row]):
            design = np.column_stack((np.ones(len(y)), toe_shape(c - window_um, w, power).mean(axis=1)))
            coefficients, *_ = np.linalg.lstsq(design, y, rcond=None)
            dense = float(np.sum((y - design @ coefficients) ** 2))
            if coefficients[1] > 0:
                assert r == pytest.approx(dense, rel=1e-9, abs=1e-9)
            else:
                assert r == np.inf
