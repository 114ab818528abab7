//! The peer's state machine: firmware controller + simulated bench (mounts and flash
//! chip, see [`super::bench`]) + clock. When its power is cut in a flash write it falls
//! silent, as a board without power does.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use anyhow::Context;
use optalign_firmware::{BoardInfo, Controller, LinkKind, RamStorage, RngSource, Session};
use optalign_protocol::{
    Capabilities, Command, FrameError, MoveResult, Notification, PeerMessage, Reply, Request,
    RequestId,
};

use super::bench::{self, Bench, FlashPort, MountsPort, SharedBench};
use super::clock::{SimClock, TimeMode};
use super::mechanics::MechanicsOptions;
use super::state_file::StateFiles;
use crate::link::AccessKey;

/// How a simulated peer is set up.
#[derive(Clone, Debug)]
pub struct PeerOptions {
    /// Number of axes (1..=8).
    pub axes: u8,
    pub mechanics: MechanicsOptions,
    /// Access key as a client gives it (a passphrase, stretched for this peer's board id,
    /// or `hex:` and the derived key), provisioned at start-up as if over the serial link.
    pub key: Option<String>,
    /// The controller's flash image survives restarts in this file, the true mount state in
    /// `FILE.mounts.json` beside it.
    pub state_file: Option<PathBuf>,
    pub time: TimeMode,
    /// Network slots (1..=16): connections served at once with full rights; a newcomer
    /// evicts an unauthenticated one when all are taken (see
    /// [`optalign_firmware::admission`]).
    pub max_clients: usize,
}

impl Default for PeerOptions {
    fn default() -> Self {
        Self {
            axes: 4,
            mechanics: MechanicsOptions::default(),
            key: None,
            state_file: None,
            time: TimeMode::Scaled(1.0),
            max_clients: 4,
        }
    }
}

/// Randomness for challenge and boot nonces, from the operating system's generator (or,
/// should it fail, the thread generator it seeded).
struct OsRandom;

impl RngSource for OsRandom {
    fn fill(&mut self, buf: &mut [u8]) {
        use rand::TryRngCore;
        if rand::rngs::OsRng.try_fill_bytes(buf).is_err() {
            rand::fill(buf);
        }
    }
}

/// Everything one simulated controller is.
pub struct PeerCore {
    controller: Controller<FlashPort>,
    bench: SharedBench,
    clock: SimClock,
    /// A session of the peer's own, to ask the controller about move outcomes.
    probe: Session,
    /// The power failed (in a torn flash write): nothing is answered or stepped any more.
    off: bool,
}

impl PeerOptions {
    /// The bench the options describe: from the state files when they exist, otherwise a
    /// fresh board on new mounts.
    pub fn bench(&self) -> anyhow::Result<Bench> {
        let Some(path) = &self.state_file else {
            let mounts = self.mechanics.driver(self.axes);
            return Ok(Bench::new(mounts, RamStorage::new(), None));
        };
        let mut files = StateFiles::new(path.clone());
        let saved = files
            .load()
            .with_context(|| format!("reading peer state {}", path.display()))?;
        let (mounts, flash) = match saved {
            Some(saved) => (
                match saved.mounts {
                    Some(mounts) => optalign_firmware::sim::SimDriver::new(mounts),
                    None => self.mechanics.driver(self.axes),
                },
                saved.flash,
            ),
            None => (self.mechanics.driver(self.axes), RamStorage::new()),
        };
        Ok(Bench::new(mounts, flash, Some(files)))
    }
}

impl PeerCore {
    /// A controller starting up on the bench `options` describe.
    pub fn new(options: &PeerOptions) -> anyhow::Result<Self> {
        Self::on_bench(options, options.bench()?)
    }

    /// A controller starting up on `bench` (after a power cut, [`Bench::power_cycled`]).
    pub fn on_bench(options: &PeerOptions, bench: Bench) -> anyhow::Result<Self> {
        anyhow::ensure!(
            (1..=optalign_protocol::MAX_AXES as u8).contains(&options.axes),
            "--axes must be 1..={}, got {}",
            optalign_protocol::MAX_AXES,
            options.axes
        );
        anyhow::ensure!(
            (1..=optalign_firmware::admission::MAX_SLOTS).contains(&options.max_clients),
            "--max-clients must be 1..={}, got {}",
            optalign_firmware::admission::MAX_SLOTS,
            options.max_clients
        );
        let clock = SimClock::new(options.time);
        let board_id = 0x5157_0000_0000_0000 | u64::from(options.axes);
        let bench = Arc::new(Mutex::new(bench));
        let info = BoardInfo {
            board: "optalign-sim-peer",
            firmware_version: env!("CARGO_PKG_VERSION"),
            board_id,
            axes: options.axes,
            capabilities: Capabilities::UNIPOLAR_HALF_STEP
                | Capabilities::STEP_DIR
                | Capabilities::PERSISTENCE
                | Capabilities::SERIAL
                | Capabilities::SIMULATED,
        };
        let flash = FlashPort(bench.clone());
        let controller = Controller::new(info, flash, clock.now_us(), &mut OsRandom);
        let mut core = Self {
            controller,
            bench,
            clock,
            probe: Session::new(LinkKind::Serial),
            off: false,
        };
        core.probe = core.serial_session();
        if let Some(text) = &options.key {
            let access: AccessKey = text.parse().context("reading the peer's --key")?;
            core.provision_key(access.for_board(board_id))?;
        }
        Ok(core)
    }

