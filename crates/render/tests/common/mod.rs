//! Helpers shared by the integration tests.
#![allow(dead_code, missing_docs)]

pub mod bsdf;
pub mod chi2;
pub mod gltf;

use std::path::PathBuf;

use glam::DVec3;
use tessera_render::integrator::radiance;
use tessera_render::math::Ray;
use tessera_render::sampling::PixelSampler;
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{render_frame, Image, RenderSettings, Strategy};

/// `texels` (row-major, `w` wide) as an RGB float EXR file's bytes.
pub fn exr_bytes(w: usize, h: usize, texels: &[glam::Vec3A]) -> Vec<u8> {
    use exr::prelude::*;
    let pixels = SpecificChannels::rgb(|p: Vec2<usize>| {
        let t = texels[p.y() * w + p.x()];
        (t.x, t.y, t.z)
    });
    let image = Image::from_channels((w, h), pixels);
    let mut out = std::io::Cursor::new(Vec::new());
    image.write().to_buffered(&mut out).expect("write exr");
    out.into_inner()
}

pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// An 8-bit RGB PNG of `w` × `h` texels, row 0 at the top.
pub fn png_rgb(w: u32, h: u32, rgb: &[u8]) -> Vec<u8> {
    png_8bit(w, h, png::ColorType::Rgb, rgb)
}

/// An 8-bit RGBA PNG of `w` × `h` texels, row 0 at the top.
pub fn png_rgba(w: u32, h: u32, rgba: &[u8]) -> Vec<u8> {
    png_8bit(w, h, png::ColorType::Rgba, rgba)
}

fn png_8bit(w: u32, h: u32, color: png::ColorType, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut e = png::Encoder::new(&mut out, w, h);
        e.set_color(color);
        e.set_depth(png::BitDepth::Eight);
        let mut w = e.write_header().expect("header");
        w.write_image_data(data).expect("data");
    }
    out
}

pub fn load(name: &str) -> Scene {
    let path = repo_root().join("scenes").join(name);
    Scene::file(&path, &Limits::default())
        .load()
        .unwrap_or_else(|e| panic!("{e}"))
}

/// A scene from text with the files it names held in memory.
pub fn scene_with_files(text: &str, files: &[(&str, &[u8])]) -> Scene {
    try_scene_with_files(text, files).unwrap_or_else(|e| panic!("{e}"))
}

/// [`scene_with_files`], or the error as the user would read it.
pub fn try_scene_with_files(text: &str, files: &[(&str, &[u8])]) -> Result<Scene, String> {
    let files = tessera_render::scene::assets::MemAssets(
        files
            .iter()
            .map(|(n, b)| (n.to_string(), b.to_vec()))
            .collect(),
    );
    Scene::text(text, Format::Toml, "test.toml", &Limits::default())
        .at(1)
        .assets(&files)
        .load()
        .map_err(|e| e.to_string())
}

pub fn scene(text: &str) -> Scene {
    Scene::text(text, Format::Toml, "test.toml", &Limits::default())
        .load()
        .unwrap_or_else(|e| panic!("{e}"))
}

/// A closed, two-sided diffuse sphere of albedo `rho` emitting `le`, seen from inside on a
/// `width` × `height` film: the furnace whose radiance is Le/(1 − ρ) everywhere.
pub fn closed_sphere(rho: [f64; 3], le: [f64; 3], width: u32, height: u32) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0.1, 0.2, 0.0]\ntarget = [1, 0.3, 0.2]\nfov = 90\n[film]\nwidth = {width}\nheight = {height}\n\
         [materials.shell]\ntype = \"diffuse\"\nalbedo = {rho:?}\nemission = {le:?}\ntwo_sided = true\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"shell\"\nradius = 2.0\n"
    )
}

pub fn render(scene: &Scene, settings: &RenderSettings) -> Image {
    render_frame(scene, settings, &|_| {}).finalize()
}

/// Mean and standard error of the mean over a pixel region, per channel, from the per-pixel
/// variance estimates.
pub fn region_stats(img: &Image, x0: u32, y0: u32, w: u32, h: u32) -> ([f64; 3], [f64; 3]) {
    let mut mean = [0f64; 3];
    let mut var = [0f64; 3];
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            let i = (y * img.width + x) as usize;
            for c in 0..3 {
                mean[c] += img.rgb[i][c] as f64;
                var[c] += img.variance[i][c] as f64;
            }
        }
    }
    let n = (w * h) as f64;
    (mean.map(|m| m / n), var.map(|v| (v / (n * n)).sqrt()))
}

/// The mean radiance along `ray` over `n` paths, and its standard error, per channel.
pub fn estimate(sc: &Scene, ray: Ray, strategy: Strategy, n: u32) -> (DVec3, DVec3) {
    let settings = RenderSettings {
        strategy,
        ..RenderSettings::default()
    };
    let (mut sum, mut sq) = (DVec3::ZERO, DVec3::ZERO);
    for i in 0..n {
        let l = radiance(sc, &settings, ray, &PixelSampler::new(1, 3, 5, i)).as_dvec3();
        assert!(l.is_finite(), "{strategy:?}: non-finite radiance {l}");
        sum += l;
        sq += l * l;
    }
    let mean = sum / n as f64;
    let var = (sq / n as f64 - mean * mean).max(DVec3::ZERO);
    (mean, (var / n as f64).map(f64::sqrt))
}

/// Per-pixel z-test of two independent renders; returns (the fraction of pixel-channels with
/// |z| > 4, the largest |z| over 4×4-pixel blocks).
pub fn z_test(a: &Image, b: &Image) -> (f64, f64) {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let mut outliers = 0usize;
    for i in 0..a.rgb.len() {
        for c in 0..3 {
            let var = a.variance[i][c] as f64 + b.variance[i][c] as f64;
            let diff = a.rgb[i][c] as f64 - b.rgb[i][c] as f64;
            if diff.abs() > 4.0 * var.sqrt() + 1e-6 * a.rgb[i][c].abs() as f64 {
                outliers += 1;
            }
        }
    }
    let mut worst = 0f64;
    for by in 0..a.height / 4 {
        for bx in 0..a.width / 4 {
            let (ma, sa) = region_stats(a, bx * 4, by * 4, 4, 4);
            let (mb, sb) = region_stats(b, bx * 4, by * 4, 4, 4);
            for c in 0..3 {
                let se = (sa[c] * sa[c] + sb[c] * sb[c]).sqrt();
                if se > 0.0 {
                    worst = worst.max((ma[c] - mb[c]).abs() / se);
                } else {
                    assert_eq!(ma[c], mb[c], "noise-free blocks must agree exactly");
                }
            }
        }
    }
    (outliers as f64 / (3 * a.rgb.len()) as f64, worst)
}
