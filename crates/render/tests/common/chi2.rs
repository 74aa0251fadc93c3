//! Chi-square tests of a direction sampler against the density it claims (pbrt-v4 style):
//! directions are binned over the sphere, each bin's expected count is the claimed pdf
//! integrated over the bin by quadrature, and Pearson's statistic must not reject at 1%,
//! Šidák-corrected over the `tests` a file runs. Every sample must also land where the pdf is
//! positive.

use std::f64::consts::PI;

use glam::Vec3A;
use tessera_render::sampling::HashRng;

const THETA_BINS: usize = 24;
const PHI_BINS: usize = 48;
const SAMPLES: usize = 200_000;

fn bin_of(w: Vec3A) -> usize {
    let z = (w.z as f64).clamp(-1.0, 1.0);
    let t = (((1.0 - z) / 2.0 * THETA_BINS as f64) as usize).min(THETA_BINS - 1);
    let mut phi = (w.y as f64).atan2(w.x as f64);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    let p = ((phi / (2.0 * PI) * PHI_BINS as f64) as usize).min(PHI_BINS - 1);
    t * PHI_BINS + p
}

/// ∫ pdf over each bin, by a midpoint rule in (θ, φ) within it, dω = sin θ dθ dφ: steps even
/// in θ resolve lobes a degree or two wide at the poles, where bins even in cos θ are widest.
fn expected(pdf: &dyn Fn(Vec3A) -> f64, n: usize, sub_phi: usize) -> Vec<f64> {
    const SUB_THETA: usize = 256;
    let mut e = vec![0f64; THETA_BINS * PHI_BINS];
    let dphi = 2.0 * PI / (PHI_BINS * sub_phi) as f64;
    for t in 0..THETA_BINS {
        // The bin spans z from 1 − 2t/T down to 1 − 2(t + 1)/T.
        let z_hi = 1.0 - 2.0 * t as f64 / THETA_BINS as f64;
        let z_lo = 1.0 - 2.0 * (t + 1) as f64 / THETA_BINS as f64;
        let (th0, th1) = (z_hi.clamp(-1.0, 1.0).acos(), z_lo.clamp(-1.0, 1.0).acos());
        let dth = (th1 - th0) / SUB_THETA as f64;
        for k in 0..SUB_THETA {
            let th = th0 + (k as f64 + 0.5) * dth;
            let (r, z) = th.sin_cos();
            for j in 0..PHI_BINS * sub_phi {
                let phi = (j as f64 + 0.5) * dphi;
                let w = Vec3A::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
                e[t * PHI_BINS + j / sub_phi] += pdf(w) * r * dth * dphi * n as f64;
            }
        }
    }
    e
}

