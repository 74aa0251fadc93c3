//! `tessera bench`: speed against error.
//!
//! Renders each scene at 4, 16, … spp with several seeds, times every render, and measures
//! relMSE = mean over pixels and channels of (I − R)²/(R² + 0.01) against a converged
//! reference. It writes a CSV, a markdown report and a log–log plot of error against time.
//! Rows from peers (other renderers, measured by `bench/mitsuba_peer.py` in the same run) are
//! read from CSV files in the same format, or measured point by point, interleaved with
//! tessera's own, by a peer command (`--peer-command`, see [`PeerCommand`]), and compared: the
//! equal-time relMSE ratio is the ratio of relMSE·seconds, which is constant once error falls
//! as 1/time.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Write as _};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use tessera_render::output::{
    read_exr_provenance, read_exr_rgb, render_metadata, write_exr, ExrChannels, RgbImage,
};
use tessera_render::scene::{Limits, Scene};
use tessera_render::{render_frame, Image, RenderSettings};

/// Arguments of `tessera bench`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Scene files (default: the bundled cornell-box, spheres and glass-mirror scenes).
    #[arg(long = "scene")]
    scenes: Vec<PathBuf>,
    /// Largest spp: renders at 4, 16, 64, … up to this (a power of 4).
    #[arg(long, default_value_t = 4096, value_parser = clap::value_parser!(u32).range(4..=65536))]
    max_spp: u32,
    /// Seeds per spp.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=64))]
    seeds: u32,
    /// Worker threads (default: every core).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4096))]
    threads: Option<u32>,
    /// A converged reference for a scene, as NAME=FILE.exr (NAME is the scene file's stem, and
    /// must be one of the scenes benchmarked).
    /// cornell-box defaults to the independent Mitsuba reference in tests/data; other scenes
    /// without one get a tessera render at --reference-spp, cached under --cache.
    #[arg(long = "reference")]
    references: Vec<String>,
    /// Samples per pixel of the references tessera renders itself.
    #[arg(long, default_value_t = 16384, value_parser = clap::value_parser!(u32).range(1..))]
    reference_spp: u32,
    /// Where self-rendered references are cached (keyed by scene hash and spp).
    #[arg(long, default_value = "target/bench-cache")]
    cache: PathBuf,
    /// CSV files of peer measurements (same columns as the CSV this writes).
    #[arg(long = "peer")]
    peers: Vec<PathBuf>,
    /// A peer renderer to measure interleaved with tessera, run with `sh -c`: after each of
    /// tessera's points it is asked for the same scene, spp and seed (one `SCENE SPP SEED` line
    /// on its stdin) and answers with CSV rows and a `done` line, so that both renderers are
    /// timed within seconds of each other and a slow minute of a shared machine falls on both.
    /// `bench/mitsuba_peer.py --serve` is one.
    #[arg(long)]
    peer_command: Option<String>,
    /// Output directory.
    #[arg(long, default_value = "docs/benchmarks")]
    out: PathBuf,
    /// Base name of the report files (NAME.csv, NAME.md, NAME.svg).
    #[arg(long, default_value = "speed-vs-error")]
    name: String,
}

/// One timed render.
#[derive(Clone, Debug)]
struct Row {
    renderer: String,
    scene: String,
    spp: u32,
    seed: u64,
    threads: usize,
    seconds: f64,
    msamples_per_s: f64,
    relmse: f64,
}

const CSV_HEADER: &str = "renderer,scene,spp,seed,threads,seconds,msamples_per_s,relmse";

impl Row {
    fn to_csv(&self) -> String {
        format!(
            "{},{},{},{},{},{:.6},{:.4},{:.6e}",
            self.renderer,
            self.scene,
            self.spp,
            self.seed,
            self.threads,
            self.seconds,
            self.msamples_per_s,
            self.relmse
        )
    }

    /// One CSV row; `at` says where it came from (`FILE:LINE`) for the error.
    fn parse(line: &str, at: &str) -> Result<Self> {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != 8 {
            bail!(
                "{}: expected 8 comma-separated fields ({CSV_HEADER}), found {}",
                at,
                f.len()
            );
        }
        let num = |i: usize, what: &str| -> Result<f64> {
            let v: f64 = f[i]
                .parse()
                .with_context(|| format!("{}: {what} {:?} is not a number", at, f[i]))?;
            if !v.is_finite() || v < 0.0 {
                bail!(
                    "{}: {what} must be a finite non-negative number, got {v}",
                    at
                );
            }
            Ok(v)
        };
        let row = Row {
            renderer: f[0].to_string(),
            scene: f[1].to_string(),
            spp: num(2, "spp")? as u32,
            seed: num(3, "seed")? as u64,
            threads: num(4, "threads")? as usize,
            seconds: num(5, "seconds")?,
            msamples_per_s: num(6, "msamples_per_s")?,
            relmse: num(7, "relmse")?,
        };
        if row.renderer.is_empty() || row.scene.is_empty() || row.seconds <= 0.0 || row.spp == 0 {
            bail!(
                "{}: renderer and scene must be named, spp and seconds positive",
                at
            );
        }
        Ok(row)
    }
}

