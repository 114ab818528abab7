//! Every message of the protocol: requests from the host, and replies and notifications
//! from the controller.
//!
//! Encoding rule: postcard encodes enum variants by position, so variants and fields are
//! only ever appended, and any change to an existing layout bumps
//! [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION). `Command::Hello` is variant 0 and its
//! layout is frozen, and a peer answers a `Hello` of another version with an error reply
//! (`Reply::Error` or, from version 5 on, `Reply::Refused` with
//! [`RefusalDetail::ProtocolVersion`]: frozen too) rather than an [`Identity`], so that two
//! different versions can always tell each other apart.

use heapless::{String, Vec};
use serde::{Deserialize, Serialize};

use crate::error::ErrorReply;
use crate::limits::{KEY_LEN, MAX_AXES, NONCE_LEN, PASSPHRASE_LEN, SSID_LEN};

/// Identifies a request. Hosts pick a random start and count up, so a retransmission
/// (same id) can be recognised by the peer and answered without executing it twice.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct RequestId(pub u32);

/// A request from the host to a controller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Request {
    pub id: RequestId,
    pub command: Command,
}

/// What a request asks for.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Command {
    /// Opens a session: must be the first request on every connection.
    Hello { protocol_version: u16 },
    /// Reads the state of every axis. Allowed without authentication.
    Status,
    /// Moves the listed axes to absolute logical positions, coordinated so that all
    /// finish together. Replied to at once with [`Reply::MoveStarted`]; completion comes
    /// as [`Notification::MoveFinished`] carrying this request's id.
    MoveTo { targets: Vec<AxisValue, MAX_AXES> },
    /// Like `MoveTo` with targets relative to the current logical positions.
    MoveBy { deltas: Vec<AxisValue, MAX_AXES> },
    /// Decelerates every axis to a stop.
    Stop,
    /// Stops every axis at once, switches the coils off and latches motion off until
    /// [`Command::ClearEmergency`]. Allowed without authentication.
    EmergencyStop,
    /// Declares the current logical position of an idle axis to be `position`.
    SetPosition { axis: u8, position: i32 },
    /// Reads one axis's configuration.
    GetConfig { axis: u8 },
    /// Replaces one axis's configuration (takes effect at once; persisted by `SaveConfig`).
    SetConfig { axis: u8, config: AxisConfig },
    /// Persists configuration and positions.
    SaveConfig,
    /// Stores Wi-Fi credentials. Accepted on the serial link only.
    ProvisionWifi {
        ssid: String<SSID_LEN>,
        passphrase: String<PASSPHRASE_LEN>,
    },
    /// Stores the pre-shared access key. Accepted on the serial link only.
    SetKey { key: [u8; KEY_LEN] },
    /// Asks for a fresh challenge nonce.
    AuthChallenge,
    /// Answers the latest challenge: `client_nonce` is drawn by the client, `tag` is
    /// HMAC-SHA256(key, context || nonce || client_nonce) (see [`crate::auth`]). When it
    /// verifies, every later frame of the session is sealed ([`crate::seal`]), the `Ok`
    /// reply included.
    AuthResponse {
        tag: [u8; KEY_LEN],
        client_nonce: [u8; NONCE_LEN],
    },
    /// Releases the emergency latch so that moves are accepted again (coils stay off until
    /// the next move).
    ClearEmergency,
    /// Asks how the move started by `request` ended, for a host that missed its
    /// [`Notification::MoveFinished`]. Allowed without authentication.
    MoveResult { request: RequestId },
    /// Recovery mode: like `MoveBy`, and also accepted on axes flagged
    /// [`Faults::POSITION_LOST`], which stay flagged (only `SetPosition` declares where an
    /// axis is). On such an axis the soft limits cannot be checked, since the position they
    /// bound is unknown: each delta must instead be no larger than the width of the axis's
    /// soft limits. For finding a lost position again from the camera (`optalign rezero`);
    /// there is no absolute move on a lost axis.
    RecoveryMoveBy { deltas: Vec<AxisValue, MAX_AXES> },
}

