//! Triangle meshes in whole scenes: furnaces with answers in closed form, smooth shading
//! against the analytic sphere, instancing at scale, the scene errors a mesh can give, and the
//! scene identity covering the mesh files.

mod common;

use std::fmt::Write as _;
use std::sync::Arc;

use common::{render, scene_with_files};
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::shape::Shape;
use tessera_render::{RenderSettings, Strategy};

/// A UV sphere of radius 1 as OBJ text: `rings` × `segments` quads, with vertex normals.
fn uv_sphere_obj(rings: usize, segments: usize) -> String {
    let mut s = String::new();
    for r in 0..=rings {
        for k in 0..segments {
            let theta = std::f64::consts::PI * r as f64 / rings as f64;
            let phi = std::f64::consts::TAU * k as f64 / segments as f64;
            let (x, y, z) = (
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            );
            writeln!(s, "v {x} {y} {z}\nvn {x} {y} {z}").expect("write");
        }
    }
    let v = |r: usize, k: usize| r * segments + k % segments + 1;
    for r in 0..rings {
        for k in 0..segments {
            // Counter-clockwise seen from outside.
            let (a, b, c, d) = (v(r, k), v(r, k + 1), v(r + 1, k), v(r + 1, k + 1));
            writeln!(
                s,
                "f {a}//{a} {b}//{b} {d}//{d}\nf {a}//{a} {d}//{d} {c}//{c}"
            )
            .expect("write");
        }
    }
    s
}

fn head(width: u32, eye: &str, target: &str, fov: u32) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = {eye}\ntarget = {target}\nfov = {fov}\n[film]\nwidth = {width}\nheight = {width}\n"
    )
}

/// A closed, two-sided, emitting diffuse mesh seen from inside: L = Le/(1 − ρ) exactly, with
/// every strategy (the emissive mesh's area sampling, MIS against it, and the mesh's hits).
#[test]
fn closed_emitting_mesh_gives_le_over_one_minus_albedo() {
    let (rho, le) = ([0.8f64, 0.5, 0.3], [0.5f64, 1.0, 2.0]);
    let text = format!(
        "{}[materials.shell]\ntype = \"diffuse\"\nalbedo = {rho:?}\nemission = {le:?}\ntwo_sided = true\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"sphere.obj\"\nmaterial = \"shell\"\ntransform = {{ scale = [2, 1.5, 2.5] }}\n",
        head(16, "[0.1, 0.2, 0.0]", "[1, 0.3, 0.2]", 90)
    );
    let s = scene_with_files(&text, &[("sphere.obj", uv_sphere_obj(12, 24).as_bytes())]);
    for strategy in [Strategy::Bsdf, Strategy::Nee, Strategy::Mis] {
        let img = render(
            &s,
            &RenderSettings {
                spp: 128,
                seed: 3,
                strategy,
                ..RenderSettings::default()
            },
        );
        let (mean, se) = common::region_stats(&img, 0, 0, img.width, img.height);
        for c in 0..3 {
            let expected = le[c] / (1.0 - rho[c]);
            assert!(
                (mean[c] - expected).abs() <= 3.0 * se[c] + 1e-5 * expected && se[c] > 0.0,
                "{strategy:?} channel {c}: {} vs Le/(1-ρ) = {expected} ± {}",
                mean[c],
                se[c]
            );
        }
    }
}

