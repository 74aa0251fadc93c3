//! The farm commands: `coordinator` and `worker` (servers), and `submit`, `status`, `cancel`,
//! `workers` and `fetch` (clients of a coordinator's `Jobs` service).

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use indicatif::ProgressBar;
use tessera_coordinator::{config, ServerTls};
use tessera_proto::client::{endpoint, Bearer, ClientOptions, ClientTls};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_client::JobsClient;
use tessera_proto::{parse_token, Secret};
use tessera_render::scene::Limits;
use tessera_render::{DEFAULT_TILE, TILE_RANGE};

/// clap's parser for a tile edge in [`TILE_RANGE`].
fn tile_range() -> clap::builder::RangedI64ValueParser<u32> {
    clap::value_parser!(u32).range(i64::from(*TILE_RANGE.start())..=i64::from(*TILE_RANGE.end()))
}

use crate::render::{check_extension, check_output_dir};
use crate::{printable, progress_style};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;
use tonic::Code;

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
fn warn_if_others_can_read(path: &Path) {
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
        })
    }
}

/// Arguments of `tessera coordinator`.
#[derive(Debug, clap::Args)]
pub struct CoordinatorArgs {
    /// Address to listen on (use 0.0.0.0:7878 to accept workers from other machines).
    #[arg(long, default_value = "127.0.0.1:7878")]
    listen: String,
    /// Directory for the durable state (jobs, scenes, merged sums).
    #[arg(long)]
    data_dir: PathBuf,
    /// Directory for finished EXRs (default: DATA_DIR/output).
    #[arg(long)]
    output_dir: Option<PathBuf>,
    /// Seconds a lease lasts without a heartbeat before its unit is handed to another worker.
    #[arg(long, default_value_t = config::DEFAULT_LEASE_TIMEOUT.as_secs_f64())]
    lease_timeout: f64,
    /// Default tile edge in pixels for jobs that do not choose one.
    #[arg(long, default_value_t = DEFAULT_TILE, value_parser = tile_range())]
    tile_size: u32,
    /// Largest scene accepted, in bytes.
    #[arg(long, default_value_t = config::DEFAULT_MAX_SCENE_BYTES)]
    max_scene_bytes: usize,
    /// Largest spp accepted.
    #[arg(long, default_value_t = Limits::default().max_spp)]
    max_spp: u32,
    /// Largest image width or height accepted.
    #[arg(long, default_value_t = Limits::default().max_resolution)]
    max_resolution: u32,
    /// File holding the farm's token; every RPC must then carry it (default: the
    /// TESSERA_TOKEN environment variable, if set; without either, no token is required).
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// PEM certificate chain to serve TLS with (needs --tls-key).
    #[arg(long, requires = "tls_key")]
    tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert.
    #[arg(long, requires = "tls_cert")]
    tls_key: Option<PathBuf>,
    /// PEM CA: clients must present a certificate it signed (mutual TLS; needs --tls-cert).
    #[arg(long, requires = "tls_cert")]
    tls_client_ca: Option<PathBuf>,
    /// Invalid results after which a worker is quarantined.
    #[arg(long, default_value_t = config::DEFAULT_QUARANTINE_AFTER, value_parser = clap::value_parser!(u64).range(1..))]
    quarantine_after: u64,
    /// Most units one worker may hold at once (a stock worker holds at most 3).
    #[arg(long, default_value_t = config::DEFAULT_MAX_LEASES_PER_WORKER as u32, value_parser = clap::value_parser!(u32).range(1..=4096))]
    max_leases_per_worker: u32,
    /// Most client connections open at once.
    #[arg(long, default_value_t = config::DEFAULT_MAX_CONNECTIONS as u32, value_parser = clap::value_parser!(u32).range(1..))]
    max_connections: u32,
}

/// Arguments of `tessera worker`.
#[derive(Debug, clap::Args)]
pub struct WorkerArgs {
    #[command(flatten)]
    url: CoordinatorUrl,
    /// Render threads (default: every core).
    #[arg(long, env = "TESSERA_WORKER_THREADS", value_parser = clap::value_parser!(u32).range(1..=4096))]
    threads: Option<u32>,
    /// Name shown by `tessera workers` (default: the host name).
    #[arg(long)]
    name: Option<String>,
}

