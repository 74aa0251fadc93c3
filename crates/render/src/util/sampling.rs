//! Deterministic sample generation and the warps from the unit square to the domains the
//! integrator samples.
//!
//! Every random number is a pure function of (job seed, pixel, sample index, dimension): the
//! sampler holds no state that depends on which thread or tile runs a pixel, so any cut of the
//! frame into tiles, threads, batches or machines draws the same numbers.

use std::f32::consts::{FRAC_1_PI, FRAC_PI_4};

use glam::{Vec2, Vec3A};

use crate::util::lanes::{F, M, V3};

/// Largest f32 below 1. Warps clamp to it so that `u = 1 − 2⁻²⁴` style inputs stay inside
/// their domain.
pub const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON * 0.5;

/// A 64-bit finaliser (SplitMix64 / Stafford variant 13): a strong bijective mixer used to
/// derive seeds from coordinates.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Hashes several words into one seed.
#[inline]
pub fn hash_words(words: &[u64]) -> u64 {
    let mut h = 0x9e37_79b9_7f4a_7c15u64;
    for &w in words {
        h = mix64(h ^ w.wrapping_add(0x9e37_79b9_7f4a_7c15));
    }
    h
}

/// Sample dimensions for one pixel sample.
///
/// Dimensions come in groups of four (the integrator's layout is documented at its `trace`:
/// each group holds four numbers that one term of the image depends on jointly). The first
/// [`SOBOL_GROUPS`] groups (the pixel and first light point, and the first two bounces) are
/// Owen-scrambled Sobol points: group `g` of sample `i` is dimension set 0 of the Sobol
/// sequence seeded by hash(job seed, pixel, g, i ≫ 16), "padding by seeding", so each group
/// is its own independently scrambled 4-D sequence whose four dimensions are stratified
/// jointly. Deeper groups are independent uniform numbers from a
/// counter-based hash of the same coordinates: stratification there buys almost nothing (those
/// bounces carry little of the image's variance), and a Sobol group costs ~11 ns against ~5 ns
/// for the hash (`cargo bench -p tessera-render -- sampler`). Either way every number is a pure
/// function of (job seed, pixel, sample index, dimension), and path depth is unbounded.
///
/// A sampler is made once per pixel and moved from sample to sample with
/// [`PixelSampler::set_index`]: everything in a Sobol group's numbers that does not depend on
/// the sample index (the group's seed and its five scramble keys) is hashed when the sampler is
/// made, not once per group of numbers (about 240 of a Cornell box sample's 5 500
/// instructions, docs/renderer.md). The numbers are the same either way.
#[derive(Clone, Copy)]
pub struct PixelSampler {
    pixel_seed: u64,
    index: u32,
    /// The keys of the 2¹⁶-sample block `index >> 16`.
    keys: [GroupKeys; SOBOL_GROUPS as usize],
    /// [`SOBOL_NIBBLES`], dereferenced once per pixel rather than once per group: each
    /// `LazyLock` dereference is an atomic load and a branch.
    table: &'static SobolTable,
}

impl std::fmt::Debug for PixelSampler {
    // Without the table, which is the same for every sampler.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PixelSampler")
            .field("pixel_seed", &self.pixel_seed)
            .field("index", &self.index)
            .field("keys", &self.keys)
            .finish_non_exhaustive()
    }
}

/// A Sobol group's scramble keys for one pixel and block: the index shuffle's and each
/// dimension's Owen scramble's, all functions of the group's seed alone.
#[derive(Clone, Copy, Debug)]
struct GroupKeys {
    index: u32,
    dims: [u32; 4],
}

impl GroupKeys {
    /// The keys `sobol_burley::sample_4d(_, 0, seed)` derives from `seed`.
    #[inline]
    fn new(seed: u32) -> Self {
        use sobol_burley::parts::hash;
        const DIM_KEYS: [u32; 4] = [0x912f_69ba, 0x174f_18ab, 0x691e_72ca, 0xb40c_c1b8];
        let s = seed.wrapping_mul(0x9c8f_2d3b);
        Self {
            index: hash(seed ^ 0x79c6_8e4a),
            dims: DIM_KEYS.map(|k| hash(s ^ k)),
        }
    }
}

