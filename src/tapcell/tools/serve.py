"""`tapcell serve`, on the working copy of a config tapcell must not rewrite.

The API server (`tapcell.host.api_server`) serves the file it is given, and SAVE_CONFIG from
Mainsail or Fluidd rewrites it. Like the console and `tapcell run`, `serve` given a config git
tracks or one installed with tapcell works on the user's copy of it (`tapcell.tools.workspace`,
the same copy the console and `run` use), and says so on stderr; any other config is served in
place. Everything else is the server's own command line.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from tapcell.tools.workspace import working_config


def served_argv(argv: list[str]) -> tuple[list[str], str | None]:
    """`argv` with --config pointing at the working copy when it must be one (and the line saying
    so), else unchanged (and None)."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--config")
    known, _ = parser.parse_known_args(argv)
    if not known.config or not os.path.isfile(known.config):
        return argv, None  # the server says what is wrong
    path, where = working_config(Path(known.config))
    if path == Path(known.config):
        return argv, None
    rewritten = []
    for index, arg in enumerate(argv):
        if arg == "--config" and index + 1 < len(argv) and argv[index + 1] == known.config:
            rewritten.append(arg)
        elif index > 0 and argv[index - 1] == "--config" and arg == known.config:
            rewritten.append(str(path))
        elif arg == f"--config={known.config}":
            rewritten.append(f"--config={path}")
        else:
            rewritten.append(arg)
    return rewritten, where


def main(argv: list[str]) -> int:
    from tapcell.host import api_server

    argv, where = served_argv(argv)
    if where is not None:
        print(f"tapcell serve: {where}", file=sys.stderr, flush=True)
    return api_server.main(argv)