/// Arguments of `tessera submit`.
#[derive(Debug, clap::Args)]
pub struct SubmitArgs {
    /// Scene file (TOML, or JSON by its .json extension).
    scene: PathBuf,
    #[command(flatten)]
    url: CoordinatorUrl,
    #[command(flatten)]
    settings: crate::render::SettingsArgs,
    /// Tile edge in pixels (default: the coordinator's).
    #[arg(long, value_parser = tile_range())]
    tile_size: Option<u32>,
    /// Higher runs first.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    priority: i32,
    /// File name of the EXR in the coordinator's output directory (default: JOB.exr).
    #[arg(long)]
    name: Option<String>,
    /// Add variance-of-the-mean channels to the EXR.
    #[arg(long)]
    variance: bool,
    /// Add a per-pixel sample-count channel to the EXR.
    #[arg(long)]
    sample_count: bool,
    /// Follow the job with a progress bar, then fetch its EXR.
    #[arg(long)]
    wait: bool,
    /// Where `--wait` saves the EXR (default: the job's output name, here).
    #[arg(long, short)]
    output: Option<PathBuf>,
}

/// Arguments of `tessera status`.
#[derive(Debug, clap::Args)]
pub struct StatusArgs {
    /// A job id; without it, every job is listed.
    job: Option<String>,
    #[command(flatten)]
    url: CoordinatorUrl,
}

/// Arguments of `tessera cancel`.
#[derive(Debug, clap::Args)]
pub struct CancelArgs {
    /// Job id.
    job: String,
    #[command(flatten)]
    url: CoordinatorUrl,
}

/// Arguments of `tessera workers`.
#[derive(Debug, clap::Args)]
pub struct WorkersArgs {
    #[command(flatten)]
    url: CoordinatorUrl,
}

