//! Network sessions under attack: sealed frames after authentication, the backoff after
//! failed authentications, and closing unauthenticated connections.

use optalign_protocol::auth::session_key;
use optalign_protocol::seal::{Direction, Inbound, Opener, Sealer};
use optalign_protocol::{
    Command, ErrorCode, FrameDecoder, FrameError, MAX_FRAME, PROTOCOL_VERSION, PeerMessage,
    RefusalDetail, Reply, Request, RequestId, encode_frame, encode_sealed_frame,
};

use super::dispatch::{
    CLIENT_NONCE, KEY, a_move, authenticate, code, detail, network, plain, reason, response,
};
use super::rig::Rig;
use crate::admission::{MAX_SLOTS, Standing, Ticket};
use crate::backoff::FIRST_DELAY_US;
use crate::{Connection, Deadlines, LinkKind, Port, Received, Session};

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
    assert_eq!(detail(&reply), Some(RefusalDetail::RetryAfterMs(250)));
    rig.now += 100_000;
    let reply = rig.send_on(&mut guesser, RequestId(4), Command::AuthChallenge);
    assert_eq!(code(&reply), Some(ErrorCode::AUTH_BACKOFF));
    assert_eq!(detail(&reply), Some(RefusalDetail::RetryAfterMs(150)));

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

/// The rig as an embedder's [`Port`], noting what it is told about standing and ends, and
/// giving a lobby connection `slot` when asked for one.
struct RigPort<'a> {
    rig: &'a mut Rig,
    standings: Vec<(Ticket, Standing)>,
    ended: Vec<Ticket>,
    slot: Option<Ticket>,
}

impl<'a> RigPort<'a> {
    fn new(rig: &'a mut Rig) -> Self {
        Self {
            rig,
            standings: Vec::new(),
            ended: Vec::new(),
            slot: None,
        }
    }
}

const SLOT: Ticket = Ticket::Network {
    index: 0,
    generation: 1,
};

const LOBBY: Ticket = Ticket::Network {
    index: MAX_SLOTS as u8,
    generation: 2,
};

impl Port for RigPort<'_> {
    fn request(
        &mut self,
        session: &mut Session,
        request: &Request,
        out: &mut dyn FnMut(PeerMessage),
    ) {
        let rig = &mut *self.rig;
        rig.controller
            .handle(session, request, rig.now, &mut rig.rng, out);
    }

    fn link_error(&mut self, error: FrameError, out: &mut dyn FnMut(PeerMessage)) {
        self.rig.controller.link_error(error, out);
    }

    fn standing(&mut self, ticket: Ticket, standing: Standing) {
        self.standings.push((ticket, standing));
    }

    fn promote(&mut self, ticket: Ticket) -> Option<Ticket> {
        assert_eq!(ticket, LOBBY, "only a lobby connection asks");
        self.slot
    }

    fn end(&mut self, session: &mut Session, ticket: Ticket) {
        self.rig.controller.end_session(session);
        self.ended.push(ticket);
    }
}

/// Feeds `bytes` to `connection` at `now`; what it answers, and whether it closes.
fn feed(
    connection: &mut Connection,
    port: &mut RigPort,
    now: u64,
    bytes: &[u8],
) -> (Vec<PeerMessage>, bool) {
    let mut out = Vec::new();
    for &byte in bytes {
        match connection.receive(byte, now, port) {
            Received::Nothing => {}
            Received::Send(message) => out.push(message),
            Received::SendAndClose(message) => {
                out.push(message);
                return (out, true);
            }
        }
    }
    (out, false)
}

fn request_frame(id: u32, command: Command) -> Vec<u8> {
    frame(
        &Request {
            id: RequestId(id),
            command,
        },
        None,
    )
}

fn hello() -> Command {
    Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    }
}

fn replied(messages: &[PeerMessage]) -> Vec<Reply> {
    messages
        .iter()
        .filter_map(|m| match m {
            PeerMessage::Reply { reply, .. } => Some(reply.clone()),
            _ => None,
        })
        .collect()
}

