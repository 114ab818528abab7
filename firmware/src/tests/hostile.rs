//! Hostile input behind valid checksums: frames whose CRC checks out around mutated or
//! random payloads, fed through the decoder into the controller as the board's link does;
//! and record images (both slots, and the mark) that are torn, random, or damaged and then
//! resealed with a correct CRC, decoded and booted from.
//!
//! Cases per property: 1,000 by default; `OPTALIGN_FUZZ_CASES=N` runs N instead.

use std::cell::Cell;

use optalign_protocol::limits::KEY_LEN;
use optalign_protocol::{
    AxisConfig, BootRecord, Capabilities, Command, ErrorCode, FrameDecoder, MAX_AXES, MAX_FRAME,
    MAX_PAYLOAD, PROTOCOL_VERSION, PeerMessage, Reply, Request, RequestId, Slack, encode_frame,
};
use proptest::prelude::*;
use proptest::test_runner::TestRunner;
use serde::ser::{Serialize, SerializeTuple, Serializer};

use super::dispatch::network;
use super::rig::{CAPABILITIES, Rig, values};
use super::robustness::{axis_config, command};
use crate::mark::{self, MARK_LEN};
use crate::record::{self, AxisRecord, RECORD_LEN, Record};
use crate::sim::MountModel;
use crate::{RamStorage, Session};

/// `OPTALIGN_FUZZ_CASES` cases per property, `default` without it.
pub(super) fn fuzz_cases(default: u32) -> u32 {
    match std::env::var("OPTALIGN_FUZZ_CASES") {
        Ok(text) => text
            .parse()
            .unwrap_or_else(|_| panic!("OPTALIGN_FUZZ_CASES must be a whole number, got {text:?}")),
        Err(_) => default,
    }
}

fn fuzz_runner() -> TestRunner {
    let cases = fuzz_cases(1_000);
    TestRunner::new(ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    })
}

fn passed<T: core::fmt::Debug>(result: Result<(), proptest::test_runner::TestError<T>>) {
    if let Err(failure) = result {
        panic!("{failure}");
    }
}

/// Bytes serialised as they are (a postcard tuple of `u8` has no length prefix), so that
/// `encode_frame` seals any payload with a valid CRC.
struct RawPayload<'a>(&'a [u8]);

impl Serialize for RawPayload<'_> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut tuple = serializer.serialize_tuple(self.0.len())?;
        for byte in self.0 {
            tuple.serialize_element(byte)?;
        }
        tuple.end()
    }
}

fn sealed(payload: &[u8]) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = encode_frame(&RawPayload(payload), &mut out).expect("payload fits a frame");
    out[..len].to_vec()
}

fn frame_of(request: &Request) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = encode_frame(request, &mut out).expect("every request fits a frame");
    out[..len].to_vec()
}

/// The postcard encoding of `value`.
fn encoded<T: Serialize>(value: &T) -> Vec<u8> {
    let mut buf = [0u8; RECORD_LEN];
    postcard::to_slice(value, &mut buf)
        .expect("every value encodes in a slot")
        .to_vec()
}

/// Damages `payload`: `(kind, position, value)` triples applied in turn.
fn damaged(mut payload: Vec<u8>, damage: &[(u8, prop::sample::Index, u8)]) -> Vec<u8> {
    for &(kind, at, value) in damage {
        let len = payload.len();
        match kind % 5 {
            0 => payload.truncate(at.index(len.max(1))),
            1 if len > 0 => payload[at.index(len)] ^= 1 << (value % 8),
            2 if len > 0 => payload[at.index(len)] = value,
            3 => {
                let at = at.index(len + 1);
                payload.splice(
                    at..at,
                    std::iter::repeat_n(0xFF, usize::from(value % 8) + 1),
                );
            }
            _ => payload.push(value),
        }
    }
    payload.truncate(MAX_PAYLOAD);
    payload
}

fn damage() -> impl Strategy<Value = Vec<(u8, prop::sample::Index, u8)>> {
    prop::collection::vec(any::<(u8, prop::sample::Index, u8)>(), 1..4)
}

/// One frame of hostile traffic.
#[derive(Clone, Debug)]
enum Hostile {
    /// A payload behind a valid CRC: a damaged request, or random bytes.
    Sealed(Vec<u8>),
    /// Bytes as they come (mostly bad CRC or stuffing, with stray delimiters).
    Raw(Vec<u8>),
}

