//! The report's pictures: accuracy against latency per method (the paper's
//! scatter), recall per condition, and precision against recall on the
//! clean condition (one curve per method, swept over the top-1 score).
//!
//! Charts are drawn as SVG by `plotters` (its SVG backend needs no system
//! libraries) and rasterised to PNG by `resvg`, which finds its fonts among
//! the system's (Debian's `fonts-dejavu-core`); without fonts the charts are
//! still drawn, only without their text. Both files are kept: the SVG for
//! documents, the PNG for quick viewing.

use std::path::Path;

use anyhow::Context;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::report::EvalReport;

/// One colour per method, in report order.
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

fn methods(report: &EvalReport) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for c in &report.conditions {
        for r in &c.results {
            if !names.contains(&r.method) {
                names.push(r.method.clone());
            }
        }
    }
    names
}

fn colour(methods: &[String], method: &str) -> RGBColor {
    let i = methods.iter().position(|m| m == method).unwrap_or(0);
    PALETTE[i % PALETTE.len()]
}

/// A chart of this module: a Cartesian chart over `f64` on an SVG string.
type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// How every chart ends: its legend, framed on a pale background at
/// `legend`, then the drawing written out to the SVG string.
fn finish<'a, 'b: 'a>(
    mut chart: Chart<'a, 'b>,
    root: &DrawingArea<SVGBackend<'b>, Shift>,
    legend: SeriesLabelPosition,
) -> anyhow::Result<()> {
    chart
        .configure_series_labels()
        .position(legend)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()?;
    root.present()?;
    Ok(())
}

/// Recall@1 against median latency, one point per method and condition.
pub fn accuracy_latency_svg(report: &EvalReport) -> anyhow::Result<String> {
    let names = methods(report);
    let points: Vec<(f64, f64, &str, &str)> = report
        .conditions
        .iter()
        .flat_map(|c| {
            c.results.iter().map(move |r| {
                (
                    r.latency.median_ms.max(0.01),
                    r.retrieval.recall_at_1,
                    r.method.as_str(),
                    c.condition.as_str(),
                )
            })
        })
        .collect();
    let max_ms = points.iter().map(|p| p.0).fold(1.0f64, f64::max) * 1.15;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (800, 520)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{}: Recall@1 against median latency", report.dataset),
                ("sans-serif", 22),
            )
            .margin(16)
            .x_label_area_size(48)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0..max_ms, 0.0f64..1.05)?;
        chart
            .configure_mesh()
            .light_line_style(WHITE)
            .x_desc("median latency per query (ms)")
            .y_desc("Recall@1")
            .label_style(("sans-serif", 14))
            .draw()?;
        for name in &names {
            let c = colour(&names, name);
            let mine: Vec<_> = points.iter().filter(|p| p.2 == name).collect();
            chart
                .draw_series(mine.iter().map(|p| {
                    let style = if p.3 == "clean" {
                        c.filled()
                    } else {
                        c.stroke_width(2)
                    };
                    Circle::new((p.0, p.1), 6, style)
                }))?
                .label(name.as_str())
                .legend(move |(x, y)| Circle::new((x, y), 5, c.filled()));
            chart.draw_series(mine.iter().filter(|p| p.3 != "clean").map(|p| {
                Text::new(
                    p.3.to_string(),
                    (p.0, p.1),
                    ("sans-serif", 12).into_font().color(&c),
                )
            }))?;
        }
        finish(chart, &root, SeriesLabelPosition::LowerRight)?;
    }
    Ok(svg)
}

