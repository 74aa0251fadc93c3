//! `tessera bench --adaptive`: noise-targeted adaptive sampling against uniform sampling, in
//! the same run. Each scene is rendered with a ladder of noise targets (`--max-spp` the cap);
//! for each point, the time uniform sampling needs to reach the same relMSE is read off the
//! uniform series measured just before (log–log interpolation between its points), and the
//! ratio of the two times is the speed-up at equal error.

use std::fmt::Write as _;
use std::time::Instant;

use anyhow::Result;
use tessera_render::output::RgbImage;
use tessera_render::scene::Scene;
use tessera_render::{render_frame, Adaptive, RenderSettings};

use super::peer::Row;
use super::stats::{rel_mse, series};

/// Noise targets measured: the image's expected √relMSE, about 2× the samples from one to the
/// next where no tile is capped, spanning the uniform series' 64 to 1024 spp on the bench's
/// scenes (a target above a scene's 64-spp error stops every tile at its pilot).
pub(super) const TARGETS: [f64; 7] = [0.12, 0.08, 0.05, 0.035, 0.025, 0.0175, 0.0125];

/// One timed adaptive render.
#[derive(Clone, Debug)]
pub(super) struct Point {
    pub(super) scene: String,
    pub(super) target: f64,
    pub(super) seed: u64,
    pub(super) seconds: f64,
    pub(super) mean_spp: f64,
    pub(super) relmse: f64,
}

pub(super) const CSV_HEADER: &str = "scene,noise_target,cap_spp,tile,seed,seconds,mean_spp,relmse";

/// Renders `scene` at every target of [`TARGETS`] for seeds `1..=seeds` (the uniform series'
/// seeds), capped at `cap` spp, deciding per `tile`-pixel tile.
pub(super) fn measure(
    scene: &Scene,
    name: &str,
    reference: &RgbImage,
    pool: &rayon::ThreadPool,
    (cap, tile, seeds): (u32, u32, u32),
) -> Result<Vec<Point>> {
    let mut out = Vec::new();
    for target in TARGETS {
        for seed in 1..=seeds as u64 {
            let settings = RenderSettings {
                seed,
                spp: cap,
                adaptive: Some(Adaptive::new(target, tile)?),
                ..RenderSettings::default()
            };
            let start = Instant::now();
            let sums = pool.install(|| render_frame(scene, &settings, &|_| {}));
            let seconds = start.elapsed().as_secs_f64();
            let mean_spp =
                sums.count.iter().map(|&k| k as f64).sum::<f64>() / sums.count.len() as f64;
            let p = Point {
                scene: name.to_string(),
                target,
                seed,
                seconds,
                mean_spp,
                relmse: rel_mse(&sums.finalize(), reference),
            };
            errln!("{}", to_csv(&p, cap, tile));
            out.push(p);
        }
    }
    Ok(out)
}

/// One CSV row.
pub(super) fn to_csv(p: &Point, cap: u32, tile: u32) -> String {
    format!(
        "{},{},{cap},{tile},{},{:.6},{:.2},{:.6e}",
        p.scene, p.target, p.seed, p.seconds, p.mean_spp, p.relmse
    )
}

/// Seconds the uniform series `(seconds, relMSE)` (by increasing spp) needs to reach `err`:
/// interpolated linearly in log–log between the two points around it, or, past the last
/// point, extrapolated from it with error ∝ 1/time (how Monte Carlo error falls there).
/// `None` above the first point's error. The flag says whether it was extrapolated.
pub(super) fn uniform_time_to(points: &[(f64, f64)], err: f64) -> Option<(f64, bool)> {
    let first = points.first()?;
    if err > first.1 {
        return None;
    }
    for w in points.windows(2) {
        let ((t0, e0), (t1, e1)) = (w[0], w[1]);
        if err <= e0 && err >= e1 {
            if e0 == e1 {
                return Some((t0, false));
            }
            let f = (err.ln() - e0.ln()) / (e1.ln() - e0.ln());
            return Some(((t0.ln() + f * (t1.ln() - t0.ln())).exp(), false));
        }
    }
    let &(t, e) = points.last()?;
    Some((t * e / err, err < e))
}

