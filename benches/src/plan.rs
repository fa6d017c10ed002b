//! The planner's chart (`terrabake-bench plan`): for each DEM and budget,
//! plan, bake what the plan says, and measure what the bake achieved with
//! `check` on posts the plan never saw: budget against achieved error, and
//! budget against bake time and bytes (docs/PLANNING.md).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use serde::Serialize;

use super::chart::{log_log_svg, Series};
use super::markdown_table;
use terrabake::plan::budget::{Budget, Request};
use terrabake::plan::check::{check, CheckOptions};
use terrabake::plumbing::progress::Progress;
use terrabake::stage::run_stage;

/// One DEM and one budget: predicted and achieved.
#[derive(Debug, Clone, Serialize)]
pub struct PlanRow {
    pub dem: String,
    pub budget_deg: f64,
    pub sectors: usize,
    /// How far a stored direction may sit from `i * 360 / S`, degrees.
    pub direction_tolerance_deg: f64,
    pub encoding: String,
    /// The distance limit baked, km (NaN: to the edge).
    pub max_distance_km: f64,
    pub predicted_p99_deg: f64,
    pub achieved_p99_deg: f64,
    pub achieved_svf_p99: f64,
    pub predicted_seconds: f64,
    /// Where the plan said the bake's time would fall, seconds.
    pub predicted_range_seconds: (f64, f64),
    /// Wall seconds of the horizons and sky stages.
    pub bake_seconds: f64,
    pub plan_seconds: f64,
    pub predicted_bytes: u64,
    /// The asset's bytes on disk after the bake, as `check` measures them.
    pub asset_bytes: u64,
    pub met: bool,
    /// The planner refused the budget (the rest of the row is empty).
    pub refused: bool,
}

impl PlanRow {
    fn refused(dem: &str, budget_deg: f64) -> Self {
        Self {
            dem: dem.into(),
            budget_deg,
            sectors: 0,
            direction_tolerance_deg: f64::NAN,
            encoding: String::new(),
            max_distance_km: f64::NAN,
            predicted_p99_deg: f64::NAN,
            achieved_p99_deg: f64::NAN,
            achieved_svf_p99: f64::NAN,
            predicted_seconds: f64::NAN,
            predicted_range_seconds: (f64::NAN, f64::NAN),
            bake_seconds: f64::NAN,
            plan_seconds: f64::NAN,
            predicted_bytes: 0,
            asset_bytes: 0,
            met: false,
            refused: true,
        }
    }
}

/// `terrabake-bench plan`: its arguments.
#[derive(clap::Args, Debug)]
pub struct BenchPlanArgs {
    /// Ingested assets; their horizon and sky layers are baked again for each budget.
    #[arg(required = true)]
    pub assets: Vec<PathBuf>,
    /// Horizon budgets, degrees (the 99th percentile of the absolute error).
    #[arg(long, value_delimiter = ',', default_value = "0.25,0.5,1,2,4")]
    pub budgets: Vec<f64>,
    /// Write PREFIX_error.svg (achieved against budget), PREFIX_cost.svg (bake seconds
    /// against budget) and PREFIX_bytes.svg (the asset's bytes on disk against budget).
    #[arg(long, value_name = "PREFIX")]
    pub chart: Option<PathBuf>,
    /// Print the rows as JSON.
    #[arg(long)]
    pub json: bool,
}

