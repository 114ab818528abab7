// Boots an RP2040 firmware ELF in rp2040js without the boot ROM, plays a script of bytes
// into UART0 at given emulated times, and writes a trace of what the firmware did.
//
//   node run.mjs --image FIRMWARE.elf --script SCRIPT --trace TRACE [--ms 3000]
//       [--wall-ms 120000] [--freeze START_US:LEN_US] [--profile REGEX]
//
// SCRIPT: one line per burst, `<emulated µs> <hex bytes>`; the bytes arrive 86.8 µs apart
// (115200 baud 8N1) from that time on.
// TRACE: `U <µs> <byte>` for every byte the firmware sends on UART0 TX, `G <ns> <gpio>
// <0|1>` for every output level change on GPIO 2..17, `C <symbol> <cycles>` for every
// call of a profiled function, and a last line `END <reason> <emulated ms>`, reason `time`
// when the run lasted its full length. The process exits non-zero when it did not (a
// panic's `bkpt`, a jump into the absent boot ROM, an emulator exception, the wall-clock
// budget).
//
// --freeze stalls the core for LEN_US from START_US, as the longest critical section
// would: no instruction runs and no interrupt is taken, while the clock, the timer, the
// DMA and the PIO go on. --profile counts, for each call of the functions whose ELF symbol
// (mangled) matches REGEX, the cycles from its entry to its return, interrupts taken
// meanwhile included.
//
// Deterministic: the run loop executes one instruction at a time and, while the core sleeps
// in WFE/WFI, jumps the clock to the next alarm or PIO event; the same image and script
// give the same trace. The assertions live in the Rust test that writes the script and
// reads the trace (firmware/tests/emulator.rs).
//
// rp2040js 1.4.1 (pinned in package-lock.json) needs seven corrections for embassy-rp and
// the step engine, applied below to its internals; the harness refuses to run if those
// internals changed.
import { readFileSync, writeFileSync } from 'node:fs';
import { RP2040 } from 'rp2040js';

const args = {};
for (let i = 2; i < process.argv.length; i += 2) {
  const key = process.argv[i];
  if (!key.startsWith('--') || i + 1 >= process.argv.length) fail(`bad argument ${key}`);
  args[key.slice(2)] = process.argv[i + 1];
}
for (const required of ['image', 'script', 'trace']) {
  if (!args[required]) fail(`missing --${required}`);
}
const RUN_NS = Number(args.ms ?? 3000) * 1e6;
const WALL_MS = Number(args['wall-ms'] ?? 120000);
const [FREEZE_FROM_NS, FREEZE_UNTIL_NS] = (() => {
  if (!args.freeze) return [Infinity, Infinity];
  const [from, length] = args.freeze.split(':').map(Number);
  if (!(from >= 0) || !(length > 0)) fail(`bad --freeze ${args.freeze}: START_US:LEN_US`);
  return [from * 1000, (from + length) * 1000];
})();
const FLASH_BASE = 0x10000000;
const UART_BYTE_NS = 86_800;
const TRACED_GPIO = [...Array(16).keys()].map((i) => i + 2);

function fail(message) {
  console.error(`run.mjs: ${message}`);
  process.exit(2);
}

