//! `[animation]`: a frame of an animated scene is the still scene its keys describe there, and
//! bad keys are refused with their place in the file.

mod common;

use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{render_frame, RenderSettings};

fn still(eye_z: f32, ball_x: f32) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1, {eye_z}]\ntarget = [0, 0.5, 0]\nfov = 50\n\
         [film]\nwidth = 24\nheight = 16\n[environment]\ntype = \"constant\"\nradiance = [1, 1, 1]\n\
         [materials.grey]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
         [[objects]]\nshape = \"plane\"\nmaterial = \"grey\"\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"grey\"\nradius = 0.5\ncenter = [0, 0.5, 0]\ntransform = {{ translate = [{ball_x}, 0, 0] }}\n"
    )
}

fn animated() -> String {
    // The ball's own transform is kept: the keys move it from there.
    still(4.0, 0.0).replace("transform = { translate = [0, 0, 0] }", "")
        + "[animation]\n\
           [[animation.camera]]\nframe = 1\neye = [0, 1, 4]\n\
           [[animation.camera]]\nframe = 9\neye = [0, 1, 3]\n\
           [[animation.objects]]\nobject = 1\nkeys = [{ frame = 1, translate = [-1, 0, 0] }, { frame = 9, translate = [1, 0, 0] }]\n"
}

fn render(scene: &Scene) -> Vec<[f64; 3]> {
    let settings = RenderSettings {
        spp: 8,
        seed: 2,
        ..RenderSettings::default()
    };
    render_frame(scene, &settings, &|_| {}).sum
}

fn at(text: &str, frame: u32) -> Scene {
    Scene::text(text, Format::Toml, "a.toml", &Limits::default())
        .at(frame)
        .load()
        .unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn a_frame_renders_the_still_scene_its_keys_give() {
    let text = animated();
    // Frame 5 is halfway: eye z 3.5, ball x 0; frames outside the keys hold the ends.
    for (frame, eye_z, ball_x) in [
        (5, 3.5, 0.0),
        (1, 4.0, -1.0),
        (9, 3.0, 1.0),
        (40, 3.0, 1.0),
        (0, 4.0, -1.0),
    ] {
        let want = render(&common::scene(&still(eye_z, ball_x)));
        assert!(render(&at(&text, frame)) == want, "frame {frame}");
    }
    assert!(
        render(&at(&text, 3)) != render(&at(&text, 5)),
        "frames must differ"
    );
    // The hash is the file's: one scene, many frames.
    assert_eq!(at(&text, 1).hash, at(&text, 7).hash);
}

#[test]
fn bad_animations_name_the_key_and_line() {
    let base = animated();
    let cases = [
        (
            base.replace("frame = 9\neye", "frame = 1\neye"),
            "animation.camera[1].frame",
        ),
        (
            base.replace("object = 1", "object = 7"),
            "object 7 does not exist",
        ),
        (
            base.replace("frame = 9\neye = [0, 1, 3]", "frame = 9\nfov = 30"),
            "same fields",
        ),
        (base.replace("eye = [0, 1, 3]", "eye = [0, 1]"), "3 numbers"),
        (
            base + "[[animation.objects]]\nobject = 1\nkeys = [{ frame = 1 }]\n",
            "animated twice",
        ),
    ];
    for (text, want) in cases {
        let e = Scene::text(&text, Format::Toml, "a.toml", &Limits::default())
            .at(3)
            .load()
            .expect_err(want)
            .to_string();
        assert!(e.contains(want), "{e}");
        assert!(e.starts_with("a.toml:"), "{e}");
    }
}
