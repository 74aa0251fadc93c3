//! glTF 2.0 files as scenes and as scene objects: what is read (node trees, instancing,
//! quantized and sparse accessors, strips and fans, cameras, punctual lights) and what is
//! refused, each with one line naming the place. Materials: `gltf_materials.rs`.

use std::collections::BTreeMap;
use std::path::Path;

mod common;

use common::gltf::*;

use glam::Vec3A;
use serde_json::{json, Value};
use tessera_render::light::LightShape;
use tessera_render::scene::assets::MemAssets;
use tessera_render::scene::{gltf_scene_text, Format, GltfOptions, Limits, Scene};
use tessera_render::shape::Shape;

const SAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/gltf/sample.glb");

fn mesh_bounds(scene: &Scene) -> Vec<(Vec3A, Vec3A)> {
    scene
        .prims
        .iter()
        .map(|p| {
            let b = p.shape.bounds();
            (b.min, b.max)
        })
        .collect()
}

#[test]
fn the_sample_scene_reads_its_camera_lights_materials_and_instances() {
    let scene = Scene::file(Path::new(SAMPLE), &Limits::default())
        .load()
        .expect("sample.glb loads");
    assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
    // 16:9 from the camera's aspect ratio.
    assert_eq!((scene.width, scene.height), (1280, 720));
    // Floor, two placements of one gold ball, the glass ball and the box.
    assert_eq!(scene.prims.len(), 5);
    let meshes: Vec<_> = scene
        .prims
        .iter()
        .filter_map(|p| match &p.shape {
            Shape::Mesh(m) => Some(m.mesh.clone()),
            _ => None,
        })
        .collect();
    assert!(
        std::sync::Arc::ptr_eq(&meshes[1], &meshes[2]),
        "one BVH, placed twice"
    );
    assert!(!std::sync::Arc::ptr_eq(&meshes[1], &meshes[3]));
    let kinds: Vec<&str> = scene
        .lights
        .lights
        .iter()
        .map(|l| match l.shape {
            LightShape::Point { .. } => "point",
            LightShape::Directional { .. } => "directional",
            _ => "other",
        })
        .collect();
    assert_eq!(kinds, ["directional", "point"]);
    // The lamp node sits at (-2, 2.5, 2) and shines 12 × its colour.
    let point = &scene.lights.lights[1];
    assert!(
        matches!(point.shape, LightShape::Point { position } if position == Vec3A::new(-2.0, 2.5, 2.0))
    );
    assert!(
        near(point.radiance, Vec3A::new(12.0, 10.8, 9.6)),
        "{}",
        point.radiance
    );
    // The camera's node: at (0, 2.2, 6.2), looking down 18°; the middle ray starts on the
    // near plane, znear = 0.1 along it.
    let ray = scene.camera.ray(640.0, 360.0);
    assert!(
        (ray.o - Vec3A::new(0.0, 2.2, 6.2) - ray.d.normalize() * 0.1).length() < 1e-5,
        "{:?}",
        ray.o
    );
    let down = (-ray.d.normalize().y).asin().to_degrees();
    assert!((down - 18.0).abs() < 0.1, "{down}");
    // The glass is refracting glass with its volume's attenuation.
    assert!(scene.has_absorption());
    // The file is one asset, and the scene's identity covers it.
    assert_eq!(scene.files.len(), 1);
    assert_eq!(scene.files[0].0, "sample.glb");
}

#[test]
fn the_farm_builds_the_same_scene_from_the_text_and_the_uploaded_file() {
    let local = Scene::file(Path::new(SAMPLE), &Limits::default())
        .load()
        .expect("loads");
    let bytes = std::fs::read(SAMPLE).expect("read");
    let text = gltf_scene_text("sample.glb", &bytes, &GltfOptions::default());
    let files = MemAssets(BTreeMap::from([("sample.glb".to_string(), bytes)]));
    let farm = Scene::text(&text, Format::Toml, "job", &Limits::default())
        .at(1)
        .assets(&files)
        .load()
        .expect("loads from memory");
    assert_eq!(farm.hash, local.hash);
    assert_eq!(mesh_bounds(&farm), mesh_bounds(&local));
}