/// Arguments of `tessera fetch`.
#[derive(Debug, clap::Args)]
pub struct FetchArgs {
    /// Job id.
    job: String,
    #[command(flatten)]
    url: CoordinatorUrl,
    /// Where to save the EXR.
    #[arg(long, short)]
    output: PathBuf,
    /// Wait for the job to finish first.
    #[arg(long)]
    wait: bool,
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

/// Runs `tessera coordinator`.
pub fn coordinator(args: CoordinatorArgs) -> Result<()> {
    if !(args.lease_timeout.is_finite() && (0.1..=86_400.0).contains(&args.lease_timeout)) {
        bail!(
            "--lease-timeout must be between 0.1 and 86400 seconds, got {}",
            args.lease_timeout
        );
    }
    init_logging();
    let mut config = tessera_coordinator::Config::new(&args.data_dir);
    config.output_dir = args.output_dir;
    config.lease_timeout = Duration::from_secs_f64(args.lease_timeout);
    config.default_tile_size = args.tile_size;
    config.limits.max_bytes = args.max_scene_bytes;
    config.limits.max_spp = args.max_spp;
    config.limits.max_resolution = args.max_resolution;
    config.max_message_bytes = config
        .max_message_bytes
        .max(args.max_scene_bytes + (1 << 20));
    config.quarantine_after = args.quarantine_after;
    config.max_leases_per_worker = args.max_leases_per_worker as usize;
    config.max_connections = args.max_connections as usize;
    config.token = load_token(args.token_file.as_deref())?;
    if let (Some(cert), Some(key)) = (&args.tls_cert, &args.tls_key) {
        config.tls = Some(ServerTls {
            cert_pem: read_file("--tls-cert", cert)?,
            key_pem: Secret::new(String::from_utf8_lossy(&read_file("--tls-key", key)?)),
            client_ca_pem: args
                .tls_client_ca
                .as_deref()
                .map(|p| read_file("--tls-client-ca", p))
                .transpose()?,
        });
    }
    let auth = match (&config.token, &config.tls) {
        (Some(_), Some(_)) => "token and TLS",
        (Some(_), None) => "token (no TLS: the token crosses the network in clear)",
        (None, Some(_)) => "TLS, no token",
        (None, None) => "none: anyone who can connect may submit, lease and fetch",
    };
    runtime()?.block_on(async {
        let listener = tokio::net::TcpListener::bind(&args.listen)
            .await
            .with_context(|| format!("--listen {}: cannot listen", args.listen))?;
        let addr = listener.local_addr()?;
        // Said once the store is open and the TLS key loaded, so that a script (or a person)
        // waiting for it knows the coordinator is really up; a failure before that is the
        // one line of the error instead. stdout is line-buffered, so the newline sends it.
        // Best effort: a script that read it and closed the pipe must not stop the server.
        let ready = move || {
            tracing::info!("auth: {auth}");
            let _ = writeln!(std::io::stdout(), "listening on {addr}");
        };
        tessera_coordinator::serve_when_ready(config, listener, shutdown_signal(), ready).await?;
        Ok(())
    })
}

/// Runs `tessera worker`.
pub fn worker(args: WorkerArgs) -> Result<()> {
    init_logging();
    let options = args.url.options()?;
    let mut config = tessera_worker::Config::new(args.url.coordinator);
    config.client = options;
    config.threads = args.threads.map(|t| t as usize);
    config.name = match args.name {
        Some(n) => n,
        None => hostname::get()
            .ok()
            .and_then(|h| h.into_string().ok())
            .unwrap_or_else(|| "worker".into()),
    };
    runtime()?.block_on(tessera_worker::run(config, shutdown_signal()))?;
    Ok(())
}

/// Turns a gRPC error into one line that says what failed.
fn rpc_error(url: &str, what: &str, e: tonic::Status) -> anyhow::Error {
    match e.code() {
        Code::Unavailable => anyhow!("cannot reach the coordinator at {url}: {}", e.message()),
        _ if e.message().contains(what) => anyhow!("{}", e.message()),
        _ => anyhow!("{what}: {}", e.message()),
    }
}

/// A `Jobs` client with the token attached.
type Client = JobsClient<InterceptedService<Channel, Bearer>>;

async fn connect(args: &CoordinatorUrl) -> Result<Client> {
    let url = &args.coordinator;
    let options = args.options()?;
    let endpoint = endpoint(url, &options)?;
    let channel = endpoint.connect().await.map_err(|e| {
        let mut msg = e.to_string();
        let mut src = std::error::Error::source(&e);
        while let Some(s) = src {
            msg = s.to_string();
            src = s.source();
        }
        anyhow!("cannot reach the coordinator at {url}: {msg}")
    })?;
    Ok(JobsClient::with_interceptor(channel, Bearer::new(&options))
        .max_decoding_message_size(tessera_proto::MAX_MESSAGE_BYTES)
        // What may be sent is the coordinator's to decide (its --max-scene-bytes): it refuses
        // a message too large with a clear error.
        .max_encoding_message_size(usize::MAX))
}

fn state_name(state: i32) -> String {
    pb::JobState::try_from(state)
        .map(|s| {
            s.as_str_name()
                .trim_start_matches("JOB_STATE_")
                .to_lowercase()
        })
        .unwrap_or_else(|_| "unknown".into())
}

fn fmt_eta(secs: f64) -> String {
    if !(secs >= 0.0) {
        return "?".into();
    }
    let s = secs.round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, s / 60 % 60)
    } else {
        format!("{}m{:02}s", s / 60, s % 60)
    }
}

/// Notices a job that waits with no worker to render it, and says so once.
///
/// Without this, `submit --wait` on a farm whose workers never started (or all crashed) shows
/// a bar that never moves. The job keeps waiting: a worker may join at any time.
#[derive(Default)]
struct IdleFarm {
    /// Since when the job has had no unit leased.
    since: Option<std::time::Instant>,
    /// When the coordinator's worker list was last read.
    checked: Option<std::time::Instant>,
    /// The warning is on screen (until a worker shows up).
    warned: bool,
}

impl IdleFarm {
    /// How long a job may sit with nothing leased before the worker list is read: long enough
    /// for a live worker's next lease call, short enough that a person is told at once.
    const GRACE: Duration = Duration::from_secs(2);

