//! BSDF-only, NEE-only and MIS renders of the same scenes agree statistically: three estimators
//! of one integral, with different variance, must converge to the same image.

mod common;

use common::{region_stats, render};
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{RenderSettings, Strategy};

fn shrink(name: &str, w: u32, h: u32) -> Scene {
    let path = common::repo_root().join("scenes").join(name);
    let text = std::fs::read_to_string(&path).expect("scene");
    let text = text
        .lines()
        .map(|l| {
            if l.starts_with("width =") {
                format!("width = {w}")
            } else if l.starts_with("height =") {
                format!("height = {h}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    Scene::text(&text, Format::Toml, name, &Limits::default())
        .load()
        .expect("valid")
}

fn agree(scene: &Scene, spp: [u32; 3], block: u32) {
    let strategies = [Strategy::Mis, Strategy::Nee, Strategy::Bsdf];
    let imgs: Vec<_> = strategies
        .iter()
        .zip(spp)
        .map(|(&strategy, spp)| {
            render(
                scene,
                &RenderSettings {
                    spp,
                    seed: 11,
                    strategy,
                    ..RenderSettings::default()
                },
            )
        })
        .collect();
    let mut worst = 0f64;
    let mut failures = Vec::new();
    for y0 in (0..scene.height).step_by(block as usize) {
        for x0 in (0..scene.width).step_by(block as usize) {
            let (w, h) = (block.min(scene.width - x0), block.min(scene.height - y0));
            let stats: Vec<_> = imgs.iter().map(|i| region_stats(i, x0, y0, w, h)).collect();
            for (a, b) in [(0, 1), (0, 2), (1, 2)] {
                for c in 0..3 {
                    let se = (stats[a].1[c].powi(2) + stats[b].1[c].powi(2)).sqrt();
                    let z = (stats[a].0[c] - stats[b].0[c]) / se.max(1e-9);
                    worst = worst.max(z.abs());
                    if z.abs() > 5.0 {
                        failures.push(format!(
                            "region ({x0},{y0}) channel {c}: {:?} {:.5} vs {:?} {:.5}, z = {z:.2}",
                            strategies[a], stats[a].0[c], strategies[b], stats[b].0[c]
                        ));
                    }
                }
            }
        }
    }
    eprintln!("worst |z| = {worst:.2}");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn strategies_agree_on_the_cornell_box() {
    agree(&shrink("cornell-box.toml", 40, 40), [256, 256, 1024], 8);
}

#[test]
fn strategies_agree_with_glass_mirror_and_a_sphere_light() {
    agree(&shrink("spheres.toml", 48, 36), [256, 256, 1024], 12);
}

#[test]
fn strategies_agree_on_rough_metals() {
    // Gold at roughness 0.1, copper at 0.35, aluminium at 0.7 (by eta and k), a small lamp.
    agree(&shrink("metals.toml", 40, 25), [256, 256, 1024], 8);
    // A large lamp whose reflection in the rough metals is as wide as their lobes, where light
    // and BSDF sampling both matter and the MIS weights must add to one.
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1, 5]\ntarget = [0, 0.5, 0]\n\
                fov = 45\n[film]\nwidth = 32\nheight = 24\n\
                [materials.floor]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
                [materials.a]\ntype = \"conductor\"\nmetal = \"copper\"\nroughness = 0.4\n\
                [materials.b]\ntype = \"conductor\"\nf0 = [0.9, 0.9, 0.9]\nroughness = 0.7\n\
                [materials.lamp]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [3, 3, 3]\n\
                [[objects]]\nshape = \"plane\"\nmaterial = \"floor\"\npoint = [0, 0, 0]\nnormal = [0, 1, 0]\n\
                [[objects]]\nshape = \"sphere\"\nmaterial = \"a\"\ncenter = [-0.9, 0.8, 0]\nradius = 0.8\n\
                [[objects]]\nshape = \"sphere\"\nmaterial = \"b\"\ncenter = [0.9, 0.8, 0]\nradius = 0.8\n\
                [[objects]]\nshape = \"sphere\"\nmaterial = \"lamp\"\ncenter = [0, 3.5, 2.5]\nradius = 1.2\n";
    let scene = Scene::text(text, Format::Toml, "big-lamp.toml", &Limits::default())
        .load()
        .expect("valid");
    agree(&scene, [256, 256, 1024], 8);
}

#[test]
fn strategies_agree_on_rough_and_coloured_glass() {
    // Frosted glass (light sampled from both sides of it), coloured rough glass, and a lamp
    // seen through both. Rough enough that light sampling alone is well behaved: through a
    // narrow lobe (roughness 0.2) its estimate is heavy-tailed (six seeds at 4096 spp gave
    // 0.917 to 0.995 of the BSDF estimate's 0.956, averaging 0.955), and its sample variance
    // cannot be trusted for a z-test. Halving the BSDF density in the MIS weight fails this
    // test (|z| = 15).
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1, 5]\ntarget = [0, 0.6, 0]\n\
                fov = 45\n[film]\nwidth = 32\nheight = 24\n\
                [materials.floor]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
                [materials.frosted]\ntype = \"dielectric\"\nior = 1.5\nroughness = 0.6\n\
                [materials.tinted]\ntype = \"dielectric\"\nior = 1.33\nroughness = 0.5\nabsorption = [0.2, 0.8, 1.6]\n\
                [materials.lamp]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [4, 4, 4]\n\
                [[objects]]\nshape = \"plane\"\nmaterial = \"floor\"\npoint = [0, 0, 0]\nnormal = [0, 1, 0]\n\
                [[objects]]\nshape = \"sphere\"\nmaterial = \"frosted\"\ncenter = [-0.9, 0.8, 0]\nradius = 0.8\n\
                [[objects]]\nshape = \"box\"\nmaterial = \"tinted\"\nmin = [0.2, 0, -0.6]\nmax = [1.6, 1.4, 0.6]\n\
                [[objects]]\nshape = \"sphere\"\nmaterial = \"lamp\"\ncenter = [-0.3, 1.0, -2.5]\nradius = 1.0\n";
    let scene = Scene::text(text, Format::Toml, "glass.toml", &Limits::default())
        .load()
        .expect("valid");
    agree(&scene, [512, 512, 2048], 8);
}

#[test]
fn strategies_agree_on_plastic_and_on_an_environment_map() {
    // A smooth-coated and a rough-coated plastic ball under a large lamp; then the same balls
    // under the bundled sky alone (a sun in it), whose directions light sampling draws from the
    // map and weighs against the plastics' mixture densities; then under both. Halving the plastic's
    // BSDF density in its MIS weight fails the first (|z| = 7.5); halving the map's density in
    // an escaping ray's weight fails the second (|z| = 10.0). The second found a real bug:
    // shadow rays towards the map ended past the scene's finite objects, so the sky just under
    // the horizon lit the balls through the infinite floor's far part, and light sampling
    // alone read 2% more than MIS and BSDF sampling (|z| = 5.4).
    let balls = "[materials.floor]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
                 [materials.smooth]\ntype = \"plastic\"\nalbedo = [0.8, 0.2, 0.1]\n\
                 [materials.rough]\ntype = \"plastic\"\nalbedo = [0.1, 0.6, 0.2]\nroughness = 0.5\nior = 1.6\n\
                 [[objects]]\nshape = \"plane\"\nmaterial = \"floor\"\npoint = [0, 0, 0]\nnormal = [0, 1, 0]\n\
                 [[objects]]\nshape = \"sphere\"\nmaterial = \"smooth\"\ncenter = [-0.9, 0.8, 0]\nradius = 0.8\n\
                 [[objects]]\nshape = \"sphere\"\nmaterial = \"rough\"\ncenter = [0.9, 0.8, 0]\nradius = 0.8\n";
    let camera =
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1, 5]\ntarget = [0, 0.6, 0]\n\
                  fov = 45\n[film]\nwidth = 32\nheight = 24\n";
    let lamp = format!(
        "{camera}{balls}[materials.lamp]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [3, 3, 3]\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"lamp\"\ncenter = [0, 3.5, 2.5]\nradius = 1.2\n"
    );
    agree(&common::scene(&lamp), [2048, 2048, 4096], 8);
    let sky = std::fs::read(common::repo_root().join("scenes/textures/sky.exr")).expect("sky");
    let mapped =
        format!("{camera}[environment]\ntype = \"map\"\nfile = \"sky.exr\"\nrotate = 200\n{balls}");
    agree(
        &common::scene_with_files(&mapped, &[("sky.exr", &sky)]),
        [4096, 4096, 4096],
        8,
    );
    // Both: light sampling chooses between the lamp and the map by power.
    let both = format!("{mapped}{}", &lamp[camera.len() + balls.len()..]);
    agree(
        &common::scene_with_files(&both, &[("sky.exr", &sky)]),
        [2048, 2048, 4096],
        8,
    );
}

#[test]
fn strategies_agree_with_punctual_and_area_lights_together() {
    // A point, a spot and a directional light beside an area light, over diffuse and rough
    // metal: BSDF-only rendering samples the punctual ones (nothing else can reach them) and
    // finds the area light by its rays.
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1.5, 5]\ntarget = [0, 0.5, 0]\n\
                fov = 45\n[film]\nwidth = 32\nheight = 24\n\
                [materials.floor]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
                [materials.metal]\ntype = \"conductor\"\nmetal = \"copper\"\nroughness = 0.5\n\
                [materials.lamp]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [3, 3, 3]\n\
                [[objects]]\nshape = \"plane\"\nmaterial = \"floor\"\npoint = [0, 0, 0]\nnormal = [0, 1, 0]\n\
                [[objects]]\nshape = \"sphere\"\nmaterial = \"metal\"\ncenter = [-0.8, 0.7, 0]\nradius = 0.7\n\
                [[objects]]\nshape = \"box\"\nmaterial = \"floor\"\nmin = [0.4, 0, -0.5]\nmax = [1.4, 1, 0.5]\n\
                [[objects]]\nshape = \"sphere\"\nmaterial = \"lamp\"\ncenter = [2, 3, -1]\nradius = 0.6\n\
                [[lights]]\ntype = \"point\"\nposition = [-1.5, 2, 1.5]\nintensity = [4, 3, 2]\n\
                [[lights]]\ntype = \"spot\"\nposition = [1, 2.5, 1]\ndirection = [0, -1, -0.3]\nintensity = [6, 6, 6]\ninner_angle = 15\nouter_angle = 30\n\
                [[lights]]\ntype = \"directional\"\ndirection = [1, -2, -1]\nirradiance = [0.5, 0.6, 0.8]\n";
    let scene = Scene::text(text, Format::Toml, "punctual.toml", &Limits::default())
        .load()
        .expect("valid");
    agree(&scene, [256, 256, 1024], 8);
}

#[test]
fn nee_reduces_variance_against_bsdf_sampling() {
    // Not a time assertion: the same sample count, and MIS must be the less noisy estimator.
    let scene = shrink("cornell-box.toml", 32, 32);
    let noise = |strategy| {
        render(
            &scene,
            &RenderSettings {
                spp: 64,
                seed: 2,
                strategy,
                ..RenderSettings::default()
            },
        )
        .noise()
        .0
    };
    let (mis, bsdf) = (noise(Strategy::Mis), noise(Strategy::Bsdf));
    assert!(
        mis < bsdf,
        "MIS noise {mis} should be below BSDF-only {bsdf}"
    );
}
