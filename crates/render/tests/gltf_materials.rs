//! glTF files' materials as tessera reads them: texture transforms and samplers,
//! `materials_map`, alpha MASK and BLEND, emission textures (and TOML's `emission_texture`),
//! and normal maps in the file's tangent frame or MikkTSpace's.

use std::collections::BTreeMap;

mod common;

use base64::Engine as _;
use common::gltf::*;
use glam::Vec3A;
use serde_json::{json, Value};
use tessera_render::scene::assets::MemAssets;
use tessera_render::scene::{Format, GltfOptions, Limits, Scene};
use tessera_render::shape::Shape;

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
        Scene::text(&text, Format::Toml, "s.toml", &Limits::default())
            .at(1)
            .assets(&files)
            .load()
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
    Scene::text(text, Format::Toml, "lamp.toml", &Limits::default())
        .at(1)
        .assets(&files)
        .load()
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
        Scene::text(&text(shape), Format::Toml, "lamp.toml", &Limits::default())
            .at(1)
            .assets(&files)
            .load()
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
        let tessera_render::material::Bsdf::Pbr(tessera_render::material::pbr::PbrRef(i)) =
            s.materials[0].bsdf
        else {
            panic!()
        };
        s.tables().pbr(i).bend(&s.textures, &frame, Vec3A::Z)
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
    assert!(
        e.contains("/meshes/0/primitives/0/attributes/TANGENT: 3 for 4 positions"),
        "{e}"
    );
}

/// A one-triangle glTF file whose grey dielectric material (base 0.5, roughness 0.5) carries
/// the material extension `name` with `value`, if any, loaded.
fn grey_with(name: &str, value: Option<Value>) -> Result<Scene, String> {
    let mut material = json!({"pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 0.5,
            "baseColorFactor": [0.5, 0.5, 0.5, 1.0]}});
    if let Some(v) = value {
        material["extensions"] = json!({ name: v });
    }
    let gltf = triangle_doc(
        &QUAD,
        &[0, 1, 2],
        json!({
            "extensionsUsed": [name],
            "materials": [material],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        }),
    );
    load(&gltf, &GltfOptions::default())
}

/// The head-on albedo (red) of `s`'s first pbr material, untextured: its BSDF's weights over a
/// 64² grid of the square and a spread of lobe choices.
fn head_on_albedo(s: &Scene) -> f64 {
    use tessera_render::material::pbr::PbrRef;
    use tessera_render::material::Bsdf;
    let i = s
        .materials
        .iter()
        .find_map(|m| match m.bsdf {
            Bsdf::Pbr(PbrRef(i)) => Some(i),
            _ => None,
        })
        .expect("a pbr material");
    let m = s.tables().pbr(i);
    let b = m.bsdf(m.params(&s.textures, glam::Vec2::ZERO));
    let n = 64;
    let mut sum = 0.0f64;
    for k in 0..n * n {
        let u = glam::Vec2::new(
            ((k % n) as f32 + 0.5) / n as f32,
            ((k / n) as f32 + 0.5) / n as f32,
        );
        if let Some(x) = b.sample(Vec3A::Z, u, ((k * 7919) % (n * n)) as f32 / (n * n) as f32) {
            sum += f64::from(x.weight.x);
        }
    }
    sum / (n * n) as f64
}

/// `KHR_materials_specular` as Blender writes it (`specularFactor` = 2 × Specular IOR Level):
/// a factor of 0 is no specular layer, so a grey dielectric base returns its own albedo
/// head-on (Blender's diffuse walls); 0.5 halves the layer's F0, whose white reflection adds to
/// the grey, between that and no extension at all.
#[test]
fn the_specular_factor_scales_the_dielectric_layer_as_blender_writes_it() {
    let albedo_head_on = |specular: Option<f32>| {
        let value = specular.map(|s| json!({ "specularFactor": s }));
        let s = grey_with("KHR_materials_specular", value).expect("loads");
        assert!(s.warnings.is_empty(), "{:?}", s.warnings);
        head_on_albedo(&s)
    };
    let none = albedo_head_on(Some(0.0));
    let half = albedo_head_on(Some(0.5));
    let full = albedo_head_on(None);
    eprintln!("grey base, roughness 0.5, head-on albedo: factor 0 {none}, 0.5 {half}, none {full}");
    assert!((none - 0.5).abs() < 1e-3, "no specular layer: {none}");
    assert!(none < half && half < full, "{none} < {half} < {full}");
    // A factor of 1 is the extension's default: the index itself.
    assert_eq!(albedo_head_on(Some(1.0)), full);
}

