//! `tessera loadtest`: many simulated workers against one real coordinator on loopback, sending
//! full-size results.
//!
//! The coordinator is a `tessera coordinator` process of its own (this binary), so that its
//! CPU time, memory and bytes written can be read from `/proc` without counting the
//! simulated workers'. The workers are tasks in this process, each with its own connection
//! and registration, doing what a stock worker does with one unit at a time: lease, render,
//! submit. A unit is full size (a 128² tile of a 2048² Cornell box, with the batch the job's
//! settings give it), so the coordinator decodes, checks, merges and stores as many bytes per
//! sample as it does in production. Rendering every unit for real would make the load
//! generator, not the coordinator, the bottleneck: the sums of one real render of a tile (16
//! samples a pixel, made once) are replayed for each unit, scaled to the unit's sample count,
//! so every result passes the coordinator's checks as an honest one does. `--rate` paces the
//! workers to an aggregate rate of samples; without it they send as fast as the coordinator
//! takes them, which measures the most it sustains.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_client::JobsClient;
use tessera_proto::v1::workers_client::WorkersClient;
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{render_tile, PixelRect, RenderSettings, TileSums};
use tonic::transport::Channel;

mod memory;
mod report;
mod training;
use report::{report, to_csv};

/// Arguments of `tessera loadtest`.
#[derive(Debug, clap::Args)]
pub struct LoadArgs {
    /// Simulated worker counts, one run each.
    #[arg(long, value_delimiter = ',', default_values_t = [10usize, 100, 1000])]
    workers: Vec<usize>,
    /// Seconds each run is measured for, once its workers have registered.
    #[arg(long, default_value_t = 20)]
    seconds: u64,
    /// The report's name: OUT_DIR/NAME.md and OUT_DIR/NAME.csv.
    #[arg(long, default_value = "loadtest")]
    name: String,
    /// Where the report goes.
    #[arg(long, default_value = "docs/benchmarks")]
    out_dir: PathBuf,
    /// Give the coordinator CPU 0 and the simulated workers the others (with `taskset`), so
    /// that the workers' load does not take the coordinator's core.
    #[arg(long)]
    split_cores: bool,
    /// Aggregate rate the workers send at, in million samples a second (0: as fast as the
    /// coordinator takes them).
    #[arg(long, default_value_t = 0.0)]
    rate: f64,
    /// The job's batch (default: the one `tessera submit` chooses for it, by the unit rule).
    #[arg(long, value_parser = crate::args::batch_range())]
    batch: Option<u32>,
    /// The coordinator's --checkpoint-interval, in seconds (default: its default).
    #[arg(long)]
    checkpoint_interval: Option<f64>,
    /// The coordinator's --evict-open-over, in bytes (default: its default).
    #[arg(long)]
    evict_open_over: Option<u64>,
    /// The coordinator's --max-unstored-bytes (default: its default).
    #[arg(long)]
    max_unstored_bytes: Option<u64>,
    /// Instead of the rate runs: for each frame edge here (e.g. 4096,8192), render --jobs
    /// jobs of that size² at 8 spp to the end with 16 simulated workers, and report the
    /// coordinator's peak memory and its memory once they are done.
    #[arg(long, value_delimiter = ',')]
    memory: Vec<u32>,
    /// Jobs at once for --memory.
    #[arg(long, default_value_t = 2)]
    jobs: usize,
    /// After each worker count's run, the same with a guided job (`submit --guiding`): its
    /// units return training trees, which the coordinator checks, adds and freezes into
    /// guides between epochs (the records are synthetic; see `load/training.rs`).
    #[arg(long)]
    guiding: bool,
}

/// The job every run renders: a 2048² Cornell box in 128-pixel tiles, with more samples than
/// any run merges (256 tiles × 65,536 samples a pixel: 275 Gsamples).
const SIZE: u32 = 2048;
const SPP: u32 = 65_536;
pub(super) const TILE: u32 = 128;
/// Samples a pixel of the one real render whose sums every result replays.
const TEMPLATE_SPP: u32 = 16;

/// The flags the coordinator under test takes from the load test's own.
fn coordinator_args(args: &LoadArgs) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(c) = args.checkpoint_interval {
        out.extend(["--checkpoint-interval".to_string(), c.to_string()]);
    }
    if let Some(b) = args.evict_open_over {
        out.extend(["--evict-open-over".to_string(), b.to_string()]);
    }
    if let Some(b) = args.max_unstored_bytes {
        out.extend(["--max-unstored-bytes".to_string(), b.to_string()]);
    }
    out
}