/// Groups of four dimensions drawn from scrambled Sobol sequences; the rest are hashed.
pub const SOBOL_GROUPS: u32 = 5;

impl PixelSampler {
    /// Sampler for `sample_index` of pixel (`x`, `y`) of a job with `seed`.
    #[inline]
    pub fn new(seed: u64, x: u32, y: u32, sample_index: u32) -> Self {
        let pixel_seed = hash_words(&[seed, ((x as u64) << 32) | y as u64]);
        Self {
            pixel_seed,
            index: sample_index,
            keys: Self::block_keys(pixel_seed, sample_index >> 16),
            table: &SOBOL_NIBBLES,
        }
    }

    /// Moves to sample `sample_index` of the same pixel.
    #[inline]
    pub fn set_index(&mut self, sample_index: u32) {
        if sample_index >> 16 != self.index >> 16 {
            self.keys = Self::block_keys(self.pixel_seed, sample_index >> 16);
        }
        self.index = sample_index;
    }

    fn block_keys(pixel_seed: u64, block: u32) -> [GroupKeys; SOBOL_GROUPS as usize] {
        std::array::from_fn(|group| {
            let seed = hash_words(&[pixel_seed, ((group as u64) << 32) | u64::from(block)]);
            GroupKeys::new(seed as u32)
        })
    }

    /// The four dimensions of group `group`, each in [0, 1).
    #[inline]
    pub fn get4(&self, group: u32) -> [f32; 4] {
        if let Some(keys) = self.keys.get(group as usize) {
            // At most 1 − 2⁻²³ (23 bits below 1), so below 1 without a clamp.
            owen_sobol_4d_keyed(self.table, self.index & 0xffff, keys)
        } else {
            let h0 = mix64(
                self.pixel_seed
                    ^ (((self.index as u64) << 32) | group as u64)
                        .wrapping_mul(0x9e37_79b9_7f4a_7c15),
            );
            let h1 = mix64(h0 ^ 0xd1b5_4a32_d192_ed03);
            // The top 24 bits of each 32-bit half: exact in f32, so always below 1. Through
            // u32, whose conversion is one instruction; u64's needs a sign fix-up on x86.
            let f = |w: u64| ((w >> 8) as u32) as f32 * (1.0 / (1u32 << 24) as f32);
            [
                f(h0 >> 32),
                f(h0 & 0xffff_ffff),
                f(h1 >> 32),
                f(h1 & 0xffff_ffff),
            ]
        }
    }
}

/// Direction-vector XORs of dimension set 0 of `sobol_burley`'s Sobol sequence, one table per
/// nibble of the 16-bit bit-reversed index: entry `[k][v]` is the Sobol point of the index
/// whose nibble `k` is `v` and other bits are zero. Sobol points are linear over GF(2) in the
/// index bits, so four lookups XORed together give any point, without the crate's
/// data-dependent loop over set bits (whose branch mispredictions were most of its cost).
static SOBOL_NIBBLES: std::sync::LazyLock<SobolTable> = std::sync::LazyLock::new(|| {
    let mut t = [[[0u32; 4]; 16]; 4];
    for (k, table) in t.iter_mut().enumerate() {
        for (v, entry) in table.iter_mut().enumerate() {
            let index_rev = (v as u32) << (16 + 4 * k);
            for (d, x) in entry.iter_mut().enumerate() {
                *x = sobol_burley::parts::sobol_rev(index_rev, d as u32);
            }
        }
    }
    t
});

/// The same numbers as `sobol_burley::sample_4d(index, 0, seed)` (the unit test
/// `owen_sobol_matches_sobol_burley` checks every bit), computed from a table of Sobol points
/// per index nibble: the crate's index shuffle and per-dimension Owen scramble, with a
/// branch-free Sobol step.
#[inline]
pub fn owen_sobol_4d(index: u32, seed: u32) -> [f32; 4] {
    owen_sobol_4d_keyed(&SOBOL_NIBBLES, index, &GroupKeys::new(seed))
}

