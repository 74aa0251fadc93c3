//! glTF's metallic–roughness material (`pbr`) in whole renders: white furnaces under a uniform
//! sky, normal maps against the analytic answer of a tilted Lambertian surface under a
//! directional light (which pins the tangent frame's handedness), textured parameters, and
//! the errors a bad material gets.

mod common;

use common::{region_stats, render, scene, scene_with_files, try_scene_with_files};
use tessera_render::RenderSettings;

/// A 2 × 2 image of one colour.
fn flat(rgb: [u8; 3]) -> Vec<u8> {
    common::png_rgb(2, 2, &rgb.repeat(4))
}

const SKY: [f64; 3] = [1.0, 0.5, 0.25];

fn sky_scene(material: &str) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 6]\ntarget = [0, 0, 0]\nfov = 30\n[film]\nwidth = 32\nheight = 32\n\
         [environment]\ntype = \"constant\"\nradiance = {SKY:?}\n\
         [materials.m]\ntype = \"pbr\"\nbase_color = [1, 1, 1]\n{material}\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\nradius = 1.0\n"
    )
}

/// A white pbr sphere under a uniform sky shows at most the sky, whatever its parameters;
/// smooth and without metal it shows the sky itself (its coat, base and sheet add up to one),
/// sample by sample where no diffuse base is left to draw from.
#[test]
fn a_white_pbr_sphere_never_outshines_a_uniform_sky() {
    let cases = [
        ("metallic = 0\nroughness = 0", Some(2e-2)),
        ("metallic = 0\nroughness = 0\ntransmission = 1", Some(1e-5)),
        ("metallic = 0\nroughness = 0.5", None),
        ("metallic = 0.5\nroughness = 0.8\ntransmission = 0.5", None),
        (
            "metallic = 0\nroughness = 0.4\ntransmission = 1\nior = 1.3",
            None,
        ),
    ];
    for (material, exact) in cases {
        let img = render(
            &scene(&sky_scene(material)),
            &RenderSettings {
                spp: 64,
                seed: 4,
                // No Russian roulette: every path of a convex object escapes to the sky in
                // the end, so a sheet's samples are exactly the sky, not the sky on average.
                rr_depth: 10_000,
                ..RenderSettings::default()
            },
        );
        assert_eq!(img.nonfinite, 0, "{material}");
        for y in (0..32).step_by(4) {
            for x in (0..32).step_by(4) {
                let (mean, se) = region_stats(&img, x, y, 4, 4);
                for c in 0..3 {
                    assert!(
                        mean[c] <= SKY[c] * 1.003 + 4.0 * se[c] + 1e-6,
                        "{material}: block ({x},{y}) channel {c}: {} above the sky (±{})",
                        mean[c],
                        se[c]
                    );
                    if let Some(tol) = exact {
                        assert!(
                            (mean[c] - SKY[c]).abs() <= tol * SKY[c] + 4.0 * se[c],
                            "{material}: block ({x},{y}) channel {c}: {} is not the sky (±{})",
                            mean[c],
                            se[c]
                        );
                    }
                }
            }
        }
    }
}

/// A quad facing the camera, of a Lambertian pbr (index 1: no coat; no metal) with a normal
/// map of one texel value, under a directional light arriving from `to_light`.
fn mapped_quad(normal_png: Option<&[u8]>, to_light: [f64; 3]) -> tessera_render::scene::Scene {
    let quad = std::fs::read(common::repo_root().join("scenes/meshes/quad.obj")).expect("quad");
    let map = if normal_png.is_some() {
        "normal_map = { texture = \"n.png\" }\n"
    } else {
        ""
    };
    let d = to_light.map(|x| -x);
    let text = format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 3]\ntarget = [0, 0, 0]\nfov = 30\n[film]\nwidth = 16\nheight = 16\n\
         [materials.m]\ntype = \"pbr\"\nbase_color = [0.8, 0.6, 0.4]\nmetallic = 0\nroughness = 1\nior = 1\n{map}\
         [[lights]]\ntype = \"directional\"\ndirection = {d:?}\nirradiance = [3, 3, 3]\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"quad.obj\"\nmaterial = \"m\"\n"
    );
    let mut files: Vec<(&str, &[u8])> = vec![("quad.obj", &quad)];
    if let Some(n) = normal_png {
        files.push(("n.png", n));
    }
    scene_with_files(&text, &files)
}

/// The normal a map's 8-bit texel encodes: (2·code/255 − 1), normalised.
fn decoded(code: [u8; 3]) -> [f64; 3] {
    let v = code.map(|c| 2.0 * f64::from(c) / 255.0 - 1.0);
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|x| x / l)
}

