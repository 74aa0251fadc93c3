//! What the BSDF tests share: incident directions, points of the unit square and a `pbr`
//! sampler's albedo.

use glam::{Vec2, Vec3A};
use tessera_render::bsdf::{PbrBsdf, PbrSample};
use tessera_render::sampling::HashRng;

/// The direction `deg` degrees from the normal (+z), in the xz plane.
pub fn incident(deg: f32) -> Vec3A {
    let t = deg.to_radians();
    Vec3A::new(t.sin(), 0.0, t.cos())
}

/// A point of the unit square.
pub fn u2(rng: &mut HashRng) -> Vec2 {
    Vec2::new(rng.next_f32(), rng.next_f32())
}

/// E[weight] (red) over `b`'s sampler at incidence `o`, delta lobes included, from `n` draws
/// of the stream `seed`, with its standard error.
pub fn pbr_albedo(b: &PbrBsdf<'_>, o: Vec3A, n: usize, seed: u64) -> (f64, f64) {
    let mut rng = HashRng::new(seed);
    let (mut sum, mut sq) = (0.0f64, 0.0f64);
    for _ in 0..n {
        let c = rng.next_f32();
        let w = b
            .sample(o, u2(&mut rng), c)
            .map_or(0.0, |s| f64::from(s.weight.x));
        sum += w;
        sq += w * w;
    }
    let mean = sum / n as f64;
    (
        mean,
        ((sq / n as f64 - mean * mean).max(0.0) / n as f64).sqrt(),
    )
}

/// `n` draws of `b` from the stream `rng`, each at a cosine-distributed incidence: the
/// incidence and the sample, where one was drawn.
pub fn pbr_draws<'a>(
    b: &'a PbrBsdf<'a>,
    rng: &'a mut HashRng,
    n: usize,
) -> impl Iterator<Item = (Vec3A, PbrSample)> + 'a {
    (0..n).filter_map(move |_| {
        let o = tessera_render::sampling::square_to_cosine_hemisphere(u2(rng));
        let c = rng.next_f32();
        b.sample(o, u2(rng), c).map(|s| (o, s))
    })
}

/// A drawn sample's weight is finite and not negative, and where it is not a delta its
/// density and weight are `pdf`'s and `eval` / `pdf`'s.
pub fn check_draw(case: &str, b: &PbrBsdf<'_>, o: Vec3A, s: &PbrSample) {
    assert!(
        s.weight.is_finite() && s.weight.min_element() >= 0.0,
        "{case}: {s:?}"
    );
    if s.delta {
        return;
    }
    let (pdf, f) = (b.pdf(o, s.wi), b.eval(o, s.wi));
    assert!(
        (s.pdf - pdf).abs() <= 1e-4 * pdf,
        "{case}: pdf {} vs {pdf}",
        s.pdf
    );
    let want = f / pdf;
    assert!(
        (s.weight - want).abs().max_element() <= 1e-4 * want.max_element() + 1e-7,
        "{case}: weight {} vs {want}",
        s.weight
    );
}