#[test]
fn unauthenticated_network_connections_are_closed_when_idle_and_lobby_ones_soon() {
    let t0 = 10_000_000;
    let deadlines = Deadlines::STANDARD;
    let slot = SLOT;
    let serial = Connection::open(LinkKind::Serial, Ticket::Serial, t0, deadlines);
    assert_eq!(serial.close_at_us(), None);

    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut port = RigPort::new(&mut rig);
    let mut idle = Connection::open(LinkKind::Network, slot, t0, deadlines);
    assert_eq!(idle.close_at_us(), Some(t0 + deadlines.idle_us));
    feed(
        &mut idle,
        &mut port,
        t0 + 3_000_000,
        &request_frame(1, hello()),
    );
    assert_eq!(idle.close_at_us(), Some(t0 + 3_000_000 + deadlines.idle_us));
    // Garbage is not a request: it keeps nobody open.
    feed(&mut idle, &mut port, t0 + 4_000_000, &[1, 2, 3, 0]);
    assert_eq!(idle.close_at_us(), Some(t0 + 3_000_000 + deadlines.idle_us));
    assert_eq!(port.standings, [(slot, Standing::Spoke)]);
    assert_eq!(
        idle.send_deadline_us(t0 + 5_000_000),
        t0 + 5_000_000 + deadlines.send_us
    );

    let mut stop_only = Connection::open(LinkKind::Network, LOBBY, t0, deadlines);
    feed(
        &mut stop_only,
        &mut port,
        t0 + 1_000_000,
        &request_frame(1, hello()),
    );
    assert_eq!(
        stop_only.close_at_us(),
        Some(t0 + deadlines.stop_only_us),
        "talking does not keep a lobby connection"
    );

    // Authenticated through the connection: never closed for idleness, and its standing
    // reaches the admission table.
    let Received::Send(PeerMessage::Reply {
        reply: Reply::Challenge { nonce },
        ..
    }) = request_frame(2, Command::AuthChallenge)
        .iter()
        .map(|&b| idle.receive(b, t0 + 5_000_000, &mut port))
        .last()
        .unwrap()
    else {
        panic!("no challenge");
    };
    let (out, closed) = feed(
        &mut idle,
        &mut port,
        t0 + 5_000_000,
        &request_frame(3, response(&KEY, &nonce)),
    );
    assert_eq!(replied(&out), [Reply::Ok]);
    assert!(!closed);
    assert_eq!(
        idle.close_at_us(),
        None,
        "an authenticated connection stays"
    );
    assert_eq!(
        port.standings.last(),
        Some(&(slot, Standing::Authenticated))
    );
    // From the confirming reply on, its frames are sealed.
    let mut buf = [0u8; MAX_FRAME];
    let plain_len = encode_frame(&out[0], &mut buf).unwrap();
    let sealed_len = idle.encode(&out[0], &mut buf).unwrap();
    assert!(sealed_len > plain_len, "sealed: {sealed_len} > {plain_len}");
    idle.end(&mut port);
    assert_eq!(port.ended, [slot]);
}

