//! AOVs for denoising: what each plane holds, checked where the answer is known exactly; that
//! they leave the beauty's bits alone; and that they merge like the beauty.

mod common;

use common::{load, render, scene};
use tessera_render::{render_tile, Aovs, PixelRect, RenderSettings};

fn with_aovs(spp: u32, batch: u32) -> RenderSettings {
    RenderSettings {
        spp,
        batch,
        seed: 3,
        aovs: Aovs::ALL,
        ..RenderSettings::default()
    }
}

/// The camera at the centre of a two-sided diffuse sphere of radius 2 (dyadic albedo, so
/// means of it are exact), with `extra` objects and materials.
fn inside_sphere(target: &str, extra: &str) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1, 0]\ntarget = {target}\nfov = 60\n\
         [film]\nwidth = 8\nheight = 8\n\
         [materials.shell]\ntype = \"diffuse\"\nalbedo = [0.5, 0.25, 0.125]\ntwo_sided = true\n\
         {extra}\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"shell\"\ncenter = [0, 1, 0]\nradius = 2.0\n"
    )
}

#[test]
fn inside_a_sphere_every_pixel_sees_its_albedo_at_its_radius_facing_back() {
    let sc = scene(&inside_sphere("[1, 1, 0.3]", ""));
    let img = render(&sc, &with_aovs(16, 8));
    let aov = img.aov.as_ref().expect("AOV planes");
    for y in 0..8 {
        for x in 0..8 {
            let i = (y * 8 + x) as usize;
            assert_eq!(aov.albedo[i], [0.5, 0.25, 0.125], "pixel ({x}, {y})");
            assert!((aov.depth[i] - 2.0).abs() < 1e-4, "depth {}", aov.depth[i]);
            // The mean of the normals facing back along the pixel's rays points back along
            // the pixel's centre ray, and is nearly unit (the rays of a pixel differ little).
            let d = sc.camera.ray(x as f32 + 0.5, y as f32 + 0.5).d;
            let n = aov.normal[i];
            let dot = n[0] * d.x + n[1] * d.y + n[2] * d.z;
            assert!(dot < -0.995, "pixel ({x}, {y}): normal {n:?} · ray {dot}");
        }
    }
}

#[test]
fn a_mirror_shows_the_albedo_it_reflects_and_the_depth_of_the_mirror() {
    // Looking down at 45° onto a mirror floor at y = 0: the lower half of the frame meets the
    // mirror first, one unit or so away, and sees the sphere's albedo in it.
    let floor = "[materials.floor]\ntype = \"mirror\"\n\
                 [[objects]]\nshape = \"plane\"\nmaterial = \"floor\"\n";
    let sc = scene(&inside_sphere("[0, 0, 1]", floor));
    let img = render(&sc, &with_aovs(8, 8));
    let aov = img.aov.as_ref().expect("AOV planes");
    for x in 0..8 {
        let i = 7 * 8 + x;
        assert_eq!(aov.albedo[i], [0.5, 0.25, 0.125], "bottom row, column {x}");
        assert!(
            aov.depth[i] < 1.9,
            "the mirror is nearer than the sphere: {}",
            aov.depth[i]
        );
        // The sphere's normal, seen via the floor, faces down-ish: the reflected rays go up.
        assert!(aov.normal[7 * 8 + x][1] < 0.0, "{:?}", aov.normal[i]);
    }
    // The same floor, diffuse: its own albedo and its own normal (up).
    let floor = "[materials.floor]\ntype = \"diffuse\"\nalbedo = [0.75, 0.75, 0.75]\n\
                 [[objects]]\nshape = \"plane\"\nmaterial = \"floor\"\n";
    let img = render(&scene(&inside_sphere("[0, 0, 1]", floor)), &with_aovs(8, 8));
    let aov = img.aov.as_ref().expect("AOV planes");
    assert_eq!(aov.albedo[60], [0.75; 3]);
    assert!(
        (aov.normal[60][1] - 1.0).abs() < 1e-6,
        "{:?}",
        aov.normal[60]
    );
}