/// Smooth shading against the analytic sphere: under a sky that is bright above and dark
/// below, a diffuse sphere's shading follows its normal. Every pixel of the smooth-shaded mesh
/// of a sphere (16 × 32 quads) must be within 2% of the analytic sphere's (a fixed bound: at
/// 1024 spp the Sobol samples' error is far below the per-pixel variance estimate, which
/// would hide the difference sought); the same mesh shaded flat must not be (its facets
/// show), so the check can tell whether the shading normal is used. The margins measured are
/// in docs/renderer.md ("Smooth shading").
#[test]
fn smooth_sphere_mesh_matches_the_analytic_sphere() {
    let text = |shape: &str| {
        format!(
            "{}[environment]\ntype = \"gradient\"\ntop = [2, 2, 2]\nbottom = [0.1, 0.1, 0.1]\n\
             [materials.m]\ntype = \"diffuse\"\nalbedo = [0.6, 0.6, 0.6]\n\
             [[objects]]\nmaterial = \"m\"\n{shape}\n",
            head(32, "[0, 0, 6]", "[0, 0, 0]", 22)
        )
    };
    let obj = uv_sphere_obj(16, 32);
    let settings = RenderSettings {
        spp: 1024,
        seed: 5,
        ..RenderSettings::default()
    };
    let files = [("sphere.obj", obj.as_bytes())];
    let analytic = render(
        &scene_with_files(&text("shape = \"sphere\""), &[]),
        &settings,
    );
    let mesh = |smooth: bool| {
        let shape = format!("shape = \"mesh\"\nfile = \"sphere.obj\"\nsmooth = {smooth}");
        render(&scene_with_files(&text(&shape), &files), &settings)
    };
    let (smooth, flat) = (mesh(true), mesh(false));
    // Pixels inside the silhouette (the sphere spans about 26 of the 32 pixels).
    let worst = |img: &tessera_render::Image| {
        let mut worst = 0f64;
        for y0 in 8..24 {
            for x0 in 8..24 {
                let (a, _) = common::region_stats(&analytic, x0, y0, 1, 1);
                let (m, _) = common::region_stats(img, x0, y0, 1, 1);
                worst = worst.max((m[0] - a[0]).abs() / a[0]);
            }
        }
        worst
    };
    let (ws, wf) = (worst(&smooth), worst(&flat));
    eprintln!("worst relative difference per pixel: smooth {ws}, flat {wf}");
    assert!(ws <= 0.02, "smooth mesh differs from the sphere by {ws}");
    assert!(
        wf > 0.02,
        "flat shading matched too ({wf}): the test cannot see the shading normal"
    );
    assert_eq!(smooth.nonfinite, 0);
}

/// 1,000 instances of one 100,000-triangle mesh: the file is read and its BVH built once,
/// every instance shares it, and rays find the instances.
#[test]
fn a_thousand_instances_of_a_100k_triangle_mesh_share_one_mesh() {
    // A binary PLY grid of 224 × 224 quads (100,352 triangles).
    let n = 224u32;
    let mut ply = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        (n + 1) * (n + 1),
        n * n
    )
    .into_bytes();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
            let z = 0.05 * (x * 20.0).sin() * (y * 20.0).cos();
            for c in [x, y, z] {
                ply.extend(c.to_le_bytes());
            }
        }
    }
    for j in 0..n {
        for i in 0..n {
            let v = j * (n + 1) + i;
            ply.push(4);
            for k in [v, v + 1, v + n + 2, v + n + 1] {
                ply.extend(k.to_le_bytes());
            }
        }
    }
    let mut text = head(8, "[0, 0, 60]", "[0, 0, 0]", 60);
    text.push_str("[materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n");
    for k in 0..1000 {
        let (x, y) = ((k % 40) as f32 - 20.0, (k / 40) as f32 - 12.5);
        writeln!(
            text,
            "[[objects]]\nshape = \"mesh\"\nfile = \"grid.ply\"\nmaterial = \"m\"\ntransform = {{ translate = [{x}, {y}, 0], rotate = {{ axis = [0, 0, 1], degrees = {k} }}, scale = [0.9, 0.9, 0.9] }}"
        )
        .expect("write");
    }
    let s = scene_with_files(&text, &[("grid.ply", &ply)]);
    assert_eq!(s.prims.len(), 1000);
    let meshes: Vec<_> = s
        .prims
        .iter()
        .map(|p| match &p.shape {
            Shape::Mesh(m) => Arc::clone(&m.mesh),
            other => panic!("{other:?}"),
        })
        .collect();
    assert_eq!(meshes[0].len(), 100_352);
    assert!(meshes.iter().all(|m| Arc::ptr_eq(m, &meshes[0])));
    // Rays straight down hit the instance under them.
    let mut hits = 0;
    for k in 0..1000 {
        // The grid's centre (0.5, 0.5) under the instance's transform.
        let a = (k as f32).to_radians();
        let (c, r) = (
            0.45 * a.cos() - 0.45 * a.sin(),
            0.45 * a.sin() + 0.45 * a.cos(),
        );
        let (x, y) = ((k % 40) as f32 - 20.0 + c, (k / 40) as f32 - 12.5 + r);
        let ray = tessera_render::math::Ray::new(
            glam::Vec3A::new(x, y, 10.0),
            glam::Vec3A::new(0.0, 0.0, -1.0),
        );
        hits += usize::from(s.intersect(&ray, f32::INFINITY).is_some());
    }
    assert_eq!(hits, 1000, "every instance is hit at its centre");
    let img = render(
        &s,
        &RenderSettings {
            spp: 1,
            ..RenderSettings::default()
        },
    );
    assert_eq!(img.nonfinite, 0);
}