fn hostile() -> impl Strategy<Value = Hostile> {
    let request = (any::<u32>(), command()).prop_map(|(id, command)| {
        encoded(&Request {
            id: RequestId(id),
            command,
        })
    });
    prop_oneof![
        6 => (request, damage()).prop_map(|(payload, damage): (Vec<u8>, Vec<_>)| Hostile::Sealed(damaged(payload, &damage))),
        2 => prop::collection::vec(any::<u8>(), 0..MAX_PAYLOAD).prop_map(Hostile::Sealed),
        1 => prop::collection::vec(any::<u8>(), 0..600).prop_map(Hostile::Raw),
    ]
}

fn hostile_bytes(traffic: &[Hostile]) -> Vec<u8> {
    let mut bytes = Vec::new();
    for frame in traffic {
        match frame {
            Hostile::Sealed(payload) => bytes.extend(sealed(payload)),
            Hostile::Raw(raw) => bytes.extend(raw),
        }
    }
    // Ends whatever half frame the raw bytes left, as a host does on connect.
    bytes.push(0);
    bytes
}

/// What the controller did with a stream of frames on one session.
#[derive(Default)]
struct Served {
    replies: Vec<(RequestId, Reply)>,
    link_errors: usize,
    decoded: usize,
}

/// Feeds `bytes` through a decoder into the controller as the board's link does: each
/// request is handled, each unreadable frame answered with exactly one `LinkError` carrying
/// its error's code, and the controller is polled after each frame.
fn serve(
    rig: &mut Rig,
    session: &mut Session,
    decoder: &mut FrameDecoder,
    bytes: &[u8],
) -> Result<Served, TestCaseError> {
    let mut frames = Vec::new();
    decoder.feed(bytes, |frame| frames.push(frame));
    let mut served = Served::default();
    for frame in frames {
        let mut out = Vec::new();
        match frame {
            Ok(request) => {
                served.decoded += 1;
                let request: Request = request;
                rig.controller
                    .handle(session, &request, rig.now, &mut rig.rng, &mut |m| {
                        out.push(m)
                    });
                match out.as_slice() {
                    [PeerMessage::Reply { id, reply }] if *id == request.id => {
                        served.replies.push((*id, reply.clone()))
                    }
                    other => prop_assert!(false, "{request:?} was answered {other:?}"),
                }
            }
            Err(error) => {
                served.link_errors += 1;
                let before = rig.controller.status(session, rig.now);
                rig.controller.link_error(error, &mut |m| out.push(m));
                match out.as_slice() {
                    [PeerMessage::LinkError(reply)] => prop_assert_eq!(reply.code, error.code()),
                    other => prop_assert!(false, "{error:?} was answered {other:?}"),
                }
                prop_assert_eq!(rig.controller.status(session, rig.now), before);
            }
        }
        rig.now += 1_000;
        rig.poll();
    }
    Ok(served)
}

fn hello(id: u32) -> Request {
    Request {
        id: RequestId(id),
        command: Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    }
}

#[test]
fn hostile_frames_from_an_unauthenticated_client_never_move_or_write_anything() {
    let decoded = Cell::new(0);
    let link_errors = Cell::new(0);
    let mut runner = fuzz_runner();
    let strategy = prop::collection::vec(hostile(), 1..40);
    let result = runner.run(&strategy, |traffic| {
        let mut rig = Rig::new(3, 5, default_config());
        rig.ok(Command::SetKey { key: [3; KEY_LEN] });
        let writes = rig.controller.storage().writes();
        let mut session = network(&mut rig);
        let mut decoder = FrameDecoder::new();
        let served = serve(
            &mut rig,
            &mut session,
            &mut decoder,
            &hostile_bytes(&traffic),
        )?;
        decoded.set(decoded.get() + served.decoded);
        link_errors.set(link_errors.get() + served.link_errors);
        for (id, reply) in &served.replies {
            prop_assert!(
                !matches!(reply, Reply::MoveStarted { .. }),
                "request {:?} started a move: {:?}",
                id,
                reply
            );
        }
        rig.settle_fast();
        prop_assert!(rig.driver.steps.is_empty(), "garbage made a motor step");
        prop_assert_eq!(
            rig.controller.storage().writes(),
            writes,
            "garbage wrote storage"
        );
        prop_assert!(!rig.status().axes.iter().any(|a| a.powered));

        // Valid requests after the garbage are understood on the same connection (the
        // handshake again first: a garbled Hello of another version undoes it).
        let mut valid = frame_of(&hello(0xC0FFEE));
        valid.extend(frame_of(&Request {
            id: RequestId(0xC0FFEF),
            command: Command::Status,
        }));
        let after = serve(&mut rig, &mut session, &mut decoder, &valid)?;
        prop_assert_eq!(after.replies.len(), 2);
        prop_assert!(matches!(after.replies[0].1, Reply::Hello(_)));
        prop_assert_eq!(after.replies[1].0, RequestId(0xC0FFEF));
        prop_assert!(matches!(after.replies[1].1, Reply::Status(_)));
        Ok(())
    });
    passed(result);
    assert!(
        decoded.get() > 0 && link_errors.get() > 0,
        "{} frames decoded, {} unreadable",
        decoded.get(),
        link_errors.get()
    );
}

