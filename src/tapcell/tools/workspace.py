"""Where `tapcell console` and `tapcell demo` keep the printer config they work on.

SAVE_CONFIG rewrites the config file. The console must never rewrite a file git tracks (the
example config, a config kept in a repository) nor one installed with tapcell (the examples in
the package): it works on a copy in the user's folder (`$TAPCELL_HOME`, else
`$XDG_CONFIG_HOME/tapcell`, else `~/.config/tapcell`), made on first use and kept, so a
calibration saved there is still there next time. One copy per source file, keyed by its full
path: two printers' `printer.cfg` get two copies. `tapcell run` works on the same copy, so a
calibration saved in the console holds in a run. A config file neither git nor tapcell owns is
the user's own and is used in place.

`--scenario NAME` picks the virtual printer's world in the file worked on (`[virtual_printer]
scenario:`); the demo starts its config the same way.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
from pathlib import Path

from tapcell.host.config import write_atomically
from tapcell.package_files import PACKAGE_DIR
from tapcell.sim.scenarios import SCENARIOS

GIT_TIMEOUT_S = 10.0
SECTION_RE = re.compile(r"(?m)^\[([^\]]+)\]\s*$")


def user_config_dir() -> Path:
    """The folder for the user's working copies of printer configs."""
    if os.environ.get("TAPCELL_HOME"):
        return Path(os.environ["TAPCELL_HOME"]).expanduser()
    base = os.environ.get("XDG_CONFIG_HOME") or "~/.config"
    return Path(base).expanduser() / "tapcell"


def is_tracked(path: Path) -> bool:
    """Whether git tracks `path` (False outside a repository or without git)."""
    path = Path(path).resolve()
    try:
        done = subprocess.run(["git", "-C", str(path.parent), "ls-files", "--error-unmatch", path.name],
                              capture_output=True, timeout=GIT_TIMEOUT_S, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return done.returncode == 0


def is_installed_with_tapcell(path: Path) -> bool:
    """Whether `path` is one of the package's own files (an installed example config)."""
    return Path(path).resolve().is_relative_to(PACKAGE_DIR)


def copy_path(source: Path) -> Path:
    """The working copy of `source` in the user's folder: its name, then a digest of its full path,
    so the copies of two files of one name never meet."""
    resolved = Path(source).resolve()
    digest = hashlib.sha256(str(resolved).encode("utf-8")).hexdigest()[:10]
    return user_config_dir() / f"{resolved.stem}-{digest}{resolved.suffix}"


def working_config(source: Path, *, fresh: bool = False) -> tuple[Path, str]:
    """(the config file to work on, a line saying which and why) for `source`."""
    source = Path(source)
    if is_installed_with_tapcell(source):
        owner, which = "it is installed with tapcell", "which is installed with tapcell"
    elif is_tracked(source):
        owner, which = "git tracks it", "which git tracks"
    else:
        return source, f"Working on {source} (SAVE_CONFIG writes there)"
    copy = copy_path(source)
    if fresh or not copy.exists():
        copy.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, copy)
        return copy, (f"Working on a copy of {source} ({owner}, so it is never rewritten): {copy}; "
                      "SAVE_CONFIG writes there")
    return copy, (f"Working on your copy {copy} (of {source}, {which}); SAVE_CONFIG writes there; "
                  "--fresh starts again from the original")


class ScenarioError(ValueError):
    """An unknown scenario name."""


def with_scenario(text: str, scenario: str) -> str:
    """Config text whose `[virtual_printer]` uses `scenario` (the section is added if missing)."""
    if scenario not in SCENARIOS:
        raise ScenarioError(f"unknown scenario '{scenario}'; one of: {', '.join(SCENARIOS)} (tapcell scenarios "
                            "describes them)")
    headers = list(SECTION_RE.finditer(text))
    for index, header in enumerate(headers):
        if header.group(1).strip() != "virtual_printer":
            continue
        end = headers[index + 1].start() if index + 1 < len(headers) else len(text)
        body = text[header.end():end]
        line = f"scenario: {scenario}"
        body, replaced = re.subn(r"(?m)^scenario\s*[:=].*$", line, body, count=1)
        if not replaced:
            body = f"\n{line}" + body
        return text[:header.end()] + body + text[end:]
    return f"[virtual_printer]\nscenario: {scenario}\n\n" + text


def set_scenario(path: Path, scenario: str) -> None:
    """Write `scenario` into the config file at `path` (atomically: `write_atomically`, ConfigError when
    it cannot, the file left as it was)."""
    write_atomically(str(path), with_scenario(Path(path).read_text(encoding="utf-8"), scenario))