// ---------------------------------------------------------------- the chip and its fixes
const mcu = new RP2040();
const clock = mcu.clock;
mcu.logger = {
  debug() {},
  // (3) SEV only logs 'SEV' in rp2040js; on a Cortex-M0+ it sets the event register, which
  // embassy's thread-mode executor relies on to leave WFE after a task wake-up.
  info(_component, message) {
    if (message === 'SEV') mcu.core.eventRegistered = true;
  },
  // Unmodelled registers (ROSC, VREG, ...) warn; they do not matter here.
  warn() {},
  error(component, message) {
    throw new Error(`${component}: ${message}`);
  },
};
{
  const timer = mcu.peripherals[0x40054];
  const uart = mcu.uart[0];
  const machine = mcu.pio[1]?.machines?.[0];
  const known =
    typeof timer?.fireAlarm === 'function' && timer.alarms?.[0]?.clockAlarm &&
    'interruptStatus' in uart && 'interruptMask' in uart && typeof uart.checkInterrupts === 'function' &&
    'eventRegistered' in mcu.core && typeof mcu.core.executeInstruction === 'function' &&
    'nextAlarm' in clock && typeof mcu.pio[1]?.run === 'function' && 'stopped' in mcu.pio[1] &&
    typeof machine?.step === 'function' && typeof machine?.checkWait === 'function' &&
    'waiting' in machine && 'x' in machine && machine?.txFIFO?.constructor &&
    typeof mcu.pio[1]?.checkChangedPins === 'function';
  if (!known) fail('rp2040js internals changed: re-check the corrections in run.mjs (written for 1.4.1)');
}
// (1) UARTDMACR (0x48) is not modelled and reads as all ones, which makes embassy's buffered
// UART interrupt handler believe RX DMA is on and return at once: model it as a register.
// (2) The UART's TX interrupt is raised on every register access and can never be cleared,
// so UART0_IRQ fires forever: raise it only when written data has gone out (TX is instant
// here), and clear it by ICR, as the PL011 does.
for (const uart of mcu.uart) {
  let dmacr = 0;
  const read = uart.readUint32.bind(uart);
  const write = uart.writeUint32.bind(uart);
  uart.checkInterrupts = function () {
    this.rp2040.setInterrupt(this.irq, !!(this.interruptStatus & this.interruptMask));
  };
  uart.readUint32 = (offset) => (offset === 0x48 ? dmacr : read(offset));
  uart.writeUint32 = (offset, value) => {
    if (offset === 0x48) {
      dmacr = value & 7;
      return;
    }
    write(offset, value);
    if (offset === 0x00) {
      uart.interruptStatus |= 1 << 5;
      uart.checkInterrupts();
    }
  };
}
// (4) TIMER alarms are scheduled from a fractional microsecond and fire up to 1 µs early;
// schedule them at the exact microsecond at which TIMELR equals the alarm, as on silicon.
{
  const timer = mcu.peripherals[0x40054];
  const write = timer.writeUint32.bind(timer);
  timer.writeUint32 = (offset, value) => {
    write(offset, value);
    if (offset >= 0x10 && offset <= 0x1c) {
      const alarm = timer.alarms[(offset - 0x10) >> 2];
      const nowUs = Math.floor(clock.nanos / 1000);
      const deltaUs = ((value >>> 0) - (nowUs >>> 0)) >>> 0;
      alarm.clockAlarm.schedule(Math.max(0, (nowUs + deltaUs) * 1000 - clock.nanos));
    }
  };
}
// (5) XIP_CTRL is not mapped and reads as all ones; reads as zero (idle) instead.
mcu.peripherals[(0x14000000 >>> 14) << 2] = { readUint32: () => 0, writeUint32Atomic() {} };
// (6) The PIO runs from setTimeout callbacks, off the emulated clock: run it in step with the
// core instead (`advancePio` below), one instruction per state machine and system clock
// cycle (the images run their state machines at divider 1).
for (const pio of mcu.pio) pio.run = () => {};
// (7) FIFO join is not modelled: a state machine whose SHIFTCTRL joins the FIFOs gets its
// 8-word transmit FIFO, as on silicon.
const SHIFTCTRL_FJOIN_TX = 1 << 30;
for (const pio of mcu.pio) {
  for (const machine of pio.machines) {
    const write = machine.writeUint32.bind(machine);
    machine.writeUint32 = (offset, value) => {
      write(offset, value);
      const size = value & SHIFTCTRL_FJOIN_TX ? 8 : 4;
      if (offset === 0x0d0 - 0x0c8 && machine.txFIFO.size !== size && machine.txFIFO.empty) {
        machine.txFIFO = new machine.txFIFO.constructor(size);
      }
    };
  }
}

// ---------------------------------------------------------------- the PIO, in step
const NS_PER_CYCLE = 1e9 / mcu.clkSys;
// The time of the cycle the PIO is executing, while it runs: pin changes are stamped with it.
let pioStampNs = null;

