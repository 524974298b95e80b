"""make firmware-emu: build the emulator images, boot each, check and measure them.

For each board (QEMU `microbit`, a Cortex-M0; rp2040js, the RP2040's Cortex-M0+) and each
optimisation level (-O2, -Os) this writes the scenario table from the host library
(scenarios.py), builds the image (firmware/Makefile `emu`), boots it, and reads what the
image reports over semihosting: PASS/FAIL per scenario (each checked bit for bit inside the
image) and its measurements. It adds the checks made on the linked image (no __aeabi_*div or
__aeabi_l* helper, exit status 0) and prints a table, then `N passed, N failed`.

Instructions and cycles per tc_trigger_sample() on bench/firmware_cost's 4-section case:
  QEMU: with -icount shift=0 one instruction is one nanosecond of virtual time; the image times
        8 x 200 calls with the 16 MHz timer, minus the same loop calling an empty function.
  rp2040js: run.mjs times every call from its first instruction to its return (exact).
Both are printed beside the instruction and cycle counts of bench/firmware_cost's unicorn
harness for the same build, which is run here too.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

PORT = Path(__file__).resolve().parent
FIRMWARE = PORT.parent
REPO = FIRMWARE.parent
BUILD = FIRMWARE / "build" / "emu"
sys.path.insert(0, str(PORT))
sys.path.insert(0, str(REPO))

import scenarios   # noqa: E402

BOARDS = {"microbit": 16_000_000, "rp2040": 1_000_000}
OPTS = ("O2", "Os")
TIMEOUT_S = 60
QEMU = ["qemu-system-arm", "-M", "microbit", "-display", "none", "-monitor", "none", "-serial", "null",
        "-icount", "shift=0,sleep=off", "-semihosting-config", "enable=on,target=native", "-kernel"]
FORBIDDEN_HELPER = re.compile(r"^__aeabi_(\w*div\w*|l\w+)$|^__(u?div|u?mod)[sd]i3$")
CORE_OBJECTS = ("load_cell_trigger", "sos_filter", "hx71x")


@dataclass
class ImageRun:
    board: str
    opt: str
    status: int = -1
    seconds: float = 0.0
    passed: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    measures: dict[str, int] = field(default_factory=dict)
    phases: dict[int, tuple[int, int, int]] = field(default_factory=dict)   # phase: calls, cycles, instructions
    output: str = ""


def _symbols(elf: Path) -> dict[str, int]:
    out = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    return {parts[2]: int(parts[0], 16) for parts in (line.split() for line in out.splitlines()) if len(parts) == 3}


def _section_sizes(elf: Path) -> tuple[int, int, int]:
    out = subprocess.run(["arm-none-eabi-size", str(elf)], capture_output=True, text=True, check=True).stdout
    text, data, bss = (int(v) for v in out.splitlines()[1].split()[:3])
    return text, data, bss


def _core_text(map_file: Path) -> int:
    """Linked bytes of code and constants from the core's objects (trigger, filter, HX71x driver)."""
    text = map_file.read_text()
    text = text[text.index("Linker script and memory map"):]   # past the discarded sections
    core = {f"{name}.o" for name in CORE_OBJECTS}
    total, section = 0, None
    for line in text.splitlines():
        parts = line.split()
        if line.startswith(" .") and len(parts) in (1, 4):
            section = parts[0]
            parts = parts[1:]
        elif not (section and len(parts) == 3 and line.startswith(" " * 16)):
            section = None
            continue
        if len(parts) == 3 and parts[1].startswith("0x") and section.startswith((".text", ".rodata")):
            if Path(parts[2]).name in core and "/src/" in parts[2]:
                total += int(parts[1], 16)
        if len(parts) == 3:
            section = None
    return total


def _parse(run: ImageRun, text: str) -> None:
    run.output = text
    for line in text.splitlines():
        if line.startswith("FAILURES "):
            continue
        if line.startswith("PASS "):
            run.passed.append(line[5:].split(" ")[0])
        elif line.startswith("FAIL"):
            run.failed.append(line)
        elif line.startswith("M "):
            key, value = line[2:].split()
            run.measures[key] = int(value, 16)
        elif line.startswith("RP2040 phase "):
            parts = line.split()
            run.phases[int(parts[2])] = (int(parts[4]), int(parts[6]), int(parts[8]))


@dataclass
class Cost:
    instructions: float | None       # per tc_trigger_sample() on the bench's case
    cycles: float | None             # rp2040js only
    not_armed: str                   # the not-armed call, with its unit
    resolution: float                # of `instructions`


def cost_of(run: ImageRun) -> Cost:
    m = run.measures
    if run.board == "microbit" and "cost.samples" in m:
        # icount shift=0: one instruction per ns of virtual time; the empty function's body is 2
        # instructions; each of the 8 timed passes reads the 16 MHz timer to +-1 tick.
        ns_per_tick = 1e9 / m["board.ticks_per_s"]
        n = m["cost.samples"]
        instructions = (m["cost.armed_loop_ticks"] - m["cost.null_loop_ticks"]) * ns_per_tick / n + 2
        idle = (m["cost.idle_loop_ticks"] - m["cost.null_loop_ticks"]) * ns_per_tick / n + 2
        return Cost(instructions, None, f"{idle:.1f} in", 8 * ns_per_tick / n)
    if 1 in run.phases:
        calls, cycles, instructions = run.phases[1]
        idle_calls, idle_cycles, _ = run.phases.get(2, (1, 0, 0))
        return Cost(instructions / calls, cycles / calls, f"{idle_cycles / idle_calls:.1f} cy", 0.0)
    return Cost(None, None, "-", 0.0)


