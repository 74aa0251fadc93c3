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

//!
//! Built only with the `bench` feature (`cargo build --release -p tessera-cli --features
//! bench`), so that the farm and render commands never compile beside the plotting library.
//! The parts: [`peer`] (CSV rows and the peer protocol), [`stats`], [`report`] and [`plot`].

mod adaptive;
mod denoised;
mod guiding_cost;
pub mod load;
mod peer;
mod plot;
mod report;
mod stats;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use tessera_render::output::{
    read_exr_provenance, read_exr_rgb, render_metadata, write_exr, ExrChannels, RgbImage,
};
use tessera_render::scene::{Limits, Scene};
use tessera_render::{render_frame, RenderSettings};

use peer::{PeerCommand, Row, CSV_HEADER};
use report::{measured_clock_ghz, report};

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
    /// Also measure noise-targeted adaptive sampling against uniform sampling: each scene at
    /// a ladder of noise targets capped at --max-spp, right after its uniform points, reported
    /// as the time each mode needs for the same relMSE (NAME-adaptive.md and .csv).
    #[arg(long)]
    adaptive: bool,
    /// Also measure path guiding against unguided rendering: after each uniform point, the
    /// same scene, spp and seed with `--guiding` (renderer `tessera-guided` in the report),
    /// and the time each needs for the same relMSE (NAME-guiding.md).
    #[arg(long)]
    guiding: bool,
    /// Also measure denoising: after each uniform point, the same scene, spp and seed
    /// rendered with the denoiser's AOVs and denoised (Intel Open Image Denoise, which
    /// scripts/install-oidn.sh installs), timed whole, as renderer `tessera-denoised`.
    #[arg(long)]
    denoise: bool,
    /// Tile edge, in pixels, of the adaptive renders' noise decisions.
    #[arg(long, default_value_t = 32, value_parser = crate::args::tile_range())]
    adaptive_tile: u32,
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
        // Minutes on a large scene: a bar shows it is working (hidden where stderr is no
        // terminal, as in CI's logs).
        let bar =
            indicatif::ProgressBar::new(scene.width as u64 * scene.height as u64 * spp as u64);
        bar.set_style(crate::terminal::progress_style(
            "{percent:>3}% ETA {eta} {wide_msg}",
        ));
        bar.set_message(format!("{name} reference"));
        let done = std::sync::atomic::AtomicU64::new(0);
        let img = pool
            .install(|| {
                render_frame(scene, &settings, &|n| {
                    bar.set_position(done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n);
                })
            })
            .finalize();
        bar.finish_and_clear();
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

/// Fewest triangles a mesh needs for its BVH build time to be reported: below this the time is
/// the thread pool's start-up, and "seconds per million" of it means nothing.
const MIN_TIMED_TRIANGLES: usize = 10_000;

/// For each distinct mesh of `scene` of at least [`MIN_TIMED_TRIANGLES`], a report line with the
/// time its BVH takes to build (built again from its triangles, as the loader builds it, on
/// `pool`).
fn mesh_builds(
    name: &str,
    scene: &Scene,
    load_seconds: f64,
    pool: &rayon::ThreadPool,
) -> Vec<String> {
    let mut seen: Vec<*const tessera_render::mesh::TriMesh> = Vec::new();
    let mut out = Vec::new();
    for p in &scene.prims {
        let tessera_render::shape::Shape::Mesh(m) = &p.shape else {
            continue;
        };
        if seen.contains(&std::sync::Arc::as_ptr(&m.mesh)) {
            continue;
        }
        seen.push(std::sync::Arc::as_ptr(&m.mesh));
        if m.mesh.len() < MIN_TIMED_TRIANGLES {
            continue;
        }
        let tris: Vec<_> = m.mesh.triangles().collect();
        let n = tris.len();
        let start = Instant::now();
        let built =
            pool.install(|| tessera_render::mesh::TriMesh::new(tris, Vec::new(), Vec::new()));
        let seconds = start.elapsed().as_secs_f64();
        drop(built);
        out.push(format!(
            "- {name}: {n} triangles in {seconds:.3} s ({:.3} s per million; scene load {load_seconds:.2} s)",
            seconds / (n as f64 / 1e6)
        ));
        errln!("{}", out.last().map_or("", String::as_str));
    }
    out
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
    if args.denoise {
        // Before anything is measured: a missing library fails the run at once.
        tessera_denoise::library_version().context("--denoise")?;
    }
    let (scenes, names) = scene_list(&args)?;
    let given = given_references(&args, &names)?;
    let peer_rows = read_peer_rows(&args.peers)?;
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
    let mut m = Measured {
        threads: pool.current_num_threads(),
        clock_ghz: measured_clock_ghz(),
        ..Measured::default()
    };
    for (path, name) in scenes.iter().zip(&names) {
        let given = given.get(name.as_str()).copied();
        measure_scene(&args, (path, name, given), &pool, peer.as_mut(), &mut m)?;
    }
    drop(peer);
    m.rows.extend(peer_rows);
    write_reports(&args, &m)
}

