//! Proptest strategies for every protocol message, shared by the protocol test suites.

use heapless::{String, Vec};
use optalign_protocol::*;
use proptest::prelude::*;

pub fn axis_values() -> impl Strategy<Value = Vec<AxisValue, MAX_AXES>> {
    prop::collection::vec((any::<u8>(), any::<i32>()), 0..=MAX_AXES).prop_map(|v| {
        v.into_iter()
            .map(|(axis, steps)| AxisValue { axis, steps })
            .collect()
    })
}

pub fn text<const N: usize>() -> impl Strategy<Value = String<N>> {
    prop::collection::vec(any::<char>(), 0..N / 4).prop_map(|chars| {
        let mut s = String::new();
        for c in chars {
            if s.push(c).is_err() {
                break;
            }
        }
        s
    })
}

pub fn limits() -> impl Strategy<Value = SoftLimits> {
    (any::<i32>(), any::<i32>()).prop_map(|(min, max)| SoftLimits { min, max })
}

pub fn config() -> impl Strategy<Value = AxisConfig> {
    (
        any::<u32>(),
        any::<u32>(),
        any::<u16>(),
        prop_oneof![
            Just(BacklashMode::Off),
            Just(BacklashMode::OneSided),
            Just(BacklashMode::TakeUp)
        ],
        prop_oneof![Just(Approach::Positive), Just(Approach::Negative)],
        any::<u16>(),
        limits(),
        any::<bool>(),
        any::<u32>(),
        prop_oneof![
            Just(DriverKind::UnipolarHalfStep),
            Just(DriverKind::StepDir)
        ],
    )
        .prop_map(
            |(
                max_speed,
                acceleration,
                backlash,
                backlash_mode,
                approach,
                overshoot_margin,
                limits,
                invert,
                idle_power_down_ms,
                driver,
            )| AxisConfig {
                max_speed,
                acceleration,
                backlash,
                backlash_mode,
                approach,
                overshoot_margin,
                limits,
                invert,
                idle_power_down_ms,
                driver,
            },
        )
}

pub fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        any::<u16>().prop_map(|protocol_version| Command::Hello { protocol_version }),
        Just(Command::Status),
        axis_values().prop_map(|targets| Command::MoveTo { targets }),
        axis_values().prop_map(|deltas| Command::MoveBy { deltas }),
        Just(Command::Stop),
        Just(Command::EmergencyStop),
        (any::<u8>(), any::<i32>())
            .prop_map(|(axis, position)| Command::SetPosition { axis, position }),
        any::<u8>().prop_map(|axis| Command::GetConfig { axis }),
        (any::<u8>(), config()).prop_map(|(axis, config)| Command::SetConfig { axis, config }),
        Just(Command::SaveConfig),
        (text::<32>(), text::<64>())
            .prop_map(|(ssid, passphrase)| Command::ProvisionWifi { ssid, passphrase }),
        any::<[u8; 32]>().prop_map(|key| Command::SetKey { key }),
        Just(Command::AuthChallenge),
        (any::<[u8; 32]>(), any::<[u8; 16]>())
            .prop_map(|(tag, client_nonce)| Command::AuthResponse { tag, client_nonce }),
        Just(Command::ClearEmergency),
        any::<u32>().prop_map(|request| Command::MoveResult {
            request: RequestId(request)
        }),
        axis_values().prop_map(|deltas| Command::RecoveryMoveBy { deltas }),
    ]
}

pub fn request() -> impl Strategy<Value = Request> {
    (any::<u32>(), command()).prop_map(|(id, command)| Request {
        id: RequestId(id),
        command,
    })
}

pub fn axis_status() -> impl Strategy<Value = AxisStatus> {
    (
        any::<(i32, i32, i32, bool, bool)>(),
        prop_oneof![
            Just(Direction::Idle),
            Just(Direction::Positive),
            Just(Direction::Negative)
        ],
        prop_oneof![
            Just(Slack::Unknown),
            Just(Slack::TakenUpPositive),
            Just(Slack::TakenUpNegative)
        ],
        limits(),
        any::<(u8, u32)>(),
    )
        .prop_map(
            |(
                (position, motor_steps, target, moving, powered),
                direction,
                slack,
                limits,
                (faults, underruns),
            )| AxisStatus {
                position,
                motor_steps,
                target,
                moving,
                direction,
                slack,
                limits,
                faults: Faults(faults),
                powered,
                underruns,
            },
        )
}

