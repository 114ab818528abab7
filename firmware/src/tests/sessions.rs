//! Network sessions under attack: sealed frames after authentication, the backoff after
//! failed authentications, and closing unauthenticated connections.

use optalign_protocol::auth::session_key;
use optalign_protocol::seal::{Direction, Inbound, Opener, Sealer};
use optalign_protocol::{
    Command, ErrorCode, FrameDecoder, FrameError, MAX_FRAME, PROTOCOL_VERSION, PeerMessage, Reply,
    Request, RequestId, encode_frame, encode_sealed_frame,
};

use super::dispatch::{
    CLIENT_NONCE, KEY, a_move, authenticate, code, network, plain, reason, response,
};
use super::rig::Rig;
use crate::backoff::FIRST_DELAY_US;
use crate::session::{RESERVED_SLOT_AUTH_US, UNAUTHENTICATED_IDLE_US};
use crate::{LinkKind, Session};

/// Authenticates `session` under `KEY`; returns the sealer its client seals requests with.
fn authenticated(rig: &mut Rig, session: &mut Session) -> Sealer {
    let Reply::Challenge { nonce } = rig.send_on(session, RequestId(2), Command::AuthChallenge)
    else {
        panic!("no challenge");
    };
    assert_eq!(
        rig.send_on(session, RequestId(3), response(&KEY, &nonce)),
        Reply::Ok
    );
    Sealer::new(
        session_key(&KEY, &nonce, &CLIENT_NONCE),
        Direction::ToController,
    )
}

fn frame(request: &Request, sealer: Option<&mut Sealer>) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = match sealer {
        Some(sealer) => encode_sealed_frame(request, sealer, &mut out),
        None => encode_frame(request, &mut out),
    }
    .unwrap();
    out[..len].to_vec()
}

/// Serves `bytes` on `session` as a board's link does: every frame is checked against the
/// session; what passes is handled, what does not is reported.
fn serve(rig: &mut Rig, session: &mut Session, bytes: &[u8]) -> Vec<PeerMessage> {
    let mut decoder = FrameDecoder::new();
    let mut frames = Vec::new();
    decoder.feed_checked::<Request>(bytes, session.inbound(), |f| frames.push(f));
    let mut out = Vec::new();
    for frame in frames {
        match frame {
            Ok(request) => {
                rig.controller
                    .handle(session, &request, rig.now, &mut rig.rng, &mut |m| {
                        out.push(m)
                    })
            }
            Err(error) => rig.controller.link_error(error, &mut |m| out.push(m)),
        }
    }
    out
}

fn refused_as(messages: &[PeerMessage], error: FrameError) -> bool {
    matches!(messages, [PeerMessage::LinkError(reply)] if reply.code == ErrorCode::BAD_SEAL
        && reply.reason.as_str() == error.to_string())
}

fn move_request(id: u32) -> Request {
    Request {
        id: RequestId(id),
        command: a_move(),
    }
}

#[test]
fn an_authenticated_session_acts_only_on_frames_sealed_for_it_once() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut net = network(&mut rig);
    let mut sealer = authenticated(&mut rig, &mut net);
    assert!(net.inbound().is_sealed());

    // Unsealed: what a machine that only watched the handshake would send.
    let out = serve(&mut rig, &mut net, &frame(&move_request(10), None));
    assert!(refused_as(&out, FrameError::Unsealed), "{out:?}");
    // Sealed under the same key for another session (other nonces).
    let mut other_session = Sealer::new(
        session_key(&KEY, &[0; 16], &CLIENT_NONCE),
        Direction::ToController,
    );
    let forged = frame(&move_request(11), Some(&mut other_session));
    let out = serve(&mut rig, &mut net, &forged);
    assert!(refused_as(&out, FrameError::BadSeal), "{out:?}");
    // Sealed the other way round (a controller's frame reflected back).
    let mut reflected = Sealer::new(
        session_key(&KEY, &[0; 16], &CLIENT_NONCE),
        Direction::ToHost,
    );
    let out = serve(
        &mut rig,
        &mut net,
        &frame(&move_request(12), Some(&mut reflected)),
    );
    assert!(refused_as(&out, FrameError::BadSeal), "{out:?}");
    assert!(!rig.controller.is_moving(), "nothing refused was acted on");

    // The session's own frame runs; the same bytes again are a replay.
    let genuine = frame(&move_request(13), Some(&mut sealer));
    let out = serve(&mut rig, &mut net, &genuine);
    assert!(
        matches!(
            out.as_slice(),
            [PeerMessage::Reply {
                reply: Reply::MoveStarted { .. },
                ..
            }]
        ),
        "{out:?}"
    );
    rig.settle();
    assert_eq!(rig.position(0), 10);
    let out = serve(&mut rig, &mut net, &genuine);
    assert!(refused_as(&out, FrameError::Replayed), "{out:?}");
    // The replay did not move anything again.
    rig.settle();
    assert_eq!(rig.finished().len(), 1);
    assert_eq!(rig.status().security.rejected_frames, 4);
    assert_eq!(rig.status().security.failed_authentications, 0);
}

