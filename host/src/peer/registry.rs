//! The simulated peers running in this process, by the address or pseudo-terminal they
//! serve. A simulated camera uses it to find the true shaft positions behind a controller
//! URL, the way a real camera sees the real mirrors behind a real controller.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, OnceLock, Weak};

use super::server::SimPeer;
use crate::link::Endpoint;

/// Where a peer is served.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
enum Served {
    Tcp(SocketAddr),
    Serial(String),
}

fn peers() -> &'static Mutex<HashMap<Served, Weak<SimPeer>>> {
    static PEERS: OnceLock<Mutex<HashMap<Served, Weak<SimPeer>>>> = OnceLock::new();
    PEERS.get_or_init(Mutex::default)
}

fn register(served: Served, peer: &Arc<SimPeer>) {
    let mut peers = peers().lock().unwrap_or_else(|e| e.into_inner());
    peers.retain(|_, weak| weak.strong_count() > 0);
    peers.insert(served, Arc::downgrade(peer));
}

/// Records that `peer` serves TCP at `address`.
pub(crate) fn register_tcp(address: SocketAddr, peer: &Arc<SimPeer>) {
    register(Served::Tcp(address), peer);
}

/// Records that `peer` serves its serial link on the pseudo-terminal `path`.
pub(crate) fn register_serial(path: &str, peer: &Arc<SimPeer>) {
    register(Served::Serial(path.to_owned()), peer);
}

/// The simulated peer in this process behind `endpoint`, if any.
pub fn lookup(endpoint: &Endpoint) -> Option<Arc<SimPeer>> {
    let served = match endpoint {
        Endpoint::Tcp { host, port } => Served::Tcp(format!("{host}:{port}").parse().ok()?),
        Endpoint::Serial { path } => Served::Serial(path.clone()),
    };
    peers()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .get(&served)
        .and_then(Weak::upgrade)
}
