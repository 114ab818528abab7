//! The emulator image (`--features emu`) booted in rp2040js: protocol frames go in over
//! UART0, and the pins and the replies that come out are checked against the firmware
//! core itself, run here on the host as the oracle for the very same requests.
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
use optalign_protocol::{
    AxisConfig, AxisStatus, AxisValue, BacklashMode, Capabilities, Command, FrameDecoder,
    MAX_FRAME, MoveOutcome, Notification, PROTOCOL_VERSION, PeerMessage, Reply, Request, RequestId,
    encode_frame,
};

const AXES: u8 = 4;
/// The first GPIO of axis `a` is `FIRST_GPIO + 4 a`.
const FIRST_GPIO: u32 = 2;
/// Time between a move's planned end and the next request: idle coils are released
/// after 500 ms, so every move's power-down is timed too.
const GAP_US: u64 = 700_000;
/// Pin changes closer than this on one axis are one pattern change.
const SAME_CHANGE_NS: u64 = 20_000;
/// Allowed difference between an emulated and a planned interval: the emulator image times
/// steps with timer interrupts (about 5-12 µs of wake-up latency).
const TOLERANCE_US: f64 = 30.0;

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
        }
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
    for (at, request) in &plan.requests {
        let mut frame = [0u8; MAX_FRAME];
        let len = encode_frame(request, &mut frame).unwrap();
        let hex: String = frame[..len].iter().map(|b| format!("{b:02x}")).collect();
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
        .arg((plan.end_us / 1000).to_string())
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
    let request_times: Vec<f64> = plan.requests.iter().map(|r| r.0 as f64).collect();
    let mut worst = 0.0f64;
    for (axis, (got, planned)) in emulated.iter().zip(&plan.oracle.pins.changes).enumerate() {
        let patterns = |c: &[(f64, u8)]| c.iter().map(|c| c.1).collect::<Vec<_>>();
        let planned_f: Vec<(f64, u8)> = planned.iter().map(|&(t, p)| (t as f64, p)).collect();
        assert_eq!(
            patterns(got),
            patterns(&planned_f),
            "axis {axis}: the half-step pattern sequence"
        );
        for i in 1..got.len() {
            let (a, b) = (planned_f[i - 1].0, planned_f[i].0);
            // Intervals across a request carry that request's arrival delay: not compared.
            if request_times.iter().any(|&r| r > a && r <= b) {
                continue;
            }
            let error = (got[i].0 - got[i - 1].0) - (b - a);
            worst = worst.max(error.abs());
            assert!(
                error.abs() <= TOLERANCE_US,
                "axis {axis}, change {i}: interval {:.1} µs, planned {:.1} µs",
                got[i].0 - got[i - 1].0,
                b - a
            );
        }
    }

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
         axis 1 runs {runs:?}, worst interval error {worst:.1} µs",
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