#[test]
fn a_lamp_seen_from_its_front_records_its_emitted_colour_and_from_behind_its_material() {
    // Two one-sided rect lamps of the white material, emission (4, 2, 1): the left one faces
    // the camera (front normal +z towards it), the right one faces away.
    let lamps = "[materials.lamp]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
                 emission = [4, 2, 1]\n\
                 [[objects]]\nshape = \"rect\"\nmaterial = \"lamp\"\nsize = [4, 4]\n\
                 transform = { translate = [-2.2, 0, 0] }\n\
                 [[objects]]\nshape = \"rect\"\nmaterial = \"lamp\"\nsize = [4, 4]\n\
                 transform.matrix = [[-1, 0, 0, 2.2], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]\n";
    let sc = scene(&format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 6]\ntarget = [0, 0, 0]\nfov = 40\n\
         [film]\nwidth = 8\nheight = 8\n{lamps}"
    ));
    let img = render(&sc, &with_aovs(4, 4));
    let aov = img.aov.as_ref().expect("AOV planes");
    let (left, right) = (3 * 8 + 1, 3 * 8 + 6);
    // The emitted colour with its largest channel 1: an edge for the denoiser against a
    // surround of the lamp's own albedo.
    assert_eq!(aov.albedo[left], [1.0, 0.5, 0.25]);
    // Nothing is emitted backwards: the back records what its material does.
    assert_ne!(aov.albedo[right], [1.0, 0.5, 0.25]);
    let beauty = img.rgb[right];
    assert_eq!(beauty, [0.0; 3], "the lamp's back emits nothing");
}

#[test]
fn a_ray_that_meets_nothing_has_no_albedo_no_normal_and_infinite_depth() {
    let sc = scene(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 0]\ntarget = [0, 0, 1]\nfov = 20\n\
         [film]\nwidth = 8\nheight = 8\n[environment]\ntype = \"constant\"\nradiance = [1, 1, 1]\n\
         [materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\ncenter = [0, 0, 10]\nradius = 1.0\n",
    );
    let img = render(&sc, &with_aovs(4, 4));
    let aov = img.aov.as_ref().expect("AOV planes");
    assert_eq!(aov.albedo[0], [0.0; 3]);
    assert_eq!(aov.normal[0], [0.0; 3]);
    assert_eq!(aov.depth[0], f32::INFINITY);
    // Within 2.5° of the axis every ray meets the sphere's near side, 9 to 9.09 away
    // (10 cos θ − √(1 − 100 sin² θ)).
    let centre = 3 * 8 + 3;
    assert!(
        (9.0..9.09).contains(&aov.depth[centre]),
        "{}",
        aov.depth[centre]
    );
    assert_eq!(aov.albedo[centre], [0.5; 3]);
}

#[test]
fn asking_for_aovs_leaves_every_bit_of_the_beauty() {
    let sc = load("cornell-box.toml");
    let plain = RenderSettings {
        spp: 4,
        batch: 2,
        seed: 3,
        ..RenderSettings::default()
    };
    let a = tessera_render::render_frame(&sc, &plain, &|_| {});
    let b = tessera_render::render_frame(&sc, &with_aovs(4, 2), &|_| {});
    assert!(a.aov.is_none() && b.aov.is_some());
    assert!(a.sum == b.sum && a.sum_sq == b.sum_sq && a.count == b.count);
}

#[test]
fn aov_sums_of_two_batches_merge_to_the_bits_of_one_call() {
    let sc = load("glass-mirror.toml");
    let settings = with_aovs(8, 4);
    let rect = PixelRect {
        x0: 100,
        y0: 120,
        width: 12,
        height: 5,
    };
    let whole = render_tile(&sc, &settings, rect, 0..8);
    let mut parts = render_tile(&sc, &settings, rect, 0..4);
    parts
        .merge(&render_tile(&sc, &settings, rect, 4..8))
        .expect("merges");
    assert_eq!(whole, parts);
    // A part without AOV sums does not merge into one with them.
    let plain = RenderSettings {
        aovs: Aovs::default(),
        ..settings
    };
    let mut first = render_tile(&sc, &settings, rect, 0..4);
    assert!(first.merge(&render_tile(&sc, &plain, rect, 4..8)).is_err());
}

#[test]
fn the_aov_list_parses_and_names_what_it_does_not_know() {
    assert_eq!(
        Aovs::parse("albedo, depth").expect("ok").list(),
        "albedo,depth"
    );
    assert_eq!(Aovs::parse("").expect("ok"), Aovs::default());
    let e = Aovs::parse("albedo,normals").expect_err("unknown");
    assert!(
        e.contains("\"normals\"") && e.contains("albedo, normal, depth"),
        "{e}"
    );
}
