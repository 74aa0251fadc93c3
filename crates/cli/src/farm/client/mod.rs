//! The client commands, over a coordinator's `Jobs` service: `submit` ([`submit`](mod@submit)),
//! `status`, `cancel` and `workers` ([`status`](mod@status)), and `fetch` ([`fetch`](mod@fetch)).
//! What they share is here: the connection, one-line errors, following a job with a progress
//! bar, and downloading its EXR.

mod control;
mod fetch;
mod logs;
mod status;
mod submit;

use std::path::Path;
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use indicatif::ProgressBar;
use tessera_proto::client::{endpoint, Bearer};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_client::JobsClient;
use tessera_proto::view::job_state_name;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;
use tonic::Code;

pub use control::{pause, priority, retry, PauseArgs, PriorityArgs, RetryArgs};
pub use fetch::{fetch, FetchArgs};
pub use logs::{logs, LogsArgs};
pub use status::{cancel, status, workers, CancelArgs, StatusArgs, WorkersArgs};
pub use submit::{submit, SubmitArgs};

use super::CoordinatorUrl;
use crate::terminal::{printable, progress_style};

/// Turns a gRPC error into one line that says what failed.
fn rpc_error(url: &str, what: &str, e: tonic::Status) -> anyhow::Error {
    if answers_http_not_grpc(&e) {
        return anyhow!(
            "{url} answers HTTP, not gRPC: it looks like the coordinator's dashboard port. \
             Clients and workers use its gRPC port, the one `tessera coordinator` prints as \
             `listening on` (127.0.0.1:7878 by default), not its dashboard (--http) address"
        );
    }
    match e.code() {
        Code::Unavailable => anyhow!("{}", tessera_proto::client::unreachable(url, &e)),
        _ if e.message().contains(what) => anyhow!("{}", e.message()),
        _ => anyhow!("{what}: {}", e.message()),
    }
}

/// Whether `e` is what tonic makes of an HTTP answer that is not gRPC (a web page's body read
/// as a gRPC frame: "invalid compression flag: 110" is its first byte, or a status without
/// `grpc-status`).
fn answers_http_not_grpc(e: &tonic::Status) -> bool {
    let m = e.message();
    m.contains("invalid compression flag")
        || m.contains("grpc-status header missing")
        || m.contains("invalid content type")
}

/// A `Jobs` client with the token attached.
type Client = JobsClient<InterceptedService<Channel, Bearer>>;

async fn connect(args: &CoordinatorUrl) -> Result<Client> {
    let url = &args.coordinator;
    let options = args.options()?;
    let endpoint = endpoint(url, &options)?;
    let channel = endpoint
        .connect()
        .await
        .map_err(|e| anyhow!("{}", tessera_proto::client::unreachable(url, &e)))?;
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
        if live && !s.waiting.is_empty() {
            // Workers are there, and none can take it: its requirements say why.
            if !self.warned {
                self.warned = true;
                bar.suspend(|| {
                    errln!(
                        "{} is waiting: {} (still waiting)",
                        s.job_id,
                        printable(&s.waiting)
                    )
                });
            }
        } else if live {
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

/// `s` if its job is done (with a warning for each check its image failed), else an error
/// that says how it ended.
fn done(job: &str, s: pb::JobStatus) -> Result<pb::JobStatus> {
    match pb::JobState::try_from(s.state) {
        Ok(pb::JobState::Done) => {
            for c in &s.checks {
                errln!("warning: {job}: {}", printable(&c.message));
            }
            Ok(s)
        }
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
    // As `tessera render` writes its EXR: complete or not at all, never through a link, and
    // readable as any new file of the user's (it was 0600).
    tessera_render::files::place_bytes(
        out,
        tessera_render::files::Place::Replace,
        tessera_render::files::Access::Shared,
        &data,
    )
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
