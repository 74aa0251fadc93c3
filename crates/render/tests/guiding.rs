//! Path guiding (issue #60) is unbiased and deterministic: guided renders agree with unguided
//! ones within their noise on the hard cases guiding is for and on a furnace, a guide trained
//! on garbage changes the noise and not the mean at any selection probability a leaf may
//! choose, an epoch whose guide does not pay renders the unguided bits, and the same guided
//! render gives the same bits on any number of threads.

mod common;

use glam::{Vec2, Vec3A};
use tessera_render::guide::{from_square, SdTree, ALPHAS, DEFAULT_ALPHA};
use tessera_render::guiding::{
    guides, render_frame_guided, render_tile_guided, FIRST_OFF_EPOCH, OFF_ABOVE,
};
use tessera_render::scene::Scene;
use tessera_render::{assemble_render, Image, PixelRect, RenderSettings};

fn settings(spp: u32, seed: u64) -> RenderSettings {
    RenderSettings {
        spp,
        seed,
        ..RenderSettings::default()
    }
}

/// A bundled scene at `size`×`size` pixels.
fn small(name: &str, size: u32) -> Scene {
    let path = common::repo_root().join("scenes").join(name);
    let text = std::fs::read_to_string(&path).expect("bundled scene");
    let text: Vec<String> = text
        .lines()
        .map(|l| match l.split_once(" = ") {
            Some(("width" | "height", _)) => format!("{} = {size}", &l[..l.find(' ').unwrap_or(0)]),
            _ => l.to_string(),
        })
        .collect();
    common::scene(&text.join("\n"))
}

fn guided(scene: &Scene, settings: &RenderSettings) -> Image {
    render_frame_guided(scene, settings, &|_| {})
        .sums
        .finalize()
}

/// Guided and unguided renders of `scene` (different seeds) agree: few pixel-channels beyond
/// 4σ, no 4×4 block beyond 6σ (the caustics' variance estimates are heavy-tailed at this
/// spp, so the bound leaves them room; a bias of a few percent fails it).
fn agree(name: &str, scene: &Scene, spp: u32) {
    let plain = common::render(scene, &settings(spp, 1));
    let with = guided(scene, &settings(spp, 2));
    agree_images(name, &plain, &with);
}

/// [`agree`]'s checks of two renders of one scene.
fn agree_images(name: &str, plain: &Image, with: &Image) {
    let (frac, worst) = common::z_test(plain, with);
    assert!(frac < 0.01, "{name}: {frac} of pixel-channels beyond 4σ");
    assert!(worst < 6.0, "{name}: a 4×4 block {worst:.2}σ apart");
    let (m0, s0) = common::region_stats(plain, 0, 0, plain.width, plain.height);
    let (m1, s1) = common::region_stats(with, 0, 0, with.width, with.height);
    for c in 0..3 {
        let z = (m0[c] - m1[c]).abs() / (s0[c] * s0[c] + s1[c] * s1[c]).sqrt().max(1e-12);
        assert!(
            z < 4.0,
            "{name}: image means {} and {} are {z:.2}σ apart",
            m0[c],
            m1[c]
        );
    }
}

#[test]
fn guided_renders_agree_with_unguided_ones_on_the_hard_cases() {
    for name in ["caustic.toml", "glass-mirror.toml"] {
        agree(name, &small(name, 48), 256);
    }
}

/// A guided render turns guiding off on these scenes from sample 7, so the test above mostly
/// compares unguided samples: here every sample of a 256-spp render samples a guide learned
/// as a guided render learns it (epochs 0–2 of a 128×128 render, whose guide holds where the
/// 48×48 one samples it: leaves are in the scene's space), each leaf with its own α, some
/// above 0.
#[test]
fn renders_sampling_a_learned_guide_throughout_agree_with_unguided_ones() {
    for name in ["caustic.toml", "glass-mirror.toml"] {
        let scene = small(name, 48);
        let guide = render_frame_guided(&small(name, 128), &settings(15, 8), &|_| {})
            .guide
            .expect("a guide");
        let h = guide.alpha_histogram();
        assert!(h[1..].iter().sum::<usize>() > 0, "{name}: α per leaf {h:?}");
        let with = with_guide(&scene, &settings(1024, 9), &guide);
        let plain = common::render(&scene, &settings(1024, 10));
        agree_images(name, &plain, &with);
    }
}

