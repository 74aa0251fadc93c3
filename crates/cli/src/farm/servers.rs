//! `tessera coordinator` and `tessera worker`: the servers, run until Ctrl-C or SIGTERM.

use std::io::Write as _;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use tessera_coordinator::{config, ServerTls};
use tessera_proto::Secret;
use tessera_render::scene::Limits;
use tessera_render::DEFAULT_TILE;

use super::{init_logging, load_token, read_file, runtime, shutdown_signal, CoordinatorUrl};
use crate::args::tile_range;

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
    /// Seconds between checkpoints of merged results to the state store. A crash costs at
    /// most the units merged since the last one, which are rendered again (their bits are
    /// the same); 0 makes every merge durable before it is acknowledged, at a disk write per
    /// result.
    #[arg(long, default_value_t = config::DEFAULT_CHECKPOINT_INTERVAL.as_secs_f64())]
    checkpoint_interval: f64,
    /// Bytes of a job's frame of sums (52 a pixel) above which its open tiles leave memory
    /// once checkpointed and are read back from the state store for their next batch, so
    /// memory does not grow with the frame; smaller jobs keep them, saving a read per merge.
    #[arg(long, default_value_t = config::DEFAULT_EVICT_OPEN_OVER)]
    evict_open_over: u64,
    /// Bytes of merged sums not yet written to the state store at which workers' results are
    /// deferred (they retry) until a checkpoint commits: bounds the coordinator's memory when
    /// results arrive faster than its disk and CPU store them.
    #[arg(long, default_value_t = config::DEFAULT_MAX_UNSTORED_BYTES)]
    max_unstored_bytes: u64,
    /// Denoise the frames of jobs submitted with --denoise, here, once each frame's last
    /// result is merged (Intel Open Image Denoise, loaded at start: scripts/install-oidn.sh).
    /// Without it such frames are denoised by workers started with --denoise, and wait for
    /// one.
    #[arg(long)]
    denoise: bool,
    /// Default tile edge in pixels for jobs that do not choose one.
    #[arg(long, default_value_t = DEFAULT_TILE, value_parser = tile_range())]
    tile_size: u32,
    /// Largest scene accepted, in bytes.
    #[arg(long, default_value_t = config::DEFAULT_MAX_SCENE_BYTES)]
    max_scene_bytes: usize,
    /// Largest file (a mesh) a scene may name, in bytes.
    #[arg(long, default_value_t = Limits::default().max_asset_bytes)]
    max_asset_bytes: u64,
    /// Most bytes the asset store (the files scenes name, under DATA_DIR/assets) may hold; an
    /// upload that would pass it is refused.
    #[arg(long, default_value_t = config::DEFAULT_ASSET_STORE_BYTES)]
    asset_store_bytes: u64,
    /// Seconds an uploaded file is kept after the last active job naming it ended (or after
    /// its upload, if no job names it); then it is deleted.
    #[arg(long, default_value_t = config::DEFAULT_ASSET_RETENTION.as_secs_f64())]
    asset_retention: f64,
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
    /// File of named tokens, `NAME TOKEN` a line (`NAME TOKEN admin` for one who may change
    /// anyone's jobs), instead of one token: each job records its submitter, equal-priority
    /// jobs share workers between users, and a user changes only their own jobs. Reread on
    /// SIGHUP (docs/farm.md, "Users").
    #[arg(long, conflicts_with = "token_file")]
    tokens_file: Option<PathBuf>,
    /// Most units one user's jobs may hold leased at once (0: no cap).
    #[arg(long, default_value_t = 0)]
    max_leases_per_user: u32,
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
    /// Failures of one job's units on one worker after which that worker is blocklisted for
    /// the job (it takes other jobs as before).
    #[arg(long, default_value_t = config::DEFAULT_BLOCKLIST_AFTER, value_parser = clap::value_parser!(u32).range(1..=100))]
    blocklist_after: u32,
    /// Failures after which a frame fails, with every reason; one machine's count at most
    /// --blocklist-after times and fewer than this, and a machine that fails this many of a
    /// job's units under any names is blocklisted for the job by address (the frame fails
    /// sooner when every connected worker that fits it is blocklisted).
    #[arg(long, default_value_t = config::DEFAULT_FAIL_FRAME_AFTER, value_parser = clap::value_parser!(u32).range(1..=100))]
    fail_frame_after: u32,
    /// Different machines one unit's lease may lapse on (each worker died or stopped answering
    /// while it held the unit) before its frame fails: a unit that crashes whoever takes it
    /// stops there instead of going round the farm; 0 never fails a frame for lapses.
    #[arg(long, default_value_t = config::DEFAULT_FAIL_UNIT_AFTER_LAPSES, value_parser = clap::value_parser!(u32).range(0..=100))]
    fail_unit_after_lapses: u32,
    /// Seconds a failed job stays retryable (`tessera retry`): its scene and the files it
    /// names are kept that long after it failed.
    #[arg(long, default_value_t = config::DEFAULT_RETRY_WINDOW.as_secs_f64())]
    retry_window: f64,
    /// Seconds an ended job's workers' log is kept (`tessera logs`); memory holds only active
    /// jobs' logs, the store the ended ones' until then.
    #[arg(long, default_value_t = config::DEFAULT_LOG_RETENTION.as_secs_f64())]
    log_retention: f64,
    /// Most bytes of ended jobs' logs kept in the store in all (e.g. 256M); past it the
    /// oldest go first.
    #[arg(long, value_name = "SIZE", default_value = "256M", value_parser = crate::args::memory_size)]
    max_log_bytes: u64,
    /// Seconds an ended job (done, failed or cancelled) stays listed and known by its id
    /// (status, logs, fetch, retry); its output files stay where they were written.
    #[arg(long, default_value_t = config::DEFAULT_JOB_RETENTION.as_secs_f64())]
    job_retention: f64,
    /// Most ended jobs kept in all (a frame range counts its frames); past it the oldest are
    /// forgotten first.
    #[arg(long, default_value_t = config::DEFAULT_MAX_ENDED_JOBS as u32, value_parser = clap::value_parser!(u32).range(1..))]
    max_ended_jobs: u32,
    /// Most units one worker may hold at once (a stock worker holds at most 3).
    #[arg(long, default_value_t = config::DEFAULT_MAX_LEASES_PER_WORKER as u32, value_parser = clap::value_parser!(u32).range(1..=4096))]
    max_leases_per_worker: u32,
    /// Fraction of units (0 to 1) that a worker on another host renders too, compared bit for
    /// bit with the first; when the copies differ the coordinator renders the unit itself, and
    /// a worker whose bits differ from its render is quarantined and its results rendered
    /// again (docs/farm.md, "Audits").
    #[arg(long, default_value_t = 0.0)]
    audit: f64,
    /// Most live worker registrations from one host (the address it registers from).
    #[arg(long, default_value_t = config::DEFAULT_MAX_WORKERS_PER_HOST as u32, value_parser = clap::value_parser!(u32).range(1..))]
    max_workers_per_host: u32,
    /// Most client connections open at once.
    #[arg(long, default_value_t = config::DEFAULT_MAX_CONNECTIONS as u32, value_parser = clap::value_parser!(u32).range(1..))]
    max_connections: u32,
    /// Address to serve the web dashboard and Prometheus metrics (/metrics) on, e.g.
    /// 127.0.0.1:7880; off unless given. Same token and TLS as the gRPC API.
    #[arg(long, value_name = "ADDR")]
    http: Option<String>,
    /// A host name the dashboard is reached by (repeatable), e.g. renderbox or
    /// farm.studio.example. IP addresses and localhost always are; on a farm without a token,
    /// requests that name any other host are refused, so that a web page elsewhere cannot
    /// reach the farm through a name it points at it (DNS rebinding).
    #[arg(long = "http-host", value_name = "NAME")]
    http_hosts: Vec<String>,
    /// Most memory, in bytes, that the coordinator's own renders (an audit's referee) may spend
    /// decoding textures at once (more wait their turn). Submitted scenes' images are checked
    /// by their headers alone, never decoded.
    #[arg(long, default_value_t = tessera_render::texture::DEFAULT_DECODE_BUDGET)]
    texture_decode_bytes: u64,
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
    /// Where the files scenes name (meshes) are cached by hash, fetched once per machine
    /// (default: tessera-assets in the system's temporary directory).
    #[arg(long, env = "TESSERA_CACHE_DIR")]
    cache_dir: Option<std::path::PathBuf>,
    /// Most bytes the cache keeps; the least recently used files go first.
    #[arg(long, env = "TESSERA_CACHE_BYTES", default_value_t = tessera_worker::DEFAULT_CACHE_BYTES)]
    cache_bytes: u64,
    /// Most memory, in bytes, that loading scenes may spend decoding their textures at once (a
    /// unit whose texture needs more is handed back as one this worker cannot render).
    #[arg(long, env = "TESSERA_TEXTURE_DECODE_BYTES", default_value_t = tessera_render::texture::DEFAULT_DECODE_BUDGET)]
    texture_decode_bytes: u64,
    /// A tag jobs can require (`submit --require`), repeatable: NAME or NAME=VALUE, e.g.
    /// `--tag pool=fast --tag big-mem`.
    #[arg(long = "tag", value_name = "TAG", value_parser = crate::args::tag)]
    tags: Vec<String>,
    /// Memory to report to the coordinator, e.g. 16G (default: the machine's, or its
    /// container's limit if lower).
    #[arg(long, env = "TESSERA_WORKER_MEMORY", value_name = "SIZE", value_parser = crate::args::memory_size)]
    memory: Option<u64>,
    /// Also denoise finished frames of jobs submitted with --denoise, when the coordinator
    /// does not denoise them itself (Intel Open Image Denoise, loaded at start: the worker
    /// does not start without it; scripts/install-oidn.sh installs it). Shown as the tag
    /// `denoise` by `tessera workers`.
    #[arg(long)]
    denoise: bool,
}

