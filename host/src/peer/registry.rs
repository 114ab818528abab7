//! The simulated peers running in this process, by the address they serve. A simulated
//! camera uses it to find the true shaft positions behind a controller URL, the way a real
//! camera sees the real mirrors behind a real controller.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, OnceLock, Weak};

use super::server::SimPeer;

fn peers() -> &'static Mutex<HashMap<SocketAddr, Weak<SimPeer>>> {
    static PEERS: OnceLock<Mutex<HashMap<SocketAddr, Weak<SimPeer>>>> = OnceLock::new();
    PEERS.get_or_init(Mutex::default)
}

/// Records that `peer` serves `address`.
pub(crate) fn register(address: SocketAddr, peer: &Arc<SimPeer>) {
    let mut peers = peers().lock().unwrap_or_else(|e| e.into_inner());
    peers.retain(|_, weak| weak.strong_count() > 0);
    peers.insert(address, Arc::downgrade(peer));
}

/// The simulated peer in this process serving `address`, if any.
pub fn lookup(address: SocketAddr) -> Option<Arc<SimPeer>> {
    peers()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .get(&address)
        .and_then(Weak::upgrade)
}
