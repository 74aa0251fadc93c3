//! A quick efficiency probe for tuning the integrator: renders one scene with the settings
//! given in environment variables, and prints throughput, relMSE against a reference and
//! relMSE·seconds per seed, and how the error splits over the reference's brightness (the
//! `+ 0.01` in relMSE's denominator makes dark pixels count most).
//!
//! ```sh
//! RR=3 RR_T=0.25 SPP=256 SEEDS=2 cargo run --release -p tessera-render --example efficiency
//! ```
//!
//! Variables: `SCENE` (default `scenes/cornell-box.toml`), `REF` (default the Mitsuba
//! reference in `tests/data`), `SPP` (64), `SEEDS` (2), `RR` (Russian roulette start depth),
//! `RR_T` (its threshold), `STRATEGY` (`mis`, `bsdf` or `nee`). Relative `SCENE` and `REF`
//! paths are the repository's, wherever the probe runs from. `tessera bench` is the report to
//! quote; this is for before/after comparisons in one sitting.

use std::io::Write;
use std::time::Instant;

use tessera_render::output::read_exr_rgb;
use tessera_render::scene::{Limits, Scene};
use tessera_render::{render_frame, RenderSettings, Strategy};

/// Upper edges of the reference-luminance bins the error is split over.
const BINS: [f32; 5] = [0.05, 0.1, 0.2, 0.5, 2.0];

/// What ends the probe early: a bad variable or an unreadable file, reported as one line
/// instead of a panic, or a closed stdout (as under `| head`), which ends it quietly.
type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

fn var<T: std::str::FromStr>(name: &str, default: T) -> Result<T> {
    match std::env::var(name) {
        Ok(v) => v
            .parse()
            .map_err(|_| format!("{name}={v} does not parse").into()),
        Err(_) => Ok(default),
    }
}

fn main() -> std::process::ExitCode {
    // Display, not the Debug form `main` would print for a returned error.
    match probe() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // A reader that stopped early (`| head`) has all it wanted: end quietly, as ripgrep does.
        Err(e)
            if e.downcast_ref::<std::io::Error>()
                .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe) =>
        {
            std::process::ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("efficiency: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn probe() -> Result<()> {
    let d = RenderSettings::default();
    let spp: u32 = var("SPP", 64)?;
    let seeds: u64 = var("SEEDS", 2)?;
    let strategy_name: String = var("STRATEGY", "mis".to_string())?;
    let strategy = Strategy::from_name(&strategy_name)
        .ok_or_else(|| format!("STRATEGY={strategy_name}: expected mis, bsdf or nee"))?;
    // Relative paths are the repository's, so the probe runs the same from any directory.
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let scene_path = root.join(var("SCENE", "scenes/cornell-box.toml".to_string())?);
    let ref_path = root.join(var(
        "REF",
        "tests/data/cornell-box-reference.exr".to_string(),
    )?);
    let scene = Scene::file(&scene_path, &Limits::default()).load()?;
    let reference = read_exr_rgb(&ref_path)?;
    let base = RenderSettings {
        spp,
        strategy,
        rr_depth: var("RR", d.rr_depth)?,
        rr_threshold: var("RR_T", d.rr_threshold)?,
        ..d
    };
    let mut out = std::io::stdout().lock();
    let mut err_time = 0.0;
    let mut bins = [0f64; BINS.len() + 1];
    for seed in 1..=seeds {
        let settings = RenderSettings {
            seed,
            ..base.clone()
        };
        let t = Instant::now();
        let img = render_frame(&scene, &settings, &|_| {}).finalize();
        let secs = t.elapsed().as_secs_f64();
        if img.rgb.len() != reference.rgb.len() {
            return Err(format!("{}: not the scene's size", ref_path.display()).into());
        }
        let mut sum = 0f64;
        for (p, r) in img.rgb.iter().zip(&reference.rgb) {
            let lum = (r[0] + r[1] + r[2]) / 3.0;
            let bin = BINS.iter().take_while(|&&edge| lum >= edge).count();
            for c in 0..3 {
                let (i, r) = (f64::from(p[c]), f64::from(r[c]));
                let e = (i - r).powi(2) / (r * r + 0.01);
                sum += e;
                bins[bin] += e;
            }
        }
        let rel = sum / (img.rgb.len() * 3) as f64;
        err_time += rel * secs;
        let msps = img.rgb.len() as f64 * f64::from(spp) / secs / 1e6;
        writeln!(
            out,
            "seed {seed}: {secs:.2} s, {msps:.2} Msamples/s, relMSE {rel:.4e}, relMSE·s {:.4e}",
            rel * secs
        )?;
    }
    let total: f64 = bins.iter().sum();
    let shares = bins.map(|b| format!("{:.1}%", 100.0 * b / total));
    writeln!(
        out,
        "mean relMSE·s {:.4e}; error share by reference luminance (<{:?}, rest): {shares:?}",
        err_time / seeds as f64,
        BINS
    )?;
    Ok(())
}