fn load_err(text: &str, files: &[(&str, &[u8])]) -> String {
    let files = tessera_render::scene::assets::MemAssets(
        files
            .iter()
            .map(|(n, b)| (n.to_string(), b.to_vec()))
            .collect(),
    );
    Scene::text(text, Format::Toml, "s.toml", &Limits::default())
        .at(1)
        .assets(&files)
        .load()
        .expect_err("refused")
        .to_string()
}

/// What a mesh object can get wrong, each named at its key with file:line:column.
#[test]
fn mesh_errors_name_the_key_and_the_file() {
    let base = format!(
        "{}[materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n[materials.r]\ntype = \"diffuse\"\nalbedo = [0.5, 0, 0]\n",
        head(4, "[0, 0, 5]", "[0, 0, 0]", 40)
    );
    let tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n".as_slice();
    let obj =
        |extra: &str| format!("{base}[[objects]]\nshape = \"mesh\"\nmaterial = \"m\"\n{extra}");
    type Files<'a> = &'a [(&'a str, &'a [u8])];
    let cases: [(String, Files, &str); 7] = [
        (obj(""), &[], "s.toml:16:1: objects[0].file: a mesh needs `file`"),
        (
            obj("file = \"a.obj\"\n"),
            &[],
            "s.toml:19:8: objects[0].file: `a.obj` is not among the scene's files",
        ),
        (
            obj("file = \"a.stl\"\n"),
            &[],
            "s.toml:19:8: objects[0].file: `a.stl`: a mesh file must be .obj or .ply (by its extension)",
        ),
        (
            obj("file = \"a.obj\"\n"),
            &[("a.obj", b"v 0 0 0\nv 1 0 x\n")],
            "s.toml:19:8: objects[0].file: a.obj:2: bad vertex position: `v` needs three numbers",
        ),
        (
            obj("file = \"a.obj\"\nmaterials_map = { blue = \"r\" }\n"),
            &[("a.obj", tri)],
            "s.toml:20:26: objects[0].materials_map.blue: `a.obj` has no material group `blue` (it has: red)",
        ),
        (
            obj("file = \"a.obj\"\nmaterials_map = { red = \"nope\" }\n"),
            &[("a.obj", tri)],
            "s.toml:20:25: objects[0].materials_map.red: material `nope` is not defined (defined: m, r)",
        ),
        (
            obj("file = \"a.obj\"\nradius = 2\n"),
            &[("a.obj", tri)],
            "s.toml:20:10: objects[0].radius: `radius` does not apply to a mesh",
        ),
    ];
    let got: Vec<String> = cases.iter().map(|(t, f, _)| load_err(t, f)).collect();
    let want: Vec<&str> = cases.iter().map(|c| c.2).collect();
    assert_eq!(got, want);
    let sphere =
        format!("{base}[[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\nsmooth = true\n");
    assert_eq!(
        load_err(&sphere, &[]),
        "s.toml:19:10: objects[0].smooth: `smooth` does not apply to a sphere"
    );
}

