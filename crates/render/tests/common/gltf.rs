//! glTF documents for the glTF tests (`gltf.rs`, `gltf_materials.rs`): JSON around buffers
//! given as data URIs, built in memory, and loaded as `tessera render` loads a file.

use base64::Engine as _;
use glam::Vec3A;
use serde_json::{json, Value};
use tessera_render::scene::{GltfOptions, Limits, Scene};

/// The unit quad in the z = 0 plane, counter-clockwise seen from +z.
pub const QUAD: [f32; 12] = [0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.];

/// A glTF document around one buffer, given as a data URI.
pub fn doc(buffer: &[u8], mut body: Value) -> Value {
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(buffer)
    );
    body["asset"] = json!({"version": "2.0"});
    body["buffers"] = json!([{"byteLength": buffer.len(), "uri": uri}]);
    body
}

/// The floats' little-endian bytes, as a buffer holds them.
pub fn f32s(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// One triangle mesh of `positions` (and `indices`, u16, after them in the buffer), one node.
pub fn triangle_doc(positions: &[f32], indices: &[u16], extra: Value) -> Value {
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
pub fn textured_quad_doc(png: &[u8], mut body: Value) -> Value {
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
pub fn load_file(
    name: &str,
    bytes: &[u8],
    opts: &GltfOptions,
    limits: &Limits,
) -> Result<Scene, String> {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).expect("write");
    Scene::file(&path, limits)
        .gltf(opts)
        .at(1)
        .load()
        .map_err(|e| {
            let e = e.to_string();
            e.strip_prefix(&format!("{}/", dir.path().display()))
                .unwrap_or(&e)
                .to_string()
        })
}

/// Loads `gltf` as the whole scene of a file named `model.gltf`.
pub fn load(gltf: &Value, opts: &GltfOptions) -> Result<Scene, String> {
    let bytes = serde_json::to_vec(gltf).expect("json");
    load_file("model.gltf", &bytes, opts, &Limits::default())
}

/// Equal within a relative 10⁻⁴.
pub fn near(a: Vec3A, b: Vec3A) -> bool {
    (a - b).length() < 1e-4 * (1.0 + b.length())
}
