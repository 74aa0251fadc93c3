//! Every bad scene gives an error naming the file, line:column and key path — never a panic.

use tessera_render::scene::{Format, Limits, Scene, SceneError};

const HEAD: &str = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = 40\n[film]\nwidth = 8\nheight = 8\n[materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n";

fn err(text: &str) -> SceneError {
    err_with(text, Format::Toml, &Limits::default())
}

fn err_with(text: &str, format: Format, limits: &Limits) -> SceneError {
    match Scene::text(text, format, "s.toml", limits).load() {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e,
    }
}

fn check(text: &str, line: usize, path: &str, message: &str) {
    let e = err(text);
    assert_eq!(e.line, line, "{e}");
    assert!(e.column >= 1, "{e}");
    assert_eq!(e.path, path, "{e}");
    assert!(e.message.contains(message), "{e}");
    assert!(e.to_string().starts_with(&format!("s.toml:{line}:")), "{e}");
}

#[test]
fn parser_errors() {
    check(
        &format!("{HEAD}[[objects]\n"),
        13,
        "(document)",
        "syntax error",
    );
    check(
        &format!("{HEAD}[[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\nradiuss = 1\n"),
        16,
        "objects[0].radiuss",
        "unknown field `radiuss`",
    );
    check(
        &format!("{HEAD}[[objects]]\nshape = \"cone\"\nmaterial = \"m\"\n"),
        14,
        "objects[0].shape",
        "unknown variant `cone`",
    );
    check(
        &format!("{HEAD}[[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\nradius = \"big\"\n"),
        16,
        "objects[0].radius",
        "invalid type",
    );
    check(
        &HEAD.replace("version = 1\n", ""),
        1,
        "(document)",
        "missing field `version`",
    );
    check(
        &HEAD.replace("width = 8", "width = -8"),
        8,
        "film.width",
        "invalid value",
    );
    // A vector of more (or fewer) than three numbers is an error, not its first three.
    check(
        &HEAD.replace("eye = [0, 0, 5]", "eye = [0, 0, 3.9, 42]"),
        4,
        "camera.eye",
        "invalid length 4, expected a vector of 3 numbers",
    );
    check(
        &HEAD.replace("eye = [0, 0, 5]", "eye = [0, 0, 3.9, 42, \"junk\"]"),
        4,
        "camera.eye[4]",
        "invalid type",
    );
    check(
        &HEAD.replace("albedo = [0.5, 0.5, 0.5]", "albedo = [0.5, 0.5]"),
        12,
        "materials.m.albedo",
        "invalid length 2",
    );
}

#[test]
fn validation_errors() {
    let obj = |body: &str| format!("{HEAD}[[objects]]\n{body}");
    check(
        &obj("shape = \"sphere\"\nmaterial = \"m\"\nradius = nan\n"),
        16,
        "objects[0].radius",
        "finite number greater than 0",
    );
    check(
        &obj("shape = \"sphere\"\nmaterial = \"m\"\nradius = 0.0\n"),
        16,
        "objects[0].radius",
        "greater than 0",
    );
    check(
        &obj("shape = \"sphere\"\nmaterial = \"m\"\ncenter = [0, inf, 0]\n"),
        16,
        "objects[0].center",
        "finite",
    );
    check(
        &obj("shape = \"sphere\"\nmaterial = \"nope\"\n"),
        15,
        "objects[0].material",
        "material `nope` is not defined",
    );
    check(
        &obj("shape = \"rect\"\nmaterial = \"m\"\nsize = [1, -2]\n"),
        16,
        "objects[0].size[1]",
        "greater than 0",
    );
    check(
        &obj("shape = \"box\"\nmaterial = \"m\"\nmin = [0, 0, 0]\nmax = [1, 0, 1]\n"),
        17,
        "objects[0].max",
        "positive on every axis",
    );
    check(
        &obj("shape = \"box\"\nmaterial = \"m\"\nradius = 2\n"),
        16,
        "objects[0].radius",
        "does not apply to a box",
    );
    check(
        &obj("shape = \"box\"\nmaterial = \"m\"\ntransform = { scale = [1, 0, 1] }\n"),
        16,
        "objects[0].transform",
        "degenerate",
    );
    check(
        &obj("shape = \"box\"\nmaterial = \"m\"\ntransform = { matrix = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,1]] }\n"),
        16,
        "objects[0].transform.matrix[3]",
        "last row",
    );
    check(
        &HEAD.replace("fov = 40", "fov = 0"),
        6,
        "camera.fov",
        "(0°, 180°)",
    );
    check(
        &HEAD.replace("fov = 40", "fov = 180"),
        6,
        "camera.fov",
        "(0°, 180°)",
    );
    check(
        &HEAD.replace("target = [0, 0, 0]", "target = [0, 0, 5]"),
        2,
        "camera",
        "degenerate camera",
    );
    check(
        &HEAD.replace("albedo = [0.5, 0.5, 0.5]", "albedo = [0.5, 1.5, 0.5]"),
        12,
        "materials.m.albedo",
        "at most 1",
    );
    // A missing key is reported at that key's path, on the line of the table that lacks it.
    check(
        &HEAD.replace("albedo = [0.5, 0.5, 0.5]\n", ""),
        10,
        "materials.m.albedo",
        "a diffuse material needs `albedo`",
    );
    check(
        &HEAD.replace("target = [0, 0, 0]\n", ""),
        2,
        "camera.target",
        "a look_at camera needs `target`",
    );
    check(
        &format!("{HEAD}[environment]\ntype = \"gradient\"\ntop = [1, 1, 1]\n"),
        13,
        "environment.bottom",
        "a gradient environment needs `bottom`",
    );
    check(
        &HEAD.replace("version = 1", "version = 2"),
        1,
        "version",
        "unsupported version 2",
    );
    check(
        &format!("{}[materials.lamp]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [1, 1, 1]\n[[objects]]\nshape = \"plane\"\nmaterial = \"lamp\"\n", HEAD),
        19,
        "objects[0].material",
        "infinite plane cannot emit",
    );
}

#[test]
fn limits_are_enforced() {
    let limits = Limits {
        max_resolution: 4,
        ..Limits::default()
    };
    let e = err_with(HEAD, Format::Toml, &limits);
    assert_eq!((e.line, e.path.as_str()), (8, "film.width"), "{e}");
    assert!(e.message.contains("above the limit of 4"), "{e}");
    let limits = Limits {
        max_bytes: 10,
        ..Limits::default()
    };
    assert!(err_with(HEAD, Format::Toml, &limits)
        .message
        .contains("bytes"));
    let limits = Limits {
        max_objects: 0,
        ..Limits::default()
    };
    let e = err_with(
        &format!("{HEAD}[[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\n"),
        Format::Toml,
        &limits,
    );
    assert!(e.message.contains("objects is above the limit"), "{e}");
}

#[test]
fn json_errors_have_positions_too() {
    let good = r#"{"version": 1, "camera": {"model": "look_at", "eye": [0,0,5], "target": [0,0,0], "fov": 40},
 "film": {"width": 8, "height": 8},
 "materials": {"m": {"type": "diffuse", "albedo": [0.5,0.5,0.5]}},
 "objects": [{"shape": "sphere", "material": "m", "radius": 1}]}"#;
    assert!(
        Scene::text(good, Format::Json, "s.json", &Limits::default())
            .load()
            .is_ok()
    );
    let e = err_with(
        &good.replace("\"radius\": 1", "\"radius\": -1"),
        Format::Json,
        &Limits::default(),
    );
    assert_eq!(
        (e.line, e.column, e.path.as_str()),
        (4, 51, "objects[0].radius"),
        "{e}"
    );
    let e = err_with(
        &good.replace("\"fov\": 40", "\"fov\": 40,"),
        Format::Json,
        &Limits::default(),
    );
    assert_eq!(e.line, 1, "{e}");
    let e = err_with(
        &good.replace("\"radius\"", "\"radios\""),
        Format::Json,
        &Limits::default(),
    );
    assert!(
        e.message.contains("unknown field `radios`") && e.line == 4,
        "{e}"
    );
}