/// A peer renderer run as a child process that measures one point at a time, so that each of
/// its points is timed right after tessera's point of the same scene, spp and seed. A peer
/// measured in a separate pass runs minutes away from tessera's matching point, and a slow
/// minute of a shared machine then lands on one side of the ratio only.
///
/// The protocol is one line at a time. tessera writes `SCENE SPP SEED`. The peer answers with
/// zero or more rows in the CSV format (one per renderer it runs at that point, none for a
/// scene it has no counterpart of) and then `done`. A line `error: MESSAGE` ends the run with
/// that message. Closing its stdin asks it to exit.
struct PeerCommand {
    command: String,
    child: Child,
    stdin: Option<ChildStdin>,
    stdout: BufReader<ChildStdout>,
    /// Lines read so far, to say which line of the peer's output was wrong.
    lines: usize,
}

impl PeerCommand {
    fn start(command: &str) -> Result<Self> {
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(command)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("starting --peer-command {command:?}"))?;
        let (Some(stdin), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            bail!("--peer-command {command:?}: no pipe to its stdin or stdout");
        };
        Ok(Self {
            command: command.to_string(),
            child,
            stdin: Some(stdin),
            stdout: BufReader::new(stdout),
            lines: 0,
        })
    }

    /// The peer's rows for one point, checked to be that point's.
    fn measure(&mut self, scene: &str, spp: u32, seed: u64) -> Result<Vec<Row>> {
        let point = format!("{scene} {spp} {seed}");
        let sent = self.stdin.as_mut().is_some_and(|stdin| {
            writeln!(stdin, "{point}")
                .and_then(|()| stdin.flush())
                .is_ok()
        });
        if !sent {
            return Err(self.ended(&point));
        }
        let mut rows = Vec::new();
        loop {
            let mut line = String::new();
            let read = self.stdout.read_line(&mut line).with_context(|| {
                format!(
                    "--peer-command {:?}: reading its answer to `{point}`",
                    self.command
                )
            })?;
            if read == 0 {
                return Err(self.ended(&point));
            }
            self.lines += 1;
            let line = line.trim();
            if line == "done" {
                return Ok(rows);
            }
            if let Some(message) = line.strip_prefix("error:") {
                bail!(
                    "--peer-command {:?} failed at `{point}`: {}",
                    self.command,
                    message.trim()
                );
            }
            let at = format!("--peer-command output line {}", self.lines);
            let row = Row::parse(line, &at)?;
            if (row.scene.as_str(), row.spp, row.seed) != (scene, spp, seed) {
                bail!(
                    "{at}: a row for scene {} at {} spp, seed {}, in answer to `{point}`",
                    row.scene,
                    row.spp,
                    row.seed
                );
            }
            if row.renderer == "tessera" {
                bail!("{at}: a peer's row may not be named tessera");
            }
            rows.push(row);
        }
    }

    /// The error for a peer that closed its pipes before answering `point`, with how it ended.
    fn ended(&mut self, point: &str) -> anyhow::Error {
        self.stdin = None;
        let status = self
            .child
            .wait()
            .map_or_else(|e| format!("cannot tell how: {e}"), |s| s.to_string());
        anyhow::anyhow!(
            "--peer-command {:?} ended ({status}) before it answered `{point}`",
            self.command
        )
    }
}