pub fn error_reply() -> impl Strategy<Value = ErrorReply> {
    (any::<u16>(), text::<96>()).prop_map(|(code, reason)| ErrorReply {
        code: ErrorCode(code),
        reason,
    })
}

pub fn reply() -> impl Strategy<Value = Reply> {
    prop_oneof![
        (
            any::<(u16, u64, u8, u32, u64)>(),
            text::<16>(),
            text::<24>()
        )
            .prop_map(
                |(
                    (protocol_version, board_id, axes, caps, boot_nonce),
                    firmware_version,
                    board,
                )| {
                    Reply::Hello(Identity {
                        protocol_version,
                        firmware_version,
                        board,
                        board_id,
                        axes,
                        capabilities: Capabilities(caps),
                        boot_nonce,
                    })
                }
            ),
        (
            prop::collection::vec(axis_status(), 0..=MAX_AXES),
            any::<(bool, bool, bool, bool, u64)>(),
            prop_oneof![
                Just(BootRecord::NoRecordYet),
                Just(BootRecord::Restored),
                Just(BootRecord::Unreadable),
                Just(BootRecord::InterruptedMove),
            ],
            (
                any::<(bool, u32, u32, u32)>(),
                prop_oneof![
                    Just(None),
                    Just(Some(StorageFailure::Write)),
                    Just(Some(StorageFailure::ReadBack)),
                ]
            )
        )
            .prop_map(
                |(
                    axes,
                    (trusted_link, authenticated, key_provisioned, emergency_stopped, uptime_ms),
                    boot,
                    (
                        (unsaved, failed_writes, failed_authentications, rejected_frames),
                        last_failure,
                    ),
                )| {
                    Reply::Status(Status {
                        axes: axes.into_iter().collect(),
                        session: SessionState {
                            trusted_link,
                            authenticated,
                            key_provisioned,
                        },
                        emergency_stopped,
                        uptime_ms,
                        boot,
                        storage: StorageHealth {
                            unsaved,
                            failed_writes,
                            last_failure,
                        },
                        security: SecurityCounters {
                            failed_authentications,
                            rejected_frames,
                        },
                    })
                }
            ),
        any::<u32>().prop_map(|duration_ms| Reply::MoveStarted { duration_ms }),
        Just(Reply::Ok),
        config().prop_map(Reply::Config),
        any::<[u8; 16]>().prop_map(|nonce| Reply::Challenge { nonce }),
        error_reply().prop_map(Reply::Error),
        (
            error_reply(),
            prop_oneof![
                any::<u16>().prop_map(RefusalDetail::ProtocolVersion),
                any::<u32>().prop_map(RefusalDetail::RetryAfterMs),
            ]
        )
            .prop_map(|(error, detail)| Reply::Refused { error, detail }),
        Just(Reply::MoveResult(MoveResult::Unknown)),
        Just(Reply::MoveResult(MoveResult::InProgress)),
        (
            prop_oneof![
                Just(MoveOutcome::Completed),
                Just(MoveOutcome::Stopped),
                Just(MoveOutcome::EmergencyStopped),
                Just(MoveOutcome::Faulted),
            ],
            prop::collection::vec(any::<i32>(), 0..=MAX_AXES)
        )
            .prop_map(
                |(outcome, positions)| Reply::MoveResult(MoveResult::Finished {
                    outcome,
                    positions: positions.into_iter().collect(),
                })
            ),
    ]
}

pub fn peer_message() -> impl Strategy<Value = PeerMessage> {
    prop_oneof![
        (any::<u32>(), reply()).prop_map(|(id, reply)| PeerMessage::Reply {
            id: RequestId(id),
            reply
        }),
        (
            any::<u32>(),
            prop::collection::vec(any::<i32>(), 0..=MAX_AXES),
            0..4u8
        )
            .prop_map(|(id, positions, outcome)| {
                PeerMessage::Notify(Notification::MoveFinished {
                    request: RequestId(id),
                    outcome: [
                        MoveOutcome::Completed,
                        MoveOutcome::Stopped,
                        MoveOutcome::EmergencyStopped,
                        MoveOutcome::Faulted,
                    ][outcome as usize],
                    positions: positions.into_iter().collect(),
                })
            }),
        (any::<u8>(), any::<u8>()).prop_map(|(axis, faults)| PeerMessage::Notify(
            Notification::Fault {
                axis,
                faults: Faults(faults)
            }
        )),
        error_reply().prop_map(PeerMessage::LinkError),
    ]
}