    async fn observe(
        &mut self,
        s: &pb::JobStatus,
        client: &mut Client,
        url: &str,
        bar: &ProgressBar,
    ) {
        let waiting = matches!(
            pb::JobState::try_from(s.state),
            Ok(pb::JobState::Queued | pb::JobState::Running)
        ) && s.units_leased == 0;
        if !waiting {
            self.since = None;
            self.warned = false;
            return;
        }
        let now = std::time::Instant::now();
        let since = *self.since.get_or_insert(now);
        let due = self
            .checked
            .is_none_or(|c| now.duration_since(c) >= Self::GRACE);
        if now.duration_since(since) < Self::GRACE || !due {
            return;
        }
        self.checked = Some(now);
        let Ok(list) = client.list_workers(pb::ListWorkersRequest {}).await else {
            return;
        };
        let live = list
            .into_inner()
            .workers
            .iter()
            .any(|w| w.alive && !w.quarantined);
        if live {
            self.warned = false;
        } else if !self.warned {
            self.warned = true;
            bar.suspend(|| {
                errln!(
                    "no worker is connected to {url}; start one with `tessera worker --coordinator {url}` (still waiting)"
                )
            });
        }
    }
}

/// Follows a job until it ends, with a progress bar on stderr; errors unless it is done.
async fn follow(client: &mut Client, url: &str, job: &str) -> Result<pb::JobStatus> {
    let bar = ProgressBar::new(1);
    bar.set_style(progress_style("{percent:>3}% {wide_msg}"));
    let mut last: Option<pb::JobStatus> = None;
    let mut workers = client.clone();
    let mut idle = IdleFarm::default();
    // A coordinator restart or a network blip breaks the stream; the job survives both, so
    // reconnect (the channel does so by itself) for up to OUTAGE before giving up.
    const OUTAGE: Duration = Duration::from_secs(600);
    let mut down_since: Option<std::time::Instant> = None;
    let mut attempt = 0u32;
    loop {
        let streamed = async {
            let mut stream = client
                .watch_job(pb::WatchJobRequest {
                    job_id: job.into(),
                    interval_ms: 500,
                })
                .await?
                .into_inner();
            while let Some(s) = stream.message().await? {
                down_since = None;
                attempt = 0;
                idle.observe(&s, &mut workers, url, &bar).await;
                bar.set_length(s.samples_total.max(1));
                bar.set_position(s.samples_done);
                bar.set_message(format!(
                    "{} {}/{} units, {:.2} Msamples/s, noise {:.2}%, ETA {}",
                    state_name(s.state),
                    s.units_done,
                    s.units_total,
                    s.samples_per_second / 1e6,
                    s.noise_relative * 100.0,
                    fmt_eta(s.eta_seconds)
                ));
                last = Some(s);
            }
            Ok::<(), tonic::Status>(())
        }
        .await;
        let ended = last.as_ref().is_some_and(|s| {
            matches!(
                pb::JobState::try_from(s.state),
                Ok(pb::JobState::Done | pb::JobState::Cancelled | pb::JobState::Failed)
            )
        });
        // A stream that closes before a final state means the coordinator went away.
        let streamed = match streamed {
            Ok(()) if !ended => Err(tonic::Status::unavailable("the stream closed early")),
            other => other,
        };
        match streamed {
            Ok(()) => break,
            Err(e) if matches!(e.code(), Code::Unavailable | Code::Unknown | Code::Internal) => {
                let since = *down_since.get_or_insert_with(std::time::Instant::now);
                if since.elapsed() > OUTAGE {
                    bar.finish_and_clear();
                    return Err(rpc_error(url, job, e));
                }
                bar.set_message(format!(
                    "coordinator unreachable ({}), retrying",
                    e.message()
                ));
                tokio::time::sleep(Duration::from_millis(200 << attempt.min(4))).await;
                attempt += 1;
            }
            Err(e) => {
                bar.finish_and_clear();
                return Err(rpc_error(url, job, e));
            }
        }
    }
    bar.finish_and_clear();
    let s = last.ok_or_else(|| anyhow!("{job}: the coordinator closed the stream"))?;
    match pb::JobState::try_from(s.state) {
        Ok(pb::JobState::Done) => Ok(s),
        Ok(pb::JobState::Failed) => bail!("{job} failed: {}", s.error),
        _ => bail!("{job} ended {}", state_name(s.state)),
    }
}