    /// A trusted serial session that has completed the handshake, for in-process use.
    pub fn serial_session(&mut self) -> Session {
        let mut session = Session::new(LinkKind::Serial);
        let hello = Request {
            id: RequestId(0),
            command: Command::Hello {
                protocol_version: optalign_protocol::PROTOCOL_VERSION,
            },
        };
        self.handle(&mut session, &hello);
        session
    }

    /// Stores the access key through the serial-only command, as `optalign provision` does.
    fn provision_key(&mut self, key: optalign_protocol::auth::Key) -> anyhow::Result<()> {
        let mut session = self.serial_session();
        let set_key = Request {
            id: RequestId(rand::random()),
            command: Command::SetKey { key },
        };
        for message in self.handle(&mut session, &set_key) {
            if let PeerMessage::Reply {
                reply: optalign_protocol::Reply::Error(error),
                ..
            } = message
            {
                anyhow::bail!("provisioning the peer's key failed: {error}");
            }
        }
        Ok(())
    }

    /// Executes one request from `session`; returns the replies for that session.
    ///
    /// On instant time, simulated time passes only when something waits for it: an
    /// authentication attempt during the backoff after failures moves it to the backoff's
    /// end, so the backoff costs no wall-clock time there (scaled time keeps it real).
    pub fn handle(&mut self, session: &mut Session, request: &Request) -> Vec<PeerMessage> {
        if self.off {
            return Vec::new();
        }
        if self.clock.mode() == TimeMode::Instant
            && matches!(
                request.command,
                Command::AuthChallenge | Command::AuthResponse { .. }
            )
        {
            self.clock
                .jump_to(self.controller.authentication_reopens_at_us());
        }
        let is_move = matches!(
            request.command,
            Command::MoveTo { .. } | Command::MoveBy { .. } | Command::RecoveryMoveBy { .. }
        ) && bench::lock(&self.bench).log().is_some();
        let known_before = is_move && self.move_known(request.id);
        let mut out = Vec::new();
        let now = self.clock.now_us();
        self.controller
            .handle(session, request, now, &mut OsRandom, &mut |m| out.push(m));
        if is_move
            && !known_before
            && self.move_known(request.id)
            && let Some(log) = bench::lock(&self.bench).log_mut()
        {
            log.started(request.id.0);
        }
        if let [
            PeerMessage::Reply {
                reply: Reply::Status(status),
                ..
            },
        ] = out.as_slice()
        {
            bench::lock(&self.bench).check_status(status);
        }
        self.after_call(out)
    }

    /// Whether the controller has started the move of `request` (its outcome is known):
    /// a move request that turns it from unknown to known was executed, not replayed.
    fn move_known(&mut self, request: RequestId) -> bool {
        let ask = Request {
            id: RequestId(0),
            command: Command::MoveResult { request },
        };
        let mut known = false;
        let now = self.clock.now_us();
        self.controller
            .handle(&mut self.probe, &ask, now, &mut OsRandom, &mut |message| {
                known |= !matches!(
                    message,
                    PeerMessage::Reply {
                        reply: Reply::MoveResult(MoveResult::Unknown),
                        ..
                    }
                );
            });
        known
    }

    /// What a call sends, unless the power failed during it.
    fn after_call(&mut self, out: Vec<PeerMessage>) -> Vec<PeerMessage> {
        let mut bench = bench::lock(&self.bench);
        if bench.power_failed() {
            self.off = true;
            return Vec::new();
        }
        if let Err(error) = bench.save_mounts() {
            tracing::error!(%error, "cannot write the peer's mounts file");
        }
        if let Some(log) = bench.log_mut() {
            for message in &out {
                if let PeerMessage::Notify(Notification::MoveFinished {
                    request,
                    outcome,
                    positions,
                }) = message
                {
                    log.finished(request.0, *outcome, positions.to_vec());
                }
            }
        }
        out
    }

    /// Ends `session` (its connection closed), releasing control if it held it.
    pub fn end_session(&mut self, session: &mut Session) {
        self.controller.end_session(session);
    }

    /// Answers an unreadable frame from `session`.
    pub fn link_error(&mut self, error: FrameError) -> Vec<PeerMessage> {
        let mut out = Vec::new();
        if self.off {
            return out;
        }
        self.controller.link_error(error, &mut |m| out.push(m));
        out
    }

