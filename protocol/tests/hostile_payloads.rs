//! Hostile payloads behind a valid CRC: random bytes almost never pass the CRC, so these
//! tests seal arbitrary and mutated payloads (random bytes, truncations, bit flips, spliced
//! and oversized lengths of every message variant) in frames whose CRC checks out, and feed
//! them to the decoder as `Request` and as `PeerMessage`.
//!
//! Properties: decoding never panics; a payload is either a message whose re-encoding
//! decodes to the same message, or exactly `Malformed`; a payload too large for a frame is
//! exactly `TooLarge`; a valid frame after the garbage is still understood. Every strict
//! prefix of a valid encoding is `Malformed` (postcard encodings are self-delimiting).
//!
//! Cases: 10,000 per campaign and 1,000 per prefix property by default;
//! `OPTALIGN_FUZZ_CASES=N` runs N cases of each instead.

mod strategies;

use optalign_protocol::*;
use proptest::prelude::*;
use proptest::test_runner::TestRunner;
use strategies::{peer_message, request};

fn fuzz_config(default_cases: u32) -> ProptestConfig {
    let cases = match std::env::var("OPTALIGN_FUZZ_CASES") {
        Ok(text) => text
            .parse()
            .unwrap_or_else(|_| panic!("OPTALIGN_FUZZ_CASES must be a whole number, got {text:?}")),
        Err(_) => default_cases,
    };
    ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

fn crc32c(bytes: &[u8]) -> u32 {
    crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(bytes)
}

/// `payload` framed with a correct CRC (however long it is: the decoder must cope).
fn sealed(payload: &[u8]) -> Vec<u8> {
    let mut raw = payload.to_vec();
    raw.extend_from_slice(&crc32c(payload).to_le_bytes());
    let mut out = vec![0u8; cobs::max_encoding_length(raw.len())];
    let len = cobs::encode(&raw, &mut out);
    out.truncate(len);
    out.push(0);
    out
}

fn encoded<T: serde::Serialize>(message: &T) -> Vec<u8> {
    postcard::to_allocvec(message).expect("every message encodes")
}

fn frame_of<T: serde::Serialize>(message: &T) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = encode_frame(message, &mut out).expect("every message fits a frame");
    out[..len].to_vec()
}

fn decode_all<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Vec<Result<T, FrameError>> {
    let mut decoder = FrameDecoder::new();
    let mut out = Vec::new();
    decoder.feed(bytes, |m| out.push(m));
    out
}

/// One way to damage a valid encoding.
#[derive(Clone, Debug)]
enum Damage {
    Truncate(prop::sample::Index),
    FlipBit(prop::sample::Index, u8),
    SetByte(prop::sample::Index, u8),
    /// A run of 0xFF: varint lengths and counts far beyond every bound.
    HugeVarint(prop::sample::Index, usize),
    Insert(prop::sample::Index, Vec<u8>),
    Append(Vec<u8>),
}

fn damage() -> impl Strategy<Value = Damage> {
    let bytes = prop::collection::vec(any::<u8>(), 1..16);
    prop_oneof![
        any::<prop::sample::Index>().prop_map(Damage::Truncate),
        (any::<prop::sample::Index>(), 0u8..8).prop_map(|(at, bit)| Damage::FlipBit(at, bit)),
        (any::<prop::sample::Index>(), any::<u8>()).prop_map(|(at, b)| Damage::SetByte(at, b)),
        (any::<prop::sample::Index>(), 1usize..12).prop_map(|(at, n)| Damage::HugeVarint(at, n)),
        (any::<prop::sample::Index>(), bytes.clone()).prop_map(|(at, b)| Damage::Insert(at, b)),
        bytes.prop_map(Damage::Append),
    ]
}

fn apply(damage: &Damage, payload: &mut Vec<u8>) {
    let len = payload.len();
    match damage {
        Damage::Truncate(at) => payload.truncate(at.index(len.max(1))),
        Damage::FlipBit(at, bit) if len > 0 => payload[at.index(len)] ^= 1 << bit,
        Damage::SetByte(at, byte) if len > 0 => payload[at.index(len)] = *byte,
        Damage::HugeVarint(at, run) => {
            let at = at.index(len + 1);
            payload.splice(at..at, std::iter::repeat_n(0xFF, *run));
        }
        Damage::Insert(at, bytes) => {
            let at = at.index(len + 1);
            payload.splice(at..at, bytes.iter().copied());
        }
        Damage::Append(bytes) => payload.extend_from_slice(bytes),
        Damage::FlipBit(..) | Damage::SetByte(..) => {}
    }
}

