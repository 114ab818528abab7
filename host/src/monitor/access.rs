//! Who may use a monitor: on a loopback address anyone on this machine; on any other
//! address (or when asked for) only a client that presents the random token printed in the
//! monitor's URL, on every request, the stop included.

use std::net::SocketAddr;

use axum::extract::{Request, State};
use axum::http::StatusCode;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use rand::Rng;

/// The query parameter that carries the token.
pub const TOKEN_PARAMETER: &str = "token";

/// A monitor's access rule.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Access {
    /// Required on every request when set.
    pub token: Option<String>,
}

impl Access {
    /// Open on a loopback address; a fresh random token otherwise, or when `force_token`.
    pub fn for_address(address: SocketAddr, force_token: bool) -> Self {
        let token = (force_token || !address.ip().is_loopback()).then(random_token);
        Self { token }
    }

    /// The URL to print for `address` (the token included when one is needed).
    pub fn url(&self, address: SocketAddr) -> String {
        match &self.token {
            Some(token) => format!("http://{address}/?{TOKEN_PARAMETER}={token}"),
            None => format!("http://{address}/"),
        }
    }

    /// Whether a request with this query string may pass.
    pub fn allows(&self, query: Option<&str>) -> bool {
        let Some(expected) = &self.token else {
            return true;
        };
        query
            .into_iter()
            .flat_map(|q| q.split('&'))
            .filter_map(|pair| pair.split_once('='))
            .any(|(name, value)| name == TOKEN_PARAMETER && same_secret(value, expected))
    }
}

/// 128 random bits as hex.
fn random_token() -> String {
    let bytes: [u8; 16] = rand::rng().random();
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Compares without stopping at the first difference.
fn same_secret(given: &str, expected: &str) -> bool {
    given.len() == expected.len()
        && given
            .bytes()
            .zip(expected.bytes())
            .fold(0u8, |acc, (a, b)| acc | (a ^ b))
            == 0
}

/// The guard in front of every route.
pub async fn guard(State(access): State<Access>, request: Request, next: Next) -> Response {
    if access.allows(request.uri().query()) {
        next.run(request).await
    } else {
        (
            StatusCode::UNAUTHORIZED,
            "this monitor needs the token from the URL it printed (?token=...)\n",
        )
            .into_response()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_is_open_and_other_addresses_need_a_random_token() {
        let open = Access::for_address("127.0.0.1:8787".parse().unwrap(), false);
        assert_eq!(open.token, None);
        assert!(open.allows(None));
        assert_eq!(
            open.url("127.0.0.1:8787".parse().unwrap()),
            "http://127.0.0.1:8787/"
        );
        assert_eq!(
            Access::for_address("[::1]:1".parse().unwrap(), false).token,
            None
        );

        let remote = Access::for_address("0.0.0.0:8787".parse().unwrap(), false);
        let token = remote.token.clone().expect("a token off loopback");
        assert_eq!(token.len(), 32);
        assert_ne!(
            Access::for_address("0.0.0.0:8787".parse().unwrap(), false).token,
            Some(token.clone()),
            "each monitor draws its own token"
        );
        assert!(!remote.allows(None));
        assert!(!remote.allows(Some("token=")));
        assert!(!remote.allows(Some(&format!("token={}x", token))));
        assert!(!remote.allows(Some(&format!("other={token}"))));
        assert!(remote.allows(Some(&format!("since=3&token={token}"))));
        assert!(
            remote
                .url("0.0.0.0:8787".parse().unwrap())
                .ends_with(&format!("/?token={token}"))
        );
        assert!(
            Access::for_address("127.0.0.1:1".parse().unwrap(), true)
                .token
                .is_some()
        );
    }
}
