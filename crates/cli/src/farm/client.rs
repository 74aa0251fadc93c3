//! The client commands: `submit`, `status`, `cancel`, `workers` and `fetch`, over a
//! coordinator's `Jobs` service.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use indicatif::ProgressBar;
use tessera_proto::client::{endpoint, Bearer};
use tessera_proto::convert::job_state_name;
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_client::JobsClient;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;
use tonic::Code;

use super::{runtime, tile_range, CoordinatorUrl};
use crate::render::{check_extension, check_output_dir};
use crate::{printable, progress_style};
use tessera_render::scene::assets::sha256_hex;
use tessera_render::scene::{FrameRange, Limits, Scene, FIRST_FRAME};
use tessera_render::DEFAULT_TILE;

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
    /// Render frames FIRST-LAST or FIRST-LAST:STEP of the scene's `[animation]` as one job,
    /// one EXR per frame (NAME.####.exr); the first frames finish first.
    #[arg(long, value_name = "FIRST-LAST[:STEP]", conflicts_with = "frame")]
    frames: Option<FrameRange>,
    /// Follow the job with a progress bar, then fetch its EXR (a frame range's EXRs).
    #[arg(long)]
    wait: bool,
    /// Where `--wait` saves the EXR (default: the job's output name, here); for `--frames`,
    /// the directory the frames' EXRs go to.
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
    /// Print JSON (one object for a job, an array for the list) for scripts, not the table.
    #[arg(long)]
    json: bool,
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
    /// Print a JSON array for scripts, not the table.
    #[arg(long)]
    json: bool,
}

