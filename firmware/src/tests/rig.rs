//! A test bench: a controller, simulated mounts, a serial session and simulated time.

use optalign_protocol::{
    AxisConfig, AxisValue, Capabilities, Command, ErrorCode, Notification, PROTOCOL_VERSION,
    PeerMessage, Reply, Request, RequestId, Status,
};

use crate::sim::{MountModel, SimDriver, SimRng};
use crate::{
    BoardInfo, Controller, LinkKind, RamStorage, RngSource, Session, StepDirection, StepDriver,
};

pub const CAPABILITIES: u32 = Capabilities::UNIPOLAR_HALF_STEP
    | Capabilities::STEP_DIR
    | Capabilities::PERSISTENCE
    | Capabilities::SERIAL
    | Capabilities::SIMULATED;

pub fn board(axes: u8) -> BoardInfo {
    BoardInfo {
        board: "test-bench",
        firmware_version: "0.1.0",
        board_id: 0x0BAD_CAFE,
        axes,
        capabilities: CAPABILITIES,
    }
}

/// A step the driver was asked for, and when.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Logged {
    pub axis: u8,
    pub direction: StepDirection,
    pub at_us: u64,
}

/// A [`SimDriver`] that also logs every call with the simulated time.
pub struct TimedDriver {
    pub sim: SimDriver,
    pub now: u64,
    pub steps: Vec<Logged>,
    /// (axis, on, time)
    pub power: Vec<(u8, bool, u64)>,
}

impl StepDriver for TimedDriver {
    fn step(&mut self, axis: u8, direction: StepDirection, motor_steps: i32) {
        self.steps.push(Logged {
            axis,
            direction,
            at_us: self.now,
        });
        self.sim.step(axis, direction, motor_steps);
    }

    fn set_power(&mut self, axis: u8, on: bool, motor_steps: i32) {
        self.power.push((axis, on, self.now));
        self.sim.set_power(axis, on, motor_steps);
    }
}

pub struct Rig {
    pub controller: Controller<RamStorage>,
    pub driver: TimedDriver,
    pub session: Session,
    pub rng: SimRng,
    pub now: u64,
    /// Notifications delivered by poll.
    pub notes: Vec<Notification>,
    next_id: u32,
}

impl Rig {
    /// `axes` axes, each on a mount with a true dead band of `true_backlash`, all with
    /// `config`; handshake done on a serial session.
    pub fn new(axes: u8, true_backlash: u32, config: AxisConfig) -> Self {
        let mut rig = Self::boot(
            RamStorage::new(),
            (0..axes).map(|_| MountModel::new(true_backlash)),
            axes,
        );
        for axis in 0..axes {
            rig.ok(Command::SetConfig { axis, config });
        }
        rig
    }

