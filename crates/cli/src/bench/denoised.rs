//! `tessera bench --denoise`: the denoised curve beside the raw one, in the same run. After
//! each of tessera's uniform points the same scene, spp and seed is rendered with the albedo
//! and normal the denoiser takes, and denoised (Intel Open Image Denoise, `high`, HDR), timed
//! whole (render, AOVs and filter), as renderer `tessera-denoised`: the report and plot carry
//! it as a series of its own, against the raw render's and the peer's.

use std::time::Instant;

use anyhow::{Context, Result};
use tessera_render::output::RgbImage;
use tessera_render::scene::Scene;
use tessera_render::{render_frame, RenderSettings};

use super::peer::Row;
use super::stats::errors;

/// The renderer name of denoised rows.
pub(super) const RENDERER: &str = "tessera-denoised";

/// One timed render of `scene` (named `name`) with `settings`, denoised.
pub(super) fn measure(
    scene: &Scene,
    name: &str,
    settings: &RenderSettings,
    reference: &RgbImage,
    pool: &rayon::ThreadPool,
) -> Result<Row> {
    let mut settings = settings.clone();
    tessera_denoise::gather_inputs(&mut settings);
    let options = tessera_denoise::Options {
        threads: Some(pool.current_num_threads() as u32),
        ..tessera_denoise::Options::default()
    };
    let start = Instant::now();
    let mut img = pool
        .install(|| render_frame(scene, &settings, &|_| {}))
        .finalize();
    let denoised = tessera_denoise::denoise_image(&img, &options).context("--denoise")?;
    let seconds = start.elapsed().as_secs_f64();
    img.rgb = denoised.color;
    let threads = pool.current_num_threads();
    Ok(Row::timed(
        RENDERER,
        (scene, name),
        &settings,
        (threads, seconds),
        errors(&img, reference),
    ))
}
