//! The real library (installed by `scripts/install-oidn.sh`, as a user installs it): the
//! version it reports, that denoising brings a noisy image closer to the truth, that it is the
//! same bits on any number of threads, and that bad pixels do not reach it.

use tessera_denoise::{denoise, library_version, Frame, Options, Quality};

/// A smooth image (a gradient lit from one side), and the same with deterministic noise of
/// about ±40% per pixel, as a render of a few samples is.
fn images(w: u32, h: u32) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut truth = Vec::new();
    let mut noisy = Vec::new();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for y in 0..h {
        for x in 0..w {
            let v = 0.2 + 0.8 * x as f32 / w as f32;
            let c = [v, 0.5 * v, 0.25 + 0.5 * y as f32 / h as f32];
            truth.push(c);
            noisy.push(c.map(|c| {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                let u = (state >> 40) as f32 / (1u64 << 24) as f32;
                c * (0.6 + 0.8 * u)
            }));
        }
    }
    (truth, noisy)
}

#[test]
fn the_installed_library_is_open_image_denoise_2_5_1() {
    tessera_testkit::install_oidn();
    assert_eq!(library_version().expect("the library loads"), 20501);
}

#[test]
fn a_noisy_image_comes_out_closer_to_the_truth_and_the_same_on_any_thread_count() {
    tessera_testkit::install_oidn();
    let (w, h) = (64, 48);
    let (truth, noisy) = images(w, h);
    let albedo = vec![[0.8f32, 0.8, 0.8]; (w * h) as usize];
    let normal = vec![[0.0f32, 0.0, 1.0]; (w * h) as usize];
    let frame = Frame {
        width: w,
        height: h,
        color: &noisy,
        albedo: &albedo,
        normal: &normal,
    };
    let one = denoise(
        &frame,
        &Options {
            threads: Some(1),
            ..Options::default()
        },
    )
    .expect("denoised");
    let (before, after) = (
        tessera_testkit::rel_mse(&noisy, &truth),
        tessera_testkit::rel_mse(&one.color, &truth),
    );
    assert!(
        after < before / 5.0,
        "relMSE {before} before denoising, {after} after"
    );
    let two = denoise(
        &frame,
        &Options {
            threads: Some(2),
            ..Options::default()
        },
    )
    .expect("denoised");
    assert!(one == two, "one and two threads gave different bits");
    // Each quality runs, and the fast one is a different filter.
    let fast = denoise(
        &frame,
        &Options {
            quality: Quality::Fast,
            ..Options::default()
        },
    )
    .expect("denoised");
    assert!(tessera_testkit::rel_mse(&fast.color, &truth) < before);
}

#[test]
fn non_finite_pixels_do_not_reach_the_filter() {
    tessera_testkit::install_oidn();
    let (w, h) = (16, 16);
    let (_, mut noisy) = images(w, h);
    noisy[5] = [f32::NAN, f32::INFINITY, -f32::INFINITY];
    let aux = vec![[0.5f32; 3]; (w * h) as usize];
    let out = denoise(
        &Frame {
            width: w,
            height: h,
            color: &noisy,
            albedo: &aux,
            normal: &aux,
        },
        &Options::default(),
    )
    .expect("denoised");
    assert!(out.color.iter().flatten().all(|c| c.is_finite()));
}
