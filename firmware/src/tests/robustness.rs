//! Random request sequences from three sessions (serial, network with and without the
//! key): the controller never panics and keeps its invariants. 192 sequences by default,
//! `OPTALIGN_FUZZ_CASES=N` for N.

use optalign_protocol::{
    Approach, AxisConfig, AxisValue, BacklashMode, Command, DriverKind, FrameError, MAX_AXES,
    PeerMessage, Reply, RequestId, SoftLimits,
};
use std::cell::Cell;

use optalign_protocol::PROTOCOL_VERSION;
use optalign_protocol::auth::challenge_tag;
use proptest::prelude::*;
use proptest::test_runner::TestRunner;

use super::rig::Rig;
use crate::{LinkKind, Session};

fn axis_values() -> impl Strategy<Value = heapless::Vec<AxisValue, MAX_AXES>> {
    let value = (
        prop_oneof![19 => 0u8..3, 1 => any::<u8>()],
        prop_oneof![6 => -3000i32..3000, 1 => any::<i32>()],
    )
        .prop_map(|(axis, steps)| AxisValue { axis, steps });
    // Mostly one to three axes, sometimes a full list.
    let len = prop_oneof![9 => 0..4usize, 1 => 0..=MAX_AXES];
    (prop::collection::vec(value, MAX_AXES), len)
        .prop_map(|(values, len)| values.into_iter().take(len).collect())
}

pub(super) fn axis_config() -> impl Strategy<Value = AxisConfig> {
    (
        (
            prop_oneof![1u32..20_000, any::<u32>()],
            prop_oneof![10u32..500_000, any::<u32>()],
        ),
        (
            0u16..100,
            prop_oneof![
                Just(BacklashMode::Off),
                Just(BacklashMode::OneSided),
                Just(BacklashMode::TakeUp)
            ],
        ),
        (
            any::<bool>(),
            0u16..50,
            prop_oneof![(-5000i32..0, 0i32..5000), (any::<i32>(), any::<i32>())],
        ),
        (any::<bool>(), 0u32..2000, any::<bool>()),
    )
        .prop_map(
            |(
                (max_speed, acceleration),
                (backlash, backlash_mode),
                (positive, overshoot_margin, (min, max)),
                (invert, idle_power_down_ms, step_dir),
            )| AxisConfig {
                max_speed,
                acceleration,
                backlash,
                backlash_mode,
                approach: if positive {
                    Approach::Positive
                } else {
                    Approach::Negative
                },
                overshoot_margin,
                limits: SoftLimits { min, max },
                invert,
                idle_power_down_ms,
                driver: if step_dir {
                    DriverKind::StepDir
                } else {
                    DriverKind::UnipolarHalfStep
                },
            },
        )
}

pub(super) fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        1 => prop_oneof![4 => Just(PROTOCOL_VERSION), 1 => any::<u16>()]
            .prop_map(|protocol_version| Command::Hello { protocol_version }),
        1 => Just(Command::Status),
        4 => axis_values().prop_map(|targets| Command::MoveTo { targets }),
        4 => axis_values().prop_map(|deltas| Command::MoveBy { deltas }),
        1 => axis_values().prop_map(|deltas| Command::RecoveryMoveBy { deltas }),
        2 => Just(Command::Stop),
        1 => Just(Command::EmergencyStop),
        2 => Just(Command::ClearEmergency),
        1 => (0u32..12).prop_map(|request| Command::MoveResult { request: RequestId(request) }),
        1 => (0u8..4, prop_oneof![-3000i32..3000, any::<i32>()])
            .prop_map(|(axis, position)| Command::SetPosition { axis, position }),
        1 => (0u8..4).prop_map(|axis| Command::GetConfig { axis }),
        1 => (0u8..4, axis_config()).prop_map(|(axis, config)| Command::SetConfig { axis, config }),
        1 => Just(Command::SaveConfig),
        1 => ("[a-z]{0,32}", "[ -~]{0,64}").prop_map(|(ssid, passphrase)| Command::ProvisionWifi {
            ssid: ssid.as_str().try_into().unwrap(),
            passphrase: passphrase.as_str().try_into().unwrap(),
        }),
        1 => (0u8..3).prop_map(|key| Command::SetKey { key: [key; 32] }),
        1 => Just(Command::AuthChallenge),
        1 => (any::<[u8; 32]>(), any::<[u8; 16]>())
            .prop_map(|(tag, client_nonce)| Command::AuthResponse { tag, client_nonce }),
    ]
}

