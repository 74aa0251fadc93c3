//! glTF 2.0 files as scenes and as scene objects: what is read (node trees, instancing,
//! quantized and sparse accessors, strips and fans, texture transforms and samplers, cameras,
//! punctual lights, materials) and what is refused, each with one line naming the place.

use std::collections::BTreeMap;
use std::path::Path;

mod common;

use base64::Engine as _;
use glam::Vec3A;
use serde_json::{json, Value};
use tessera_render::light::LightShape;
use tessera_render::scene::assets::MemAssets;
use tessera_render::scene::{gltf_scene_text, Format, GltfOptions, Limits, Scene};
use tessera_render::shape::Shape;

const SAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/gltf/sample.glb");

/// A glTF document around one buffer, given as a data URI.
fn doc(buffer: &[u8], mut body: Value) -> Value {
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(buffer)
    );
    body["asset"] = json!({"version": "2.0"});
    body["buffers"] = json!([{"byteLength": buffer.len(), "uri": uri}]);
    body
}

fn f32s(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// One triangle mesh of `positions` (and `indices`, u16, after them in the buffer), one node.
fn triangle_doc(positions: &[f32], indices: &[u16], extra: Value) -> Value {
    let mut buf = f32s(positions);
    let at = buf.len();
    buf.extend(indices.iter().flat_map(|i| i.to_le_bytes()));
    let n = positions.len() / 3;
    let mut min = [f32::MAX; 3];
    let mut max = [f32::MIN; 3];
    for p in positions.chunks(3) {
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    let mut body = json!({
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": at},
            {"buffer": 0, "byteOffset": at, "byteLength": indices.len() * 2},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3", "min": min, "max": max},
            {"bufferView": 1, "componentType": 5123, "count": indices.len(), "type": "SCALAR"},
        ],
    });
    if let (Value::Object(b), Value::Object(e)) = (&mut body, extra) {
        for (k, v) in e {
            b.insert(k, v);
        }
    }
    doc(&buf, body)
}

/// A document whose buffer holds the quad (accessors 0 to 2: positions, texture coordinates
/// with v = 0 at the top of the image, indices) and `png` (image 0), around `body`, which
/// gives the scene, meshes, materials, textures and samplers.
fn textured_quad_doc(png: &[u8], mut body: Value) -> Value {
    let mut buf = f32s(&QUAD);
    let uv_at = buf.len();
    buf.extend(f32s(&[0., 1., 1., 1., 1., 0., 0., 0.]));
    let idx_at = buf.len();
    buf.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
    let img_at = buf.len();
    buf.extend(png);
    body["images"] = json!([{"bufferView": 3, "mimeType": "image/png"}]);
    body["bufferViews"] = json!([
        {"buffer": 0, "byteOffset": 0, "byteLength": 48},
        {"buffer": 0, "byteOffset": uv_at, "byteLength": 32},
        {"buffer": 0, "byteOffset": idx_at, "byteLength": 12},
        {"buffer": 0, "byteOffset": img_at, "byteLength": png.len()},
    ]);
    body["accessors"] = json!([
        {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
        {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
    ]);
    doc(&buf, body)
}

/// Loads `bytes` as the whole scene of a file named `name`, as `tessera render` does; the
/// error is what it prints, without the directory.
fn load_file(
    name: &str,
    bytes: &[u8],
    opts: &GltfOptions,
    limits: &Limits,
) -> Result<Scene, String> {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).expect("write");
    Scene::load_with(&path, opts, limits, 1).map_err(|e| {
        let e = e.to_string();
        e.strip_prefix(&format!("{}/", dir.path().display()))
            .unwrap_or(&e)
            .to_string()
    })
}

/// Loads `gltf` as the whole scene of a file named `model.gltf`.
fn load(gltf: &Value, opts: &GltfOptions) -> Result<Scene, String> {
    let bytes = serde_json::to_vec(gltf).expect("json");
    load_file("model.gltf", &bytes, opts, &Limits::default())
}

fn near(a: Vec3A, b: Vec3A) -> bool {
    (a - b).length() < 1e-4 * (1.0 + b.length())
}

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

const QUAD: [f32; 12] = [0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.];

#[test]
fn the_sample_scene_reads_its_camera_lights_materials_and_instances() {
    let scene = Scene::load(Path::new(SAMPLE), &Limits::default()).expect("sample.glb loads");
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
    // The camera's node: at (0, 2.2, 6.2), looking down 18°.
    let ray = scene.camera.ray(640.0, 360.0);
    assert!(
        (ray.o - Vec3A::new(0.0, 2.2, 6.2)).length() < 1e-5,
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
    let local = Scene::load(Path::new(SAMPLE), &Limits::default()).expect("loads");
    let bytes = std::fs::read(SAMPLE).expect("read");
    let text = gltf_scene_text("sample.glb", &bytes, &GltfOptions::default());
    let files = MemAssets(BTreeMap::from([("sample.glb".to_string(), bytes)]));
    let farm = Scene::from_str_with(&text, Format::Toml, "job", &Limits::default(), 1, &files)
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
            "POSITION: vertex 2 is not finite",
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
            "images[0] has neither a bufferView nor a uri",
        ),
        (
            {
                let mut g = good.clone();
                g["nodes"] = json!([{"mesh": 0}, {"camera": 0}]);
                g["scenes"] = json!([{"nodes": [0, 1]}]);
                g["cameras"] = json!([{"type": "perspective", "orthographic": {"xmag": 1, "ymag": 1, "znear": 0.1, "zfar": 9}}]);
                g
            },
            "cameras[0]: its type's values",
        ),
        (
            {
                let mut g = good.clone();
                g["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(9);
                g
            },
            "accessor 9 does not exist",
        ),
        (json!({"asset": {"version": "1.0"}}), "glTF 2.0"),
        (
            json!({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 4, "uri": "gone.bin"}]}),
            "buffers[0]: cannot read `gone.bin`",
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
    let eye = |s: &Scene| {
        s.camera
            .ray(0.5 * s.width as f32, 0.5 * s.height as f32)
            .o
            .z
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
        near(a.o, Vec3A::new(-1.0, 1.0, 7.0)) && near(b.o, Vec3A::new(1.0, -1.0, 7.0)),
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
fn an_unlit_file_gets_a_white_sky_and_a_lit_one_its_own_light() {
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
                {"type": "spot", "intensity": 3, "color": [1, 0.5, 0.25],
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
    // A cone whose outer angle is not past its inner one is refused, naming the light.
    let mut bad = lit.clone();
    bad["extensions"]["KHR_lights_punctual"]["lights"][0]["spot"]["outerConeAngle"] = json!(0.1);
    let e = load(&bad, &GltfOptions::default()).expect_err("refused");
    assert!(
        e.contains("KHR_lights_punctual.lights[0].outer_angle"),
        "{e}"
    );
}

#[test]
fn texture_transforms_and_samplers_shape_the_coordinates() {
    // One texel row: a 4 × 1 PNG, two black then two white; the quad's u runs 0..1.
    let png = common::png_rgb(4, 1, &[[0u8; 3], [0; 3], [255; 3], [255; 3]].concat());
    let make = |transform: Value, wrap: u32| {
        textured_quad_doc(
            &png,
            json!({
                "extensionsUsed": ["KHR_texture_transform"],
                "scenes": [{"nodes": [0]}],
                "nodes": [{"mesh": 0}],
                "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
                "materials": [{"pbrMetallicRoughness": {"metallicFactor": 0, "baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": transform}}}}],
                "textures": [{"source": 0, "sampler": 0}],
                "samplers": [{"wrapS": wrap, "wrapT": wrap}],
            }),
        )
    };
    // The base colour seen at quad point x (y = 0.5), through the scene's texture.
    let seen = |gltf: &Value, x: f32| {
        let s = load(gltf, &GltfOptions::default()).expect("ok");
        let Shape::Mesh(m) = &s.prims[0].shape else {
            panic!()
        };
        let ray = tessera_render::util::math::Ray::new(Vec3A::new(x, 0.5, 1.0), Vec3A::NEG_Z);
        let (_, tri) = m.intersect(&ray, f32::INFINITY).expect("hit");
        let frame = m.uv_frame(&ray, tri).expect("uvs");
        s.textures[0].lookup(frame.uv).x
    };
    const REPEAT: u32 = 10497;
    const CLAMP: u32 = 33071;
    // Untransformed: dark at the left, bright at the right.
    let plain = make(json!({}), REPEAT);
    assert!(seen(&plain, 0.3) < 0.01 && seen(&plain, 0.8) > 0.99);
    // Offset by half a texture: swapped, when repeating.
    let shifted = make(json!({"offset": [0.5, 0]}), REPEAT);
    assert!(seen(&shifted, 0.3) > 0.99 && seen(&shifted, 0.8) < 0.01);
    // Clamped, the shifted right half reads the edge texel: bright.
    let clamped = make(json!({"offset": [0.5, 0]}), CLAMP);
    assert!(seen(&clamped, 0.8) > 0.99);
    // A half turn about the origin takes u to −u: repeating, the left is bright.
    let turned = make(json!({"rotation": std::f32::consts::PI}), REPEAT);
    assert!(seen(&turned, 0.3) > 0.99, "{}", seen(&turned, 0.3));
}

#[test]
fn materials_map_replaces_a_file_material_by_name() {
    let gltf = triangle_doc(
        &QUAD,
        &[0, 1, 2],
        json!({
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
            "materials": [{"name": "paint"}],
        }),
    );
    let bytes = serde_json::to_vec(&gltf).expect("ok");
    let scene = |map: &str| {
        let text = format!(
            "version = 1\n[camera]\nmodel = \"gltf\"\n[film]\nwidth = 8\nheight = 8\n\
             [materials.red]\ntype = \"diffuse\"\nalbedo = [0.8, 0.1, 0.1]\n\
             [[objects]]\nshape = \"gltf\"\nfile = \"m.gltf\"\n{map}"
        );
        let files = MemAssets(BTreeMap::from([("m.gltf".to_string(), bytes.clone())]));
        Scene::from_str_with(&text, Format::Toml, "s.toml", &Limits::default(), 1, &files)
    };
    let s = scene("materials_override = { paint = \"red\" }").expect("ok");
    assert_eq!(s.prims[0].material, 0, "the scene's `red`");
    let e = scene("materials_map = { paint = \"blue\" }")
        .expect_err("refused")
        .to_string();
    assert!(e.contains("material `blue` is not defined"), "{e}");
    let e = scene("materials_map = { chrome = \"red\" }")
        .expect_err("refused")
        .to_string();
    assert!(
        e.contains("has no material of") && e.contains("it has: paint"),
        "{e}"
    );
    let e = scene("material = \"red\"")
        .expect_err("refused")
        .to_string();
    assert!(
        e.contains("objects[0].material") && e.contains("materials_map"),
        "{e}"
    );
}

/// A front quad of `material` (z = 1) over a back quad (z = 0), both x, y in [0, 1].
fn two_quads(material: Value, png: &[u8]) -> Value {
    let prim = |m: u32| json!({"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": m});
    textured_quad_doc(
        png,
        json!({
            "scenes": [{"nodes": [0, 1]}],
            "nodes": [{"mesh": 0, "translation": [0, 0, 1]}, {"mesh": 1}],
            "meshes": [{"primitives": [prim(0)]}, {"primitives": [prim(1)]}],
            "materials": [material, {"name": "back"}],
            "textures": [{"source": 0, "sampler": 0}],
            "samplers": [{"wrapS": 33071, "wrapT": 33071}],
        }),
    )
}

#[test]
fn alpha_masked_surfaces_are_passed_through_by_every_ray() {
    // Four texels across u: alpha 0, 0, 1, 1 (the colour is white throughout).
    let png = common::png_rgba(
        4,
        1,
        &[
            [255u8, 255, 255, 0],
            [255, 255, 255, 0],
            [255, 255, 255, 255],
            [255, 255, 255, 255],
        ]
        .concat(),
    );
    let mask =
        json!({"alphaMode": "MASK", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}});
    let s = load(&two_quads(mask, &png), &GltfOptions::default()).expect("ok");
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let down = |x: f32| tessera_render::util::math::Ray::new(Vec3A::new(x, 0.5, 3.0), Vec3A::NEG_Z);
    // Through the cut-out half to the back quad (z = 0, t = 3); on the kept half, the front
    // quad (t = 2), with its t along the original ray either way.
    let cut = s
        .intersect(&down(0.2), f32::INFINITY)
        .expect("the back quad");
    assert!((cut.t - 3.0).abs() < 1e-5 && cut.prim == 1, "{cut:?}");
    let kept = s
        .intersect(&down(0.8), f32::INFINITY)
        .expect("the front quad");
    assert!((kept.t - 2.0).abs() < 1e-5 && kept.prim == 0, "{kept:?}");
    // Shadow rays: blocked by the kept half only (stopping short of the back quad).
    assert!(!s.occluded(&down(0.2), 2.5));
    assert!(s.occluded(&down(0.8), 2.5));
    // The same file opaque: the front quad everywhere.
    let opaque = json!({"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}});
    let s = load(&two_quads(opaque, &png), &GltfOptions::default()).expect("ok");
    assert_eq!(s.intersect(&down(0.2), f32::INFINITY).expect("hit").prim, 0);
}

#[test]
fn alpha_blended_surfaces_are_met_with_their_alpha_as_probability_and_the_same_bits() {
    let png = common::png_rgba(1, 1, &[255, 255, 255, 255]);
    let blend = json!({"alphaMode": "BLEND", "pbrMetallicRoughness": {
        "baseColorFactor": [1, 1, 1, 0.25], "baseColorTexture": {"index": 0}}});
    let s = load(&two_quads(blend, &png), &GltfOptions::default()).expect("ok");
    let n = 20_000;
    let mut front = 0;
    let mut rng = tessera_render::sampling::HashRng::new(9);
    for _ in 0..n {
        let (x, y) = (rng.next_f32(), rng.next_f32());
        let ray = tessera_render::util::math::Ray::new(Vec3A::new(x, y, 3.0), Vec3A::NEG_Z);
        let hit = s.intersect(&ray, f32::INFINITY).expect("one of the quads");
        // The same ray meets the same surface every time.
        assert_eq!(
            s.intersect(&ray, f32::INFINITY).expect("hit").prim,
            hit.prim
        );
        front += usize::from(hit.prim == 0);
    }
    // Binomial(20000, 0.25): standard deviation 61; 5σ either side.
    let want = n as f64 * 0.25;
    eprintln!("{front} of {n} rays met the blended quad");
    assert!(
        (front as f64 - want).abs() < 5.0 * (want * 0.75).sqrt(),
        "{front} of {n}"
    );
}

/// A glTF emitter (the quad, double-sided, `emissiveFactor` 2 × `emissiveTexture`) placed
/// facing down at y = 1 over a diffuse floor, seen from the side, as a TOML scene.
fn emitter_scene(png: &[u8]) -> Scene {
    let gltf = textured_quad_doc(
        png,
        json!({
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
            "materials": [{"doubleSided": true, "emissiveFactor": [2, 2, 2], "emissiveTexture": {"index": 0},
                           "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0}}],
            "textures": [{"source": 0, "sampler": 0}],
            "samplers": [{"wrapS": 33071, "wrapT": 33071}],
        }),
    );
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0.5, 0.5, 3]\n\
                target = [0.5, 0, 0.5]\nfov = 50\n[film]\nwidth = 24\nheight = 24\n\
                [materials.floor]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
                [[objects]]\nshape = \"plane\"\nmaterial = \"floor\"\n\
                [[objects]]\nshape = \"gltf\"\nfile = \"lamp.gltf\"\n\
                transform = { rotate = { axis = [1, 0, 0], degrees = 90 }, translate = [0, 1, 0] }\n";
    let files = MemAssets(BTreeMap::from([(
        "lamp.gltf".to_string(),
        serde_json::to_vec(&gltf).expect("json"),
    )]));
    Scene::from_str_with(
        text,
        Format::Toml,
        "lamp.toml",
        &Limits::default(),
        1,
        &files,
    )
    .expect("loads")
}

/// The image mean of `scene` under `strategy` at `spp`, with its standard error.
fn image_mean(scene: &Scene, strategy: tessera_render::Strategy, spp: u32) -> (f64, f64) {
    use tessera_render::{render_tile, PixelRect, RenderSettings};
    let settings = RenderSettings {
        spp,
        batch: spp,
        seed: 5,
        strategy,
        ..RenderSettings::default()
    };
    let rect = PixelRect {
        x0: 0,
        y0: 0,
        width: scene.width,
        height: scene.height,
    };
    let t = render_tile(scene, &settings, rect, 0..spp);
    let n = t.count.len() as f64;
    let (mut mean, mut var) = (0.0, 0.0);
    for ((s, q), &c) in t.sum.iter().zip(&t.sum_sq).zip(&t.count) {
        let c = f64::from(c);
        let m = s.iter().sum::<f64>() / (3.0 * c);
        let m2 = q.iter().sum::<f64>() / (3.0 * c);
        mean += m / n;
        var += (m2 - m * m).max(0.0) / c / (n * n);
    }
    (mean, var.sqrt())
}

#[test]
fn emission_textures_light_the_same_under_every_strategy_and_scale_a_uniform_light() {
    use tessera_render::Strategy;
    // Half the lamp emits (texels black, black, white, white across u).
    let half = emitter_scene(&common::png_rgb(
        4,
        1,
        &[[0u8; 3], [0; 3], [255; 3], [255; 3]].concat(),
    ));
    assert!(half.warnings.is_empty(), "{:?}", half.warnings);
    assert!(half.lights.lights.iter().any(|l| l.texture.is_some()));
    let (mis, se_mis) = image_mean(&half, Strategy::Mis, 256);
    for s in [Strategy::Nee, Strategy::Bsdf] {
        let (m, se) = image_mean(&half, s, 256);
        let z = (m - mis) / se_mis.hypot(se);
        assert!(z.abs() < 4.5, "{s:?}: {m} against MIS {mis}, z = {z:.2}");
    }
    // A uniform texel c is a light of c times the factor: all white gives twice the half-lit
    // floor's light, give or take where the dark half stood.
    let white = emitter_scene(&common::png_rgb(1, 1, &[255; 3]));
    let (w, se_w) = image_mean(&white, Strategy::Mis, 256);
    let dark = emitter_scene(&common::png_rgb(1, 1, &[0; 3]));
    let (d, _) = image_mean(&dark, Strategy::Mis, 16);
    assert_eq!(d, 0.0, "a black emission texture emits nothing");
    assert!(
        w > mis * 1.3 && w < mis * 2.7,
        "white {w} ± {se_w} against half {mis}"
    );
}

#[test]
fn a_toml_meshs_emission_texture_lights_as_the_gltf_one_does() {
    use tessera_render::Strategy;
    // Black at both ends, so that repeating (TOML's default) and clamping (the glTF lamp's
    // sampler) filter the same.
    let png = common::png_rgb(4, 1, &[[0u8; 3], [255; 3], [255; 3], [0; 3]].concat());
    let gltf = emitter_scene(&png);
    // The same lamp: the quad with the same coordinates (v up: glTF's flipped), the same
    // black pbr surface, the same emission.
    let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
               f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n";
    let text = |shape: &str| {
        format!(
            "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0.5, 0.5, 3]\n\
             target = [0.5, 0, 0.5]\nfov = 50\n[film]\nwidth = 24\nheight = 24\n\
             [materials.floor]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
             [materials.lamp]\ntype = \"pbr\"\nbase_color = [0, 0, 0]\nmetallic = 0\n\
             emission = [2, 2, 2]\nemission_texture = \"band.png\"\ntwo_sided = true\n\
             [[objects]]\nshape = \"plane\"\nmaterial = \"floor\"\n\
             [[objects]]\n{shape}\nmaterial = \"lamp\"\n\
             transform = {{ rotate = {{ axis = [1, 0, 0], degrees = 90 }}, translate = [0, 1, 0] }}\n"
        )
    };
    let files = MemAssets(BTreeMap::from([
        ("lamp.obj".to_string(), obj.as_bytes().to_vec()),
        ("band.png".to_string(), png.clone()),
    ]));
    let load = |shape: &str| {
        Scene::from_str_with(
            &text(shape),
            Format::Toml,
            "lamp.toml",
            &Limits::default(),
            1,
            &files,
        )
    };
    let toml = load("shape = \"mesh\"\nfile = \"lamp.obj\"").expect("loads");
    assert!(toml.lights.lights.iter().any(|l| l.texture.is_some()));
    let (g, se_g) = image_mean(&gltf, Strategy::Mis, 256);
    for s in [Strategy::Mis, Strategy::Nee, Strategy::Bsdf] {
        let (t, se_t) = image_mean(&toml, s, 256);
        let z = (t - g) / se_t.hypot(se_g);
        assert!(
            z.abs() < 4.5,
            "{s:?}: TOML {t} against glTF {g}, z = {z:.2}"
        );
    }
    // Without texture coordinates there is nothing to look the texture up at.
    let e = load("shape = \"sphere\"\ncenter = [0, 0, 0]\nradius = 0.5")
        .expect_err("refused")
        .to_string();
    assert!(e.contains("needs a mesh with texture coordinates"), "{e}");
}

/// `gltf` with a second buffer holding `tangents` (one VEC4 per quad corner) as accessor 3.
fn with_tangents(mut gltf: Value, tangents: &[[f32; 4]; 4]) -> Value {
    let bytes = f32s(tangents.as_flattened());
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bytes)
    );
    let push = |v: &mut Value, item: Value| v.as_array_mut().expect("array").push(item);
    push(
        &mut gltf["buffers"],
        json!({"byteLength": bytes.len(), "uri": uri}),
    );
    push(
        &mut gltf["bufferViews"],
        json!({"buffer": 1, "byteLength": bytes.len()}),
    );
    push(
        &mut gltf["accessors"],
        json!({"bufferView": 4, "componentType": 5126, "count": 4, "type": "VEC4"}),
    );
    gltf
}

#[test]
fn normal_maps_read_in_the_files_tangents_or_mikktspaces_and_mirroring_keeps_them_up_the_image() {
    // One texel tilting the normal 45° towards the bitangent (green): up the image.
    let png = common::png_rgb(1, 1, &[128, 218, 218]);
    let quad = |node: Value, tangent: bool| {
        let mut attributes = json!({"POSITION": 0, "TEXCOORD_0": 1});
        if tangent {
            attributes["TANGENT"] = json!(3);
        }
        textured_quad_doc(
            &png,
            json!({
                "scenes": [{"nodes": [0]}],
                "nodes": [node],
                "meshes": [{"primitives": [{"attributes": attributes, "indices": 2, "material": 0}]}],
                "materials": [{"pbrMetallicRoughness": {}, "normalTexture": {"index": 0}}],
                "textures": [{"source": 0}],
            }),
        )
    };
    // The bent normal at the quad's centre, seen from +z.
    let bent = |gltf: &Value| {
        let s = load(gltf, &GltfOptions::default()).expect("loads");
        let Shape::Mesh(m) = &s.prims[0].shape else {
            panic!()
        };
        let x = m.xf.to_world.transform_point3a(Vec3A::new(0.4, 0.6, 0.0));
        let ray = tessera_render::util::math::Ray::new(x + Vec3A::Z, Vec3A::NEG_Z);
        let (_, tri) = m.intersect(&ray, f32::INFINITY).expect("hit");
        let frame = m.uv_frame(&ray, tri).expect("uvs");
        let tessera_render::bsdf::Bsdf::Pbr(i) = s.materials[0].bsdf else {
            panic!()
        };
        s.pbr(i).bend(&s.textures, &frame, Vec3A::Z)
    };
    let tilted = |toward: Vec3A| (toward + Vec3A::Z).normalize();
    // Within the texel's 8-bit rounding (128 is 0.004 off zero).
    let near = |a: Vec3A, b: Vec3A| (a - b).length() < 1e-2;
    let plain = json!({"mesh": 0});
    // MikkTSpace's frame on a flat quad is the triangle's: green tilts up the image, +y.
    let b = bent(&quad(plain.clone(), false));
    assert!(near(b, tilted(Vec3A::Y)), "{b}");
    // The file's tangents win: tangent +y, so the bitangent n × t is −x, and w = −1 turns it
    // to +x.
    let rotated = with_tangents(quad(plain.clone(), true), &[[0.0, 1.0, 0.0, -1.0]; 4]);
    assert!(near(bent(&rotated), tilted(Vec3A::X)), "{}", bent(&rotated));
    // A mirroring node (x → −x): the image's up is still +y, for given and computed tangents.
    let mirror = json!({"mesh": 0, "scale": [-1.0, 1.0, 1.0]});
    let given = with_tangents(quad(mirror.clone(), true), &[[1.0, 0.0, 0.0, 1.0]; 4]);
    assert!(near(bent(&given), tilted(Vec3A::Y)), "{}", bent(&given));
    assert!(near(bent(&quad(mirror, false)), tilted(Vec3A::Y)));
    // A TANGENT accessor of the wrong length is refused by name.
    let mut short = with_tangents(quad(plain, true), &[[1.0, 0.0, 0.0, 1.0]; 4]);
    short["accessors"][3]["count"] = json!(3);
    let e = load(&short, &GltfOptions::default()).expect_err("refused");
    assert!(e.contains("TANGENT: 3 for 4 positions"), "{e}");
}