/// Arguments of `tessera fetch`.
#[derive(Debug, clap::Args)]
pub struct FetchArgs {
    /// Job id.
    job: String,
    #[command(flatten)]
    url: CoordinatorUrl,
    /// Where to save the EXR (default: the job's output name, here, as `submit --wait`); for
    /// a frame-range job without `--frame`, the directory every finished frame's EXR goes to
    /// (under its NAME.####.exr; default: here).
    #[arg(long, short)]
    output: Option<PathBuf>,
    /// One frame of a frame-range job.
    #[arg(long)]
    frame: Option<u32>,
    /// Wait for the job to finish first.
    #[arg(long)]
    wait: bool,
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

/// Columns the progress line takes before its message: the spinner, the elapsed time, the
/// 24-column bar and the percentage, with their spaces (`progress_style`).
const PROGRESS_PREFIX: usize = 1 + 1 + 10 + 1 + 24 + 1 + 4 + 1;

/// A job's progress in at most `width` columns: its fields by importance (the noise and the ETA,
/// which the README promises, first; then units, rate, state), each left out whole, never cut,
/// when it does not fit; in their usual order.
fn progress_message(s: &pb::JobStatus, width: usize) -> String {
    // (importance, text): lower is kept first.
    let noise = if s.samples_done > 0 && s.noise_relative.is_finite() {
        format!("noise {:.2}%", s.noise_relative * 100.0)
    } else {
        "noise –".to_string()
    };
    let fields = [
        (4, job_state_name(s.state).to_string()),
        (2, format!("{}/{} units", s.units_done, s.units_total)),
        (3, format!("{:.2} Msamples/s", s.samples_per_second / 1e6)),
        (0, noise),
        (1, format!("ETA {}", fmt_eta(s.eta_seconds))),
    ];
    let joined = |keep: usize| {
        fields
            .iter()
            .filter(|(rank, _)| *rank < keep)
            .map(|(_, t)| t.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    (1..=fields.len())
        .rev()
        .map(joined)
        .find(|m| m.chars().count() <= width)
        .unwrap_or_default()
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
    done(job, follow_to_end(client, url, job).await?)
}

/// `s` if its job is done, else an error that says how it ended.
fn done(job: &str, s: pb::JobStatus) -> Result<pb::JobStatus> {
    match pb::JobState::try_from(s.state) {
        Ok(pb::JobState::Done) => Ok(s),
        Ok(pb::JobState::Failed) => bail!("{job} failed: {}", s.error),
        _ => bail!("{job} ended {}", job_state_name(s.state)),
    }
}

/// Follows a job until it ends, with a progress bar on stderr, and returns its last status.
async fn follow_to_end(client: &mut Client, url: &str, job: &str) -> Result<pb::JobStatus> {
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
                let width = console::Term::stderr().size().1 as usize;
                bar.set_message(progress_message(&s, width.saturating_sub(PROGRESS_PREFIX)));
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
    last.ok_or_else(|| anyhow!("{job}: the coordinator closed the stream"))
}

/// Streams a done job's EXR (one frame's, for a frame-range job) into `out` (atomically:
/// temp file, then rename).
async fn download(
    client: &mut Client,
    url: &str,
    job: &str,
    frame: Option<u32>,
    out: &Path,
) -> Result<u64> {
    let mut stream = client
        .fetch_result(pb::FetchResultRequest {
            job_id: job.into(),
            frame,
        })
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

/// Downloads every finished frame of frame-range job `s` into `dir`, each under its output
/// name, and says which did not finish (an error, after the others are saved).
async fn download_frames(
    client: &mut Client,
    url: &str,
    s: &pb::JobStatus,
    dir: &Path,
) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    let mut missing = Vec::new();
    for f in &s.frames {
        if f.state != pb::JobState::Done as i32 {
            missing.push(format!("{} ({})", f.frame, job_state_name(f.state)));
            continue;
        }
        let out = dir.join(&f.output_name);
        let bytes = download(client, url, &s.job_id, Some(f.frame), &out).await?;
        outln!(
            "{} frame {} → {} ({bytes} bytes)",
            s.job_id,
            f.frame,
            out.display()
        );
    }
    if !missing.is_empty() {
        let why = if s.error.is_empty() {
            String::new()
        } else {
            format!(" ({})", printable(&s.error))
        };
        bail!(
            "{}: {} of {} frames not saved, not done: {}{why}",
            s.job_id,
            missing.len(),
            s.frames.len(),
            missing.join(", ")
        );
    }
    Ok(())
}

/// Checks `--output` for a frame range: a directory, or a name for a new one.
fn check_frames_dir(dir: &Path) -> Result<()> {
    let exr = dir
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    if (dir.exists() && !dir.is_dir()) || (exr && !dir.is_dir()) {
        bail!(
            "--output {}: a frame range is saved as one EXR per frame, so --output names a \
             directory (or fetch one frame with --frame N)",
            dir.display()
        );
    }
    Ok(())
}

/// The files the scene names (meshes, textures), as (name, SHA-256, path): found by loading
/// the scene here, at the frame the job starts with. A scene that does not load here is
/// refused here with the error `tessera render` prints (a mesh that is missing or truncated, a
/// texture that is a directory: the cause, not "not among the files sent"). Only the limits a
/// coordinator may raise (resolution, spp, sizes) are lifted for this check, so a scene within
/// its coordinator's limits but above the defaults is still sent, for it to decide.
fn scene_files(args: &SubmitArgs) -> Result<Vec<(String, String, PathBuf)>> {
    let frame = args
        .frames
        .map_or(args.settings.frame.unwrap_or(FIRST_FRAME), |r| r.first);
    let lifted = Limits {
        max_resolution: u32::MAX,
        max_pixels: u64::MAX,
        max_bytes: usize::MAX,
        max_spp: u32::MAX,
        max_asset_bytes: u64::MAX,
        ..Limits::default()
    };
    let scene = Scene::load_at(&args.scene, &lifted, frame)?;
    let dir = args.scene.parent().unwrap_or(Path::new("")).to_path_buf();
    Ok(scene
        .files
        .into_iter()
        .map(|(name, hash)| {
            let path = dir.join(&name);
            (name, hash, path)
        })
        .collect())
}

/// Uploads one file unless the coordinator holds it already, resuming from the bytes it holds
/// of an earlier, interrupted upload.
async fn upload(client: &mut Client, url: &str, name: &str, hash: &str, path: &Path) -> Result<()> {
    let status = client
        .get_asset_status(pb::GetAssetStatusRequest {
            sha256: hash.to_string(),
        })
        .await
        .map_err(|e| rpc_error(url, "asset status refused", e))?
        .into_inner();
    if status.complete {
        return Ok(());
    }
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    if sha256_hex(&bytes) != hash {
        bail!(
            "{}: changed while it was being submitted; submit again",
            path.display()
        );
    }
    let total = bytes.len() as u64;
    let from = usize::try_from(status.received)
        .unwrap_or(usize::MAX)
        .min(bytes.len());
    if from > 0 {
        errln!("{name}: resuming the upload at byte {from} of {total}");
    }
    // Chunks are cut as the stream is read, so a large file is in memory once, not twice.
    const CHUNK: usize = 1 << 20;
    let count = (bytes.len() - from).div_ceil(CHUNK).max(1);
    let sha = hash.to_string();
    let chunks = (0..count).map(move |i| {
        let start = from + i * CHUNK;
        let end = (start + CHUNK).min(bytes.len());
        pb::AssetChunk {
            sha256: sha.clone(),
            offset: start as u64,
            total_size: total,
            data: bytes[start..end].to_vec(),
        }
    });
    let done = client
        .upload_asset(tokio_stream::iter(chunks))
        .await
        .map_err(|e| rpc_error(url, &format!("upload of {name} refused"), e))?
        .into_inner();
    if !done.complete {
        bail!(
            "upload of {name}: the coordinator holds {} of {total} bytes; submit again to resume",
            done.received
        );
    }
    errln!("{name}: uploaded ({total} bytes, sha256 {hash})");
    Ok(())
}

/// Runs `tessera submit`.
pub fn submit(args: SubmitArgs) -> Result<()> {
    if let Some(o) = &args.output {
        if !args.wait {
            bail!("--output needs --wait (or use `tessera fetch JOB --output FILE` later)");
        }
        if args.frames.is_some() {
            check_frames_dir(o)?;
        } else {
            check_extension("--output", o, "exr")?;
            check_output_dir(o)?;
        }
    }
    let text = std::fs::read_to_string(&args.scene)
        .with_context(|| format!("{}: cannot read the scene", args.scene.display()))?;
    let json = args
        .scene
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    let files = scene_files(&args)?;
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let assets = files
            .iter()
            .map(|(name, hash, _)| pb::AssetRef {
                name: name.clone(),
                sha256: hash.clone(),
            })
            .collect();
        let req = pb::SubmitJobRequest {
            assets,
            scene_text: text,
            scene_format: if json {
                pb::SceneFormat::Json
            } else {
                pb::SceneFormat::Toml
            } as i32,
            scene_name: args.scene.display().to_string(),
            settings: Some(pb::RenderSettings::from(&args.settings.to_settings(args.tile_size.unwrap_or(DEFAULT_TILE)))),
            tile_size: args.tile_size.unwrap_or(0),
            output_name: args.name.clone().unwrap_or_default(),
            priority: args.priority,
            channels: Some(pb::OutputChannels {
                variance: args.variance,
                sample_count: args.sample_count,
            }),
            frames: args.frames.map(|r| pb::FrameRange {
                first: r.first,
                last: r.last,
                step: r.step,
            }),
        };
        // The coordinator deletes files no active job has used for a while; one it held when
        // `upload` asked may be gone by the submission. Uploading again and resubmitting
        // settles that (twice at most: a file deleted every time is a misconfigured farm).
        let mut tries = 0;
        let resp = loop {
            for (name, hash, path) in &files {
                upload(&mut client, &url, name, hash, path).await?;
            }
            match client.submit_job(req.clone()).await {
                Err(e)
                    if e.code() == tonic::Code::FailedPrecondition
                        && e.message().starts_with("not uploaded")
                        && tries < 2 =>
                {
                    tries += 1;
                    errln!("the coordinator no longer holds a file ({}); uploading again", e.message());
                }
                r => break r.map_err(|e| rpc_error(&url, "submit refused", e))?.into_inner(),
            }
        };
        if !args.wait {
            outln!("{}", resp.job_id);
            return Ok(());
        }
        errln!("{} submitted ({} units)", resp.job_id, resp.units);
        // Ctrl-C stops the following, not the job: say so, with the id to pick it up again.
        let job = resp.job_id.clone();
        let follow_and_fetch = async move {
            if args.frames.is_some() {
                errln!("{} frames", resp.frames);
                let s = follow_to_end(&mut client, &url, &resp.job_id).await?;
                let dir = args.output.clone().unwrap_or_else(|| PathBuf::from("."));
                return download_frames(&mut client, &url, &s, &dir).await;
            }
            let s = follow(&mut client, &url, &resp.job_id).await?;
            let out = args
                .output
                .clone()
                .unwrap_or_else(|| PathBuf::from(&s.output_name));
            let bytes = download(&mut client, &url, &resp.job_id, None, &out).await?;
            let secs = (s.finished_unix_ms - s.submitted_unix_ms) as f64 / 1000.0;
            outln!(
                "{} done: {}×{} at {} in {:.2} s, noise σ≈{:.4} ({:.2}% of mean) → {} ({bytes} bytes)",
                s.job_id,
                s.width,
                s.height,
                spp_said(&s),
                secs,
                s.noise_rms,
                s.noise_relative * 100.0,
                out.display()
            );
            Ok(())
        };
        tokio::select! {
            r = follow_and_fetch => r,
            _ = tokio::signal::ctrl_c() => bail!(
                "interrupted: {job} goes on rendering on the farm; follow it with `tessera \
                 status {job}`, fetch it with `tessera fetch {job} --wait`, or stop it with \
                 `tessera cancel {job}`"
            ),
        }
    })
}

/// A job's status as JSON for scripts: the same fields the table shows, under stable names,
/// with the state as a word and figures that do not exist yet (ETA, noise) as null.
fn job_json(s: &pb::JobStatus) -> serde_json::Value {
    let settings = s.settings.unwrap_or_default();
    let finite = |x: f64, ok: bool| (ok && x.is_finite()).then_some(x);
    serde_json::json!({
        "job_id": s.job_id,
        "state": job_state_name(s.state),
        "error": s.error,
        "scene": s.scene_name,
        "scene_sha256": s.scene_hash,
        "width": s.width,
        "height": s.height,
        "spp": settings.spp,
        "seed": settings.seed,
        "batch": settings.batch,
        "frame": settings.frame,
        "noise_target": (settings.noise_target > 0.0).then_some(settings.noise_target),
        "tile_size": s.tile_size,
        "priority": s.priority,
        "units_done": s.units_done,
        "units_total": s.units_total,
        "units_leased": s.units_leased,
        "samples_done": s.samples_done,
        "samples_total": s.samples_total,
        "samples_per_second": s.samples_per_second,
        "eta_seconds": finite(s.eta_seconds, s.eta_seconds >= 0.0),
        "noise_rms": finite(s.noise_rms, s.samples_done > 0),
        "noise_relative": finite(s.noise_relative, s.samples_done > 0),
        "nonfinite_samples": s.nonfinite_samples,
        "output": s.output_name,
        "range_job_id": (!s.range_job_id.is_empty()).then_some(&s.range_job_id),
        "frames": s.frames.iter().map(|f| serde_json::json!({
            "frame": f.frame,
            "job_id": f.job_id,
            "state": job_state_name(f.state),
            "output": f.output_name,
        })).collect::<Vec<_>>(),
    })
}

/// A worker as JSON for scripts, as `tessera workers` lists it.
fn worker_json(w: &pb::WorkerInfo) -> serde_json::Value {
    serde_json::json!({
        "worker_id": w.worker_id,
        "name": w.name,
        "cores": w.cores,
        "state": w.state(),
        "leases": w.leases,
        "units_done": w.units_done,
        "samples_done": w.samples_done,
        "samples_per_second": w.samples_per_second,
        "bad_results": w.bad_results,
        "audits_passed": w.audits_passed,
        "convicted": (!w.convicted.is_empty()).then_some(&w.convicted),
        "last_seen_seconds_ago": w.last_seen_ms_ago as f64 / 1000.0,
        "host": (!w.host.is_empty()).then_some(&w.host),
    })
}

/// The samples a finished job took, as `tessera render` says them: "N spp", or for an
/// adaptive job the average per pixel with its target and cap.
fn spp_said(s: &pb::JobStatus) -> String {
    let settings = s.settings.unwrap_or_default();
    if settings.noise_target > 0.0 {
        let pixels = (f64::from(s.width) * f64::from(s.height)).max(1.0);
        format!(
            "{:.1} spp on average (noise target {}, cap {})",
            s.samples_done as f64 / pixels,
            settings.noise_target,
            settings.spp
        )
    } else {
        format!("{} spp", settings.spp)
    }
}

fn print_job(s: &pb::JobStatus) -> std::io::Result<()> {
    let settings = s.settings.unwrap_or_default();
    outln!("{}", s.job_id);
    outln!("  state      {}", job_state_name(s.state));
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
    if let Some(f) = settings.frame {
        outln!("  frame      {f}");
    }
    if !s.range_job_id.is_empty() {
        outln!("  range      a frame of {}", s.range_job_id);
    }
    if settings.noise_target > 0.0 {
        outln!(
            "  adaptive   noise target {} (expected √relMSE of the image; {} spp is the cap)",
            settings.noise_target,
            settings.spp
        );
    }
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
    if s.samples_done > 0 {
        outln!(
            "  noise      σ≈{:.4} ({:.2}% of mean), {} non-finite samples",
            s.noise_rms,
            s.noise_relative * 100.0,
            s.nonfinite_samples
        );
    } else {
        outln!("  noise      – (no sample merged)");
    }
    outln!("  output     {}", s.output_name);
    if let Some(r) = s.frame_range {
        let count = |st: pb::JobState| s.frames.iter().filter(|f| f.state == st as i32).count();
        outln!(
            "  frames     {}-{}:{}, {} frames: {} done, {} running, {} queued, {} failed, {} \
             cancelled",
            r.first,
            r.last,
            r.step,
            s.frames.len(),
            count(pb::JobState::Done),
            count(pb::JobState::Running),
            count(pb::JobState::Queued),
            count(pb::JobState::Failed),
            count(pb::JobState::Cancelled)
        );
        outln!(
            "  {:>8} {:<12} {:<10} {:>12}  OUTPUT",
            "FRAME",
            "JOB",
            "STATE",
            "UNITS"
        );
        for f in &s.frames {
            outln!(
                "  {:>8} {:<12} {:<10} {:>12}  {}",
                f.frame,
                f.job_id,
                job_state_name(f.state),
                format!("{}/{}", f.units_done, f.units_total),
                f.output_name
            );
            if !f.error.is_empty() {
                outln!("  {:>8} error: {}", "", printable(&f.error));
            }
        }
    }
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
            if args.json {
                outln!("{}", job_json(&s));
            } else {
                print_job(&s)?;
            }
            return Ok(());
        }
        let jobs = client
            .list_jobs(pb::ListJobsRequest {})
            .await
            .map_err(|e| rpc_error(&url, "listing jobs", e))?
            .into_inner()
            .jobs;
        if args.json {
            let list: Vec<serde_json::Value> = jobs.iter().map(job_json).collect();
            outln!("{}", serde_json::Value::Array(list));
            return Ok(());
        }
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
                job_state_name(s.state),
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
            bail!(
                "{} had already ended ({})",
                args.job,
                job_state_name(r.state)
            )
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
        if args.json {
            let list: Vec<serde_json::Value> = workers.iter().map(worker_json).collect();
            outln!("{}", serde_json::Value::Array(list));
            return Ok(());
        }
        outln!(
            "{:<10} {:<20} {:>5} {:<11} {:>6} {:>8} {:>12} {:>5} {:>6} {:>9}  HOST",
            "WORKER",
            "NAME",
            "CORES",
            "STATE",
            "LEASES",
            "UNITS",
            "SAMPLES",
            "BAD",
            "AUDITS",
            "SEEN"
        );
        for w in &workers {
            outln!(
                "{:<10} {:<20} {:>5} {:<11} {:>6} {:>8} {:>12} {:>5} {:>6} {:>8.1}s  {}",
                w.worker_id,
                printable(&w.name),
                w.cores,
                w.state(),
                w.leases,
                w.units_done,
                w.samples_done,
                w.bad_results,
                w.audits_passed,
                w.last_seen_ms_ago as f64 / 1000.0,
                if w.host.is_empty() {
                    "-".to_string()
                } else {
                    printable(&w.host)
                }
            );
        }
        for w in workers.iter().filter(|w| !w.convicted.is_empty()) {
            outln!(
                "{} ({}): {}",
                w.worker_id,
                printable(&w.name),
                printable(&w.convicted)
            );
        }
        Ok(())
    })
}