/// Four tables, one per index nibble, of sixteen 4-D Sobol points.
type SobolTable = [[[u32; 4]; 16]; 4];

/// [`owen_sobol_4d`] with the seed's keys already derived.
///
/// The four dimensions go through the Owen scramble, the bit reversal and the conversion to
/// float together, in `sobol_burley`'s SSE lanes: the same integer operations as four scalar
/// passes, so the same bits.
#[inline]
fn owen_sobol_4d_keyed(t: &SobolTable, index: u32, keys: &GroupKeys) -> [f32; 4] {
    use sobol_burley::parts::{owen_scramble_int4_rev, owen_scramble_rev, Int4};
    debug_assert!(index < 1 << 16);
    let r = owen_scramble_rev(index.reverse_bits(), keys.index);
    let n = |k: u32| Int4::from(t[k as usize][((r >> (16 + 4 * k)) & 15) as usize]);
    let sobol = n(0) ^ n(1) ^ n(2) ^ n(3);
    owen_scramble_int4_rev(sobol, keys.dims.into())
        .reverse_bits()
        .to_f32_norm()
}

/// A small counter-based generator for tests and tools (never for rendering, whose numbers
/// come from [`PixelSampler`]).
#[derive(Clone, Debug)]
pub struct HashRng {
    key: u64,
    counter: u64,
}

impl HashRng {
    /// Generator with `seed`.
    pub fn new(seed: u64) -> Self {
        Self {
            key: mix64(seed ^ 0xd1b5_4a32_d192_ed03),
            counter: 0,
        }
    }

    /// Next uniform f32 in [0, 1).
    pub fn next_f32(&mut self) -> f32 {
        self.counter += 1;
        (mix64(self.key ^ self.counter.wrapping_mul(0x9e37_79b9_7f4a_7c15)) >> 40) as f32
            * (1.0 / (1u64 << 24) as f32)
    }
}

/// Shirley–Chiu concentric map from the unit square to the unit disk: area preserving and
/// low distortion, so it keeps the stratification of the input points.
#[inline]
pub fn square_to_disk_concentric(u: Vec2) -> Vec2 {
    let a = 2.0 * u - Vec2::ONE;
    if a.x == 0.0 && a.y == 0.0 {
        return Vec2::ZERO;
    }
    if a.x.abs() > a.y.abs() {
        let (s, c) = sin_cos_octant(FRAC_PI_4 * (a.y / a.x));
        Vec2::new(a.x * c, a.x * s)
    } else {
        // θ = π/2 − β: sin θ = cos β, cos θ = sin β.
        let (s, c) = sin_cos_octant(FRAC_PI_4 * (a.x / a.y));
        Vec2::new(a.y * s, a.y * c)
    }
}

/// (sin x, cos x) for |x| ≤ π/4, by polynomials in plain f32 arithmetic (Taylor to x⁹ and
/// x¹⁰: truncation below 3e-8, so within an ulp or two of the true values).
///
/// Not `f32::sin_cos`: glibc picks its implementation per CPU at load time (an FMA build on
/// newer x86), and the two can round differently, which would let two workers on different
/// machines return different bits for the same sample. Basic f32 operations round the same
/// everywhere, and inlined polynomials are also faster than the library call.
#[inline]
pub fn sin_cos_octant(x: f32) -> (f32, f32) {
    debug_assert!(x.abs() <= FRAC_PI_4 * 1.000_001, "{x}");
    sin_cos_polynomials(x)
}

/// [`sin_cos_octant`]'s polynomials for a number or for SIMD lanes, each lane by the same
/// operations in the same order, so the many-path tracer's sines and cosines are the scalar
/// ones, bit for bit.
#[inline(always)]
pub(crate) fn sin_cos_polynomials<T>(x: T) -> (T, T)
where
    T: Copy + std::ops::Mul<Output = T> + std::ops::Mul<f32, Output = T>,
    f32: std::ops::Add<T, Output = T>,
{
    let x2 = x * x;
    let s = x
        * (1.0
            + x2 * (-1.0 / 6.0
                + x2 * (1.0 / 120.0 + x2 * (-1.0 / 5040.0 + x2 * (1.0 / 362_880.0)))));
    let c = 1.0
        + x2 * (-0.5
            + x2 * (1.0 / 24.0
                + x2 * (-1.0 / 720.0 + x2 * (1.0 / 40320.0 + x2 * (-1.0 / 3_628_800.0)))));
    (s, c)
}

