//! `tessera status`, `tessera cancel` and `tessera workers`: the coordinator's views of its
//! jobs and workers ([`JobView`], [`WorkerView`]), as tables or as the JSON the dashboard
//! serves.
use tessera_proto::view::job_state_name;

use super::{connect, fmt_eta, rpc_error};
use crate::farm::{runtime, CoordinatorUrl};
use crate::printable;

use anyhow::{anyhow, bail, Result};
use tessera_proto::v1 as pb;

use tessera_proto::view::{JobView, WorkerView};

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

/// A job's status as JSON for scripts: its view ([`JobView`]), the document the dashboard
/// serves at `/api/jobs/JOB`, with the state as a word and figures that do not exist yet (ETA,
/// noise) as null.
fn job_json(s: &pb::JobStatus) -> Result<String> {
    let view = JobView::try_from(s).map_err(|e| anyhow!("the coordinator sent a job {e}"))?;
    Ok(serde_json::to_string(&view)?)
}

/// The workers as JSON for scripts: their views, as the dashboard serves them.
fn workers_json(workers: &[WorkerView]) -> Result<String> {
    Ok(serde_json::to_string(workers)?)
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
                outln!("{}", job_json(&s)?);
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
            let list = jobs
                .iter()
                .map(JobView::try_from)
                .collect::<Result<Vec<_>, _>>()
                .map_err(|e| anyhow!("the coordinator sent a job {e}"))?;
            outln!("{}", serde_json::to_string(&list)?);
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
            .workers
            .iter()
            .map(WorkerView::try_from)
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| anyhow!("the coordinator sent a worker {e}"))?;
        if args.json {
            outln!("{}", workers_json(&workers)?);
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
                w.state.name(),
                w.leases,
                w.units_done,
                w.samples_done,
                w.bad_results,
                w.audits_passed,
                w.last_seen_seconds_ago,
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
