//! A chart from measured points that a script gathered (a peer had to run,
//! so the measuring is a shell script and this is its chart): one curve per
//! series, each point labelled with its knob. `pipelines/compare_grass_viewshed.sh`
//! draws the viewshed chart (time against posts searched, terrabake beside
//! GRASS `r.viewshed`, every point labelled with the two's agreement) this way.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use crate::chart::{log_log_svg_with_marks, Series};

/// `terrabake-bench points`: its arguments.
#[derive(clap::Args, Debug)]
pub struct BenchPointsArgs {
    /// The points, tab-separated with a header row: series, kind (`line` for ours, `mark`
    /// for a peer's), label (written beside the point; may be empty), x, y.
    pub points: PathBuf,
    /// The chart to write (SVG).
    #[arg(long)]
    pub chart: PathBuf,
    #[arg(long)]
    pub title: String,
    #[arg(long)]
    pub x_label: String,
    #[arg(long)]
    pub y_label: String,
}

impl BenchPointsArgs {
    pub fn run(&self, say: &dyn Fn(String)) -> Result<()> {
        let path = self.points.display();
        let text = std::fs::read_to_string(&self.points)
            .with_context(|| format!("{path}: cannot read the points"))?;
        // (series, is ours, points with their labels), in the order first seen.
        type Curve = (String, bool, Vec<(f64, f64, String)>);
        let mut curves: Vec<Curve> = Vec::new();
        for (i, line) in text.lines().enumerate().skip(1) {
            let cells: Vec<&str> = line.split('\t').collect();
            let [series, kind, label, x, y] = cells[..] else {
                bail!("{path}:{}: expected 5 tab-separated columns", i + 1);
            };
            let number = |c: &str| -> Result<f64> {
                c.trim()
                    .parse::<f64>()
                    .with_context(|| format!("{path}:{}: {c:?} is not a number", i + 1))
            };
            let ours = match kind {
                "line" => true,
                "mark" => false,
                other => bail!("{path}:{}: kind {other:?}: line or mark", i + 1),
            };
            let point = (number(x)?, number(y)?, label.to_string());
            match curves.iter_mut().find(|c| c.0 == series && c.1 == ours) {
                Some(c) => c.2.push(point),
                None => curves.push((series.to_string(), ours, vec![point])),
            }
        }
        let to_series = |ours: bool| -> Vec<Series> {
            curves
                .iter()
                .filter(|c| c.1 == ours)
                .map(|(name, _, points)| Series::through(name, points.clone()))
                .collect()
        };
        log_log_svg_with_marks(
            &self.chart,
            &self.title,
            &self.x_label,
            &self.y_label,
            &to_series(true),
            &to_series(false),
        )?;
        say(format!("wrote {}", self.chart.display()));
        Ok(())
    }
}