#[test]
fn garbage_never_panics() {
    // Truncations and byte flips of a valid scene: every one is an error or a scene, no panic.
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/cornell-box.toml"
    ))
    .expect("scene");
    for cut in (0..text.len()).step_by(7) {
        let _ = Scene::text(
            &text[..text.floor_char_boundary(cut)],
            Format::Toml,
            "cut.toml",
            &Limits::default(),
        )
        .load();
    }
    let bytes = text.as_bytes();
    for i in (0..bytes.len()).step_by(5) {
        for b in [b'[', b'"', b'=', b'9', b'\n', b'-', b'e'] {
            let mut v = bytes.to_vec();
            v[i] = b;
            if let Ok(s) = String::from_utf8(v) {
                let _ = Scene::text(&s, Format::Toml, "flip.toml", &Limits::default()).load();
                let _ = Scene::text(&s, Format::Json, "flip.json", &Limits::default()).load();
            }
        }
    }
}

#[test]
fn plastic_errors_name_the_key() {
    let plastic = |body: &str| format!("{HEAD}[materials.p]\ntype = \"plastic\"\n{body}");
    check(
        &plastic("albedo = [0.5, 0.5, 0.5]\nroughness = 2\n"),
        16,
        "materials.p.roughness",
        "must be between 0 and 1, got 2",
    );
    check(
        &plastic("albedo = [0.5, 0.5, 0.5]\nior = 1\n"),
        16,
        "materials.p.ior",
        "a plastic's coat of index 1 is no coat",
    );
    check(
        &plastic("albedo = [0.5, 0.5, 0.5]\nior = -1.5\n"),
        16,
        "materials.p.ior",
        "must be a finite number greater than 0, got -1.5",
    );
    check(
        &plastic("roughness = 0.3\n"),
        13,
        "materials.p.albedo",
        "a plastic material needs `albedo`",
    );
    check(
        &plastic("albedo = [1.5, 0.5, 0.5]\n"),
        15,
        "materials.p.albedo",
        "must be at most 1",
    );
    check(
        &plastic("albedo = { texture = \"t.png\" }\n"),
        15,
        "materials.p.albedo.texture",
        "a plastic's albedo is a colour",
    );
    check(
        &plastic("albedo = [0.5, 0.5, 0.5]\nemission_texture = \"glow.png\"\n"),
        16,
        "materials.p.emission_texture",
        "an emission texture scales `emission`: give the radiance it scales",
    );
    check(
        &plastic("albedo = [0.5, 0.5, 0.5]\nmetal = \"gold\"\n"),
        16,
        "materials.p.metal",
        "`metal` does not apply to a plastic material",
    );
    // The microfacet model is the pbr material's (plastic's coat scatters once, as Mitsuba's).
    check(
        &plastic("albedo = [0.5, 0.5, 0.5]\ndistribution = \"ggx\"\n"),
        16,
        "materials.p.distribution",
        "`distribution` does not apply to a plastic material",
    );
}

