//! SVG line charts for the benchmarks (docs/charts/), with plotters' SVG
//! backend: no system fonts, text left to the viewer's default sans-serif.

use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;

/// One line of a chart: its points and, where a knob sets each point (a
/// direction count, a slice count, a search radius), the knob's value
/// written beside it.
#[derive(Debug, Clone, Default)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// One label a point, or none at all.
    pub labels: Vec<String>,
}

impl Series {
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            name: name.into(),
            points,
            labels: Vec::new(),
        }
    }

    /// A curve through `points` in the order of x, each labelled with its
    /// string (no labels where every string is empty).
    pub fn through(name: impl Into<String>, mut points: Vec<(f64, f64, String)>) -> Self {
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        let series = Series::new(name, points.iter().map(|p| (p.0, p.1)).collect());
        if points.iter().any(|p| !p.2.is_empty()) {
            series.labelled(points.into_iter().map(|p| p.2).collect())
        } else {
            series
        }
    }

    /// `self` with each point labelled (as many labels as points).
    pub fn labelled(mut self, labels: Vec<String>) -> Self {
        assert_eq!(
            labels.len(),
            self.points.len(),
            "{}: a label a point",
            self.name
        );
        self.labels = labels;
        self
    }
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

/// The picture (pixels), and the plot's share of its width: the legend
/// takes the rest.
const WIDTH: u32 = 960;
const HEIGHT: u32 = 480;
const PLOT_WIDTH: u32 = 690;

/// Legend lines of at most this many characters: a longer name wraps.
const LEGEND_CHARS: usize = 36;

/// `name` broken at spaces into lines of at most [`LEGEND_CHARS`].
fn wrapped(name: &str) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    for word in name.split(' ') {
        match lines.last_mut() {
            Some(line) if line.len() + 1 + word.len() <= LEGEND_CHARS => {
                line.push(' ');
                line.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
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

/// [`log_log_svg`] with `marks` besides: other tools' results, triangles
/// joined by a dashed line where a tool has several (its curve over its own
/// knob). Every point carries its series' label, if any; the legend stands
/// to the right of the plot, never over a point.
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
    let colour = |i: usize| palette[i % palette.len()];
    let label_font = ("sans-serif", 10).into_font();
    // Drawn into memory, then written atomically like every other output.
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (WIDTH, HEIGHT)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let (plot, legend) = root.split_horizontally(PLOT_WIDTH);
        let mut chart = ChartBuilder::on(&plot)
            .caption(title, ("sans-serif", 18))
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
        for (i, s) in series.iter().chain(marks).enumerate() {
            let c = colour(i);
            let mark = i >= series.len();
            if mark {
                chart
                    .draw_series(DashedLineSeries::new(
                        s.points.iter().copied(),
                        6,
                        4,
                        c.stroke_width(1),
                    ))
                    .map_err(|e| err(&e))?;
                chart
                    .draw_series(
                        s.points
                            .iter()
                            .map(|&p| TriangleMarker::new(p, 6, c.filled())),
                    )
                    .map_err(|e| err(&e))?;
            } else {
                chart
                    .draw_series(LineSeries::new(s.points.iter().copied(), c.stroke_width(2)))
                    .map_err(|e| err(&e))?;
                chart
                    .draw_series(s.points.iter().map(|&p| Circle::new(p, 3, c.filled())))
                    .map_err(|e| err(&e))?;
            }
            chart
                .draw_series(s.labels.iter().zip(&s.points).map(|(label, &p)| {
                    EmptyElement::at(p) + Text::new(label.clone(), (4, -12), label_font.color(&c))
                }))
                .map_err(|e| err(&e))?;
        }
        // The legend, a column of its own beside the plot.
        let font = ("sans-serif", 12).into_font();
        let mut y = 40;
        for (i, s) in series.iter().chain(marks).enumerate() {
            let c = colour(i);
            if i < series.len() {
                legend
                    .draw(&PathElement::new(
                        vec![(4, y + 6), (24, y + 6)],
                        c.stroke_width(2),
                    ))
                    .map_err(|e| err(&e))?;
            } else {
                legend
                    .draw(&TriangleMarker::new((14, y + 6), 5, c.filled()))
                    .map_err(|e| err(&e))?;
            }
            for line in wrapped(&s.name) {
                legend
                    .draw(&Text::new(line, (30, y), font.clone()))
                    .map_err(|e| err(&e))?;
                y += 15;
            }
            y += 5;
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The x of every `<text>` holding `s` in an SVG.
    fn text_x(svg: &str, s: &str) -> Vec<f64> {
        svg.split("<text ")
            .skip(1)
            .filter(|t| {
                t.split('>')
                    .nth(1)
                    .is_some_and(|body| body.trim_start().starts_with(s))
            })
            .map(|t| {
                let x = t.split("x=\"").nth(1).expect("a text has an x");
                x[..x.find('"').expect("closed")].parse().expect("a number")
            })
            .collect()
    }

    #[test]
    fn every_point_carries_its_knob_and_the_legend_stands_beside_the_plot() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("chart.svg");
        let ours = Series::new(
            "ours, a long name that wraps onto a second line",
            vec![(1.0, 1.0), (2.0, 0.5)],
        )
        .labelled(vec!["K=8".into(), "K=16".into()]);
        let peer = Series::new("a peer", vec![(10.0, 2.0), (20.0, 1.0), (40.0, 0.7)])
            .labelled(vec!["8".into(), "16".into(), "32".into()]);
        log_log_svg_with_marks(&path, "t", "x", "y", &[ours], &[peer]).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        for label in ["K=8", "K=16", "16", "32"] {
            let xs = text_x(&svg, label);
            assert!(!xs.is_empty(), "{label} is on the chart");
            assert!(
                xs.iter().all(|&x| x < f64::from(PLOT_WIDTH)),
                "{label} inside the plot"
            );
        }
        for name in ["ours, a long name that", "a peer"] {
            let xs = text_x(&svg, name);
            assert_eq!(xs.len(), 1, "{name} once in the legend");
            assert!(
                xs[0] > f64::from(PLOT_WIDTH),
                "{name} beside the plot, not over it"
            );
        }
        // The peer's three points are joined (a curve, not three marks).
        assert!(
            svg.matches("<polygon").count() > 3,
            "three triangles and the legend's"
        );
        assert!(
            svg.matches("<polyline").count() > 20,
            "dashes between the peer's points"
        );
    }

    #[test]
    fn a_long_name_wraps_at_spaces() {
        let lines = wrapped("sampled (centre line, nearest post), K = 8 .. 256 and more words");
        assert!(lines.len() > 1);
        assert!(lines.iter().all(|l| l.len() <= LEGEND_CHARS));
        assert_eq!(
            lines.join(" "),
            "sampled (centre line, nearest post), K = 8 .. 256 and more words"
        );
    }
}