/// With a normal map the surface shades as if tilted: c/π · E · (n'·L), with n' the map's
/// normal in the frame (∂p/∂u, ∂p/∂v, n) — red along u, green up the image — which for
/// quad.obj is (+x, +y, +z). A map tilted towards the light brightens the quad, one tilted away
/// darkens it, and a flat one changes nothing.
#[test]
fn a_normal_map_tilts_the_shading_normal_along_u_and_v() {
    let (s30, c30) = (0.5f64, 0.75f64.sqrt());
    let albedo = [0.8f64, 0.6, 0.4];
    let settings = RenderSettings {
        spp: 4,
        seed: 1,
        ..RenderSettings::default()
    };
    // (texel, direction to the light).
    let tilt = |a: f64| (127.5 * (1.0 + a)).round() as u8;
    let (s20, c20) = (20f64.to_radians().sin(), 20f64.to_radians().cos());
    let cases = [
        ([tilt(s20), 128, tilt(c20)], [s30, 0.0, c30]),
        ([tilt(-s20), 128, tilt(c20)], [s30, 0.0, c30]),
        ([128, tilt(s20), tilt(c20)], [0.0, s30, c30]),
        ([128, tilt(-s20), tilt(c20)], [0.0, s30, c30]),
        ([128, 128, 255], [s30, 0.0, c30]),
    ];
    let plain = render(&mapped_quad(None, [s30, 0.0, c30]), &settings);
    let (flat_mean, _) = region_stats(&plain, 4, 4, 8, 8);
    for (code, to_light) in cases {
        let n = decoded(code);
        let cos = n[0] * to_light[0] + n[1] * to_light[1] + n[2] * to_light[2];
        let img = render(&mapped_quad(Some(&flat(code)), to_light), &settings);
        assert_eq!(img.nonfinite, 0);
        let (mean, _) = region_stats(&img, 4, 4, 8, 8);
        for c in 0..3 {
            let want = albedo[c] / std::f64::consts::PI * 3.0 * cos;
            assert!(
                (mean[c] - want).abs() <= 2e-3 * want,
                "texel {code:?}, light {to_light:?}, channel {c}: {} vs c/π·E·cos = {want}",
                mean[c]
            );
        }
        if code == [128, 128, 255] {
            // A flat map is the surface's own normal, to the texel's rounding.
            assert!((mean[0] - flat_mean[0]).abs() <= 3e-3 * flat_mean[0]);
        }
    }
    // Without a map: cos 30°.
    let want = albedo[0] / std::f64::consts::PI * 3.0 * c30;
    assert!((flat_mean[0] - want).abs() <= 1e-3 * want, "{flat_mean:?}");
}

/// A scalar parameter read from a named channel takes that channel (here metallic from blue,
/// roughness from green, glTF's packing), and a whole-image scalar must be grey.
#[test]
fn textured_parameters_read_their_channel_and_refuse_a_colour_image() {
    let quad = std::fs::read(common::repo_root().join("scenes/meshes/quad.obj")).expect("quad");
    let text = |params: &str| {
        format!(
            "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 3]\ntarget = [0, 0, 0]\nfov = 30\n[film]\nwidth = 8\nheight = 8\n\
             [environment]\ntype = \"constant\"\nradiance = [1, 1, 1]\n\
             [materials.m]\ntype = \"pbr\"\nbase_color = [0.5, 0.5, 0.5]\n{params}\n\
             [[objects]]\nshape = \"mesh\"\nfile = \"quad.obj\"\nmaterial = \"m\"\n"
        )
    };
    // Blue 255 (metal), green 0 (smooth): a mirror of F0 = 0.5 showing the white sky; the same
    // file read through the other channels would be a rough dielectric.
    let packed = flat([0, 0, 255]);
    let files: [(&str, &[u8]); 2] = [("quad.obj", &quad), ("mr.png", &packed)];
    let metal = scene_with_files(
        &text(
            "metallic = { texture = \"mr.png\", channel = \"b\" }\n\
             roughness = { texture = \"mr.png\", channel = \"g\" }",
        ),
        &files,
    );
    let img = render(
        &metal,
        &RenderSettings {
            spp: 4,
            ..RenderSettings::default()
        },
    );
    // Head-on, Schlick's F at cos 1 is F0 = 0.5 exactly.
    for p in &img.rgb {
        assert!((p[0] - 0.5).abs() < 1e-3, "{p:?}");
    }
    let e = try_scene_with_files(&text("metallic = { texture = \"mr.png\" }"), &files)
        .expect_err("a colour image for one number");
    assert!(
        e.contains("materials.m.metallic.texture")
            && e.contains("a colour image where one number is expected"),
        "{e}"
    );
    let grey = flat([77, 77, 77]);
    let files: [(&str, &[u8]); 2] = [("quad.obj", &quad), ("mr.png", &grey)];
    try_scene_with_files(&text("metallic = { texture = \"mr.png\" }"), &files)
        .expect("a grey image is one number");
}