#[test]
fn conductor_errors_name_the_key() {
    let metal = |body: &str| format!("{HEAD}[materials.c]\ntype = \"conductor\"\n{body}");
    check(
        &metal("metal = \"gold\"\nroughness = 1.5\n"),
        16,
        "materials.c.roughness",
        "must be between 0 and 1, got 1.5",
    );
    check(
        &metal("metal = \"gold\"\nroughness = -0.1\n"),
        16,
        "materials.c.roughness",
        "must be between 0 and 1",
    );
    check(
        &metal("metal = \"unobtainium\"\n"),
        15,
        "materials.c.metal",
        "unknown metal \"unobtainium\"; known: aluminium, chromium, copper, gold",
    );
    check(
        &metal("eta = [0.2, -0.4, 1.3]\nk = [3, 2, 1]\n"),
        15,
        "materials.c.eta",
        "must be greater than 0",
    );
    check(
        &metal("eta = [0.2, 0.4, 1.3]\nk = [3, -2, 1]\n"),
        16,
        "materials.c.k",
        "must not be negative",
    );
    check(
        &metal("eta = [0.2, 0.4, 1.3]\n"),
        13,
        "materials.c.k",
        "a conductor given `eta` needs `k`",
    );
    check(
        &metal("f0 = [0.9, 1.2, 0.5]\n"),
        15,
        "materials.c.f0",
        "must be at most 1",
    );
    check(
        &metal("f0 = [0.9, 0.9, 0.5]\nmetal = \"gold\"\n"),
        13,
        "materials.c",
        "exactly one of `metal`",
    );
    check(
        &metal("roughness = 0.3\n"),
        13,
        "materials.c",
        "exactly one of `metal`",
    );
    check(
        &metal("metal = \"gold\"\nalbedo = [1, 1, 1]\n"),
        16,
        "materials.c.albedo",
        "`albedo` does not apply to a conductor material",
    );
    check(
        &format!("{HEAD}[materials.g]\ntype = \"dielectric\"\nior = 1.5\nmetal = \"gold\"\n"),
        16,
        "materials.g.metal",
        "`metal` does not apply to a dielectric material",
    );
    check(
        &format!("{HEAD}[materials.d]\ntype = \"diffuse\"\nalbedo = [1, 1, 1]\nroughness = 0.2\n"),
        16,
        "materials.d.roughness",
        "`roughness` does not apply to a diffuse material",
    );
    check(
        &metal("metal = \"gold\"\nroughness = nan\n"),
        16,
        "materials.c.roughness",
        "must be between 0 and 1, got NaN",
    );
}

