//! The `pbr` material's layers over its base: the clear coat (`KHR_materials_clearcoat`,
//! Blender's Coat) and the sheen (`KHR_materials_sheen`). White furnaces at every coat, sheen
//! and base roughness (a white material under them keeps all its energy), chi-square tests of
//! the directions drawn, `sample` against `eval` and `pdf` at every draw, a layer of weight 0
//! (or a black sheen) being no layer bit for bit, and the coat's value on a Lambertian base.

mod common;

use common::bsdf::{check_draw, incident, pbr_albedo, pbr_draws, u2};

use glam::Vec3A;
use tessera_render::bsdf::pbr::{CoatTable, Distribution};
use tessera_render::bsdf::{PbrBsdf, PbrParams};
use tessera_render::sampling::HashRng;

const MS: Distribution = Distribution::MultiscatterGgx;

/// Base roughness, metallic, transmission; then the coat's weight and roughness.
fn params((r, m, t): (f32, f32, f32), (w, rc): (f32, f32), c: Vec3A) -> PbrParams {
    PbrParams {
        base_color: c,
        metallic: m,
        roughness: r,
        transmission: t,
        clearcoat: w,
        clearcoat_roughness: rc,
        sheen_color: Vec3A::ZERO,
        sheen_roughness: 0.0,
    }
}

/// `p` under a sheen of colour `c` and roughness `r`.
fn sheened(p: PbrParams, c: Vec3A, r: f32) -> PbrParams {
    PbrParams {
        sheen_color: c,
        sheen_roughness: r,
        ..p
    }
}

/// The BSDF of `p` with its sheen and clear coat.
fn layered<'a>(
    p: PbrParams,
    base: &'a CoatTable,
    cc: &'a CoatTable,
    d: Distribution,
) -> PbrBsdf<'a> {
    PbrBsdf::new(p, base, d).with_sheen().with_clearcoat(cc, d)
}

fn coated<'a>(
    p: PbrParams,
    base: &'a CoatTable,
    cc: &'a CoatTable,
    d: Distribution,
) -> PbrBsdf<'a> {
    PbrBsdf::new(p, base, d).with_clearcoat(cc, d)
}

const BASES: [(f32, f32, f32); 5] = [
    (0.0, 0.0, 0.0),
    (0.3, 0.0, 0.0),
    (0.8, 0.0, 0.0),
    (0.5, 1.0, 0.0),
    (0.5, 0.0, 1.0),
];

#[test]
fn a_white_material_under_a_clear_coat_keeps_all_its_energy() {
    let (base, cc) = (CoatTable::new(1.5), CoatTable::new(1.5));
    let mut worst = 0f64;
    for b in BASES {
        for coat in [(1.0, 0.0), (1.0, 0.1), (0.5, 0.4), (1.0, 0.8), (1.0, 1.0)] {
            let bsdf = coated(params(b, coat, Vec3A::ONE), &base, &cc, MS);
            let single = coated(params(b, coat, Vec3A::ONE), &base, &cc, Distribution::Ggx);
            for deg in [0.0f32, 45.0, 80.0, 89.0] {
                let o = incident(deg);
                let case = format!("base {b:?} coat {coat:?} θo={deg}°");
                let (mean, se) = pbr_albedo(&bsdf, o, 200_000, 5);
                worst = worst.max((mean - 1.0).abs());
                assert!(
                    (mean - 1.0).abs() <= 4.0 * se + 3e-3,
                    "{case}: albedo {mean} ± {se}"
                );
                // Single scattering loses what bounces between facets, never gains.
                let (mean, se) = pbr_albedo(&single, o, 100_000, 5);
                assert!(mean <= 1.0 + 4.0 * se + 3e-3, "{case} ggx: {mean} ± {se}");
            }
        }
    }
    eprintln!("white furnace under a clear coat: worst |albedo − 1| {worst:.4}");
}

