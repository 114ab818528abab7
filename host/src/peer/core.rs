//! The peer's state machine: firmware controller + simulated mounts + clock, with the
//! state file kept in step with the controller's persisted record.

use std::path::PathBuf;

use anyhow::Context;
use optalign_firmware::sim::SimDriver;
use optalign_firmware::{BoardInfo, Controller, LinkKind, RamStorage, RngSource, Session};
use optalign_protocol::{Capabilities, Command, FrameError, PeerMessage, Request, RequestId};

use super::clock::{SimClock, TimeMode};
use super::mechanics::MechanicsOptions;
use super::state_file::StateFile;
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
    /// Where the controller's persisted record and the true mount state survive restarts.
    pub state_file: Option<PathBuf>,
    pub time: TimeMode,
    /// Network clients served at once (at least 2); the last free slot is kept for a
    /// client that authenticates, so observers cannot lock out a new controlling client.
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
    controller: Controller<RamStorage>,
    mounts: SimDriver,
    clock: SimClock,
    state_file: Option<StateFile>,
    axes: u8,
}

impl PeerCore {
    pub fn new(options: &PeerOptions) -> anyhow::Result<Self> {
        anyhow::ensure!(
            (1..=optalign_protocol::MAX_AXES as u8).contains(&options.axes),
            "--axes must be 1..={}, got {}",
            optalign_protocol::MAX_AXES,
            options.axes
        );
        anyhow::ensure!(
            options.max_clients >= 2,
            "--max-clients must be at least 2 (one slot is kept for a controlling client), got {}",
            options.max_clients
        );
        let state_file = options.state_file.clone().map(StateFile::new);
        let saved = match &state_file {
            Some(file) => file
                .load()
                .with_context(|| format!("reading peer state {}", file.path().display()))?,
            None => None,
        };
        let clock = SimClock::new(options.time);
        let (mounts, storage) = match saved {
            Some(saved) => (
                SimDriver::new(saved.mounts),
                RamStorage::from_bytes(&saved.flash),
            ),
            None => (options.mechanics.driver(options.axes), RamStorage::new()),
        };
        let board_id = 0x5157_0000_0000_0000 | u64::from(options.axes);
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
        let controller = Controller::new(info, storage, clock.now_us(), &mut OsRandom);
        let mut core = Self {
            controller,
            mounts,
            clock,
            state_file,
            axes: options.axes,
        };
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
        if self.clock.mode() == TimeMode::Instant
            && matches!(
                request.command,
                Command::AuthChallenge | Command::AuthResponse { .. }
            )
        {
            self.clock
                .jump_to(self.controller.authentication_reopens_at_us());
        }
        let mut out = Vec::new();
        let now = self.clock.now_us();
        self.controller
            .handle(session, request, now, &mut OsRandom, &mut |m| out.push(m));
        self.save_if_changed();
        out
    }

    /// Ends `session` (its connection closed), releasing control if it held it.
    pub fn end_session(&mut self, session: &mut Session) {
        self.controller.end_session(session);
    }

    /// Answers an unreadable frame from `session`.
    pub fn link_error(&mut self, error: FrameError) -> Vec<PeerMessage> {
        let mut out = Vec::new();
        self.controller.link_error(error, &mut |m| out.push(m));
        out
    }

    /// Runs every step due now; returns notifications for all sessions and the next
    /// deadline (simulated µs) at which `poll` must run again.
    pub fn poll(&mut self) -> (Vec<PeerMessage>, Option<u64>) {
        let mut out = Vec::new();
        let now = self.clock.now_us();
        self.controller
            .poll(now, &mut self.mounts, &mut |m| out.push(m));
        self.save_if_changed();
        (out, self.controller.next_deadline_us())
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
                    // Straight to the move's last step: one poll takes all its steps.
                    let end = self.controller.motion_end_us().unwrap_or(deadline);
                    self.clock.jump_to(deadline.max(end))
                }
                _ => return out,
            }
        }
    }

    pub fn clock(&self) -> &SimClock {
        &self.clock
    }

    pub fn clock_mut(&mut self) -> &mut SimClock {
        &mut self.clock
    }

    pub fn is_moving(&self) -> bool {
        self.controller.is_moving()
    }

    /// True shaft positions of the mounts, in steps: hidden truth for scenes and tests.
    pub fn shaft_positions(&self) -> Vec<i32> {
        (0..self.axes)
            .filter_map(|axis| self.mounts.mount(axis))
            .map(|m| m.mirror_position())
            .collect()
    }

    /// Whether the coils of `axis` are energised (seen from the mount side).
    pub fn coils_powered(&self, axis: u8) -> bool {
        self.mounts.is_powered(axis)
    }

    fn save_if_changed(&mut self) {
        if let Some(file) = &mut self.state_file
            && let Err(error) =
                file.save_if_changed(self.controller.storage(), &self.mounts, self.axes)
        {
            tracing::error!(%error, path = %file.path().display(), "cannot write peer state file");
        }
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