/// Payloads for the decoder: valid encodings of every variant with one to four kinds of
/// damage; any variant tag (known or not, after a request id or alone) followed by random
/// bytes; random bytes of any length up to twice the largest payload; the empty one.
fn hostile_payload() -> impl Strategy<Value = Vec<u8>> {
    let mutated = |valid: BoxedStrategy<Vec<u8>>| {
        (valid, prop::collection::vec(damage(), 1..5)).prop_map(|(mut payload, damages)| {
            for damage in &damages {
                apply(damage, &mut payload);
            }
            payload
        })
    };
    prop_oneof![
        4 => mutated(request().prop_map(|r| encoded(&r)).boxed()),
        4 => mutated(peer_message().prop_map(|m| encoded(&m)).boxed()),
        2 => (any::<u32>(), 0u8..24, prop::collection::vec(any::<u8>(), 0..64)).prop_map(
            |(id, tag, body)| {
                let mut payload = encoded(&id);
                payload.push(tag);
                payload.extend(body);
                payload
            }
        ),
        2 => (0u8..24, prop::collection::vec(any::<u8>(), 0..64)).prop_map(|(tag, body)| {
            let mut payload = vec![tag];
            payload.extend(body);
            payload
        }),
        2 => prop::collection::vec(any::<u8>(), 0..=2 * MAX_PAYLOAD),
        1 => Just(Vec::new()),
    ]
}

/// Decodes `payload` behind a valid CRC as `T`, then a valid frame of `follower`; checks
/// the properties and returns whether the payload decoded.
fn check_decoding<T>(payload: &[u8], follower: &T) -> Result<bool, TestCaseError>
where
    T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
{
    let mut stream = sealed(payload);
    // The decoder holds up to MAX_FRAME bytes before the delimiter.
    let fits = stream.len() - 1 <= MAX_FRAME;
    stream.extend(frame_of(follower));
    let results = decode_all::<T>(&stream);
    prop_assert_eq!(results.len(), 2, "one result per frame");
    let decoded = match &results[0] {
        Ok(message) => {
            prop_assert!(fits, "an oversized frame must not decode");
            // Whatever decodes is a message this side can send back unchanged.
            let again = decode_all::<T>(&frame_of(message));
            prop_assert_eq!(again.len(), 1);
            prop_assert_eq!(again[0].as_ref(), Ok(message));
            true
        }
        Err(error) if fits => {
            prop_assert_eq!(*error, FrameError::Malformed);
            false
        }
        Err(error) => {
            prop_assert_eq!(*error, FrameError::TooLarge);
            false
        }
    };
    prop_assert_eq!(
        results[1].as_ref(),
        Ok(follower),
        "the decoder resynchronises"
    );
    Ok(decoded)
}

fn run_campaign<T>(follower: impl Strategy<Value = T>)
where
    T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
{
    let decoded = std::cell::Cell::new(0u32);
    let rejected = std::cell::Cell::new(0u32);
    let mut runner = TestRunner::new(fuzz_config(10_000));
    let result = runner.run(&(hostile_payload(), follower), |(payload, follower)| {
        let counter = if check_decoding(&payload, &follower)? {
            &decoded
        } else {
            &rejected
        };
        counter.set(counter.get() + 1);
        Ok(())
    });
    if let Err(failure) = result {
        panic!("{failure}");
    }
    // The campaign reaches both sides of the decoder: it is not all CRC or framing errors.
    assert!(
        decoded.get() > 0 && rejected.get() > 0,
        "{} payloads decoded, {} rejected",
        decoded.get(),
        rejected.get()
    );
}

#[test]
fn hostile_payloads_decode_as_requests_or_are_malformed() {
    run_campaign(request());
}

#[test]
fn hostile_payloads_decode_as_peer_messages_or_are_malformed() {
    run_campaign(peer_message());
}

proptest! {
    #![proptest_config(fuzz_config(1_000))]

    #[test]
    fn every_strict_prefix_of_a_request_is_malformed(req in request()) {
        let payload = encoded(&req);
        for len in 0..payload.len() {
            prop_assert_eq!(
                decode_all::<Request>(&sealed(&payload[..len])),
                vec![Err(FrameError::Malformed)],
                "prefix of {} bytes", len
            );
        }
    }

    #[test]
    fn every_strict_prefix_of_a_peer_message_is_malformed(msg in peer_message()) {
        let payload = encoded(&msg);
        for len in 0..payload.len() {
            prop_assert_eq!(
                decode_all::<PeerMessage>(&sealed(&payload[..len])),
                vec![Err(FrameError::Malformed)],
                "prefix of {} bytes", len
            );
        }
    }
}

#[test]
fn a_payload_too_large_for_a_frame_is_too_large_even_with_a_valid_crc() {
    let valid = encoded(&Request {
        id: RequestId(1),
        command: Command::Status,
    });
    let mut payload = valid.clone();
    payload.resize(MAX_FRAME, 0x01);
    let mut stream = sealed(&payload);
    assert!(stream.len() > MAX_FRAME);
    stream.extend(sealed(&valid));
    let results = decode_all::<Request>(&stream);
    assert_eq!(results[0], Err(FrameError::TooLarge));
    assert_eq!(
        results[1],
        Ok(Request {
            id: RequestId(1),
            command: Command::Status
        })
    );
}

#[test]
fn unknown_variant_tags_are_malformed() {
    // Past the last command and the last peer message, with an id before the tag.
    for tag in [16u8, 17, 0x7F] {
        let payload = [0x01, tag];
        assert_eq!(
            decode_all::<Request>(&sealed(&payload)),
            vec![Err(FrameError::Malformed)],
            "command tag {tag}"
        );
    }
    for tag in [3u8, 4, 0x7F] {
        assert_eq!(
            decode_all::<PeerMessage>(&sealed(&[tag])),
            vec![Err(FrameError::Malformed)],
            "message tag {tag}"
        );
    }
}
