//! The emulator image (`--features emu`) booted in rp2040js: protocol frames go in over
//! UART0, and the pins and the replies that come out are checked against the firmware
//! core itself, run here on the host as the oracle for the very same requests.
//!
//! The image times steps as the boards do, with PIO state machines fed by DMA, and the
//! harness runs the PIO cycle by cycle in step with the core (firmware/emu/run.mjs), so an
//! edge's time is exact to the cycle: intervals are checked to the nanosecond, under a
//! flood of requests and authentications too, and a core stalled past the lookahead shows
//! as underruns in `Status`.
//!
//! Ignored by default: it needs the image and Node. `.ci/run` builds the image, runs
//! `npm ci` in `firmware/emu`, then `cargo test -p optalign-firmware --test emulator --
//! --ignored`. `OPTALIGN_EMU_ELF` names another image.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use optalign_firmware::config::default_config;
use optalign_firmware::{
    BoardInfo, Controller, LinkKind, RamStorage, RngSource, Session, StepDirection, StepDriver,
    half_step_coils,
};
use optalign_protocol::auth::{Nonce, challenge_tag, session_key};
use optalign_protocol::seal::{Direction, Inbound, Opener, Sealer};
use optalign_protocol::{
    AxisConfig, AxisStatus, AxisValue, BacklashMode, Capabilities, Command, FrameDecoder,
    MAX_FRAME, MoveOutcome, Notification, PROTOCOL_VERSION, PeerMessage, Reply, Request, RequestId,
    Status, encode_frame, encode_sealed_frame,
};

const AXES: u8 = 4;
/// The first GPIO of axis `a` is `FIRST_GPIO + 4 a`.
const FIRST_GPIO: u32 = 2;
/// Time between a move's planned end and the next request: idle coils are released
/// after 500 ms, so every move's power-down is timed too.
const GAP_US: u64 = 700_000;
/// Pin changes closer than this on one axis are one pattern change.
const SAME_CHANGE_NS: u64 = 20_000;
/// Allowed difference between an emulated and a planned interval between two changes of
/// one timeline: one PIO cycle (8 ns at 125 MHz), from the rounding the step engine carries.
const TOLERANCE_US: f64 = 0.008;
/// UART bytes at 115200 baud 8N1, in µs.
const BYTE_US: f64 = 86.8;

/// The emulator image's identity (src/bin/optalign-emu.rs).
fn board() -> BoardInfo {
    BoardInfo {
        board: "rp2040-emulator",
        firmware_version: env!("CARGO_PKG_VERSION"),
        board_id: 0x0E30_2040,
        axes: AXES,
        capabilities: Capabilities::UNIPOLAR_HALF_STEP
            | Capabilities::STEP_DIR
            | Capabilities::SERIAL,
    }
}

/// An axis set up like a fresh one on the emulator image, with the given motion and
/// backlash settings.
fn config(max_speed: u32, acceleration: u32, backlash: u16, mode: BacklashMode) -> AxisConfig {
    AxisConfig {
        max_speed,
        acceleration,
        backlash,
        backlash_mode: mode,
        ..default_config(Capabilities(board().capabilities))
    }
}

fn values(pairs: &[(u8, i32)]) -> heapless::Vec<AxisValue, 8> {
    pairs
        .iter()
        .map(|&(axis, steps)| AxisValue { axis, steps })
        .collect()
}

/// Pin patterns the core asks for, per axis, with the time of the poll that asked.
struct Recorder {
    now: u64,
    changes: Vec<Vec<(u64, u8)>>,
}

impl Recorder {
    fn push(&mut self, axis: u8, pattern: u8) {
        let changes = &mut self.changes[usize::from(axis)];
        if changes.last().map(|c| c.1) != Some(pattern) {
            changes.push((self.now, pattern));
        }
    }
}

impl StepDriver for Recorder {
    fn step(&mut self, axis: u8, _: StepDirection, motor_steps: i32) {
        self.push(axis, half_step_coils(motor_steps));
    }

    fn set_power(&mut self, axis: u8, on: bool, motor_steps: i32) {
        self.push(axis, if on { half_step_coils(motor_steps) } else { 0 });
    }
}

struct NoRng;

impl RngSource for NoRng {
    fn fill(&mut self, buf: &mut [u8]) {
        buf.fill(0);
    }
}

/// The firmware core on the host, fed the same requests at the same times.
struct Oracle {
    core: Controller<RamStorage>,
    session: Session,
    pins: Recorder,
    notes: Vec<Notification>,
    /// Whether a move ran after each poll: (µs, moving).
    moving: Vec<(u64, bool)>,
}