/// Runs `tessera coordinator`.
pub fn coordinator(args: CoordinatorArgs) -> Result<()> {
    if !(args.audit.is_finite() && (0.0..=1.0).contains(&args.audit)) {
        bail!(
            "--audit must be a fraction between 0 and 1, got {}",
            args.audit
        );
    }
    init_logging();
    tessera_render::texture::DecodeBudget::global().set_total(args.texture_decode_bytes);
    let config = coordinator_config(&args)?;
    let tokens = config.tokens.clone();
    let auth = match (config.auth().is_some(), &config.tls) {
        (true, Some(_)) => "token and TLS",
        (true, None) => "token (no TLS: the token crosses the network in clear)",
        (false, Some(_)) => "TLS, no token",
        (false, None) => "none: anyone who can connect may submit, lease and fetch",
    };
    runtime()?.block_on(async {
        let listener = tokio::net::TcpListener::bind(&args.listen)
            .await
            .with_context(|| format!("--listen {}: cannot listen", args.listen))?;
        let addr = listener.local_addr()?;
        let http = match &args.http {
            Some(a) => Some(
                tokio::net::TcpListener::bind(a)
                    .await
                    .with_context(|| format!("--http {a}: cannot listen"))?,
            ),
            None => None,
        };
        let http_addr = http.as_ref().map(|l| l.local_addr()).transpose()?;
        let scheme = if config.tls.is_some() {
            "https"
        } else {
            "http"
        };
        // Said once the store is open and the TLS key loaded, so that a script (or a person)
        // waiting for it knows the coordinator is really up; a failure before that is the
        // one line of the error instead. stdout is line-buffered, so the newline sends it.
        // Best effort: a script that read it and closed the pipe must not stop the server.
        let ready = move || {
            tracing::info!("auth: {auth}");
            let _ = writeln!(std::io::stdout(), "listening on {addr}");
            if let Some(h) = http_addr {
                let _ = writeln!(std::io::stdout(), "dashboard on {scheme}://{h}/");
            }
        };
        let listeners = tessera_coordinator::Listeners {
            grpc: listener,
            http,
        };
        // Listening before `listening on` is printed, so that a SIGHUP sent once it is seen
        // rereads the file rather than ending the process (SIGHUP's default).
        #[cfg(unix)]
        if let (Some(tokens), Some(path)) = (tokens, args.tokens_file.clone()) {
            use tokio::signal::unix::{signal, SignalKind};
            let hup = signal(SignalKind::hangup()).context("cannot listen for SIGHUP")?;
            tokio::spawn(reload_on_sighup(hup, tokens, path));
        }
        #[cfg(not(unix))]
        drop(tokens);
        tessera_coordinator::serve_when_ready(config, listeners, shutdown_signal(), ready).await?;
        Ok(())
    })
}