/// (sin 2πu, cos 2πu) for u in [0, 1], reduced to [`sin_cos_octant`] by the octant of u
/// (exact: 8u and its fraction are exact in f32).
#[inline]
pub fn sin_cos_turn(u: f32) -> (f32, f32) {
    let scaled = 8.0 * u;
    let k = (scaled.floor() as u32).min(7);
    let f = scaled - k as f32;
    // In an odd octant k, 2πu = (k + 1)·π/4 − (1 − f)·π/4, and (k + 1)·π/4 is a multiple of
    // π/2, so the sine and cosine of the remainder swap roles.
    let a = if k % 2 == 1 { 1.0 - f } else { f };
    let (s, c) = sin_cos_octant(FRAC_PI_4 * a);
    match k {
        0 => (s, c),
        1 => (c, s),
        2 => (c, -s),
        3 => (s, -c),
        4 => (-s, -c),
        5 => (-c, -s),
        6 => (-c, s),
        _ => (-s, c),
    }
}

/// [`sin_cos_turn`], lane by lane, for the many-path tracer: the octant's swap and signs as
/// selects, so every lane gets the scalar bits (`tests::the_lanes_twins_give_the_scalar_bits`).
#[inline(always)]
pub fn sin_cos_turn_lanes<const N: usize>(u: F<N>) -> (F<N>, F<N>) {
    let scaled = 8.0 * u;
    let (mut odd, mut swap, mut neg_sin, mut neg_cos) = (0u32, 0u32, 0u32, 0u32);
    let mut k = [0.0f32; N];
    for (lane, (k, scaled)) in k.iter_mut().zip(scaled.0).enumerate() {
        let octant = (scaled.floor() as u32).min(7);
        *k = octant as f32;
        odd |= (octant & 1) << lane;
        // The scalar function's table: (c, ·) in octants 1, 2, 5, 6; −sin in 4 to 7, −cos in
        // 2 to 5.
        swap |= u32::from(matches!(octant, 1 | 2 | 5 | 6)) << lane;
        neg_sin |= u32::from(octant >= 4) << lane;
        neg_cos |= u32::from((2..=5).contains(&octant)) << lane;
    }
    let f = scaled - F(k);
    let a = F::select(M::from_bits(odd), 1.0 - f, f);
    let (s, c) = sin_cos_polynomials(FRAC_PI_4 * a);
    let swap = M::from_bits(swap);
    let (first, second) = (F::select(swap, c, s), F::select(swap, s, c));
    (
        F::select(M::from_bits(neg_sin), -first, first),
        F::select(M::from_bits(neg_cos), -second, second),
    )
}

/// Cosine-weighted direction on the +z hemisphere (Malley's method). pdf = cos θ / π.
#[inline]
pub fn square_to_cosine_hemisphere(u: Vec2) -> Vec3A {
    let d = square_to_disk_concentric(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3A::new(d.x, d.y, z)
}

/// Density of [`square_to_cosine_hemisphere`] in solid angle.
#[inline]
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    if cos_theta > 0.0 {
        cos_theta * FRAC_1_PI
    } else {
        0.0
    }
}

/// Uniform direction on the unit sphere. pdf = 1/(4π).
#[inline]
pub fn square_to_uniform_sphere(u: Vec2) -> Vec3A {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = sin_cos_turn(u.y);
    Vec3A::new(r * c, r * s, z)
}