impl Oracle {
    fn new() -> Self {
        Self {
            core: Controller::new(board(), RamStorage::new(), 0, &mut NoRng),
            session: Session::new(LinkKind::Serial),
            pins: Recorder {
                now: 0,
                changes: vec![Vec::new(); usize::from(AXES)],
            },
            notes: Vec::new(),
            moving: Vec::new(),
        }
    }

    /// Whether the board keeps one timeline from the change at `a` to the one at `b` (µs):
    /// it pads the timelines while a move runs, so when a move ran after every poll from
    /// `a` up to `b`. Across a pause the next change starts a new timeline, a few µs after
    /// its time.
    fn continuous(&self, a: u64, b: u64) -> bool {
        let mut polls = self.moving.iter().filter(|(at, _)| (a..b).contains(at));
        polls.all(|&(_, moving)| moving)
    }

    /// Polls at every deadline up to `until`.
    fn run_until(&mut self, until: u64) {
        while let Some(deadline) = self.core.next_deadline_us() {
            if deadline > until {
                break;
            }
            self.pins.now = self.pins.now.max(deadline);
            let notes = &mut self.notes;
            self.core.poll(self.pins.now, &mut self.pins, &mut |m| {
                if let PeerMessage::Notify(note) = m {
                    notes.push(note);
                }
            });
            self.moving.push((self.pins.now, self.core.is_moving()));
        }
        self.pins.now = self.pins.now.max(until);
    }

    fn handle(&mut self, at: u64, request: &Request) -> Reply {
        self.run_until(at);
        let mut reply = None;
        self.core
            .handle(&mut self.session, request, at, &mut NoRng, &mut |m| {
                if let PeerMessage::Reply { reply: r, .. } = m {
                    reply = Some(r);
                }
            });
        reply.expect("one reply per request")
    }
}

/// A planned exchange: requests at emulated times, and the oracle's answers.
struct Plan {
    requests: Vec<(u64, Request)>,
    replies: Vec<Reply>,
    oracle: Oracle,
    end_us: u64,
}

/// Plans `commands`, each sent once the previous one is done (a move: its planned end plus
/// [`GAP_US`]).
fn plan(commands: Vec<Command>) -> Plan {
    plan_timed(commands.into_iter().map(|c| (None, c)).collect())
}

/// Plans `commands`; one with `Some(delay)` is sent that long after the previous request
/// instead.
fn plan_timed(commands: Vec<(Option<u64>, Command)>) -> Plan {
    let mut oracle = Oracle::new();
    let mut requests: Vec<(u64, Request)> = Vec::new();
    let mut replies = Vec::new();
    let mut at = 5_000;
    let mut wait = 0;
    for (id, (delay, command)) in (1..).zip(commands) {
        if let (Some(delay), Some(previous)) = (delay, requests.last()) {
            at = previous.0 + delay;
        } else {
            at += wait;
        }
        let request = Request {
            id: RequestId(id),
            command,
        };
        let reply = oracle.handle(at, &request);
        wait = match &reply {
            Reply::MoveStarted { duration_ms } => u64::from(*duration_ms) * 1000 + GAP_US,
            Reply::Error(error) => panic!("the oracle refused {request:?}: {error}"),
            _ => 20_000,
        };
        requests.push((at, request));
        replies.push(reply);
    }
    at += wait;
    let end_us = at + 50_000;
    oracle.run_until(end_us);
    Plan {
        requests,
        replies,
        oracle,
        end_us,
    }
}

/// The messages the firmware sent on UART0.
fn messages(trace: &Trace) -> Vec<PeerMessage> {
    let mut decoder = FrameDecoder::new();
    trace
        .uart
        .iter()
        .filter_map(|&b| decoder.push::<PeerMessage>(b))
        .map(|m| m.expect("every frame from the firmware decodes"))
        .collect()
}

/// What the emulated firmware did.
struct Trace {
    uart: Vec<u8>,
    /// (ns, gpio, level)
    edges: Vec<(u64, u32, bool)>,
    /// Profiled calls: (function, cycles).
    calls: Vec<(String, u64)>,
}

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn image() -> PathBuf {
    if let Some(path) = std::env::var_os("OPTALIGN_EMU_ELF") {
        return PathBuf::from(path);
    }
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace().join("target"));
    target.join("thumbv6m-none-eabi/release/optalign-emu")
}

/// Boots the image with `plan`'s requests on UART0; `name` tells runs apart.
fn emulate(plan: &Plan, name: &str) -> Trace {
    let frames: Vec<(u64, Vec<u8>)> = plan
        .requests
        .iter()
        .map(|(at, request)| (*at, plain_frame(request)))
        .collect();
    emulate_frames(&frames, plan.end_us, name, &[])
}

