"""tapcell installed from its built wheel works outside the checkout: the firmware library and the
example configs are in the wheel, and demo, console (a script on stdin), serve (G28 through the
API socket) and analyze run from a temporary folder.

Bounded: the sdist and the wheel are built without build isolation (the venv has the build
requirements), the fresh venv gets the wheel with --no-deps and finds the dependencies in this
venv's site-packages through a .pth line (which adds the folder to sys.path but runs none of its
.pth files, so this venv's editable tapcell stays out).
"""

from __future__ import annotations

import fcntl
import os
import selectors
import signal
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import pytest

from api.klippy_client import KlippyClient

ROOT = Path(__file__).resolve().parents[1]
BUILD_TIMEOUT_S = 300.0  # six C files at -O3 on a busy 2-core machine
RUN_TIMEOUT_S = 120.0
SERVE_START_TIMEOUT_S = 60.0


@pytest.fixture(scope="module")
def dist(tmp_path_factory) -> Path:
    """The sdist and the wheel built from it, as `make dist` builds them: once per test run, the
    parallel workers (pytest-xdist) sharing it through the run's common temporary folder."""
    pytest.importorskip("build", reason="the dev extra's 'build' (make venv installs it)")
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # this run's folder, not older runs'
    out = shared / "tapcell-dist"
    with open(shared / "tapcell-dist.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one worker builds, the other waits for it
        if not list(out.glob("*.whl")):
            done = subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(ROOT)],
                                  capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
            assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def installed(dist, tmp_path_factory) -> Path:
    """A fresh venv with the wheel installed: its bin/ folder."""
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=RUN_TIMEOUT_S)
    python = venv / "bin" / "python"
    wheel = next(dist.glob("*.whl"))
    done = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps",
                           "--no-index", str(wheel)], capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    (site / "dependencies-from-the-test-venv.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return venv / "bin"


@pytest.fixture(scope="module")
def elsewhere(tmp_path_factory) -> Path:
    """A working folder outside the checkout, with a home of its own for the console's copies."""
    return tmp_path_factory.mktemp("elsewhere")


def tapcell(bin_dir: Path, cwd: Path, *args: str, stdin: str = "") -> subprocess.CompletedProcess:
    env = {**os.environ, "TAPCELL_HOME": str(cwd / "home"), "COLUMNS": "120"}
    env.pop("TAPCELL_FW_LIB", None)
    return subprocess.run([str(bin_dir / "tapcell"), *args], cwd=cwd, input=stdin, capture_output=True,
                          text=True, timeout=RUN_TIMEOUT_S, env=env)


def test_the_sdist_and_the_wheel_carry_the_firmware_and_the_examples(dist):
    with tarfile.open(next(dist.glob("*.tar.gz"))) as sdist:
        names = {name.split("/", 1)[1] for name in sdist.getnames() if "/" in name}
    assert {"firmware/src/load_cell_trigger.c", "firmware/host/batch.c", "firmware/include/hal.h",
            "examples/virtual-printer.cfg", "examples/voron-load-cell.cfg"} <= names
    with zipfile.ZipFile(next(dist.glob("*.whl"))) as wheel:
        names = set(wheel.namelist())
    assert {"tapcell/examples/virtual-printer.cfg", "tapcell/examples/voron-load-cell.cfg"} <= names
    assert [name for name in names if name.startswith("tapcell/mcu/_firmware") and name.endswith(".so")]


def test_the_installed_package_runs_from_its_own_files(installed, elsewhere):
    done = subprocess.run([str(installed / "python"), "-c",
                           "import tapcell, tapcell.package_files as f, tapcell.mcu._lib as lib;"
                           "print(tapcell.__file__); print(f.checkout_dir()); print(lib.library_path());"
                           "print(f.example_config())"],
                          cwd=elsewhere, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, check=True)
    package, checkout, library, example = done.stdout.splitlines()
    venv = str(installed.parent)
    assert package.startswith(venv) and checkout == "None"
    assert library.startswith(venv) and "_firmware" in library
    assert example.startswith(venv) and example.endswith("tapcell/examples/virtual-printer.cfg")


def test_demo_console_and_analyze_run_from_any_folder(installed, elsewhere):
    demo = tapcell(installed, elsewhere, "demo")
    assert demo.returncode == 0, demo.stdout[-2000:] + demo.stderr[-2000:]
    assert "The calibrated printer is in out/printer.cfg" in demo.stdout
    assert (elsewhere / "out" / "bed-mesh.png").stat().st_size > 0
    console = tapcell(installed, elsewhere, "console", "--config", "out/printer.cfg",
                      stdin="G28\nPROBE\nexit\n")
    assert console.returncode == 0, console.stdout + console.stderr
    assert "// probe at 117.500,117.500 is z=" in console.stdout
    assert "!!" not in console.stdout and "Traceback" not in console.stderr
    analyze = tapcell(installed, elsewhere, "analyze", "out/last-taps.jsonl")
    assert analyze.returncode == 0, analyze.stdout + analyze.stderr
    assert analyze.stdout.count("\n") >= 10


def test_a_missing_extra_names_the_wheel_to_install_it_from(installed, elsewhere, dist):
    from test_cli_extras import WITHOUT_MODULE

    done = subprocess.run([str(installed / "python"), "-c", WITHOUT_MODULE, "rich", "demo"], cwd=elsewhere,
                          capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
    wheel = next(dist.glob("*.whl"))
    assert (done.returncode, done.stderr) == (1, "tapcell demo: needs rich, which comes with tapcell's [tools] "
                                                 f"extra: pip install '{wheel}[tools]' (or [all])\n")


def test_every_command_starts_from_any_folder(installed, elsewhere):
    from tapcell.tools.cli import SUBCOMMANDS

    for command in SUBCOMMANDS:
        done = tapcell(installed, elsewhere, command, "--help")
        assert (command, done.returncode, done.stderr) == (command, 0, ""), done.stdout
        assert done.stdout.startswith(f"usage: tapcell {command}")
    scenarios = tapcell(installed, elsewhere, "scenarios")
    assert scenarios.returncode == 0 and "warped-bed" in scenarios.stdout


def test_init_writes_a_printer_folder_the_console_starts_from(installed, elsewhere):
    init = tapcell(installed, elsewhere, "init", "my-printer")
    assert init.returncode == 0, init.stderr
    config = elsewhere / "my-printer" / "config" / "printer.cfg"
    assert f"    tapcell console --config {config}" in init.stdout.splitlines()
    console = tapcell(installed, elsewhere, "console", "--config", str(config), stdin="STATUS\n")
    assert console.returncode == 0 and "Traceback" not in console.stderr
    assert console.stdout.splitlines()[0] == f"// Working on {config} (SAVE_CONFIG writes there)"


def test_serve_homes_through_the_api_socket(installed, elsewhere):
    """The issue's failure: serve said ready, then G28 failed with 'firmware sources not found'."""
    if not (elsewhere / "out" / "printer.cfg").exists():  # the demo's calibrated printer
        assert tapcell(installed, elsewhere, "demo").returncode == 0
    sock = elsewhere / "klippy.sock"
    server = subprocess.Popen([str(installed / "tapcell"), "serve", "--config", "out/printer.cfg",
                               "--socket", str(sock)], cwd=elsewhere, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        with selectors.DefaultSelector() as selector:
            selector.register(server.stdout, selectors.EVENT_READ)
            assert selector.select(SERVE_START_TIMEOUT_S), "tapcell serve did not start"
        assert server.stdout.readline().startswith("tapcell serve: Printer is ready; listening on")
        client = KlippyClient(sock)
        try:
            reply = client.call("gcode/script", script="G28")
            assert reply == {"id": 1, "result": {}}, reply
            position = client.call("objects/query", objects={"toolhead": ["homed_axes"]})
            assert position["result"]["status"]["toolhead"]["homed_axes"] == "xyz"
        finally:
            client.close()
    finally:
        server.send_signal(signal.SIGINT)
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