/// `KHR_materials_clearcoat` as Blender writes it (Coat Weight and Coat Roughness as factors):
/// the coat is read, so a grey base under it returns more head-on than without; a weight of 0
/// is no coat, bit for bit; its textures are warned about; a factor out of [0, 1] is refused at
/// its key.
#[test]
fn the_clearcoat_extension_is_read_as_blender_writes_it() {
    let load_coat = |coat: Option<Value>| grey_with("KHR_materials_clearcoat", coat);
    let albedo_head_on = |coat: Option<Value>| {
        let s = load_coat(coat).expect("loads");
        (head_on_albedo(&s), s.warnings)
    };
    let (none, warnings) = albedo_head_on(None);
    assert!(warnings.is_empty(), "{warnings:?}");
    let (zero, _) = albedo_head_on(Some(
        json!({"clearcoatFactor": 0.0, "clearcoatRoughnessFactor": 0.2}),
    ));
    assert_eq!(zero, none, "a weight of 0 is no coat");
    let (coated, warnings) = albedo_head_on(Some(
        json!({"clearcoatFactor": 1.0, "clearcoatRoughnessFactor": 0.1}),
    ));
    assert!(warnings.is_empty(), "{warnings:?}");
    eprintln!("grey base, head-on albedo: no coat {none}, coat {coated}");
    assert!(
        coated > none + 0.01,
        "the coat reflects: {coated} vs {none}"
    );
    let (_, warnings) = albedo_head_on(Some(
        json!({"clearcoatFactor": 1.0, "clearcoatTexture": {"index": 0}}),
    ));
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("KHR_materials_clearcoat's factors, not its textures")),
        "{warnings:?}"
    );
    for (coat, key) in [
        (json!({"clearcoatFactor": 1.5}), "clearcoatFactor"),
        (
            json!({"clearcoatFactor": 1.0, "clearcoatRoughnessFactor": "rough"}),
            "clearcoatRoughnessFactor",
        ),
    ] {
        let e = load_coat(Some(coat)).expect_err("out of range").to_string();
        assert!(
            e.contains(&format!(
                "/materials/0/extensions/KHR_materials_clearcoat/{key}"
            )) && e.contains("[0, 1]"),
            "{e}"
        );
    }
}

/// `KHR_materials_sheen` as Blender writes it (Sheen Weight × Tint as the colour, Sheen
/// Roughness): read, so a grey base under a white sheen returns more head-on than without; a
/// black sheen is none, bit for bit; textures warned about; a bad factor refused at its key.
#[test]
fn the_sheen_extension_is_read() {
    let load_sheen = |sheen: Option<Value>| grey_with("KHR_materials_sheen", sheen);
    let albedo = |sheen: Option<Value>| {
        let s = load_sheen(sheen).expect("loads");
        (head_on_albedo(&s), s.warnings)
    };
    let (none, warnings) = albedo(None);
    assert!(warnings.is_empty(), "{warnings:?}");
    let (black, _) = albedo(Some(
        json!({"sheenColorFactor": [0, 0, 0], "sheenRoughnessFactor": 0.5}),
    ));
    assert_eq!(black, none, "a black sheen is none");
    let (white, warnings) = albedo(Some(
        json!({"sheenColorFactor": [1, 1, 1], "sheenRoughnessFactor": 0.5}),
    ));
    assert!(warnings.is_empty(), "{warnings:?}");
    assert!(
        white > none + 0.005,
        "the sheen reflects: {white} vs {none}"
    );
    let (_, warnings) = albedo(Some(
        json!({"sheenColorFactor": [1, 1, 1], "sheenColorTexture": {"index": 0}}),
    ));
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("KHR_materials_sheen's factors, not its textures")),
        "{warnings:?}"
    );
    for (x, key) in [
        (json!({"sheenColorFactor": [1, 2, 0]}), "sheenColorFactor"),
        (json!({"sheenColorFactor": [1, 1]}), "sheenColorFactor"),
        (json!({"sheenRoughnessFactor": -1}), "sheenRoughnessFactor"),
    ] {
        let e = load_sheen(Some(x)).expect_err("refused").to_string();
        assert!(
            e.contains(&format!(
                "/materials/0/extensions/KHR_materials_sheen/{key}"
            )),
            "{e}"
        );
    }
}
