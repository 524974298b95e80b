"""Fixtures the tap tests share: the reference taps (the other generator's) and the sweep's taps made from them."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from bench.tap_sweep import CASES, analyse_in_process, case_taps, reference_taps
from tapcell.tap import analysis


@pytest.fixture(params=["kernel", "twin"])
def kernel_or_twin(request, monkeypatch):
    """The test runs with analysis.py's compiled kernels (where built) and with their numpy twins."""
    if request.param == "kernel" and analysis._C is None:
        pytest.skip("the compiled kernels are not built here")
    if request.param == "twin":
        monkeypatch.setattr(analysis, "_C", None)
    return request.param


@pytest.fixture(scope="session")
def reference_dir(tmp_path_factory):
    """The reference taps, unpacked once a session; a test needing them is skipped where there are none."""
    return reference_taps(None, tmp_path_factory.mktemp("reference")) or pytest.skip("no reference taps here")


@pytest.fixture(scope="session")
def sweep_tap(reference_dir) -> Callable[[str, int, int], tuple[dict, float]]:
    """(tap object, true contact Z in mm) of the sweep's case `name`, seed `seed`, tap `k`."""
    cases = {case.name: case for case in CASES}
    return lambda name, seed, k: case_taps(cases[name], seed, k + 1, reference_dir)[k]


@pytest.fixture(scope="session")
def measured_within(sweep_tap) -> Callable[[str, int, int, float], dict]:
    """The sweep's tap (`sweep_tap`) analysed, asserted valid and within `sigmas` of its z_sigma_um
    (at least 1 µm each) of the truth; its answer."""
    def analysed(name: str, seed: int, k: int, sigmas: float) -> dict:
        tap, z_mm = sweep_tap(name, seed, k)
        answer = analyse_in_process(tap)
        assert answer["valid"], answer["message"]
        assert abs(answer["z"] - z_mm) * 1000.0 < sigmas * max(answer["z_sigma_um"], 1.0)
        return answer
    return analysed