/// Every bad key names itself and what is wrong, in one line.
#[test]
fn bad_pbr_materials_name_the_key() {
    let quad = std::fs::read(common::repo_root().join("scenes/meshes/quad.obj")).expect("quad");
    let n = flat([128, 128, 255]);
    let files: [(&str, &[u8]); 2] = [("quad.obj", &quad), ("n.png", &n)];
    let case = |params: &str, shape: &str| {
        let text = format!(
            "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 3]\ntarget = [0, 0, 0]\nfov = 30\n[film]\nwidth = 8\nheight = 8\n\
             [materials.m]\ntype = \"pbr\"\n{params}\n[[objects]]\n{shape}\nmaterial = \"m\"\n"
        );
        try_scene_with_files(&text, &files).expect_err(params)
    };
    let mesh = "shape = \"mesh\"\nfile = \"quad.obj\"";
    let sphere = "shape = \"sphere\"\nradius = 1";
    for (params, shape, key, what) in [
        (
            "roughness = 1.5",
            mesh,
            "materials.m.roughness",
            "between 0 and 1",
        ),
        (
            "metallic = -0.1",
            mesh,
            "materials.m.metallic",
            "between 0 and 1",
        ),
        (
            "transmission = 2",
            mesh,
            "materials.m.transmission",
            "between 0 and 1",
        ),
        ("ior = 0", mesh, "materials.m.ior", "greater than 0"),
        (
            "distribution = \"beckmann\"",
            sphere,
            "materials.m.distribution",
            "`multiscatter_ggx` or `ggx`",
        ),
        ("ior = -1.5", mesh, "materials.m.ior", "greater than 0"),
        (
            "clearcoat = 1.5",
            mesh,
            "materials.m.clearcoat",
            "between 0 and 1",
        ),
        (
            "clearcoat = 1\nclearcoat_roughness = -1",
            mesh,
            "materials.m.clearcoat_roughness",
            "between 0 and 1",
        ),
        (
            "sheen_color = [1, 1.5, 0]",
            mesh,
            "materials.m.sheen_color",
            "",
        ),
        (
            "sheen_color = [1, 1, 1]\nsheen_roughness = 3",
            mesh,
            "materials.m.sheen_roughness",
            "between 0 and 1",
        ),
        (
            "clearcoat_roughness = 2",
            mesh,
            "materials.m.clearcoat_roughness",
            "between 0 and 1",
        ),
        (
            "base_color = [1.2, 0, 0]",
            mesh,
            "materials.m.base_color",
            "",
        ),
        (
            "metallic = { texture = \"n.png\", channel = \"a\" }",
            mesh,
            "",
            "\"r\", \"g\" or \"b\"",
        ),
        (
            "roughness = { texture = \"n.png\", channel = \"g\", factor = 3 }",
            mesh,
            "materials.m.roughness.factor",
            "between 0 and 1",
        ),
        (
            "normal_map = { texture = \"missing.png\" }",
            mesh,
            "materials.m.normal_map.texture",
            "missing.png",
        ),
        (
            "normal_map = { texture = \"n.png\" }",
            sphere,
            "objects[0].material",
            "texture coordinates",
        ),
        ("albedo = [1, 1, 1]", mesh, "materials.m", "albedo"),
    ] {
        let e = case(params, shape);
        assert!(
            e.contains(key) && e.contains(what) && !e.contains('\n'),
            "{params}: {e}"
        );
    }
    // And a roughness texture is for pbr materials only.
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 3]\ntarget = [0, 0, 0]\nfov = 30\n[film]\nwidth = 8\nheight = 8\n\
         [materials.m]\ntype = \"conductor\"\nmetal = \"gold\"\nroughness = { texture = \"n.png\", channel = \"g\" }\n\
         [[objects]]\nshape = \"sphere\"\nradius = 1\nmaterial = \"m\"\n";
    let e = try_scene_with_files(text, &files).expect_err("texture roughness on a metal");
    assert!(
        e.contains("materials.m.roughness") && e.contains("textures are for pbr materials"),
        "{e}"
    );
}
