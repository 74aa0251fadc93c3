//! Scenes against independent converged references rendered by Mitsuba 3 at 16384 spp:
//! - cornell-box: the full image (`tests/data/cornell-box-reference.exr`);
//! - glass-mirror (a mirror ball and a glass ball in the box: specular chains, caustics, total
//!   internal reflection): its 4×4-pixel block means (`tests/data/glass-mirror-reference-4x4.exr`,
//!   made by `bench/mitsuba_peer.py`), small enough to keep in the repository. Region means are
//!   all the checks below read, so the blocks lose nothing;
//! - mesh-glass (an OBJ lamp, smooth PLY spheres, one of them glass): its 4×4 block means
//!   likewise (`tests/data/mesh-glass-reference-4x4.exr`), Mitsuba reading the same files, and
//!   at 128² for the raw bound at 16384 spp (`tests/data/mesh-glass-128-reference-4x4.exr`);
//! - cornell-mesh (the boxes as triangle meshes) against cornell-box's reference;
//! - metals-box (rough gold and aluminium balls in the box) against Mitsuba's `roughconductor`,
//!   its 4×4 block means (`tests/data/metals-box-reference-4x4.exr`; at 128²,
//!   `tests/data/metals-box-128-reference-4x4.exr`);
//! - envmap-balls (a diffuse, a rough gold and a frosted glass ball on a ground square under an
//!   HDR sky with a sun), its film cut to 128², against Mitsuba's `envmap`, `plastic`,
//!   `roughconductor` and `roughdielectric`, its 4×4 block means
//!   (`tests/data/envmap-balls-128-reference-4x4.exr`);
//! - gltf-metals and gltf-glass: glTF files (`scenes/gltf/metals.glb`, `glass.glb`) placed in
//!   TOML scenes under the sky, converted for Mitsuba by `bench/gltf_mitsuba.py` (full metals,
//!   one textured, as `principled`; volume glass as `dielectric` and `roughdielectric` with an
//!   absorbing interior under `volpath`), at 128² (`tests/data/gltf-*-128-reference-4x4.exr`).
//!
//! Three checks per scene, each able to fail:
//! - z-test: every 32×32 region mean agrees within 4.5 standard errors (192 region-channels,
//!   so a false alarm has probability ~1e-3; the seed is fixed, so the outcome is too);
//! - bias bound: for every 64×64 region, the 99% confidence interval of the relative bias
//!   (|Δ| − 2.6·SE) must reach below 0.5%. A fixed 0.5% on the raw difference cannot be asked of
//!   the darkest regions at 1024 spp, whose own noise is about 0.3%;
//! - the whole image's mean, whose noise is ~0.03%, within 0.5% outright.

mod common;

use common::{load, region_stats, render, repo_root};
use tessera_render::output::{read_exr_rgb, RgbImage};
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{Image, RenderSettings};

const SPP: u32 = 1024;

/// A reference image whose texels are the means of `block`×`block` pixel squares.
struct Reference {
    img: RgbImage,
    block: u32,
}

impl Reference {
    fn load(file: &str, block: u32) -> Self {
        let img = read_exr_rgb(&repo_root().join("tests/data").join(file)).expect("reference");
        Self { img, block }
    }

    /// Mean over a pixel region whose edges lie on block boundaries.
    fn mean(&self, x0: u32, y0: u32, w: u32, h: u32) -> [f64; 3] {
        let b = self.block;
        assert!([x0, y0, w, h].iter().all(|v| v.is_multiple_of(b)));
        let (tx, ty, tw, th) = (x0 / b, y0 / b, w / b, h / b);
        let mut m = [0f64; 3];
        for y in ty..ty + th {
            for x in tx..tx + tw {
                let p = self.img.rgb[y as usize * self.img.width + x as usize];
                for c in 0..3 {
                    m[c] += p[c] as f64 / (tw * th) as f64;
                }
            }
        }
        m
    }
}

/// (relative difference, z, relative combined standard error, ours, reference) per channel.
fn compare(
    img: &Image,
    r: &Reference,
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
) -> [(f64, f64, f64, f64, f64); 3] {
    let (mean, se) = region_stats(img, x0, y0, w, h);
    let rm = r.mean(x0, y0, w, h);
    std::array::from_fn(|c| {
        // The reference's own noise is about SPP/16384 of ours in variance.
        let se_both = se[c] * (1.0 + SPP as f64 / 16384.0).sqrt();
        let diff = mean[c] - rm[c];
        (
            diff / rm[c].max(1e-4),
            diff / se_both.max(1e-12),
            se_both / rm[c].max(1e-4),
            mean[c],
            rm[c],
        )
    })
}

