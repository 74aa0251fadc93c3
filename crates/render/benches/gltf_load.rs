//! Loading a large glTF file (parse, read its accessors, decode its textures, build the BVH)
//! against loading the same triangles from a binary PLY file, the mesh path measured before
//! glTF: `cargo bench -p tessera-render --bench gltf_load`. The file is generated here, in
//! memory: a bumpy sphere of 2 × 1024² triangles with normals and texture coordinates, an
//! embedded 1024² base-colour PNG and a 512² metallic–roughness PNG (about 60 MB as a .glb),
//! and once more with a 512² normal map, whose tangents the load computes.
//! The goal is at most 1 s per million triangles on a 2-core machine.

#![allow(missing_docs)] // criterion_group! generates an undocumented function

use std::collections::BTreeMap;
use std::f32::consts::PI;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use tessera_render::scene::assets::MemAssets;
use tessera_render::scene::{gltf_scene_text, Format, GltfOptions, Limits, Scene};

/// Quads per side of the grid: 2·N² triangles.
const N: usize = 1024;

struct Grid {
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    indices: Vec<u32>,
}

fn grid() -> Grid {
    let side = N + 1;
    let mut g = Grid {
        positions: Vec::with_capacity(side * side),
        normals: Vec::with_capacity(side * side),
        uvs: Vec::with_capacity(side * side),
        indices: Vec::with_capacity(6 * N * N),
    };
    for i in 0..side {
        let th = PI * i as f32 / N as f32;
        for j in 0..side {
            let ph = 2.0 * PI * j as f32 / N as f32;
            let d = [th.sin() * ph.cos(), th.cos(), -th.sin() * ph.sin()];
            let r = 1.0 + 0.02 * (9.0 * th).sin() * (13.0 * ph).sin();
            g.positions.push(d.map(|c| c * r));
            g.normals.push(d);
            g.uvs.push([j as f32 / N as f32, i as f32 / N as f32]);
        }
    }
    for i in 0..N {
        for j in 0..N {
            let a = (i * side + j) as u32;
            let b = a + side as u32;
            g.indices.extend([a, b, a + 1, a + 1, b, b + 1]);
        }
    }
    g
}

fn png(size: u32, texel: impl Fn(u32, u32) -> [u8; 3]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, size, size);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().expect("png header");
    let data: Vec<u8> = (0..size * size)
        .flat_map(|i| texel(i % size, i / size))
        .collect();
    w.write_image_data(&data).expect("png data");
    drop(w);
    out
}

fn bytes<T: bytemuck::Pod>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}