    /// A controller started from `storage` (handshake done on a serial session).
    pub fn boot(
        storage: RamStorage,
        mounts: impl IntoIterator<Item = MountModel>,
        axes: u8,
    ) -> Self {
        let mut rig = Self {
            controller: Controller::new(board(axes), storage, 1_000, &mut SimRng::new(7)),
            driver: TimedDriver {
                sim: SimDriver::new(mounts),
                now: 1_000,
                steps: Vec::new(),
                power: Vec::new(),
            },
            session: Session::new(LinkKind::Serial),
            rng: SimRng::new(42),
            now: 1_000,
            notes: Vec::new(),
            next_id: 1000,
        };
        let hello = rig.send(Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        });
        assert!(matches!(hello, Reply::Hello(_)), "{hello:?}");
        rig
    }

    /// Sends `command` under `id` on `session` and returns the reply.
    pub fn send_on(&mut self, session: &mut Session, id: RequestId, command: Command) -> Reply {
        let mut rng = self.rng.clone();
        let reply = self.send_drawing(session, id, command, &mut rng);
        self.rng = rng;
        reply
    }

    /// [`Self::send_on`], the controller drawing its randomness from `rng`.
    pub fn send_drawing(
        &mut self,
        session: &mut Session,
        id: RequestId,
        command: Command,
        rng: &mut dyn RngSource,
    ) -> Reply {
        let mut replies = Vec::new();
        let request = Request { id, command };
        self.controller
            .handle(session, &request, self.now, rng, &mut |m| replies.push(m));
        assert_eq!(replies.len(), 1, "one reply per request");
        match replies.pop() {
            Some(PeerMessage::Reply { id: got, reply }) => {
                assert_eq!(got, id);
                reply
            }
            other => panic!("expected a reply, got {other:?}"),
        }
    }

    pub fn send_id(&mut self, id: RequestId, command: Command) -> Reply {
        let mut session = self.session.clone();
        let reply = self.send_on(&mut session, id, command);
        self.session = session;
        reply
    }

    pub fn send(&mut self, command: Command) -> Reply {
        self.next_id += 1;
        self.send_id(RequestId(self.next_id), command)
    }

    /// Sends a command that must succeed with `Ok`.
    pub fn ok(&mut self, command: Command) {
        let reply = self.send(command);
        assert_eq!(reply, Reply::Ok);
    }

    /// Sends a command that must fail with `code`; returns the reason.
    pub fn error(&mut self, command: Command, code: ErrorCode) -> String {
        match self.send(command) {
            Reply::Error(error) if error.code == code => error.reason.to_string(),
            other => panic!("expected {code}, got {other:?}"),
        }
    }

    /// Polls once at `now`.
    pub fn poll(&mut self) {
        self.driver.now = self.now;
        let notes = &mut self.notes;
        self.controller
            .poll(self.now, &mut self.driver, &mut |m| match m {
                PeerMessage::Notify(n) => notes.push(n),
                other => panic!("poll sent {other:?}"),
            });
    }

    /// Polls at every deadline up to `until` (inclusive), then at `until`.
    pub fn run_until(&mut self, until: u64) {
        while let Some(deadline) = self.controller.next_deadline_us() {
            if deadline > until {
                break;
            }
            self.now = self.now.max(deadline);
            self.poll();
        }
        self.now = self.now.max(until);
        self.poll();
    }

    /// Polls at every deadline until nothing is due (motion over, coils released).
    pub fn settle(&mut self) {
        for _ in 0..10_000_000 {
            let Some(deadline) = self.controller.next_deadline_us() else {
                return;
            };
            self.now = self.now.max(deadline);
            self.poll();
        }
        panic!("controller never settled");
    }

    /// Lets all pending work happen, jumping time far ahead at each poll (every due step
    /// runs in one poll, as when the host's simulation advances time in big strides).
    pub fn settle_fast(&mut self) {
        for _ in 0..1000 {
            let Some(deadline) = self.controller.next_deadline_us() else {
                return;
            };
            self.now = self.now.max(deadline) + 1_000_000_000;
            self.poll();
        }
        panic!("controller never settled");
    }

    pub fn move_to(&mut self, targets: &[(u8, i32)]) -> Reply {
        self.send(Command::MoveTo {
            targets: values(targets),
        })
    }

    /// Moves and runs the move to its end; returns the reply.
    pub fn move_and_settle(&mut self, targets: &[(u8, i32)]) -> Reply {
        let reply = self.move_to(targets);
        self.settle();
        reply
    }

    pub fn status(&self) -> Status {
        self.controller.status(&self.session, self.now)
    }

    /// Every axis idle at its target: nothing moving, nothing left to do.
    pub fn all_idle_at_target(&self) -> bool {
        self.status()
            .axes
            .iter()
            .all(|a| !a.moving && a.target == a.position)
    }

    pub fn position(&self, axis: u8) -> i32 {
        self.status().axes[usize::from(axis)].position
    }

    pub fn shaft(&self, axis: u8) -> i32 {
        self.driver.sim.mount(axis).unwrap().shaft_position()
    }

    /// Steps logged for `axis`.
    pub fn steps_of(&self, axis: u8) -> Vec<Logged> {
        self.driver
            .steps
            .iter()
            .filter(|s| s.axis == axis)
            .copied()
            .collect()
    }

    /// The `MoveFinished` notifications received, in order.
    pub fn finished(&self) -> Vec<(RequestId, optalign_protocol::MoveOutcome, Vec<i32>)> {
        self.notes
            .iter()
            .filter_map(|n| match n {
                Notification::MoveFinished {
                    request,
                    outcome,
                    positions,
                } => Some((*request, *outcome, positions.to_vec())),
                Notification::Fault { .. } => None,
            })
            .collect()
    }
}

pub fn values(targets: &[(u8, i32)]) -> heapless::Vec<AxisValue, { optalign_protocol::MAX_AXES }> {
    targets
        .iter()
        .map(|&(axis, steps)| AxisValue { axis, steps })
        .collect()
}