def boot(board: str, opt: str) -> ImageRun:
    run = ImageRun(board, opt)
    elf = BUILD / f"{board}-{opt}.elf"
    if board == "microbit":
        cmd = [*QEMU, str(elf)]
    else:
        symbols = _symbols(elf)
        cmd = ["node", str(PORT / "rp2040" / "run.mjs"), str(elf.with_suffix(".bin")),
               hex(symbols["tc_trigger_sample"]), hex(symbols["app_phase"])]
    start = time.monotonic()
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S)
        run.status = done.returncode
        _parse(run, done.stdout + done.stderr)
    except subprocess.TimeoutExpired as expired:
        run.failed.append(f"FAIL no exit within {TIMEOUT_S} s")
        _parse(run, (expired.stdout or b"").decode(errors="replace"))
    run.seconds = time.monotonic() - start
    return run


def bench_counts(opt: str) -> tuple[float, float]:
    """bench/firmware_cost's unicorn harness on its 4-section case: (instructions, cycles) per sample."""
    import bench.firmware_cost as cost
    case = cost.make_case(4, 200)
    with tempfile.TemporaryDirectory() as tmp:
        build = cost.build_arm_harness(Path(tmp), opt)
        try:
            return cost.m0_counts(case, opt, build)
        except RuntimeError:          # its output differs from the reference: the images fail too
            return float("nan"), float("nan")


def main() -> int:
    missing = [tool for tool in ("arm-none-eabi-gcc", "qemu-system-arm", "node") if not shutil.which(tool)]
    if not (PORT / "rp2040" / "node_modules" / "rp2040js").is_dir():
        missing.append("rp2040js (npm ci in firmware/port/rp2040)")
    if missing:
        print(f"firmware-emu: missing {', '.join(missing)}: run `make firmware-emu`, which installs them")
        return 1
    started = time.monotonic()
    try:
        for board, hz in BOARDS.items():
            scenarios.write_c(hz, BUILD / board / "scenarios.c")
    except RuntimeError as problem:   # the host library, its Python model and the scenario disagree
        print(f"FAIL scenarios: {problem}")
        print("0 passed, 1 failed")
        return 1
    if subprocess.run(["make", "-s", "-C", str(FIRMWARE), "-j2", "emu"]).returncode != 0:
        print("FAIL build of the emulator images (make -C firmware emu)")
        print("0 passed, 1 failed")
        return 1
    jobs = [(board, opt) for board in BOARDS for opt in OPTS]
    with ThreadPoolExecutor(max_workers=2) as pool:
        bench_future = {opt: pool.submit(bench_counts, opt) for opt in OPTS}
        runs = list(pool.map(lambda job: boot(*job), jobs))
    expected = ["unconfigured", *(name for name, *_ in scenarios.describe(BOARDS["microbit"])), "cost"]

    passed = failed = 0
    print(f"{'image':<14}{'check':<28}result")
    for run in runs:
        image = f"{run.board}-{run.opt}"
        elf = BUILD / f"{image}.elf"
        checks = [(name, name in run.passed) for name in expected]
        helpers = sorted(name for name in _symbols(elf) if FORBIDDEN_HELPER.match(name))
        checks.append(("no divide/64-bit helper", not helpers))
        checks.append(("exit status 0", run.status == 0))
        cost, bench_instructions = cost_of(run), bench_future[run.opt].result()[0]
        checks.append(("instructions = bench's", cost.instructions is not None
                       and abs(cost.instructions - bench_instructions) <= cost.resolution + 1e-9))
        for name, ok in checks:
            passed += ok
            failed += not ok
            detail = f" ({', '.join(helpers)})" if name.startswith("no divide") and helpers else ""
            print(f"{image:<14}{name:<28}{'pass' if ok else 'FAIL'}{detail}")
        for line in run.failed:
            print(f"{image:<14}  {line}")

    print()
    print(f"{'image':<14}{'instr/sample':>13}{'bench instr':>12}{'cycles/sample':>14}{'bench cycles':>13}"
          f"{'not armed':>10}{'ready->trigger':>16}{'watchdog late':>15}{'stack':>7}"
          f"{'.text':>7}{'.data':>6}{'.bss':>6}{'core .text':>11}{'boot s':>7}")
    for run in runs:
        image = f"{run.board}-{run.opt}"
        elf = BUILD / f"{image}.elf"
        m = run.measures
        hz = m.get("board.ticks_per_s", BOARDS[run.board])
        ns_per_tick = 1e9 / hz
        bench_instr, bench_cycles = bench_future[run.opt].result()
        cost = cost_of(run)
        instr_s = "-" if cost.instructions is None else f"{cost.instructions:.1f}"
        cycles_s = "-" if cost.cycles is None else f"{cost.cycles:.1f}"
        idle_s = cost.not_armed
        tap = m.get("tap.ready_to_event_ticks")
        late = m.get("watchdog.detect_latency_ticks")
        text, data, bss = _section_sizes(elf)
        print(f"{image:<14}{instr_s:>13}{bench_instr:>12.1f}{cycles_s:>14}{bench_cycles:>13.1f}{idle_s:>10}"
              f"{'-' if tap is None else f'{tap * ns_per_tick / 1000:.1f} us':>16}"
              f"{'-' if late is None else f'{late * ns_per_tick / 1000:.1f} us':>15}"
              f"{m.get('stack.high_water_bytes', 0):>7}{text:>7}{data:>6}{bss:>6}"
              f"{_core_text(elf.with_suffix('.map')):>11}{run.seconds:>7.2f}")
    print(f"(ready->trigger: data-ready interrupt time to tc_trigger_sample's TRIGGER, the HX717 frame's bit-bang "
          f"included; watchdog late: detection past the deadline, check interrupt every 1/4 period; stack: painted "
          f"high-water mark, bytes; total {time.monotonic() - started:.1f} s)")
    print(f"{passed} passed, {failed} failed")
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
