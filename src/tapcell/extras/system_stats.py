"""`system_stats`: the host's load, CPU time and free memory (Klipper's status object; always loaded).

Mainsail and Fluidd show these on their system panel: `sysload` is the 1-minute load average,
`cputime` the seconds of CPU this process used, `memavail` the memory available in kB (from
/proc/meminfo; 0 where the system has none).
"""

from __future__ import annotations

import os
import time

from tapcell.host.config import ConfigSection

MEMINFO = "/proc/meminfo"


def memory_available_kb(meminfo_path: str = MEMINFO) -> int:
    try:
        with open(meminfo_path) as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return 0


class SystemStats:
    def get_status(self, eventtime=None) -> dict:
        try:
            load = os.getloadavg()[0]
        except OSError:  # no load average on this system
            load = 0.0
        return {"sysload": round(float(load), 2), "cputime": time.process_time(),
                "memavail": memory_available_kb()}


def load_config(section: ConfigSection, printer) -> SystemStats:
    return SystemStats()
