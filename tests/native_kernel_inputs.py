"""Real inputs for the analysis kernels' tests: taps of the independent generator (taplab), and the
arguments the analysis passes to a function while it analyses them."""

from __future__ import annotations

import functools

import numpy as np

from tapcell.tap import AnalysisOptions, analyze_tap
from tapcell.tap.readers import tap_from_object
from tapcell.taplab.generate import SCENARIOS, make_tap

# The options of the final gate: the default (toe) and the sharp model without a sensor delay, plus
# the sharp model's onset paths (fitted per tap, calibrated).
OPTIONS = {
    "default": AnalysisOptions(),
    "sharp": AnalysisOptions(contact_model="sharp", sensor_delay_s=0.0),
    "fitted_onset": AnalysisOptions(fit_contact_onset=True),
    "calibrated_onset": AnalysisOptions(contact_onset_um=4.0),
}


@functools.cache
def generated_taps(per_scenario: int = 2, seed: int = 12) -> tuple:
    """`per_scenario` taps of every taplab scenario (clean, drift, ooze, hum, corrupt frames, ...)."""
    taps = []
    for index, name in enumerate(SCENARIOS):
        for k in range(per_scenario):
            rng = np.random.default_rng([seed, index, k])
            tap, _ = make_tap(SCENARIOS[name].draw(rng), rng)
            taps.append(tap_from_object(tap, f"{name}-{k}"))
    return tuple(taps)


def recorded_calls(monkeypatch, module, name: str, options: list[AnalysisOptions]) -> list[tuple]:
    """The arguments of every call of `module.name` while the generated taps are analysed."""
    calls = []
    function = getattr(module, name)

    def recording(*args):
        calls.append(args)
        return function(*args)

    with monkeypatch.context() as patch:
        patch.setattr(module, name, recording)
        for option in options:
            for tap in generated_taps():
                analyze_tap(tap, option)
    return calls


def kernel_functions_used(monkeypatch, module, options: AnalysisOptions) -> list[str]:
    """The names the analysis of one generated tap takes from `module._C` (its kernel), in order."""
    used = []
    kernel = module._C

    class Spy:
        def __getattr__(self, name):
            used.append(name)
            return getattr(kernel, name)

    with monkeypatch.context() as patch:
        patch.setattr(module, "_C", Spy())
        analyze_tap(generated_taps()[0], options)
    return used