/// `request` as one unsealed frame.
fn plain_frame(request: &Request) -> Vec<u8> {
    let mut frame = [0u8; MAX_FRAME];
    let len = encode_frame(request, &mut frame).unwrap();
    frame[..len].to_vec()
}

/// Boots the image, plays `frames` (each from its emulated µs) into UART0 for `end_us`,
/// with the harness's `options`; `name` tells runs apart.
fn emulate_frames(frames: &[(u64, Vec<u8>)], end_us: u64, name: &str, options: &[&str]) -> Trace {
    let image = image();
    assert!(
        image.exists(),
        "no emulator image at {}: cargo build --release -p optalign-firmware --features emu \
         --target thumbv6m-none-eabi",
        image.display()
    );
    let harness = Path::new(env!("CARGO_MANIFEST_DIR")).join("emu");
    assert!(
        harness.join("node_modules/rp2040js").exists(),
        "rp2040js is not installed: npm ci in {}",
        harness.display()
    );
    let dir = std::env::temp_dir().join(format!("optalign-emu-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let script = dir.join("script");
    let trace = dir.join("trace");
    let mut lines = String::new();
    for (at, frame) in frames {
        let hex: String = frame.iter().map(|b| format!("{b:02x}")).collect();
        lines.push_str(&format!("{at} {hex}\n"));
    }
    std::fs::write(&script, lines).unwrap();
    let output = Process::new("node")
        .current_dir(&harness)
        .arg("run.mjs")
        .arg("--image")
        .arg(&image)
        .arg("--script")
        .arg(&script)
        .arg("--trace")
        .arg(&trace)
        .arg("--ms")
        .arg((end_us / 1000).to_string())
        .args(options)
        .output()
        .expect("node runs");
    eprint!("{}", String::from_utf8_lossy(&output.stderr));
    let text = std::fs::read_to_string(&trace).expect("the harness wrote a trace");
    std::fs::remove_dir_all(&dir).ok();
    assert!(
        output.status.success(),
        "emulation failed: {}",
        text.lines().last().unwrap_or("")
    );
    let mut parsed = Trace {
        uart: Vec::new(),
        edges: Vec::new(),
        calls: Vec::new(),
    };
    for line in text.lines() {
        let fields: Vec<&str> = line.split(' ').collect();
        match fields.as_slice() {
            ["U", _, byte] => parsed.uart.push(byte.parse().unwrap()),
            ["G", ns, gpio, level] => {
                parsed
                    .edges
                    .push((ns.parse().unwrap(), gpio.parse().unwrap(), *level == "1"));
            }
            ["C", name, cycles] => parsed
                .calls
                .push((name.to_string(), cycles.parse().unwrap())),
            _ => {}
        }
    }
    parsed
}

/// The pattern changes of each axis's four pins, as (µs, pattern).
fn pin_changes(edges: &[(u64, u32, bool)]) -> Vec<Vec<(f64, u8)>> {
    let mut axes: Vec<Vec<(u64, u8)>> = vec![Vec::new(); usize::from(AXES)];
    let mut levels = [0u8; AXES as usize];
    for &(ns, gpio, high) in edges {
        let Some(offset) = gpio.checked_sub(FIRST_GPIO) else {
            continue;
        };
        let (axis, bit) = ((offset / 4) as usize, offset % 4);
        if axis >= usize::from(AXES) {
            continue;
        }
        if high {
            levels[axis] |= 1 << bit;
        } else {
            levels[axis] &= !(1 << bit);
        }
        let changes = &mut axes[axis];
        match changes.last_mut() {
            Some(last) if ns - last.0 < SAME_CHANGE_NS => last.1 = levels[axis],
            _ => changes.push((ns, levels[axis])),
        }
    }
    axes.into_iter()
        .map(|changes| {
            let mut out: Vec<(f64, u8)> = Vec::new();
            for (ns, pattern) in changes {
                if out.last().map(|c| c.1).unwrap_or(0) != pattern {
                    out.push((ns as f64 / 1000.0, pattern));
                }
            }
            out
        })
        .collect()
}

/// Index of a half-step pattern in the 8-phase sequence.
fn phase(pattern: u8) -> Option<i32> {
    (0..8).find(|&i| half_step_coils(i) == pattern)
}

/// Motor steps made between consecutive patterns (+1, -1), and power changes (0).
fn steps(changes: &[(f64, u8)]) -> Vec<i32> {
    changes
        .windows(2)
        .map(|w| match (phase(w[0].1), phase(w[1].1)) {
            (Some(a), Some(b)) => match (b - a).rem_euclid(8) {
                1 => 1,
                7 => -1,
                other => panic!("not a neighbouring half-step: {other} phases apart"),
            },
            _ => 0,
        })
        .collect()
}

/// Checks every axis's pin changes against the oracle's: the same patterns in the same
/// order, and every interval within one timeline within [`TOLERANCE_US`] of the plan.
/// Returns the worst interval error (µs) and how many intervals were compared.
fn check_timing(emulated: &[Vec<(f64, u8)>], oracle: &Oracle) -> (f64, usize) {
    let mut worst = 0.0f64;
    let mut compared = 0;
    for (axis, (got, planned)) in emulated.iter().zip(&oracle.pins.changes).enumerate() {
        let got_patterns: Vec<u8> = got.iter().map(|c| c.1).collect();
        let planned_patterns: Vec<u8> = planned.iter().map(|c| c.1).collect();
        assert_eq!(
            got_patterns, planned_patterns,
            "axis {axis}: the half-step pattern sequence"
        );
        for i in 1..got.len() {
            let (a, b) = (planned[i - 1].0, planned[i].0);
            if !oracle.continuous(a, b) {
                continue;
            }
            compared += 1;
            let interval = got[i].0 - got[i - 1].0;
            let error = interval - (b - a) as f64;
            worst = worst.max(error.abs());
            assert!(
                error.abs() <= TOLERANCE_US,
                "axis {axis}, change {i}: interval {interval:.3} µs, planned {} µs",
                b - a
            );
        }
    }
    (worst, compared)
}

#[test]
#[ignore = "needs the emulator image and Node: see the module documentation"]
fn the_emulated_image_steps_exactly_as_the_core_plans() {
    let plan = plan(vec![
        Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
        Command::SetConfig {
            axis: 0,
            config: config(800, 4000, 0, BacklashMode::Off),
        },
        Command::SetConfig {
            axis: 1,
            config: config(1000, 5000, 40, BacklashMode::OneSided),
        },
        // A plain move: ramp up, cruise at 800 steps/s, ramp down.
        Command::MoveTo {
            targets: values(&[(0, 300)]),
        },
        // The first move of axis 1, then a reversal: one-sided backlash compensation
        // overshoots past the target and comes back in the approach direction.
        Command::MoveTo {
            targets: values(&[(1, 200)]),
        },
        Command::MoveBy {
            deltas: values(&[(1, -100)]),
        },
        Command::Status,
    ]);
    let trace = emulate(&plan, "moves");

    // Replies and notifications, decoded from the UART.
    let messages = messages(&trace);
    let replies: Vec<Reply> = messages
        .iter()
        .filter_map(|m| match m {
            PeerMessage::Reply { reply, .. } => Some(reply.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(replies.len(), plan.requests.len(), "one reply per request");
    let Reply::Hello(identity) = &replies[0] else {
        panic!("no identity: {:?}", replies[0]);
    };
    assert_eq!(identity.board.as_str(), "rp2040-emulator");
    for (index, (got, want)) in replies.iter().zip(&plan.replies).enumerate().skip(1) {
        match (got, want) {
            (Reply::Status(got), Reply::Status(want)) => {
                let axes = |s: &optalign_protocol::Status| s.axes.to_vec();
                assert_eq!(axes(got), axes(want), "status");
                assert!(
                    got.axes
                        .iter()
                        .all(|a: &AxisStatus| !a.moving && !a.powered)
                );
                assert_eq!((got.axes[0].position, got.axes[1].position), (300, 100));
                assert!(got.session.trusted_link && !got.emergency_stopped);
            }
            (Reply::MoveStarted { duration_ms: got }, Reply::MoveStarted { duration_ms: want }) => {
                assert!(
                    got.abs_diff(*want) <= 1,
                    "request {index}: {got} ms, planned {want}"
                );
            }
            _ => assert_eq!(got, want, "request {index}"),
        }
    }
    let finished: Vec<(MoveOutcome, Vec<i32>)> = messages
        .iter()
        .filter_map(|m| match m {
            PeerMessage::Notify(Notification::MoveFinished {
                outcome, positions, ..
            }) => Some((*outcome, positions.to_vec())),
            _ => None,
        })
        .collect();
    let planned: Vec<(MoveOutcome, Vec<i32>)> = plan
        .oracle
        .notes
        .iter()
        .filter_map(|n| match n {
            Notification::MoveFinished {
                outcome, positions, ..
            } => Some((*outcome, positions.to_vec())),
            _ => None,
        })
        .collect();
    assert_eq!(finished, planned, "MoveFinished notifications");
    assert!(finished.iter().all(|f| f.0 == MoveOutcome::Completed));

    // The pins: the same pattern changes in the same order, at the planned intervals.
    let emulated = pin_changes(&trace.edges);
    let (worst, compared) = check_timing(&emulated, &plan.oracle);

    // Spelled out: axis 0 made exactly 300 forward steps, ramping to 1250 µs per step.
    let axis0 = &emulated[0];
    let steps0 = steps(axis0);
    assert_eq!(steps0.iter().filter(|&&s| s == 1).count(), 300);
    assert!(steps0.iter().all(|&s| s >= 0), "axis 0 never reverses");
    let intervals: Vec<f64> = axis0.windows(2).map(|w| w[1].0 - w[0].0).collect();
    let stepping = &intervals[1..intervals.len() - 1];
    let cruise = stepping.iter().copied().fold(f64::MAX, f64::min);
    assert!(
        (cruise - 1250.0).abs() <= TOLERANCE_US,
        "cruise {cruise} µs per step"
    );
    assert!(
        stepping[0] > 2.0 * cruise,
        "the move starts slowly: {}",
        stepping[0]
    );
    assert!(
        stepping[stepping.len() - 1] > 2.0 * cruise,
        "and ends slowly"
    );
    // Axis 1: the reversal runs past the target by backlash + margin, then comes back.
    let steps1 = steps(&emulated[1]);
    let runs: Vec<(i32, usize)> = steps1
        .chunk_by(|a, b| a == b)
        .filter(|run| run[0] != 0)
        .map(|run| (run[0], run.len()))
        .collect();
    let planned_runs: Vec<(i32, usize)> = {
        let planned: Vec<(f64, u8)> = plan.oracle.pins.changes[1]
            .iter()
            .map(|&(t, p)| (t as f64, p))
            .collect();
        steps(&planned)
            .chunk_by(|a, b| a == b)
            .filter(|run| run[0] != 0)
            .map(|run| (run[0], run.len()))
            .collect()
    };
    assert_eq!(runs, planned_runs);
    // The reversal's last two runs: back past the target, then forward: the forward run
    // takes up the 40-step dead band and returns the overshoot of backlash + margin (50).
    let [.., (-1, back), (1, forward)] = runs.as_slice() else {
        panic!("axis 1: expected the move to end with a back and a forward run: {runs:?}");
    };
    assert_eq!(*forward, 40 + 40 + 10, "take-up plus overshoot");
    assert_eq!(back - forward, 100, "net travel of the reversal");
    eprintln!(
        "emulator: {} replies, {} notifications, axis 0 {} steps (cruise {cruise:.1} µs), \
         axis 1 runs {runs:?}, worst interval error {worst:.3} µs over {compared} intervals",
        replies.len(),
        finished.len(),
        steps0.iter().filter(|&&s| s == 1).count()
    );
}

#[test]
#[ignore = "needs the emulator image and Node: see the module documentation"]
fn an_emergency_stop_cuts_the_coils_at_once_and_positions_stay_exact() {
    let stop_after_us = 400_000;
    let plan = plan_timed(vec![
        (
            None,
            Command::Hello {
                protocol_version: PROTOCOL_VERSION,
            },
        ),
        (
            None,
            Command::SetConfig {
                axis: 0,
                config: config(800, 4000, 0, BacklashMode::Off),
            },
        ),
        (
            None,
            Command::MoveTo {
                targets: values(&[(0, 3000)]),
            },
        ),
        (Some(stop_after_us), Command::EmergencyStop),
        (Some(300_000), Command::Status),
    ]);
    let trace = emulate(&plan, "stop");
    let messages = messages(&trace);
    let reply = |id: u32| {
        messages.iter().find_map(|m| match m {
            PeerMessage::Reply { id: got, reply } if got.0 == id => Some(reply.clone()),
            _ => None,
        })
    };
    assert_eq!(reply(4), Some(Reply::Ok), "the emergency stop is accepted");
    let Some((outcome, stopped_at)) = messages.iter().find_map(|m| match m {
        PeerMessage::Notify(Notification::MoveFinished {
            outcome, positions, ..
        }) => Some((*outcome, positions[0])),
        _ => None,
    }) else {
        panic!("no MoveFinished");
    };
    assert_eq!(outcome, MoveOutcome::EmergencyStopped);
    assert!(
        0 < stopped_at && stopped_at < 3000,
        "stopped at {stopped_at}"
    );

    // The pins: exactly as many steps as the position says, then the coils go off.
    let axis0 = &pin_changes(&trace.edges)[0];
    let made = steps(axis0).iter().filter(|&&s| s == 1).count();
    assert_eq!(made as i32, stopped_at, "steps made = reported position");
    let (off_us, last) = *axis0.last().unwrap();
    assert_eq!(last, 0, "coils off");
    let (request_us, request) = &plan.requests[3];
    let mut frame = [0u8; MAX_FRAME];
    let arrived_us = *request_us as f64 + encode_frame(request, &mut frame).unwrap() as f64 * 86.8;
    let latency_us = off_us - arrived_us;
    assert!(
        (0.0..3_000.0).contains(&latency_us),
        "coils off {latency_us:.0} µs after the request arrived"
    );

    let Some(Reply::Status(status)) = reply(5) else {
        panic!("no status");
    };
    assert!(status.emergency_stopped);
    let axis = &status.axes[0];
    assert_eq!(
        (axis.position, axis.moving, axis.powered),
        (stopped_at, false, false)
    );
    eprintln!(
        "emulator: emergency stop after {made} steps, coils off {latency_us:.0} µs after the \
         request arrived"
    );
}

/// The access key the flood provisions.
const FLOOD_KEY: [u8; 32] = [0x5A; 32];

/// The client nonce of the flood's `k`-th authentication.
fn client_nonce(k: usize) -> Nonce {
    let mut nonce = [0xC1; 16];
    nonce[..8].copy_from_slice(&(k as u64).to_le_bytes());
    nonce
}

/// When `frame` has been received in full if it starts arriving at `at` µs.
fn after(at: u64, frame: &[u8]) -> u64 {
    at + (frame.len() as f64 * BYTE_US).ceil() as u64
}

/// The replies of `messages`, by request id.
fn replies_by_id(messages: &[PeerMessage]) -> std::collections::HashMap<u32, Reply> {
    messages
        .iter()
        .filter_map(|m| match m {
            PeerMessage::Reply { id, reply } => Some((id.0, reply.clone())),
            _ => None,
        })
        .collect()
}

/// The messages the firmware sent on a session that authenticated once with each of
/// `keys` in turn: plain frames first, then each sealed under the latest key.
fn sealed_messages(trace: &Trace, keys: &[[u8; 32]]) -> Vec<PeerMessage> {
    let mut inbounds: Vec<Inbound> = std::iter::once(Inbound::plain())
        .chain(keys.iter().map(|key| {
            let mut inbound = Inbound::plain();
            inbound.install(Opener::new(*key, Direction::ToHost), true);
            inbound
        }))
        .collect();
    let mut current = 0;
    let mut messages = Vec::new();
    for frame in trace.uart.split_inclusive(|&b| b == 0) {
        let last = inbounds.len().min(current + 2);
        let decoded = (current..last).find_map(|index| {
            let mut decoder = FrameDecoder::new();
            let mut result = None;
            decoder.feed_checked::<PeerMessage>(frame, &mut inbounds[index], |m| result = Some(m));
            result.and_then(Result::ok).map(|message| (index, message))
        });
        let (index, message) = decoded
            .unwrap_or_else(|| panic!("a frame from the firmware does not decode: {frame:02x?}"));
        current = index;
        messages.push(message);
    }
    messages
}

/// The first `count` challenge nonces the emulated board issues after a boot: the nonce
/// of a draw depends on the boot, the draw counter and the generator seeded at boot, not
/// on when it is drawn, and the emulation is deterministic.
fn challenge_nonces(count: usize) -> Vec<Nonce> {
    let mut frames = Vec::new();
    let mut at = 5_000;
    let setup = [
        Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
        Command::SetKey { key: FLOOD_KEY },
    ];
    let challenges = std::iter::repeat_n(Command::AuthChallenge, count);
    for (id, command) in (1..).zip(setup.into_iter().chain(challenges)) {
        let frame = plain_frame(&Request {
            id: RequestId(id),
            command,
        });
        let next = after(at, &frame) + 3_000;
        frames.push((at, frame));
        at = next;
    }
    let trace = emulate_frames(&frames, at + 20_000, "nonces", &[]);
    let replies = replies_by_id(&messages(&trace));
    (3..3 + count as u32)
        .map(|id| match replies.get(&id) {
            Some(Reply::Challenge { nonce }) => *nonce,
            other => panic!("challenge {id}: {other:?}"),
        })
        .collect()
}

#[test]
#[ignore = "needs the emulator image and Node: see the module documentation"]
fn a_flooded_link_does_not_move_an_edge() {
    // A long move of all four axes, each at its own speed.
    let targets = [(0, 1500), (1, -2000), (2, 2600), (3, -3000)];
    let mut commands = vec![
        Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
        Command::SetKey { key: FLOOD_KEY },
    ];
    for (axis, speed) in [(0, 1000), (1, 1400), (2, 1800), (3, 2200)] {
        commands.push(Command::SetConfig {
            axis,
            config: config(speed, 6000, 0, BacklashMode::Off),
        });
    }
    commands.push(Command::MoveTo {
        targets: values(&targets),
    });
    let plan = plan(commands);
    let (move_at, _) = plan.requests.last().unwrap();
    let Some(Reply::MoveStarted { duration_ms }) = plan.replies.last() else {
        panic!("the move was not planned");
    };
    let move_end = move_at + u64::from(*duration_ms) * 1000;
    assert!(*duration_ms > 1_200, "a long move: {duration_ms} ms");

    // From just after the move starts to just before it ends, the UART never rests:
    // Status requests and complete authentications back to back, each authentication
    // sealing the session under a new key (two HMAC-SHA256 and a SHA-256 on the board,
    // and an HMAC for every frame in and out).
    let nonces = challenge_nonces(120);
    let mut frames: Vec<(u64, Vec<u8>)> = plan
        .requests
        .iter()
        .map(|(at, request)| (*at, plain_frame(request)))
        .collect();
    let mut sealer: Option<Sealer> = None;
    let mut keys = Vec::new();
    let mut expected = Vec::new();
    let mut at = move_at + 20_000;
    let mut id = 1_000;
    let mut push = |at: u64, id: u32, command: Command, sealer: &mut Option<Sealer>| {
        let request = Request {
            id: RequestId(id),
            command,
        };
        let mut buffer = [0u8; MAX_FRAME];
        let len = match sealer {
            Some(sealer) => encode_sealed_frame(&request, sealer, &mut buffer),
            None => encode_frame(&request, &mut buffer),
        }
        .unwrap();
        let frame = buffer[..len].to_vec();
        let next = after(at, &frame);
        frames.push((at, frame));
        next
    };
    for (k, nonce) in nonces.iter().enumerate() {
        if at + 20_000 > move_end {
            break;
        }
        let client = client_nonce(k);
        let tag = challenge_tag(&FLOOD_KEY, nonce, &client);
        for command in [
            Command::Status,
            Command::Status,
            Command::AuthChallenge,
            Command::AuthResponse {
                tag,
                client_nonce: client,
            },
        ] {
            expected.push((id, command.clone(), k));
            at = push(at, id, command, &mut sealer);
            id += 1;
        }
        let key = session_key(&FLOOD_KEY, nonce, &client);
        sealer = Some(Sealer::new(key, Direction::ToController));
        keys.push(key);
    }
    let flood_end = at;
    let status_id = id;
    push(
        plan.end_us - 30_000,
        status_id,
        Command::Status,
        &mut sealer,
    );
    assert!(keys.len() >= 40, "{} authentications", keys.len());

    let trace = emulate_frames(&frames, plan.end_us, "flood", &[]);
    let messages = sealed_messages(&trace, &keys);
    let replies = replies_by_id(&messages);

    // Every flood request was answered, each authentication succeeded.
    for (id, command, k) in &expected {
        let reply = replies
            .get(id)
            .unwrap_or_else(|| panic!("request {id} ({}) was not answered", command.name()));
        match (command, reply) {
            (Command::Status, Reply::Status(_)) | (Command::AuthResponse { .. }, Reply::Ok) => {}
            (Command::AuthChallenge, Reply::Challenge { nonce }) => {
                assert_eq!(nonce, &nonces[*k], "challenge {k}");
            }
            (command, reply) => panic!("{} answered {reply:?}", command.name()),
        }
    }
    // The move ran to its end, with no underrun on any axis.
    let Some(Reply::Status(status)) = replies.get(&status_id) else {
        panic!("no final status");
    };
    let status: &Status = status;
    let positions: Vec<i32> = status.axes.iter().map(|a| a.position).collect();
    assert_eq!(positions, targets.map(|t| t.1));
    assert!(status.axes.iter().all(|a| !a.moving));
    let underruns: Vec<u32> = status.axes.iter().map(|a| a.underruns).collect();
    assert_eq!(underruns, [0; 4], "underruns per axis");
    // And every edge of the move is on its cycle.
    let emulated = pin_changes(&trace.edges);
    let (worst, compared) = check_timing(&emulated, &plan.oracle);
    let steps: usize = emulated.iter().map(|axis| steps(axis).len()).sum();
    assert!(compared > 9_000, "{compared} intervals compared");
    eprintln!(
        "emulator: {} requests in {:.0} ms of flood ({} authentications) during a {duration_ms} ms \
         move of {steps} pin changes; worst interval error {worst:.3} µs over {compared} \
         intervals; underruns {underruns:?}",
        expected.len(),
        (flood_end - move_at) as f64 / 1000.0,
        keys.len(),
    );
}

#[test]
#[ignore = "needs the emulator image and Node: see the module documentation"]
fn a_core_stalled_past_the_lookahead_is_reported_as_an_underrun_and_no_step_is_lost() {
    let plan = plan(vec![
        Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
        Command::SetConfig {
            axis: 0,
            config: config(1000, 5000, 0, BacklashMode::Off),
        },
        Command::MoveTo {
            targets: values(&[(0, 600)]),
        },
        Command::Status,
    ]);
    let (move_at, _) = plan.requests[2];
    let frames: Vec<(u64, Vec<u8>)> = plan
        .requests
        .iter()
        .map(|(at, request)| (*at, plain_frame(request)))
        .collect();
    let stalled = |length_us: u64, name: &str| {
        // Halfway through the move.
        let freeze = format!("{}:{length_us}", move_at + 300_000);
        let trace = emulate_frames(&frames, plan.end_us, name, &["--freeze", &freeze]);
        let replies = replies_by_id(&messages(&trace));
        let Some(Reply::Status(status)) = replies.get(&4) else {
            panic!("no status");
        };
        (trace, status.clone())
    };

    // Well within the lookahead less the motion task's period: nothing shows on the pins.
    let (trace, status) = stalled(500, "short-stall");
    assert_eq!(status.axes[0].underruns, 0);
    let (_, compared) = check_timing(&pin_changes(&trace.edges), &plan.oracle);
    assert!(compared >= 599, "{compared} intervals compared");

    // Three times the lookahead: the steps after it come late, and it is reported.
    let (trace, status) = stalled(6_000, "stall");
    let axis = &status.axes[0];
    assert_eq!((axis.position, axis.moving), (600, false));
    assert!(axis.underruns >= 1, "the stall went unnoticed");
    assert!(status.axes[1..].iter().all(|a| a.underruns == 0));

    // Every step was made, in order; the ones after the stall came late.
    let emulated = pin_changes(&trace.edges);
    let got: Vec<u8> = emulated[0].iter().map(|c| c.1).collect();
    let planned: Vec<u8> = plan.oracle.pins.changes[0].iter().map(|c| c.1).collect();
    assert_eq!(got, planned, "the half-step pattern sequence");
    assert_eq!(steps(&emulated[0]).iter().filter(|&&s| s == 1).count(), 600);
    let late = emulated[0]
        .windows(2)
        .zip(plan.oracle.pins.changes[0].windows(2))
        .map(|(got, planned)| (got[1].0 - got[0].0) - (planned[1].0 - planned[0].0) as f64)
        .fold(0.0f64, f64::max);
    assert!(late > 1_000.0, "no step came late: {late:.1} µs");
    eprintln!(
        "emulator: a 0.5 ms stall of the core mid-move changes no edge; a 6 ms one: {} \
         underrun(s) on axis 0, steps late by up to {late:.0} µs, all 600 made",
        axis.underruns
    );
}

/// The CRC-32C's cost on the image, each way: every frame's checksum profiled in the
/// emulator, received requests and sent replies apart. A measurement (docs/results.md):
/// run it on images built with each CRC implementation.
#[test]
#[ignore = "needs the emulator image and Node: see the module documentation"]
fn crc_cycles_per_frame_each_way() {
    let mut commands = vec![Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    }];
    commands.extend(std::iter::repeat_n(Command::Status, 16));
    commands.push(Command::GetConfig { axis: 0 });
    let plan = plan(commands);
    let frames: Vec<(u64, Vec<u8>)> = plan
        .requests
        .iter()
        .map(|(at, request)| (*at, plain_frame(request)))
        .collect();
    let trace = emulate_frames(&frames, plan.end_us, "crc", &["--profile", "frame_crc"]);
    // One request, then its reply, and so on: received and sent frames alternate.
    let received: Vec<usize> = plan.requests.iter().map(|(_, r)| payload_len(r)).collect();
    let sent: Vec<usize> = messages(&trace).iter().map(payload_len).collect();
    assert_eq!(
        trace.calls.len(),
        received.len() + sent.len(),
        "one checksum per frame"
    );
    let mut report = Vec::new();
    for (way, lengths, parity) in [("received", &received, 0), ("sent", &sent, 1)] {
        let mut by_length: std::collections::BTreeMap<usize, Vec<u64>> = Default::default();
        for (length, (_, cycles)) in lengths
            .iter()
            .zip(trace.calls.iter().skip(parity).step_by(2))
        {
            by_length.entry(*length).or_default().push(*cycles);
        }
        for (length, mut cycles) in by_length {
            cycles.sort_unstable();
            let least = cycles[0];
            assert!(least > 0);
            report.push(format!(
                "{way} {length}-byte payload: {least} cycles ({:.1} per byte, {} frames)",
                least as f64 / length as f64,
                cycles.len()
            ));
        }
    }
    eprintln!("emulator: CRC-32C per frame (fewest cycles of each size):");
    for line in report {
        eprintln!("  {line}");
    }
}

/// A message's postcard payload length: what the CRC covers in a plain frame.
fn payload_len<T: serde::Serialize>(message: &T) -> usize {
    let mut buffer = [0u8; optalign_protocol::MAX_PAYLOAD];
    postcard::to_slice(message, &mut buffer).unwrap().len()
}
