//! `tessera render`: the embedded, local renderer.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use indicatif::ProgressBar;
use tessera_render::output::{render_metadata, write_exr, write_png_preview, ExrChannels, Preview};
use tessera_render::scene::{Limits, Scene, FIRST_FRAME};
use tessera_render::{
    render_frame, Adaptive, RenderSettings, Strategy, Tracer, BATCH_RANGE, DEFAULT_BATCH,
    DEFAULT_TILE,
};

/// clap's parser for a batch size in [`BATCH_RANGE`].
pub fn batch_range() -> clap::builder::RangedI64ValueParser<u32> {
    clap::value_parser!(u32).range(i64::from(*BATCH_RANGE.start())..=i64::from(*BATCH_RANGE.end()))
}

/// The settings that decide a render's bits: the same flags, defaults and ranges for `tessera
/// render` and `tessera submit`, so that the two give the same image for the same command.
#[derive(Debug, clap::Args)]
pub struct SettingsArgs {
    /// Samples per pixel.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub spp: u32,
    /// Job seed: the same seed gives the same bits.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Samples per batch (part of the job's identity, like the seed; `render` and `submit`
    /// share the default, so a farm job with the same settings gives the same bits).
    #[arg(long, default_value_t = DEFAULT_BATCH, value_parser = batch_range())]
    pub batch: u32,
    /// Direct-lighting strategy (mis is the best; the others exist for comparisons).
    #[arg(long, value_enum, default_value_t = StrategyArg::Mis)]
    pub strategy: StrategyArg,
    /// Adaptive sampling: samples go to the tiles where they lower the image's relative error
    /// most, until its expected value (√relMSE, e.g. 0.02) is this, and --spp becomes the cap.
    /// Tiles are --tile-size pixels, which is then part of the render's identity.
    #[arg(long, value_parser = noise_target)]
    pub noise_target: Option<f64>,
    /// Frame of the scene's `[animation]` to render (the EXR's header then names it, and it is
    /// part of the render's identity).
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=9_999_999))]
    pub frame: Option<u32>,
}

/// clap's parser for a noise target in [`tessera_render::adaptive::NOISE_TARGET_RANGE`].
fn noise_target(s: &str) -> Result<f64, String> {
    let t: f64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number (a relative error such as 0.01)"))?;
    Adaptive::new(t, DEFAULT_TILE)
        .map(|a| a.noise_target)
        .map_err(|e| e.to_string())
}

impl SettingsArgs {
    /// The renderer's settings, with noise decisions (if any) for tiles of `tile` pixels.
    pub fn to_settings(&self, tile: u32) -> RenderSettings {
        RenderSettings {
            seed: self.seed,
            spp: self.spp,
            batch: self.batch,
            strategy: self.strategy.to_strategy(),
            adaptive: self
                .noise_target
                .map(|noise_target| Adaptive { noise_target, tile }),
            frame: self.frame,
            ..RenderSettings::default()
        }
    }
}

/// Arguments of `tessera render`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// Scene file (TOML, or JSON by its .json extension).
    scene: PathBuf,
    #[command(flatten)]
    settings: SettingsArgs,
    /// Output OpenEXR file.
    #[arg(long, short)]
    output: PathBuf,
    /// Tile edge in pixels for --noise-target's decisions (the farm's default tile, so that
    /// `tessera submit` with the same flags gives the same bits). Without a noise target the
    /// tiles cannot change a bit.
    #[arg(long, default_value_t = DEFAULT_TILE, value_parser = crate::farm::tile_range())]
    tile_size: u32,
    /// Worker threads (default: every core).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4096))]
    threads: Option<u32>,
    /// Also write an 8-bit sRGB PNG preview here.
    #[arg(long)]
    preview: Option<PathBuf>,
    /// Preview exposure in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f32,
    /// Add variance-of-the-mean channels (variance.R/G/B) to the EXR.
    #[arg(long)]
    variance: bool,
    /// Add a per-pixel sample-count channel (samples) to the EXR.
    #[arg(long)]
    sample_count: bool,
    /// Which path tracer runs. Every choice gives the same bits; it is for timing the tracers
    /// against each other.
    #[arg(long, value_enum, default_value_t = TracerArg::Auto)]
    tracer: TracerArg,
    /// Largest spp accepted.
    #[arg(long, default_value_t = Limits::default().max_spp)]
    max_spp: u32,
    /// Largest image width or height accepted.
    #[arg(long, default_value_t = Limits::default().max_resolution)]
    max_resolution: u32,
}

/// `--strategy` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum StrategyArg {
    /// Multiple importance sampling.
    Mis,
    /// BSDF sampling only.
    Bsdf,
    /// Light sampling only.
    Nee,
}

impl StrategyArg {
    fn to_strategy(self) -> Strategy {
        match self {
            StrategyArg::Mis => Strategy::Mis,
            StrategyArg::Bsdf => Strategy::Bsdf,
            StrategyArg::Nee => Strategy::Nee,
        }
    }
}

