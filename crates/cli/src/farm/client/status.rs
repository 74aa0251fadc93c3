//! `tessera status`, `tessera cancel` and `tessera workers`: the coordinator's views of its
//! jobs and workers ([`JobView`], [`WorkerView`]), as tables or as the JSON the dashboard
//! serves.
use tessera_proto::view::job_state_name;

use super::{connect, fmt_eta, rpc_error};
use crate::farm::{runtime, CoordinatorUrl};
use crate::terminal::printable;

use anyhow::{anyhow, bail, Result};
use tessera_proto::v1 as pb;

use tessera_proto::view::{JobState, JobView, WorkerView};

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
    #[arg(long, conflicts_with_all = ["drain", "release"])]
    json: bool,
    /// Drain the live workers of this name (or this worker id) instead of listing: each
    /// finishes the units it holds, hands back those not started, and exits.
    #[arg(long, value_name = "NAME|ID", conflicts_with = "release")]
    drain: Option<String>,
    /// Lift the quarantine of the workers of this name (or this worker id), an admin's verb:
    /// their count of invalid results and any audit conviction are cleared, and they may
    /// lease again.
    #[arg(long, value_name = "NAME|ID")]
    release: Option<String>,
}

/// A job's status as its view ([`JobView`]): what the table, the detail and `--json` print.
/// `--json` serialises it as it is, the document the dashboard serves at `/api/jobs/JOB`, with
/// the state as a word and figures that do not exist yet (ETA, noise) as null.
fn job_view(s: &pb::JobStatus) -> Result<JobView> {
    JobView::try_from(s).map_err(|e| anyhow!("the coordinator sent a job {e}"))
}

/// One job in detail, as `tessera status JOB` prints it: what it renders, how it is
/// scheduled, how far it is, and a range's frames.
fn print_job(v: &JobView) -> std::io::Result<()> {
    print_what(v)?;
    print_scheduling(v)?;
    print_progress(v)?;
    print_frames(v)
}

/// The job's state, scene, image and render settings.
fn print_what(v: &JobView) -> std::io::Result<()> {
    let settings = &v.settings;
    outln!("{}", v.job_id);
    if v.paused {
        outln!(
            "  state      {} (paused: `tessera resume` to go on)",
            v.state.name()
        );
    } else {
        outln!("  state      {}", v.state.name());
    }
    if !v.error.is_empty() {
        outln!("  error      {}", printable(&v.error));
    }
    outln!(
        "  scene      {} (sha256 {})",
        printable(&v.scene),
        v.scene_sha256
    );
    outln!(
        "  image      {}×{}, {} spp, seed {}, batch {}, tiles {}",
        v.width,
        v.height,
        settings.spp,
        settings.seed,
        settings.batch,
        v.tile_size
    );
    if let Some(f) = settings.frame {
        outln!("  frame      {f}");
    }
    if let Some(r) = v.range_job_id {
        outln!("  range      a frame of {r}");
    }
    if let Some(target) = settings.noise_target {
        outln!(
            "  adaptive   noise target {target} (expected √relMSE of the image; {} spp is the cap)",
            settings.spp
        );
    }
    if settings.guiding {
        outln!(
            "  guiding    path guiding: epochs of doubling samples, each sampling the last's guide"
        );
    }
    Ok(())
}