/// The grid as a .glb with its two textures embedded, and with `normal_map` a third: a
/// normal map, whose tangents the load computes (MikkTSpace), as the file gives none.
fn glb(g: &Grid, normal_map: bool) -> Vec<u8> {
    let base = png(1024, |x, y| {
        let c = ((x / 64 + y / 64) % 2) as u8;
        [60 + 150 * c, 90 + (x % 97) as u8, 160 - (y % 89) as u8]
    });
    let mr = png(512, |x, y| {
        [
            0,
            40 + ((x ^ y) % 160) as u8,
            if (x / 32 + y / 32) % 2 == 0 { 255 } else { 0 },
        ]
    });
    let bumps = png(512, |x, y| {
        let tilt = |t: u32| (128.0 + 60.0 * (t as f32 * 0.2).sin()) as u8;
        [tilt(x), tilt(y), 230]
    });
    let mut parts = vec![
        bytes(&g.positions),
        bytes(&g.normals),
        bytes(&g.uvs),
        bytes(&g.indices),
        &base[..],
        &mr[..],
    ];
    let mut material = serde_json::json!({"pbrMetallicRoughness": {
        "baseColorTexture": {"index": 0}, "metallicRoughnessTexture": {"index": 1}}});
    let mut images = vec![
        serde_json::json!({"bufferView": 4, "mimeType": "image/png"}),
        serde_json::json!({"bufferView": 5, "mimeType": "image/png"}),
    ];
    if normal_map {
        parts.push(&bumps[..]);
        material["normalTexture"] = serde_json::json!({"index": 2});
        images.push(serde_json::json!({"bufferView": 6, "mimeType": "image/png"}));
    }
    let textures: Vec<_> = (0..images.len())
        .map(|i| serde_json::json!({"source": i}))
        .collect();
    let mut bin = Vec::new();
    let mut views = Vec::new();
    for part in parts {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(
            serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": part.len()}),
        );
        bin.extend_from_slice(part);
    }
    let n = g.positions.len();
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0}, {"camera": 0, "translation": [0, 0, 4]}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.1}}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3, "material": 0}]}],
        "materials": [material],
        "textures": textures,
        "images": images,
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3",
             "min": [-1.1, -1.1, -1.1], "max": [1.1, 1.1, 1.1]},
            {"bufferView": 1, "componentType": 5126, "count": n, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": n, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5125, "count": g.indices.len(), "type": "SCALAR"},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    let mut js = serde_json::to_vec(&json).expect("json");
    while !js.len().is_multiple_of(4) {
        js.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend(((12 + 8 + js.len() + 8 + bin.len()) as u32).to_le_bytes());
    out.extend((js.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(js);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(bin);
    out
}

/// The grid as a binary PLY with normals and texture coordinates (no textures: an OBJ or PLY
/// scene names its images apart, so they are left out of both sides of the ratio below).
fn ply(g: &Grid) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float u\n\
         property float v\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        g.positions.len(),
        g.indices.len() / 3
    )
    .into_bytes();
    for ((p, n), uv) in g.positions.iter().zip(&g.normals).zip(&g.uvs) {
        out.extend(bytes(p));
        out.extend(bytes(n));
        out.extend(bytes(uv));
    }
    for t in g.indices.chunks(3) {
        out.push(3);
        out.extend(bytes(t));
    }
    out
}

fn load(c: &mut Criterion) {
    let g = grid();
    let triangles = (g.indices.len() / 3) as u64;
    let ply = ply(&g);
    let limits = Limits::default();
    let [(gltf_text, gltf_files), (bumpy_text, bumpy_files)] = [false, true].map(|normal_map| {
        let glb = glb(&g, normal_map);
        (
            gltf_scene_text("big.glb", &glb, &GltfOptions::default()),
            MemAssets(BTreeMap::from([("big.glb".to_string(), glb)])),
        )
    });
    let ply_text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 4]\ntarget = [0, 0, 0]\n\
                    fov = 40\n[film]\nwidth = 1280\nheight = 720\n[materials.m]\ntype = \"diffuse\"\n\
                    albedo = [0.5, 0.5, 0.5]\n[[objects]]\nshape = \"mesh\"\nfile = \"big.ply\"\n\
                    material = \"m\"\nsmooth = true\n";
    let ply_files = MemAssets(BTreeMap::from([("big.ply".to_string(), ply)]));
    let mut group = c.benchmark_group("load_2M_triangles");
    group.sample_size(10);
    group.throughput(Throughput::Elements(triangles));
    group.bench_function("glb_with_textures", |b| {
        b.iter(|| {
            Scene::text(&gltf_text, Format::Toml, "big", &limits)
                .at(1)
                .assets(&gltf_files)
                .load()
                .expect("glb loads")
        })
    });
    group.bench_function("glb_with_textures_and_normal_map", |b| {
        b.iter(|| {
            Scene::text(&bumpy_text, Format::Toml, "big", &limits)
                .at(1)
                .assets(&bumpy_files)
                .load()
                .expect("glb loads")
        })
    });
    group.bench_function("ply", |b| {
        b.iter(|| {
            Scene::text(ply_text, Format::Toml, "big", &limits)
                .at(1)
                .assets(&ply_files)
                .load()
                .expect("ply loads")
        })
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default();
    targets = load
}
criterion_main!(benches);