/// Renders `scene` at [`SPP`] and runs the three checks against `reference`.
fn check_against(scene: &str, reference: &Reference) {
    check_scene_against(&load(scene), reference)
}

/// A bundled scene with its film cut to `size`², the rest of its text unchanged.
fn load_at(name: &str, size: u32) -> Scene {
    let text = std::fs::read_to_string(repo_root().join("scenes").join(name)).expect("scene");
    let text: Vec<String> = text
        .lines()
        .map(|l| match l {
            _ if l.starts_with("width =") => format!("width = {size}"),
            _ if l.starts_with("height =") => format!("height = {size}"),
            _ => l.to_string(),
        })
        .collect();
    let files = tessera_render::scene::assets::DirAssets(repo_root().join("scenes"));
    Scene::text(&text.join("\n"), Format::Toml, name, &Limits::default())
        .at(1)
        .assets(&files)
        .load()
        .expect("scene")
}

/// [`check_against`] for a scene already loaded: its film square, a multiple of 64 pixels.
fn check_scene_against(scene: &Scene, reference: &Reference) {
    let size = scene.width;
    assert!(scene.height == size && size.is_multiple_of(64));
    assert_eq!(
        (reference.img.width as u32, reference.img.height as u32),
        (size / reference.block, size / reference.block)
    );
    let img = render(
        scene,
        &RenderSettings {
            spp: SPP,
            seed: 1,
            ..RenderSettings::default()
        },
    );
    assert_eq!(img.nonfinite, 0);

    let mut failures = Vec::new();
    let mut worst_z = 0f64;
    let mut worst_rel = 0f64;
    for block in [32u32, 64] {
        for y0 in (0..size).step_by(block as usize) {
            for x0 in (0..size).step_by(block as usize) {
                for (c, (rel, z, rel_se, ours, theirs)) in
                    compare(&img, reference, x0, y0, block, block)
                        .into_iter()
                        .enumerate()
                {
                    let what = format!("{block}² region at ({x0},{y0}) channel {c}: ours {ours:.5}, reference {theirs:.5}, z = {z:.2}, rel = {:.3}%", rel * 100.0);
                    if block == 32 {
                        worst_z = worst_z.max(z.abs());
                        worst_rel = worst_rel.max(rel.abs());
                        if z.abs() > 4.5 {
                            failures.push(format!("z-test: {what}"));
                        }
                    } else if rel.abs() - 2.6 * rel_se > 0.005 {
                        failures.push(format!("bias above 0.5%: {what}, ±{:.3}%", rel_se * 100.0));
                    }
                }
            }
        }
    }
    for (c, (rel, z, _, ours, theirs)) in compare(&img, reference, 0, 0, size, size)
        .into_iter()
        .enumerate()
    {
        eprintln!(
            "image mean channel {c}: ours {ours:.5}, reference {theirs:.5}, rel {:.3}%, z {z:.2}",
            rel * 100.0
        );
        if rel.abs() > 0.005 {
            failures.push(format!("image mean channel {c} off by {:.3}%", rel * 100.0));
        }
    }
    eprintln!(
        "worst over 32² regions: |z| {worst_z:.2}, |relative difference| {:.3}%",
        worst_rel * 100.0
    );
    assert!(
        failures.is_empty(),
        "{} checks failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn cornell_box_matches_the_independent_reference() {
    check_against(
        "cornell-box.toml",
        &Reference::load("cornell-box-reference.exr", 1),
    );
}

#[test]
fn glass_mirror_matches_the_independent_reference() {
    check_against(
        "glass-mirror.toml",
        &Reference::load("glass-mirror-reference-4x4.exr", 4),
    );
}

/// The Cornell box with its boxes as triangle meshes (two instances of one OBJ file) against
/// the analytic box's independent reference: the mesh path (file, BVH, watertight triangles,
/// ray offsets) changes nothing but the time.
#[test]
fn cornell_mesh_matches_the_analytic_boxs_reference() {
    check_against(
        "cornell-mesh.toml",
        &Reference::load("cornell-box-reference.exr", 1),
    );
}

/// Meshes against an independent renderer: `scenes/mesh-glass.toml` (an OBJ lamp whose
/// emitting group is the only light, a smooth-shaded diffuse PLY sphere, and a smooth-shaded
/// glass sphere of the same PLY in front of it) against Mitsuba 3's render of the same files.
#[test]
fn mesh_glass_matches_the_independent_reference() {
    check_against(
        "mesh-glass.toml",
        &Reference::load("mesh-glass-reference-4x4.exr", 4),
    );
}

/// The bound as the mesh issue states it, on raw differences: at 16384 spp, every 32² region
/// of `scenes/mesh-glass.toml` is within 0.5% of Mitsuba's 16384-spp render, in each channel,
/// with the film cut to 128² as for the environment map below (a quarter of the pixels, so
/// that it runs in under three minutes on two cores; a 32² region holds as many pixels, and
/// so as much noise, as at 256²). At [`SPP`] the glass sphere's caustic regions carry about
/// 1.4% of noise of their own, which is why the test above, at 256², bounds the bias instead;
/// sixteen times the samples take it to a quarter. Ignored in `cargo test`; `.ci/run` runs it.
#[test]
#[ignore = "about three minutes on two cores: .ci/run runs it"]
fn mesh_glass_regions_within_half_a_percent_at_16384_spp() {
    scene_regions_within_half_a_percent(
        &load_at("mesh-glass.toml", 128),
        &Reference::load("mesh-glass-128-reference-4x4.exr", 4),
        16384,
    );
}

/// Rough metals against an independent renderer: `scenes/metals-box.toml` (a gold ball by
/// name and an aluminium ball by its complex index, GGX roughness 0.3, in the Cornell box)
/// against Mitsuba 3's `roughconductor`. Mitsuba's masking term is the separable
/// G1(o)·G1(i), tessera's the height-correlated one; at α = 0.09 the two albedos differ by at
/// most 0.3%, at 80° from the normal (docs/renderer.md, "Metals").
#[test]
fn metals_box_matches_the_independent_reference() {
    check_against(
        "metals-box.toml",
        &Reference::load("metals-box-reference-4x4.exr", 4),
    );
}

/// The metals issue's bound: at 16384 spp every 32² region of `scenes/metals-box.toml` within
/// 0.5% of Mitsuba's, the film cut to 128² as for mesh-glass above. Ignored in `cargo test`
/// (under two minutes on two cores); `.ci/run` runs it.
#[test]
#[ignore = "under two minutes on two cores: .ci/run runs it"]
fn metals_box_regions_within_half_a_percent_at_16384_spp() {
    scene_regions_within_half_a_percent(
        &load_at("metals-box.toml", 128),
        &Reference::load("metals-box-128-reference-4x4.exr", 4),
        16384,
    );
}

/// An environment map against an independent renderer: `scenes/envmap-balls.toml`, its film
/// cut to 128² (a quarter of the pixels, so that the raw bound below can run at 16384 spp in
/// the time CI has), against Mitsuba 3's `envmap` (the same texels, parameterisation and
/// bilinear lookup), `plastic` (the smooth-coated ball: the same model), `roughconductor` and
/// `roughdielectric` (α = 0.09: the masking terms differ as for the metals).
#[test]
fn envmap_balls_matches_the_independent_reference() {
    check_scene_against(
        &load_at("envmap-balls.toml", 128),
        &Reference::load("envmap-balls-128-reference-4x4.exr", 4),
    );
}

/// The materials issue's bound for the environment map and plastic: at 16384 spp every 32²
/// region of `scenes/envmap-balls.toml` at 128² within 0.5% of Mitsuba's 16384-spp render.
/// Ignored in `cargo test` (about two minutes on two cores); `.ci/run` runs it.
#[test]
#[ignore = "about two minutes on two cores: .ci/run runs it"]
fn envmap_balls_regions_within_half_a_percent_at_16384_spp() {
    scene_regions_within_half_a_percent(
        &load_at("envmap-balls.toml", 128),
        &Reference::load("envmap-balls-128-reference-4x4.exr", 4),
        16384,
    );
}

/// The same scene under a sky 512 texels wide (`scenes/envmap-balls-wide.toml`), whose columns
/// tessera draws from alias tables rather than by inverting each row's cdf (image revision 13),
/// against Mitsuba 3 reading the same file.
#[test]
fn envmap_balls_under_a_wide_sky_matches_the_independent_reference() {
    check_scene_against(
        &load_at("envmap-balls-wide.toml", 128),
        &Reference::load("envmap-balls-wide-128-reference-4x4.exr", 4),
    );
}

/// The 0.5% bound of `envmap_balls_regions_within_half_a_percent_at_16384_spp` under the wide
/// sky. Ignored in `cargo test` (about 70 s on two cores); `.ci/run` runs it.
#[test]
#[ignore = "about 70 s on two cores: .ci/run runs it"]
fn envmap_balls_under_a_wide_sky_regions_within_half_a_percent_at_16384_spp() {
    scene_regions_within_half_a_percent(
        &load_at("envmap-balls-wide.toml", 128),
        &Reference::load("envmap-balls-wide-128-reference-4x4.exr", 4),
        16384,
    );
}

/// glTF's `pbr` material where its model and Mitsuba's `principled` agree: two fully metallic
/// balls (Schlick's Fresnel of F0 = the base colour over GGX; the masking terms differ as for
/// the metals) under the sky map, `scenes/pbr-metals.toml` at 128².
#[test]
fn pbr_metals_match_the_independent_reference() {
    check_scene_against(
        &load_at("pbr-metals.toml", 128),
        &Reference::load("pbr-metals-128-reference-4x4.exr", 4),
    );
}

/// The materials issue's bound for the glTF material: at 8192 spp every 32² region of
/// `scenes/pbr-metals.toml` at 128² within 0.5% of Mitsuba's `principled` at 16384 spp (half
/// the others' spp: a region's noise is then still under a third of the bound, and CI's time
/// is short). Ignored in `cargo test` (about a minute on two cores); `.ci/run` runs it.
#[test]
#[ignore = "about a minute on two cores: .ci/run runs it"]
fn pbr_metals_regions_within_half_a_percent_at_8192_spp() {
    scene_regions_within_half_a_percent(
        &load_at("pbr-metals.toml", 128),
        &Reference::load("pbr-metals-128-reference-4x4.exr", 4),
        8192,
    );
}

/// Renders `scene` at `spp`: every 32² region, each channel, within 0.5% of `reference`.
fn scene_regions_within_half_a_percent(scene: &Scene, reference: &Reference, spp: u32) {
    let size = scene.width;
    let img = render(
        scene,
        &RenderSettings {
            spp,
            seed: 1,
            ..RenderSettings::default()
        },
    );
    assert_eq!(img.nonfinite, 0);
    let (mut worst, mut failures) = (0f64, Vec::new());
    for y0 in (0..size).step_by(32) {
        for x0 in (0..size).step_by(32) {
            // Only the raw difference is read: `compare`'s z and standard error are for SPP.
            let regions = compare(&img, reference, x0, y0, 32, 32);
            for (c, (rel, _, _, ours, theirs)) in regions.into_iter().enumerate() {
                worst = worst.max(rel.abs());
                if rel.abs() > 0.005 {
                    failures.push(format!(
                        "32² region at ({x0},{y0}) channel {c}: ours {ours:.5}, reference {theirs:.5}, {:.3}%",
                        rel * 100.0
                    ));
                }
            }
        }
    }
    eprintln!("worst over 32² regions at {spp} spp: {:.3}%", worst * 100.0);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// glTF import against an independent renderer reading the same file: two full metals of the
/// metallic–roughness material, one with a base colour and a packed metallic–roughness texture,
/// lit by the file's point light and the sky (`scenes/gltf-metals.toml` at 128²).
#[test]
fn gltf_metals_match_the_independent_reference() {
    check_scene_against(
        &load_at("gltf-metals.toml", 128),
        &Reference::load("gltf-metals-128-reference-4x4.exr", 4),
    );
}

/// The same for glass from `KHR_materials_transmission` + `_volume`: a smooth and a rough
/// ball, each absorbing inside (`scenes/gltf-glass.toml` at 128²).
#[test]
fn gltf_glass_matches_the_independent_reference() {
    check_scene_against(
        &load_at("gltf-glass.toml", 128),
        &Reference::load("gltf-glass-128-reference-4x4.exr", 4),
    );
}

/// The glTF issue's bound: every 32² region of both glTF scenes at 128² within 0.5% of
/// Mitsuba's 16384-spp renders, at 8192 spp. Ignored in `cargo test` (about two minutes on two
/// cores); `.ci/run` runs it.
#[test]
#[ignore = "about two minutes on two cores: .ci/run runs it"]
fn gltf_scenes_regions_within_half_a_percent_at_8192_spp() {
    for name in ["gltf-metals", "gltf-glass"] {
        scene_regions_within_half_a_percent(
            &load_at(&format!("{name}.toml"), 128),
            &Reference::load(&format!("{name}-128-reference-4x4.exr"), 4),
            8192,
        );
    }
}