/** Cycles state machine `machine` keeps looping on a `jmp x--` to itself, or 0. */
function countdown(pio, machine) {
  const op = pio.instructions[machine.pc];
  const jmpXDec = op >>> 13 === 0 && ((op >> 5) & 7) === 2;
  const toItself = (op & 0x1f) === machine.pc && ((op >> 8) & 0x1f) === 0;
  return jmpXDec && toItself ? machine.x >>> 0 : 0;
}

/** Runs every enabled state machine for `cycles` cycles from `startNs`. */
function advancePio(cycles, startNs) {
  for (const pio of mcu.pio) {
    if (pio.stopped) continue;
    for (const machine of pio.machines) {
      if (!machine.enabled) continue;
      let done = 0;
      while (done < cycles) {
        if (machine.waiting) {
          machine.checkWait();
          if (machine.waiting) break;
        }
        const loop = countdown(pio, machine);
        if (loop > 0) {
          const skip = Math.min(loop, cycles - done);
          machine.x = (machine.x - skip) >>> 0;
          done += skip;
          continue;
        }
        pioStampNs = startNs + done * NS_PER_CYCLE;
        machine.step();
        pio.checkChangedPins();
        done += 1;
      }
    }
  }
  pioStampNs = null;
}

/** Cycles until some state machine does more than wait or count down (at least 1). */
function pioQuietCycles() {
  let quiet = Infinity;
  for (const pio of mcu.pio) {
    if (pio.stopped) continue;
    for (const machine of pio.machines) {
      if (!machine.enabled || machine.waiting) continue;
      quiet = Math.min(quiet, Math.max(1, countdown(pio, machine)));
    }
  }
  return quiet;
}

/** Lets `ns` pass with the core doing nothing (asleep, or frozen). */
function idle(ns) {
  const start = clock.nanos;
  advancePio(Math.round(ns / NS_PER_CYCLE), start);
  clock.tick(ns);
}

/** How long the core may idle before something happens (an alarm, a PIO event, the end). */
function idleSpan(limitNs) {
  const alarm = clock.nextAlarm ? Math.max(0, clock.nextAlarm.nanos - clock.nanos) : Infinity;
  return Math.min(alarm, pioQuietCycles() * NS_PER_CYCLE, limitNs - clock.nanos);
}

// ---------------------------------------------------------------- image, direct boot
const elf = readFileSync(args.image);
if (elf.readUInt32BE(0) !== 0x7f454c46) fail(`${args.image} is not an ELF file`);
{
  const table = elf.readUInt32LE(28);
  const entrySize = elf.readUInt16LE(42);
  const count = elf.readUInt16LE(44);
  for (let i = 0; i < count; i++) {
    const entry = table + i * entrySize;
    const [type, offset, paddr, size] = [0, 4, 12, 16].map((at) => elf.readUInt32LE(entry + at));
    if (type !== 1 || size === 0) continue;
    if (paddr < FLASH_BASE || paddr + size > FLASH_BASE + mcu.flash.length) {
      fail(`segment at 0x${paddr.toString(16)} is not in flash`);
    }
    mcu.flash.set(elf.subarray(offset, offset + size), paddr - FLASH_BASE);
  }
}
// No boot ROM and no boot2: rp2040js maps flash at 0x10000000 without XIP set-up, so start
// from the vector table the way boot2 would leave it.
mcu.core.VTOR = FLASH_BASE + 0x100;
mcu.core.SP = mcu.readUint32(FLASH_BASE + 0x100);
mcu.core.PC = mcu.readUint32(FLASH_BASE + 0x104) & ~1;

// ---------------------------------------------------------------- stimulus and trace
const trace = [];
mcu.uart[0].onByte = (byte) => trace.push(`U ${(clock.nanos / 1000).toFixed(3)} ${byte}`);
for (const gpio of TRACED_GPIO) {
  // GPIOPinState: Low 0, High 1; inputs and pulls (2..5) are not output levels.
  let level = null;
  mcu.gpio[gpio].addListener((state) => {
    if (state > 1 || state === level) return;
    level = state;
    trace.push(`G ${Math.round(pioStampNs ?? clock.nanos)} ${gpio} ${state}`);
  });
}