/// Runs `tessera fetch`.
pub fn fetch(args: FetchArgs) -> Result<()> {
    // A name that can only be a file is checked before anything is asked of the coordinator;
    // one that may be a frame range's directory once the job says what it is.
    let maybe_dir = args
        .output
        .as_ref()
        .is_none_or(|o| args.frame.is_none() && (o.is_dir() || o.extension().is_none()));
    if let (false, Some(o)) = (maybe_dir, &args.output) {
        check_extension("--output", o, "exr")?;
        check_output_dir(o)?;
    }
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let s = if args.wait {
            follow_to_end(&mut client, &url, &args.job).await?
        } else {
            client
                .get_job(pb::GetJobRequest {
                    job_id: args.job.clone(),
                })
                .await
                .map_err(|e| rpc_error(&url, &args.job, e))?
                .into_inner()
        };
        // A whole frame range goes into a directory; one frame, or a one-frame job, to a file.
        if !s.frames.is_empty() && args.frame.is_none() {
            let dir = args.output.clone().unwrap_or_else(|| PathBuf::from("."));
            check_frames_dir(&dir)?;
            return download_frames(&mut client, &url, &s, &dir).await;
        }
        // One frame of a range is saved under that frame's own name.
        let default_name = match args.frame {
            Some(f) => s
                .frames
                .iter()
                .find(|x| x.frame == f)
                .map_or_else(|| s.output_name.clone(), |x| x.output_name.clone()),
            None => s.output_name.clone(),
        };
        if args.wait && s.frames.is_empty() {
            done(&args.job, s)?;
        }
        let out = args
            .output
            .clone()
            .unwrap_or_else(|| PathBuf::from(default_name));
        if maybe_dir {
            check_extension("--output", &out, "exr")?;
            check_output_dir(&out)?;
        }
        let bytes = download(&mut client, &url, &args.job, args.frame, &out).await?;
        outln!("{} → {} ({bytes} bytes)", args.job, out.display());
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// #55: at 80 columns the line was cut mid-word (`75% running 383/512 units, 3.07
    /// Msamples/`), losing the noise and the ETA. Now fields are dropped whole, least
    /// important first, and the noise and ETA stay.
    #[test]
    fn the_progress_message_fits_by_dropping_whole_fields() {
        let s = pb::JobStatus {
            state: pb::JobState::Running as i32,
            units_done: 383,
            units_total: 512,
            samples_done: 1 << 20,
            samples_per_second: 3.07e6,
            noise_relative: 0.0123,
            eta_seconds: 62.0,
            ..pb::JobStatus::default()
        };
        let at80 = progress_message(&s, 80 - PROGRESS_PREFIX);
        assert_eq!(at80, "383/512 units, noise 1.23%, ETA 1m02s");
        let wide = progress_message(&s, 200);
        assert_eq!(
            wide,
            "running, 383/512 units, 3.07 Msamples/s, noise 1.23%, ETA 1m02s"
        );
        assert_eq!(progress_message(&s, 22), "noise 1.23%, ETA 1m02s");
        assert_eq!(progress_message(&s, 12), "noise 1.23%");
        // Before any sample there is no noise to show.
        let fresh = pb::JobStatus {
            samples_done: 0,
            noise_relative: 0.0,
            ..s
        };
        assert!(progress_message(&fresh, 200).contains("noise –"));
    }
}
