"""`tapcell init`'s folder works as Moonraker's data folder: the serve line it prints and the
real Moonraker (pinned, own venv) on its moonraker.conf reach Klippy ready together."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import urllib.error
import urllib.request

from conftest import START_TIMEOUT_S, free_port, stop, wait_for
from real_packages import moonraker_python


def test_the_init_folder_serves_to_the_real_moonraker(tmp_path):
    python = moonraker_python()
    data = tmp_path / "printer_data"
    init = subprocess.run([sys.executable, "-m", "tapcell", "init", str(data)], capture_output=True, text=True,
                          timeout=60, check=True)
    serve_line = next(line.strip() for line in init.stdout.splitlines() if line.strip().startswith("tapcell serve "))
    assert init.stdout.splitlines()[-1].strip() == f"moonraker -d {data}"
    # The only change to what init wrote: a free port instead of Moonraker's default 7125.
    port = free_port()
    conf = data / "config" / "moonraker.conf"
    conf.write_text(conf.read_text().replace("[server]\n", f"[server]\nport: {port}\n", 1))
    serve = subprocess.Popen([sys.executable, "-m", "tapcell", *shlex.split(serve_line)[1:]],
                             stdout=(data / "logs" / "serve.out").open("w"), stderr=subprocess.STDOUT)
    moonraker = None
    try:
        wait_for((data / "comms" / "klippy.sock").exists, START_TIMEOUT_S, "tapcell serve to listen", serve)
        moonraker = subprocess.Popen([str(python), "-m", "moonraker", "-d", str(data)],
                                     stdout=subprocess.DEVNULL, stderr=(data / "logs" / "moonraker.err").open("w"),
                                     env=dict(os.environ, PYTHONPATH=""))

        def klippy_state():
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/server/info", timeout=5) as answer:
                    return json.loads(answer.read())["result"]["klippy_state"]
            except (urllib.error.URLError, ConnectionError, TimeoutError):
                return None

        assert wait_for(lambda: klippy_state() == "ready", START_TIMEOUT_S, "Klippy ready", moonraker)
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/printer/objects/query?configfile=config",
                                    timeout=30) as answer:
            config = json.loads(answer.read())["result"]["status"]["configfile"]["config"]
        assert config["safe_z_home"]["home_xy_position"] == "117.5, 117.5"  # the example, as init wrote it
    finally:
        if moonraker is not None:
            stop(moonraker)
        stop(serve)