/// A scene's identity covers its mesh files: another mesh under the same text is another
/// scene, the same bytes the same one; a scene without files keeps its text's hash.
#[test]
fn the_scene_hash_covers_the_mesh_files() {
    let text = format!(
        "{}[materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n[[objects]]\nshape = \"mesh\"\nfile = \"a.obj\"\nmaterial = \"m\"\n",
        head(4, "[0, 0, 5]", "[0, 0, 0]", 40)
    );
    let a = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".as_slice();
    let b = b"v 0 0 0\nv 1 0 0\nv 0 2 0\nf 1 2 3\n".as_slice();
    let h = |bytes: &[u8]| scene_with_files(&text, &[("a.obj", bytes)]).hash;
    assert_eq!(h(a), h(a));
    assert_ne!(h(a), h(b));
    let s = scene_with_files(&text, &[("a.obj", a)]);
    assert_eq!(s.files.len(), 1);
    assert_eq!(s.files[0].0, "a.obj");
    let plain = common::load("cornell-box.toml");
    let bytes = std::fs::read(common::repo_root().join("scenes/cornell-box.toml")).expect("read");
    assert_eq!(
        plain.hash,
        tessera_render::scene::assets::sha256_hex(&bytes),
        "a scene without files is addressed by its text alone"
    );
    assert!(plain.files.is_empty());
}

/// The mesh scenes that ship load (reading their files beside them), and docs/scene-format.md
/// shows `scenes/mesh-glass.toml` as it is.
#[test]
fn the_shipped_mesh_scenes_load_and_the_docs_show_them_as_they_are() {
    for name in ["cornell-mesh.toml", "mesh-glass.toml"] {
        let s = common::load(name);
        assert!(!s.files.is_empty(), "{name} reads its mesh files");
    }
    let glass = common::load("mesh-glass.toml");
    // One read of icosphere.ply serves both of its instances.
    let names: Vec<&str> = glass.files.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["meshes/lamp.obj", "meshes/icosphere.ply"]);
    assert_eq!(
        glass.lights.lights.len(),
        1,
        "the lamp's glow group is the one light"
    );
    let root = common::repo_root();
    let docs = std::fs::read_to_string(root.join("docs/scene-format.md")).expect("docs");
    let scene = std::fs::read_to_string(root.join("scenes/mesh-glass.toml")).expect("scene");
    assert!(
        docs.contains(&scene),
        "docs/scene-format.md's example differs from scenes/mesh-glass.toml"
    );
}

/// scenes/textured.toml loads its two OBJ files and its PNG, and renders the painting upright:
/// the texture's red stripe (its top edge) shows at the top of the painting, and the checks
/// below it.
#[test]
fn the_shipped_textured_scene_shows_its_texture_upright() {
    let s = common::load("textured.toml");
    let names: Vec<&str> = s.files.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "textures/checker.png",
            "meshes/quad.obj",
            "meshes/textured-cube.obj"
        ]
    );
    let text = std::fs::read_to_string(common::repo_root().join("scenes/textured.toml"))
        .expect("scene")
        .replace("width = 256", "width = 64")
        .replace("height = 256", "height = 64");
    let root = common::repo_root().join("scenes");
    let file = |n: &str| std::fs::read(root.join(n)).expect("scene file");
    let (quad, cube, png) = (
        file("meshes/quad.obj"),
        file("meshes/textured-cube.obj"),
        file("textures/checker.png"),
    );
    let s = scene_with_files(
        &text,
        &[
            ("meshes/quad.obj", &quad),
            ("meshes/textured-cube.obj", &cube),
            ("textures/checker.png", &png),
        ],
    );
    let img = render(
        &s,
        &RenderSettings {
            spp: 64,
            seed: 1,
            ..RenderSettings::default()
        },
    );
    // The painting spans columns 23.7 to 40.3 and rows 19.2 to 35.7 of 64 (world x ±0.45 and
    // y -0.2 to 0.7, 4.89 in front of a camera whose film spans ±1.746 there); its top
    // eighth, the stripe, is rows 19.2 to 21.3.
    let (stripe, _) = common::region_stats(&img, 28, 20, 8, 1);
    // The stripe reflects almost no green (sRGB 190, 40, 30); both checks reflect more than
    // a third as much green as red, even under the box's orange light.
    assert!(stripe[1] < 0.2 * stripe[0], "stripe {stripe:?}");
    for (x0, y0) in [(26, 25), (30, 30), (36, 33)] {
        let (check, _) = common::region_stats(&img, x0, y0, 2, 2);
        assert!(check[1] > 0.3 * check[0], "check at ({x0},{y0}): {check:?}");
    }
}

