//! The solar panel of the speed-against-accuracy charts, from the points
//! `pipelines/solar/chart_rsun.sh` measures (GRASS `r.sun` has to run, so
//! the measuring is a shell script and this is its chart): day 172's error
//! in the global irradiation against its seconds, terrabake's direction
//! counts as a curve per DEM, `r.sun` with its own shadowing and fed our
//! horizons as points.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use crate::chart::{log_log_svg_with_marks, Series};

/// `terrabake-bench solar`: its arguments.
#[derive(clap::Args, Debug)]
pub struct BenchSolarArgs {
    /// The points: chart_rsun.sh's points.tsv (dem, series, kind, directions, seconds,
    /// mean_pct, p95_pct; kind `line` for a curve, `mark` for a peer's point).
    pub points: PathBuf,
    /// The error to chart: `mean` or `p95` (of |x - reference| / reference, per cent).
    #[arg(long, default_value = "mean", value_parser = ["mean", "p95"])]
    pub error: String,
    /// Write one chart per DEM, PREFIX_DEM.svg.
    #[arg(long, value_name = "PREFIX")]
    pub chart: PathBuf,
}

impl BenchSolarArgs {
    pub fn run(&self, say: &dyn Fn(String)) -> Result<()> {
        let text = std::fs::read_to_string(&self.points)
            .with_context(|| format!("{}: cannot read the points", self.points.display()))?;
        // Per DEM: each series' points, and the direction counts of each curve.
        // Each point with its direction count, the label it carries.
        type Points = BTreeMap<String, Vec<(f64, f64, String)>>;
        let mut dems: BTreeMap<String, (Points, Points, Vec<u32>)> = BTreeMap::new();
        let column = if self.error == "mean" { 5 } else { 6 };
        for (i, line) in text.lines().enumerate().skip(1) {
            let cells: Vec<&str> = line.split('\t').collect();
            if cells.len() != 7 {
                bail!("{}:{}: expected 7 columns", self.points.display(), i + 1);
            }
            let number = |c: usize| -> Result<f64> {
                cells[c].trim().parse::<f64>().with_context(|| {
                    format!(
                        "{}:{}: {:?} is not a number",
                        self.points.display(),
                        i + 1,
                        cells[c]
                    )
                })
            };
            let (dem, series, kind, directions) = (cells[0], cells[1], cells[2], cells[3]);
            let point = (number(4)?, number(column)?, directions.to_string());
            let (lines, marks, counts) = dems.entry(dem.to_string()).or_default();
            match kind {
                "line" => {
                    lines.entry(series.to_string()).or_default().push(point);
                    counts.push(number(3)? as u32);
                }
                "mark" if directions.is_empty() => {
                    marks.entry(series.to_string()).or_default().push(point)
                }
                "mark" => marks
                    .entry(format!("{series}, by direction count"))
                    .or_default()
                    .push(point),
                other => bail!(
                    "{}:{}: kind {other:?}: line or mark",
                    self.points.display(),
                    i + 1
                ),
            }
        }
        for (dem, (lines, marks, counts)) in dems {
            let (lo, hi) = (counts.iter().min(), counts.iter().max());
            let span = match (lo, hi) {
                (Some(lo), Some(hi)) => format!(" ({lo} to {hi} directions)"),
                _ => String::new(),
            };
            let to_series = |m: Points, suffix: &str| -> Vec<Series> {
                m.into_iter()
                    .map(|(name, points)| Series::through(format!("{name}{suffix}"), points))
                    .collect()
            };
            let path = PathBuf::from(format!("{}_{dem}.svg", self.chart.display()));
            log_log_svg_with_marks(
                &path,
                &format!("Solar on {dem}: day 172, error against time"),
                "seconds for the day with its horizons (2 cores)",
                &format!("{} abs error of daily global irradiation, %", self.error),
                &to_series(lines, &span),
                &to_series(marks, ""),
            )?;
            say(format!("wrote {}", path.display()));
        }
        Ok(())
    }
}
