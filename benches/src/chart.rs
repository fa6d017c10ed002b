//! SVG line charts for the benchmarks (docs/charts/), with plotters' SVG
//! backend: no system fonts, text left to the viewer's default sans-serif.

use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;

/// One line of a chart.
#[derive(Debug, Clone)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// A tick label: whole numbers from 10 up, two significant digits below.
fn tick(v: f64) -> String {
    if v >= 10.0 {
        format!("{v:.0}")
    } else {
        let digits = (1 - v.log10().floor() as i32).max(0) as usize;
        format!("{v:.digits$}")
    }
}

/// Ticks at 1, 2 and 5 times the powers of ten within `[lo, hi]`
/// (plotters' own log axis labels only the powers, too few within a decade).
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let mut ticks = Vec::new();
    let mut decade = 10f64.powi(lo.log10().floor() as i32);
    while decade <= hi {
        for m in [1.0, 2.0, 5.0] {
            let v = m * decade;
            if (lo..=hi).contains(&v) {
                ticks.push(v);
            }
        }
        decade *= 10.0;
    }
    ticks
}

/// The corner with the fewest points near it (in log space), for the
/// legend; upper corners win ties.
fn legend_corner(
    points: &[(f64, f64)],
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
) -> SeriesLabelPosition {
    let (xm, ym) = ((x0 * x1).sqrt(), (y0 * y1).sqrt());
    let count = |upper: bool, left: bool| {
        points
            .iter()
            .filter(|p| (p.1 >= ym) == upper && (p.0 < xm) == left)
            .count()
    };
    [
        (count(true, true), SeriesLabelPosition::UpperLeft),
        (count(true, false), SeriesLabelPosition::UpperRight),
        (count(false, true), SeriesLabelPosition::LowerLeft),
        (count(false, false), SeriesLabelPosition::LowerRight),
    ]
    .into_iter()
    .min_by_key(|(n, _)| *n)
    .map(|(_, corner)| corner)
    .expect("four corners")
}

/// A log-log line chart of `series`, written to `path` (SVG).
pub fn log_log_svg(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<()> {
    log_log_svg_with_marks(path, title, x_label, y_label, series, &[])
}

/// [`log_log_svg`] with `marks` besides: series drawn as triangles without
/// lines (other tools' results, one point each or a few).
pub fn log_log_svg_with_marks(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    marks: &[Series],
) -> Result<()> {
    let all: Vec<(f64, f64)> = series
        .iter()
        .chain(marks)
        .flat_map(|s| s.points.iter().copied())
        .filter(|p| p.0 > 0.0 && p.1 > 0.0)
        .collect();
    anyhow::ensure!(!all.is_empty(), "nothing to chart");
    let (x0, x1) = all
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (y0, y1) = all
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    let err = |e: &dyn std::fmt::Display| anyhow!("{}: {e}", path.display());
    // Drawn into memory, then written atomically like every other output.
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (720, 480)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(
                (x0 / 1.3..x1 * 1.3)
                    .log_scale()
                    .with_key_points(log_ticks(x0 / 1.3, x1 * 1.3)),
                (y0 / 1.25..y1 * 1.25)
                    .log_scale()
                    .with_key_points(log_ticks(y0 / 1.25, y1 * 1.25)),
            )
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .x_labels(12)
            .y_labels(12)
            .x_label_formatter(&|v| tick(*v))
            .y_label_formatter(&|v| tick(*v))
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(|e| err(&e))?;
        let palette = [
            RGBColor(0x1f, 0x77, 0xb4),
            RGBColor(0xd6, 0x27, 0x28),
            RGBColor(0x2c, 0xa0, 0x2c),
            RGBColor(0x94, 0x67, 0xbd),
            RGBColor(0xff, 0x7f, 0x0e),
            RGBColor(0x8c, 0x56, 0x4b),
            RGBColor(0xe3, 0x77, 0xc2),
            RGBColor(0x17, 0xbe, 0xcf),
            RGBColor(0xbc, 0xbd, 0x22),
            RGBColor(0x7f, 0x7f, 0x7f),
            RGBColor(0x39, 0x3b, 0x79),
            RGBColor(0xad, 0x49, 0x4a),
        ];
        for (i, s) in series.iter().enumerate() {
            let colour = palette[i % palette.len()];
            chart
                .draw_series(LineSeries::new(
                    s.points.iter().copied(),
                    colour.stroke_width(2),
                ))
                .map_err(|e| err(&e))?
                .label(s.name.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                });
            chart
                .draw_series(s.points.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                .map_err(|e| err(&e))?;
        }
        for (i, s) in marks.iter().enumerate() {
            let colour = palette[(series.len() + i) % palette.len()];
            chart
                .draw_series(
                    s.points
                        .iter()
                        .map(|&p| TriangleMarker::new(p, 7, colour.filled())),
                )
                .map_err(|e| err(&e))?
                .label(s.name.as_str())
                .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 6, colour.filled()));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .position(legend_corner(&all, (x0, x1), (y0, y1)))
            .draw()
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(terrabake::plumbing::output::write_atomically(
        path,
        |out| {
            use std::io::Write;
            Ok(out.write_all(svg.as_bytes())?)
        },
    )?)
}
