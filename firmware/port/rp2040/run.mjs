// Boot an RP2040 image in rp2040js and serve its semihosting calls.
//
//   node run.mjs IMAGE.bin TC_TRIGGER_SAMPLE_ADDR APP_PHASE_ADDR
//
// The image (linked for SRAM at 0x20000000, firmware/port/rp2040/link.ld) is loaded
// there and started through its own vector table (VTOR = 0x20000000). The core runs
// at rp2040js's 125 MHz: each instruction advances the simulated clock by its cycles,
// and WFI skips to the next timer alarm. Semihosting (BKPT 0xAB): SYS_WRITE0 prints,
// SYS_EXIT / SYS_EXIT_EXTENDED end the run with the image's status.
//
// Every call of tc_trigger_sample() is timed from its first instruction to its return
// (cycles and instructions, rp2040js's cycle model) and filed under the image's
// app_phase at entry; the totals print as "RP2040 phase N calls C cycles Y instructions I".
import { readFileSync } from 'node:fs';
import { RP2040 } from 'rp2040js';

const SRAM_BASE = 0x20000000;
const CYCLE_NANOS = 1e9 / 125e6;
const MAX_CYCLES = 2e9;   // a hung image stops here

const [imagePath, sampleArg, phaseArg] = process.argv.slice(2);
if (!phaseArg) {
  console.error('usage: node run.mjs IMAGE.bin TC_TRIGGER_SAMPLE_ADDR APP_PHASE_ADDR');
  process.exit(64);
}
const sampleAddr = Number(sampleArg) & ~1;
const phaseAddr = Number(phaseArg);

const mcu = new RP2040();
mcu.sram.set(readFileSync(imagePath), 0);
mcu.core.VTOR = SRAM_BASE;
mcu.core.reset();

const core = mcu.core;
const phases = new Map();
let exitStatus = null;

function readString(address) {
  let text = '';
  for (let byte = mcu.readUint8(address); byte !== 0; byte = mcu.readUint8(++address)) {
    text += String.fromCharCode(byte);
  }
  return text;
}

mcu.onBreak = (code) => {
  if (code !== 0xab) {
    console.log(`FAIL breakpoint ${code} at 0x${(core.PC - 2).toString(16)}`);
    exitStatus = 3;
    return;
  }
  const op = core.registers[0];
  const arg = core.registers[1];
  if (op === 0x04) {            // SYS_WRITE0
    process.stdout.write(readString(arg));
  } else if (op === 0x18) {     // SYS_EXIT: reason in r1
    exitStatus = arg === 0x20026 ? 0 : 1;
  } else if (op === 0x20) {     // SYS_EXIT_EXTENDED: {reason, code} at r1
    exitStatus = mcu.readUint32(arg) === 0x20026 ? mcu.readUint32(arg + 4) : 1;
  } else {
    console.log(`FAIL unsupported semihosting call 0x${op.toString(16)}`);
    exitStatus = 3;
  }
  core.registers[0] = 0;
};

let call = null;
while (exitStatus === null) {
  if (core.waiting) {
    mcu.clock.tick(mcu.clock.nanosToNextAlarm);   // the alarm's interrupt wakes the core
    continue;
  }
  if (call === null && core.PC === sampleAddr) {
    call = { phase: mcu.readUint32(phaseAddr), cycles: core.cycles, instructions: 0, ret: core.LR & ~1 };
  }
  const cycles = core.executeInstruction();
  mcu.clock.tick(cycles * CYCLE_NANOS);
  if (call !== null) {
    call.instructions++;
    if (core.PC === call.ret) {
      const total = phases.get(call.phase) ?? { calls: 0, cycles: 0, instructions: 0 };
      total.calls++;
      total.cycles += core.cycles - call.cycles;
      total.instructions += call.instructions;
      phases.set(call.phase, total);
      call = null;
    }
  }
  if (core.cycles > MAX_CYCLES) {
    console.log(`FAIL no exit after ${MAX_CYCLES} cycles (PC 0x${core.PC.toString(16)})`);
    exitStatus = 4;
  }
}
for (const [phase, total] of [...phases].sort((a, b) => a[0] - b[0])) {
  console.log(`RP2040 phase ${phase} calls ${total.calls} cycles ${total.cycles} instructions ${total.instructions}`);
}
process.exit(exitStatus);