#[test]
fn a_guided_furnace_gives_its_analytic_radiance() {
    // Le/(1 − ρ) everywhere: 0.5/(1 − 0.8) = 2.5.
    let img = guided(&furnace(), &settings(128, 3));
    assert_furnace(&img, "");
}

/// A closed sphere of albedo 0.8 emitting 0.5, seen from inside at 16×16: Le/(1 − ρ) = 2.5
/// everywhere.
fn furnace() -> Scene {
    common::scene(&common::closed_sphere([0.8; 3], [0.5; 3], 16, 16))
}

/// `img` of [`furnace`] is 2.5 within 4σ in each channel; `what` names the case.
fn assert_furnace(img: &Image, what: &str) {
    let (mean, se) = common::region_stats(img, 0, 0, 16, 16);
    for c in 0..3 {
        assert!(
            (mean[c] - 2.5).abs() < 4.0 * se[c] + 1e-4,
            "{what}channel {c}: {} ± {}",
            mean[c],
            se[c]
        );
    }
}

/// A guide that has learned that all light arrives from one quarter of the sphere's
/// longitudes, and most from one small patch of it: nowhere near where it comes from in
/// any test scene. One spatial leaf, so that every vertex samples the garbage, with
/// probability `ALPHAS[alpha]` (its last epoch measured that candidate least).
fn garbage(alpha: usize) -> SdTree {
    let mut garbage = SdTree::new(Vec3A::splat(-10.0), Vec3A::splat(10.0));
    for _ in 0..3 {
        let mut next = garbage.refined(u64::MAX, 0.01);
        for i in 0..20_000 {
            let u = Vec2::new(
                (i % 97) as f32 / 97.0 * 0.25,
                0.1 + (i % 89) as f32 / 89.0 * 0.8,
            );
            let u = if i % 4 == 0 {
                u
            } else {
                u * 0.1 + Vec2::new(0.1, 0.5)
            };
            next.record(Vec3A::ZERO, from_square(u), 1.0);
        }
        let moments = std::array::from_fn(|i| 1.0 + (i as f64 - alpha as f64).abs());
        next.record_with(Vec3A::ZERO, Vec3A::Z, 1.0, Some(&moments));
        next.freeze();
        garbage = next;
    }
    assert_eq!(garbage.alpha_at(Vec3A::ZERO).1, ALPHAS[alpha]);
    garbage
}

/// The rectangle of the whole frame.
fn whole(scene: &Scene) -> PixelRect {
    PixelRect {
        x0: 0,
        y0: 0,
        width: scene.width,
        height: scene.height,
    }
}

/// `scene` rendered whole as one tile, sampling `guide` and training nothing (samples from
/// 0, so epoch 0, which never turns guiding off).
fn with_guide(scene: &Scene, s: &RenderSettings, guide: &SdTree) -> Image {
    let (sums, trained) = render_tile_guided(scene, s, whole(scene), 0..s.spp, Some(guide), None);
    assert!(trained.is_none());
    frame_of(s, scene, sums)
}

fn frame_of(s: &RenderSettings, scene: &Scene, sums: tessera_render::TileSums) -> Image {
    assemble_render(s, scene.width, scene.height, &[sums])
        .expect("one tile, the frame")
        .finalize()
}

/// At the default selection probability and at the largest a leaf may choose.
#[test]
fn a_guide_trained_on_garbage_stays_unbiased() {
    for alpha in [
        ALPHAS.iter().position(|&a| a == DEFAULT_ALPHA),
        Some(ALPHAS.len() - 1),
    ] {
        let alpha = alpha.expect("a candidate");
        let guide = garbage(alpha);
        assert!(guide.at(Vec3A::ZERO).len() > 10, "the garbage was learned");
        // The furnace: exactly Le/(1 − ρ).
        let img = with_guide(&furnace(), &settings(64, 4), &guide);
        assert_furnace(&img, &format!("α = {}: ", ALPHAS[alpha]));
        // The caustic, against an unguided render.
        let scene = small("caustic.toml", 32);
        let with = with_guide(&scene, &settings(512, 5), &guide);
        let plain = common::render(&scene, &settings(512, 6));
        let (frac, worst) = common::z_test(&plain, &with);
        let a = ALPHAS[alpha];
        assert!(frac < 0.01, "α = {a}: {frac} of pixel-channels beyond 4σ");
        assert!(worst < 6.0, "α = {a}: a 4×4 block {worst:.2}σ apart");
    }
}

