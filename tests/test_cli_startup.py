"""`tapcell analyze` starts lean: a fresh interpreter imports only what the analysis needs, and
numpy's OpenBLAS runs one thread in every sub-command (its per-core workers only cost CPU on arrays
of a tap's size, and the printer analyses its taps in-process)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tapcell.tap import cli, readers, tap_to_json_dict
from tapcell.tap.synth import synth_tap

RUN = """
import contextlib, io, os, sys
from tapcell.tools import cli
with contextlib.redirect_stdout(io.StringIO()):
    status = cli.main(["analyze", "--json", sys.argv[1]])
modules = sorted(sys.modules)  # before this script's own json
import json
threads = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("Threads:"))
print(json.dumps({"status": status, "threads": threads, "blas": os.environ.get("OPENBLAS_NUM_THREADS"),
                  "modules": modules}))
"""
# The process's threads once numpy is imported, the CLI left out (the control).
NUMPY_ALONE = """
import numpy
print(next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("Threads:")))
"""


def _run(script: str, *args: str, blas: str | None = None) -> str:
    env = {key: value for key, value in os.environ.items() if key != "OPENBLAS_NUM_THREADS"}
    if blas is not None:
        env["OPENBLAS_NUM_THREADS"] = blas
    return subprocess.run([sys.executable, "-c", script, *args], env=env, capture_output=True, text=True,
                          check=True, timeout=60).stdout


@pytest.fixture(scope="module")
def tap_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("startup") / "tap.json"
    path.write_text(json.dumps(tap_to_json_dict(synth_tap(seed=3))))
    return str(path)


@pytest.fixture(scope="module")
def run(tap_file):
    """What a fresh `tapcell analyze --json` process reports of itself, OPENBLAS_NUM_THREADS unset."""
    return json.loads(_run(RUN, tap_file))


def test_analyze_imports_only_what_the_analysis_needs(run):
    assert run["status"] == 0
    modules = set(run["modules"])
    assert {"numpy", "tapcell.tap.analysis", "tapcell.tap.readers"} <= modules
    unneeded = {"pathlib", "csv", "matplotlib", "scipy", "tapcell.tap.plot", "tapcell.taplab", "tapcell.sim",
                "tapcell.host", "tapcell.tools.frontend",
                "tapcell.tap.hum",  # this tap asks for no hum removal (no mains_hz in its meta or options)
                "json",  # the reader's and the output's kernels read and write it
                "argparse", "shutil"}  # `--json FILE` is read without argparse (tap.cli._arguments)
    if readers._C is None or cli._C is None:
        unneeded.discard("json")
    assert sorted(unneeded & modules) == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="counts threads in /proc/self/status")
def test_analyze_runs_blas_on_one_thread_unless_the_user_chose(run, tap_file):
    assert run["blas"] == "1" and run["threads"] == 1
    if (os.cpu_count() or 1) > 1:  # the control: numpy alone starts a worker per core
        assert int(_run(NUMPY_ALONE)) > 1
    assert json.loads(_run(RUN, tap_file, blas="2"))["blas"] == "2"


# A sub-command that stops at once (its usage error) after the CLI chose the BLAS threads.
SUBCOMMAND_ENV = """
import contextlib, io, json, os, sys
from tapcell.tools import cli
with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
    try:
        cli.main([sys.argv[1], "--no-such-option"])
    except SystemExit:
        pass
