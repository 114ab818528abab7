//! The host side of the controller link: addresses, byte transports, framing on async
//! streams and the typed client.

pub mod client;
pub mod endpoint;
pub mod framed;
pub mod key;
pub mod report;
pub mod transport;
mod waiters;

pub use client::{Client, ClientError, ClientOptions, Event, MoveReport, Unknown};
pub use endpoint::{Endpoint, EndpointError};
pub use key::{AccessKey, KeyError};
