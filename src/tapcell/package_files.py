"""Where tapcell's own files are, in a checkout and installed alike.

In a checkout (an editable install) the example configs are `examples/` and the firmware sources
`firmware/` beside `src/`. An installed wheel has no checkout: setup.py puts the examples into the
package (`tapcell/examples/`) and builds the firmware host library into it
(`tapcell/mcu/_firmware*.so`). Every reader of these files asks here, so no module guesses a
checkout from its own path.
"""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
_CHECKOUT_DIR = PACKAGE_DIR.parents[1]  # src/tapcell -> the repository, when there is one


def checkout_dir() -> Path | None:
    """The source checkout this package runs from, or None when it is installed."""
    if PACKAGE_DIR.parent.name == "src" and (_CHECKOUT_DIR / "pyproject.toml").is_file() \
            and (_CHECKOUT_DIR / "examples").is_dir():
        return _CHECKOUT_DIR
    return None


def examples_dir() -> Path:
    """The folder of the example printer configs (examples/ in a checkout, package data installed)."""
    checkout = checkout_dir()
    return checkout / "examples" if checkout is not None else PACKAGE_DIR / "examples"


def example_config(name: str = "virtual-printer.cfg") -> Path:
    """One example config by file name."""
    return examples_dir() / name


def example_names() -> list[str]:
    """The example configs there are, by file name."""
    return sorted(path.name for path in examples_dir().glob("*.cfg"))


def software_root() -> Path:
    """The checkout (with docs/ and examples/) or, installed, the package folder."""
    return checkout_dir() or PACKAGE_DIR
