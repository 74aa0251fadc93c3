//! Same job, same bits: whatever the thread count, tile size or batch cut.

mod common;

use common::load;
use tessera_render::output::{write_exr, ExrChannels};
use tessera_render::{
    assemble_frame, assemble_image, assemble_render, render_frame, render_tile, PixelRect,
    RenderSettings, Strategy, TileSums,
};

fn frame_by_tiles(
    scene: &tessera_render::scene::Scene,
    settings: &RenderSettings,
    tile: u32,
) -> TileSums {
    let tiles: Vec<TileSums> = PixelRect::tiles(scene.width, scene.height, tile)
        .into_iter()
        .map(|rect| {
            let mut acc = TileSums::empty(rect, 0);
            // Sample batches of 16 rendered separately and merged in order, as the farm does.
            for s in (0..settings.spp).step_by(16) {
                acc.merge(&render_tile(
                    scene,
                    settings,
                    rect,
                    s..(s + 16).min(settings.spp),
                ))
                .expect("in order");
            }
            acc
        })
        .collect();
    assemble_frame(scene.width, scene.height, settings.spp, &tiles).expect("fits")
}

#[test]
fn threads_tiles_and_batches_do_not_change_bits() {
    let scene = load("spheres.toml");
    let settings = RenderSettings {
        spp: 32,
        seed: 9,
        ..RenderSettings::default()
    };
    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .expect("pool")
    };
    let one = pool(1).install(|| render_frame(&scene, &settings, &|_| {}));
    let two = pool(2).install(|| render_frame(&scene, &settings, &|_| {}));
    assert_eq!(one, two, "1 vs 2 threads");
    for tile in [7, 16, 64, 1000] {
        let t = pool(2).install(|| frame_by_tiles(&scene, &settings, tile));
        assert_eq!(one, t, "tile size {tile}");
    }
    // The whole range in one call equals batches merged in order.
    let rect = PixelRect {
        x0: 50,
        y0: 40,
        width: 9,
        height: 5,
    };
    let whole = render_tile(&scene, &settings, rect, 0..32);
    let mut parts = render_tile(&scene, &settings, rect, 0..16);
    parts
        .merge(&render_tile(&scene, &settings, rect, 16..32))
        .expect("in order");
    assert_eq!(whole, parts);
    // Out-of-order merges are refused, not silently reordered.
    let mut a = render_tile(&scene, &settings, rect, 16..32);
    assert!(a
        .merge(&render_tile(&scene, &settings, rect, 0..16))
        .is_err());
}

#[test]
fn seed_decides_the_noise() {
    let scene = load("cornell-box.toml");
    let rect = PixelRect {
        x0: 100,
        y0: 100,
        width: 16,
        height: 16,
    };
    let s = |seed| {
        render_tile(
            &scene,
            &RenderSettings {
                spp: 8,
                seed,
                ..RenderSettings::default()
            },
            rect,
            0..8,
        )
    };
    assert_eq!(s(1), s(1));
    let (a, b) = (s(1), s(2));
    let differing = a.sum.iter().zip(&b.sum).filter(|(x, y)| x != y).count();
    assert!(
        differing > rect.area() * 9 / 10,
        "only {differing} pixels differ between seeds"
    );
}

#[test]
fn exr_files_are_bit_identical() {
    let scene = load("cornell-box.toml");
    let settings = RenderSettings {
        spp: 2,
        seed: 4,
        ..RenderSettings::default()
    };
    let img = render_frame(&scene, &settings, &|_| {}).finalize();
    let dir = std::env::temp_dir().join(format!("tessera-det-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp");
    let meta = vec![
        ("seed".to_string(), "4".to_string()),
        ("spp".to_string(), "2".to_string()),
    ];
    let ch = ExrChannels {
        variance: true,
        samples: true,
        ..ExrChannels::default()
    };
    write_exr(&dir.join("a.exr"), &img, ch, &meta).expect("write");
    write_exr(&dir.join("b.exr"), &img, ch, &meta).expect("write");
    let (a, b) = (
        std::fs::read(dir.join("a.exr")).expect("a"),
        std::fs::read(dir.join("b.exr")).expect("b"),
    );
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(a, b);
}

/// FNV-1a over the bits of a render's sums, squares and counts.
fn sums_hash(hash: &mut u64, t: &TileSums) {
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            *hash = (*hash ^ b as u64).wrapping_mul(0x100_0000_01b3);
        }
    };
    for (s, q) in t.sum.iter().zip(&t.sum_sq) {
        for c in 0..3 {
            eat(&s[c].to_bits().to_le_bytes());
            eat(&q[c].to_bits().to_le_bytes());
        }
    }
    for &k in &t.count {
        eat(&k.to_le_bytes());
    }
    eat(&t.nonfinite.to_le_bytes());
    if let Some(a) = &t.aov {
        for i in 0..a.count.len() {
            for c in 0..3 {
                eat(&a.albedo[i][c].to_bits().to_le_bytes());
                eat(&a.normal[i][c].to_bits().to_le_bytes());
            }
            eat(&a.depth[i].to_bits().to_le_bytes());
            eat(&a.hits[i].to_le_bytes());
            eat(&a.count[i].to_le_bytes());
        }
    }
}