#[test]
fn the_controller_seals_from_the_reply_that_confirms_authentication() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut net = network(&mut rig);
    assert!(
        net.take_sealer().is_none(),
        "nothing to seal before authentication"
    );
    let Reply::Challenge { nonce } = rig.send_on(&mut net, RequestId(2), Command::AuthChallenge)
    else {
        panic!("no challenge");
    };
    rig.send_on(&mut net, RequestId(3), response(&KEY, &nonce));
    let mut sealer = net.take_sealer().expect("a sealer once authenticated");
    assert!(net.take_sealer().is_none(), "handed over once");
    // The client checks the controller's frames with the key it derived on its side.
    let mut client = Inbound::plain();
    client.install(
        Opener::new(session_key(&KEY, &nonce, &CLIENT_NONCE), Direction::ToHost),
        false,
    );
    let reply = PeerMessage::Reply {
        id: RequestId(3),
        reply: Reply::Ok,
    };
    let mut out = [0u8; MAX_FRAME];
    let len = encode_sealed_frame(&reply, &mut sealer, &mut out).unwrap();
    let mut decoder = FrameDecoder::new();
    let mut got = Vec::new();
    decoder.feed_checked::<PeerMessage>(&out[..len], &mut client, |m| got.push(m));
    assert_eq!(got, vec![Ok(reply)]);
    assert!(client.is_sealed());
}

#[test]
fn failed_authentications_are_counted_and_close_authentication_for_a_growing_while() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut guesser = network(&mut rig);
    let mut honest = network(&mut rig);
    // A challenge drawn before the failure cannot be spent during the backoff either.
    let Reply::Challenge { nonce: early } =
        rig.send_on(&mut honest, RequestId(2), Command::AuthChallenge)
    else {
        panic!("no challenge");
    };
    assert_eq!(
        code(&authenticate(&mut rig, &mut guesser, &[8; 32])),
        Some(ErrorCode::AUTH_FAILED)
    );
    assert_eq!(rig.status().security.failed_authentications, 1);
    // Closed for every connection, not only the guesser's.
    let reply = rig.send_on(&mut honest, RequestId(3), response(&KEY, &early));
    assert_eq!(code(&reply), Some(ErrorCode::AUTH_BACKOFF));
    assert!(reason(&reply).contains("try again in 250 ms"), "{reply:?}");
    let reply = rig.send_on(&mut guesser, RequestId(4), Command::AuthChallenge);
    assert_eq!(code(&reply), Some(ErrorCode::AUTH_BACKOFF));

    // The second failure in a row doubles the delay.
    rig.now += FIRST_DELAY_US;
    assert_eq!(
        code(&authenticate(&mut rig, &mut guesser, &[9; 32])),
        Some(ErrorCode::AUTH_FAILED)
    );
    rig.now += FIRST_DELAY_US;
    let reply = rig.send_on(&mut honest, RequestId(5), Command::AuthChallenge);
    assert!(reason(&reply).contains("try again in 250 ms"), "{reply:?}");
    rig.now += FIRST_DELAY_US;
    assert_eq!(authenticate(&mut rig, &mut honest, &KEY), Reply::Ok);
    assert_eq!(rig.status().security.failed_authentications, 2);
    // A success ends the run: the next failure waits the first delay again.
    assert_eq!(
        code(&authenticate(&mut rig, &mut guesser, &[8; 32])),
        Some(ErrorCode::AUTH_FAILED)
    );
    let reply = rig.send_on(&mut guesser, RequestId(6), Command::AuthChallenge);
    assert!(reason(&reply).contains("try again in 250 ms"), "{reply:?}");
}

#[test]
fn unauthenticated_network_sessions_are_closed_when_idle_and_the_reserved_slot_soon() {
    let t0 = 10_000_000;
    let serial = Session::opened(LinkKind::Serial, t0);
    assert_eq!(serial.close_at_us(), None);

    let mut idle = Session::opened(LinkKind::Network, t0);
    assert_eq!(idle.close_at_us(), Some(t0 + UNAUTHENTICATED_IDLE_US));
    idle.heard(t0 + 3_000_000);
    assert_eq!(
        idle.close_at_us(),
        Some(t0 + 3_000_000 + UNAUTHENTICATED_IDLE_US)
    );
    idle.heard(t0 + 1_000_000);
    assert_eq!(
        idle.close_at_us(),
        Some(t0 + 3_000_000 + UNAUTHENTICATED_IDLE_US),
        "an earlier time never moves the deadline back"
    );

    let mut reserved = Session::opened(LinkKind::Network, t0);
    reserved.keep_for_authentication();
    reserved.heard(t0 + 4_000_000);
    assert_eq!(
        reserved.close_at_us(),
        Some(t0 + RESERVED_SLOT_AUTH_US),
        "talking does not keep the reserved slot"
    );

    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut session = Session::opened(LinkKind::Network, t0);
    session.keep_for_authentication();
    let hello = Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    };
    assert!(matches!(
        rig.send_on(&mut session, RequestId(1), hello),
        Reply::Hello(_)
    ));
    authenticated(&mut rig, &mut session);
    assert_eq!(
        session.close_at_us(),
        None,
        "an authenticated session stays"
    );
}

#[test]
fn the_reserved_slot_may_only_authenticate_or_stop_until_it_has_authenticated() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut session = Session::new(LinkKind::Network);
    session.keep_for_authentication();
    let hello = Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    };
    assert!(matches!(
        rig.send_on(&mut session, RequestId(1), hello),
        Reply::Hello(_)
    ));
    let reply = rig.send_on(&mut session, RequestId(2), Command::Status);
    assert_eq!(code(&reply), Some(ErrorCode::BUSY));
    assert!(reason(&reply).contains("kept for a client that authenticates"));
    assert_eq!(
        rig.send_on(&mut session, RequestId(3), Command::EmergencyStop),
        Reply::Ok
    );
    authenticated(&mut rig, &mut session);
    assert!(matches!(
        rig.send_on(&mut session, RequestId(4), Command::Status),
        Reply::Status(_)
    ));
}