#[test]
fn hostile_frames_on_the_serial_link_leave_the_controller_serving() {
    let mut runner = fuzz_runner();
    let strategy = prop::collection::vec(hostile(), 1..40);
    let result = runner.run(&strategy, |traffic| {
        let mut rig = Rig::new(3, 5, default_config());
        let mut session = rig.session.clone();
        let mut decoder = FrameDecoder::new();
        // Unreadable frames change nothing (checked inside `serve`); readable ones are
        // requests from the trusted link and may do anything a request may do.
        serve(
            &mut rig,
            &mut session,
            &mut decoder,
            &hostile_bytes(&traffic),
        )?;
        rig.settle_fast();
        prop_assert!(rig.all_idle_at_target());
        prop_assert_eq!(rig.driver.sim.unpowered_steps(), 0);

        // The controller still moves when asked properly.
        let mut valid = frame_of(&hello(0x9F));
        for (id, command) in [
            (0xA0, Command::ClearEmergency),
            (
                0xA1,
                Command::SetConfig {
                    axis: 0,
                    config: default_config(),
                },
            ),
            (
                0xA2,
                Command::SetPosition {
                    axis: 0,
                    position: 0,
                },
            ),
            (
                0xA3,
                Command::MoveTo {
                    targets: values(&[(0, 40)]),
                },
            ),
        ] {
            valid.extend(frame_of(&Request {
                id: RequestId(id),
                command,
            }));
        }
        let answered = serve(&mut rig, &mut session, &mut decoder, &valid)?;
        prop_assert_eq!(answered.replies.len(), 5);
        prop_assert!(
            matches!(answered.replies[4].1, Reply::MoveStarted { .. }),
            "{:?}",
            answered.replies
        );
        rig.settle_fast();
        prop_assert_eq!(rig.position(0), 40);
        Ok(())
    });
    passed(result);
}

fn default_config() -> AxisConfig {
    crate::config::default_config(Capabilities(CAPABILITIES))
}

fn record() -> impl Strategy<Value = Record> {
    let axis = (
        axis_config(),
        any::<(i32, i32, i32, u16)>(),
        prop_oneof![
            Just(Slack::Unknown),
            Just(Slack::TakenUpPositive),
            Just(Slack::TakenUpNegative)
        ],
    )
        .prop_map(
            |(config, (position, motor_steps, coil_steps, band), slack)| AxisRecord {
                config,
                position,
                motor_steps,
                coil_steps,
                slack,
                band,
            },
        );
    (
        prop::option::of(any::<[u8; KEY_LEN]>()),
        prop::collection::vec(axis, 0..=MAX_AXES),
    )
        .prop_map(|(key, axes)| Record {
            key,
            wifi: None,
            axes: axes.into_iter().collect(),
            boots: 0,
        })
}

const HEADER_LEN: usize = 12;

/// Writes the length field and CRC of `payload` into a slot, as `record::encode` does, so
/// that the damaged payload reaches the postcard decoder.
fn resealed(sequence: u32, payload: &[u8]) -> [u8; RECORD_LEN] {
    let mut slot = [0xFF; RECORD_LEN];
    let len = payload.len().min(RECORD_LEN - HEADER_LEN - 4);
    slot[..4].copy_from_slice(b"OPTA");
    slot[4..6].copy_from_slice(&record::RECORD_VERSION.to_le_bytes());
    slot[6..10].copy_from_slice(&sequence.to_le_bytes());
    slot[10..12].copy_from_slice(&(len as u16).to_le_bytes());
    slot[HEADER_LEN..HEADER_LEN + len].copy_from_slice(&payload[..len]);
    let end = HEADER_LEN + len;
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(&slot[..end]);
    slot[end..end + 4].copy_from_slice(&crc.to_le_bytes());
    slot
}

fn encoded_slot(record: &Record, sequence: u32) -> [u8; RECORD_LEN] {
    let mut slot = [0u8; RECORD_LEN];
    record::encode(record, sequence, &mut slot).expect("the record fits a slot");
    slot
}

