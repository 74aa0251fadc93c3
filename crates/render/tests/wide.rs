//! The many-path tracer (`tessera_render::wide`) against the scalar one: every sample's value,
//! bit for bit, on the scenes it takes, and which scenes those are.

mod common;

use common::{load, scene};
use glam::Vec3A;
use tessera_render::integrator::sample_pixel;
use tessera_render::sampling::PixelSampler;
use tessera_render::scene::Scene;
use tessera_render::wide::{PixelRun, Wide};
use tessera_render::{RenderSettings, Strategy};

/// Compares every sample of `samples` for a spread of pixels (edges and corners included),
/// with four, eight and sixteen lanes, each pixel's run traced together with the other pixels'
/// so that lanes go on from one pixel to the next; returns how many samples were compared per
/// lane count and how many of them had any light.
fn compare(scene: &Scene, settings: &RenderSettings, samples: std::ops::Range<u32>) -> (u64, u64) {
    let xs = (0..scene.width).step_by(9).chain([scene.width - 1]);
    let pixels: Vec<(u32, u32)> = xs
        .flat_map(|x| {
            (0..scene.height)
                .step_by(11)
                .chain([scene.height - 1])
                .map(move |y| (x, y))
        })
        .collect();
    let expected: Vec<Vec<Vec3A>> = pixels
        .iter()
        .map(|&(x, y)| {
            let mut s = PixelSampler::new(settings.seed, x, y, samples.start);
            samples
                .clone()
                .map(|index| {
                    s.set_index(index);
                    sample_pixel(scene, settings, x, y, &s)
                })
                .collect()
        })
        .collect();
    let runs: Vec<PixelRun> = pixels
        .iter()
        .map(|&(x, y)| PixelRun {
            x,
            y,
            sampler: PixelSampler::new(settings.seed, x, y, samples.start),
            samples: samples.clone(),
        })
        .collect();
    let bits = |c: Vec3A| c.to_array().map(f32::to_bits);
    let (mut count, mut lit) = (0u64, 0u64);
    for lanes in [4, 8, 16] {
        // Where the tracer runs by default (`Wide::new`) it is this one.
        let wide = Wide::anywhere(scene, settings)
            .and_then(|w| w.with_lanes(lanes))
            .expect("the scene is one the many-path tracer can run");
        let mut values = Vec::new();
        // In windows of a few pixels, as `render_tile` cuts a row.
        for (window, expected) in runs.chunks(7).zip(expected.chunks(7)) {
            wide.trace(window, &mut values);
            assert_eq!(values.len(), window.len() * samples.len());
            let expected = expected.iter().flatten();
            for (i, (v, e)) in values.iter().zip(expected).enumerate() {
                let run = &window[i / samples.len()];
                let index = samples.start as usize + i % samples.len();
                assert_eq!(
                    bits(*v),
                    bits(*e),
                    "{lanes} lanes, pixel ({}, {}) sample {index}: lanes gave {v}, one path {e}",
                    run.x,
                    run.y
                );
            }
        }
        // One pixel at a time gives the same values: a lit pixel (a black one would compare
        // nothing).
        let lit_pixel = expected
            .iter()
            .position(|e| e.iter().any(|v| *v != Vec3A::ZERO))
            .expect("a lit pixel");
        let (x, y) = pixels[lit_pixel];
        let mut s = PixelSampler::new(settings.seed, x, y, samples.start);
        wide.sample_pixel(x, y, &s, samples.clone(), &mut values);
        for (index, v) in samples.clone().zip(&values) {
            s.set_index(index);
            assert_eq!(bits(*v), bits(sample_pixel(scene, settings, x, y, &s)));
        }
        assert!(
            values.iter().any(|v| *v != Vec3A::ZERO),
            "pixel ({x}, {y}) is black in every sample"
        );
    }
    for e in expected.iter().flatten() {
        count += 1;
        lit += u64::from(*e != Vec3A::ZERO);
    }
    (count, lit)
}

/// Asserts that the default tracer takes `scene` (`Wide::new`) and gives the scalar trace's
/// bits over `samples` at `seed`, with more than `min` samples compared and most of them lit.
fn taken_with_the_scalar_bits(scene: &Scene, seed: u64, samples: std::ops::Range<u32>, min: u64) {
    let settings = RenderSettings {
        seed,
        ..RenderSettings::default()
    };
    assert!(Wide::new(scene, &settings).is_some(), "the lanes take it");
    let (count, lit) = compare(scene, &settings, samples);
    assert!(count > min && lit > count / 2, "{count} samples, {lit} lit");
}