/// The strip of `rows` rows through the middle of `scene`'s frame.
fn middle(scene: &tessera_render::scene::Scene, rows: u32) -> PixelRect {
    PixelRect {
        x0: 0,
        y0: scene.height / 2 - rows / 2,
        width: scene.width,
        height: rows,
    }
}

/// The image revision and the hash of its renders: the bundled scenes of each kind (analytic
/// shapes, glass, meshes, textures), plus an ellipsoid (the one shape they lack), for a few
/// samples of each strategy over a strip through the middle of the frame, and a guided render
/// of glass-mirror (since revision 6: before, guided bits could change unseen), and since
/// revision 7 the AOVs of the glTF sample (smooth normals, a normal map) and the textured scene,
/// and since revision 10 the material showcase (an environment map, every material kind, packed
/// and normal-map textures), whose map's bits were not pinned before, and since revision 12 the
/// ellipsoid's AOVs over its whole frame (its lamp in view), and since revision 13 a sphere under
/// a map wide enough for alias tables.
const PINNED: (u32, u64) = (16, 0xca5a_561f_75e0_457c);

/// The camera, film and diffuse material `a` of the pin's own scenes (an ellipsoid, a ball
/// under a wide map).
const PIN_VIEW: &str = r#"
version = 1
[camera]
model = "look_at"
eye = [0.0, 0.5, 4.0]
up = [0.0, 1.0, 0.0]
target = [0.0, 0.0, 0.0]
fov = 40.0
[film]
width = 48
height = 32
[materials.a]
type = "diffuse"
albedo = [0.7, 0.6, 0.5]"#;

/// The bits the renderer returns are pinned to [`tessera_render::IMAGE_REVISION`]: a change
/// that alters them must bump the revision (and update the hash here), because the farm refuses
/// to mix results of different revisions and can only do that if the number changes with the
/// bits. This is also a check that a render gives the same bits on every machine CI runs on.
#[test]
fn the_image_revision_pins_the_bits() {
    let ellipsoid = common::scene(&format!(
        r#"{PIN_VIEW}
[environment]
type = "constant"
radiance = [0.6, 0.7, 0.8]
[materials.lamp]
type = "diffuse"
albedo = [0.5, 0.5, 0.5]
emission = [5.0, 5.0, 5.0]
[[objects]]
shape = "sphere"
material = "a"
transform.matrix = [[1, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 0.8, 0], [0, 0, 0, 1]]
[[objects]]
shape = "sphere"
material = "lamp"
center = [1.5, 1.5, 1.0]
radius = 0.3
"#
    ));
    let scenes = [
        load("cornell-box.toml"),
        load("spheres.toml"),
        load("glass-mirror.toml"),
        // Triangles (the wide BVH and the four-lane test), smooth shading and textures.
        load("cornell-mesh.toml"),
        load("mesh-glass.toml"),
        load("textured.toml"),
        ellipsoid,
        load("materials.toml"),
    ];
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    // Eight samples of a strip through the middle, under each of `strategies`.
    let strips = |hash: &mut u64, scene: &tessera_render::scene::Scene, strategies: &[Strategy]| {
        for &strategy in strategies {
            let settings = RenderSettings {
                seed: 3,
                spp: 8,
                strategy,
                ..RenderSettings::default()
            };
            sums_hash(hash, &render_tile(scene, &settings, middle(scene, 8), 0..8));
        }
    };
    for scene in &scenes {
        strips(
            &mut hash,
            scene,
            &[Strategy::Mis, Strategy::Bsdf, Strategy::Nee],
        );
    }
    // Guided renders too (epochs, guides, each leaf's α, turning off from epoch 3): glass-mirror
    // at 16 spp has guided epochs and an unguided one after.
    let guided = RenderSettings {
        seed: 3,
        spp: 16,
        guiding: true,
        ..RenderSettings::default()
    };
    let frame = tessera_render::guiding::render_frame_guided(&scenes[2], &guided, &|_| {});
    sums_hash(&mut hash, &frame.sums);
    // AOVs (revision 7 clamped each sample's albedo and normal where it enters a sum).
    let aovs = RenderSettings {
        seed: 3,
        spp: 4,
        aovs: tessera_render::Aovs::parse("albedo,normal,depth").expect("aovs"),
        ..RenderSettings::default()
    };
    for scene in [&load("gltf/sample.glb"), &scenes[5]] {
        sums_hash(
            &mut hash,
            &render_tile(scene, &aovs, middle(scene, 4), 0..4),
        );
    }
    // The ellipsoid's whole frame, whose lamp the camera sees (revision 12 records an
    // emitter's colour as its albedo).
    let whole = PixelRect {
        x0: 0,
        y0: 0,
        width: scenes[6].width,
        height: scenes[6].height,
    };
    sums_hash(&mut hash, &render_tile(&scenes[6], &aovs, whole, 0..4));
    // A map wide enough to draw its columns from alias tables (revision 13), under which the
    // bundled scenes' 64-wide sky never comes.
    let (w, h) = (512, 6);
    let texels: Vec<glam::Vec3A> = (0..w * h)
        .map(|k| {
            let (x, y) = ((k % w) as f32, (k / w) as f32);
            glam::Vec3A::new(1.0 + (x * 0.05).sin(), 0.5 + 0.1 * y, 0.2 + 0.001 * x)
                * if k == 3 * w / 2 { 500.0 } else { 1.0 }
        })
        .collect();
    let wide = common::scene_with_files(
        &format!(
            r#"{PIN_VIEW}
[environment]
type = "map"
file = "sky.exr"
rotate = 20.0
[[objects]]
shape = "sphere"
material = "a"
center = [0.0, 0.0, 0.0]
radius = 1.0
"#
        ),
        &[("sky.exr", &common::exr_bytes(w, h, &texels))],
    );
    strips(&mut hash, &wide, &[Strategy::Mis, Strategy::Nee]);
    assert_eq!(
        (tessera_render::IMAGE_REVISION, hash),
        PINNED,
        "the renderer's bits changed (hash {hash:#x}): if that is intended, bump \
         IMAGE_REVISION in crates/render/src/lib.rs and set PINNED in this test to \
         (the new revision, {hash:#x})"
    );
}

