//! Session keys and sealed frames: both sides agree on the key, and a receiver accepts
//! exactly the frames its peer sealed for this session, once each, in order.

use optalign_protocol::auth::{self, Key, Nonce};
use optalign_protocol::seal::{Direction, Inbound, Opener, SEAL_LEN, Sealer};
use optalign_protocol::*;

const KEY: Key = [0x5a; 32];
const PEER_NONCE: Nonce = [1; 16];
const CLIENT_NONCE: Nonce = [2; 16];

fn status_request(id: u32) -> Request {
    Request {
        id: RequestId(id),
        command: Command::Status,
    }
}

fn sealed(message: &Request, sealer: &mut Sealer) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = encode_sealed_frame(message, sealer, &mut out).expect("fits");
    out[..len].to_vec()
}

fn plain(message: &Request) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = encode_frame(message, &mut out).expect("fits");
    out[..len].to_vec()
}

/// Decodes every frame in `bytes` against `inbound`.
fn receive(bytes: &[u8], inbound: &mut Inbound) -> Vec<Result<Request, FrameError>> {
    let mut decoder = FrameDecoder::new();
    let mut out = Vec::new();
    decoder.feed_checked(bytes, inbound, |frame| out.push(frame));
    out
}

/// What the controller holds once the client authenticated: it accepts sealed frames only.
fn controller_inbound(key: &Key, nonce: &Nonce, client_nonce: &Nonce) -> Inbound {
    let mut inbound = Inbound::plain();
    let session = auth::session_key(key, nonce, client_nonce);
    inbound.install(Opener::new(session, Direction::ToController), true);
    inbound
}

fn client_sealer(key: &Key, nonce: &Nonce, client_nonce: &Nonce) -> Sealer {
    Sealer::new(
        auth::session_key(key, nonce, client_nonce),
        Direction::ToController,
    )
}

