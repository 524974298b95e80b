"""Locate, build on demand and load the firmware host library (cffi ABI mode).

In a checkout the library is firmware/build/host/libtapcell_fw.so, rebuilt with
`make -C firmware host` when it is missing or older than any firmware source or header.
Installed (no firmware/ folder), it is the copy setup.py built into the package,
tapcell/mcu/_firmware*.so. TAPCELL_FW_LIB names a prebuilt library instead (no build).
Each caller passes its own cdef; one dlopen is kept per cdef.
"""

from __future__ import annotations

import fcntl
import importlib.machinery
import os
import subprocess
import threading
from pathlib import Path

from cffi import FFI

from tapcell.package_files import checkout_dir

REPO_DIR = checkout_dir()
FIRMWARE_DIR = (REPO_DIR or Path(__file__).resolve().parents[3]) / "firmware"
DEFAULT_LIB_PATH = FIRMWARE_DIR / "build" / "host" / "libtapcell_fw.so"
ENV_LIB_PATH = "TAPCELL_FW_LIB"

_loaded: dict[str, tuple[FFI, object]] = {}
_lock = threading.Lock()


class FirmwareBuildError(RuntimeError):
    """The firmware host library could not be built or found."""


def _sources() -> list[Path]:
    """Every file the host library is built from (firmware/Makefile's host target)."""
    return [*FIRMWARE_DIR.glob("src/*.c"), *FIRMWARE_DIR.glob("host/*.c"), *FIRMWARE_DIR.glob("include/*.h"),
            FIRMWARE_DIR / "Makefile"]


def _is_stale(lib_path: Path) -> bool:
    if not lib_path.exists():
        return True
    built = lib_path.stat().st_mtime
    return any(src.stat().st_mtime > built for src in _sources() if src.exists())


def library_path() -> Path:
    """Path of the library to load, building it first when needed."""
    override = os.environ.get(ENV_LIB_PATH)
    if override:
        path = Path(override)
        if not path.exists():
            raise FirmwareBuildError(f"{ENV_LIB_PATH}={override}: no such file")
        return path
    if REPO_DIR is None or not FIRMWARE_DIR.is_dir():
        return installed_library_path()
    if _is_stale(DEFAULT_LIB_PATH):
        DEFAULT_LIB_PATH.parent.mkdir(parents=True, exist_ok=True)
        # Parallel test workers share the build: one builds, the others wait.
        with open(DEFAULT_LIB_PATH.parent / ".build.lock", "w") as lock_file:
            fcntl.flock(lock_file, fcntl.LOCK_EX)
            if _is_stale(DEFAULT_LIB_PATH):
                result = subprocess.run(["make", "-C", str(FIRMWARE_DIR), "host"],
                                        capture_output=True, text=True)
                if result.returncode != 0:
                    raise FirmwareBuildError(
                        f"make -C {FIRMWARE_DIR} host failed:\n{result.stdout}{result.stderr}")
    return DEFAULT_LIB_PATH


def installed_library_path() -> Path:
    """The library setup.py built into the installed package (FirmwareBuildError when it did not)."""
    package_dir = Path(__file__).resolve().parent
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        candidate = package_dir / f"_firmware{suffix}"
        if candidate.exists():
            return candidate
    raise FirmwareBuildError(
        f"the firmware library was not built when tapcell was installed (no C compiler then?): "
        f"install one (Debian: apt-get install gcc) and reinstall tapcell, or set {ENV_LIB_PATH} "
        f"to a library built with 'make -C firmware host'")


def load(cdef: str) -> tuple[FFI, object]:
    """(ffi, lib) for this cdef: the firmware library opened with these declarations."""
    with _lock:
        if cdef not in _loaded:
            ffi = FFI()
            ffi.cdef(cdef)
            _loaded[cdef] = (ffi, ffi.dlopen(str(library_path())))
        return _loaded[cdef]