/// Its priority, submitter, dependency, requirements, failures and why it waits.
fn print_scheduling(v: &JobView) -> std::io::Result<()> {
    outln!("  priority   {}", v.priority);
    if !v.submitter.is_empty() {
        outln!("  submitter  {}", printable(&v.submitter));
    }
    if let Some(a) = v.after {
        let waiting = if v.state == JobState::Queued {
            " (starts when it is done)"
        } else {
            ""
        };
        outln!("  after      {a}{waiting}");
    }
    if !v.require.is_empty() || v.min_memory_bytes > 0 {
        let mut needs = v.require.clone();
        if v.min_memory_bytes > 0 {
            needs.push(format!(
                "{} of memory",
                tessera_proto::tags::memory_words(v.min_memory_bytes)
            ));
        }
        outln!("  requires   {}", printable(&needs.join(", ")));
    }
    if v.failures > 0 {
        let blocked = if v.blocklist.is_empty() {
            String::new()
        } else {
            format!("; blocklisted: {}", printable(&v.blocklist.join(", ")))
        };
        outln!(
            "  failures   {} unit(s) failed on workers and went to others{blocked}",
            v.failures
        );
    }
    if v.retries > 0 {
        outln!("  retried    {} time(s) (tessera retry)", v.retries);
    }
    if v.retryable {
        outln!(
            "  retry      tessera retry {} puts the failed frames back",
            v.job_id
        );
    }
    if let Some(w) = &v.waiting {
        outln!("  waiting    {}", printable(w));
    }
    Ok(())
}

/// How far it is: units, samples, rate, noise, output and the finished image's checks.
fn print_progress(v: &JobView) -> std::io::Result<()> {
    outln!(
        "  progress   {}/{} units ({} leased), {}/{} samples",
        v.units_done,
        v.units_total,
        v.units_leased,
        v.samples_done,
        v.samples_total
    );
    outln!(
        "  rate       {:.2} Msamples/s, ETA {}",
        v.samples_per_second / 1e6,
        fmt_eta(v.eta_seconds.unwrap_or(f64::NAN))
    );
    match (v.noise_rms, v.noise_relative) {
        (Some(rms), Some(rel)) => outln!(
            "  noise      σ≈{rms:.4} ({:.2}% of mean), {} non-finite samples",
            rel * 100.0,
            v.nonfinite_samples
        ),
        _ => outln!("  noise      – (no sample merged)"),
    }
    outln!("  output     {}", v.output);
    for c in &v.checks {
        outln!(
            "  check      {}: {}",
            printable(&c.code),
            printable(&c.message)
        );
    }
    if v.progressive {
        outln!("  order      progressive: every frame's first batch before any frame's second");
    }
    Ok(())
}