#[test]
fn dielectric_errors_name_the_key() {
    let glass = |body: &str| format!("{HEAD}[materials.g]\ntype = \"dielectric\"\n{body}");
    check(
        &glass("ior = 1.5\nroughness = 2\n"),
        16,
        "materials.g.roughness",
        "must be between 0 and 1, got 2",
    );
    check(
        &glass("ior = 0\nroughness = 0.5\n"),
        15,
        "materials.g.ior",
        "must be a finite number greater than 0, got 0",
    );
    check(
        &glass("ior = -1.5\n"),
        15,
        "materials.g.ior",
        "greater than 0, got -1.5",
    );
    check(
        &glass("ior = 1.5\nthin = true\nroughness = 0.3\n"),
        17,
        "materials.g.roughness",
        "rough thin sheets are not modelled",
    );
    check(
        &glass("ior = 1.5\nthin = true\nabsorption = [1, 1, 1]\n"),
        17,
        "materials.g.absorption",
        "a thin dielectric has no inside to absorb in",
    );
    check(
        &glass("ior = 1.5\nabsorption = [1, -1, 1]\n"),
        16,
        "materials.g.absorption",
        "must not be negative",
    );
    check(
        &glass("ior = 1.5\nabsorption = [1, inf, 1]\n"),
        16,
        "materials.g.absorption",
        "must be finite",
    );
    check(
        &glass("roughness = 0.3\n"),
        13,
        "materials.g.ior",
        "a dielectric material needs `ior`",
    );
}