impl Command {
    /// The command's name, for messages.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Hello { .. } => "Hello",
            Self::Status => "Status",
            Self::MoveTo { .. } => "MoveTo",
            Self::MoveBy { .. } => "MoveBy",
            Self::Stop => "Stop",
            Self::EmergencyStop => "EmergencyStop",
            Self::SetPosition { .. } => "SetPosition",
            Self::GetConfig { .. } => "GetConfig",
            Self::SetConfig { .. } => "SetConfig",
            Self::SaveConfig => "SaveConfig",
            Self::ProvisionWifi { .. } => "ProvisionWifi",
            Self::SetKey { .. } => "SetKey",
            Self::AuthChallenge => "AuthChallenge",
            Self::AuthResponse { .. } => "AuthResponse",
            Self::ClearEmergency => "ClearEmergency",
            Self::MoveResult { .. } => "MoveResult",
            Self::RecoveryMoveBy { .. } => "RecoveryMoveBy",
        }
    }

    /// What the command needs from the session before it may run.
    pub fn access(&self) -> Access {
        match self {
            Self::Hello { .. }
            | Self::Status
            | Self::GetConfig { .. }
            | Self::AuthChallenge
            | Self::AuthResponse { .. }
            | Self::EmergencyStop
            | Self::MoveResult { .. } => Access::Open,
            Self::MoveTo { .. }
            | Self::MoveBy { .. }
            | Self::Stop
            | Self::SetPosition { .. }
            | Self::SetConfig { .. }
            | Self::SaveConfig
            | Self::ClearEmergency
            | Self::RecoveryMoveBy { .. } => Access::Control,
            Self::ProvisionWifi { .. } | Self::SetKey { .. } => Access::SerialOnly,
        }
    }

    /// Whether executing the command twice would differ from executing it once, so that
    /// a retransmission must be answered from the reply cache.
    pub fn has_effect(&self) -> bool {
        !matches!(
            self,
            Self::Status | Self::GetConfig { .. } | Self::Hello { .. } | Self::MoveResult { .. }
        )
    }
}

/// The access a command requires.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Anyone who completed the handshake.
    Open,
    /// The serial link, or an authenticated network session.
    Control,
    /// The serial link only (physical access).
    SerialOnly,
}

/// A value for one axis: a target or a delta in steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct AxisValue {
    pub axis: u8,
    pub steps: i32,
}

/// A message from a controller to the host.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum PeerMessage {
    /// The answer to the request with this id.
    Reply { id: RequestId, reply: Reply },
    /// Something happened that the host did not ask about just now.
    Notify(Notification),
    /// A frame could not be read (bad stuffing, CRC or size, or not a request); no
    /// request id is known, and nothing was executed.
    LinkError(ErrorReply),
}

/// The answer to a request.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Reply {
    /// Handshake accepted; who the peer is.
    Hello(Identity),
    Status(Status),
    /// Motion planned and started; `duration_ms` is the planned travel time.
    MoveStarted {
        duration_ms: u32,
    },
    /// Done, nothing to report.
    Ok,
    Config(AxisConfig),
    Challenge {
        nonce: [u8; NONCE_LEN],
    },
    Error(ErrorReply),
    /// What became of a move (the answer to [`Command::MoveResult`]).
    MoveResult(MoveResult),
    /// An error with a field a program acts on, where reading the reason would be guessing
    /// (version 5): the wait of `auth-backoff`, the controller's version on
    /// `version-mismatch`. Its layout and [`RefusalDetail::ProtocolVersion`] are frozen like
    /// `Error`'s.
    Refused {
        error: ErrorReply,
        detail: RefusalDetail,
    },
}

impl Reply {
    /// The error this reply carries, plain or with its detail.
    pub fn error(&self) -> Option<&ErrorReply> {
        match self {
            Self::Error(error) | Self::Refused { error, .. } => Some(error),
            _ => None,
        }
    }
}