/// The next guide after `guide`, one leaf trained, whose largest α measured `gain` of the
/// cosine lobe's second moment and every other candidate as much as the lobe: it chooses the
/// largest α, with ratio `gain`.
fn measured(guide: &SdTree, gain: f64) -> SdTree {
    let mut next = guide.refined(u64::MAX, 0.01);
    next.record(Vec3A::ZERO, Vec3A::Z, 1.0);
    let m = std::array::from_fn(|i| if i + 1 == ALPHAS.len() { gain } else { 1.0 });
    next.record_with(Vec3A::ZERO, Vec3A::Z, 1.0, Some(&m));
    next.freeze();
    next
}

/// From [`FIRST_OFF_EPOCH`] on, a guide whose leaves all chose α = 0, or whose choices
/// measured more than [`OFF_ABOVE`] of the cosine lobe's second moment, is not sampled: the
/// epoch's unit is the unguided renderer's bits, and its training tree comes back with
/// nothing recorded. Before that epoch the same guide is sampled and trains.
#[test]
fn an_epoch_whose_guide_does_not_pay_renders_unguided_and_trains_nothing() {
    let scene = small("glass-mirror.toml", 16);
    let s = settings(64, 7);
    // Epochs of 64 spp: [0,1) [1,3) [3,7) [7,15) [15,31) [31,64).
    let off_epoch = 7..15;
    let on_epoch = 3..7;
    // Every leaf chose 0 (its second moments least there); then every leaf chose ¾ but only
    // gained a little: both are off from epoch 3, and sampled before.
    for (alpha, gain) in [(0, None), (ALPHAS.len() - 1, Some(0.9))] {
        let mut guide = garbage(alpha);
        if let Some(g) = gain {
            guide = measured(&guide, g);
            assert!(guide.guides(), "a leaf samples it");
            assert!(guide.second_moment_ratio().is_some_and(|r| r > OFF_ABOVE));
        }
        assert!(guides(FIRST_OFF_EPOCH - 1, Some(&guide)));
        assert!(!guides(FIRST_OFF_EPOCH, Some(&guide)));
        let structure = guide.refined(u64::MAX, 0.01);
        let (sums, trained) = render_tile_guided(
            &scene,
            &s,
            whole(&scene),
            off_epoch.clone(),
            Some(&guide),
            Some(&structure),
        );
        let plain = tessera_render::render_tile(&scene, &s, whole(&scene), off_epoch.clone());
        let bits = |t: &tessera_render::TileSums| {
            (t.sum.iter().chain(&t.sum_sq))
                .flat_map(|v| v.map(f64::to_bits))
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&sums), bits(&plain), "the unguided bits");
        let trained = trained.expect("the epoch trains");
        assert_eq!(trained.records(), 0);
        assert!(trained.same_shape(&structure));
        let (_, on) = render_tile_guided(
            &scene,
            &s,
            whole(&scene),
            on_epoch.clone(),
            Some(&guide),
            Some(&structure),
        );
        assert!(on.is_some_and(|t| t.records() > 0), "epoch 2 trains");
    }
    // A guide sampled at a good gain stays on.
    let good = measured(&garbage(ALPHAS.len() - 1), 0.3);
    assert!(guides(FIRST_OFF_EPOCH + 5, Some(&good)));
    assert!(!guides(0, None));
}

#[test]
fn a_guided_render_is_the_same_bits_on_any_number_of_threads() {
    let scene = small("glass-mirror.toml", 24);
    let s = settings(16, 9);
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| render_frame_guided(&scene, &s, &|_| {}))
    };
    let one = run(1);
    let three = run(3);
    assert_eq!(one.epochs, three.epochs);
    assert!(one.epochs.last().is_some_and(|e| e.guide_leaves > 0));
    let bits = |f: &tessera_render::guiding::GuidedFrame| {
        f.sums
            .sum
            .iter()
            .chain(&f.sums.sum_sq)
            .flat_map(|v| v.map(f64::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&one), bits(&three));
}