/// The coordinator's configuration from its flags: bounds, durations, tokens, TLS (files read
/// here, so that a missing one stops it before it listens).
fn coordinator_config(args: &CoordinatorArgs) -> Result<tessera_coordinator::Config> {
    let mut config = tessera_coordinator::Config::new(&args.data_dir);
    config.audit = args.audit;
    config.output_dir = args.output_dir.clone();
    config.lease_timeout = seconds("--lease-timeout", args.lease_timeout, 0.1..=86_400.0)?;
    config.checkpoint_interval = seconds(
        "--checkpoint-interval",
        args.checkpoint_interval,
        0.0..=3600.0,
    )?;
    config.default_tile_size = args.tile_size;
    config.limits.max_bytes = args.max_scene_bytes;
    config.limits.max_spp = args.max_spp;
    config.limits.max_asset_bytes = args.max_asset_bytes;
    config.asset_store_bytes = args.asset_store_bytes;
    config.evict_open_over = args.evict_open_over;
    config.max_unstored_bytes = args.max_unstored_bytes;
    config.denoise = args.denoise;
    config.asset_retention = seconds("--asset-retention", args.asset_retention, 0.0..=1e9)?;
    config.limits.max_resolution = args.max_resolution;
    config.max_message_bytes = config
        .max_message_bytes
        .max(args.max_scene_bytes + (1 << 20));
    config.quarantine_after = args.quarantine_after;
    config.blocklist_after = args.blocklist_after;
    config.fail_frame_after = args.fail_frame_after;
    config.fail_unit_after_lapses = args.fail_unit_after_lapses;
    config.retry_window = seconds("--retry-window", args.retry_window, 0.0..=1e9)?;
    config.http_hosts = args
        .http_hosts
        .iter()
        .map(|h| h.to_ascii_lowercase())
        .collect();
    config.log_retention = seconds("--log-retention", args.log_retention, 0.0..=1e9)?;
    config.job_retention = seconds("--job-retention", args.job_retention, 0.0..=1e9)?;
    config.max_ended_jobs = args.max_ended_jobs as usize;
    config.max_log_bytes = args.max_log_bytes;
    config.max_leases_per_worker = args.max_leases_per_worker as usize;
    config.max_connections = args.max_connections as usize;
    config.max_workers_per_host = args.max_workers_per_host as usize;
    config.max_leases_per_user = args.max_leases_per_user as usize;
    if let Some(path) = &args.tokens_file {
        if std::env::var_os("TESSERA_TOKEN").is_some_and(|v| !v.is_empty()) {
            bail!("--tokens-file and TESSERA_TOKEN: give one (unset TESSERA_TOKEN)");
        }
        super::warn_if_others_can_read(path);
        config.tokens = Some(tessera_coordinator::Tokens::load(path).map_err(anyhow::Error::msg)?);
    } else {
        config.token = load_token(args.token_file.as_deref())?;
    }
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
    Ok(config)
}