/// Uniform direction in the cone of half-angle θmax around +z, given cos θmax. pdf =
/// 1/(2π(1 − cos θmax)). Uses `1 − cos θmax` computed by the caller to avoid cancellation
/// for tiny cones (a small, distant light).
#[inline]
pub fn square_to_uniform_cone(u: Vec2, one_minus_cos_max: f32) -> Vec3A {
    let one_minus_cos = u.x * one_minus_cos_max;
    let cos = 1.0 - one_minus_cos;
    // sin² = 1 − cos² = (1 − cos)(1 + cos), exact for small angles.
    let sin = (one_minus_cos * (2.0 - one_minus_cos)).max(0.0).sqrt();
    let (s, c) = sin_cos_turn(u.y);
    Vec3A::new(sin * c, sin * s, cos)
}

/// Power heuristic (β = 2) MIS weight of a technique with density `f` against one with `g`.
#[inline]
pub fn power_heuristic(f: f32, g: f32) -> f32 {
    let (f2, g2) = (f * f, g * g);
    if f2.is_infinite() {
        return 1.0;
    }
    if f2 + g2 == 0.0 {
        return 0.0;
    }
    f2 / (f2 + g2)
}

/// [`square_to_cosine_hemisphere`], lane by lane, for the many-path tracer: the same bits in
/// every lane (`tests::the_lanes_twins_give_the_scalar_bits`).
#[inline(always)]
pub fn square_to_cosine_hemisphere_lanes<const N: usize>(u0: F<N>, u1: F<N>) -> V3<N> {
    let ax = 2.0 * u0 - F::ONE;
    let ay = 2.0 * u1 - F::ONE;
    let origin = ax.cmpeq(F::ZERO) & ay.cmpeq(F::ZERO);
    let x_major = ax.abs().cmpgt(ay.abs());
    let num = F::select(x_major, ay, ax);
    let den = F::select(x_major, ax, ay);
    let (s, c) = sin_cos_polynomials(std::f32::consts::FRAC_PI_4 * (num / den));
    let dx = F::select(origin, F::ZERO, den * F::select(x_major, c, s));
    let dy = F::select(origin, F::ZERO, den * F::select(x_major, s, c));
    let z = (1.0 - (dx * dx + dy * dy)).max(F::ZERO).sqrt();
    [dx, dy, z]
}