impl BenchPlanArgs {
    pub fn run(&self, say: &dyn Fn(String)) -> Result<()> {
        let mut rows = Vec::new();
        for path in &self.assets {
            let dem = path.file_stem().map_or_else(
                || path.display().to_string(),
                |s| s.to_string_lossy().into_owned(),
            );
            for &horizon in &self.budgets {
                let budget = Budget {
                    horizon,
                    ..Default::default()
                };
                let request = Request {
                    budget,
                    ..Default::default()
                };
                let start = Instant::now();
                let asset = terrabake::stage::asset::open(path)?;
                let plan = match terrabake::plan::plan(&asset, &request, Progress::hidden()) {
                    Ok(plan) => plan,
                    Err(e) => {
                        say(format!("{dem} {horizon} deg: refused: {e:#}"));
                        rows.push(PlanRow::refused(&dem, horizon));
                        continue;
                    }
                };
                drop(asset);
                let plan_seconds = start.elapsed().as_secs_f64();
                let start = Instant::now();
                for stage in plan.stages() {
                    run_stage(path, stage.as_ref(), true, Progress::hidden())?;
                }
                let bake_seconds = start.elapsed().as_secs_f64();
                let report = check(
                    &terrabake::stage::asset::open(path)?,
                    &CheckOptions {
                        samples: 400,
                        seed: 99,
                        directions: 720,
                        cuts: &[],
                    },
                    Some(&budget),
                    &[],
                    Progress::hidden(),
                )?;
                let achieved = report.horizons.as_ref().expect("the plan baked horizons");
                let chosen = plan
                    .chosen
                    .as_ref()
                    .expect("the default needs take horizons");
                say(format!(
                    "{dem} {horizon} deg: {} directions {}, achieved p99 {:.3}",
                    chosen.sectors,
                    chosen.encoding.name(),
                    achieved.horizon_p99_deg
                ));
                rows.push(PlanRow {
                    dem: dem.clone(),
                    budget_deg: horizon,
                    sectors: chosen.sectors,
                    direction_tolerance_deg: chosen.direction_tolerance.unwrap_or(f64::NAN),
                    encoding: chosen.encoding.name().into(),
                    max_distance_km: chosen.max_distance.map_or(f64::NAN, |d| d / 1000.0),
                    predicted_p99_deg: chosen.horizon_p99_deg,
                    achieved_p99_deg: achieved.horizon_p99_deg,
                    achieved_svf_p99: achieved.svf_p99.unwrap_or(f64::NAN),
                    predicted_seconds: plan.seconds,
                    predicted_range_seconds: plan.seconds_range,
                    bake_seconds,
                    plan_seconds,
                    predicted_bytes: plan.bytes,
                    asset_bytes: report.bytes,
                    met: report.within_budget(),
                    refused: false,
                });
            }
        }
        if self.json {
            println!("{}", serde_json::to_string_pretty(&rows)?);
        } else {
            print!("{}", table(&rows));
            println!("\n{}\n{}", over_time(&rows), in_range(&rows));
        }
        if let Some(prefix) = &self.chart {
            charts(prefix, &rows)?;
        }
        Ok(())
    }
}

fn table(rows: &[PlanRow]) -> String {
    markdown_table(
        &[
            "DEM",
            "budget (deg)",
            "directions",
            "within (deg)",
            "encoding",
            "distance (km)",
            "predicted p99",
            "achieved p99",
            "achieved svf p99",
            "plan (s)",
            "bake (s)",
            "predicted bake (s)",
            "predicted bytes (MiB)",
            "bytes on disk (MiB)",
            "met",
        ],
        rows.iter().map(|r| {
            vec![
                r.dem.clone(),
                format!("{}", r.budget_deg),
                r.sectors.to_string(),
                format!("{:.2}", r.direction_tolerance_deg),
                r.encoding.clone(),
                if r.max_distance_km.is_nan() {
                    "edge".into()
                } else {
                    format!("{}", r.max_distance_km)
                },
                format!("{:.3}", r.predicted_p99_deg),
                format!("{:.3}", r.achieved_p99_deg),
                format!("{:.4}", r.achieved_svf_p99),
                format!("{:.1}", r.plan_seconds),
                format!("{:.2}", r.bake_seconds),
                format!("{:.2}", r.predicted_seconds),
                format!("{:.1}", r.predicted_bytes as f64 / f64::from(1 << 20)),
                format!("{:.1}", r.asset_bytes as f64 / f64::from(1 << 20)),
                match (r.refused, r.met) {
                    (true, _) => "refused",
                    (false, true) => "yes",
                    (false, false) => "NO",
                }
                .into(),
            ]
        }),
    )
}

/// How many bakes took longer than their plan predicted, and the most:
/// where the time models (`TERRABAKE_TIME_MODELS`) fall short on this
/// machine.
fn over_time(rows: &[PlanRow]) -> String {
    let baked: Vec<&PlanRow> = rows.iter().filter(|r| !r.refused).collect();
    let over: Vec<&PlanRow> = baked
        .iter()
        .copied()
        .filter(|r| r.bake_seconds > r.predicted_seconds)
        .collect();
    let ratio = |r: &PlanRow| r.bake_seconds / r.predicted_seconds;
    let worst = over
        .iter()
        .max_by(|a, b| ratio(a).total_cmp(&ratio(b)))
        .map_or(String::new(), |r| {
            format!(
                " (the most {:.2}x: {} at {} deg, {:.2} s against {:.2})",
                ratio(r),
                r.dem,
                r.budget_deg,
                r.bake_seconds,
                r.predicted_seconds
            )
        });
    format!(
        "bakes over their predicted time: {} of {}{worst}",
        over.len(),
        baked.len()
    )
}