#[test]
fn a_lobby_connection_may_only_shake_hands_and_stop_and_is_closed_after_anything_else() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut port = RigPort::new(&mut rig);
    let mut connection = Connection::open(LinkKind::Network, LOBBY, 0, Deadlines::STANDARD);
    let (out, closed) = feed(&mut connection, &mut port, 0, &request_frame(1, hello()));
    assert!(matches!(replied(&out)[..], [Reply::Hello(_)]), "{out:?}");
    assert!(!closed);
    let (out, closed) = feed(
        &mut connection,
        &mut port,
        0,
        &request_frame(2, Command::EmergencyStop),
    );
    assert_eq!(replied(&out), [Reply::Ok]);
    assert!(!closed);
    assert!(port.rig.status().emergency_stopped);

    for command in [Command::Status, Command::AuthChallenge] {
        let mut connection = Connection::open(LinkKind::Network, LOBBY, 0, Deadlines::STANDARD);
        feed(&mut connection, &mut port, 0, &request_frame(1, hello()));
        let (out, closed) = feed(&mut connection, &mut port, 0, &request_frame(2, command));
        let [reply] = &replied(&out)[..] else {
            panic!("{out:?}");
        };
        assert_eq!(code(reply), Some(ErrorCode::BUSY));
        assert!(
            reason(reply).contains("only Hello and EmergencyStop"),
            "{reply:?}"
        );
        assert!(closed, "closed after the refusal");
    }

    // Given a slot when it speaks, it has full rights from that request on, and its
    // deadlines are those of a slot.
    port.slot = Some(SLOT);
    let mut connection = Connection::open(LinkKind::Network, LOBBY, 0, Deadlines::STANDARD);
    feed(&mut connection, &mut port, 10, &request_frame(1, hello()));
    assert_eq!(connection.ticket(), SLOT);
    assert_eq!(
        connection.close_at_us(),
        Some(10 + Deadlines::STANDARD.idle_us)
    );
    let (out, closed) = feed(
        &mut connection,
        &mut port,
        20,
        &request_frame(2, Command::Status),
    );
    assert!(matches!(replied(&out)[..], [Reply::Status(_)]), "{out:?}");
    assert!(!closed);
    assert_eq!(port.standings.last(), Some(&(SLOT, Standing::Spoke)));
}

/// Sends `command` on `session` through the two halves, running the cryptography with the
/// controller untouched in between, and `between` then; the reply.
fn split(
    rig: &mut Rig,
    session: &mut Session,
    id: u32,
    command: Command,
    between: impl FnOnce(&mut Rig),
) -> Reply {
    let request = Request {
        id: RequestId(id),
        command,
    };
    let mut replies = Vec::new();
    let work = rig
        .controller
        .begin(session, &request, rig.now, &mut |m| replies.push(m));
    let work = work.expect("authentication leaves work to do");
    assert!(replies.is_empty(), "no reply before the work is done");
    let done = work.run(&mut rig.rng);
    between(rig);
    rig.controller
        .finish(session, &request, done, rig.now, &mut |m| replies.push(m));
    match replies.as_slice() {
        [PeerMessage::Reply { id: got, reply }] if got.0 == id => reply.clone(),
        other => panic!("expected one reply to {id}: {other:?}"),
    }
}

#[test]
fn authentication_in_two_halves_answers_as_in_one_and_refuses_a_key_changed_between() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    // Challenge and response through begin / run / finish: authenticated and sealed.
    let mut session = network(&mut rig);
    let Reply::Challenge { nonce } =
        split(&mut rig, &mut session, 2, Command::AuthChallenge, |_| {})
    else {
        panic!("no challenge");
    };
    assert_eq!(
        split(&mut rig, &mut session, 3, response(&KEY, &nonce), |_| {}),
        Reply::Ok
    );
    assert!(session.has_authenticated());
    assert!(session.take_sealer().is_some(), "the reply is sealed");
    // Everything else is answered by `begin` alone.
    let mut replies = Vec::new();
    let status = Request {
        id: RequestId(4),
        command: Command::Status,
    };
    assert!(
        rig.controller
            .begin(&mut session, &status, rig.now, &mut |m| replies.push(m))
            .is_none()
    );
    assert_eq!(replies.len(), 1);

    // A response checked against a key that the serial link replaced meanwhile: refused,
    // neither authenticated nor counted as a guess.
    let mut late = network(&mut rig);
    let Reply::Challenge { nonce } = split(&mut rig, &mut late, 2, Command::AuthChallenge, |_| {})
    else {
        panic!("no challenge");
    };
    let reply = split(&mut rig, &mut late, 3, response(&KEY, &nonce), |rig| {
        rig.ok(Command::SetKey { key: [9; 32] })
    });
    assert_eq!(code(&reply), Some(ErrorCode::AUTH_FAILED));
    assert!(reason(&reply).contains("key changed"), "{reply:?}");
    assert!(!late.has_authenticated());
    assert_eq!(rig.status().security.failed_authentications, 0);
}