/// The adaptive report: per scene and target, the mean over seeds, the uniform time to the
/// same relMSE and the speed-up; then the speed-up's geometric mean per scene.
pub(super) fn report(rows: &[Row], points: &[Point], cap: u32, tile: u32, command: &str) -> String {
    let uniform = series(rows);
    let mut md = String::new();
    let _ = writeln!(md, "# Adaptive against uniform sampling\n");
    let _ = writeln!(md, "Made by `{command}`.\n");
    let _ = writeln!(
        md,
        "Uniform: tessera at 4, 16, … {cap} spp. Adaptive: `--noise-target T` for T in {:?}, \
         capped at {cap} spp, decided per {tile}×{tile} tile. Both with the same seeds, on the \
         same machine, one right after the other. \"uniform s\" is the time uniform sampling \
         needs for the adaptive point's relMSE, interpolated log–log between its two points \
         around it (marked * where extrapolated past its last point with error ∝ 1/time); \
         speed-up = uniform s / adaptive s, above 1 when adaptive sampling is faster. The \
         target is the image's expected √relMSE, so the √relMSE column says how well the \
         estimate from the samples kept it.\n",
        TARGETS
    );
    let _ = writeln!(
        md,
        "| scene | target | mean spp | adaptive s | relMSE | √relMSE | uniform s | speed-up |\n|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    let mut per_scene: Vec<(String, Vec<f64>)> = Vec::new();
    let mut scenes: Vec<&str> = points.iter().map(|p| p.scene.as_str()).collect();
    scenes.dedup();
    for scene in scenes {
        let Some(u) = uniform.get(&(scene.to_string(), "tessera".to_string())) else {
            continue;
        };
        let curve: Vec<(f64, f64)> = u.values().map(|(s, e, _)| (*s, *e)).collect();
        let mut ups = Vec::new();
        for target in TARGETS {
            let of: Vec<&Point> = points
                .iter()
                .filter(|p| p.scene == scene && p.target == target)
                .collect();
            if of.is_empty() {
                continue;
            }
            let n = of.len() as f64;
            let secs = of.iter().map(|p| p.seconds).sum::<f64>() / n;
            let err = of.iter().map(|p| p.relmse).sum::<f64>() / n;
            let spp = of.iter().map(|p| p.mean_spp).sum::<f64>() / n;
            let (ut, up) = match uniform_time_to(&curve, err) {
                Some((t, extrapolated)) => {
                    ups.push(t / secs);
                    (
                        format!("{t:.3}{}", if extrapolated { "*" } else { "" }),
                        format!("{:.2}×", t / secs),
                    )
                }
                None => ("".into(), "".into()),
            };
            let _ = writeln!(
                md,
                "| {scene} | {target} | {spp:.0} | {secs:.3} | {err:.3e} | {:.4} | {ut} | {up} |",
                err.sqrt()
            );
        }
        per_scene.push((scene.to_string(), ups));
    }
    let _ = writeln!(md, "\n## Summary\n");
    let _ = writeln!(
        md,
        "| scene | speed-up, geometric mean over targets | worst | best |\n|---|---:|---:|---:|"
    );
    for (scene, ups) in per_scene {
        if ups.is_empty() {
            continue;
        }
        let geo = (ups.iter().map(|u| u.ln()).sum::<f64>() / ups.len() as f64).exp();
        let worst = ups.iter().copied().fold(f64::INFINITY, f64::min);
        let best = ups.iter().copied().fold(0.0, f64::max);
        let _ = writeln!(md, "| {scene} | {geo:.2}× | {worst:.2}× | {best:.2}× |");
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_time_is_interpolated_log_log_and_extrapolated_as_one_over_time() {
        let curve = [(1.0, 1.0), (4.0, 0.25), (16.0, 0.0625)];
        let (t, x) = uniform_time_to(&curve, 0.5).expect("inside");
        assert!((t - 2.0).abs() < 1e-12 && !x, "{t}");
        let (t, x) = uniform_time_to(&curve, 0.25).expect("on a point");
        assert!((t - 4.0).abs() < 1e-12 && !x);
        let (t, x) = uniform_time_to(&curve, 0.03125).expect("past the end");
        assert!((t - 32.0).abs() < 1e-12 && x);
        assert_eq!(uniform_time_to(&curve, 2.0), None);
    }
}
