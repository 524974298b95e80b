"""Packaging: `pip install` prints no setuptools deprecation block (framed in `!!` lines, which a
Klipper user reads as an error)."""

import re
import tomllib
from pathlib import Path

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def test_license_is_an_spdx_string_with_a_setuptools_that_reads_it():
    project = tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))
    # The table form `{ text = ... }` is deprecated since setuptools 77 and warns on every build.
    assert project["project"]["license"] == "GPL-3.0-or-later"
    requires = project["build-system"]["requires"]
    setuptools = [r for r in requires if r.startswith("setuptools")]
    assert len(setuptools) == 1
    minimum = re.fullmatch(r"setuptools>=(\d+)(?:\.\d+)*", setuptools[0])
    assert minimum is not None and int(minimum.group(1)) >= 77  # the first to read an SPDX string