impl Drop for PeerCommand {
    /// Closes the peer's stdin, which asks it to exit, and waits a little for it; a peer that
    /// does not exit by then is killed, so that it never outlives the bench.
    fn drop(&mut self) {
        self.stdin = None;
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            match self.child.try_wait() {
                Ok(Some(_)) | Err(_) => return,
                Ok(None) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// relMSE of `img` against `reference`: mean over pixels and channels of (I−R)²/(R²+0.01).
fn rel_mse(img: &Image, reference: &RgbImage) -> f64 {
    let mut sum = 0f64;
    for (p, r) in img.rgb.iter().zip(&reference.rgb) {
        for c in 0..3 {
            let (i, r) = (p[c] as f64, r[c] as f64);
            sum += (i - r) * (i - r) / (r * r + 0.01);
        }
    }
    sum / (3 * img.rgb.len()) as f64
}

/// The core clock, timed on a chain of dependent rotate-and-xor operations, which take one
/// cycle each on current x86-64 and AArch64 cores. The best of three runs, so a moment's
/// contention does not lower it. Shared machines change clock from one sitting to the next,
/// and with it every absolute figure of a report; the ratios, measured in one run, do not.
fn measured_clock_ghz() -> f64 {
    // Not inlined, so the chain's length stays opaque to the optimiser.
    #[inline(never)]
    fn chain(n: u64, mut x: u64) -> u64 {
        for _ in 0..n {
            x = x.rotate_left(1) ^ 0x9e37_79b9_7f4a_7c15;
        }
        x
    }
    const STEPS: u64 = 100_000_000;
    (0..3)
        .map(|_| {
            let start = Instant::now();
            std::hint::black_box(chain(std::hint::black_box(STEPS), 1));
            2.0 * STEPS as f64 / start.elapsed().as_secs_f64().max(1e-9) / 1e9
        })
        .fold(0.0, f64::max)
}

/// The vector extensions this CPU has. tessera is built for baseline x86-64 so that every worker
/// rounds alike, but a peer that compiles its kernels on the host (Mitsuba's `llvm_ad_rgb`) uses
/// the widest it finds, so this explains much of a peer's speed from one sitting to the next.
fn simd_extensions() -> String {
    #[cfg(target_arch = "x86_64")]
    let found: Vec<&str> = [
        ("SSE4.1", std::arch::is_x86_feature_detected!("sse4.1")),
        ("AVX", std::arch::is_x86_feature_detected!("avx")),
        ("AVX2", std::arch::is_x86_feature_detected!("avx2")),
        ("FMA", std::arch::is_x86_feature_detected!("fma")),
        ("AVX-512F", std::arch::is_x86_feature_detected!("avx512f")),
    ]
    .into_iter()
    .filter_map(|(name, has)| has.then_some(name))
    .collect();
    #[cfg(target_arch = "aarch64")]
    let found = vec!["NEON"];
    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
    let found: Vec<&str> = Vec::new();
    if found.is_empty() {
        "none detected".into()
    } else {
        found.join(", ")
    }
}

fn machine(clock_ghz: f64) -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let mem = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("MemTotal"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map(|kb| format!(", {:.0} GiB", kb / 1024.0 / 1024.0))
        .unwrap_or_default();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!(
        "{cpu}, {cores} cores available{mem}; vector extensions: {}; clock {clock_ghz:.2} GHz \
         (timed on a chain of dependent rotate-and-xor operations, one cycle each, before \
         rendering)",
        simd_extensions()
    )
}

/// The `--reference NAME=FILE.exr` arguments by scene name, checked before anything renders:
/// a malformed one, a name given twice or a name that is none of `names` is an error, since a
/// reference silently ignored would leave the report measured against another one.
fn given_references<'a>(
    args: &'a BenchArgs,
    names: &[String],
) -> Result<BTreeMap<&'a str, &'a Path>> {
    let mut given = BTreeMap::new();
    for r in &args.references {
        let (name, file) = r
            .split_once('=')
            .with_context(|| format!("--reference {r:?}: expected NAME=FILE.exr"))?;
        if !names.iter().any(|n| n == name) {
            bail!(
                "--reference {r:?}: no scene is named {name:?} (the scenes are {})",
                names.join(", ")
            );
        }
        if given.insert(name, Path::new(file)).is_some() {
            bail!("--reference {r:?}: {name} is given a reference twice");
        }
    }
    Ok(given)
}

/// The reference for `name`: given, the bundled independent one, or rendered here (cached).
fn reference(
    args: &BenchArgs,
    given: Option<&Path>,
    name: &str,
    scene: &Scene,
    pool: &rayon::ThreadPool,
) -> Result<(RgbImage, String)> {
    if let Some(file) = given {
        let img = read_exr_rgb(file)?;
        let origin = read_exr_provenance(file)?
            .unwrap_or_else(|| "its header does not say where it came from".into());
        return Ok((img, format!("`{}` ({origin})", file.display())));
    }
    let bundled = Path::new("tests/data").join(format!("{name}-reference.exr"));
    if bundled.is_file() {
        return Ok((
            read_exr_rgb(&bundled)?,
            format!(
                "`{}` (independent: Mitsuba 3, 16384 spp)",
                bundled.display()
            ),
        ));
    }
    let spp = args.reference_spp;
    let cached = args.cache.join(format!("{}-{spp}.exr", &scene.hash[..16]));
    if !cached.is_file() {
        std::fs::create_dir_all(&args.cache)
            .with_context(|| format!("creating {}", args.cache.display()))?;
        errln!(
            "rendering a {spp}-spp reference of {name} (cached as {})",
            cached.display()
        );
        // A seed no benchmark render uses, so the reference's noise is independent.
        let settings = RenderSettings {
            seed: u64::MAX,
            spp,
            ..RenderSettings::default()
        };
        let img = pool
            .install(|| render_frame(scene, &settings, &|_| {}))
            .finalize();
        write_exr(
            &cached,
            &img,
            ExrChannels::default(),
            &render_metadata(&scene.hash, &settings),
        )?;
    }
    Ok((
        read_exr_rgb(&cached)?,
        format!("tessera at {spp} spp, seed 2⁶⁴−1 (`{}`)", cached.display()),
    ))
}

/// Runs `tessera bench`.
pub fn run(args: BenchArgs) -> Result<()> {
    if !args.max_spp.is_power_of_two() || !args.max_spp.trailing_zeros().is_multiple_of(2) {
        bail!(
            "--max-spp must be a power of 4 (4, 16, 64, …), got {}",
            args.max_spp
        );
    }
    if !args.out.is_dir() {
        bail!("output directory {} does not exist", args.out.display());
    }
    let scenes = if args.scenes.is_empty() {
        ["cornell-box", "spheres", "glass-mirror"]
            .iter()
            .map(|s| PathBuf::from(format!("scenes/{s}.toml")))
            .collect()
    } else {
        args.scenes.clone()
    };
    let names = scenes
        .iter()
        .map(|path| {
            path.file_stem()
                .and_then(|s| s.to_str())
                .map(str::to_string)
                .with_context(|| format!("{}: a scene file needs a UTF-8 name", path.display()))
        })
        .collect::<Result<Vec<_>>>()?;
    let given = given_references(&args, &names)?;
    let mut peer_rows = Vec::new();
    for file in &args.peers {
        let text =
            std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
        for (i, line) in text.lines().enumerate() {
            if i == 0 && line.trim() == CSV_HEADER || line.trim().is_empty() {
                continue;
            }
            peer_rows.push(Row::parse(line, &format!("{}:{}", file.display(), i + 1))?);
        }
    }
    let mut peer = args
        .peer_command
        .as_deref()
        .map(PeerCommand::start)
        .transpose()?;
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        pool = pool.num_threads(t as usize);
    }
    let pool = pool.build().context("starting the render threads")?;
    let threads = pool.current_num_threads();
    let clock_ghz = measured_clock_ghz();

    let mut rows = Vec::new();
    let mut references = Vec::new();
    for (path, name) in scenes.iter().zip(&names) {
        let scene = Scene::load(path, &Limits::default())?;
        let (reference, source) = reference(
            &args,
            given.get(name.as_str()).copied(),
            name,
            &scene,
            &pool,
        )?;
        if (reference.width, reference.height) != (scene.width as usize, scene.height as usize) {
            bail!(
                "the reference for {name} is {}×{}, the scene {}×{}",
                reference.width,
                reference.height,
                scene.width,
                scene.height
            );
        }
        references.push((name.clone(), source));
        // Warm-up (page faults, thread start), not timed.
        let warm = RenderSettings {
            spp: 1,
            ..RenderSettings::default()
        };
        pool.install(|| render_frame(&scene, &warm, &|_| {}));
        let mut spp = 4;
        while spp <= args.max_spp {
            for seed in 0..args.seeds as u64 {
                let settings = RenderSettings {
                    seed: 1 + seed,
                    spp,
                    ..RenderSettings::default()
                };
                let start = Instant::now();
                let sums = pool.install(|| render_frame(&scene, &settings, &|_| {}));
                let seconds = start.elapsed().as_secs_f64();
                let img = sums.finalize();
                let samples = scene.width as f64 * scene.height as f64 * spp as f64;
                let row = Row {
                    renderer: "tessera".into(),
                    scene: name.clone(),
                    spp,
                    seed: settings.seed,
                    threads,
                    seconds,
                    msamples_per_s: samples / seconds / 1e6,
                    relmse: rel_mse(&img, &reference),
                };
                errln!("{}", row.to_csv());
                rows.push(row);
                if let Some(peer) = peer.as_mut() {
                    for row in peer.measure(name, spp, settings.seed)? {
                        errln!("{}", row.to_csv());
                        rows.push(row);
                    }
                }
            }
            spp *= 4;
        }
    }
    drop(peer);
    rows.extend(peer_rows);

    let base = args.out.join(&args.name);
    let csv = std::iter::once(CSV_HEADER.to_string())
        .chain(rows.iter().map(Row::to_csv))
        .collect::<Vec<_>>()
        .join("\n")
        + "\n";
    let csv_path = base.with_extension("csv");
    std::fs::write(&csv_path, csv).with_context(|| format!("writing {}", csv_path.display()))?;
    let svg_path = base.with_extension("svg");
    plot(&rows, &svg_path)?;
    let md_path = base.with_extension("md");
    let md = report(
        &rows,
        &references,
        &args,
        threads,
        clock_ghz,
        &svg_path,
        &csv_path,
    );
    std::fs::write(&md_path, md).with_context(|| format!("writing {}", md_path.display()))?;
    outln!(
        "wrote {}, {} and {}",
        md_path.display(),
        csv_path.display(),
        svg_path.display()
    );
    Ok(())
}

/// Per (scene, renderer, spp): mean seconds, mean relMSE, mean Msamples/s over seeds.
type Series = BTreeMap<(String, String), BTreeMap<u32, (f64, f64, f64)>>;

fn series(rows: &[Row]) -> Series {
    let mut acc: BTreeMap<(String, String), BTreeMap<u32, Vec<&Row>>> = BTreeMap::new();
    for r in rows {
        acc.entry((r.scene.clone(), r.renderer.clone()))
            .or_default()
            .entry(r.spp)
            .or_default()
            .push(r);
    }
    acc.into_iter()
        .map(|(k, by_spp)| {
            let v = by_spp
                .into_iter()
                .map(|(spp, rs)| {
                    let n = rs.len() as f64;
                    let mean = |f: &dyn Fn(&Row) -> f64| rs.iter().map(|r| f(r)).sum::<f64>() / n;
                    (
                        spp,
                        (
                            mean(&|r| r.seconds),
                            mean(&|r| r.relmse),
                            mean(&|r| r.msamples_per_s),
                        ),
                    )
                })
                .collect();
            (k, v)
        })
        .collect()
}

/// relMSE·seconds (geometric mean over spp ≥ 64, where error falls as 1/time and fixed costs
/// no longer dominate) and throughput (all samples over all time) of one series.
fn summary(points: &BTreeMap<u32, (f64, f64, f64)>) -> (f64, f64) {
    let fit: Vec<f64> = points
        .iter()
        .filter(|(spp, _)| **spp >= 64)
        .map(|(_, (s, e, _))| (s * e).ln())
        .collect();
    let err_time = if fit.is_empty() {
        f64::NAN
    } else {
        (fit.iter().sum::<f64>() / fit.len() as f64).exp()
    };
    let (samples, secs) = points
        .values()
        .fold((0.0, 0.0), |(n, t), (s, _, m)| (n + m * s, t + s));
    (err_time, samples / secs)
}

/// The expected share of the reference's own noise in every relMSE of `scene`, estimated from
/// the renderers' top octave.
///
/// A render I and a reference R are independent, so E[(I − R)²] = E[(I − μ)²] + E[(R − μ)²]:
/// the reference adds the same ρ to every point of a scene, whichever renderer made it, and at
/// high spp it is a large part of a good render's error (docs/renderer.md gives its share on
/// the Cornell box). Where a renderer's own error falls as 1/spp over its last octave (e at 4N
/// is e/4), its points e₁ at N and e₄ at 4N give ρ = (4·e₄ − e₁)/3. A renderer whose error
/// falls faster there (quasi-Monte Carlo) makes the estimate smaller, never larger, so the
/// correction leans towards too little. The mean over
/// the scene's renderers, `None` without a top octave or where the estimate is not positive.
fn reference_noise(all: &Series, scene: &str) -> Option<f64> {
    let of_scene: Vec<_> = all
        .iter()
        .filter(|((s, _), _)| s == scene)
        .map(|(_, points)| points)
        .collect();
    let estimates: Vec<f64> = of_scene
        .iter()
        .filter_map(|points| {
            let mut top = points.iter().rev();
            let (&n4, &(_, e4, _)) = top.next()?;
            let (&n1, &(_, e1, _)) = top.next()?;
            (n4 == 4 * n1).then_some((4.0 * e4 - e1) / 3.0)
        })
        .collect();
    let rho = estimates.iter().sum::<f64>() / estimates.len() as f64;
    // Below every point's error, or the "corrected" error of some point would be 0 or less.
    let floor = of_scene
        .iter()
        .flat_map(|p| p.values().map(|v| v.1))
        .fold(f64::INFINITY, f64::min);
    (rho > 0.0 && rho < floor).then_some(rho)
}

/// [`reference_noise`] of every scene of `all`, estimated once for the table and its notes.
fn reference_noises(all: &Series) -> BTreeMap<String, Option<f64>> {
    all.keys()
        .map(|(scene, _)| (scene.clone(), reference_noise(all, scene)))
        .collect()
}

/// Rows of the by-spp table: for each peer of each scene and each spp both measured, tessera's
/// relMSE·s over the peer's as measured and with the scene's estimated reference noise `rho`
/// taken off both.
fn by_spp(
    all: &Series,
    rho: &BTreeMap<String, Option<f64>>,
) -> Vec<(String, String, u32, f64, Option<f64>)> {
    let mut out = Vec::new();
    for ((scene, renderer), points) in all {
        let Some(t) = all.get(&(scene.clone(), "tessera".to_string())) else {
            continue;
        };
        if renderer == "tessera" {
            continue;
        }
        let rho = rho.get(scene).copied().flatten();
        for (spp, &(ps, pe, _)) in points {
            let Some(&(ts, te, _)) = t.get(spp) else {
                continue;
            };
            let raw = (ts * te) / (ps * pe);
            let corrected = rho.map(|r| (ts * (te - r)) / (ps * (pe - r)));
            out.push((scene.clone(), renderer.clone(), *spp, raw, corrected));
        }
    }
    out
}

fn report(
    rows: &[Row],
    references: &[(String, String)],
    args: &BenchArgs,
    threads: usize,
    clock_ghz: f64,
    svg: &Path,
    csv: &Path,
) -> String {
    let all = series(rows);
    let mut md = String::new();
    // Quoted as a shell would need them, so that the line can be run again as it stands
    // (a --peer-command is one argument with spaces).
    let command: Vec<String> = std::env::args().map(|a| shell_quote(&a)).collect();
    let _ = writeln!(md, "# Speed against error\n");
    let _ = writeln!(
        md,
        "Made by `{}` (tessera on {threads} threads).\n",
        command.join(" ")
    );
    let _ = writeln!(md, "Machine: {}.\n", machine(clock_ghz));
    let peers = match (&args.peer_command, args.peers.is_empty()) {
        (Some(_), true) => {
            "Peers were measured interleaved with tessera: each peer point right after tessera's \
             point of the same scene, spp and seed, so that both face the same minute of the \
             machine. "
        }
        (Some(_), false) => {
            "Peers were measured interleaved with tessera (each peer point right after tessera's \
             point of the same scene, spp and seed), or read from CSV files measured in the same \
             run. "
        }
        (None, false) => "Peers' rows come from their own CSV files, measured in the same run. ",
        (None, true) => "",
    };
    let _ = writeln!(
        md,
        "Each scene is rendered at 4, 16, … {} spp with {} seeds; a row is the mean over seeds. \
         relMSE = mean over pixels and channels of (I − R)²/(R² + 0.01); efficiency = 1/(relMSE·s). \
         relMSE·s is the geometric mean over spp ≥ 64, where error falls as 1/time. \
         {peers}Data: [`{}`]({}), plot: [`{}`]({}).\n",
        args.max_spp,
        args.seeds,
        csv.display(),
        csv.file_name().map_or_else(String::new, |f| f.to_string_lossy().into()),
        svg.display(),
        svg.file_name().map_or_else(String::new, |f| f.to_string_lossy().into()),
    );
    let _ = writeln!(md, "References:\n");
    for (name, source) in references {
        let _ = writeln!(md, "- {name}: {source}");
    }
    let _ = writeln!(md, "\n## Summary\n");
    let _ = writeln!(
        md,
        "| scene | renderer | Msamples/s | relMSE·s | efficiency | throughput vs tessera | equal-time relMSE vs tessera |\n|---|---|---:|---:|---:|---:|---:|"
    );
    for ((scene, renderer), points) in &all {
        let (et, ms) = summary(points);
        let (ratio_t, ratio_e) = match all.get(&(scene.clone(), "tessera".to_string())) {
            Some(t) if renderer != "tessera" => {
                let (t_et, t_ms) = summary(t);
                (format!("{:.2}×", t_ms / ms), format!("{:.3}×", t_et / et))
            }
            _ => ("".into(), "".into()),
        };
        let _ = writeln!(
            md,
            "| {scene} | {renderer} | {ms:.2} | {et:.4} | {:.0} | {ratio_t} | {ratio_e} |",
            1.0 / et
        );
    }
    let _ = writeln!(
        md,
        "\n\"throughput vs tessera\" is tessera's Msamples/s over the peer's; \"equal-time relMSE vs \
         tessera\" is tessera's relMSE·s over the peer's: the error tessera reaches in the time the \
         peer needs for its own (below 1 is better for tessera).\n"
    );
    let noises = reference_noises(&all);
    let table = by_spp(&all, &noises);
    if !table.is_empty() {
        let _ = writeln!(md, "## Equal-time relMSE by spp\n");
        let _ = writeln!(
            md,
            "tessera's relMSE·s over the peer's at each spp. The summary's one number hides how \
             the ratio moves with spp. At high spp part of every error is the reference's own \
             noise, the same amount ρ for every renderer of a scene, so it weighs most on the \
             renderer with the smaller error. The last column takes an estimate of ρ off both: \
             ρ = (4·e(4N) − e(N))/3 from each renderer's top octave (exact where error falls as \
             1/spp; quasi-Monte Carlo makes it an underestimate), averaged over the scene's \
             renderers. It is an estimate, for reading the measured column, not a replacement \
             for it.\n"
        );
        let _ = writeln!(
            md,
            "| scene | peer | spp | measured | reference noise removed |\n|---|---|---:|---:|---:|"
        );
        for (scene, peer, spp, raw, corrected) in table {
            let corrected = corrected.map_or_else(|| "".into(), |c| format!("{c:.3}×"));
            let _ = writeln!(md, "| {scene} | {peer} | {spp} | {raw:.3}× | {corrected} |");
        }
        let _ = writeln!(md);
        for (scene, rho) in &noises {
            if let Some(rho) = rho {
                let _ = writeln!(md, "- {scene}: estimated reference noise ρ = {rho:.2e}");
            }
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md, "## All points\n");
    let _ = writeln!(
        md,
        "| scene | renderer | spp | seconds | Msamples/s | relMSE | efficiency |\n|---|---|---:|---:|---:|---:|---:|"
    );
    for ((scene, renderer), points) in &all {
        for (spp, (s, e, m)) in points {
            let _ = writeln!(
                md,
                "| {scene} | {renderer} | {spp} | {s:.3} | {m:.2} | {e:.3e} | {:.1} |",
                1.0 / (e * s)
            );
        }
    }
    md
}

/// `arg` as one shell word: as it is when that is safe, else in single quotes.
fn shell_quote(arg: &str) -> String {
    let plain = !arg.is_empty()
        && arg
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c));
    if plain {
        arg.to_string()
    } else {
        format!("'{}'", arg.replace('\'', "'\\''"))
    }
}

