//! `tessera loadtest --memory`: the coordinator's memory for large frames, from admission to
//! the written EXR. Jobs of a frame edge (4096, 8192, …) at 8 spp are rendered to the end by
//! simulated workers replaying real sums (as the rate runs do), while the coordinator's
//! resident memory is sampled; the report gives its peak and what it holds once every job is
//! done.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Result};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_client::JobsClient;
use tessera_render::scene::Scene;
use tessera_render::RenderSettings;

use super::{proc_figures, simulated_worker, sized_scene, template, Coordinator, Shared, TILE};

/// Samples per pixel of every job.
const SPP: u32 = 8;
/// Simulated workers.
const WORKERS: usize = 16;

/// One frame size's figures.
struct MemRun {
    size: u32,
    jobs: usize,
    batch: u32,
    seconds: f64,
    peak_mib: f64,
    done_mib: f64,
    later_mib: f64,
    idle_mib: f64,
    sums_mib: f64,
    deferred: u64,
}

/// How `--memory` runs its jobs.
pub(crate) struct Plan {
    /// Jobs at once.
    pub jobs: usize,
    /// The coordinator on core 0, the simulated workers on the rest.
    pub split_cores: bool,
    /// Every job's batch (default: the unit rule's).
    pub batch: Option<u32>,
    /// Flags for the coordinator.
    pub coordinator_args: Vec<String>,
}