/// Under a rough coat every lobe is drawn together; the smooth ones' deltas count as failures,
/// so the density must integrate to the rest's share.
#[test]
fn directions_under_a_rough_coat_follow_their_density() {
    let (base, cc) = (CoatTable::new(1.5), CoatTable::new(1.5));
    let cases = [
        ((0.6, 0.0, 0.0), (1.0, 0.3)),
        ((0.5, 1.0, 0.0), (0.7, 0.2)),
        ((0.4, 0.0, 1.0), (1.0, 0.5)),
        ((0.0, 0.0, 0.0), (1.0, 0.4)),
    ];
    let tests = (cases.len() * 3) as f64;
    for (b, coat) in cases {
        let bsdf = coated(params(b, coat, Vec3A::new(0.8, 0.5, 0.2)), &base, &cc, MS);
        chi_square(&format!("clear coat {coat:?} over {b:?}"), &bsdf, tests);
    }
}

/// The directions `bsdf` draws (its deltas counted as failures) against its density, at
/// incidences of 0°, 45° and 80°; `tests` in all, for the significance level.
fn chi_square(name: &str, bsdf: &PbrBsdf<'_>, tests: f64) {
    for deg in [0.0f32, 45.0, 80.0] {
        let o = incident(deg);
        let mut rng_u = HashRng::new(17);
        common::chi2::chi_square_with_failures(
            &format!("{name} θo={deg}°"),
            tests,
            |rng| {
                let c = rng_u.next_f32();
                bsdf.sample(o, u2(rng), c)
                    .filter(|s| !s.delta)
                    .map(|s| s.wi)
            },
            &|i| bsdf.pdf(o, i) as f64,
        );
    }
}

#[test]
fn samples_under_a_coat_agree_with_eval_and_pdf() {
    let (base, cc) = (CoatTable::new(1.5), CoatTable::new(1.5));
    let mut rng = HashRng::new(23);
    for b in BASES {
        for coat in [(1.0, 0.0), (0.6, 0.2), (1.0, 0.9)] {
            let bsdf = coated(params(b, coat, Vec3A::new(0.9, 0.4, 0.1)), &base, &cc, MS);
            for (o, s) in pbr_draws(&bsdf, &mut rng, 5_000) {
                let case = format!("base {b:?} coat {coat:?}");
                check_draw(&case, &bsdf, o, &s);
                if s.delta {
                    let mirror = Vec3A::new(-o.x, -o.y, o.z);
                    let smooth_base = b.0 == 0.0;
                    let ok = (s.wi - mirror).length() < 1e-6 && (coat.1 == 0.0 || smooth_base)
                        || (s.wi + o).length() < 1e-6 && smooth_base;
                    assert!(ok, "{case}: a delta where no lobe is smooth: {s:?}");
                }
            }
        }
    }
}

/// A coat of weight 0 changes nothing: the same samples, values and densities, bit for bit,
/// so a material without a coat renders as it did before coats were read.
#[test]
fn a_coat_of_weight_zero_is_no_coat_bit_for_bit() {
    let (base, cc) = (CoatTable::new(1.5), CoatTable::new(1.5));
    let mut rng = HashRng::new(29);
    for b in BASES {
        let p = params(b, (0.0, 0.3), Vec3A::new(0.7, 0.6, 0.2));
        let (plain, zero) = (PbrBsdf::new(p, &base, MS), coated(p, &base, &cc, MS));
        for _ in 0..2_000 {
            let o = tessera_render::sampling::square_to_cosine_hemisphere(u2(&mut rng));
            let (u, c) = (u2(&mut rng), rng.next_f32());
            let (a, z) = (plain.sample(o, u, c), zero.sample(o, u, c));
            assert_eq!(format!("{a:?}"), format!("{z:?}"));
            let i = tessera_render::sampling::square_to_cosine_hemisphere(u);
            assert_eq!(plain.eval(o, i).to_array(), zero.eval(o, i).to_array());
            assert_eq!(plain.pdf(o, i).to_bits(), zero.pdf(o, i).to_bits());
        }
    }
}