/// Streams a done job's EXR into `out` (atomically: temp file, then rename).
async fn download(client: &mut Client, url: &str, job: &str, out: &Path) -> Result<u64> {
    let mut stream = client
        .fetch_result(pb::FetchResultRequest { job_id: job.into() })
        .await
        .map_err(|e| rpc_error(url, job, e))?
        .into_inner();
    let mut data = Vec::new();
    while let Some(c) = stream.message().await.map_err(|e| rpc_error(url, job, e))? {
        data.extend_from_slice(&c.data);
        if data.len() as u64 > c.total_bytes {
            bail!("{job}: the coordinator sent more bytes than it announced");
        }
    }
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    // A fresh, randomly named file (created exclusively, never through a link someone left
    // under a predictable name), renamed over `out` once complete.
    let mut tmp = tempfile::Builder::new()
        .prefix(".tessera-fetch-")
        .suffix(".part")
        .tempfile_in(dir)
        .with_context(|| {
            format!(
                "writing {}: cannot create a file in {}",
                out.display(),
                dir.display()
            )
        })?;
    tmp.write_all(&data)
        .and_then(|()| tmp.as_file().sync_all())
        .with_context(|| format!("writing {}", out.display()))?;
    tmp.persist(out)
        .map_err(|e| e.error)
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(data.len() as u64)
}

/// Runs `tessera submit`.
pub fn submit(args: SubmitArgs) -> Result<()> {
    if let Some(o) = &args.output {
        if !args.wait {
            bail!("--output needs --wait (or use `tessera fetch JOB --output FILE` later)");
        }
        check_extension("--output", o, "exr")?;
        check_output_dir(o)?;
    }
    let text = std::fs::read_to_string(&args.scene)
        .with_context(|| format!("{}: cannot read the scene", args.scene.display()))?;
    let json = args
        .scene
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let req = pb::SubmitJobRequest {
            scene_text: text,
            scene_format: if json {
                pb::SceneFormat::Json
            } else {
                pb::SceneFormat::Toml
            } as i32,
            scene_name: args.scene.display().to_string(),
            settings: Some(pb::RenderSettings::from(&args.settings.to_settings())),
            tile_size: args.tile_size.unwrap_or(0),
            output_name: args.name.clone().unwrap_or_default(),
            priority: args.priority,
            channels: Some(pb::OutputChannels {
                variance: args.variance,
                sample_count: args.sample_count,
            }),
        };
        let resp = client
            .submit_job(req)
            .await
            .map_err(|e| rpc_error(&url, "submit refused", e))?
            .into_inner();
        if !args.wait {
            outln!("{}", resp.job_id);
            return Ok(());
        }
        errln!("{} submitted ({} units)", resp.job_id, resp.units);
        let s = follow(&mut client, &url, &resp.job_id).await?;
        let out = args
            .output
            .clone()
            .unwrap_or_else(|| PathBuf::from(&s.output_name));
        let bytes = download(&mut client, &url, &resp.job_id, &out).await?;
        let secs = (s.finished_unix_ms - s.submitted_unix_ms) as f64 / 1000.0;
        outln!(
            "{} done: {}×{} at {} spp in {:.2} s, noise σ≈{:.4} ({:.2}% of mean) → {} ({bytes} bytes)",
            s.job_id,
            s.width,
            s.height,
            s.settings.map(|x| x.spp).unwrap_or(0),
            secs,
            s.noise_rms,
            s.noise_relative * 100.0,
            out.display()
        );
        Ok(())
    })
}