#[test]
fn node_trees_place_meshes_and_a_shared_mesh_is_one_bvh() {
    let extra = json!({
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {"children": [1, 2], "translation": [10, 0, 0], "scale": [2, 2, 2]},
            {"mesh": 0, "translation": [0, 0, 1]},
            // A column-major matrix: a quarter turn about z, then up 5.
            {"mesh": 0, "matrix": [0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1, 0, 0, 5, 0, 1]},
        ],
    });
    let scene = load(
        &triangle_doc(&QUAD, &[0, 1, 2, 0, 2, 3], extra),
        &GltfOptions::default(),
    )
    .expect("ok");
    let b = mesh_bounds(&scene);
    assert_eq!(b.len(), 2);
    assert!(
        near(b[0].0, Vec3A::new(10.0, 0.0, 2.0)) && near(b[0].1, Vec3A::new(12.0, 2.0, 2.0)),
        "{b:?}"
    );
    let (lo, hi) = b[1];
    assert!(
        near(lo, Vec3A::new(8.0, 10.0, 0.0)) && near(hi, Vec3A::new(10.0, 12.0, 0.0)),
        "{lo} {hi}"
    );
    match (&scene.prims[0].shape, &scene.prims[1].shape) {
        (Shape::Mesh(a), Shape::Mesh(b)) => assert!(std::sync::Arc::ptr_eq(&a.mesh, &b.mesh)),
        _ => panic!("meshes"),
    }
}

#[test]
fn a_cycle_or_a_node_with_two_parents_is_refused_not_walked_forever() {
    for nodes in [
        json!([{"children": [1]}, {"children": [0], "mesh": 0}]),
        json!([{"children": [2]}, {"children": [2]}, {"mesh": 0}]),
    ] {
        let extra = json!({"scenes": [{"nodes": [0, 1]}], "nodes": nodes});
        let e = load(
            &triangle_doc(&QUAD, &[0, 1, 2], extra),
            &GltfOptions::default(),
        )
        .expect_err("refused");
        assert!(e.contains("is reached twice"), "{e}");
    }
}

#[test]
fn quantized_and_sparse_positions_read_as_the_floats_they_stand_for() {
    // KHR_mesh_quantization: i16 positions, normalized, scaled back by the node.
    let q: [i16; 12] = [0, 0, 0, 32767, 0, 0, 32767, 32767, 0, 0, 32767, 0];
    let mut buf: Vec<u8> = q.iter().flat_map(|x| x.to_le_bytes()).collect();
    // Sparse: vertex 2 replaced by (2, 2, 0) in f32... of an i16 accessor, so as i16 codes.
    let sparse_at = buf.len();
    buf.extend(2u16.to_le_bytes());
    buf.extend([0u8; 2]);
    let values_at = buf.len();
    for c in [16384i16, 16384, 0] {
        buf.extend(c.to_le_bytes());
    }
    let gltf = doc(
        &buf,
        json!({
            "extensionsUsed": ["KHR_mesh_quantization"],
            "extensionsRequired": ["KHR_mesh_quantization"],
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0, "scale": [4, 4, 4]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 24},
                {"buffer": 0, "byteOffset": sparse_at, "byteLength": 2},
                {"buffer": 0, "byteOffset": values_at, "byteLength": 6},
            ],
            "accessors": [{
                "bufferView": 0, "componentType": 5122, "normalized": true, "count": 3,
                "type": "VEC3", "min": [0, 0, 0], "max": [32767, 32767, 0],
                "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5123},
                           "values": {"bufferView": 2}},
            }],
        }),
    );
    let scene = load(&gltf, &GltfOptions::default()).expect("ok");
    let (lo, hi) = mesh_bounds(&scene)[0];
    assert!(near(lo, Vec3A::ZERO), "{lo}");
    // (1, 0, 0) × 4 and the sparse (0.5, 0.5, 0) × 4.
    assert!(near(hi, Vec3A::new(4.0, 2.0, 0.0)), "{hi}");
}