/// One slot as storage might hold it.
fn slot_image() -> impl Strategy<Value = [u8; RECORD_LEN]> {
    prop_oneof![
        1 => Just([0xFF; RECORD_LEN]),
        1 => Just([0; RECORD_LEN]),
        2 => (record(), any::<u32>()).prop_map(|(record, sequence)| encoded_slot(&record, sequence)),
        // Torn: a valid slot cut short by a power loss, the rest still erased.
        2 => (record(), any::<u32>(), 0..RECORD_LEN).prop_map(|(record, sequence, cut)| {
            let mut slot = encoded_slot(&record, sequence);
            slot[cut..].fill(0xFF);
            slot
        }),
        // Damaged, then resealed: only the postcard decoder can tell.
        4 => (record(), any::<u32>(), damage()).prop_map(|(record, sequence, damage): (Record, u32, Vec<_>)| {
            let payload = encoded(&record);
            resealed(sequence, &damaged(payload, &damage))
        }),
        1 => (any::<u32>(), prop::collection::vec(any::<u8>(), 0..200))
            .prop_map(|(sequence, payload)| resealed(sequence, &payload)),
        1 => prop::collection::vec(any::<u8>(), RECORD_LEN).prop_map(|bytes| {
            bytes.try_into().expect("RECORD_LEN bytes")
        }),
    ]
}

#[test]
fn hostile_record_slots_decode_to_a_record_that_round_trips_or_are_invalid() {
    let outcomes = Cell::new([0usize; 3]);
    let mut runner = fuzz_runner();
    let result = runner.run(&slot_image(), |slot| {
        let mut seen = outcomes.get();
        match record::decode(&slot) {
            Ok(None) => {
                seen[0] += 1;
                prop_assert!(slot.iter().all(|&b| b == 0xFF) || slot.iter().all(|&b| b == 0));
            }
            Ok(Some((sequence, record))) => {
                seen[1] += 1;
                let again = encoded_slot(&record, sequence);
                prop_assert_eq!(record::decode(&again), Ok(Some((sequence, record))));
            }
            Err(record::InvalidSlot) => seen[2] += 1,
        }
        outcomes.set(seen);
        Ok(())
    });
    passed(result);
    let [blank, valid, invalid] = outcomes.get();
    assert!(
        valid > 0 && invalid > 0,
        "{blank} blank, {valid} valid, {invalid} invalid"
    );
}

#[test]
fn a_board_booted_from_hostile_storage_says_so_and_never_moves_a_lost_axis() {
    let mut runner = fuzz_runner();
    let strategy = (
        slot_image(),
        slot_image(),
        prop_oneof![
            Just([0xFF; MARK_LEN]),
            (0u8..8).prop_map(mark::encode),
            any::<[u8; MARK_LEN]>()
        ],
        prop::collection::vec(-300i32..300, 3),
    );
    let result = runner.run(&strategy, |(slot0, slot1, marked, deltas)| {
        let mut bytes = slot0.to_vec();
        bytes.extend_from_slice(&slot1);
        bytes.extend_from_slice(&marked);
        let decoded = [record::decode(&slot0), record::decode(&slot1)];
        let readable = decoded.iter().any(|d| matches!(d, Ok(Some(_))));
        let blank = decoded.iter().all(|d| matches!(d, Ok(None)));
        let mut rig = Rig::boot(
            RamStorage::from_bytes(&bytes),
            (0..3).map(|_| MountModel::new(5)),
            3,
        );
        let status = rig.status();
        let lost = |faults: optalign_protocol::Faults| {
            faults.has(optalign_protocol::Faults::POSITION_LOST)
        };
        if !readable && !blank {
            prop_assert_eq!(status.boot, BootRecord::Unreadable);
            prop_assert!(status.axes.iter().all(|a| lost(a.faults)));
        }
        if blank && mark::decode(&marked) == 0 {
            prop_assert_eq!(status.boot, BootRecord::NoRecordYet);
        }
        for (axis, delta) in (0u8..).zip(deltas) {
            let was_lost = lost(status.axes[usize::from(axis)].faults);
            let reply = rig.send(Command::MoveBy {
                deltas: values(&[(axis, delta)]),
            });
            if was_lost {
                match &reply {
                    Reply::Error(error) => prop_assert_eq!(error.code, ErrorCode::AXIS_FAULT),
                    other => prop_assert!(false, "a lost axis was moved: {:?}", other),
                }
            }
            rig.settle_fast();
            if was_lost {
                prop_assert!(rig.steps_of(axis).is_empty(), "lost axis {} stepped", axis);
            }
        }
        prop_assert!(rig.all_idle_at_target());
        Ok(())
    });
    passed(result);
}
