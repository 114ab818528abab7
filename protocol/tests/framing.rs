//! Property tests of the framing: round trips, resynchronisation and hostile input.

mod strategies;

use heapless::{String, Vec};
use optalign_protocol::auth;
use optalign_protocol::*;
use proptest::prelude::*;
use strategies::*;

fn frame_of<T: serde::Serialize>(message: &T) -> std::vec::Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = encode_frame(message, &mut out).expect("every message fits a frame");
    out[..len].to_vec()
}

fn decode_all<T: serde::de::DeserializeOwned>(
    bytes: &[u8],
) -> std::vec::Vec<Result<T, FrameError>> {
    let mut decoder = FrameDecoder::new();
    let mut out = std::vec::Vec::new();
    decoder.feed(bytes, |m| out.push(m));
    out
}

proptest! {
    #[test]
    fn every_request_round_trips(req in request()) {
        let frame = frame_of(&req);
        prop_assert!(frame.len() <= MAX_FRAME);
        prop_assert_eq!(frame.iter().filter(|&&b| b == 0).count(), 1, "only the delimiter is zero");
        prop_assert_eq!(decode_all::<Request>(&frame), vec![Ok(req)]);
    }

    #[test]
    fn every_peer_message_round_trips(msg in peer_message()) {
        let frame = frame_of(&msg);
        prop_assert_eq!(decode_all::<PeerMessage>(&frame), vec![Ok(msg)]);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..4096)) {
        let results = decode_all::<Request>(&bytes);
        prop_assert!(results.len() <= bytes.iter().filter(|&&b| b == 0).count());
    }

    #[test]
    fn feeding_a_buffer_equals_pushing_each_byte(bytes in prop::collection::vec(prop_oneof![Just(0u8), any::<u8>()], 0..3000)) {
        let fed = decode_all::<Request>(&bytes);
        let mut decoder = FrameDecoder::new();
        let pushed: std::vec::Vec<_> = bytes.iter().filter_map(|&b| decoder.push::<Request>(b)).collect();
        prop_assert_eq!(fed, pushed);
    }

    #[test]
    fn decoder_resynchronises_after_garbage(garbage in prop::collection::vec(any::<u8>(), 0..2000), req in request()) {
        // Garbage, then a delimiter, then a good frame: the good frame always comes out last.
        let mut stream = garbage.clone();
        stream.push(0);
        stream.extend(frame_of(&req));
        let results = decode_all::<Request>(&stream);
        prop_assert_eq!(results.last(), Some(&Ok(req)));
    }

    #[test]
    fn torn_frames_reassemble(reqs in prop::collection::vec(request(), 1..6), cuts in prop::collection::vec(1usize..40, 1..20)) {
        // Merged into one stream, delivered in arbitrary pieces.
        let stream: std::vec::Vec<u8> = reqs.iter().flat_map(frame_of).collect();
        let mut decoder = FrameDecoder::new();
        let mut out = std::vec::Vec::new();
        let mut rest = &stream[..];
        for cut in cuts.iter().cycle() {
            if rest.is_empty() { break; }
            let (piece, tail) = rest.split_at((*cut).min(rest.len()));
            decoder.feed::<Request>(piece, |m| out.push(m.unwrap()));
            rest = tail;
        }
        prop_assert_eq!(out, reqs);
    }

    #[test]
    fn a_flipped_byte_is_caught(req in request(), index in any::<prop::sample::Index>(), flip in 1u8..=255) {
        let mut frame = frame_of(&req);
        let body = frame.len() - 1;
        let i = index.index(body);
        frame[i] ^= flip;
        let results = decode_all::<Request>(&frame);
        // A corrupted frame never decodes as a different message: it is an error, or (if
        // the corruption produced a zero) split into pieces that are all errors.
        prop_assert!(!results.is_empty());
        for r in results {
            prop_assert!(r.is_err(), "corruption went undetected: {:?}", r);
        }
    }
}

#[test]
fn oversized_frame_is_one_error_and_the_next_frame_survives() {
    let mut stream = vec![0x55u8; MAX_FRAME * 3];
    stream.push(0);
    let good = Request {
        id: RequestId(7),
        command: Command::Status,
    };
    stream.extend(frame_of(&good));
    let results = decode_all::<Request>(&stream);
    assert_eq!(results, vec![Err(FrameError::TooLarge), Ok(good)]);
}

#[test]
fn bad_crc_is_reported_as_such() {
    let req = Request {
        id: RequestId(1),
        command: Command::Stop,
    };
    let mut out = [0u8; MAX_FRAME];
    let mut raw = postcard::to_allocvec(&req).unwrap();
    raw.extend_from_slice(&0xdead_beefu32.to_le_bytes());
    let len = cobs::encode(&raw, &mut out);
    out[len] = 0;
    assert_eq!(
        decode_all::<Request>(&out[..=len]),
        vec![Err(FrameError::BadCrc)]
    );
}

#[test]
fn valid_crc_over_a_non_message_is_malformed() {
    let raw = [0xffu8, 0xff, 0xff, 0xff, 0xff, 0xff];
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(&raw);
    let mut payload = raw.to_vec();
    payload.extend_from_slice(&crc.to_le_bytes());
    let mut out = [0u8; MAX_FRAME];
    let len = cobs::encode(&payload, &mut out);
    out[len] = 0;
    assert_eq!(
        decode_all::<Request>(&out[..=len]),
        vec![Err(FrameError::Malformed)]
    );
}

#[test]
fn the_largest_messages_fit_a_frame() {
    let mut targets = Vec::new();
    for axis in 0..MAX_AXES as u8 {
        targets
            .push(AxisValue {
                axis,
                steps: i32::MIN,
            })
            .unwrap();
    }
    frame_of(&Request {
        id: RequestId(u32::MAX),
        command: Command::MoveTo { targets },
    });
    let long = |n| core::iter::repeat_n('\u{10FFFF}', n).collect::<std::string::String>();
    let mut reason = String::<96>::new();
    reason.push_str(&long(24)).unwrap();
    frame_of(&PeerMessage::LinkError(ErrorReply {
        code: ErrorCode(u16::MAX),
        reason,
    }));
}

#[test]
fn error_reasons_are_cut_not_rejected() {
    let reply = error_reply!(ErrorCode::BUSY, "{}", "x".repeat(500));
    assert_eq!(reply.reason.len(), 96);
    assert_eq!(reply.code.name(), "busy");
    assert_eq!(ErrorCode(9999).name(), "unknown");
}

#[test]
fn challenge_tags_verify_only_with_the_right_key_and_both_nonces() {
    let key = [0x11; 32];
    let (nonce, client_nonce) = ([7u8; 16], [9u8; 16]);
    let tag = auth::challenge_tag(&key, &nonce, &client_nonce);
    assert!(auth::verify_tag(&key, &nonce, &client_nonce, &tag));
    assert!(!auth::verify_tag(&[0x12; 32], &nonce, &client_nonce, &tag));
    assert!(!auth::verify_tag(&key, &[8u8; 16], &client_nonce, &tag));
    assert!(!auth::verify_tag(&key, &nonce, &[8u8; 16], &tag));
}