/// An 8-bit PNG of `w` × `h` grey levels (row 0 at the top).
fn grey_png(w: u32, h: u32, levels: &[u8]) -> Vec<u8> {
    let mut png = Vec::new();
    let mut e = png::Encoder::new(&mut png, w, h);
    e.set_color(png::ColorType::Grayscale);
    e.set_depth(png::BitDepth::Eight);
    let mut writer = e.write_header().expect("header");
    writer.write_image_data(levels).expect("data");
    drop(writer);
    png
}

/// A textured albedo: a flat quad with texture coordinates, facing the camera under a
/// uniform sky L, shows ρ(u, v)·L (every bounce leaves to the sky), with ρ the texel decoded
/// from sRGB. A 2×2 checker of two grey levels, each cell 32 texels square so that bilinear
/// filtering blends only at its edges: the middle of each cell must be its level.
#[test]
fn a_textured_quad_under_a_sky_shows_the_decoded_texels() {
    let obj = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n";
    // Top left and bottom right 200, the others 60.
    let levels: Vec<u8> = (0..64 * 64)
        .map(|i| {
            if (i % 64 < 32) == (i / 64 < 32) {
                200
            } else {
                60
            }
        })
        .collect();
    let png = grey_png(64, 64, &levels);
    let text = format!(
        "{}[environment]\ntype = \"constant\"\nradiance = [1, 1, 1]\n\
         [materials.m]\ntype = \"diffuse\"\nalbedo = {{ texture = \"checker.png\" }}\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"quad.obj\"\nmaterial = \"m\"\n",
        head(32, "[0, 0, 2.4]", "[0, 0, 0]", 46)
    );
    let s = scene_with_files(
        &text,
        &[("quad.obj", obj.as_bytes()), ("checker.png", &png)],
    );
    let names: Vec<&str> = s.files.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["checker.png", "quad.obj"],
        "the texture is one of the scene's files"
    );
    let img = render(
        &s,
        &RenderSettings {
            spp: 64,
            seed: 2,
            ..RenderSettings::default()
        },
    );
    let lin = |c: u8| tessera_render::texture::srgb_to_linear(f64::from(c) / 255.0);
    // Cell centres: the quad fills about the whole 32² film; each cell is a 16² quarter.
    for (x0, y0, level) in [(5, 5, 200u8), (21, 5, 60), (5, 21, 60), (21, 21, 200)] {
        let (mean, se) = common::region_stats(&img, x0, y0, 6, 6);
        let want = lin(level);
        assert!(
            (mean[0] - want).abs() <= 3.0 * se[0] + 1e-3 * want,
            "cell at ({x0},{y0}): {} vs the texel {level} decoded, {want}",
            mean[0]
        );
    }
    assert_eq!(img.nonfinite, 0);
}

