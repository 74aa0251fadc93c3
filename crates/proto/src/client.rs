//! How clients (workers, the CLI) connect: URL, TLS and the bearer token.

use std::time::Duration;

use tonic::metadata::AsciiMetadataValue;
use tonic::service::Interceptor;
use tonic::transport::{Certificate, ClientTlsConfig, Endpoint, Identity};
use tonic::{Request, Status};

use crate::Secret;

/// TLS settings of a client.
#[derive(Clone, Debug, Default)]
pub struct ClientTls {
    /// PEM CA certificate(s) to trust for the coordinator (default: none, so set it).
    pub ca_pem: Option<Vec<u8>>,
    /// PEM certificate and key to present, for coordinators that require client certificates.
    pub identity: Option<(Vec<u8>, Secret)>,
    /// Name to check the coordinator's certificate against (default: the URL's host).
    pub domain: Option<String>,
}

/// Everything a client needs besides the URL.
#[derive(Clone, Debug, Default)]
pub struct ClientOptions {
    /// Bearer token sent with every call.
    pub token: Option<Secret>,
    /// TLS, required for `https://` URLs.
    pub tls: Option<ClientTls>,
    /// The local address to connect from, on a machine with several (the coordinator knows a
    /// worker's host by it); the system's choice if `None`.
    pub source_address: Option<std::net::IpAddr>,
}

/// Why a client cannot be set up.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// Not a usable URL.
    #[error("coordinator URL {url:?}: {message}")]
    Url {
        /// The URL.
        url: String,
        /// Why.
        message: String,
    },
    /// TLS settings rejected.
    #[error("TLS: {0}")]
    Tls(String),
}

/// An endpoint for `url` with `options`' TLS; `http://` needs no TLS, `https://` needs it.
pub fn endpoint(url: &str, options: &ClientOptions) -> Result<Endpoint, ClientError> {
    let bad = |message: &str| ClientError::Url {
        url: url.to_string(),
        message: message.to_string(),
    };
    let mut ep = Endpoint::from_shared(url.to_string())
        .map_err(|e| bad(&e.to_string()))?
        .connect_timeout(Duration::from_secs(5))
        .tcp_nodelay(true)
        // A connection through a network that dropped silently is noticed within ~10 s
        // instead of hanging until TCP gives up; the channel then reconnects.
        .http2_keep_alive_interval(Duration::from_secs(5))
        .keep_alive_timeout(Duration::from_secs(5))
        .keep_alive_while_idle(true)
        // No unary call (long-polling leases wait 30 s at most) should take this long.
        .timeout(Duration::from_secs(120))
        .local_address(options.source_address);
    if ep.uri().host().is_none() || ep.uri().port_u16().is_none() {
        return Err(bad(
            "must name a host and a port, e.g. http://10.0.0.5:7878",
        ));
    }
    match (ep.uri().scheme_str(), &options.tls) {
        (Some("http"), None) => {}
        (Some("http"), Some(_)) => {
            return Err(bad("TLS options were given, so use an https:// URL"));
        }
        (Some("https"), Some(tls)) => {
            let mut cfg = ClientTlsConfig::new();
            if let Some(ca) = &tls.ca_pem {
                cfg = cfg.ca_certificate(Certificate::from_pem(ca));
            }
            if let Some((cert, key)) = &tls.identity {
                cfg = cfg.identity(Identity::from_pem(cert, key.expose()));
            }
            if let Some(d) = &tls.domain {
                cfg = cfg.domain_name(d.clone());
            }
            ep = ep
                .tls_config(cfg)
                .map_err(|e| ClientError::Tls(e.to_string()))?;
        }
        (Some("https"), None) => {
            return Err(bad(
                "an https:// URL needs --tls-ca (the CA that signed the coordinator's certificate)",
            ));
        }
        _ => return Err(bad("must start with http:// or https://")),
    }
    Ok(ep)
}

/// Adds `authorization: Bearer TOKEN` to every call when a token is set.
#[derive(Clone, Debug, Default)]
pub struct Bearer(Option<AsciiMetadataValue>);

impl Bearer {
    /// The interceptor for `options`' token.
    pub fn new(options: &ClientOptions) -> Self {
        Self(
            options
                .token
                .as_ref()
                .and_then(|t| format!("Bearer {}", t.expose()).parse().ok()),
        )
    }
}

impl Interceptor for Bearer {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        if let Some(v) = &self.0 {
            request.metadata_mut().insert("authorization", v.clone());
        }
        Ok(request)
    }
}

/// Why the coordinator at `url` could not be reached, for a person: the innermost cause of a
/// connection error (tonic's own message is only "tcp connect error" or "dns error") and what
/// to check for it.
pub fn unreachable(url: &str, error: &(dyn std::error::Error + 'static)) -> String {
    let mut cause = error.to_string();
    let mut source = error.source();
    while let Some(s) = source {
        cause = s.to_string();
        source = s.source();
    }
    let lower = cause.to_ascii_lowercase();
    let check = if lower.contains("dns") || lower.contains("lookup") || lower.contains("resolve") {
        "the host name does not resolve here: check the URL's spelling and this machine's DNS"
    } else if lower.contains("refused") {
        "nothing listens there: is the coordinator running, and is this the port it printed as \
         `listening on` (its gRPC port, not the dashboard's)?"
    } else if lower.contains("timed out") || lower.contains("unreachable") {
        "no answer: check the address, the route to it, and any firewall between"
    } else {
        "check the URL (--coordinator or TESSERA_COORDINATOR) and that the coordinator is up"
    };
    format!("cannot reach the coordinator at {url}: {cause} ({check})")
}

#[cfg(test)]
mod unreachable_tests {
    use super::unreachable;

    #[derive(Debug)]
    struct Wrapped(&'static str, std::io::Error);
    impl std::fmt::Display for Wrapped {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str(self.0)
        }
    }
    impl std::error::Error for Wrapped {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.1)
        }
    }

    #[test]
    fn the_innermost_cause_is_named_with_what_to_check() {
        let refused = Wrapped(
            "tcp connect error",
            std::io::Error::new(std::io::ErrorKind::ConnectionRefused, "Connection refused"),
        );
        let m = unreachable("http://farm:7878", &refused);
        assert!(
            m.contains("http://farm:7878: Connection refused") && m.contains("listening on"),
            "{m}"
        );
        let dns = Wrapped(
            "dns error",
            std::io::Error::other("failed to lookup address information"),
        );
        assert!(unreachable("http://nowhere:1", &dns).contains("does not resolve"));
    }
}
