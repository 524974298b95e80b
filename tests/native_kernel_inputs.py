"""Real inputs for the analysis kernels' tests: taps of the independent generator (taplab), and the
arguments the analysis passes to a function while it analyses them."""

from __future__ import annotations

import functools
import importlib.util
import shutil
import subprocess
import sysconfig
from pathlib import Path

import numpy as np
import pytest

import tapcell.tap
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
def generated_tap_objects(per_scenario: int = 2, seed: int = 12, scenarios: tuple[str, ...] | None = None
                          ) -> tuple[tuple[str, dict], ...]:
    """(scenario, tap-format object) for `per_scenario` taps of every taplab scenario (clean, drift,
    ooze, hum, corrupt frames, ...), or of `scenarios`."""
    objects = []
    for index, name in enumerate(SCENARIOS):
        if scenarios is not None and name not in scenarios:
            continue
        for k in range(per_scenario):
            rng = np.random.default_rng([seed, index, k])
            objects.append((name, make_tap(SCENARIOS[name].draw(rng), rng)[0]))
    return tuple(objects)


@functools.cache
def generated_taps(per_scenario: int = 2, seed: int = 12, scenarios: tuple[str, ...] | None = None) -> tuple:
    """`generated_tap_objects` as TapData."""
    return tuple(tap_from_object(tap, f"{name}-{k}")
                 for k, (name, tap) in enumerate(generated_tap_objects(per_scenario, seed, scenarios)))


def recorded_calls(module, name: str, options: list[AnalysisOptions], taps: tuple | None = None) -> list[tuple]:
    """The arguments of every call of `module.name` while `taps` (default: the generated taps) are analysed."""
    calls = []
    function = getattr(module, name)

    def recording(*args):
        calls.append(args)
        return function(*args)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(module, name, recording)
        for option in options:
            for tap in generated_taps() if taps is None else taps:
                analyze_tap(tap, option)
    return calls


def kernel_functions_used(module, options: AnalysisOptions) -> list[str]:
    """The names the analysis of one generated tap takes from `module._C` (its kernel), in order."""
    used = []
    kernel = module._C

    class Spy:
        def __getattr__(self, name):
            used.append(name)
            return getattr(kernel, name)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(module, "_C", Spy())
        analyze_tap(generated_taps()[0], options)
    return used


def scalar_build(name: str, directory: Path):
    """The kernel c/<name>.c built with -DTAPCELL_SCALAR (the plain loops a board without SSE2 runs
    instead of the vector ones) into `directory`, loaded beside the installed kernel; skips the test
    without a C compiler."""
    compiler = shutil.which(sysconfig.get_config_var("CC").split()[0]) if sysconfig.get_config_var("CC") else None
    if compiler is None:
        pytest.skip("no C compiler")
    source = Path(tapcell.tap.__file__).with_name("c") / f"{name}.c"
    library = directory / (f"_c_{name}" + sysconfig.get_config_var("EXT_SUFFIX"))
    subprocess.run([compiler, "-shared", "-fPIC", "-std=c99", "-O3", "-fno-fast-math", "-ffp-contract=off",
                    "-DTAPCELL_SCALAR", "-I" + sysconfig.get_paths()["include"], str(source), "-o", str(library)],
                   check=True)
    spec = importlib.util.spec_from_file_location(f"_c_{name}", library)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
