//! Microbenchmarks of the renderer's inner loops: the intersection kernels, the sampler, one
//! path, and a tile render on one thread. Run with `cargo bench -p tessera-render`; compare
//! before/after runs of the same machine, never absolute figures across machines.

#![allow(missing_docs)] // criterion_group! generates an undocumented function

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::Vec3A;
use tessera_render::math::{Aabb, Ray};
use tessera_render::sampling::{owen_sobol_4d, PixelSampler};
use tessera_render::scene::{Limits, Scene};
use tessera_render::shape::{slab, sphere_roots};
use tessera_render::{render_tile, PixelRect, RenderSettings};

fn scene(name: &str) -> Scene {
    let path = format!("{}/../../scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    Scene::file(path.as_ref(), &Limits::default())
        .load()
        .expect("bundled scene loads")
}

fn kernels(c: &mut Criterion) {
    let o = Vec3A::new(0.1, 0.2, 5.0);
    let d = Vec3A::new(0.01, -0.02, -1.0).normalize();
    c.bench_function("sphere_roots", |b| {
        b.iter(|| sphere_roots(black_box(o), black_box(d), Vec3A::ZERO, 1.0))
    });
    c.bench_function("slab", |b| {
        b.iter(|| slab(black_box(o), black_box(d), Vec3A::splat(-1.0), Vec3A::ONE))
    });
    let bx = Aabb {
        min: Vec3A::splat(-1.0),
        max: Vec3A::ONE,
    };
    let inv = d.recip();
    c.bench_function("aabb_hit", |b| {
        b.iter(|| bx.hit(black_box(o), black_box(inv), f32::INFINITY))
    });
    // Indices vary from call to call, as they do in a render: a fixed index would let the
    // branch predictor learn sobol_burley's data-dependent loop.
    let mut i = 0u32;
    let mut next = move || {
        i = (i + 1) & 0xffff;
        i
    };
    // A render makes one sampler per pixel and moves it from sample to sample.
    let mut sampler = PixelSampler::new(7, 10, 20, 0);
    c.bench_function("sampler_get4_hashed", |b| {
        b.iter(|| {
            sampler.set_index(next());
            sampler.get4(black_box(5))
        })
    });
    c.bench_function("sampler_get4_sobol", |b| {
        b.iter(|| {
            sampler.set_index(next());
            sampler.get4(black_box(0))
        })
    });
    c.bench_function("sampler_new", |b| {
        b.iter(|| PixelSampler::new(7, black_box(10), 20, next()))
    });
    // The crate the table-driven Sobol reproduces, as the peer of the next line.
    c.bench_function("sobol_burley_sample_4d", |b| {
        b.iter(|| sobol_burley::sample_4d(next(), 0, black_box(0x1234_5678)))
    });
    c.bench_function("owen_sobol_4d", |b| {
        b.iter(|| owen_sobol_4d(next(), black_box(0x1234_5678)))
    });
    let cbox = scene("cornell-box");
    let ray = cbox.camera.ray(128.5, 100.5);
    c.bench_function("cornell_closest_hit", |b| {
        b.iter(|| cbox.intersect(black_box(&ray), f32::INFINITY))
    });
    let shadow = Ray::new(Vec3A::new(0.0, -0.99, 0.0), Vec3A::new(0.05, 1.97, 0.02));
    c.bench_function("cornell_shadow_ray", |b| {
        b.iter(|| cbox.occluded(black_box(&shadow), 1.0 - 1e-4))
    });
}

fn tiles(c: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    let mut g = c.benchmark_group("tile_32x32_16spp_1thread");
    g.sample_size(10);
    g.throughput(Throughput::Elements(32 * 32 * 16));
    for name in ["cornell-box", "spheres"] {
        let s = scene(name);
        let settings = RenderSettings {
            spp: 16,
            ..RenderSettings::default()
        };
        let rect = PixelRect {
            x0: 112,
            y0: 112,
            width: 32,
            height: 32,
        };
        g.bench_function(name, |b| {
            b.iter(|| pool.install(|| render_tile(&s, &settings, rect, 0..16)))
        });
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default();
    targets = kernels, tiles
}
criterion_main!(benches);
