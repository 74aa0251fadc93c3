//! The log–log plot of relMSE against seconds, as SVG.

use std::path::Path;

use anyhow::Result;

use super::peer::Row;
use super::stats::series;

pub(super) fn plot(rows: &[Row], path: &Path) -> Result<()> {
    use plotters::prelude::*;
    let all = series(rows);
    let scenes: Vec<String> = {
        let mut s: Vec<String> = all.keys().map(|(s, _)| s.clone()).collect();
        s.dedup();
        s
    };
    let root = SVGBackend::new(path, (480 * scenes.len().max(1) as u32, 420)).into_drawing_area();
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        root.fill(&WHITE)?;
        let panels = root.split_evenly((1, scenes.len().max(1)));
        for (scene, panel) in scenes.iter().zip(panels.iter()) {
            let pts: Vec<(f64, f64)> = all
                .iter()
                .filter(|((s, _), _)| s == scene)
                .flat_map(|(_, p)| p.values().map(|(s, e, _)| (*s, *e)))
                .filter(|(s, e)| *s > 0.0 && *e > 0.0)
                .collect();
            if pts.is_empty() {
                continue;
            }
            let (x0, x1) = pts
                .iter()
                .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.0), a.1.max(p.0)));
            let (y0, y1) = pts
                .iter()
                .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.1), a.1.max(p.1)));
            let mut chart = ChartBuilder::on(panel)
                .caption(scene, ("sans-serif", 20))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(
                    (x0 * 0.8..x1 * 1.25).log_scale(),
                    (y0 * 0.8..y1 * 1.25).log_scale(),
                )?;
            chart
                .configure_mesh()
                .x_desc("seconds")
                .y_desc("relMSE")
                .x_label_formatter(&|v| format!("{v:.2}"))
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .draw()?;
            for (i, ((_, renderer), points)) in
                all.iter().filter(|((s, _), _)| s == scene).enumerate()
            {
                let color = Palette99::pick(i).to_rgba();
                let line: Vec<(f64, f64)> = points.values().map(|(s, e, _)| (*s, *e)).collect();
                chart
                    .draw_series(LineSeries::new(line.clone(), color.stroke_width(2)))?
                    .label(renderer.as_str())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                    });
                chart.draw_series(line.into_iter().map(|p| Circle::new(p, 3, color.filled())))?;
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()?;
        }
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| anyhow::anyhow!("drawing {}: {e}", path.display()))
}
