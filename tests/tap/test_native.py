"""The compiled kernels (tapcell.tap.native) against their numpy twins, through the whole analysis.

Each kernel's own test file compares it with its twin on its inputs; this one checks that the
analysis gives the same answers either way on the independent generator's taps (every scenario:
the walk-weighted toe fit, hum removal, ooze and short pullbacks all take their own paths).
"""

from __future__ import annotations

import pytest

from tapcell.tap import AnalysisOptions, analyze_tap, native
from tapcell.tap import contact, hum, model, readers, segments, stage, toe, uncertainty
from tapcell.tap.readers import tap_from_object
from native_kernel_inputs import generated_tap_objects

KERNEL_MODULES = {"segments": segments, "contact": contact, "toe": toe, "stage": stage, "readers": readers,
                  "output": model, "uncertainty": uncertainty, "hum": hum}
# Kernels a module holds under another name than _C: kernel name -> (module, attribute).
OTHER_KERNELS = {"ringing": (stage, "_C_RINGING")}
TAPS_PER_SCENARIO = 2
OPTIONS = (AnalysisOptions(), AnalysisOptions(contact_model="sharp", sensor_delay_s=0.0))
# Sums taken in another order differ by ~1e-12 relative; a Z a hundred times the float rounding
# of a µm-scale grid search (1e-9 µm) apart would mean different arithmetic, not rounding.
Z_TOLERANCE_UM = 1e-6


def _taps():
    return [(name, tap_from_object(tap)) for name, tap in generated_tap_objects(TAPS_PER_SCENARIO)]


def test_tapcell_native_0_turns_the_kernels_off(monkeypatch):
    monkeypatch.setenv(native.ENV, "0")
    assert all(native.load(name) is None for name in (*KERNEL_MODULES, *OTHER_KERNELS))


def test_make_test_has_every_kernel_built():
    """make test sets TAPCELL_NATIVE=required: then a kernel that failed to build fails here."""
    loaded = {name: native.load(name) for name in (*KERNEL_MODULES, *OTHER_KERNELS)}
    assert all(getattr(module, attribute) is loaded[name] for name, (module, attribute) in OTHER_KERNELS.items())
    if native.required():
        assert all(loaded.values()), loaded
    assert all(module is None or module.__name__ == f"tapcell.tap._c_{name}" for name, module in loaded.items())


@pytest.mark.skipif(not all(module._C for module in KERNEL_MODULES.values()), reason="kernels not built")
@pytest.mark.parametrize("options", OPTIONS, ids=("toe", "sharp"))
def test_the_analysis_answers_the_same_with_and_without_the_kernels(monkeypatch, options):
    taps = _taps()
    with_kernels = [analyze_tap(tap, options) for _, tap in taps]
    for module in KERNEL_MODULES.values():
        monkeypatch.setattr(module, "_C", None)
    for module, attribute in OTHER_KERNELS.values():
        monkeypatch.setattr(module, attribute, None)
    twins = [analyze_tap(tap, options) for _, tap in taps]
    valid = 0
    for (scenario, _), fast, reference in zip(taps, with_kernels, twins):
        assert (fast.valid, fast.error) == (reference.valid, reference.error), scenario
        assert (fast.z_mm is None) == (reference.z_mm is None), scenario
        if fast.z_mm is not None:
            assert abs(fast.z_mm - reference.z_mm) * 1000.0 < Z_TOLERANCE_UM, scenario
            # rel 1e-7: the sigma's noise part is each toe's residual curvature (a second difference
            # of the two grids' sums, which agree to ~1e-12 relative).
            assert fast.z_sigma_um == pytest.approx(reference.z_sigma_um, rel=1e-7), scenario
        valid += fast.valid
    assert valid >= len(taps) // 2  # the comparison covers analysed taps, not only rejections