/// `--tracer` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum TracerArg {
    /// The many-path tracer where it applies, else one path at a time.
    Auto,
    /// One path at a time.
    Scalar,
    /// The many-path tracer, 4 lanes.
    Lanes4,
    /// The many-path tracer, 8 lanes.
    Lanes8,
    /// The many-path tracer, 16 lanes.
    Lanes16,
}

impl TracerArg {
    fn to_tracer(self) -> Tracer {
        match self {
            TracerArg::Auto => Tracer::Auto,
            TracerArg::Scalar => Tracer::Scalar,
            TracerArg::Lanes4 => Tracer::Lanes(4),
            TracerArg::Lanes8 => Tracer::Lanes(8),
            TracerArg::Lanes16 => Tracer::Lanes(16),
        }
    }
}

/// Fails early, before any rendering, if `out` cannot be written: its directory does not
/// exist or is not writable, or `out` is a directory.
pub fn check_output_dir(out: &std::path::Path) -> Result<()> {
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    if !dir.is_dir() {
        bail!(
            "{}: output directory {} does not exist",
            out.display(),
            dir.display()
        );
    }
    if out.is_dir() {
        bail!("{}: is a directory", out.display());
    }
    // The file is written as a new file in that directory, then renamed: try exactly that
    // now rather than after a long render.
    tempfile::Builder::new()
        .prefix(".tessera-probe-")
        .tempfile_in(dir)
        .map(drop)
        .with_context(|| format!("{}: cannot write in {}", out.display(), dir.display()))
}

/// Fails unless `out`'s name ends in `.ext` (any case): a file is read by its extension, and
/// an EXR named `.png` (or a PNG named `.jpg`) is a file no program opens as what it says.
pub fn check_extension(flag: &str, out: &std::path::Path, ext: &str) -> Result<()> {
    let ok = out
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case(ext));
    if !ok {
        bail!(
            "{flag} {}: the file is written as {}, so its name must end in .{ext}",
            out.display(),
            ext.to_uppercase()
        );
    }
    Ok(())
}

/// Runs `tessera render`.
pub fn run(args: RenderArgs) -> Result<()> {
    if !args.exposure.is_finite() {
        bail!("--exposure must be a finite number, got {}", args.exposure);
    }
    if args.settings.spp > args.max_spp {
        bail!(
            "--spp {} is above the limit of {} (raise it with --max-spp)",
            args.settings.spp,
            args.max_spp
        );
    }
    check_extension("--output", &args.output, "exr")?;
    if let Some(p) = &args.preview {
        check_extension("--preview", p, "png")?;
    }
    for out in std::iter::once(&args.output).chain(args.preview.as_ref()) {
        check_output_dir(out)?;
    }
    let limits = Limits {
        max_spp: args.max_spp,
        max_resolution: args.max_resolution,
        ..Limits::default()
    };
    let frame = args.settings.frame.unwrap_or(FIRST_FRAME);
    let scene = Scene::load_at(&args.scene, &limits, frame)?;
    let settings = RenderSettings {
        tracer: args.tracer.to_tracer(),
        ..args.settings.to_settings(args.tile_size)
    };
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        pool = pool.num_threads(t as usize);
    }
    let pool = pool.build().context("starting the render threads")?;

    let total = scene.width as u64 * scene.height as u64 * settings.spp as u64;
    let bar = ProgressBar::new(total);
    bar.set_style(crate::progress_style("{percent:>3}% ETA {eta} {wide_msg}"));
    let done = AtomicU64::new(0);
    let start = Instant::now();
    let sums = pool.install(|| {
        render_frame(&scene, &settings, &|n| {
            let d = done.fetch_add(n, Ordering::Relaxed) + n;
            bar.set_position(d);
            let secs = start.elapsed().as_secs_f64();
            if secs > 0.0 {
                bar.set_message(format!("{:.2} Msamples/s", d as f64 / secs / 1e6));
            }
        })
    });
    let secs = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    let image = sums.finalize();

    let meta = render_metadata(&scene.hash, &settings);
    let channels = ExrChannels {
        variance: args.variance,
        samples: args.sample_count,
    };
    write_exr(&args.output, &image, channels, &meta)?;
    if let Some(p) = &args.preview {
        write_png_preview(
            p,
            &image,
            Preview {
                exposure: args.exposure,
            },
        )?;
    }
    let (noise, rel) = image.noise();
    let samples = done.load(Ordering::Relaxed);
    let spp = match settings.adaptive {
        None => format!("{} spp", settings.spp),
        Some(a) => format!(
            "{:.1} spp on average (noise target {}, cap {})",
            samples as f64 / (scene.width as f64 * scene.height as f64),
            a.noise_target,
            settings.spp
        ),
    };
    outln!(
        "rendered {}×{} at {spp} in {:.2} s on {}: {:.2} Msamples/s, noise σ≈{:.4} ({:.2}% of mean), {} non-finite samples dropped → {}",
        scene.width,
        scene.height,
        secs,
        match pool.current_num_threads() {
            1 => "1 thread".to_string(),
            n => format!("{n} threads"),
        },
        samples as f64 / secs / 1e6,
        noise,
        rel * 100.0,
        image.nonfinite,
        args.output.display()
    );
    Ok(())
}
