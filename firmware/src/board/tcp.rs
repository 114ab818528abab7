//! The protocol on TCP port [`PORT`]: [`SESSIONS`] sockets, one per task, each accepting
//! and serving one connection at a time; one client controls the motors, the others may
//! read status and stop them (see the core's single-controller rule).
//!
//! Who is served is the core's admission table's decision ([`crate::admission`], held in
//! [`link::NETWORK`]): [`link::SLOTS`] connections in slots, and one more socket for the
//! lobby, where a newcomer may shake hands and stop until a request of its own earns it a
//! slot, evicting an unauthenticated connection (whose task is told through its
//! [`link::EVICTED`] signal). Strangers holding connections therefore cannot keep out a
//! client with the key, nor an emergency stop.
//!
//! Keep-alive probes every 5 s and a 15 s timeout close a connection whose client vanished
//! with the Wi-Fi, which releases control for the next client.

use embassy_net::Stack;
use embassy_net::tcp::TcpSocket;
use embassy_time::{Duration, with_timeout};
use portable_atomic::{AtomicUsize, Ordering};

use super::link::{self, NETWORK};
use super::log::{info, warn};
use super::{SharedCore, now_us};
use crate::admission::{Admission, LOBBY};
use crate::connection::{Connection, Deadlines};
use crate::session::LinkKind;

/// The TCP port of the protocol.
pub const PORT: u16 = 7878;
/// Connections open at once (sockets, and tasks serving them).
pub const SESSIONS: usize = link::SLOTS + LOBBY;

const BUFFER: usize = 1024;
const KEEP_ALIVE: Duration = Duration::from_secs(5);
const TIMEOUT: Duration = Duration::from_secs(15);

/// Hands each task its index (its token in the admission table).
static TASKS: AtomicUsize = AtomicUsize::new(0);

/// Accepts and serves connections, one at a time per task instance.
#[embassy_executor::task(pool_size = SESSIONS)]
pub async fn serve(core: &'static SharedCore, stack: Stack<'static>) -> ! {
    let index = TASKS.fetch_add(1, Ordering::AcqRel);
    let mut rx = [0u8; BUFFER];
    let mut tx = [0u8; BUFFER];
    loop {
        stack.wait_config_up().await;
        let mut socket = TcpSocket::new(stack, &mut rx, &mut tx);
        socket.set_keep_alive(Some(KEEP_ALIVE));
        socket.set_timeout(Some(TIMEOUT));
        if let Err(error) = socket.accept(PORT).await {
            warn!("tcp: accept failed: {}", error);
            continue;
        }
        info!("tcp: client {}", socket.remote_endpoint());
        let mine = link::EVICTED.get(index);
        if let Some(signal) = mine {
            // A signal meant for this task's previous connection.
            signal.reset();
        }
        let now = now_us();
        let admission = NETWORK.lock(|table| table.borrow_mut().admit(now, index));
        let ticket = match admission {
            Admission::Slot(ticket) => Some(ticket),
            Admission::Lobby { ticket, evicted } => {
                link::evict(evicted);
                Some(ticket)
            }
            Admission::Refused => None,
        };
        if let Some(ticket) = ticket {
            let connection = Connection::open(LinkKind::Network, ticket, now, Deadlines::STANDARD);
            let (mut reader, mut writer) = socket.split();
            link::serve(core, connection, &mut reader, &mut writer, mine).await;
        } else {
            warn!("tcp: the lobby is full of clients that spoke: closing");
        }
        socket.close();
        // Let the FIN go out before the buffers are reused.
        let _ = with_timeout(Duration::from_secs(1), socket.flush()).await;
        socket.abort();
    }
}