#[derive(Clone, Debug)]
enum Event {
    Request {
        session: usize,
        id: u32,
        command: Command,
    },
    /// Answers a challenge with the right key (if one of the test keys is set).
    Authenticate(usize),
    Advance(u64),
    LinkError,
    TornWrite(usize),
    Reboot,
}

fn event() -> impl Strategy<Value = Event> {
    prop_oneof![
        8 => (prop_oneof![Just(0usize), 1usize..3], 0u32..12, command()).prop_map(|(session, id, command)| Event::Request { session, id, command }),
        1 => (1usize..3).prop_map(Event::Authenticate),
        4 => prop_oneof![0u64..50_000, 0u64..5_000_000, Just(u64::MAX / 4)].prop_map(Event::Advance),
        1 => Just(Event::LinkError),
        1 => (0usize..200).prop_map(Event::TornWrite),
        1 => Just(Event::Reboot),
    ]
}

#[test]
fn random_requests_never_panic() {
    let moves = Cell::new(0);
    let mut runner = TestRunner::new(ProptestConfig {
        cases: super::hostile::fuzz_cases(192),
        failure_persistence: None,
        ..ProptestConfig::default()
    });
    let result = runner.run(&prop::collection::vec(event(), 1..100), |events| {
        let mut rig = Rig::new(
            3,
            5,
            AxisConfig {
                backlash: 5,
                ..crate::config::default_config(optalign_protocol::Capabilities(
                    super::rig::CAPABILITIES,
                ))
            },
        );
        let open = |rig: &mut Rig, link| {
            let mut session = Session::new(link);
            let hello = Command::Hello {
                protocol_version: PROTOCOL_VERSION,
            };
            rig.send_on(&mut session, RequestId(u32::MAX), hello);
            session
        };
        let links = [LinkKind::Serial, LinkKind::Network, LinkKind::Network];
        rig.ok(Command::SetKey { key: [1; 32] });
        let mut sessions = links.map(|link| open(&mut rig, link));
        let mut started = 0;
        for event in events {
            match event {
                Event::Request {
                    session,
                    id,
                    command,
                } => {
                    let mut s = sessions[session].clone();
                    let reply = rig.send_on(&mut s, RequestId(id), command);
                    sessions[session] = s;
                    started += usize::from(matches!(reply, Reply::MoveStarted { .. }));
                    if let Reply::Status(status) = reply {
                        prop_assert_eq!(status.axes.len(), 3);
                    }
                }
                Event::Authenticate(session) => {
                    // With the key in force, if any (a wrong one would only start a backoff).
                    let mut s = sessions[session].clone();
                    if let (Some(key), Reply::Challenge { nonce }) = (
                        rig.controller.key,
                        rig.send_on(&mut s, RequestId(7), Command::AuthChallenge),
                    ) {
                        let client_nonce = [0x44; 16];
                        let tag = challenge_tag(&key, &nonce, &client_nonce);
                        rig.send_on(
                            &mut s,
                            RequestId(8),
                            Command::AuthResponse { tag, client_nonce },
                        );
                    }
                    sessions[session] = s;
                }
                Event::Advance(dt) => {
                    rig.run_until(rig.now.saturating_add(dt).min(u64::MAX / 2));
                }
                Event::LinkError => {
                    let mut out = Vec::new();
                    rig.controller
                        .link_error(FrameError::Malformed, &mut |m| out.push(m));
                    prop_assert!(matches!(out.as_slice(), [PeerMessage::LinkError(_)]));
                }
                Event::TornWrite(bytes) => rig.controller.storage_mut().tear_next_write(bytes),
                Event::Reboot => {
                    let storage = rig.controller.storage().power_cycled();
                    rig = Rig::boot(storage, (0..3).map(|_| crate::sim::MountModel::new(5)), 3);
                    sessions = links.map(|link| open(&mut rig, link));
                }
            }
            // After a poll nothing is due any more (a board would spin otherwise).
            rig.poll();
            if let Some(deadline) = rig.controller.next_deadline_us() {
                prop_assert!(deadline > rig.now, "deadline {} at {}", deadline, rig.now);
            }
        }
        moves.set(moves.get() + started);
        rig.settle_fast();
        prop_assert!(!rig.controller.is_moving());
        prop_assert_eq!(rig.driver.sim.unpowered_steps(), 0);
        prop_assert!(rig.all_idle_at_target());
        Ok(())
    });
    if let Err(failure) = result {
        panic!("{failure}");
    }
    // The sequences do reach the motion code.
    assert!(moves.get() > 300, "only {} moves started", moves.get());
}