#[test]
fn punctual_light_errors_name_the_key() {
    let light = |body: &str| format!("{HEAD}[[lights]]\n{body}");
    check(
        &light("type = \"spot\"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\nintensity = [1, 1, 1]\ninner_angle = 30\nouter_angle = 20\n"),
        19,
        "lights[0].outer_angle",
        "must be greater than inner_angle (30)",
    );
    // Blender's blend: from 0 to 1, and in place of `inner_angle`.
    check(
        &light("type = \"spot\"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\nintensity = [1, 1, 1]\nblend = 1.5\n"),
        18,
        "lights[0].blend",
        "must be from 0 to 1, got 1.5",
    );
    check(
        &light("type = \"spot\"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\nintensity = [1, 1, 1]\nblend = 0.2\ninner_angle = 10\n"),
        18,
        "lights[0].blend",
        "give `blend` or `inner_angle`, not both",
    );
    check(
        &light("type = \"spot\"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\nintensity = [1, 1, 1]\nouter_angle = 120\n"),
        18,
        "lights[0].outer_angle",
        "at most 90 degrees, got 120",
    );
    check(
        &light("type = \"point\"\nintensity = [1, 1, 1]\n"),
        13,
        "lights[0].position",
        "a point light needs `position`",
    );
    check(
        &light("type = \"point\"\nposition = [0, 1, 0]\nintensity = [0, 0, 0]\n"),
        16,
        "lights[0].intensity",
        "a light must emit something",
    );
    check(
        &light("type = \"point\"\nposition = [0, 1, 0]\nintensity = [1, -1, 1]\n"),
        16,
        "lights[0].intensity",
        "must not be negative",
    );
    check(
        &light("type = \"directional\"\ndirection = [0, 0, 0]\nirradiance = [1, 1, 1]\n"),
        15,
        "lights[0].direction",
        "must not be zero",
    );
    check(
        &light("type = \"directional\"\ndirection = [0, -1, 0]\nintensity = [1, 1, 1]\n"),
        16,
        "lights[0].intensity",
        "`intensity` does not apply to a directional light",
    );
    check(
        &light(
            "type = \"directional\"\ndirection = [0, -1, 0]\nirradiance = [1, 1, 1]\nangle = 120\n",
        ),
        17,
        "lights[0].angle",
        "must be from 0 to 90 degrees, got 120",
    );
    check(
        &light("type = \"directional\"\ndirection = [0, -1, 0]\nirradiance = [1, 1, 1]\nangle = -0.5\n"),
        17,
        "lights[0].angle",
        "must be from 0 to 90 degrees, got -0.5",
    );
    check(
        &light("type = \"directional\"\ndirection = [0, -1, 0]\nirradiance = [1e36, 1, 1]\nangle = 0.001\n"),
        16,
        "lights[0].irradiance",
        "overflows a 32-bit float",
    );
    check(
        &light("type = \"area\"\n"),
        14,
        "lights[0].type",
        "unknown variant `area`",
    );
}

/// `[render] denoise`: `true`, `false` or a table of a known quality and `ldr`; anything else
/// is refused where it is written.
#[test]
fn render_denoise_is_a_switch_or_known_options() {
    let scene = |render: &str| {
        format!("{HEAD}[render]\n{render}\n[[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\nradius = 1.0\n")
    };
    let load = |text: &str| {
        Scene::text(text, Format::Toml, "s.toml", &Limits::default())
            .load()
            .unwrap_or_else(|e| panic!("{e}"))
            .denoise
    };
    assert_eq!(load(&scene("max_depth = 3")), None);
    assert_eq!(load(&scene("denoise = false")), None);
    let on = load(&scene("denoise = true")).expect("on");
    assert_eq!((on.quality.as_str(), on.hdr), ("high", true));
    let fast = load(&scene("denoise = { quality = \"fast\", ldr = true }")).expect("on");
    assert_eq!((fast.quality.as_str(), fast.hdr), ("fast", false));
    check(
        &scene("denoise = { quality = \"best\" }"),
        14,
        "render.denoise.quality",
        "\"best\" is not fast, balanced or high",
    );
    check(
        &scene("denoise = 3"),
        14,
        "render.denoise",
        "true, false, or a table of `quality` and `ldr`",
    );
    check(
        &scene("denoise = { strength = 2 }"),
        14,
        "render.denoise.strength",
        "unknown field `strength`, expected `quality` or `ldr`",
    );
}