/// Rereads the tokens file at each SIGHUP: its tokens are accepted from then on (a user added,
/// a leaked token withdrawn) without a restart; a file that does not parse keeps the tokens
/// there were, and says why.
#[cfg(unix)]
async fn reload_on_sighup(
    mut hup: tokio::signal::unix::Signal,
    tokens: tessera_coordinator::Tokens,
    path: PathBuf,
) {
    while hup.recv().await.is_some() {
        match tokens.reload(&path) {
            Ok(n) => tracing::info!("SIGHUP: {} reread, {n} token(s)", path.display()),
            Err(e) => tracing::error!("SIGHUP: {e}; keeping the tokens there were"),
        }
    }
}

/// Runs `tessera worker`.
pub fn worker(args: WorkerArgs) -> Result<()> {
    init_logging();
    tessera_render::texture::DecodeBudget::global().set_total(args.texture_decode_bytes);
    let options = args.url.options()?;
    let mut config = tessera_worker::Config::new(args.url.coordinator);
    config.client = options;
    config.threads = args.threads.map(|t| t as usize);
    config.cache_bytes = args.cache_bytes;
    tessera_proto::tags::check_tags("--tag", &args.tags, tessera_proto::tags::MAX_TAGS)
        .map_err(anyhow::Error::msg)?;
    config.tags = args.tags;
    config.memory_bytes = args.memory;
    config.denoise = args.denoise;
    if let Some(dir) = args.cache_dir {
        config.cache_dir = dir;
    }
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

/// A flag's seconds as a duration, refused (naming the flag and the range) outside `range`
/// or when not finite: `Duration::from_secs_f64` would panic on a negative or NaN.
fn seconds(flag: &str, v: f64, range: std::ops::RangeInclusive<f64>) -> Result<Duration> {
    if !(v.is_finite() && range.contains(&v)) {
        let show = |x: f64| {
            if x >= 1e6 {
                format!("{x:e}")
            } else {
                x.to_string()
            }
        };
        bail!(
            "{flag} must be between {} and {} seconds, got {v}",
            show(*range.start()),
            show(*range.end())
        );
    }
    Ok(Duration::from_secs_f64(v))
}