// Profiled functions: entry address (Thumb bit clear) to name, from the ELF symbol table.
const profiled = new Map();
if (args.profile) {
  const wanted = new RegExp(args.profile);
  const sections = elf.readUInt32LE(32);
  const sectionSize = elf.readUInt16LE(46);
  const sectionCount = elf.readUInt16LE(48);
  const section = (i) => {
    const at = sections + i * sectionSize;
    return {
      type: elf.readUInt32LE(at + 4),
      offset: elf.readUInt32LE(at + 16),
      size: elf.readUInt32LE(at + 20),
      link: elf.readUInt32LE(at + 24),
    };
  };
  for (let i = 0; i < sectionCount; i++) {
    const symtab = section(i);
    if (symtab.type !== 2) continue;
    const strtab = section(symtab.link);
    for (let at = symtab.offset; at < symtab.offset + symtab.size; at += 16) {
      const nameAt = strtab.offset + elf.readUInt32LE(at);
      const name = elf.toString('latin1', nameAt, elf.indexOf(0, nameAt));
      const type = elf.readUInt8(at + 12) & 0xf;
      if (type === 2 && wanted.test(name)) profiled.set(elf.readUInt32LE(at + 4) & ~1, name);
    }
  }
  if (profiled.size === 0) fail(`no function matches ${args.profile} in ${args.image}`);
}
// The call being profiled: its name, where it returns to and the cycles it took so far.
let call = null;
for (const line of readFileSync(args.script, 'utf8').split('\n')) {
  if (!line.trim()) continue;
  const [at, hex] = line.trim().split(/\s+/);
  const bytes = Buffer.from(hex, 'hex');
  bytes.forEach((byte, i) => {
    clock.createAlarm(() => mcu.uart[0].feedByte(byte)).schedule(Number(at) * 1000 + i * UART_BYTE_NS);
  });
}

// ---------------------------------------------------------------- run
let reason = 'time';
mcu.onBreak = (code) => {
  reason = `bkpt-${code}-at-0x${((mcu.core.PC - 2) >>> 0).toString(16)}`;
};
const core = mcu.core;
const started = performance.now();
try {
  while (clock.nanos < RUN_NS && reason === 'time') {
    for (let i = 0; i < 100000 && clock.nanos < RUN_NS && reason === 'time'; i++) {
      const now = clock.nanos;
      if (now >= FREEZE_FROM_NS && now < FREEZE_UNTIL_NS) {
        idle(Math.max(NS_PER_CYCLE, idleSpan(Math.min(RUN_NS, FREEZE_UNTIL_NS))));
      } else if (core.waiting) {
        idle(Math.max(NS_PER_CYCLE, idleSpan(Math.min(RUN_NS, FREEZE_FROM_NS > now ? FREEZE_FROM_NS : RUN_NS))));
      } else if (core.PC < 0x4000) {
        reason = `boot-rom-call-at-0x${core.PC.toString(16)}`;
      } else {
        if (call === null && profiled.size > 0 && profiled.has(core.PC)) {
          call = { name: profiled.get(core.PC), returnTo: core.LR & ~1, cycles: 0 };
        }
        const cycles = core.executeInstruction();
        if (call !== null) {
          call.cycles += cycles;
          if (core.PC === call.returnTo) {
            trace.push(`C ${call.name} ${call.cycles}`);
            call = null;
          }
        }
        advancePio(cycles, now);
        clock.tick(cycles * NS_PER_CYCLE);
      }
    }
    if (performance.now() - started > WALL_MS) reason = 'wall-clock-budget';
  }
} catch (error) {
  reason = `exception-at-0x${core.PC.toString(16)}: ${error.message}`.replace(/\s+/g, '-');
}
trace.push(`END ${reason} ${(clock.nanos / 1e6).toFixed(3)}`);
writeFileSync(args.trace, trace.join('\n') + '\n');
console.error(
  `run.mjs: ${reason} after ${(clock.nanos / 1e6).toFixed(1)} emulated ms in ` +
    `${Math.round(performance.now() - started)} ms`,
);
process.exit(reason === 'time' ? 0 : 1);