/// Meshes placed once share one world-space mesh and BVH, and each triangle's hits still
/// name its own object: two quads of different albedo side by side (one moved and turned to
/// its place), each a flat diffuse square facing the camera under a uniform sky L, show ρ·L
/// each. A mesh placed twice keeps its own mesh (instancing), and so does a mirrored one.
#[test]
fn meshes_placed_once_merge_and_each_keeps_its_material() {
    let obj = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3 4\n";
    let text = format!(
        "{}[environment]\ntype = \"constant\"\nradiance = [1, 1, 1]\n\
         [materials.dark]\ntype = \"diffuse\"\nalbedo = [0.2, 0.3, 0.4]\n\
         [materials.light]\ntype = \"diffuse\"\nalbedo = [0.9, 0.7, 0.5]\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"quad.obj\"\nmaterial = \"dark\"\n\
         transform = {{ translate = [-1, 0, 0] }}\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"other.obj\"\nmaterial = \"light\"\n\
         transform = {{ rotate = {{ axis = [0, 0, 1], degrees = 90 }}, translate = [1, 0, 0] }}\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"twice.obj\"\nmaterial = \"light\"\n\
         transform = {{ translate = [0, 0, -5] }}\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"twice.obj\"\nmaterial = \"light\"\n\
         transform = {{ translate = [0, 3, -5] }}\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"mirrored.obj\"\nmaterial = \"light\"\n\
         transform = {{ scale = [-1, 1, 1], translate = [0, -3, -5] }}\n",
        head(32, "[0, 0, 2.5]", "[0, 0, 0]", 90)
    );
    let files = [
        ("quad.obj", obj.as_bytes()),
        ("other.obj", obj.as_bytes()),
        ("twice.obj", obj.as_bytes()),
        ("mirrored.obj", obj.as_bytes()),
    ];
    let s = scene_with_files(&text, &files);
    let mesh = |i: usize| match &s.prims[i].shape {
        Shape::Mesh(m) => Arc::clone(&m.mesh),
        other => panic!("object {i} is {other:?}"),
    };
    assert!(mesh(0).is_merged() && Arc::ptr_eq(&mesh(0), &mesh(1)));
    assert_eq!(mesh(0).len(), 4, "the two quads' triangles, once each");
    assert!(Arc::ptr_eq(&mesh(2), &mesh(3)) && !mesh(2).is_merged());
    assert!(!mesh(4).is_merged());
    let img = render(
        &s,
        &RenderSettings {
            spp: 64,
            seed: 4,
            ..RenderSettings::default()
        },
    );
    // The film spans x in [−2.5, 2.5] at the quads' depth: the left quad covers pixels 3 to
    // 15, the right one 16 to 28, both rows 10 to 22.
    for (x0, albedo) in [(6, [0.2, 0.3, 0.4]), (20, [0.9, 0.7, 0.5])] {
        let (mean, se) = common::region_stats(&img, x0, 12, 6, 8);
        for c in 0..3 {
            assert!(
                (mean[c] - albedo[c]).abs() <= 3.0 * se[c] + 1e-4,
                "pixels from x = {x0}, channel {c}: {} against the albedo {}",
                mean[c],
                albedo[c]
            );
        }
    }
}

/// What a texture can get wrong, named at its key.
#[test]
fn texture_errors_name_the_key() {
    let png = grey_png(1, 1, &[128]);
    let quad = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n".as_slice();
    let flat = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".as_slice();
    let scene = |albedo: &str, object: &str| {
        format!(
            "{}[materials.m]\ntype = \"diffuse\"\nalbedo = {albedo}\n[[objects]]\nmaterial = \"m\"\n{object}\n",
            head(4, "[0, 0, 5]", "[0, 0, 0]", 40)
        )
    };
    let tex = "{ texture = \"t.png\" }";
    let mesh = "shape = \"mesh\"\nfile = \"m.obj\"";
    let files: &[(&str, &[u8])] = &[("t.png", &png), ("m.obj", quad), ("flat.obj", flat)];
    let cases = [
        (scene(tex, "shape = \"sphere\""), "objects[0].material: its material has a texture, which needs a mesh with texture coordinates"),
        (scene(tex, "shape = \"mesh\"\nfile = \"flat.obj\""), "objects[0].material: its material has a texture, but `flat.obj` gives no texture coordinates"),
        (scene("{ texture = \"nope.png\" }", mesh), "materials.m.albedo.texture: `nope.png` is not among the scene's files"),
        (scene("{ texture = \"m.obj\" }", mesh), "materials.m.albedo.texture: `m.obj`: a texture must be .png, .jpg, .jpeg, .exr or .hdr (by its extension)"),
        (scene("{ texture = \"t.png\", scale = 2 }", mesh), "unknown field `scale`"),
        (scene("[0.5, 0.5]", mesh), "invalid length 2"),
    ];
    for (text, want) in cases {
        let got = load_err(&text, files);
        assert!(got.contains(want), "{got}\n  should contain: {want}");
    }
    let bad_png: &[(&str, &[u8])] = &[("t.png", b"not a png"), ("m.obj", quad)];
    let got = load_err(&scene(tex, mesh), bad_png);
    assert!(
        got.contains("materials.m.albedo.texture: t.png: not a readable image"),
        "{got}"
    );
}