fn scene_text() -> String {
    sized_scene(SIZE)
}

/// The Cornell box at `size`² pixels.
pub(super) fn sized_scene(size: u32) -> String {
    include_str!("../../../../scenes/cornell-box.toml")
        .replace("width = 256", &format!("width = {size}"))
        .replace("height = 256", &format!("height = {size}"))
}

fn settings(batch: Option<u32>) -> RenderSettings {
    RenderSettings {
        spp: SPP,
        batch: batch.unwrap_or_else(|| {
            tessera_render::unit_batch(SIZE, SIZE, SPP, false, tessera_render::DEFAULT_UNIT_SAMPLES)
        }),
        seed: 7,
        ..RenderSettings::default()
    }
}

/// The sums of one real render of tile 0 at [`TEMPLATE_SPP`], to be replayed for any unit.
pub(super) fn template(scene: &Scene, batch: u32) -> TileSums {
    let rect = PixelRect {
        x0: 0,
        y0: 0,
        width: TILE,
        height: TILE,
    };
    let s = RenderSettings {
        spp: TEMPLATE_SPP,
        batch: TEMPLATE_SPP,
        ..settings(Some(batch))
    };
    render_tile(scene, &s, rect, 0..TEMPLATE_SPP)
}

/// The template's sums as a `unit`'s: its rectangle and samples, every pixel's sums scaled to
/// the unit's sample count, with the same count of samples left out as non-finite (none, from
/// the Cornell box): sums an honest worker could have sent.
fn replay(t: &TileSums, unit: &pb::WorkUnit) -> Result<pb::TileResult> {
    let rect = unit.rect.ok_or_else(|| anyhow!("a unit without a rect"))?;
    if (rect.width, rect.height) != (t.rect.width, t.rect.height) {
        bail!(
            "unit {}×{} is not the template's size",
            rect.width,
            rect.height
        );
    }
    let n = unit.sample_end.saturating_sub(unit.sample_start);
    let k = n as f64 / TEMPLATE_SPP as f64;
    let scaled = |v: &[[f64; 3]]| v.iter().flatten().map(|x| x * k).collect::<Vec<f64>>();
    let count: Vec<u32> = t.count.iter().map(|c| c * n / TEMPLATE_SPP).collect();
    let nonfinite = count.iter().map(|c| u64::from(n - c)).sum();
    Ok(pb::TileResult {
        rect: Some(rect),
        sample_start: unit.sample_start,
        sample_end: unit.sample_end,
        sum: scaled(&t.sum),
        sum_sq: scaled(&t.sum_sq),
        count,
        nonfinite,
        // The load test's jobs render no AOVs.
        ..pb::TileResult::default()
    })
}

/// One run's figures.
#[derive(Clone, Debug)]
struct Run {
    workers: usize,
    /// A guided job's run.
    guided: bool,
    /// A guided run's training epochs reached, and its largest training tree's bytes.
    trained: (usize, usize),
    seconds: f64,
    merged: u64,
    /// Samples in the merged units.
    samples: u64,
    refused: u64,
    lease_p50_ms: f64,
    lease_p99_ms: f64,
    lease_max_ms: f64,
    probe_p50_ms: f64,
    probe_p99_ms: f64,
    cpu_share: f64,
    rss_mib: f64,
    peak_rss_mib: f64,
    bytes_per_unit: f64,
    /// Coordinator CPU seconds per 10⁹ samples merged.
    cpu_per_gsample: f64,
    /// Bytes the coordinator wrote to storage per 10⁹ samples merged, in MB.
    mb_per_gsample: f64,
}

/// The coordinator process, killed when dropped.
pub(super) struct Coordinator(pub(super) Child);