    /// Runs every step due now; returns notifications for all sessions and the next
    /// deadline (simulated µs) at which `poll` must run again.
    pub fn poll(&mut self) -> (Vec<PeerMessage>, Option<u64>) {
        if self.off {
            return (Vec::new(), None);
        }
        let mut out = Vec::new();
        let now = self.clock.now_us();
        let mut mounts = MountsPort(&self.bench);
        self.controller.poll(now, &mut mounts, &mut |m| out.push(m));
        let out = self.after_call(out);
        let next = if self.off {
            None
        } else {
            self.controller.next_deadline_us()
        };
        (out, next)
    }

    /// In instant mode: runs simulated time forward until no motion is pending.
    pub fn settle(&mut self) -> Vec<PeerMessage> {
        let mut out = Vec::new();
        loop {
            let (mut notes, next) = self.poll();
            out.append(&mut notes);
            match next {
                Some(deadline)
                    if self.controller.is_moving() && self.clock.mode() == TimeMode::Instant =>
                {
                    self.jump_towards(deadline)
                }
                _ => return out,
            }
        }
    }

    /// On instant time, moves the clock to `deadline`, or straight to the running move's
    /// last step when there is one: the next poll then takes all its steps, in order (step
    /// times are fixed at planning), instead of one poll (and one write of the mounts file)
    /// per step. Scaled time is not moved.
    pub fn jump_towards(&mut self, deadline: u64) {
        let end = self.controller.motion_end_us().unwrap_or(deadline);
        self.clock.jump_to(deadline.max(end));
    }

    pub fn clock(&self) -> &SimClock {
        &self.clock
    }

    pub fn clock_mut(&mut self) -> &mut SimClock {
        &mut self.clock
    }

    pub fn is_moving(&self) -> bool {
        !self.off && self.controller.is_moving()
    }

    /// Whether the power failed (in a torn flash write): the controller is silent.
    pub fn is_off(&self) -> bool {
        self.off
    }

    /// Cuts the power now: nothing is answered or stepped any more. The bench stays as it
    /// is (see [`Self::bench`]).
    pub fn cut_power(&mut self) {
        self.off = true;
    }

    /// The bench this controller runs on.
    pub fn bench(&self) -> &SharedBench {
        &self.bench
    }

    /// True shaft positions of the mounts, in steps: hidden truth for scenes and tests.
    pub fn shaft_positions(&self) -> Vec<i32> {
        bench::lock(&self.bench).shaft_positions()
    }

    /// Whether the coils of `axis` are energised (seen from the mount side).
    pub fn coils_powered(&self, axis: u8) -> bool {
        bench::lock(&self.bench).mounts().is_powered(axis)
    }
}

#[cfg(test)]
mod tests {
    use optalign_protocol::{AxisValue, Reply};

    use super::*;

    /// A peer on instant time with backlash and lost steps, so the step order matters.
    fn core() -> (PeerCore, Session) {
        let options = PeerOptions {
            mechanics: MechanicsOptions {
                backlash: 40,
                lost_step_probability: 0.01,
                seed: 7,
                ..MechanicsOptions::default()
            },
            time: TimeMode::Instant,
            ..PeerOptions::default()
        };
        let mut core = PeerCore::new(&options).unwrap();
        let session = core.serial_session();
        (core, session)
    }

    fn start_move(core: &mut PeerCore, session: &mut Session, id: u32, targets: [i32; 4]) {
        let request = Request {
            id: RequestId(id),
            command: Command::MoveTo {
                targets: (0..4u8)
                    .map(|axis| AxisValue {
                        axis,
                        steps: targets[usize::from(axis)],
                    })
                    .collect(),
            },
        };
        let replies = core.handle(session, &request);
        assert!(
            replies.iter().any(|m| matches!(
                m,
                PeerMessage::Reply {
                    reply: Reply::MoveStarted { .. },
                    ..
                }
            )),
            "{replies:?}"
        );
    }

    #[test]
    fn settling_in_one_jump_makes_the_steps_of_polling_at_every_step() {
        let (mut jumping, mut jumping_session) = core();
        let (mut stepping, mut stepping_session) = core();
        let moves = [
            [3000, -2500, 40, -7],
            [-1200, 800, -3000, 2500],
            [0, 0, 0, 0],
        ];
        for (id, targets) in (1..).zip(moves) {
            start_move(&mut jumping, &mut jumping_session, id, targets);
            let jumped = jumping.settle();
            start_move(&mut stepping, &mut stepping_session, id, targets);
            let mut stepped = Vec::new();
            loop {
                let (mut notes, next) = stepping.poll();
                stepped.append(&mut notes);
                match next {
                    Some(deadline) if stepping.is_moving() => stepping.clock.jump_to(deadline),
                    _ => break,
                }
            }
            assert_eq!(jumped, stepped);
            assert_eq!(jumping.shaft_positions(), stepping.shaft_positions());
            assert_eq!(jumping.clock.now_us(), stepping.clock.now_us());
        }
        assert_ne!(
            jumping.shaft_positions(),
            vec![0; 4],
            "lost steps and backlash show"
        );
    }
}
