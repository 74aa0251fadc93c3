//! `tessera render`: the embedded, local renderer.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use indicatif::ProgressBar;
use tessera_render::film::Image;
use tessera_render::guiding::render_frame_guided;
use tessera_render::output::{
    render_metadata, write_exr, write_exr_with_denoised, write_png_preview, ExrChannels, Preview,
};
use tessera_render::scene::{Limits, Scene};
use tessera_render::{render_frame, RenderSettings, Tracer, DEFAULT_TILE};

use crate::args::{check_extension, check_output_dir, tile_range, SettingsArgs};

/// Arguments of `tessera render`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// Scene file: TOML, JSON (by its .json extension), or glTF 2.0 (.gltf, .glb).
    scene: PathBuf,
    #[command(flatten)]
    gltf: crate::args::GltfArgs,
    #[command(flatten)]
    settings: SettingsArgs,
    /// Output OpenEXR file.
    #[arg(long, short)]
    output: PathBuf,
    /// Tile edge in pixels for --noise-target's decisions (the farm's default tile, so that
    /// `tessera submit` with the same flags gives the same bits). Without a noise target the
    /// tiles cannot change a bit.
    #[arg(long, default_value_t = DEFAULT_TILE, value_parser = tile_range())]
    tile_size: u32,
    /// Worker threads (default: every core).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4096))]
    threads: Option<u32>,
    #[command(flatten)]
    preview: crate::args::PreviewArgs,
    #[command(flatten)]
    denoise: crate::denoise::DenoiseArgs,
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

/// `--tracer` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum TracerArg {
    /// The many-path tracer where it pays (a scene lit by one rectangle light, or a closed
    /// room under any lights: no sky, no sun, no infinite plane), else one path at a time.
    Auto,
    /// One path at a time.
    Scalar,
    /// The many-path tracer, 4 lanes, wherever it can run (any lights; one path at a time
    /// only for scenes it cannot run: no diffuse surface, cut-outs, coloured glass, a depth
    /// limit, a far plane, `--strategy bsdf|nee`).
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

/// Runs `tessera render`.
pub fn run(args: RenderArgs) -> Result<()> {
    args.preview.check()?;
    if args.settings.spp > args.max_spp {
        bail!(
            "--spp {} is above the limit of {} (raise it with --max-spp)",
            args.settings.spp,
            args.max_spp
        );
    }
    if args.settings.guiding && args.settings.noise_target.is_some() {
        bail!(
            "--guiding takes every sample it is given; it cannot be combined with --noise-target"
        );
    }
    check_extension("--output", &args.output, "exr")?;
    check_output_dir(&args.output)?;
    let limits = Limits {
        max_spp: args.max_spp,
        max_resolution: args.max_resolution,
        ..Limits::default()
    };
    let gltf = args.gltf.options(&args.scene)?;
    let scene = Scene::file(&args.scene, &limits)
        .gltf(&gltf)
        .at(args.settings.shot())
        .load()?;
    for w in &scene.warnings {
        errln!("warning: {w}");
    }
    let denoiser = args
        .denoise
        .denoiser(scene.denoise.as_ref(), args.threads)?;
    let mut settings = RenderSettings {
        tracer: args.tracer.to_tracer(),
        ..args
            .settings
            .to_settings(args.tile_size, scene.width, scene.height)
    };
    if let Some(d) = &denoiser {
        settings = d.settings(settings);
    }
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        pool = pool.num_threads(t as usize);
    }
    let pool = pool.build().context("starting the render threads")?;

    let total = scene.width as u64 * scene.height as u64 * settings.spp as u64;
    let bar = ProgressBar::new(total);
    bar.set_style(crate::terminal::progress_style(
        "{percent:>3}% ETA {eta} {wide_msg}",
    ));
    let done = AtomicU64::new(0);
    let start = Instant::now();
    let progress = |n| {
        let d = done.fetch_add(n, Ordering::Relaxed) + n;
        bar.set_position(d);
        let secs = start.elapsed().as_secs_f64();
        if secs > 0.0 {
            bar.set_message(format!("{:.2} Msamples/s", d as f64 / secs / 1e6));
        }
    };
    let mut guide_note = String::new();
    let sums = pool.install(|| {
        if !settings.guiding {
            return render_frame(&scene, &settings, &progress);
        }
        let frame = render_frame_guided(&scene, &settings, &progress);
        guide_note = guide_note_of(&frame.epochs);
        frame.sums
    });
    let secs = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    let image = sums.finalize();

    let meta = render_metadata(&scene.hash, &settings);
    let denoise_note = write_outputs(&args, &image, &settings, meta, denoiser.as_ref())?;
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
    let noise = noise_said(noise, rel, image.count.iter().any(|&k| k > 1));
    outln!(
        "rendered {}×{} at {spp}{guide_note} in {:.2} s on {}: {:.2} Msamples/s, {noise}, {} non-finite samples dropped{denoise_note} → {}",
        scene.width,
        scene.height,
        secs,
        match pool.current_num_threads() {
            1 => "1 thread".to_string(),
            n => format!("{n} threads"),
        },
        samples as f64 / secs / 1e6,
        image.nonfinite,
        args.output.display()
    );
    // The checks the farm flags in `tessera status`, as warnings here.
    for (_, line) in image.checks().failed() {
        errln!("warning: {line}");
    }
    Ok(())
}