fn print_job(s: &pb::JobStatus) -> std::io::Result<()> {
    let settings = s.settings.unwrap_or_default();
    outln!("{}", s.job_id);
    outln!("  state      {}", state_name(s.state));
    if !s.error.is_empty() {
        outln!("  error      {}", printable(&s.error));
    }
    outln!(
        "  scene      {} (sha256 {})",
        printable(&s.scene_name),
        s.scene_hash
    );
    outln!(
        "  image      {}×{}, {} spp, seed {}, batch {}, tiles {}",
        s.width,
        s.height,
        settings.spp,
        settings.seed,
        settings.batch,
        s.tile_size
    );
    outln!("  priority   {}", s.priority);
    outln!(
        "  progress   {}/{} units ({} leased), {}/{} samples",
        s.units_done,
        s.units_total,
        s.units_leased,
        s.samples_done,
        s.samples_total
    );
    outln!(
        "  rate       {:.2} Msamples/s, ETA {}",
        s.samples_per_second / 1e6,
        fmt_eta(s.eta_seconds)
    );
    outln!(
        "  noise      σ≈{:.4} ({:.2}% of mean), {} non-finite samples",
        s.noise_rms,
        s.noise_relative * 100.0,
        s.nonfinite_samples
    );
    outln!("  output     {}", s.output_name);
    Ok(())
}

/// Runs `tessera status`.
pub fn status(args: StatusArgs) -> Result<()> {
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        if let Some(job) = &args.job {
            let s = client
                .get_job(pb::GetJobRequest {
                    job_id: job.clone(),
                })
                .await
                .map_err(|e| rpc_error(&url, job, e))?
                .into_inner();
            print_job(&s)?;
            return Ok(());
        }
        let jobs = client
            .list_jobs(pb::ListJobsRequest {})
            .await
            .map_err(|e| rpc_error(&url, "listing jobs", e))?
            .into_inner()
            .jobs;
        outln!(
            "{:<12} {:<10} {:>8} {:>7} {:>10} {:>8}  SCENE",
            "JOB",
            "STATE",
            "PRIORITY",
            "DONE",
            "UNITS",
            "ETA"
        );
        for s in jobs {
            outln!(
                "{:<12} {:<10} {:>8} {:>6.1}% {:>10} {:>8}  {}",
                s.job_id,
                state_name(s.state),
                s.priority,
                100.0 * s.units_done as f64 / s.units_total.max(1) as f64,
                s.units_total,
                fmt_eta(s.eta_seconds),
                printable(&s.scene_name)
            );
        }
        Ok(())
    })
}

/// Runs `tessera cancel`.
pub fn cancel(args: CancelArgs) -> Result<()> {
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let r = client
            .cancel_job(pb::CancelJobRequest {
                job_id: args.job.clone(),
            })
            .await
            .map_err(|e| rpc_error(&url, &args.job, e))?
            .into_inner();
        if r.state == pb::JobState::Cancelled as i32 {
            outln!("{} cancelled", args.job);
            Ok(())
        } else {
            bail!("{} had already ended ({})", args.job, state_name(r.state))
        }
    })
}

/// Runs `tessera workers`.
pub fn workers(args: WorkersArgs) -> Result<()> {
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let workers = client
            .list_workers(pb::ListWorkersRequest {})
            .await
            .map_err(|e| rpc_error(&url, "listing workers", e))?
            .into_inner()
            .workers;
        outln!(
            "{:<10} {:<20} {:>5} {:<11} {:>6} {:>8} {:>12} {:>5} {:>9}",
            "WORKER",
            "NAME",
            "CORES",
            "STATE",
            "LEASES",
            "UNITS",
            "SAMPLES",
            "BAD",
            "SEEN"
        );
        for w in workers {
            outln!(
                "{:<10} {:<20} {:>5} {:<11} {:>6} {:>8} {:>12} {:>5} {:>8.1}s",
                w.worker_id,
                printable(&w.name),
                w.cores,
                if w.quarantined {
                    "quarantined"
                } else if w.alive {
                    "alive"
                } else {
                    "gone"
                },
                w.leases,
                w.units_done,
                w.samples_done,
                w.bad_results,
                w.last_seen_ms_ago as f64 / 1000.0
            );
        }
        Ok(())
    })
}

/// Runs `tessera fetch`.
pub fn fetch(args: FetchArgs) -> Result<()> {
    check_extension("--output", &args.output, "exr")?;
    check_output_dir(&args.output)?;
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        if args.wait {
            follow(&mut client, &url, &args.job).await?;
        }
        let bytes = download(&mut client, &url, &args.job, &args.output).await?;
        outln!("{} → {} ({bytes} bytes)", args.job, args.output.display());
        Ok(())
    })
}
