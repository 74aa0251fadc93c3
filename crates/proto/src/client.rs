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