/// What a bench run measured, for its reports.
#[derive(Default)]
struct Measured {
    threads: usize,
    clock_ghz: f64,
    rows: Vec<Row>,
    adaptive_points: Vec<adaptive::Point>,
    /// Each scene's reference and where it came from.
    references: Vec<(String, String)>,
    /// Lines about mesh BVH builds.
    builds: Vec<String>,
}

impl Measured {
    /// Keeps `row`, printed as it comes.
    fn keep(&mut self, row: Row) {
        errln!("{}", row.to_csv());
        self.rows.push(row);
    }
}

/// The scenes to measure (the three default ones unless some are named) and their names.
fn scene_list(args: &BenchArgs) -> Result<(Vec<PathBuf>, Vec<String>)> {
    let scenes: Vec<PathBuf> = if args.scenes.is_empty() {
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
    Ok((scenes, names))
}

/// The rows of peers' CSV files (`--peer`), each line named by file and number if it is bad.
fn read_peer_rows(files: &[PathBuf]) -> Result<Vec<Row>> {
    let mut rows = Vec::new();
    for file in files {
        let text =
            std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
        for (i, line) in text.lines().enumerate() {
            // The header as written now, or without the `flip` column peers may leave out.
            let header =
                line.trim() == CSV_HEADER || Some(line.trim()) == CSV_HEADER.strip_suffix(",flip");
            if i == 0 && header || line.trim().is_empty() {
                continue;
            }
            rows.push(Row::parse(line, &format!("{}:{}", file.display(), i + 1))?);
        }
    }
    Ok(rows)
}

/// One scene's rows: tessera at 4, 16, … spp and every seed (guided too with `--guiding`),
/// the peer's at the same points, and adaptive sampling's with `--adaptive`.
fn measure_scene(
    args: &BenchArgs,
    (path, name, given): (&Path, &String, Option<&Path>),
    pool: &rayon::ThreadPool,
    mut peer: Option<&mut PeerCommand>,
    m: &mut Measured,
) -> Result<()> {
    let start = Instant::now();
    let scene = Scene::file(path, &Limits::default()).load()?;
    let load_seconds = start.elapsed().as_secs_f64();
    m.builds
        .extend(mesh_builds(name, &scene, load_seconds, pool));
    let (reference, source) = reference(args, given, name, &scene, pool)?;
    if (reference.width, reference.height) != (scene.width as usize, scene.height as usize) {
        bail!(
            "the reference for {name} is {}×{}, the scene {}×{}",
            reference.width,
            reference.height,
            scene.width,
            scene.height
        );
    }
    m.references.push((name.clone(), source));
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
            m.keep(Row::timed(
                "tessera",
                (&scene, name),
                &settings,
                (m.threads, seconds),
                stats::errors(&img, &reference),
            ));
            if args.guiding {
                m.keep(guiding_cost::measure(
                    &scene, name, &settings, &reference, pool,
                ));
            }
            if args.denoise {
                m.keep(denoised::measure(
                    &scene, name, &settings, &reference, pool,
                )?);
            }
            if let Some(peer) = peer.as_deref_mut() {
                for row in peer.measure(name, spp, settings.seed)? {
                    m.keep(row);
                }
            }
        }
        spp *= 4;
    }
    if args.adaptive {
        let knobs = (args.max_spp, args.adaptive_tile, args.seeds);
        m.adaptive_points
            .extend(adaptive::measure(&scene, name, &reference, pool, knobs)?);
    }
    Ok(())
}