/// [`power_heuristic`], lane by lane, for the many-path tracer: the same bits in every lane.
#[inline(always)]
pub fn power_heuristic_lanes<const N: usize>(f: F<N>, g: F<N>) -> F<N> {
    let (f2, g2) = (f * f, g * g);
    let sum = f2 + g2;
    let w = F::select(sum.cmpeq(F::ZERO), F::ZERO, f2 / sum);
    F::select(f2.abs().cmpeq(F::INFINITY), F::ONE, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lanes' twins give the scalar functions' bits in every lane, over a grid that holds
    /// the disk's centre and its diagonals, and for weights of 0 and ∞.
    #[test]
    fn the_lanes_twins_give_the_scalar_bits() {
        let n = 257;
        for i in 0..n {
            for j in 0..n {
                let u = Vec2::new(i as f32 / (n - 1) as f32, j as f32 / (n - 1) as f32);
                let u = Vec2::new(
                    u.x.min(1.0 - f32::EPSILON / 2.0),
                    u.y.min(1.0 - f32::EPSILON / 2.0),
                );
                let got = square_to_cosine_hemisphere_lanes::<4>(F::splat(u.x), F::splat(u.y));
                let want = square_to_cosine_hemisphere(u);
                for c in 0..3 {
                    assert_eq!(got[c].0[1].to_bits(), want[c].to_bits(), "{u}");
                }
            }
        }
        // Every octant at both ends, and a grid through them, each value in every lane.
        let n = 4096;
        let us: Vec<f32> = (0..=n)
            .map(|i| i as f32 / n as f32)
            .chain((0..=8).flat_map(|k| {
                let u = k as f32 / 8.0;
                [
                    u,
                    f32::from_bits(u.to_bits().saturating_sub(1)),
                    u + f32::EPSILON / 8.0,
                ]
            }))
            .map(|u: f32| u.clamp(0.0, 1.0))
            .collect();
        for (k, chunk) in us.chunks(8).enumerate() {
            let mut u = [0.25f32; 8];
            for (lane, &v) in chunk.iter().enumerate() {
                u[(lane + k) % 8] = v;
            }
            let (s, c) = sin_cos_turn_lanes(F(u));
            for (lane, u) in u.iter().enumerate() {
                let (ws, wc) = sin_cos_turn(*u);
                assert_eq!(s.0[lane].to_bits(), ws.to_bits(), "sin, u = {u}");
                assert_eq!(c.0[lane].to_bits(), wc.to_bits(), "cos, u = {u}");
            }
        }
        let weights = [0.0, 1e-30, 0.5, 1.0, 3.0, 1e30, f32::INFINITY];
        for f in weights {
            for g in weights {
                let got = power_heuristic_lanes::<8>(F::splat(f), F::splat(g));
                assert_eq!(
                    got.0[5].to_bits(),
                    power_heuristic(f, g).to_bits(),
                    "{f} {g}"
                );
            }
        }
    }

    /// The polynomial sine and cosine against f64's, over every octant, at both ends of each.
    #[test]
    fn sin_cos_turn_is_accurate_everywhere() {
        let mut worst = 0f64;
        let n = 1 << 20;
        let us = (0..=n)
            .map(|i| i as f32 / n as f32)
            .chain((0..=8).map(|k| k as f32 / 8.0))
            .chain([
                f32::EPSILON,
                1.0 - f32::EPSILON / 2.0,
                0.125 - 1e-8,
                0.125 + 1e-8,
            ]);
        for u in us {
            let (s, c) = sin_cos_turn(u);
            let (s64, c64) = (std::f64::consts::TAU * u as f64).sin_cos();
            worst = worst
                .max((s as f64 - s64).abs())
                .max((c as f64 - c64).abs());
            assert!(
                s * s + c * c <= 1.0 + 4.0 * f32::EPSILON,
                "u = {u}: ({s}, {c})"
            );
        }
        // f32 spacing near 1 is 6e-8 and u itself is rounded by up to 3e-8·2π.
        assert!(worst < 2.5e-7, "largest error {worst:e}");
    }

    #[test]
    fn owen_sobol_matches_sobol_burley() {
        let mut rng = HashRng::new(3);
        for seed in (0..64u32).chain((0..64).map(|_| (rng.next_f32() * 4.0e9) as u32)) {
            for index in (0..1024).chain([0xffff, 0x8000, 0x7fff, 0x5555, 0xaaaa]) {
                let ours = owen_sobol_4d(index, seed).map(f32::to_bits);
                let theirs = sobol_burley::sample_4d(index, 0, seed).map(f32::to_bits);
                assert_eq!(ours, theirs, "index {index} seed {seed:#x}");
            }
        }
    }

    #[test]
    fn sampler_is_a_pure_function_of_its_inputs() {
        let a = PixelSampler::new(7, 3, 4, 5).get4(2);
        let b = PixelSampler::new(7, 3, 4, 5).get4(2);
        assert_eq!(a, b);
        assert_ne!(a, PixelSampler::new(8, 3, 4, 5).get4(2));
        assert_ne!(a, PixelSampler::new(7, 4, 3, 5).get4(2));
        assert_ne!(a, PixelSampler::new(7, 3, 4, 6).get4(2));
        assert_ne!(a, PixelSampler::new(7, 3, 4, 5).get4(3));
        // Past the 2^16 samples of one Sobol sequence, samples still vary.
        assert_ne!(
            PixelSampler::new(7, 3, 4, 5).get4(0),
            PixelSampler::new(7, 3, 4, 5 + (1 << 16)).get4(0)
        );
    }

    #[test]
    fn a_moved_sampler_draws_what_a_new_one_does() {
        let mut moved = PixelSampler::new(7, 3, 4, 0);
        // Forward, back, and across the 2^16-sample blocks whose keys differ.
        for index in [
            1, 9, 2, 0xffff, 0x1_0000, 0x1_0003, 5, 0x2_0001, 0x2_0001, 0,
        ] {
            moved.set_index(index);
            let fresh = PixelSampler::new(7, 3, 4, index);
            for group in 0..SOBOL_GROUPS + 3 {
                assert_eq!(
                    moved.get4(group).map(f32::to_bits),
                    fresh.get4(group).map(f32::to_bits),
                    "index {index:#x} group {group}"
                );
            }
        }
    }

    #[test]
    fn sampler_is_stratified_in_each_group() {
        // 16 samples of a (0,2)-sequence put exactly one point in each 4x4 cell of dims 0-1.
        for group in 0..SOBOL_GROUPS {
            let mut cells = [0u32; 16];
            for i in 0..16 {
                let [a, b, _, _] = PixelSampler::new(1, 9, 9, i).get4(group);
                cells[(a * 4.0) as usize * 4 + (b * 4.0) as usize] += 1;
            }
            assert!(cells.iter().all(|&c| c == 1), "group {group}: {cells:?}");
        }
    }

    /// The Sobol groups need no clamp below 1: the conversion's largest output, for an all-ones
    /// integer, is 1 − 2⁻²³, and the SIMD path gives exactly the scalar conversion.
    #[test]
    fn sobol_groups_stay_below_one() {
        use sobol_burley::parts::{u32_to_f32_norm, Int4};
        assert_eq!(u32_to_f32_norm(u32::MAX), 1.0 - f32::EPSILON);
        let words = [u32::MAX, 0, 0x8000_0000, 0x1234_5678];
        assert_eq!(Int4::from(words).to_f32_norm(), words.map(u32_to_f32_norm));
        for group in 0..SOBOL_GROUPS {
            for i in 0..4096 {
                let u = PixelSampler::new(5, i % 61, i / 61, i).get4(group);
                assert!(u.iter().all(|v| (0.0..1.0).contains(v)), "{u:?}");
            }
        }
    }

    #[test]
    fn hashed_groups_are_uniform_and_independent() {
        // Pearson chi-square of each dimension over 16 bins, and of pairs over 4x4 cells, for
        // the hashed groups; 1% critical values (15 degrees of freedom): 30.6.
        let n = 16_000u32;
        for group in [SOBOL_GROUPS, SOBOL_GROUPS + 7] {
            let mut bins = [[0u32; 16]; 4];
            let mut pairs = [0u32; 16];
            for i in 0..n {
                let u = PixelSampler::new(3, i % 97, i / 97, i).get4(group);
                for (d, v) in u.iter().enumerate() {
                    assert!((0.0..1.0).contains(v), "{v}");
                    bins[d][(v * 16.0) as usize] += 1;
                }
                pairs[(u[0] * 4.0) as usize * 4 + (u[3] * 4.0) as usize] += 1;
            }
            let chi2 = |c: &[u32]| {
                let e = n as f64 / c.len() as f64;
                c.iter().map(|&o| (o as f64 - e).powi(2) / e).sum::<f64>()
            };
            for b in &bins {
                assert!(chi2(b) < 30.6, "group {group}: {b:?}");
            }
            assert!(chi2(&pairs) < 30.6, "group {group}: {pairs:?}");
        }
    }

    #[test]
    fn warps_at_domain_edges_stay_finite_and_in_domain() {
        let edges = [0.0, 0.5, ONE_MINUS_EPSILON];
        for &a in &edges {
            for &b in &edges {
                let u = Vec2::new(a, b);
                let c = square_to_cosine_hemisphere(u);
                assert!(
                    c.is_finite() && c.z >= 0.0 && (c.length() - 1.0).abs() < 1e-5,
                    "{u:?} {c:?}"
                );
                let s = square_to_uniform_sphere(u);
                assert!(s.is_finite() && (s.length() - 1.0).abs() < 1e-5);
                for omc in [1e-12, 1e-3, 1.0, 2.0] {
                    let k = square_to_uniform_cone(u, omc);
                    assert!(
                        k.is_finite() && (k.length() - 1.0).abs() < 1e-5,
                        "{omc} {k:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn power_heuristic_limits() {
        assert_eq!(power_heuristic(0.0, 0.0), 0.0);
        assert_eq!(power_heuristic(f32::INFINITY, 1.0), 1.0);
        assert!((power_heuristic(1.0, 1.0) - 0.5).abs() < 1e-7);
    }
}
