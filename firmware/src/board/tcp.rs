//! The protocol on TCP port [`PORT`], up to [`SESSIONS`] connections at once: one client
//! controls the motors, the others may read status and stop them (see the core's
//! single-controller rule).
//!
//! The last free connection is kept for a client that authenticates: a connection that
//! takes it may only shake hands, authenticate or stop until it has authenticated, and is
//! closed if it has not within a few seconds. Every unauthenticated connection is closed
//! after a few idle seconds (see the core's `Session::close_at_us`), so strangers cannot
//! hold every connection.
//!
//! Keep-alive probes every 5 s and a 15 s timeout close a connection whose client vanished
//! with the Wi-Fi, which releases control for the next client.

use embassy_net::Stack;
use embassy_net::tcp::TcpSocket;
use embassy_time::{Duration, with_timeout};
use portable_atomic::{AtomicUsize, Ordering};

use super::SharedCore;
use super::link;
use super::log::{info, warn};
use crate::session::LinkKind;

/// The TCP port of the protocol.
pub const PORT: u16 = 7878;
/// Connections served at once.
pub const SESSIONS: usize = 3;

const BUFFER: usize = 1024;

/// Connections being served now.
static OPEN: AtomicUsize = AtomicUsize::new(0);
const KEEP_ALIVE: Duration = Duration::from_secs(5);
const TIMEOUT: Duration = Duration::from_secs(15);

/// Accepts and serves connections, one at a time per task instance.
#[embassy_executor::task(pool_size = SESSIONS)]
pub async fn serve(core: &'static SharedCore, stack: Stack<'static>) -> ! {
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
        let reserved = OPEN.fetch_add(1, Ordering::AcqRel) + 1 >= SESSIONS;
        let (mut reader, mut writer) = socket.split();
        link::serve(core, LinkKind::Network, reserved, &mut reader, &mut writer).await;
        OPEN.fetch_sub(1, Ordering::AcqRel);
        socket.close();
        // Let the FIN go out before the buffers are reused.
        let _ = with_timeout(Duration::from_secs(1), socket.flush()).await;
        socket.abort();
    }
}