/// Runs `--memory` for each of `sizes` and writes OUT_DIR/NAME.md.
pub(crate) fn run(
    sizes: &[u32],
    plan: &Plan,
    scene: &Scene,
    out_dir: &Path,
    name: &str,
    runtime: &tokio::runtime::Runtime,
) -> Result<()> {
    let jobs = plan.jobs;
    if jobs == 0 || sizes.iter().any(|s| *s < TILE || s % TILE != 0) {
        bail!("--memory needs frame edges that are multiples of {TILE}, and --jobs at least 1");
    }
    let mut runs = Vec::new();
    for &size in sizes {
        errln!("{jobs} jobs of {size}² at {SPP} spp …");
        let r = runtime.block_on(one(size, plan, scene))?;
        errln!(
            "  {:.1} s; coordinator RSS peak {:.0} MiB, {:.0} MiB 2 s after the jobs are done and {:.0} MiB 15 s after ({:.0} MiB before them); their sums {:.0} MiB; {} results deferred",
            r.seconds, r.peak_mib, r.done_mib, r.later_mib, r.idle_mib, r.sums_mib, r.deferred
        );
        runs.push(r);
    }
    let command = std::iter::once("tessera".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ");
    let mut md = String::from("# The coordinator's memory for large frames\n\n");
    let _ = writeln!(md, "Made by `{command}`.\n");
    let _ = writeln!(
        md,
        "Machine: {}.\n",
        crate::bench::report::machine(crate::bench::report::measured_clock_ghz())
    );
    let _ = writeln!(
        md,
        "Each row: a `tessera coordinator` process on loopback, {jobs} Cornell-box jobs of the \
         frame size at {SPP} spp submitted at once (in the batch the table gives: {}), \
         rendered to the end by {WORKERS} simulated workers replaying real sums, each job's \
         EXR written. The resident set (`VmRSS`) is sampled every 50 ms; the peak is the \
         kernel's `VmHWM`. \"Sums\" is what the jobs' per-pixel accumulators take (52 bytes a \
         pixel), for scale. \"Results deferred\" counts the times the coordinator told a worker to send a result again later, because merged sums were waiting for its store.\n",
        if plan.batch.is_some() {
            "the load test's --batch"
        } else {
            "the unit rule's"
        }
    );
    if !plan.coordinator_args.is_empty() {
        let _ = writeln!(
            md,
            "The coordinator ran with `{}`.\n",
            plan.coordinator_args.join(" ")
        );
    }
    md.push_str("| frame | jobs | batch | seconds | RSS before the jobs, MiB | peak RSS, MiB | RSS 2 s after the jobs are done, MiB | 15 s after, MiB | their sums, MiB | results deferred |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for r in &runs {
        let _ = writeln!(
            md,
            "| {s}² | {} | {} | {:.1} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {} |",
            r.jobs,
            r.batch,
            r.seconds,
            r.idle_mib,
            r.peak_mib,
            r.done_mib,
            r.later_mib,
            r.sums_mib,
            r.deferred,
            s = r.size
        );
    }
    std::fs::create_dir_all(out_dir)?;
    let path = out_dir.join(format!("{name}.md"));
    std::fs::write(&path, md)?;
    outln!("wrote {}", path.display());
    Ok(())
}

async fn one(size: u32, plan: &Plan, scene: &Scene) -> Result<MemRun> {
    let jobs = plan.jobs;
    let dir = tempfile::tempdir()?;
    let (coordinator, url) = Coordinator::start(
        &dir.path().join("data"),
        WORKERS + 64,
        plan.split_cores,
        &plan.coordinator_args,
    )?;
    let pid = coordinator.0.id();
    let idle_mib = proc_figures(pid)?.1;
    let batch = plan.batch.unwrap_or_else(|| {
        tessera_render::unit_batch(size, size, SPP, false, tessera_render::DEFAULT_UNIT_SAMPLES)
    });
    let settings = RenderSettings {
        spp: SPP,
        batch,
        ..RenderSettings::default()
    };
    let mut client = JobsClient::new(
        tonic::transport::Channel::from_shared(url.clone())?
            .connect()
            .await?,
    )
    .max_decoding_message_size(64 << 20);
    for j in 0..jobs {
        client
            .submit_job(pb::SubmitJobRequest {
                scene_text: sized_scene(size),
                scene_name: format!("cornell-{size}-{j}.toml"),
                settings: Some(pb::RenderSettings::from(&RenderSettings {
                    seed: j as u64,
                    ..settings.clone()
                })),
                tile_size: TILE,
                ..Default::default()
            })
            .await
            .map_err(|e| anyhow!("submit: {}", e.message()))?;
    }
    let shared = Arc::new(Shared::new(template(scene, batch), None));
    let start = Instant::now();
    let tasks: Vec<_> = (0..WORKERS)
        .map(|n| tokio::spawn(simulated_worker(url.clone(), n, shared.clone(), false)))
        .collect();
    let mut peak = 0f64;
    loop {
        peak = peak.max(proc_figures(pid)?.1);
        let listed = client
            .list_jobs(pb::ListJobsRequest {
                page_size: 1000,
                ..Default::default()
            })
            .await
            .map_err(|e| anyhow!("list jobs: {}", e.message()))?
            .into_inner()
            .jobs;
        let done = listed
            .iter()
            .filter(|j| j.state == pb::JobState::Done as i32)
            .count();
        if let Some(bad) = listed.iter().find(|j| {
            j.state == pb::JobState::Failed as i32 || j.state == pb::JobState::Cancelled as i32
        }) {
            bail!("a job ended without its image: {}", bad.error);
        }
        if done == jobs {
            break;
        }
        if start.elapsed() > Duration::from_secs(1800) {
            bail!("{done} of {jobs} jobs done after 30 minutes");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let seconds = start.elapsed().as_secs_f64();
    let deferred = shared.deferred.load(Ordering::Relaxed);
    shared.stop.store(true, Ordering::Relaxed);
    for t in tasks {
        t.await??;
    }
    // What the coordinator keeps once the work is over: 2 s after, and once the runtime's
    // idle blocking threads (which wrote the EXRs, and whose heaps the allocator gives back
    // when they end) have ended, 10 s later.
    tokio::time::sleep(Duration::from_secs(2)).await;
    let (_, done_mib, _, _) = proc_figures(pid)?;
    tokio::time::sleep(Duration::from_secs(13)).await;
    let (_, later_mib, hwm, _) = proc_figures(pid)?;
    drop(coordinator);
    Ok(MemRun {
        size,
        jobs,
        batch,
        seconds,
        peak_mib: peak.max(hwm),
        done_mib,
        later_mib,
        idle_mib,
        sums_mib: jobs as f64 * f64::from(size) * f64::from(size) * 52.0 / (1 << 20) as f64,
        deferred,
    })
}