/// Recall@1 (solid) and Recall@5 (pale) per condition, one bar per method.
pub fn recall_per_condition_svg(report: &EvalReport) -> anyhow::Result<String> {
    let names = methods(report);
    let conditions: Vec<&str> = report
        .conditions
        .iter()
        .map(|c| c.condition.as_str())
        .collect();
    let groups = conditions.len().max(1);
    let slots = names.len().max(1) + 1; // one empty slot between groups
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (800, 520)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "{}: recall per condition (solid R@1, pale R@5)",
                    report.dataset
                ),
                ("sans-serif", 22),
            )
            .margin(16)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0f64..(groups * slots) as f64, 0.0f64..1.3)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .light_line_style(WHITE)
            .x_labels(0)
            .y_desc("recall")
            .y_labels(7)
            .label_style(("sans-serif", 14))
            .draw()?;
        for (g, condition) in report.conditions.iter().enumerate() {
            let base = (g * slots) as f64 + 0.5;
            chart.draw_series(std::iter::once(Text::new(
                condition.condition.clone(),
                (base + (names.len() as f64) / 2.0 - 0.5, 1.04),
                ("sans-serif", 14),
            )))?;
            for r in &condition.results {
                let i = names.iter().position(|m| *m == r.method).unwrap_or(0);
                let c = colour(&names, &r.method);
                let x0 = base + i as f64;
                chart.draw_series([
                    Rectangle::new(
                        [(x0, 0.0), (x0 + 0.85, r.retrieval.recall_at_5)],
                        c.mix(0.3).filled(),
                    ),
                    Rectangle::new(
                        [(x0, 0.0), (x0 + 0.85, r.retrieval.recall_at_1)],
                        c.filled(),
                    ),
                ])?;
            }
        }
        for name in &names {
            let c = colour(&names, name);
            chart
                .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())?
                .label(name.as_str())
                .legend(move |(x, y)| Rectangle::new([(x - 5, y - 5), (x + 5, y + 5)], c.filled()));
        }
        finish(chart, &root, SeriesLabelPosition::UpperLeft)?;
    }
    Ok(svg)
}

/// Rasterises an SVG to PNG with the system's fonts.
pub fn svg_to_png(svg: &str, path: &Path) -> anyhow::Result<()> {
    let mut options = resvg::usvg::Options::default();
    let fonts = options.fontdb_mut();
    fonts.load_system_fonts();
    // fontdb maps `sans-serif` to Arial; use a family that is installed.
    let family = fonts
        .faces()
        .flat_map(|f| f.families.iter().map(|(name, _)| name.clone()))
        .min_by_key(|name| (name != "DejaVu Sans", !name.contains("Sans"), name.clone()));
    match family {
        Some(family) => fonts.set_sans_serif_family(family),
        None => tracing::warn!("no system fonts: the charts are drawn without text"),
    }
    let tree = resvg::usvg::Tree::from_str(svg, &options).context("parsing the chart SVG")?;
    let size = tree.size().to_int_size();
    let mut pixmap = resvg::tiny_skia::Pixmap::new(size.width(), size.height())
        .context("allocating the chart image")?;
    resvg::render(
        &tree,
        resvg::tiny_skia::Transform::default(),
        &mut pixmap.as_mut(),
    );
    pixmap
        .save_png(path)
        .with_context(|| format!("writing {}", path.display()))
}

/// Precision against recall of the top-1 answer on the first (clean)
/// condition: one line per method through its curve's points, highest
/// threshold first; the operating point of each method is a filled dot.
pub fn precision_recall_svg(report: &EvalReport) -> anyhow::Result<String> {
    let names = methods(report);
    let Some(condition) = report.conditions.first() else {
        return Ok(String::new());
    };
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (800, 520)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "{} ({}): precision against recall of the top-1 answer",
                    report.dataset, condition.condition
                ),
                ("sans-serif", 22),
            )
            .margin(16)
            .x_label_area_size(48)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0f64..1.02, 0.0f64..1.05)?;
        chart
            .configure_mesh()
            .light_line_style(WHITE)
            .x_desc("recall (queries with a match)")
            .y_desc("precision (answered queries)")
            .label_style(("sans-serif", 14))
            .draw()?;
        for r in &condition.results {
            let c = colour(&names, &r.method);
            let line: Vec<(f64, f64)> = r
                .precision
                .curve
                .iter()
                .map(|p| (p.recall, p.precision))
                .collect();
            chart
                .draw_series(LineSeries::new(line, c.stroke_width(2)))?
                .label(r.method.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2))
                });
            let p = &r.precision;
            let answered_precision = if p.answered == 0 {
                1.0
            } else {
                (p.answered - p.false_top) as f64 / p.answered as f64
            };
            chart.draw_series(std::iter::once(Circle::new(
                (p.recall_at_threshold, answered_precision),
                5,
                c.filled(),
            )))?;
        }
        finish(chart, &root, SeriesLabelPosition::LowerLeft)?;
    }
    Ok(svg)
}