/// What a [`Reply::Refused`] tells beyond its error code. Variants are only appended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum RefusalDetail {
    /// The controller speaks this protocol version (with `version-mismatch`).
    ProtocolVersion(u16),
    /// Try again after this many milliseconds (with `auth-backoff`).
    RetryAfterMs(u32),
}

/// What became of the move a request started, as far as the controller remembers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum MoveResult {
    /// Not among the moves this start-up of the controller remembers: never accepted, too
    /// long ago, or started before a restart.
    Unknown,
    /// Accepted and not ended yet (running, or waiting for the motion before it to stop).
    InProgress,
    /// Ended: how, and the logical positions of all axes then (as in `MoveFinished`).
    Finished {
        outcome: MoveOutcome,
        positions: Vec<i32, MAX_AXES>,
    },
}

/// Who a controller is, and which start-up of it answers.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Identity {
    pub protocol_version: u16,
    pub firmware_version: String<16>,
    pub board: String<24>,
    pub board_id: u64,
    pub axes: u8,
    pub capabilities: Capabilities,
    /// Drawn at random at every start-up: another value means the controller restarted
    /// (and forgot its reply memory) since the last handshake.
    pub boot_nonce: u64,
}

/// Feature bits a controller advertises.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Capabilities(pub u32);

impl Capabilities {
    pub const UNIPOLAR_HALF_STEP: u32 = 1 << 0;
    pub const STEP_DIR: u32 = 1 << 1;
    pub const PERSISTENCE: u32 = 1 << 2;
    pub const WIFI: u32 = 1 << 3;
    pub const SERIAL: u32 = 1 << 4;
    pub const SIMULATED: u32 = 1 << 5;

    pub fn has(self, bit: u32) -> bool {
        self.0 & bit == bit
    }
}

/// The state of a controller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Status {
    pub axes: Vec<AxisStatus, MAX_AXES>,
    pub session: SessionState,
    /// Latched by an emergency stop; while set, moves are refused with
    /// `emergency-stopped` until [`Command::ClearEmergency`].
    pub emergency_stopped: bool,
    pub uptime_ms: u64,
    /// What the controller found in storage when it started.
    pub boot: BootRecord,
    /// Whether everything saved is durably in storage, and how writes failed.
    pub storage: StorageHealth,
    /// Network authentication and sealed-frame failures since start-up.
    pub security: SecurityCounters,
}

/// What a controller counts of failed network access since start-up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SecurityCounters {
    /// Challenge responses that did not verify (a wrong key, or guessing).
    pub failed_authentications: u32,
    /// Frames dropped on authenticated sessions: a MAC that did not verify, a replayed
    /// counter, or no MAC at all.
    pub rejected_frames: u32,
}

/// The state of a controller's persistent writes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StorageHealth {
    /// Changes not yet durably stored: a write waiting for motion to stop, or one that
    /// failed (the next save, or the record written when motion stops, tries again).
    pub unsaved: bool,
    /// Writes that failed (the write itself, or its read-back) since start-up.
    pub failed_writes: u32,
    /// How the latest failed write failed.
    pub last_failure: Option<StorageFailure>,
}

/// How a write to persistent storage failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum StorageFailure {
    /// The device reported an error while erasing or programming.
    Write,
    /// The write reported success, but reading it back gave other bytes.
    ReadBack,
}

/// What a controller found in storage at start-up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum BootRecord {
    /// Nothing was ever saved (a fresh board): positions start at 0 by assumption.
    NoRecordYet,
    /// Positions and configuration came back from the saved record.
    Restored,
    /// The saved record could not be read: every axis is flagged `POSITION_LOST`.
    Unreadable,
    /// The controller was reset while axes were moving (or before a lost position was
    /// declared again): those axes are flagged `POSITION_LOST`.
    InterruptedMove,
}

/// What this connection may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SessionState {
    pub trusted_link: bool,
    pub authenticated: bool,
    pub key_provisioned: bool,
}