print(json.dumps(os.environ.get("OPENBLAS_NUM_THREADS")))
"""


@pytest.mark.parametrize("subcommand", ["serve", "run", "console", "monitor", "demo"])
def test_the_printer_sub_commands_run_blas_on_one_thread_too(subcommand):
    assert json.loads(_run(SUBCOMMAND_ENV, subcommand)) == "1"
    assert json.loads(_run(SUBCOMMAND_ENV, subcommand, blas="4")) == "4"


def test_analyze_leaves_no_cycles_for_the_collector_it_turns_off(tmp_path, capsys):
    """`tapcell analyze` runs without the cycle collector (reference counting frees every tap): true
    only while reading and analysing a tap make no reference cycles. Every taplab scenario and a
    refused file leave no more cyclic garbage than one tap does (argparse's parser, once a run);
    the collector is on again afterwards."""
    import gc

    from native_kernel_inputs import generated_tap_objects
    from tapcell.tap import cli as analyze_cli

    files = []
    for k, (_, tap) in enumerate(generated_tap_objects(1)):
        files.append(str(tmp_path / f"tap-{k}.json"))
        Path(files[-1]).write_text(json.dumps(tap))
    (tmp_path / "broken.json").write_text('{"time": [1, 2], "force": ')
    files.append(str(tmp_path / "broken.json"))

    def cyclic_garbage_of_a_run(names):
        gc.collect()
        analyze_cli.main(["--json", *names])
        assert gc.isenabled()
        garbage = gc.collect()
        assert len(json.loads(capsys.readouterr().out)) == len([n for n in names if "broken" not in n])
        return garbage

    assert cyclic_garbage_of_a_run(files) == cyclic_garbage_of_a_run(files[:1])


@pytest.mark.parametrize("missing", [False, True])
def test_analyze_ends_without_teardown_after_its_whole_output(tmp_path, tap_file, missing):
    """The console script ends `tapcell analyze` with os._exit (tools.cli.ENDS_WITHOUT_TEARDOWN):
    every tap's result reaches the pipe first, with the run's exit status (1: a file unreadable)."""
    names = [tap_file, tap_file, tap_file] + ([str(tmp_path / "missing.json")] if missing else [])
    env = {key: value for key, value in os.environ.items() if key != "PYTHONUNBUFFERED"}  # output in a buffer
    run = subprocess.run([sys.executable, "-m", "tapcell", "analyze", "--json", *names], capture_output=True,
                         text=True, timeout=120, env=env)
    assert run.returncode == (1 if missing else 0)
    assert [tap["file"] for tap in json.loads(run.stdout)] == [tap_file] * 3
    assert ("missing.json" in run.stderr) == missing


@pytest.mark.parametrize("collecting", [True, False])
def test_a_sub_command_is_imported_without_the_cycle_collector(tmp_path, monkeypatch, collecting):
    """The collector is off while the sub-command's module imports, and as it was afterwards; what
    the import made is in the oldest generation, where no young collection walks it."""
    import gc

    from tapcell.tools import cli

    (tmp_path / "startup_probe_module.py").write_text("import gc\nCOLLECTING = gc.isenabled()\nMADE = [[]]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    was = gc.isenabled()
    (gc.enable if collecting else gc.disable)()
    try:
        module = cli._import_without_collecting("startup_probe_module")
        assert module.COLLECTING is False
        assert gc.isenabled() is collecting
        assert gc.get_freeze_count() == 0
        assert any(made is module.MADE for made in gc.get_objects(generation=2))
        assert not any(made is module.MADE for made in gc.get_objects(generation=0))
    finally:
        (gc.enable if was else gc.disable)()
        sys.modules.pop("startup_probe_module", None)


@pytest.mark.parametrize("pool", [False, True])
def test_analyze_drops_each_analysis_once_written_unless_pooling(tmp_path, capsys, monkeypatch, pool):
    """Without --pool a tap's analysis (~34 kB: the toe grid, the pullback's samples) is freed once
    its line is written, so a run's memory stays flat; --pool keeps every one for the joint fit."""
    import weakref

    from native_kernel_inputs import generated_tap_objects
    from tapcell.tap import cli as analyze_cli

    files = []
    for k, (_, tap) in enumerate(generated_tap_objects(1)[:5]):
        files.append(str(tmp_path / f"tap-{k}.json"))
        Path(files[-1]).write_text(json.dumps(tap))
    analysed = []  # a weak reference to each analysis, in order
    alive_at_each_call = []  # how many of the analyses before the last were still alive at each call
    real_analyze_tap = analyze_cli.analyze_tap

    def analyze_tap(tap, options):
        alive_at_each_call.append(sum(ref() is not None for ref in analysed[:-1]))
        result = real_analyze_tap(tap, options)
        analysed.append(weakref.ref(result))
        return result

    monkeypatch.setattr(analyze_cli, "analyze_tap", analyze_tap)
    assert analyze_cli.main(["--json", *(["--pool"] if pool else []), *files]) == 0
    assert len(json.loads(capsys.readouterr().out)) == len(files)
    assert alive_at_each_call == ([0, 0, 1, 2, 3] if pool else [0] * len(files))
