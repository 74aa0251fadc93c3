//! Noise-targeted adaptive sampling: every tile stops at the first batch at which its merged
//! sums reach its Neyman count under the scale of every tile's pilot, the bits are the same for
//! any thread count, and the answer stays right.

mod common;

use common::{load, region_stats, scene};
use tessera_render::adaptive::{min_batches, neyman_scale, tile_wants_more};
use tessera_render::{render_frame, render_tile, Adaptive, PixelRect, RenderSettings, TileSums};

fn adaptive(spp: u32, batch: u32, target: f64, tile: u32) -> RenderSettings {
    RenderSettings {
        seed: 5,
        spp,
        batch,
        adaptive: Some(Adaptive::new(target, tile).expect("target")),
        ..RenderSettings::default()
    }
}

/// Samples each tile of `rect`s took in `frame` (every pixel of a tile takes the same number,
/// as no sample of these scenes is non-finite).
fn tile_counts(frame: &TileSums, tiles: &[PixelRect]) -> Vec<u32> {
    tiles
        .iter()
        .map(|t| {
            let first = frame.count[(t.y0 * frame.rect.width + t.x0) as usize];
            for y in t.y0..t.y0 + t.height {
                for x in t.x0..t.x0 + t.width {
                    assert_eq!(frame.count[(y * frame.rect.width + x) as usize], first);
                }
            }
            first
        })
        .collect()
}

#[test]
fn every_tile_stops_at_the_first_batch_whose_sums_reach_its_neyman_count() {
    let s = load("cornell-box.toml");
    let settings = adaptive(256, 8, 0.04, 64);
    let frame = render_frame(&s, &settings, &|_| {});
    let tiles = PixelRect::tiles(s.width, s.height, 64);
    let counts = tile_counts(&frame, &tiles);
    eprintln!("samples per tile: {counts:?}");
    // The test means something only if some tiles stopped early and some did not.
    let min = *counts.iter().min().expect("tiles");
    let max = *counts.iter().max().expect("tiles");
    assert!(min < max, "every tile took {min} samples");
    assert!(
        min >= min_batches(8) * 8,
        "a tile stopped before the minimum"
    );
    // Each tile batch by batch, as a farm merges it: the pilots first, then, under the scale
    // they give, the first boundary at which a tile wants no more must be where the frame's
    // tile stopped, with the same bits.
    let step = |acc: &mut TileSums| {
        let e = (acc.samples.end + 8).min(settings.spp);
        acc.merge(&render_tile(&s, &settings, acc.rect, acc.samples.end..e))
            .expect("in order");
    };
    let pilots: Vec<TileSums> = tiles
        .iter()
        .map(|rect| {
            let mut acc = TileSums::empty(*rect, 0);
            while acc.samples.end < min_batches(8) * 8 {
                step(&mut acc);
            }
            acc
        })
        .collect();
    let scale = neyman_scale(0.04, &pilots);
    for ((rect, &k), mut acc) in tiles.iter().zip(&counts).zip(pilots) {
        while tile_wants_more(&settings, &acc, scale) {
            step(&mut acc);
        }
        assert_eq!(acc.samples.end, k, "tile {rect:?}");
        for y in 0..rect.height {
            for x in 0..rect.width {
                let f = ((rect.y0 + y) * s.width + rect.x0 + x) as usize;
                let t = (y * rect.width + x) as usize;
                assert_eq!(acc.sum[t], frame.sum[f]);
                assert_eq!(acc.sum_sq[t], frame.sum_sq[f]);
            }
        }
    }
}

#[test]
fn the_thread_count_does_not_change_an_adaptive_render() {
    let s = load("glass-mirror.toml");
    let settings = adaptive(128, 16, 0.1, 32);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| render_frame(&s, &settings, &|_| {}))
    };
    let one = run(1);
    let two = run(2);
    assert!(one == two, "1 and 2 threads differ");
    let tiles = PixelRect::tiles(s.width, s.height, 32);
    let counts = tile_counts(&one, &tiles);
    eprintln!("samples per tile: {counts:?}");
    assert!(counts.iter().any(|&k| k < 128) && counts.contains(&128));
}

/// The closed emitting sphere of `furnace.rs` (L = Le/(1 − ρ) everywhere): stopping on the
/// samples' own noise must not move the answer by more than the noise.
#[test]
fn an_adaptive_render_still_gives_the_furnace_answer() {
    let (rho, le) = ([0.8f64, 0.5, 0.3], [0.5f64, 1.0, 2.0]);
    let s = scene(&common::closed_sphere(rho, le, 32, 32));
    let settings = adaptive(1024, 8, 0.006, 2);
    let frame = render_frame(&s, &settings, &|_| {});
    let counts: Vec<u32> = frame.count.clone();
    let mean_spp = counts.iter().map(|&k| k as f64).sum::<f64>() / counts.len() as f64;
    eprintln!("mean spp {mean_spp}");
    let (min, max) = (counts.iter().min(), counts.iter().max());
    assert!(min < max, "every tile took the same samples");
    let img = frame.finalize();
    let (mean, se) = region_stats(&img, 0, 0, img.width, img.height);
    for c in 0..3 {
        let expected = le[c] / (1.0 - rho[c]);
        assert!(
            (mean[c] - expected).abs() <= 3.0 * se[c] + 1e-5 * expected,
            "channel {c}: {} vs {expected} ± {}",
            mean[c],
            3.0 * se[c]
        );
    }
}