#[test]
fn strips_and_fans_become_triangles_facing_one_way() {
    // The quad's corners as a strip (0 1 3 2) and as a fan (0 1 2 3): two triangles each,
    // both facing +z like the list's one.
    for (mode, indices, count) in [
        (5, [0, 1, 3, 2], 2),
        (6, [0, 1, 2, 3], 2),
        (4, [0, 1, 2, 3], 1),
    ] {
        let mut gltf = triangle_doc(&QUAD, &indices, json!({}));
        gltf["meshes"][0]["primitives"][0]["mode"] = json!(mode);
        let scene = load(&gltf, &GltfOptions::default()).expect("ok");
        let Shape::Mesh(m) = &scene.prims[0].shape else {
            panic!("a mesh")
        };
        assert_eq!(m.mesh.len(), count, "mode {mode}");
        for (_, n, area) in m.world_triangles() {
            assert!(
                n.z > 0.0 && area > 0.0,
                "mode {mode}: every triangle faces +z, got {n}"
            );
        }
    }
}

#[test]
fn points_and_lines_are_skipped_with_a_warning() {
    let mut gltf = triangle_doc(&QUAD, &[0, 1, 2, 0, 2, 3], json!({}));
    let prim = gltf["meshes"][0]["primitives"][0].clone();
    let mut line = prim.clone();
    line["mode"] = json!(1);
    gltf["meshes"][0]["primitives"] = json!([prim, line]);
    let scene = load(&gltf, &GltfOptions::default()).expect("ok");
    assert_eq!(scene.prims.len(), 1);
    assert!(
        scene.warnings.iter().any(|w| w.contains("points or lines")),
        "{:?}",
        scene.warnings
    );
}

// Long because it is a table of cases, one refusal each, read top to bottom.
#[test]
fn bad_files_are_refused_with_one_line_naming_the_place() {
    let good = triangle_doc(&QUAD, &[0, 1, 2], json!({}));
    let cases: Vec<(Value, &str)> = vec![
        (
            {
                let mut g = good.clone();
                g["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]);
                g["extensionsUsed"] = json!(["KHR_draco_mesh_compression"]);
                g
            },
            "decompress it first",
        ),
        (
            {
                let mut g = good.clone();
                g["extensionsRequired"] = json!(["EXT_unheard_of"]);
                g["extensionsUsed"] = json!(["EXT_unheard_of"]);
                g
            },
            "requires the extension EXT_unheard_of",
        ),
        (
            {
                let mut g = good.clone();
                g["accessors"][0]["count"] = json!(1000);
                g
            },
            "run past the end of buffer view 0",
        ),
        (
            {
                let mut g = good.clone();
                g["bufferViews"][0]["byteLength"] = json!(1 << 30);
                g
            },
            "covers bytes",
        ),
        (
            {
                let mut g = good.clone();
                g["meshes"][0]["primitives"][0]["indices"] = json!(7);
                g
            },
            "indices",
        ),
        (
            {
                let mut g = good.clone();
                g["nodes"][0]["scale"] = json!([1, 1, f32::MAX]);
                g["nodes"][0]["translation"] = json!([0, 0, 0]);
                g["nodes"][0]["rotation"] = json!([0, 0, 0, 1]);
                g
            },
            "",
        ),
        (
            triangle_doc(&QUAD, &[0, 1, 9], json!({})),
            "index 9 is past the 4 vertices",
        ),
        (
            {
                // The bounds in the JSON are finite (JSON has no infinity); the data is not.
                let mut g = triangle_doc(
                    &[0., 0., 0., 1., 0., 0., f32::INFINITY, 1., 0.],
                    &[0, 1, 2],
                    json!({}),
                );
                g["accessors"][0]["max"] = json!([1, 1, 0]);
                g
            },
            "/meshes/0/primitives/0/attributes/POSITION: vertex 2 is not finite",
        ),
        // Found by the gltf_load fuzz target: the gltf crate unwraps both (its validation
        // does not check them), so they are read from the JSON.
        (
            {
                let mut g = good.clone();
                g["meshes"][0]["primitives"][0]["material"] = json!(0);
                g["materials"] =
                    json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
                g["textures"] = json!([{"source": 0}]);
                g["images"] = json!([{"name": "nothing"}]);
                g
            },
            "/images/0: has neither a bufferView nor a uri",
        ),
        (
            {
                let mut g = good.clone();
                g["nodes"] = json!([{"mesh": 0}, {"camera": 0}]);
                g["scenes"] = json!([{"nodes": [0, 1]}]);
                g["cameras"] = json!([{"type": "perspective", "orthographic": {"xmag": 1, "ymag": 1, "znear": 0.1, "zfar": 9}}]);
                g
            },
            "/cameras/0: its type's values",
        ),
        (
            {
                let mut g = good.clone();
                g["nodes"] = json!([{"mesh": 0}, {"camera": 0}]);
                g["scenes"] = json!([{"nodes": [0, 1]}]);
                g["cameras"] =
                    json!([{"type": "perspective", "perspective": {"yfov": 4.0, "znear": 0.1}}]);
                g
            },
            "/cameras/0: yfov 4 is out of range",
        ),
        (
            {
                let mut g = good.clone();
                g["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(9);
                g
            },
            "/meshes/0/primitives/0/attributes/POSITION: accessor 9 does not exist",
        ),
        (json!({"asset": {"version": "1.0"}}), "glTF 2.0"),
        (
            json!({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 4, "uri": "gone.bin"}]}),
            "/buffers/0/uri: cannot read `gone.bin`",
        ),
    ];
    for (gltf, want) in cases {
        match load(&gltf, &GltfOptions::default()) {
            Err(e) => {
                assert!(e.contains(want), "{e}\n  should say {want:?}");
                assert!(!e.contains('\n'), "one line: {e}");
                assert!(e.starts_with("model.gltf: "), "{e}");
            }
            Ok(_) if want.is_empty() => {}
            Ok(_) => panic!("loaded; should fail with {want:?}"),
        }
    }
    // The same file as an object of a scene file: the error is placed at the key naming the
    // file, and says where in the file.
    let mut bad = good.clone();
    bad["extensionsRequired"] = json!(["EXT_unheard_of"]);
    bad["extensionsUsed"] = json!(["EXT_unheard_of"]);
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(
        dir.path().join("model.gltf"),
        serde_json::to_vec(&bad).expect("json"),
    )
    .expect("write the glTF file");
    let scene = "version = 1\n[camera]\nmodel = \"gltf\"\n\n[film]\nwidth = 8\nheight = 8\n\n\
                 [[objects]]\nshape = \"gltf\"\nfile = \"model.gltf\"\n";
    std::fs::write(dir.path().join("s.toml"), scene).expect("write the scene file");
    let e = Scene::file(&dir.path().join("s.toml"), &Limits::default())
        .load()
        .expect_err("refused")
        .to_string();
    let dir_prefix = format!("{}/", dir.path().display());
    let e = e.strip_prefix(&dir_prefix).unwrap_or(&e);
    assert_eq!(
        e,
        "s.toml:11:8: objects[0].file: model.gltf: /extensionsRequired/0: requires the \
         extension EXT_unheard_of, which tessera does not read"
    );
    // A GLB whose header lies.
    let mut glb = b"glTF".to_vec();
    glb.extend(2u32.to_le_bytes());
    glb.extend(u32::MAX.to_le_bytes());
    let e =
        load_file("m.glb", &glb, &GltfOptions::default(), &Limits::default()).expect_err("refused");
    assert!(e.starts_with("m.glb: the GLB header gives a length"), "{e}");
}