/// Writes every chart of `report` into `dir` as SVG and PNG; returns the
/// PNG file names written.
pub fn write_all(report: &EvalReport, dir: &Path) -> anyhow::Result<Vec<String>> {
    let charts = [
        ("accuracy_latency", accuracy_latency_svg(report)?),
        ("recall_per_condition", recall_per_condition_svg(report)?),
        ("precision_recall", precision_recall_svg(report)?),
    ];
    let mut written = Vec::new();
    for (name, svg) in charts {
        std::fs::write(dir.join(format!("{name}.svg")), &svg)
            .with_context(|| format!("writing {name}.svg"))?;
        svg_to_png(&svg, &dir.join(format!("{name}.png")))?;
        written.push(format!("{name}.png"));
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::{LatencyStats, Retrieval};
    use crate::report::{ConditionResult, MethodResult};

    fn result(method: &str, r1: f64, ms: f64) -> MethodResult {
        MethodResult {
            method: method.into(),
            retrieval: Retrieval {
                queries: 10,
                recall_at_1: r1,
                recall_at_5: (r1 + 0.2).min(1.0),
                mrr: r1,
            },
            latency: LatencyStats {
                samples: 30,
                mean_ms: ms,
                median_ms: ms,
                p95_ms: ms * 1.5,
            },
            stages_ms: Default::default(),
            precision: crate::report::tests::one_hit_one_false_alarm(),
        }
    }

    fn report() -> EvalReport {
        EvalReport {
            dataset: "toy".into(),
            kind: "pairs".into(),
            truth: "ground_truth.json".into(),
            references: 10,
            queries: 10,
            min_frame_gap: None,
            queries_without_match: 1,
            threshold: 0.4,
            calibration: "null".into(),
            max_candidates: 5,
            objects: crate::args::ObjectSource::Models,
            grey: false,
            verdict_replay: None,
            conditions: vec![
                ConditionResult {
                    condition: "clean".into(),
                    results: vec![result("SCAL", 0.6, 40.0), result("ORB-BoW", 0.4, 20.0)],
                },
                ConditionResult {
                    condition: "B15/D80".into(),
                    results: vec![result("SCAL", 0.1, 41.0), result("ORB-BoW", 0.05, 21.0)],
                },
            ],
        }
    }

    #[test]
    fn charts_carry_every_method_and_condition() {
        let scatter = accuracy_latency_svg(&report()).unwrap();
        assert!(scatter.contains("SCAL") && scatter.contains("ORB-BoW"));
        assert!(scatter.contains("B15/D80"));
        // Four points: two methods under two conditions.
        assert_eq!(scatter.matches("<circle").count(), 4 + 2, "{scatter}");
        let bars = recall_per_condition_svg(&report()).unwrap();
        assert!(bars.contains("clean") && bars.contains("B15/D80"));
        // One curve (a legend entry) and one operating-point dot per method
        // of the clean condition.
        let pr = precision_recall_svg(&report()).unwrap();
        assert!(pr.contains("SCAL") && pr.contains("ORB-BoW"));
        assert_eq!(pr.matches("<circle").count(), 2, "{pr}");
    }

    #[test]
    fn png_is_written_with_the_chart_size() {
        let dir = tempfile::tempdir().unwrap();
        let written = write_all(&report(), dir.path()).unwrap();
        assert_eq!(written.len(), 3);
        let png = image::open(dir.path().join("accuracy_latency.png")).unwrap();
        assert_eq!((png.width(), png.height()), (800, 520));
        // Not blank: the chart draws more than the white background.
        let rgb = png.to_rgb8();
        let coloured = rgb.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        assert!(coloured > 1000, "{coloured} non-white pixels");
    }
}