#[test]
fn both_sides_derive_the_same_session_key_and_other_nonces_give_other_keys() {
    let ours = auth::session_key(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    assert_eq!(ours, auth::session_key(&KEY, &PEER_NONCE, &CLIENT_NONCE));
    let others = [
        auth::session_key(&KEY, &[3; 16], &CLIENT_NONCE),
        auth::session_key(&KEY, &PEER_NONCE, &[3; 16]),
        auth::session_key(&KEY, &CLIENT_NONCE, &PEER_NONCE),
        auth::session_key(&[0x5b; 32], &PEER_NONCE, &CLIENT_NONCE),
    ];
    for other in others {
        assert_ne!(ours, other);
    }
    // Neither the challenge tag nor the key itself doubles as the session key.
    assert_ne!(ours, auth::challenge_tag(&KEY, &PEER_NONCE, &CLIENT_NONCE));
    assert_ne!(ours, KEY);
}

#[test]
fn sealed_frames_of_this_session_are_accepted_in_order() {
    let mut sealer = client_sealer(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let mut inbound = controller_inbound(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let bytes: Vec<u8> = (1..=3)
        .flat_map(|id| sealed(&status_request(id), &mut sealer))
        .collect();
    let received = receive(&bytes, &mut inbound);
    assert_eq!(
        received,
        (1..=3).map(|id| Ok(status_request(id))).collect::<Vec<_>>()
    );
}

#[test]
fn replays_forgeries_plain_frames_and_other_sessions_are_refused() {
    let mut sealer = client_sealer(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let mut inbound = controller_inbound(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let first = sealed(&status_request(1), &mut sealer);
    assert_eq!(receive(&first, &mut inbound), vec![Ok(status_request(1))]);
    // The same frame again: a replay.
    assert_eq!(
        receive(&first, &mut inbound),
        vec![Err(FrameError::Replayed)]
    );
    // A frame of the same key but another session (other nonces).
    let mut elsewhere = client_sealer(&KEY, &PEER_NONCE, &[9; 16]);
    let foreign = sealed(&status_request(2), &mut elsewhere);
    assert_eq!(
        receive(&foreign, &mut inbound),
        vec![Err(FrameError::BadSeal)]
    );
    // A plain frame on a sealed session.
    assert_eq!(
        receive(&plain(&status_request(3)), &mut inbound),
        vec![Err(FrameError::Unsealed)]
    );
    // The session's own traffic goes on.
    let next = sealed(&status_request(4), &mut sealer);
    assert_eq!(receive(&next, &mut inbound), vec![Ok(status_request(4))]);
}

#[test]
fn a_changed_message_or_counter_breaks_the_seal() {
    let session = auth::session_key(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let mut sealer = Sealer::new(session, Direction::ToController);
    let message = postcard::to_allocvec(&status_request(7)).unwrap();
    let seal = sealer.seal(&message);

    let mut opener = Opener::new(session, Direction::ToController);
    let mut altered = message.clone();
    *altered.last_mut().unwrap() ^= 1;
    assert_eq!(opener.open(&altered, &seal), Err(FrameError::BadSeal));
    let mut bumped = seal;
    bumped.counter += 1;
    assert_eq!(opener.open(&message, &bumped), Err(FrameError::BadSeal));
    // A frame sealed for the other direction (reflected back) does not verify.
    let mut reflected = Opener::new(session, Direction::ToHost);
    assert_eq!(reflected.open(&message, &seal), Err(FrameError::BadSeal));
    assert_eq!(opener.open(&message, &seal), Ok(()));
    assert_eq!(opener.open(&message, &seal), Err(FrameError::Replayed));
}

#[test]
fn a_client_accepts_plain_frames_until_the_first_valid_seal() {
    let session = auth::session_key(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let mut inbound = Inbound::plain();
    inbound.install(Opener::new(session, Direction::ToController), false);
    assert_eq!(
        receive(&plain(&status_request(1)), &mut inbound),
        vec![Ok(status_request(1))]
    );
    assert!(!inbound.is_sealed());
    let mut sealer = Sealer::new(session, Direction::ToController);
    assert_eq!(
        receive(&sealed(&status_request(2), &mut sealer), &mut inbound),
        vec![Ok(status_request(2))]
    );
    assert!(inbound.is_sealed());
    assert_eq!(
        receive(&plain(&status_request(3)), &mut inbound),
        vec![Err(FrameError::Unsealed)]
    );
}

#[test]
fn without_a_session_key_sealed_frames_are_refused_and_the_plain_decoder_never_takes_them() {
    let mut sealer = client_sealer(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let frame = sealed(&status_request(1), &mut sealer);
    assert_eq!(
        receive(&frame, &mut Inbound::plain()),
        vec![Err(FrameError::UnexpectedSeal)]
    );
    let mut decoder = FrameDecoder::new();
    let mut out = Vec::new();
    decoder.feed::<Request>(&frame, |frame| out.push(frame));
    assert_eq!(out, vec![Err(FrameError::Malformed)]);
}

#[test]
fn the_largest_message_still_fits_a_frame_when_sealed() {
    let reason = "x".repeat(limits::REASON_LEN);
    let largest = PeerMessage::Reply {
        id: RequestId(u32::MAX),
        reply: Reply::Error(error_reply!(ErrorCode::INTERNAL, "{reason}")),
    };
    let session = auth::session_key(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let mut sealer = Sealer::new(session, Direction::ToHost);
    let mut out = [0u8; MAX_FRAME];
    let len = encode_sealed_frame(&largest, &mut sealer, &mut out).expect("fits");
    let mut plain_out = [0u8; MAX_FRAME];
    let plain_len = encode_frame(&largest, &mut plain_out).expect("fits");
    assert!(len >= plain_len + SEAL_LEN);
    let mut inbound = Inbound::plain();
    inbound.install(Opener::new(session, Direction::ToHost), true);
    let mut decoder = FrameDecoder::new();
    let mut got = Vec::new();
    decoder.feed_checked::<PeerMessage>(&out[..len], &mut inbound, |m| got.push(m));
    assert_eq!(got, vec![Ok(largest)]);
}

/// A message type that counts how often the decoder tried to read one.
mod probe {
    use std::cell::Cell;

    use serde::de::{Deserialize, Deserializer};

    thread_local! {
        pub static DECODED: Cell<u32> = const { Cell::new(0) };
    }

    /// Decodes as whatever `Request` decodes as, counting each attempt.
    #[derive(Debug, PartialEq)]
    pub struct Probe(pub super::Request);

    impl<'de> Deserialize<'de> for Probe {
        fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
            DECODED.with(|count| count.set(count.get() + 1));
            super::Request::deserialize(deserializer).map(Probe)
        }
    }

    pub fn decoded() -> u32 {
        DECODED.with(Cell::get)
    }
}

#[test]
fn a_frame_with_a_bad_seal_is_refused_before_any_decoding() {
    use probe::{Probe, decoded};

    let decode = |bytes: &[u8], inbound: &mut Inbound| {
        let mut decoder = FrameDecoder::new();
        let mut out = Vec::new();
        decoder.feed_checked::<Probe>(bytes, inbound, |frame| out.push(frame));
        out
    };
    let mut inbound = controller_inbound(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    // Sealed for another session, and altered after sealing: neither is decoded.
    let mut elsewhere = client_sealer(&KEY, &PEER_NONCE, &[9; 16]);
    let foreign = sealed(&status_request(1), &mut elsewhere);
    assert_eq!(
        decode(&foreign, &mut inbound),
        vec![Err(FrameError::BadSeal)]
    );
    let mut sealer = client_sealer(&KEY, &PEER_NONCE, &CLIENT_NONCE);
    let mut payload = postcard::to_allocvec(&status_request(2)).unwrap();
    let seal = sealer.seal(&payload);
    payload[0] ^= 0x40;
    payload.extend_from_slice(&seal.to_bytes());
    let altered = framed(&payload);
    assert_eq!(
        decode(&altered, &mut inbound),
        vec![Err(FrameError::BadSeal)]
    );
    // A plain frame long enough to pass for a sealed one, and garbage.
    let long = plain(&Request {
        id: RequestId(3),
        command: Command::MoveTo {
            targets: (0..8)
                .map(|axis| AxisValue {
                    axis,
                    steps: i32::MAX,
                })
                .collect(),
        },
    });
    assert_eq!(decode(&long, &mut inbound), vec![Err(FrameError::BadSeal)]);
    assert_eq!(
        decode(&framed(&[0xFF; 40]), &mut inbound),
        vec![Err(FrameError::BadSeal)]
    );
    assert_eq!(decoded(), 0, "nothing reached the message decoder");
    // The session's own frame is decoded, once.
    let good = sealed(&status_request(4), &mut sealer);
    assert_eq!(
        decode(&good, &mut inbound),
        vec![Ok(Probe(status_request(4)))]
    );
    assert_eq!(decoded(), 1);
}

/// `payload` with its CRC, stuffed and delimited, as a sender frames it.
fn framed(payload: &[u8]) -> Vec<u8> {
    let mut raw = payload.to_vec();
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(payload);
    raw.extend_from_slice(&crc.to_le_bytes());
    let mut out = vec![0u8; cobs::max_encoding_length(raw.len()) + 1];
    let len = cobs::encode(&raw, &mut out);
    out.truncate(len);
    out.push(0);
    out
}
