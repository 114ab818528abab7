//! Controller addresses: `tcp://HOST:PORT` and `serial://PATH`.

use std::fmt;
use std::str::FromStr;

/// Where a controller is reached.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Endpoint {
    /// A network controller (Wi-Fi board or simulated peer): `tcp://HOST:PORT`.
    Tcp { host: String, port: u16 },
    /// A serial port (USB CDC-ACM or a pseudo-terminal): `serial://PATH`.
    Serial { path: String },
}

impl Endpoint {
    /// Whether the link is trusted (physical access) rather than a network link.
    pub fn is_serial(&self) -> bool {
        matches!(self, Self::Serial { .. })
    }
}

/// Why a controller URL was not understood.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum EndpointError {
    #[error("controller URL {0:?} has no scheme: use tcp://HOST:PORT or serial://PATH")]
    NoScheme(String),
    #[error(
        "controller URL {url:?} has unknown scheme {scheme:?}: use tcp://HOST:PORT or serial://PATH"
    )]
    UnknownScheme { url: String, scheme: String },
    #[error("controller URL {0:?} needs a port: tcp://HOST:PORT")]
    NoPort(String),
    #[error("controller URL {url:?} has an invalid port {port:?}: expected 1-65535")]
    BadPort { url: String, port: String },
    #[error("controller URL {0:?} has an empty host or path")]
    Empty(String),
    #[error(
        "controller URL {0:?} has a malformed host: write an IPv6 address in brackets \
         (tcp://[::1]:7900) and a name or IPv4 address without them"
    )]
    BadHost(String),
}

/// Splits `HOST:PORT` (or `[IPV6]:PORT`) of a tcp URL; brackets must pair up around the
/// whole host, and a host without them may not contain a colon.
fn split_host_port<'a>(url: &str, rest: &'a str) -> Result<(&'a str, &'a str), EndpointError> {
    let bad_host = || EndpointError::BadHost(url.to_owned());
    let (host, after) = match rest.strip_prefix('[') {
        Some(bracketed) => {
            let (host, after) = bracketed.split_once(']').ok_or_else(bad_host)?;
            let port_follows = after.is_empty() || after.starts_with(':');
            if host.contains(['[', ']']) || !host.contains(':') || !port_follows {
                return Err(bad_host());
            }
            (host, after)
        }
        None => {
            let end = rest.find(':').unwrap_or(rest.len());
            let (host, after) = rest.split_at(end);
            if host.contains(['[', ']']) {
                return Err(bad_host());
            }
            (host, after)
        }
    };
    let port = after
        .strip_prefix(':')
        .ok_or_else(|| EndpointError::NoPort(url.to_owned()))?;
    if port.contains(':') {
        return Err(bad_host());
    }
    if host.is_empty() {
        return Err(EndpointError::Empty(url.to_owned()));
    }
    Ok((host, port))
}

impl FromStr for Endpoint {
    type Err = EndpointError;

    fn from_str(url: &str) -> Result<Self, Self::Err> {
        let (scheme, rest) = url
            .split_once("://")
            .ok_or_else(|| EndpointError::NoScheme(url.to_owned()))?;
        match scheme {
            "tcp" => {
                let (host, port) = split_host_port(url, rest)?;
                let port = port
                    .parse::<u16>()
                    .ok()
                    .filter(|&p| p != 0)
                    .ok_or_else(|| EndpointError::BadPort {
                        url: url.to_owned(),
                        port: port.to_owned(),
                    })?;
                Ok(Self::Tcp {
                    host: host.to_owned(),
                    port,
                })
            }
            "serial" if rest.is_empty() => Err(EndpointError::Empty(url.to_owned())),
            "serial" => Ok(Self::Serial {
                path: rest.to_owned(),
            }),
            other => Err(EndpointError::UnknownScheme {
                url: url.to_owned(),
                scheme: other.to_owned(),
            }),
        }
    }
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Tcp { host, port } if host.contains(':') => write!(f, "tcp://[{host}]:{port}"),
            Self::Tcp { host, port } => write!(f, "tcp://{host}:{port}"),
            Self::Serial { path } => write!(f, "serial://{path}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_tcp_serial_and_ipv6() {
        assert_eq!(
            "tcp://127.0.0.1:7900".parse(),
            Ok(Endpoint::Tcp {
                host: "127.0.0.1".into(),
                port: 7900
            })
        );
        assert_eq!(
            "tcp://[::1]:7900".parse(),
            Ok(Endpoint::Tcp {
                host: "::1".into(),
                port: 7900
            })
        );
        assert_eq!(
            "serial:///dev/ttyACM0".parse(),
            Ok(Endpoint::Serial {
                path: "/dev/ttyACM0".into()
            })
        );
        let v6: Endpoint = "tcp://[::1]:1".parse().unwrap();
        assert_eq!(v6.to_string(), "tcp://[::1]:1");
    }

    #[test]
    fn rejects_malformed_urls_with_reasons() {
        assert!(matches!(
            "127.0.0.1:7900".parse::<Endpoint>(),
            Err(EndpointError::NoScheme(_))
        ));
        assert!(matches!(
            "http://x:1".parse::<Endpoint>(),
            Err(EndpointError::UnknownScheme { .. })
        ));
        assert!(matches!(
            "tcp://host".parse::<Endpoint>(),
            Err(EndpointError::NoPort(_))
        ));
        assert!(matches!(
            "tcp://host:99999".parse::<Endpoint>(),
            Err(EndpointError::BadPort { .. })
        ));
        assert!(matches!(
            "tcp://host:0".parse::<Endpoint>(),
            Err(EndpointError::BadPort { .. })
        ));
        assert!(matches!(
            "tcp://:80".parse::<Endpoint>(),
            Err(EndpointError::Empty(_))
        ));
        assert!(matches!(
            "serial://".parse::<Endpoint>(),
            Err(EndpointError::Empty(_))
        ));
        for malformed in [
            "tcp://[::1:5",
            "tcp://::1:5",
            "tcp://[::1]]:5",
            "tcp://[127.0.0.1]:5",
            "tcp://host]:5",
            "tcp://[::1]5",
        ] {
            assert_eq!(
                malformed.parse::<Endpoint>(),
                Err(EndpointError::BadHost(malformed.into())),
                "{malformed}"
            );
        }
        assert!(matches!(
            "tcp://[::1]".parse::<Endpoint>(),
            Err(EndpointError::NoPort(_))
        ));
    }
}
