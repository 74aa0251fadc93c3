//! The farm commands: `coordinator` and `worker` (the servers, in [`servers`]), and `submit`,
//! `status`, `cancel`, `workers` and `fetch` (clients of a coordinator's `Jobs` service, in
//! [`client`]). What they share is here: where the coordinator is and how to prove who one is,
//! the async runtime, logging and the shutdown signal.

mod client;
mod servers;

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context, Result};
use tessera_proto::client::{ClientOptions, ClientTls};
use tessera_proto::{parse_token, Secret};

pub use client::{
    cancel, fetch, logs, pause, priority, retry, status, submit, workers, CancelArgs, FetchArgs,
    LogsArgs, PauseArgs, PriorityArgs, RetryArgs, StatusArgs, SubmitArgs, WorkersArgs,
};
pub use servers::{coordinator, worker, CoordinatorArgs, WorkerArgs};

/// Where client commands find the coordinator, and how they prove who they are.
#[derive(Debug, clap::Args)]
pub struct CoordinatorUrl {
    /// Coordinator URL (https:// with --tls-ca for TLS).
    #[arg(
        long,
        env = "TESSERA_COORDINATOR",
        default_value = "http://127.0.0.1:7878"
    )]
    coordinator: String,
    /// File holding the farm's token (default: the TESSERA_TOKEN environment variable, if set).
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// PEM CA certificate that signed the coordinator's certificate (enables TLS).
    #[arg(long)]
    tls_ca: Option<PathBuf>,
    /// PEM client certificate, for coordinators that require one (mutual TLS).
    #[arg(long, requires = "tls_key")]
    tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert.
    #[arg(long, requires = "tls_cert")]
    tls_key: Option<PathBuf>,
    /// Name to check the coordinator's certificate against (default: the URL's host).
    #[arg(long)]
    tls_domain: Option<String>,
}

fn read_file(what: &str, path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("{what} {}: cannot read", path.display()))
}

/// The token from `--token-file`, or else from `TESSERA_TOKEN`. Read by hand rather than by
/// clap's `env`, so that `--help` can never print it.
fn load_token(file: Option<&Path>) -> Result<Option<Secret>> {
    let (text, source) = match file {
        Some(p) => {
            warn_if_others_can_read(p);
            (
                String::from_utf8(read_file("--token-file", p)?)
                    .map_err(|_| anyhow!("--token-file {}: not text", p.display()))?,
                format!("--token-file {}", p.display()),
            )
        }
        None => match std::env::var("TESSERA_TOKEN") {
            Ok(t) if !t.trim().is_empty() => (t, "TESSERA_TOKEN".to_string()),
            _ => return Ok(None),
        },
    };
    parse_token(&text)
        .map(Some)
        .map_err(|e| anyhow!("{source}: {e}"))
}

/// Warns when a token file can be read by others than its owner: whoever reads it can act as
/// any client or worker of the farm.
pub(super) fn warn_if_others_can_read(path: &Path) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        if let Ok(m) = std::fs::metadata(path) {
            let mode = m.permissions().mode() & 0o777;
            if mode & 0o077 != 0 {
                errln!(
                    "warning: --token-file {} can be read by others (mode {mode:03o}); `chmod 600 {}`",
                    path.display(),
                    path.display()
                );
            }
        }
    }
}

impl CoordinatorUrl {
    fn options(&self) -> Result<ClientOptions> {
        let tls = if self.tls_ca.is_some() || self.tls_cert.is_some() {
            let identity = match (&self.tls_cert, &self.tls_key) {
                (Some(c), Some(k)) => Some((
                    read_file("--tls-cert", c)?,
                    Secret::new(String::from_utf8_lossy(&read_file("--tls-key", k)?)),
                )),
                _ => None,
            };
            Some(ClientTls {
                ca_pem: self
                    .tls_ca
                    .as_deref()
                    .map(|p| read_file("--tls-ca", p))
                    .transpose()?,
                identity,
                domain: self.tls_domain.clone(),
            })
        } else {
            None
        };
        Ok(ClientOptions {
            token: load_token(self.token_file.as_deref())?,
            tls,
            source_address: None,
        })
    }
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")
}

/// Logs to stderr; `RUST_LOG` overrides the default `info`.
fn init_logging() {
    use std::io::IsTerminal as _;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    // Colour codes only for a person at a terminal, not in a log file or `docker logs`.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .try_init();
}

/// Completes on Ctrl-C or SIGTERM.
async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
    tracing::info!("signal received, shutting down");
}