/// A frame range's frames, one line each.
fn print_frames(v: &JobView) -> std::io::Result<()> {
    if let Some(r) = v.frame_range {
        let count = |st: JobState| v.frames.iter().filter(|f| f.state == st).count();
        outln!(
            "  frames     {}-{}:{}, {} frames: {} done, {} running, {} queued, {} failed, {} \
             cancelled",
            r.first,
            r.last,
            r.step,
            v.frames.len(),
            count(JobState::Done),
            count(JobState::Running),
            count(JobState::Queued),
            count(JobState::Failed),
            count(JobState::Cancelled)
        );
        outln!(
            "  {:>8} {:<12} {:<10} {:>12}  OUTPUT",
            "FRAME",
            "JOB",
            "STATE",
            "UNITS"
        );
        for f in &v.frames {
            outln!(
                "  {:>8} {:<12} {:<10} {:>12}  {}",
                f.frame,
                f.job_id.to_string(),
                f.state.name(),
                format!("{}/{}", f.units_done, f.units_total),
                f.output
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
            let v = job_view(&s)?;
            if args.json {
                outln!("{}", serde_json::to_string(&v)?);
            } else {
                print_job(&v)?;
            }
            return Ok(());
        }
        // A page at a time, so that no answer nears the message limit however many jobs the
        // coordinator keeps.
        let mut jobs = Vec::new();
        let mut page_token = String::new();
        loop {
            let page = client
                .list_jobs(pb::ListJobsRequest {
                    page_size: 1000,
                    page_token,
                })
                .await
                .map_err(|e| rpc_error(&url, "listing jobs", e))?
                .into_inner();
            for s in &page.jobs {
                jobs.push(job_view(s)?);
            }
            if page.next_page_token.is_empty() {
                break;
            }
            page_token = page.next_page_token;
        }
        if args.json {
            outln!("{}", serde_json::to_string(&jobs)?);
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
        for v in jobs {
            // A finished image's failed checks, after the scene: flagged where it is listed.
            let mut codes: Vec<&str> = v.checks.iter().map(|c| c.code.as_str()).collect();
            codes.sort_unstable();
            codes.dedup();
            let flagged = if codes.is_empty() {
                String::new()
            } else {
                format!("  [flagged: {}]", printable(&codes.join(", ")))
            };
            let waiting = match &v.waiting {
                Some(w) => format!("  [waiting: {}]", printable(w)),
                None => String::new(),
            };
            outln!(
                "{:<12} {:<10} {:>8} {:>6.1}% {:>10} {:>8}  {}{flagged}{waiting}",
                v.job_id.to_string(),
                if v.paused { "paused" } else { v.state.name() },
                v.priority,
                100.0 * v.units_done as f64 / v.units_total.max(1) as f64,
                v.units_total,
                fmt_eta(v.eta_seconds.unwrap_or(f64::NAN)),
                printable(&v.scene)
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
        if let Some(who) = &args.drain {
            let drained = client
                .drain_worker(pb::DrainWorkerRequest {
                    worker: who.clone(),
                })
                .await
                .map_err(|e| rpc_error(&url, &format!("draining {who}"), e))?
                .into_inner()
                .drained;
            outln!(
                "draining {}: each finishes the units it holds, hands back the rest, and exits",
                printable(&drained.join(", "))
            );
            return Ok(());
        }
        if let Some(who) = &args.release {
            let released = client
                .release_worker(pb::ReleaseWorkerRequest {
                    worker: who.clone(),
                })
                .await
                .map_err(|e| rpc_error(&url, &format!("releasing {who}"), e))?
                .into_inner()
                .released;
            outln!(
                "released {} from quarantine: they may lease again",
                printable(&released.join(", "))
            );
            return Ok(());
        }
        let workers = client
            .list_workers(pb::ListWorkersRequest {})
            .await
            .map_err(|e| rpc_error(&url, "listing workers", e))?
            .into_inner()
            .workers
            .iter()
            .map(WorkerView::try_from)
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| anyhow!("the coordinator sent a worker {e}"))?;
        if args.json {
            // The document the dashboard serves at `/api/workers`.
            outln!("{}", serde_json::to_string(&workers)?);
            return Ok(());
        }
        outln!(
            "{:<10} {:<20} {:>5} {:<11} {:>6} {:>8} {:>12} {:>5} {:>6} {:>9} {:>9} {:<16} HOST",
            "WORKER",
            "NAME",
            "CORES",
            "STATE",
            "LEASES",
            "UNITS",
            "SAMPLES",
            "BAD",
            "AUDITS",
            "SEEN",
            "MEMORY",
            "TAGS"
        );
        for w in &workers {
            outln!(
                "{:<10} {:<20} {:>5} {:<11} {:>6} {:>8} {:>12} {:>5} {:>6} {:>8.1}s {:>9} {:<16} {}",
                w.worker_id.to_string(),
                printable(&w.name),
                w.cores,
                w.state.name(),
                w.leases,
                w.units_done,
                w.samples_done,
                w.bad_results,
                w.audits_passed,
                w.last_seen_seconds_ago,
                if w.memory_bytes == 0 {
                    "-".to_string()
                } else {
                    tessera_proto::tags::memory_words(w.memory_bytes).replace(' ', "")
                },
                worker_tags(w),
                w.host.as_deref().map_or("-".to_string(), printable)
            );
        }
        for w in &workers {
            if let Some(why) = &w.convicted {
                outln!(
                    "{} ({}): {}",
                    w.worker_id,
                    printable(&w.name),
                    printable(why)
                );
            }
        }
        Ok(())
    })
}

/// A worker's TAGS column: its operator tags, and `denoise` for one that denoises finished
/// frames (`tessera worker --denoise`).
fn worker_tags(w: &WorkerView) -> String {
    let mut tags = w.tags.clone();
    if w.denoise_version > 0 {
        tags.push("denoise".to_string());
    }
    if tags.is_empty() {
        "-".to_string()
    } else {
        printable(&tags.join(","))
    }
}