/// On a Lambertian base (a dielectric layer of index 1 reflects nothing) a smooth coat of
/// weight 1 reflects F(μo) and passes the rest to the base: albedo F + (1 − F)·c.
#[test]
fn a_smooth_coat_over_a_lambertian_base_reflects_fresnel_and_passes_the_rest() {
    let (base, cc) = (CoatTable::new(1.0), CoatTable::new(1.5));
    let c = 0.3f32;
    for deg in [0.0f32, 60.0, 85.0] {
        let o = incident(deg);
        let bsdf = coated(
            params((0.5, 0.0, 0.0), (1.0, 0.0), Vec3A::splat(c)),
            &base,
            &cc,
            MS,
        );
        let f = tessera_render::bsdf::fresnel_dielectric(o.z, 1.5).0;
        let want = f64::from(f + (1.0 - f) * c);
        let (mean, se) = pbr_albedo(&bsdf, o, 200_000, 5);
        assert!(
            (mean - want).abs() <= 4.0 * se + 1e-3,
            "θo={deg}°: {mean} ± {se}, want {want}"
        );
    }
}

#[test]
fn a_white_material_under_a_white_sheen_keeps_all_its_energy() {
    let (base, cc) = (CoatTable::new(1.5), CoatTable::new(1.5));
    let mut worst = 0f64;
    for b in [
        (0.3, 0.0, 0.0),
        (0.8, 0.0, 0.0),
        (0.5, 1.0, 0.0),
        (0.5, 0.0, 1.0),
    ] {
        for sheen in [0.3f32, 0.6, 1.0] {
            for coat in [(0.0, 0.0), (1.0, 0.3)] {
                let p = sheened(params(b, coat, Vec3A::ONE), Vec3A::ONE, sheen);
                let bsdf = layered(p, &base, &cc, MS);
                for deg in [0.0f32, 45.0, 80.0] {
                    let o = incident(deg);
                    let case = format!("base {b:?} sheen {sheen} coat {coat:?} θo={deg}°");
                    let (mean, se) = pbr_albedo(&bsdf, o, 200_000, 7);
                    worst = worst.max((mean - 1.0).abs());
                    assert!(
                        (mean - 1.0).abs() <= 4.0 * se + 5e-3,
                        "{case}: albedo {mean} ± {se}"
                    );
                }
            }
        }
    }
    eprintln!("white furnace under a white sheen: worst |albedo − 1| {worst:.4}");
}

#[test]
fn directions_under_a_sheen_follow_their_density_and_agree_with_eval() {
    let (base, cc) = (CoatTable::new(1.5), CoatTable::new(1.5));
    let cases = [
        ((0.6, 0.0, 0.0), (0.0, 0.0), 0.5f32),
        ((0.4, 0.0, 1.0), (1.0, 0.4), 0.8),
        ((0.5, 1.0, 0.0), (0.0, 0.0), 0.3),
    ];
    let tests = (cases.len() * 3) as f64;
    let mut rng = HashRng::new(31);
    for (b, coat, sheen) in cases {
        let p = sheened(
            params(b, coat, Vec3A::new(0.8, 0.5, 0.2)),
            Vec3A::new(0.9, 0.6, 0.7),
            sheen,
        );
        let bsdf = layered(p, &base, &cc, MS);
        chi_square(
            &format!("sheen {sheen} coat {coat:?} over {b:?}"),
            &bsdf,
            tests,
        );
        for (o, s) in pbr_draws(&bsdf, &mut rng, 5_000) {
            check_draw(&format!("sheen {sheen} over {b:?}"), &bsdf, o, &s);
        }
    }
}

/// A black sheen is no sheen: the same samples, values and densities, bit for bit.
#[test]
fn a_black_sheen_is_no_sheen_bit_for_bit() {
    let (base, cc) = (CoatTable::new(1.5), CoatTable::new(1.5));
    let mut rng = HashRng::new(41);
    for b in BASES {
        let p = sheened(
            params(b, (0.5, 0.3), Vec3A::new(0.7, 0.6, 0.2)),
            Vec3A::ZERO,
            0.5,
        );
        let (plain, black) = (coated(p, &base, &cc, MS), layered(p, &base, &cc, MS));
        for _ in 0..2_000 {
            let o = tessera_render::sampling::square_to_cosine_hemisphere(u2(&mut rng));
            let (u, c) = (u2(&mut rng), rng.next_f32());
            assert_eq!(
                format!("{:?}", plain.sample(o, u, c)),
                format!("{:?}", black.sample(o, u, c))
            );
            let i = tessera_render::sampling::square_to_cosine_hemisphere(u);
            assert_eq!(plain.eval(o, i).to_array(), black.eval(o, i).to_array());
        }
    }
}
