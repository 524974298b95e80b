"""The `tapcell` command: a thin dispatcher to the subcommands.

Each subcommand lives in the module that owns the feature and exposes
`main(argv: list[str]) -> int`; importing lazily keeps `tapcell --help` fast
and lets each feature grow on its own.
"""

from __future__ import annotations

import gc
import importlib
import os
import sys

SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "init": ("tapcell.tools.init", "write a starter printer folder (printer.cfg, Moonraker's data folder)"),
    "analyze": ("tapcell.tap.cli", "analyse tap files: Z at break contact, validation, quality"),
    "benchmark": ("tapcell.taplab.benchmark", "score tap analyzers (ours, Kalico's, any) on independent labelled taps"),
    "scenarios": ("tapcell.sim.cli", "list the virtual printer's scenarios and their parameters"),
    "console": ("tapcell.tools.frontend", "interactive G-code console on the virtual printer"),
    "run": ("tapcell.tools.frontend", "run a G-code script on the virtual printer"),
    "demo": ("tapcell.tools.demo", "the main job on the virtual printer, explained"),
    "serve": ("tapcell.tools.serve", "the virtual printer behind Klipper's API (for Moonraker)"),
    "monitor": ("tapcell.tools.monitor", "analyse a real printer's taps live, through Moonraker"),
    "import": ("tapcell.tools.history", "load tap files and monitor logs into a tap store"),
    "web": ("tapcell.tools.web.app", "tap history in the browser: fleet, taps, meshes (read-only)"),
    "kalico-plugin": ("tapcell.tools.kalico_plugin", "install tapcell as Kalico's tap classifier"),
}

# Every sub-command's numpy work is many small arrays (a tap is a few hundred samples; the printer
# analyses each tap in-process). numpy's OpenBLAS starts a worker thread per core when numpy is
# imported, which there only costs CPU: ~0.13 s of a `tapcell analyze` run on 2 cores (half the CPU
# of a one-file run), and on a loaded host one small solve took 15 ms instead of 0.36 (the hum fit,
# issue 21). One thread, unless the user chose otherwise; set before any module imports numpy.


# Which extra of pyproject.toml brings each optional import (the top-level module name).
EXTRA_OF_MODULE = {
    "scipy": "sim", "cffi": "sim", "jinja2": "sim", "markupsafe": "sim",
    "matplotlib": "plot",
    "rich": "tools", "websockets": "tools", "prompt_toolkit": "tools",
}


def extra_providing(module: str | None) -> str | None:
    """The extra that installs `module` (a dotted name's top level), None for no optional one."""
    return EXTRA_OF_MODULE.get((module or "").partition(".")[0])


def install_source() -> str:
    """What this tapcell was installed from, for a pip line: the checkout or wheel pip recorded
    (direct_url.json, PEP 610), else the name."""
    import json
    import urllib.parse
    from importlib import metadata

    try:
        recorded = json.loads(metadata.distribution("tapcell").read_text("direct_url.json") or "null")
    except (metadata.PackageNotFoundError, ValueError):
        recorded = None
    url = recorded.get("url", "") if isinstance(recorded, dict) else ""
    return urllib.parse.unquote(url.removeprefix("file://")) if url.startswith("file://") else "tapcell"


def missing_extra_message(command: str, module: str, extra: str) -> str:
    """One line: what is missing and the pip line that brings it."""
    source = install_source()
    return (f"tapcell {command}: needs {module.partition('.')[0]}, which comes with tapcell's [{extra}] extra: "
            f"pip install '{source}[{extra}]' (or [all])")


def _usage() -> str:
    lines = ["usage: tapcell COMMAND [ARGS...]", "", "commands:"]
    for name, (_, summary) in SUBCOMMANDS.items():
        lines.append(f"  {name:<14} {summary}")
    lines.append("")
    lines.append("Run 'tapcell COMMAND --help' for a command's options.")
    return "\n".join(lines)


EXIT_BROKEN_PIPE = 128 + 13  # what a shell reports for a command ended by SIGPIPE


# Sub-commands whose process has nothing left to do at exit but flush its output: the console
# script ends them without the interpreter's teardown, which frees every module and result object
# one by one (1.5 % of the CPU of `tapcell analyze` over 600 tap files). A run that drew (`--plot`)
# keeps it: matplotlib registers exit handlers of its own.
ENDS_WITHOUT_TEARDOWN = frozenset({"analyze"})


def run() -> None:
    """The `tapcell` console script: `main`, then the exit."""
    args = sys.argv[1:]
    status = main(args)
    if args and args[0] in ENDS_WITHOUT_TEARDOWN and "matplotlib" not in sys.modules:
        try:
            sys.stdout.flush()
        except BrokenPipeError:  # as `main` answers it: the reader left
            status = EXIT_BROKEN_PIPE
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)


def main(argv: list[str] | None = None) -> int:
    try:
        return _dispatch(argv)
    except BrokenPipeError:
        # `tapcell analyze *.json | head`: the reader left, which ends the output, not in error.
        # Point stdout at /dev/null so that Python's own flush at exit does not complain again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_BROKEN_PIPE


def _import_without_collecting(module_name: str):
    """The module, imported with the cycle collector paused. An import makes objects that live as
    long as the process (modules, functions, classes), not garbage, and the collector would walk
    them again and again while they pile up: ~5 % of the CPU of a one-file `tapcell analyze`. They
    then join the oldest generation unwalked (what gc.freeze and gc.unfreeze do together): else
    the first young collection after the import walks them all (10 M instructions, 2 % of a
    one-file `tapcell analyze`); a full collection still looks at them, as at any old object."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        return importlib.import_module(module_name)
    finally:
        gc.freeze()
        gc.unfreeze()
        if collecting:
            gc.enable()


def _dispatch(argv: list[str] | None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if args[0] in ("-V", "--version"):
        from tapcell import __version__

        print(f"tapcell {__version__}")
        return 0
    name, rest = args[0], args[1:]
    if name not in SUBCOMMANDS:
        print(f"tapcell: unknown command '{name}'\n\n{_usage()}", file=sys.stderr)
        return 2
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        module = _import_without_collecting(SUBCOMMANDS[name][0])
        # Modules serving several subcommands take the subcommand name first.
        if hasattr(module, "SUBCOMMANDS"):
            return int(module.main([name, *rest]) or 0)
        return int(module.main(rest) or 0)
    except ModuleNotFoundError as exc:
        extra = extra_providing(exc.name)
        if extra is None:
            raise
        print(missing_extra_message(name, exc.name, extra), file=sys.stderr)
        return 1