impl Coordinator {
    /// Starts `tessera coordinator` (this binary) on a free loopback port with its store
    /// under `data`, on CPU 0 alone with `split_cores`: the process and its URL.
    pub(super) fn start(
        data: &std::path::Path,
        max_connections: usize,
        split_cores: bool,
        extra_args: &[String],
    ) -> Result<(Self, String)> {
        let exe = std::env::current_exe()?;
        let mut command = if split_cores {
            let mut c = Command::new("taskset");
            c.args(["-c", "0"]).arg(exe);
            c
        } else {
            Command::new(exe)
        };
        let mut child = command
            .args(["coordinator", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(data)
            .args(["--max-connections", &max_connections.to_string()])
            // Every simulated worker registers from loopback: one host, as far as the
            // coordinator can tell.
            .args(["--max-workers-per-host", &max_connections.to_string()])
            .args(["--tile-size", &TILE.to_string()])
            .args(extra_args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .context("starting the coordinator")?;
        let stdout = child.stdout.take().ok_or_else(|| anyhow!("no stdout"))?;
        let coordinator = Coordinator(child);
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line)?;
        let addr = line
            .trim()
            .strip_prefix("listening on ")
            .ok_or_else(|| anyhow!("the coordinator said {line:?}"))?;
        Ok((coordinator, format!("http://{addr}")))
    }
}

impl Drop for Coordinator {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// (CPU seconds, RSS MiB, peak RSS MiB, bytes written to storage) of process `pid`.
pub(super) fn proc_figures(pid: u32) -> Result<(f64, f64, f64, u64)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    // Fields after the command name, which is in parentheses and may hold spaces.
    let after = stat
        .rsplit_once(')')
        .map(|(_, a)| a)
        .ok_or_else(|| anyhow!("/proc/{pid}/stat: no command name"))?;
    let fields: Vec<&str> = after.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of stat(5), 12 and 13 after the name and state.
    let ticks: f64 = fields
        .get(11..13)
        .ok_or_else(|| anyhow!("/proc/{pid}/stat: too short"))?
        .iter()
        .map(|f| f.parse::<f64>().unwrap_or(0.0))
        .sum();
    // Linux's USER_HZ is 100 on every architecture tessera builds for.
    let cpu = ticks / 100.0;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))?;
    let kib = |key: &str| {
        status
            .lines()
            .find(|l| l.starts_with(key))
            .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    let io = std::fs::read_to_string(format!("/proc/{pid}/io")).unwrap_or_default();
    let written = io
        .lines()
        .find(|l| l.starts_with("write_bytes:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        .unwrap_or(0);
    Ok((cpu, kib("VmRSS:") / 1024.0, kib("VmHWM:") / 1024.0, written))
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// What the simulated workers share: when to stop, and what they saw.
pub(super) struct Shared {
    template: TileSums,
    /// Each worker's time between results, for an aggregate `--rate` (none: no pacing).
    pace: Option<Duration>,
    measuring: AtomicBool,
    pub(super) stop: AtomicBool,
    /// Cleared while workers register: they lease only once it is set, so that a coordinator
    /// saturated by the first ones' results does not keep the last from registering.
    go: AtomicBool,
    merged: AtomicU64,
    samples: AtomicU64,
    refused: AtomicU64,
    /// Results the coordinator deferred (told to retry while it stored merged sums).
    pub(super) deferred: AtomicU64,
    latencies: Mutex<Vec<f64>>,
    /// A guided run's training trees (none: an unguided run).
    trains: Option<training::Trains>,
    /// The probe worker's: one more worker on a thread of its own, whose round trips are the
    /// coordinator's answer time under the others' load, not the load generator's queueing.
    probe_latencies: Mutex<Vec<f64>>,
}

impl Shared {
    /// Workers replaying `template`, `pace` apart each (none: unpaced).
    pub(super) fn new(template: TileSums, pace: Option<Duration>) -> Self {
        Self {
            template,
            pace,
            measuring: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            go: AtomicBool::new(true),
            merged: AtomicU64::new(0),
            samples: AtomicU64::new(0),
            refused: AtomicU64::new(0),
            deferred: AtomicU64::new(0),
            latencies: Mutex::new(Vec::new()),
            trains: None,
            probe_latencies: Mutex::new(Vec::new()),
        }
    }
}

/// One simulated worker: registers, then leases one unit at a time, replays the template as
/// its result and submits it (no sooner than its pace allows), until told to stop.
pub(super) async fn simulated_worker(
    url: String,
    n: usize,
    shared: Arc<Shared>,
    probe: bool,
) -> Result<()> {
    let channel = Channel::from_shared(url)?.connect().await?;
    let mut client = WorkersClient::new(channel);
    let id = client
        .register(pb::RegisterRequest {
            name: format!("load-{n}"),
            cores: 1,
            version: env!("CARGO_PKG_VERSION").into(),
            image_revision: tessera_render::IMAGE_REVISION,
            ..Default::default()
        })
        .await?
        .into_inner()
        .worker_id;
    while !shared.go.load(Ordering::Relaxed) && !shared.stop.load(Ordering::Relaxed) {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let mut mine = Vec::new();
    // Workers start spread over one pace period, as real ones drift apart.
    let mut next = Instant::now()
        + shared
            .pace
            .map_or(Duration::ZERO, |p| p.mul_f64((n % 97) as f64 / 97.0));
    while !shared.stop.load(Ordering::Relaxed) {
        let start = Instant::now();
        let units = client
            .lease(pb::LeaseRequest {
                worker_id: id.clone(),
                max_units: 1,
                wait_ms: 200,
            })
            .await?
            .into_inner()
            .units;
        let measuring = shared.measuring.load(Ordering::Relaxed);
        if measuring && !units.is_empty() {
            mine.push(start.elapsed().as_secs_f64() * 1e3);
        }
        for u in units {
            let mut result = replay(&shared.template, &u)?;
            if let Some(t) = &shared.trains {
                result.guide_train = t.tree(&mut client, &id, &u).await?.to_vec();
            }
            let samples =
                u64::from(u.sample_end - u.sample_start) * u64::from(result.count.len() as u32);
            if let Some(pace) = shared.pace {
                tokio::time::sleep_until(next.into()).await;
                next = Instant::now().max(next) + pace;
            }
            // A deferred result is sent again after the worker's own backoff, as a worker does.
            let mut attempt = 0;
            let outcome = loop {
                let sent = client
                    .submit_result(pb::SubmitResultRequest {
                        worker_id: id.clone(),
                        lease_id: u.lease_id.clone(),
                        job_id: u.job_id.clone(),
                        tile_index: u.tile_index,
                        batch_index: u.batch_index,
                        result: Some(result.clone()),
                    })
                    .await;
                match sent {
                    Ok(r) => break r.into_inner().outcome,
                    Err(e) if e.code() == tonic::Code::Unavailable => {
                        shared.deferred.fetch_add(1, Ordering::Relaxed);
                        // The worker's default longest wait.
                        let max = Duration::from_secs(10);
                        tokio::time::sleep(tessera_worker::backoff_delay(attempt, max)).await;
                        attempt += 1;
                    }
                    Err(e) => return Err(e.into()),
                }
            };
            if shared.measuring.load(Ordering::Relaxed) {
                if outcome == pb::ResultOutcome::Merged as i32 {
                    shared.merged.fetch_add(1, Ordering::Relaxed);
                    shared.samples.fetch_add(samples, Ordering::Relaxed);
                } else {
                    shared.refused.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
    let to = if probe {
        &shared.probe_latencies
    } else {
        &shared.latencies
    };
    to.lock()
        .map_err(|_| anyhow!("a worker panicked"))?
        .extend(mine);
    Ok(())
}

/// One run with `workers` simulated workers for `seconds`.
/// What every run shares: the options, the job's settings and the template result.
struct Plan {
    seconds: u64,
    split_cores: bool,
    rate: f64,
    coordinator_args: Vec<String>,
    settings: RenderSettings,
    template: TileSums,
    /// The scene's box, for guided runs' training trees.
    bounds: [[f32; 3]; 2],
}

/// Waits until the coordinator lists more than `more_than` workers, asking every
/// `interval`; past `limit`, fails with `said(listed)`.
async fn wait_for_workers(
    jobs: &mut JobsClient<tonic::transport::Channel>,
    more_than: usize,
    (limit, interval): (Duration, Duration),
    said: impl Fn(usize) -> String,
) -> Result<()> {
    let start = Instant::now();
    loop {
        let listed = jobs
            .list_workers(pb::ListWorkersRequest {})
            .await
            .map_err(|e| anyhow!("list workers: {}", e.message()))?
            .into_inner()
            .workers
            .len();
        if listed > more_than {
            return Ok(());
        }
        if start.elapsed() > limit {
            bail!("{}", said(listed));
        }
        tokio::time::sleep(interval).await;
    }
}

/// One run with `workers` simulated workers, measured for `plan.seconds`.
async fn run_one(workers: usize, plan: &Plan, guided: bool) -> Result<Run> {
    let (seconds, split_cores) = (plan.seconds, plan.split_cores);
    let dir = tempfile::tempdir()?;
    let (coordinator, url) = Coordinator::start(
        &dir.path().join("data"),
        workers + 64,
        split_cores,
        &plan.coordinator_args,
    )?;
    let pid = coordinator.0.id();
    let mut jobs = JobsClient::connect(url.clone()).await?;
    jobs.submit_job(pb::SubmitJobRequest {
        scene_text: scene_text(),
        scene_name: format!("cornell-{SIZE}.toml"),
        settings: Some(pb::RenderSettings::from(&RenderSettings {
            guiding: guided,
            ..plan.settings.clone()
        })),
        tile_size: TILE,
        ..Default::default()
    })
    .await
    .map_err(|e| anyhow!("submit: {}", e.message()))?;
    let unit_samples = f64::from(TILE * TILE) * f64::from(plan.settings.batch);
    let mut shared = Shared::new(
        plan.template.clone(),
        (plan.rate > 0.0)
            .then(|| Duration::from_secs_f64(workers as f64 * unit_samples / (plan.rate * 1e6))),
    );
    shared.trains = guided.then(|| training::Trains::new(plan.bounds, plan.settings.spp));
    let shared = Arc::new(shared);
    shared.go.store(false, Ordering::Relaxed);
    // The probe first: a coordinator saturated by the others could keep it from registering.
    let probe = {
        let (url, shared) = (url.clone(), shared.clone());
        std::thread::spawn(move || -> Result<()> {
            tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()?
                .block_on(simulated_worker(url, workers, shared, true))
        })
    };
    let wait = (Duration::from_secs(60), Duration::from_millis(20));
    wait_for_workers(&mut jobs, 0, wait, |_| {
        "the probe worker did not register in 60 s".into()
    })
    .await?;
    let tasks: Vec<_> = (0..workers)
        .map(|n| tokio::spawn(simulated_worker(url.clone(), n, shared.clone(), false)))
        .collect();
    // Registered and leasing: wait until the coordinator lists them all.
    let wait = (Duration::from_secs(120), Duration::from_millis(100));
    wait_for_workers(&mut jobs, workers, wait, |listed| {
        format!("only {listed} of {workers} workers registered in 120 s")
    })
    .await?;
    shared.go.store(true, Ordering::Relaxed);
    tokio::time::sleep(Duration::from_secs(1)).await;
    let before = proc_figures(pid)?;
    let t0 = Instant::now();
    shared.measuring.store(true, Ordering::Relaxed);
    tokio::time::sleep(Duration::from_secs(seconds)).await;
    shared.measuring.store(false, Ordering::Relaxed);
    let elapsed = t0.elapsed().as_secs_f64();
    let after = proc_figures(pid)?;
    shared.stop.store(true, Ordering::Relaxed);
    for t in tasks {
        t.await??;
    }
    probe
        .join()
        .map_err(|_| anyhow!("the probe worker panicked"))??;
    drop(coordinator);
    let merged = shared.merged.load(Ordering::Relaxed);
    let samples = shared.samples.load(Ordering::Relaxed);
    let gsamples = (samples as f64 / 1e9).max(f64::MIN_POSITIVE);
    let written = after.3.saturating_sub(before.3) as f64;
    let sorted = |m: &Mutex<Vec<f64>>| -> Result<Vec<f64>> {
        let mut v = std::mem::take(&mut *m.lock().map_err(|_| anyhow!("a worker panicked"))?);
        v.sort_by(f64::total_cmp);
        Ok(v)
    };
    let (lat, probe_lat) = (sorted(&shared.latencies)?, sorted(&shared.probe_latencies)?);
    let trained = shared.trains.as_ref().map_or((0, 0), |t| t.reached());
    Ok(Run {
        workers,
        guided,
        trained,
        seconds: elapsed,
        merged,
        samples,
        refused: shared.refused.load(Ordering::Relaxed),
        lease_p50_ms: percentile(&lat, 0.5),
        lease_p99_ms: percentile(&lat, 0.99),
        lease_max_ms: lat.last().copied().unwrap_or(f64::NAN),
        probe_p50_ms: percentile(&probe_lat, 0.5),
        probe_p99_ms: percentile(&probe_lat, 0.99),
        cpu_share: (after.0 - before.0) / elapsed,
        rss_mib: after.1,
        peak_rss_mib: after.2,
        bytes_per_unit: written / merged.max(1) as f64,
        cpu_per_gsample: (after.0 - before.0) / gsamples,
        mb_per_gsample: written / 1e6 / gsamples,
    })
}

/// Runs `tessera loadtest`.
pub fn run(args: LoadArgs) -> Result<()> {
    if args.workers.is_empty() || args.workers.contains(&0) || args.seconds == 0 {
        bail!("--workers needs counts of at least 1, and --seconds at least 1");
    }
    let clock = super::report::measured_clock_ghz();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if args.split_cores {
        if cores < 2 {
            bail!("--split-cores needs at least 2 cores, and {cores} is available");
        }
        // Before the runtime starts: its threads inherit this thread's CPUs.
        let own = std::process::id().to_string();
        let others = format!("1-{}", cores - 1);
        let ok = Command::new("taskset")
            .args(["-p", "-c", &others, &own])
            .stdout(Stdio::null())
            .status()
            .context("running taskset (util-linux) for --split-cores")?
            .success();
        if !ok {
            bail!("taskset could not move the load generator to CPUs {others}");
        }
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    if !(args.rate.is_finite() && args.rate >= 0.0) {
        bail!(
            "--rate must be a rate in Msamples/s (0: unpaced), got {}",
            args.rate
        );
    }
    let settings = settings(args.batch);
    let scene = Scene::text(&scene_text(), Format::Toml, "cornell", &Limits::default()).load()?;
    if !args.memory.is_empty() {
        return memory::run(
            &args.memory,
            &memory::Plan {
                jobs: args.jobs,
                split_cores: args.split_cores,
                batch: args.batch,
                coordinator_args: coordinator_args(&args),
            },
            &scene,
            &args.out_dir,
            &args.name,
            &runtime,
        );
    }
    let plan = Plan {
        seconds: args.seconds,
        split_cores: args.split_cores,
        rate: args.rate,
        coordinator_args: coordinator_args(&args),
        template: template(&scene, settings.batch),
        bounds: tessera_render::guiding::guide_bounds(&scene),
        settings,
    };
    errln!(
        "units: {TILE}² pixels × {} samples ({:.1} Msamples, {:.0} KB of sums)",
        plan.settings.batch,
        f64::from(TILE * TILE * plan.settings.batch) / 1e6,
        f64::from(TILE * TILE) * 52.0 / 1e3
    );
    let mut runs = Vec::new();
    let kinds: &[bool] = if args.guiding {
        &[false, true]
    } else {
        &[false]
    };
    for (&n, &guided) in args
        .workers
        .iter()
        .flat_map(|n| kinds.iter().map(move |g| (n, g)))
    {
        let kind = if guided { " (guided job)" } else { "" };
        errln!("{n} simulated workers for {} s{kind} …", args.seconds);
        let r = runtime.block_on(run_one(n, &plan, guided))?;
        errln!(
            "  {:.2} Gsamples/s ({:.0} units/s), {:.3} CPU-s and {:.1} MB written per Gsample, lease p50 {:.2} ms p99 {:.2} ms (probe {:.2}/{:.2}), coordinator CPU {:.0}% RSS {:.1} MiB, {:.0} bytes written per unit",
            r.samples as f64 / 1e9 / r.seconds,
            r.merged as f64 / r.seconds,
            r.cpu_per_gsample,
            r.mb_per_gsample,
            r.lease_p50_ms,
            r.lease_p99_ms,
            r.probe_p50_ms,
            r.probe_p99_ms,
            r.cpu_share * 100.0,
            r.rss_mib,
            r.bytes_per_unit
        );
        if guided {
            errln!(
                "  training epochs reached: {}, largest training tree {:.0} KB",
                r.trained.0,
                r.trained.1 as f64 / 1e3
            );
        }
        runs.push(r);
    }
    let command = std::iter::once("tessera".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ");
    std::fs::create_dir_all(&args.out_dir)?;
    let csv = args.out_dir.join(format!("{}.csv", args.name));
    let md = args.out_dir.join(format!("{}.md", args.name));
    std::fs::write(&csv, to_csv(&runs))?;
    std::fs::write(
        &md,
        report(&runs, &command, &super::report::machine(clock), &plan),
    )?;
    outln!("wrote {} and {}", md.display(), csv.display());
    Ok(())
}