/// The farm writes its frames a band of tiles at a time ([`assemble_image`] puts those strips
/// together), `tessera render` from one frame of sums: the two images must be the same bits,
/// for full and adaptive renders, and the tile-by-tile path must refuse what the frame path
/// refuses.
#[test]
fn an_image_assembled_tile_by_tile_is_the_frame_finalized() {
    let scene = load("spheres.toml");
    let mut settings = RenderSettings {
        spp: 8,
        seed: 3,
        ..RenderSettings::default()
    };
    let rects = PixelRect::tiles(scene.width, scene.height, 24);
    let tiles = |settings: &RenderSettings, ends: &dyn Fn(usize) -> u32| -> Vec<TileSums> {
        rects
            .iter()
            .enumerate()
            .map(|(i, r)| render_tile(&scene, settings, *r, 0..ends(i)))
            .collect()
    };
    let full = tiles(&settings, &|_| 8);
    let want = assemble_render(&settings, scene.width, scene.height, &full)
        .expect("fits")
        .finalize();
    let got = assemble_image(&settings, scene.width, scene.height, full.clone()).expect("fits");
    assert_eq!(got, want);
    // A tile left out is black in both.
    let some: Vec<TileSums> = full.iter().skip(1).cloned().collect();
    assert_eq!(
        assemble_image(&settings, scene.width, scene.height, some.clone()).expect("fits"),
        assemble_render(&settings, scene.width, scene.height, &some)
            .expect("fits")
            .finalize()
    );
    // Adaptive: tiles stop at different sample counts.
    settings.adaptive = Some(tessera_render::Adaptive {
        noise_target: 0.1,
        tile: 24,
    });
    let ragged = tiles(&settings, &|i| 2 + (i as u32 % 4) * 2);
    assert_eq!(
        assemble_image(&settings, scene.width, scene.height, ragged.clone()).expect("fits"),
        assemble_render(&settings, scene.width, scene.height, &ragged)
            .expect("fits")
            .finalize()
    );
    // Refused alike: a tile past the cap, a tile outside the frame.
    settings.adaptive = None;
    assert!(assemble_image(&settings, scene.width, scene.height, ragged).is_err());
    let mut outside = full[0].clone();
    outside.rect.x0 = scene.width - 1;
    assert!(assemble_image(&settings, scene.width, scene.height, vec![outside]).is_err());
}