fn plot(rows: &[Row], path: &Path) -> Result<()> {
    use plotters::prelude::*;
    let all = series(rows);
    let scenes: Vec<String> = {
        let mut s: Vec<String> = all.keys().map(|(s, _)| s.clone()).collect();
        s.dedup();
        s
    };
    let root = SVGBackend::new(path, (480 * scenes.len().max(1) as u32, 420)).into_drawing_area();
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        root.fill(&WHITE)?;
        let panels = root.split_evenly((1, scenes.len().max(1)));
        for (scene, panel) in scenes.iter().zip(panels.iter()) {
            let pts: Vec<(f64, f64)> = all
                .iter()
                .filter(|((s, _), _)| s == scene)
                .flat_map(|(_, p)| p.values().map(|(s, e, _)| (*s, *e)))
                .filter(|(s, e)| *s > 0.0 && *e > 0.0)
                .collect();
            if pts.is_empty() {
                continue;
            }
            let (x0, x1) = pts
                .iter()
                .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.0), a.1.max(p.0)));
            let (y0, y1) = pts
                .iter()
                .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.1), a.1.max(p.1)));
            let mut chart = ChartBuilder::on(panel)
                .caption(scene, ("sans-serif", 20))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(
                    (x0 * 0.8..x1 * 1.25).log_scale(),
                    (y0 * 0.8..y1 * 1.25).log_scale(),
                )?;
            chart
                .configure_mesh()
                .x_desc("seconds")
                .y_desc("relMSE")
                .x_label_formatter(&|v| format!("{v:.2}"))
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .draw()?;
            for (i, ((_, renderer), points)) in
                all.iter().filter(|((s, _), _)| s == scene).enumerate()
            {
                let color = Palette99::pick(i).to_rgba();
                let line: Vec<(f64, f64)> = points.values().map(|(s, e, _)| (*s, *e)).collect();
                chart
                    .draw_series(LineSeries::new(line.clone(), color.stroke_width(2)))?
                    .label(renderer.as_str())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                    });
                chart.draw_series(line.into_iter().map(|p| Circle::new(p, 3, color.filled())))?;
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()?;
        }
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| anyhow::anyhow!("drawing {}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_rows_round_trip_and_bad_rows_name_their_line() {
        let r = Row {
            renderer: "mitsuba-llvm_ad_rgb".into(),
            scene: "cornell-box".into(),
            spp: 64,
            seed: 2,
            threads: 2,
            seconds: 1.5,
            msamples_per_s: 2.8,
            relmse: 1.25e-3,
        };
        let back = Row::parse(&r.to_csv(), "p.csv:2").expect("parses");
        assert_eq!((back.spp, back.seed, back.relmse), (64, 2, 1.25e-3));
        let e = Row::parse("a,b,1,2", "p.csv:7").expect_err("short");
        assert!(e.to_string().contains("p.csv:7"), "{e}");
        let e = Row::parse("a,b,4,1,2,NaN,1,1", "p.csv:3").expect_err("nan");
        assert!(e.to_string().contains("seconds"), "{e}");
    }

    #[test]
    fn shell_quote_keeps_plain_words_and_quotes_the_rest() {
        assert_eq!(shell_quote("--max-spp=4096"), "--max-spp=4096");
        assert_eq!(
            shell_quote("python peer.py --serve"),
            "'python peer.py --serve'"
        );
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
        assert_eq!(shell_quote(""), "''");
    }

    #[test]
    fn summary_is_relmse_times_seconds_over_the_1_over_n_range() {
        let mut p = BTreeMap::new();
        p.insert(4, (0.1, 1.0, 2.0)); // excluded: below 64 spp
        p.insert(64, (1.0, 0.01, 2.0));
        p.insert(256, (4.0, 0.0025, 2.0));
        let (et, ms) = summary(&p);
        assert!((et - 0.01).abs() < 1e-12, "{et}");
        assert!((ms - 2.0).abs() < 1e-12);
    }

    /// Two renderers whose own errors fall as 1/spp, against a reference that adds ρ to every
    /// point: the estimate finds ρ, and the corrected ratio is the ratio of the own errors.
    #[test]
    fn reference_noise_is_found_and_taken_off_both_sides() {
        let rho = 2e-5;
        let series = |c: f64, ms: f64| -> BTreeMap<u32, (f64, f64, f64)> {
            [64u32, 256, 1024, 4096]
                .into_iter()
                .map(|spp| {
                    let secs = 65536.0 * f64::from(spp) / (ms * 1e6);
                    (spp, (secs, c / f64::from(spp) + rho, ms))
                })
                .collect()
        };
        let mut all = Series::new();
        all.insert(("box".into(), "tessera".into()), series(0.1, 3.0));
        all.insert(("box".into(), "peer".into()), series(0.3, 2.0));
        let est = reference_noise(&all, "box").expect("estimated");
        assert!((est - rho).abs() < 1e-12, "{est}");
        let rows = by_spp(&all, &reference_noises(&all));
        assert_eq!(rows.len(), 4);
        // Own errors 0.1 against 0.3 per sample, and tessera 1.5x as fast: 1/4.5 at every spp.
        for (_, peer, spp, raw, corrected) in rows {
            assert_eq!(peer, "peer");
            let c = corrected.expect("corrected");
            assert!((c - 1.0 / 4.5).abs() < 1e-9, "{spp}: {c}");
            // The measured ratio is pulled towards 1 by the shared ρ, most at high spp.
            assert!(raw > c, "{spp}: {raw} vs {c}");
        }
        // Without a top octave (one spp), nothing is estimated.
        let mut one = Series::new();
        one.insert(
            ("box".into(), "tessera".into()),
            [(64, (1.0, 0.01, 2.0))].into(),
        );
        assert_eq!(reference_noise(&one, "box"), None);
        // An estimate at or above some point's error is refused rather than giving a negative
        // error: here the last octave does not fall at all.
        let mut flat = Series::new();
        flat.insert(
            ("box".into(), "tessera".into()),
            [(1024, (1.0, 1e-4, 2.0)), (4096, (4.0, 1e-4, 2.0))].into(),
        );
        assert_eq!(reference_noise(&flat, "box"), None);
    }
}