#[test]
fn the_triangle_limit_counts_gltf_meshes() {
    let gltf = triangle_doc(&QUAD, &[0, 1, 2, 0, 2, 3], json!({}));
    let bytes = serde_json::to_vec(&gltf).expect("ok");
    let limits = Limits {
        max_triangles: 1,
        ..Limits::default()
    };
    let e = load_file("model.gltf", &bytes, &GltfOptions::default(), &limits).expect_err("refused");
    assert!(
        e.contains("above what is left of the scene's limit of 1"),
        "{e}"
    );
}

/// An instance bomb: a mesh of 1,000 primitives (one small accessor each, all the same) under
/// 2,000 nodes is two million placed shapes from a file of a few tens of kilobytes. It is
/// refused from the JSON's counts, before a shape is built (it once took the coordinator past
/// 900 MiB); the same tree under a lower limit fits, and a declared triangle count above the
/// limit is refused before its buffer is read.
#[test]
fn the_node_tree_is_counted_before_anything_is_built() {
    let bomb = |nodes: usize, prims: usize| {
        let primitives: Vec<Value> = (0..prims)
            .map(|_| json!({"attributes": {"POSITION": 0}, "indices": 1}))
            .collect();
        let node_list: Vec<Value> = (0..nodes).map(|_| json!({"mesh": 0})).collect();
        let roots: Vec<usize> = (0..nodes).collect();
        triangle_doc(
            &QUAD,
            &[0, 1, 2, 0, 2, 3],
            json!({"scenes": [{"nodes": roots}], "nodes": node_list, "meshes": [{"primitives": primitives}]}),
        )
    };
    let bytes = serde_json::to_vec(&bomb(2000, 1000)).expect("ok");
    assert!(bytes.len() < 200_000, "{} bytes", bytes.len());
    let e = load_file(
        "bomb.gltf",
        &bytes,
        &GltfOptions::default(),
        &Limits::default(),
    )
    .expect_err("refused");
    assert!(
        e.contains("places 2000000 shapes, above the scene's limit of 1048576 placed shapes"),
        "{e}"
    );
    let small = serde_json::to_vec(&bomb(20, 10)).expect("ok");
    let limits = Limits {
        max_instances: 200,
        ..Limits::default()
    };
    let scene = load_file("ok.gltf", &small, &GltfOptions::default(), &limits).expect("fits");
    assert_eq!(scene.prims.len(), 200);
    let limits = Limits {
        max_instances: 199,
        ..Limits::default()
    };
    let e = load_file("ok.gltf", &small, &GltfOptions::default(), &limits).expect_err("refused");
    assert!(e.contains("places 200 shapes"), "{e}");
    // A declared count is enough to refuse: the accessor claims 3·10⁹ indices.
    let mut huge = bomb(1, 1);
    huge["accessors"][1]["count"] = json!(3_000_000_000u64);
    let bytes = serde_json::to_vec(&huge).expect("ok");
    let e = load_file(
        "huge.gltf",
        &bytes,
        &GltfOptions::default(),
        &Limits::default(),
    )
    .expect_err("refused");
    assert!(e.contains("declares 1000000000 triangles"), "{e}");
}