#[test]
fn lanes_give_the_scalar_bits_in_the_cornell_box() {
    let scene = load("cornell-box.toml");
    let settings = RenderSettings {
        seed: 11,
        ..RenderSettings::default()
    };
    let (count, lit) = compare(&scene, &settings, 0..37);
    assert!(
        count > 20_000 && lit > count / 2,
        "{count} samples, {lit} lit"
    );
    // Across the 2¹⁶-sample block where the Sobol groups' keys change, with lanes on both
    // sides of it at once.
    compare(&scene, &settings, 65_530..65_545);
    // Russian roulette from the first bounce, with pbrt's threshold.
    let early = RenderSettings {
        rr_depth: 1,
        rr_threshold: 1.0,
        ..settings
    };
    compare(&scene, &early, 0..9);
}

/// The Cornell box with its boxes as (flat-shaded) triangle meshes: the lanes test the meshes
/// one ray at a time, and must still give the scalar tracer's bits.
#[test]
fn lanes_give_the_scalar_bits_with_mesh_boxes() {
    taken_with_the_scalar_bits(&load("cornell-mesh.toml"), 11, 0..9, 5_000);
}

/// The same box with each cube from a file of its own, placed once each, so that the two
/// are merged into one world-space mesh whose hits name their own boxes (the small one made
/// green, so that a hit naming the other box would show): the lanes' hits must name them too.
#[test]
fn lanes_give_the_scalar_bits_with_merged_mesh_boxes() {
    let root = common::repo_root().join("scenes");
    let text = std::fs::read_to_string(root.join("cornell-mesh.toml")).expect("scene");
    let text = text
        .replacen(r#"file = "meshes/cube.obj""#, r#"file = "large.obj""#, 1)
        .replacen(
            "file = \"meshes/cube.obj\"\nmaterial = \"white\"",
            "file = \"small.obj\"\nmaterial = \"green\"",
            1,
        );
    let cube = std::fs::read(root.join("meshes/cube.obj")).expect("cube");
    let scene = common::scene_with_files(&text, &[("large.obj", &cube), ("small.obj", &cube)]);
    let merged = scene
        .prims
        .iter()
        .filter(|p| matches!(&p.shape, tessera_render::shape::Shape::Mesh(m) if m.mesh.is_merged()))
        .count();
    assert_eq!(merged, 2, "both boxes in one mesh");
    taken_with_the_scalar_bits(&scene, 12, 0..9, 5_000);
}

/// A two-sided light seen from both sides, two-sided walls, and a light that is a box's face
/// away from the camera (so paths reach its back and the light's far side).
#[test]
fn lanes_give_the_scalar_bits_with_two_sided_surfaces() {
    let scene = scene(
        r#"
version = 1
[camera]
model = "look_at"
eye = [0.0, 0.2, 3.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 50.0
[film]
width = 40
height = 30
[materials.wall]
type = "diffuse"
albedo = [0.8, 0.7, 0.6]
two_sided = true
[materials.lamp]
type = "diffuse"
albedo = [0.3, 0.3, 0.3]
emission = [4.0, 3.0, 2.0]
two_sided = true
[[objects]]
shape = "rect"
material = "wall"
transform.matrix = [[2, 0, 0, 0], [0, 0, 2, -1], [0, -2, 0, 0], [0, 0, 0, 1]]
[[objects]]
shape = "rect"
material = "lamp"
transform.matrix = [[0.5, 0, 0, 0], [0, 0.3, 0.4, 0.5], [0, -0.4, 0.3, 0], [0, 0, 0, 1]]
[[objects]]
shape = "box"
material = "wall"
transform.matrix = [[0.3, 0, 0.1, -0.5], [0, 0.4, 0, -0.6], [-0.1, 0, 0.3, 0.2], [0, 0, 0, 1]]
"#,
    );
    let settings = RenderSettings {
        seed: 5,
        ..RenderSettings::default()
    };
    let (count, lit) = compare(&scene, &settings, 0..64);
    assert!(lit > count / 4, "{count} samples, {lit} lit");
}

/// Glass and mirror balls in the box: the lanes step their vertices with the scalar trace's
/// own code, one lane at a time, and the diffuse walls' lanes around them must not disturb
/// them (nor they the walls'). Early roulette reaches paths that have refracted, whose
/// throughput roulette weighs with η² undone.
#[test]
fn lanes_give_the_scalar_bits_with_glass_and_mirrors() {
    let scene = load("glass-mirror.toml");
    taken_with_the_scalar_bits(&scene, 13, 0..17, 10_000);
    let early = RenderSettings {
        seed: 13,
        rr_depth: 1,
        rr_threshold: 1.0,
        ..RenderSettings::default()
    };
    compare(&scene, &early, 0..9);
}

/// Rough metals (which sample the light themselves, through the scalar code) and a textured
/// diffuse surface (which the lanes do not model) among diffuse walls.
#[test]
fn lanes_give_the_scalar_bits_with_metals_and_textures() {
    for name in ["metals-box.toml", "textured.toml"] {
        taken_with_the_scalar_bits(&load(name), 14, 0..9, 5_000);
    }
}

/// The glass-and-meshes room under a rectangle light, its floor an infinite plane: a scene
/// that is not one BVH leaf (its queries go lane by lane), with smooth meshes whose points
/// shade with a bent normal (the scalar step's, lane by lane), a smooth glass mesh and flat
/// diffuse walls.
#[test]
fn lanes_give_the_scalar_bits_with_smooth_meshes_and_a_plane() {
    let root = common::repo_root().join("scenes");
    let text = std::fs::read_to_string(root.join("mesh-glass.toml")).expect("scene");
    let lamp_at = text.find("[[objects]] # lamp").expect("the lamp");
    let lamp_end = lamp_at + text[lamp_at..].find("\n\n").expect("the lamp's end");
    let text = format!(
        "{}{}{}",
        &text[..lamp_at],
        "[[objects]]\nshape = \"rect\"\nmaterial = \"light\"\n\
         transform.matrix = [[0.23, 0, 0, 0], [0, 0, -0.19, 0.99], [0, 0.19, 0, 0.01], [0, 0, 0, 1]]",
        &text[lamp_end..]
    )
    .replacen(
        "shape = \"rect\"\nmaterial = \"white\"\ntransform.matrix = [[1, 0, 0, 0], [0, 0, 1, -1], [0, -1, 0, 0], [0, 0, 0, 1]]",
        "shape = \"plane\"\nmaterial = \"white\"\npoint = [0.0, -1.0, 0.0]\nnormal = [0.0, 1.0, 0.0]",
        1,
    );
    assert!(
        text.contains("\"plane\"") && !text.contains("lamp.obj"),
        "{text}"
    );
    let sphere = std::fs::read(root.join("meshes/icosphere.ply")).expect("mesh");
    let scene = common::scene_with_files(&text, &[("meshes/icosphere.ply", &sphere)]);
    assert!(!scene.is_one_leaf() && scene.has_shading_normals());
    taken_with_the_scalar_bits(&scene, 15, 0..9, 5_000);
}

/// Under any lights but one parallelogram, `--tracer lanes8` still runs the many-path tracer
/// (`Wide::anywhere`), sampling them lane by lane with the scalar code, or the map in lanes
/// where it is the only distant light: an environment map and a point light with smooth
/// meshes (one merged mesh and nothing else: the map in lanes, the lamp lane by lane, added
/// after it), a sky gradient beside a rectangle light, a sphere light over an infinite plane,
/// point, spot and sun lights. The default (`Wide::new`) leaves all of them to the scalar
/// trace, where they measured faster: each is under a sky or a sun beside other lights, or
/// not one BVH leaf.
#[test]
fn lanes_anywhere_give_the_scalar_bits_under_any_lights() {
    let settings = RenderSettings {
        seed: 16,
        ..RenderSettings::default()
    };
    for name in ["gltf-metals.toml", "spheres.toml", "caustic.toml"] {
        let scene = load(name);
        assert!(Wide::new(&scene, &settings).is_none(), "{name}");
        let (count, lit) = compare(&scene, &settings, 0..5);
        assert!(
            count > 2_000 && lit > count / 2,
            "{name}: {count} samples, {lit} lit"
        );
    }
    // Punctual lights beside a rectangle light (several lights: a vertex draws which one).
    let scene = scene(
        r#"
version = 1
[camera]
model = "look_at"
eye = [0.0, 1.0, 3.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 50.0
[film]
width = 40
height = 30
[materials.floor]
type = "diffuse"
albedo = [0.7, 0.6, 0.5]
[materials.gold]
type = "conductor"
metal = "gold"
roughness = 0.2
[materials.lamp]
type = "diffuse"
albedo = [0.3, 0.3, 0.3]
emission = [2.0, 2.0, 2.0]
[[objects]]
shape = "plane"
material = "floor"
point = [0.0, -0.5, 0.0]
normal = [0.0, 1.0, 0.0]
[[objects]]
shape = "sphere"
material = "gold"
center = [0.3, -0.2, 0.0]
radius = 0.3
[[objects]]
shape = "rect"
material = "lamp"
transform.matrix = [[0.3, 0, 0, -0.6], [0, 0, -0.3, 1.0], [0, 0.3, 0, 0], [0, 0, 0, 1]]
[[lights]]
type = "point"
position = [-0.5, 0.8, 0.5]
intensity = [1.0, 0.8, 0.6]
[[lights]]
type = "spot"
position = [0.5, 1.5, 1.0]
direction = [0.0, -1.0, -0.5]
intensity = [3.0, 3.0, 3.0]
inner_angle = 15
outer_angle = 30
[[lights]]
type = "directional"
direction = [0.3, -1.0, -0.2]
irradiance = [0.5, 0.5, 0.6]
angle = 3.0
"#,
    );
    assert!(Wide::new(&scene, &settings).is_none(), "punctual lights");
    let (count, lit) = compare(&scene, &settings, 0..16);
    assert!(
        lit > count / 2,
        "punctual lights: {count} samples, {lit} lit"
    );
}

/// A closed room of one BVH leaf takes the lanes by default whatever lights it: two
/// rectangles, a sphere, a point light and a spot, an emissive mesh (`mesh-glass.toml`'s
/// lamp), each the scalar trace's bits.
#[test]
fn closed_rooms_under_other_lights_take_the_lanes() {
    let cornell = std::fs::read_to_string(common::repo_root().join("scenes/cornell-box.toml"))
        .expect("the bundled Cornell box");
    let light = r#"[[objects]] # light
shape = "rect"
material = "light"
transform.matrix = [[0.23, 0, 0, 0], [0, 0, -0.19, 0.99], [0, 0.19, 0, 0.01], [0, 0, 0, 1]]
"#;
    assert!(
        cornell.contains(light),
        "the Cornell box's light as written here"
    );
    let lit_by = |lights: &str| scene(&cornell.replace(light, lights));
    let two = r#"[[objects]]
shape = "rect"
material = "light"
transform.matrix = [[0.23, 0, 0, -0.3], [0, 0, -0.19, 0.99], [0, 0.19, 0, 0.01], [0, 0, 0, 1]]
[[objects]]
shape = "rect"
material = "light"
transform.matrix = [[0.23, 0, 0, 0.3], [0, 0, -0.19, 0.99], [0, 0.19, 0, 0.01], [0, 0, 0, 1]]
"#;
    let sphere = r#"[[objects]]
shape = "sphere"
material = "light"
center = [0.0, 0.8, 0.0]
radius = 0.1
"#;
    let punctual = r#"[[lights]]
type = "point"
position = [0.0, 0.9, 0.0]
intensity = [3.0, 2.5, 2.0]
[[lights]]
type = "spot"
position = [0.5, 0.9, 0.5]
direction = [-0.3, -1.0, -0.2]
intensity = [4.0, 4.0, 4.0]
inner_angle = 20
outer_angle = 35
"#;
    for (lights, seed) in [(two, 31), (sphere, 32), (punctual, 33)] {
        taken_with_the_scalar_bits(&lit_by(lights), seed, 0..6, 2_000);
    }
    taken_with_the_scalar_bits(&load("mesh-glass.toml"), 34, 0..6, 2_000);
}

/// Under an environment map that is the only distant light, the lanes look it up and sample
/// it in lanes (`wide/sky.rs`), with the scalar trace's bits: diffuse ground and glossy balls,
/// pbr balls, and the material showcase (textured, normal-mapped pbr meshes, rough gold,
/// frosted glass, plastic). The default leaves them to the scalar trace (`Wide::new`).
#[test]
fn the_map_in_lanes_gives_the_scalar_bits() {
    for (name, seed) in [
        ("envmap-balls.toml", 3),
        ("pbr-metals.toml", 4),
        ("materials.toml", 5),
    ] {
        let scene = load(name);
        let settings = RenderSettings {
            seed,
            ..RenderSettings::default()
        };
        assert!(Wide::new(&scene, &settings).is_none(), "{name}");
        let (count, lit) = compare(&scene, &settings, 0..5);
        assert!(
            count > 2_000 && lit > count / 2,
            "{name}: {count} samples, {lit} lit"
        );
    }
}

/// The scenes whose bounce the lanes do not model go one path at a time.
#[test]
fn other_scenes_and_strategies_go_one_path_at_a_time() {
    let cornell = load("cornell-box.toml");
    for strategy in [Strategy::Bsdf, Strategy::Nee] {
        let settings = RenderSettings {
            strategy,
            ..RenderSettings::default()
        };
        assert!(Wide::new(&cornell, &settings).is_none(), "{strategy:?}");
    }
    let settings = RenderSettings::default();
    assert!(Wide::new(&cornell, &settings).is_some());
    // Balls under a map; meshes under a sky and a lamp.
    for name in ["envmap-balls.toml", "gltf-metals.toml"] {
        assert!(Wide::new(&load(name), &settings).is_none(), "{name}");
    }
    // A map beside a point light in one leaf: the map in lanes, the lamp lane by lane, added
    // after it.
    let root = common::repo_root().join("scenes");
    let text = std::fs::read_to_string(root.join("envmap-balls.toml")).expect("scene");
    let sky = std::fs::read(root.join("textures/sky.exr")).expect("sky");
    let text = text
        .replace("width = 256", "width = 48")
        .replace("height = 256", "height = 48");
    let lamp =
        "[[lights]]\ntype = \"point\"\nposition = [0.0, 2.0, 1.0]\nintensity = [1.0, 1.0, 1.0]\n";
    let with_lamp =
        common::scene_with_files(&format!("{text}\n{lamp}"), &[("textures/sky.exr", &sky)]);
    assert!(
        Wide::new(&with_lamp, &settings).is_none(),
        "a map and a lamp"
    );
    let (count, lit) = compare(&with_lamp, &settings, 0..6);
    assert!(
        lit > count / 2,
        "a map and a lamp: {count} samples, {lit} lit"
    );
    // A room the lanes would shade nothing of (every surface a metal), and one with coloured
    // glass (whose medium they do not track): the same room, its walls' material swapped.
    let room = |walls: &str, ball: &str| {
        scene(&format!(
            r#"
version = 1
[camera]
model = "look_at"
eye = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 40.0
[film]
width = 8
height = 8
[materials.walls]
{walls}
[materials.ball]
{ball}
[materials.lamp]
{walls}
emission = [4.0, 4.0, 4.0]
[[objects]]
shape = "rect"
material = "walls"
transform.matrix = [[1, 0, 0, 0], [0, 0, 1, -1], [0, -1, 0, 0], [0, 0, 0, 1]]
[[objects]]
shape = "rect"
material = "lamp"
transform.matrix = [[0.2, 0, 0, 0], [0, 0, -0.2, 0.9], [0, 0.2, 0, 0], [0, 0, 0, 1]]
[[objects]]
shape = "sphere"
material = "ball"
center = [0.0, -0.5, 0.0]
radius = 0.3
"#
        ))
    };
    let diffuse = "type = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]";
    let metal = "type = \"conductor\"\nmetal = \"gold\"\nroughness = 0.3";
    let glass = "type = \"dielectric\"\nior = 1.5";
    assert!(Wide::new(&room(diffuse, glass), &settings).is_some());
    assert!(
        Wide::new(&room(metal, glass), &settings).is_none(),
        "no diffuse surface"
    );
    let coloured = format!("{glass}\nabsorption = [0.1, 0.2, 0.3]");
    assert!(
        Wide::new(&room(diffuse, &coloured), &settings).is_none(),
        "coloured glass"
    );
}