/// Regularised upper incomplete gamma Q(a, x) (Numerical Recipes: series or continued fraction).
fn gamma_q(a: f64, x: f64) -> f64 {
    let ln_gamma_a = ln_gamma(a);
    if x < a + 1.0 {
        let (mut sum, mut del, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - sum * (-x + a * x.ln() - ln_gamma_a).exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        (-x + a * x.ln() - ln_gamma_a).exp() * h
    }
}

fn ln_gamma(x: f64) -> f64 {
    // Lanczos approximation (g = 7, n = 9).
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Samples `SAMPLES` directions and runs the chi-square test against `pdf`, as one of `tests`.
/// A sample of `None` is left out, and `pdf` must integrate to one over the rest.
pub fn chi_square(
    name: &str,
    tests: f64,
    sample: impl FnMut(&mut HashRng) -> Option<Vec3A>,
    pdf: &dyn Fn(Vec3A) -> f64,
) {
    run(name, tests, sample, pdf, false, 32)
}

/// [`chi_square`] with the expected counts integrated at four times the resolution in
/// longitude: for a density that is constant over cells narrower than the default quadrature
/// resolves (an environment map a thousand texels wide, whose cells' densities differ much
/// from one to the next), where the coarse quadrature's aliasing alone can fail the test.
pub fn chi_square_fine(
    name: &str,
    tests: f64,
    sample: impl FnMut(&mut HashRng) -> Option<Vec3A>,
    pdf: &dyn Fn(Vec3A) -> f64,
) {
    run(name, tests, sample, pdf, false, 128)
}

/// [`chi_square`] for a sampler that may fail (a BSDF whose sampled direction lands on the
/// wrong side ends the path): `pdf` is the density of the successful samples per attempt, so
/// it integrates to the probability of success. The successes are tested against `pdf`
/// renormalised to them, and their share of the attempts must be its integral within 4.5
/// standard errors of the share plus 0.05% for the quadrature.
pub fn chi_square_with_failures(
    name: &str,
    tests: f64,
    sample: impl FnMut(&mut HashRng) -> Option<Vec3A>,
    pdf: &dyn Fn(Vec3A) -> f64,
) {
    run(name, tests, sample, pdf, true, 32)
}

fn run(
    name: &str,
    tests: f64,
    mut sample: impl FnMut(&mut HashRng) -> Option<Vec3A>,
    pdf: &dyn Fn(Vec3A) -> f64,
    failures: bool,
    sub_phi: usize,
) {
    let mut rng = HashRng::new(0x5eed ^ name.len() as u64);
    let mut observed = vec![0f64; THETA_BINS * PHI_BINS];
    let mut taken = 0usize;
    for _ in 0..SAMPLES {
        let Some(w) = sample(&mut rng) else { continue };
        assert!(
            w.is_finite() && (w.length() - 1.0).abs() < 1e-4,
            "{name}: bad direction {w:?}"
        );
        assert!(pdf(w) > 0.0, "{name}: sample {w:?} where the pdf is zero");
        observed[bin_of(w)] += 1.0;
        taken += 1;
    }
    let mut exp = expected(pdf, taken, sub_phi);
    let total_exp: f64 = exp.iter().sum();
    if failures {
        let share = taken as f64 / SAMPLES as f64;
        let integral = total_exp / taken as f64;
        let tolerance = 4.5 * (share * (1.0 - share) / SAMPLES as f64).sqrt() + 5e-4;
        assert!(
            (integral - share).abs() < tolerance,
            "{name}: pdf integrates to {integral}, but {share} of the samples succeeded"
        );
        for e in &mut exp {
            *e /= integral;
        }
    } else {
        assert!(
            (total_exp / taken as f64 - 1.0).abs() < 0.01,
            "{name}: pdf integrates to {}",
            total_exp / taken as f64
        );
    }
    // Pool bins with fewer than 5 expected samples.
    let mut order: Vec<usize> = (0..exp.len()).collect();
    order.sort_by(|&a, &b| exp[a].total_cmp(&exp[b]));
    let (mut chi2, mut dof) = (0f64, 0usize);
    let (mut pool_o, mut pool_e) = (0f64, 0f64);
    for &i in &order {
        if exp[i] < 5.0 {
            pool_o += observed[i];
            pool_e += exp[i];
            if pool_e >= 5.0 {
                chi2 += (pool_o - pool_e).powi(2) / pool_e;
                dof += 1;
                pool_o = 0.0;
                pool_e = 0.0;
            }
            continue;
        }
        chi2 += (observed[i] - exp[i]).powi(2) / exp[i];
        dof += 1;
    }
    if pool_e > 0.0 {
        chi2 += (pool_o - pool_e).powi(2) / pool_e.max(1e-9);
        dof += 1;
    }
    let dof = dof.saturating_sub(1).max(1);
    let p = gamma_q(dof as f64 / 2.0, chi2 / 2.0);
    let alpha = 1.0 - (1.0 - 0.01f64).powf(1.0 / tests);
    eprintln!("{name}: χ² = {chi2:.1}, dof = {dof}, p = {p:.4}");
    assert!(
        p > alpha,
        "{name}: rejected, χ² = {chi2:.1} with {dof} dof, p = {p:.2e} < {alpha:.2e}"
    );
}