#[test]
fn cameras_are_picked_by_name_or_index_and_framed_without_one() {
    let cams = json!({
        "scenes": [{"nodes": [0, 1, 2, 3]}],
        "nodes": [
            {"mesh": 0},
            {"camera": 1, "translation": [0, 0, 5]},
            {"camera": 0, "translation": [0, 0, 9]},
            {"camera": 2, "translation": [0, 0, 7]},
        ],
        "cameras": [
            {"name": "far", "type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1, "aspectRatio": 2.0}},
            {"name": "near", "type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1}},
            {"name": "flat", "type": "orthographic", "orthographic": {"xmag": 1, "ymag": 1, "znear": 0.1, "zfar": 10}},
        ],
    });
    let gltf = triangle_doc(&QUAD, &[0, 1, 2, 0, 2, 3], cams);
    // Every camera looks down −z, and its rays start on its near plane, znear = 0.1 ahead:
    // the eye is that much behind.
    let eye = |s: &Scene| {
        let o = s.camera.ray(0.5 * s.width as f32, 0.5 * s.height as f32).o;
        ((o.z + 0.1) * 1000.0).round() / 1000.0
    };
    // The lowest index by default, with its aspect ratio.
    let s = load(&gltf, &GltfOptions::default()).expect("ok");
    assert_eq!((eye(&s), s.width, s.height), (9.0, 1280, 640));
    let by = |c: &str| {
        load(
            &gltf,
            &GltfOptions {
                camera: Some(c.into()),
                environment: None,
            },
        )
    };
    assert_eq!(eye(&by("near").expect("ok")), 5.0);
    assert_eq!(eye(&by("1").expect("ok")), 5.0);
    let e = by("nowhere").expect_err("refused");
    assert!(
        e.contains("no glTF camera is named \"nowhere\"") && e.contains("1 (\"near\")"),
        "{e}"
    );
    // Orthographic: parallel rays along the node's −z, the film 2·ymag high (1280 × 1280 for
    // xmag = ymag = 1).
    let flat = by("flat").expect("ok");
    assert_eq!((flat.width, flat.height), (1280, 1280));
    let (a, b) = (flat.camera.ray(0.0, 0.0), flat.camera.ray(1280.0, 1280.0));
    assert_eq!((a.d, b.d), (Vec3A::NEG_Z, Vec3A::NEG_Z));
    assert!(
        near(a.o, Vec3A::new(-1.0, 1.0, 6.9)) && near(b.o, Vec3A::new(1.0, -1.0, 6.9)),
        "{} {}",
        a.o,
        b.o
    );
    // No camera: the quad is framed from +z, whole.
    let plain = triangle_doc(&QUAD, &[0, 1, 2, 0, 2, 3], json!({}));
    let s = load(&plain, &GltfOptions::default()).expect("ok");
    assert_eq!((s.width, s.height), (1280, 720));
    for (x, y) in [(0.0, 0.0), (1280.0, 720.0)] {
        let r = s.camera.ray(x, y);
        let t = -r.o.z / r.d.z;
        let p = r.o + t * r.d;
        assert!(
            !(0.0..=1.0).contains(&p.x) || !(0.0..=1.0).contains(&p.y),
            "corner ray {p} inside the quad"
        );
    }
    let mid = s.camera.ray(640.0, 360.0);
    assert!(
        s.intersect(&mid, f32::INFINITY).is_some(),
        "the middle ray sees the quad"
    );
}

#[test]
fn an_unlit_file_gets_a_white_sky_and_a_lit_one_its_own_light_in_photometric_units() {
    let plain = triangle_doc(&QUAD, &[0, 1, 2], json!({}));
    let s = load(&plain, &GltfOptions::default()).expect("ok");
    assert!(s.environment.is_some() && s.lights.lights.is_empty());
    let lit = triangle_doc(
        &QUAD,
        &[0, 1, 2],
        json!({
            "extensionsUsed": ["KHR_lights_punctual"],
            "scenes": [{"nodes": [0, 1]}],
            "nodes": [{"mesh": 0}, {"extensions": {"KHR_lights_punctual": {"light": 0}},
                                    "translation": [0, 0, 2], "rotation": [std::f32::consts::FRAC_1_SQRT_2, 0, 0, std::f32::consts::FRAC_1_SQRT_2]}],
            "extensions": {"KHR_lights_punctual": {"lights": [
                // 3 W/sr in candela (683 lm/W, as Blender converts).
                {"type": "spot", "intensity": 3 * 683, "color": [1, 0.5, 0.25],
                 "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.4}}]}},
        }),
    );
    let s = load(&lit, &GltfOptions::default()).expect("ok");
    assert!(s.environment.is_none());
    let l = &s.lights.lights[0];
    assert_eq!(l.radiance, Vec3A::new(3.0, 1.5, 0.75));
    match l.shape {
        // A quarter turn about +x takes the light's −z to +y.
        LightShape::Spot { position, axis, .. } => {
            assert_eq!(position, Vec3A::new(0.0, 0.0, 2.0));
            assert!((axis - Vec3A::Y).length() < 1e-5, "{axis}");
        }
        _ => panic!("a spot"),
    }
    // Lux, as Blender writes a sun: 683 lux is 1 W/m².
    let mut sun = lit.clone();
    sun["extensions"]["KHR_lights_punctual"]["lights"][0] =
        json!({"type": "directional", "intensity": 2 * 683, "color": [1, 0.5, 0.25]});
    let s = load(&sun, &GltfOptions::default()).expect("ok");
    assert_eq!(s.lights.lights[0].radiance, Vec3A::new(2.0, 1.0, 0.5));
    // A cone whose outer angle is not past its inner one is refused, naming the light.
    let mut bad = lit.clone();
    bad["extensions"]["KHR_lights_punctual"]["lights"][0]["spot"]["outerConeAngle"] = json!(0.1);
    let e = load(&bad, &GltfOptions::default()).expect_err("refused");
    assert!(
        e.contains("model.gltf: /extensions/KHR_lights_punctual/lights/0/spot/outerConeAngle: "),
        "{e}"
    );
}

/// A missing texture is named once, at the image that names it (a JSON pointer), with the
/// path it was looked for at (the error once said `materials[0]:
/// materials[0].baseColorTexture: …` and only the file's own name).
#[test]
fn a_missing_texture_is_named_once_with_the_path_it_was_looked_for_at() {
    let mut gltf = textured_quad_doc(
        &[0; 4],
        json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
            "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
            "textures": [{"source": 0}],
        }),
    );
    gltf["images"] = json!([{"uri": "tex/missing.png"}]);
    let e = load(&gltf, &GltfOptions::default()).expect_err("missing");
    assert!(!e.contains("materials"), "{e}");
    assert!(
        e.contains("model.gltf: /images/0/uri: cannot read `tex/missing.png` (")
            && e.contains("/tex/missing.png): "),
        "{e}"
    );
}