/// Where the bakes fell against their predictions: the least, median and
/// largest of bake / predicted seconds, and how many fell in the predicted
/// range (what sets [`terrabake::plan::SECONDS_RANGE`]).
fn in_range(rows: &[PlanRow]) -> String {
    let baked: Vec<&PlanRow> = rows.iter().filter(|r| !r.refused).collect();
    let mut ratios: Vec<f64> = baked
        .iter()
        .map(|r| r.bake_seconds / r.predicted_seconds)
        .collect();
    if ratios.is_empty() {
        return "no bakes".into();
    }
    ratios.sort_by(f64::total_cmp);
    let within = baked
        .iter()
        .filter(|r| {
            let (low, high) = r.predicted_range_seconds;
            low <= r.bake_seconds && r.bake_seconds <= high
        })
        .count();
    format!(
        "bake / predicted: {:.2} to {:.2}, median {:.2}; in the predicted range: {within} of {}",
        ratios[0],
        ratios[ratios.len() - 1],
        ratios[ratios.len() / 2],
        baked.len()
    )
}

fn charts(prefix: &std::path::Path, rows: &[PlanRow]) -> Result<()> {
    let mut dems: Vec<&str> = rows.iter().map(|r| r.dem.as_str()).collect();
    dems.dedup();
    let series = |y: &dyn Fn(&PlanRow) -> f64| -> Vec<Series> {
        dems.iter()
            .map(|&dem| {
                let of = rows.iter().filter(|r| r.dem == dem && !r.refused);
                // Each point labelled with the directions the plan chose.
                Series::new(dem, of.clone().map(|r| (r.budget_deg, y(r))).collect())
                    .labelled(of.map(|r| r.sectors.to_string()).collect())
            })
            .collect()
    };
    let mut error = series(&|r| r.achieved_p99_deg);
    let budgets: Vec<f64> = rows.iter().map(|r| r.budget_deg).collect();
    error.push(Series::new(
        "the budget (achieved must lie below)",
        budgets.iter().map(|&b| (b, b)).collect(),
    ));
    let with = |suffix: &str| {
        let mut p = prefix.as_os_str().to_owned();
        p.push(suffix);
        PathBuf::from(p)
    };
    log_log_svg(
        &with("_error.svg"),
        "Planned bakes: achieved horizon error against the budget",
        "horizon budget, p99 (degrees)",
        "achieved p99 (degrees), independent posts",
        &error,
    )?;
    log_log_svg(
        &with("_cost.svg"),
        "Planned bakes: bake time against the budget (2 cores)",
        "horizon budget, p99 (degrees)",
        "horizons and sky stages (s)",
        &series(&|r| r.bake_seconds),
    )?;
    log_log_svg(
        &with("_bytes.svg"),
        "Planned bakes: asset bytes on disk against the budget",
        "horizon budget, p99 (degrees)",
        "asset on disk (MiB)",
        &series(&|r| r.asset_bytes as f64 / 1048576.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn over_time_counts_the_baked_rows_over_their_prediction() {
        let row = |dem: &str, bake: f64, predicted: f64| PlanRow {
            bake_seconds: bake,
            predicted_seconds: predicted,
            refused: false,
            ..PlanRow::refused(dem, 1.0)
        };
        let rows = [
            row("a", 1.0, 2.0),
            row("b", 3.0, 1.5),
            row("c", 1.1, 1.0),
            PlanRow::refused("d", 0.25),
        ];
        assert_eq!(
            over_time(&rows),
            "bakes over their predicted time: 2 of 3 (the most 2.00x: b at 1 deg, 3.00 s against 1.50)"
        );
        assert_eq!(
            over_time(&rows[..1]),
            "bakes over their predicted time: 0 of 1"
        );
    }
}