/// The run's CSV, plot and markdown report, and the guided and adaptive reports when those
/// were measured.
fn write_reports(args: &BenchArgs, m: &Measured) -> Result<()> {
    let threads = m.threads;
    let base = args.out.join(&args.name);
    let csv = std::iter::once(CSV_HEADER.to_string())
        .chain(m.rows.iter().map(Row::to_csv))
        .collect::<Vec<_>>()
        .join("\n")
        + "\n";
    let csv_path = base.with_extension("csv");
    std::fs::write(&csv_path, csv).with_context(|| format!("writing {}", csv_path.display()))?;
    let svg_path = base.with_extension("svg");
    plot::plot(&m.rows, &svg_path)?;
    let md_path = base.with_extension("md");
    let md = report(
        &m.rows,
        &m.references,
        args,
        threads,
        m.clock_ghz,
        &svg_path,
        &csv_path,
    );
    let md = if m.builds.is_empty() {
        md
    } else {
        format!(
            "{md}\n## Mesh BVH builds\n\nEach distinct mesh's BVH built again from its triangles, timed alone (the scene's \
             load, which also reads the file, in brackets), on {threads} threads:\n\n{}\n",
            m.builds.join("\n")
        )
    };
    std::fs::write(&md_path, md).with_context(|| format!("writing {}", md_path.display()))?;
    if args.guiding {
        let path = args.out.join(format!("{}-guiding.md", args.name));
        let md = guiding_cost::report(&m.rows, &report::command())
            + &format!(
                "\nMachine: {}, {threads} threads. Data: the rows of [`{}`]({}).\n",
                report::machine(m.clock_ghz),
                csv_path.display(),
                file_name(&csv_path),
            );
        std::fs::write(&path, md).with_context(|| format!("writing {}", path.display()))?;
        outln!("wrote {}", path.display());
    }
    if args.adaptive {
        write_adaptive(args, m, &md_path)?;
    }
    outln!(
        "wrote {}, {} and {}",
        md_path.display(),
        csv_path.display(),
        svg_path.display()
    );
    Ok(())
}

/// Adaptive sampling's CSV and report, beside the uniform run's report at `md_path`.
fn write_adaptive(args: &BenchArgs, m: &Measured, md_path: &Path) -> Result<()> {
    let base = args.out.join(format!("{}-adaptive", args.name));
    let (cap, tile) = (args.max_spp, args.adaptive_tile);
    let csv = std::iter::once(adaptive::CSV_HEADER.to_string())
        .chain(
            m.adaptive_points
                .iter()
                .map(|p| adaptive::to_csv(p, cap, tile)),
        )
        .collect::<Vec<_>>()
        .join("\n")
        + "\n";
    let csv_path = base.with_extension("csv");
    std::fs::write(&csv_path, csv).with_context(|| format!("writing {}", csv_path.display()))?;
    let mut md = adaptive::report(&m.rows, &m.adaptive_points, cap, tile, &report::command());
    md += &format!(
        "\nMachine: {}, {} threads. Data: [`{}`]({}); the uniform points are those of \
         [`{}`]({}).\n",
        report::machine(m.clock_ghz),
        m.threads,
        csv_path.display(),
        file_name(&csv_path),
        md_path.display(),
        file_name(md_path),
    );
    let path = base.with_extension("md");
    std::fs::write(&path, md).with_context(|| format!("writing {}", path.display()))?;
    outln!("wrote {} and {}", path.display(), csv_path.display());
    Ok(())
}

/// A path's last component, for a link beside it.
fn file_name(path: &Path) -> String {
    path.file_name()
        .map_or_else(String::new, |f| f.to_string_lossy().into())
}