/// Writes the EXR (with its denoised layer, if asked) and the preview (of the denoised image,
/// if there is one); returns what the summary line says of denoising.
fn write_outputs(
    args: &RenderArgs,
    image: &Image,
    settings: &RenderSettings,
    mut meta: Vec<(String, String)>,
    denoiser: Option<&crate::denoise::Denoiser>,
) -> Result<String> {
    let channels = ExrChannels {
        variance: args.variance,
        samples: args.sample_count,
        aovs: settings.aovs,
    };
    let mut note = String::new();
    let mut shown = None;
    match denoiser {
        None => write_exr(&args.output, image, channels, &meta)?,
        Some(d) => {
            let start = Instant::now();
            let planes = d.run(image)?;
            note = format!(", denoised in {:.2} s", start.elapsed().as_secs_f64());
            meta.push(d.metadata());
            write_exr_with_denoised(&args.output, image, channels, &meta, &planes)?;
            // The preview shows what the denoised layer holds.
            shown = Some(Image {
                rgb: planes.color,
                ..image.clone()
            });
        }
    }
    if let Some(p) = &args.preview.preview {
        let preview = Preview {
            exposure: args.preview.exposure,
        };
        write_png_preview(p, shown.as_ref().unwrap_or(image), preview)?;
    }
    Ok(note)
}

/// The summary line's noise: σ of the pixel means and its share of the mean, or, where no
/// pixel has two samples (`--spp 1`), that a pixel's variance cannot be estimated (σ≈0 would
/// say the image is clean when it is the noisiest there is).
pub(crate) fn noise_said(rms: f64, relative: f64, estimated: bool) -> String {
    if estimated {
        format!("noise σ≈{rms:.4} ({:.2}% of mean)", relative * 100.0)
    } else {
        "noise not estimated (one sample per pixel: it takes two)".to_string()
    }
}

/// What a guided render's summary line says of its epochs: how many, the largest guide any
/// sampled, and where guiding turned itself off (the guide did not pay), if it did.
fn guide_note_of(epochs: &[tessera_render::guiding::Epoch]) -> String {
    let sampled = epochs.iter().filter(|e| e.guided);
    let largest = sampled.max_by_key(|e| e.guide_bytes);
    let mut note = format!(", {} guided epochs", epochs.len());
    if let Some(e) = largest {
        note += &format!(
            " (largest guide sampled: {} leaves, {:.1} MB)",
            e.guide_leaves,
            e.guide_bytes as f64 / 1e6
        );
    }
    if let Some(off) = epochs.iter().skip(1).find(|e| !e.guided) {
        note += &format!(
            ", guiding off from sample {} (the guide did not pay for itself)",
            off.samples.start
        );
    }
    note
}

/// Arguments of `tessera preview`.
#[derive(Debug, clap::Args)]
pub struct PreviewCommandArgs {
    /// An OpenEXR file (a render's, or one fetched from the farm).
    exr: PathBuf,
    /// The PNG to write.
    #[arg(long, short)]
    output: PathBuf,
    /// Exposure in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f32,
}

/// Runs `tessera preview`: the PNG `render --preview` would have written beside the EXR.
pub fn preview(args: PreviewCommandArgs) -> Result<()> {
    let p = crate::args::PreviewArgs {
        preview: Some(args.output.clone()),
        exposure: args.exposure,
    };
    p.check()?;
    p.write_of_exr(&args.exr)?;
    outln!("{} → {}", args.exr.display(), args.output.display());
    Ok(())
}
