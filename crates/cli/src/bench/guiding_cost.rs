//! `tessera bench --guiding`: path guiding against unguided rendering, in the same run. After
//! each of tessera's uniform points the same scene, spp and seed is rendered with guiding,
//! timed whole (training epochs included), as renderer `tessera-guided`, so the main report
//! and plot carry it as a series of its own. Its own report reads off, for each guided point,
//! the time unguided rendering needs to reach the same relMSE (log–log interpolation between
//! its points, as `--adaptive` does), and the ratio of the two times is guiding's speed-up at
//! equal error.

use std::fmt::Write as _;
use std::time::Instant;

use tessera_render::guiding::render_frame_guided;
use tessera_render::output::RgbImage;
use tessera_render::scene::Scene;
use tessera_render::RenderSettings;

use super::adaptive::uniform_time_to;
use super::peer::Row;
use super::stats::{errors, series};

/// The renderer name of guided rows.
pub(super) const RENDERER: &str = "tessera-guided";

/// One timed guided render of `scene` (named `name`) with `settings`.
pub(super) fn measure(
    scene: &Scene,
    name: &str,
    settings: &RenderSettings,
    reference: &RgbImage,
    pool: &rayon::ThreadPool,
) -> Row {
    let start = Instant::now();
    let frame = pool.install(|| render_frame_guided(scene, settings, &|_| {}));
    let seconds = start.elapsed().as_secs_f64();
    let threads = pool.current_num_threads();
    let img = frame.sums.finalize();
    Row::timed(
        RENDERER,
        (scene, name),
        settings,
        (threads, seconds),
        errors(&img, reference),
    )
}

/// The guiding report: per scene and spp, guided against unguided, the mean over seeds, the
/// unguided time to the same relMSE and the speed-up; then per scene the speed-up's geometric
/// mean over spp ≥ 64 (below it the first epochs are most of the render).
pub(super) fn report(rows: &[Row], command: &str) -> String {
    let all = series(rows);
    let mut md = String::new();
    let _ = writeln!(md, "# Path guiding against unguided rendering\n");
    let _ = writeln!(md, "Made by `{command}`.\n");
    let _ = writeln!(
        md,
        "Both at the same spp and seeds, on the same machine, each guided render right after \
         the unguided one; the guided time includes its training epochs. \"unguided s\" is the \
         time unguided rendering needs for the guided point's relMSE, interpolated log–log \
         between its two points around it (marked * where extrapolated past its last point \
         with error ∝ 1/time); speed-up = unguided s / guided s, above 1 when guiding is \
         faster to the same error.\n"
    );
    let _ = writeln!(
        md,
        "| scene | spp | unguided s | unguided relMSE | guided s | guided relMSE | unguided s to the guided relMSE | speed-up |\n|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    let mut summary = String::new();
    let scenes: std::collections::BTreeSet<&String> = all.keys().map(|(s, _)| s).collect();
    for scene in scenes {
        let (Some(plain), Some(guided)) = (
            all.get(&(scene.clone(), "tessera".to_string())),
            all.get(&(scene.clone(), RENDERER.to_string())),
        ) else {
            continue;
        };
        let curve: Vec<(f64, f64)> = plain.values().map(|(s, e, _)| (*s, *e)).collect();
        let mut ups = Vec::new();
        for (spp, (secs, err, _)) in guided {
            let (ps, pe) = plain.get(spp).map_or((f64::NAN, f64::NAN), |p| (p.0, p.1));
            let (ut, up) = match uniform_time_to(&curve, *err) {
                Some((t, extrapolated)) => {
                    if *spp >= 64 {
                        ups.push(t / secs);
                    }
                    (
                        format!("{t:.3}{}", if extrapolated { "*" } else { "" }),
                        format!("{:.2}×", t / secs),
                    )
                }
                None => (String::new(), String::new()),
            };
            let _ = writeln!(
                md,
                "| {scene} | {spp} | {ps:.3} | {pe:.3e} | {secs:.3} | {err:.3e} | {ut} | {up} |"
            );
        }
        if !ups.is_empty() {
            let geo = (ups.iter().map(|u| u.ln()).sum::<f64>() / ups.len() as f64).exp();
            let worst = ups.iter().copied().fold(f64::INFINITY, f64::min);
            let best = ups.iter().copied().fold(0.0, f64::max);
            let _ = writeln!(
                summary,
                "| {scene} | {geo:.2}× | {worst:.2}× | {best:.2}× |"
            );
        }
    }
    let _ = writeln!(
        md,
        "\n## Summary\n\n| scene | speed-up, geometric mean over spp ≥ 64 | worst | best |\n|---|---:|---:|---:|\n{summary}"
    );
    md
}