/// The state of one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct AxisStatus {
    /// Logical position: where the user asked the axis to be; backlash compensation is
    /// never mixed into it.
    pub position: i32,
    /// Motor step counter: every step the driver made, compensation steps included.
    pub motor_steps: i32,
    /// Target of the motion in progress (equals `position` when idle).
    pub target: i32,
    pub moving: bool,
    pub direction: Direction,
    pub slack: Slack,
    pub limits: SoftLimits,
    pub faults: Faults,
    /// Whether the coils are energised.
    pub powered: bool,
    /// Times the axis's step engine ran out of words in the middle of a move since
    /// start-up (version 5): the steps after each came late, none was lost. 0 on a healthy
    /// controller; the simulated peer has no step engine and reports 0.
    pub underruns: u32,
}

/// Direction of travel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Direction {
    Idle,
    Positive,
    Negative,
}

/// Which side of the gear train's dead band the motor last pushed against.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Slack {
    /// Not known (after power-up, before the first move).
    Unknown,
    /// The last travel was positive: slack taken up on the positive side.
    TakenUpPositive,
    /// The last travel was negative.
    TakenUpNegative,
}

/// Inclusive soft limits of an axis, in logical steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SoftLimits {
    pub min: i32,
    pub max: i32,
}

impl SoftLimits {
    pub fn contains(self, position: i32) -> bool {
        (self.min..=self.max).contains(&position)
    }
}

/// Fault bits of an axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Faults(pub u8);

impl Faults {
    /// Stopped by an emergency stop; position may be off by a step of the last phase.
    pub const EMERGENCY_STOP: u8 = 1 << 0;
    /// The driver reported a fault (STEP/DIR drivers with a fault line).
    pub const DRIVER: u8 = 1 << 1;
    /// The position is not known: the controller was reset while the axis moved, or its
    /// record was unreadable. Moves of the axis are refused with `axis-fault` until
    /// `SetPosition` declares where it is.
    pub const POSITION_LOST: u8 = 1 << 2;

    pub fn has(self, bit: u8) -> bool {
        self.0 & bit == bit
    }

    pub fn is_clear(self) -> bool {
        self.0 == 0
    }
}

/// Per-axis configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct AxisConfig {
    /// Cruise speed, steps per second.
    pub max_speed: u32,
    /// Acceleration and deceleration, steps per second squared.
    pub acceleration: u32,
    /// Gear-train dead band to compensate, whole steps.
    pub backlash: u16,
    pub backlash_mode: BacklashMode,
    /// The direction every compensated move ends travelling in.
    pub approach: Approach,
    /// Extra steps beyond the backlash when overshooting for a one-sided approach.
    pub overshoot_margin: u16,
    pub limits: SoftLimits,
    /// Reverses the motor's sense of direction.
    pub invert: bool,
    /// Coils are switched off this long after motion ends; 0 keeps them powered.
    pub idle_power_down_ms: u32,
    pub driver: DriverKind,
}

/// How backlash is compensated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum BacklashMode {
    /// No compensation.
    Off,
    /// Every move ends travelling in the preferred direction: a move arriving from the
    /// other side overshoots by backlash + margin and comes back.
    OneSided,
    /// The backlash steps are inserted whenever the direction of travel reverses.
    TakeUp,
}

/// The preferred direction of final approach.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Approach {
    Positive,
    Negative,
}

/// The kind of motor driver on an axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum DriverKind {
    /// A unipolar stepper (28BYJ-48 class) through a ULN2003, 8-phase half stepping.
    UnipolarHalfStep,
    /// A driver with STEP and DIR inputs.
    StepDir,
}

/// Something the host did not ask about just now.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Notification {
    /// The motion started by `request` has ended.
    MoveFinished {
        request: RequestId,
        outcome: MoveOutcome,
        positions: Vec<i32, MAX_AXES>,
    },
    /// An axis entered a fault state.
    Fault { axis: u8, faults: Faults },
}

/// How a motion ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum MoveOutcome {
    /// Every axis reached its target.
    Completed,
    /// Decelerated to a stop before the target by a `Stop` request.
    Stopped,
    /// Cut short by an emergency stop.
    EmergencyStopped,
    /// Ended by a fault.
    Faulted,
}
