//! `terrabake check`: the error a bake achieved, measured against exact
//! references computed from the heights alone, never from the baked layers
//! (docs/PLANNING.md).
//!
//! **Reference.** `reference::Pilot`: sampled posts of the area the
//! horizons stage computed (random, and the highest relief), and their
//! exact line horizons in dense directions. **Error** at each post and
//! reference azimuth: what the loader serves there
//! (`HorizonMap::horizon_at`: the stored bands, linear between the two
//! nearest) minus the reference. The budget's statistic is the 99th
//! percentile of its absolute value over posts and azimuths: too few bands,
//! a distance limit, quantisation and interpolation all count.
//!
//! **Sky-view factor reference.** Zakšek's factor from the reference
//! horizons (each direction's band its share of the circle); the error is
//! the stored `svf` minus it, its statistic the 99th percentile over posts.

use std::time::Instant;

use anyhow::{bail, Context, Result};
use rayon::prelude::*;
use serde::Serialize;
use terrabake_format::horizons::HorizonMap;
use terrabake_format::layers::{HEIGHT, HORIZON, SVF};
use terrabake_format::{Asset, Mmap};

use crate::budget::Budget;
use crate::horizon::HorizonsStage;
use crate::plan::Candidate;
use crate::progress::Progress;
pub use crate::reference::{percentile, Pilot, Sampling};

/// How a check samples (the default: 400 posts and 100 of the highest
/// relief, seed 1, 720 directions).
pub type CheckOptions = Sampling;

/// What a check measured.
#[derive(Debug, Clone, Serialize)]
pub struct CheckReport {
    pub posts: usize,
    pub relief_posts: usize,
    pub reference_directions: usize,
    /// What was baked: method, bands, encoding.
    pub method: String,
    pub bands: usize,
    pub encoding: String,
    pub max_distance: Option<f64>,
    /// Absolute horizon angle error over posts and azimuths, degrees.
    pub horizon_p50_deg: f64,
    pub horizon_p99_deg: f64,
    pub horizon_max_deg: f64,
    /// Mean signed error (stored minus reference), degrees.
    pub horizon_bias_deg: f64,
    /// Absolute sky-view factor error over posts (`None`: no svf layer).
    pub svf_p99: Option<f64>,
    pub svf_max: Option<f64>,
    /// Bytes of the asset's files on disk.
    pub bytes: u64,
    pub seconds: f64,
    pub seed: u64,
    /// The budget checked against (given, or the recorded plan's), and
    /// each limit's verdict.
    pub budget: Option<Budget>,
    /// What the recorded plan (`bake --budget`) predicted, if any.
    pub predicted: Option<Candidate>,
    pub verdicts: Vec<Verdict>,
}

/// One limit of the budget against what was achieved.
#[derive(Debug, Clone, Serialize)]
pub struct Verdict {
    pub what: &'static str,
    pub achieved: Option<f64>,
    pub limit: f64,
    /// `None`: not measured by `check` (yet).
    pub met: Option<bool>,
}

impl CheckReport {
    /// Whether every measured limit was met.
    pub fn within_budget(&self) -> bool {
        self.verdicts.iter().all(|v| v.met != Some(false))
    }
}

/// Bytes of the regular files in `dir`.
fn bytes_on_disk(dir: &std::path::Path) -> u64 {
    std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .flatten()
                .filter_map(|e| e.metadata().ok())
                .filter(|m| m.is_file())
                .map(|m| m.len())
                .sum()
        })
        .unwrap_or(0)
}

/// Measures `asset`'s horizons and sky-view factor against the exact
/// references, and `budget`'s limits against them.
pub fn check(
    asset: &Asset<Mmap>,
    opts: &CheckOptions,
    budget: Option<&Budget>,
    progress: Progress,
) -> Result<CheckReport> {
    let start = Instant::now();
    let dir = asset.dir();
    let map = HorizonMap::open(asset).with_context(|| {
        format!(
            "{}: nothing to check: the asset has no horizon layer (terrabake horizons {})",
            dir.display(),
            dir.display()
        )
    })?;
    let Some(stage) = HorizonsStage::recorded(asset) else {
        bail!(
            "{}: the horizon layer has no stage record to check it against",
            dir.display()
        );
    };
    let m = asset.manifest();
    let area = stage.area(m.width as usize, m.height as usize);
    let pilot = Pilot::measure(
        asset,
        stage.curvature_coefficient(asset),
        area,
        opts,
        progress,
    )?;
    let svf_layer = asset.layer(SVF, 0).ok();
    // Per post: the signed horizon errors at every reference azimuth, and
    // the svf error.
    let per_post: Vec<Result<(Vec<f64>, Option<f64>)>> = pilot
        .posts
        .par_iter()
        .zip(&pilot.exact)
        .map(|(&(c, r), exact)| {
            let mut errors = Vec::with_capacity(exact.len());
            for (band, &truth) in pilot.reference.iter().zip(exact) {
                if let Some(stored) = map.horizon_at(c as u32, r as u32, band.azimuth)? {
                    errors.push(stored - truth);
                }
            }
            let svf_error = match &svf_layer {
                Some(layer) => {
                    let stored = layer.get::<f32>(0, c as u32, r as u32)?;
                    (!stored.is_nan()).then(|| f64::from(stored) - pilot.svf(exact))
                }
                None => None,
            };
            Ok((errors, svf_error))
        })
        .collect();
    let (mut horizon, mut svf) = (Vec::new(), Vec::new());
    for post in per_post {
        let (errors, svf_error) = post?;
        horizon.extend(errors);
        svf.extend(svf_error.map(f64::abs));
    }
    let bias = horizon.iter().sum::<f64>() / horizon.len().max(1) as f64;
    let mut horizon: Vec<f64> = horizon.into_iter().map(f64::abs).collect();
    horizon.sort_unstable_by(f64::total_cmp);
    svf.sort_unstable_by(f64::total_cmp);
    let layer = asset.layer(HORIZON, 0)?;
    let mut report = CheckReport {
        posts: pilot.posts.len(),
        relief_posts: pilot.relief_posts,
        reference_directions: pilot.reference.len(),
        method: stage.method.name().into(),
        bands: layer.bands() as usize,
        encoding: map.encoding().name().into(),
        max_distance: stage.max_distance,
        horizon_p50_deg: percentile(&horizon, 50),
        horizon_p99_deg: percentile(&horizon, 99),
        horizon_max_deg: horizon.last().copied().unwrap_or(0.0),
        horizon_bias_deg: bias,
        svf_p99: (!svf.is_empty()).then(|| percentile(&svf, 99)),
        svf_max: svf.last().copied(),
        bytes: bytes_on_disk(dir),
        seconds: start.elapsed().as_secs_f64(),
        seed: opts.seed,
        budget: budget.copied(),
        predicted: None,
        verdicts: Vec::new(),
    };
    let plan = crate::plan::recorded(asset);
    if report.budget.is_none() {
        report.budget = plan.as_ref().map(|p| p.budget);
    }
    report.predicted = plan.map(|p| p.chosen);
    if let Some(b) = report.budget {
        report.verdicts = verdicts(&report, &b);
    }
    Ok(report)
}

/// Each limit of `b` against `report`.
fn verdicts(report: &CheckReport, b: &Budget) -> Vec<Verdict> {
    let measured = |what, achieved: Option<f64>, limit: f64| Verdict {
        what,
        achieved,
        limit,
        met: achieved.map(|a| a <= limit),
    };
    let mut v = vec![measured(
        "horizon p99 (deg)",
        Some(report.horizon_p99_deg),
        b.horizon,
    )];
    if let Some(limit) = b.svf {
        // Asked for and not there is not met.
        let mut svf = measured("svf p99", report.svf_p99, limit);
        svf.met = Some(svf.met == Some(true));
        v.push(svf);
    }
    if let Some(limit) = b.bytes {
        v.push(measured("bytes", Some(report.bytes as f64), limit as f64));
    }
    for (what, limit) in [("shade share", b.shade), ("time (s)", b.time)] {
        if let Some(limit) = limit {
            v.push(Verdict {
                what,
                achieved: None,
                limit,
                met: None,
            });
        }
    }
    if let Some(limit) = b.memory {
        v.push(Verdict {
            what: "memory (MiB)",
            achieved: None,
            limit: limit as f64,
            met: None,
        });
    }
    v
}

/// Records `report` in the asset's manifest (a `check` record, dropped when
/// the heights, horizons or sky-view factors are baked again).
pub fn record(dir: &std::path::Path, report: &CheckReport) -> Result<()> {
    crate::stage::record_measurement(
        dir,
        "check",
        serde_json::to_value(report)?,
        vec![
            format!("{HEIGHT}@0"),
            format!("{HORIZON}@0"),
            format!("{SVF}@0"),
        ],
    )
}

/// The report as a table for people.
pub fn describe(report: &CheckReport) -> String {
    let mut out = format!(
        "checked {} posts ({} of the highest relief) against exact line horizons in {} directions ({:.1} s)\n\
         baked: {} horizons, {} bands, {}{}\n\n",
        report.posts,
        report.relief_posts,
        report.reference_directions,
        report.seconds,
        report.method,
        report.bands,
        report.encoding,
        report
            .max_distance
            .map_or(String::new(), |d| format!(", max distance {d} m")),
    );
    out += &format!(
        "horizon error (deg)   p50 {:.3}   p99 {:.3}   max {:.3}   bias {:+.3}\n",
        report.horizon_p50_deg,
        report.horizon_p99_deg,
        report.horizon_max_deg,
        report.horizon_bias_deg
    );
    if let (Some(p99), Some(max)) = (report.svf_p99, report.svf_max) {
        out += &format!("svf error             p99 {p99:.4}   max {max:.4}\n");
    }
    out += &format!(
        "bytes on disk         {}\n",
        crate::report::human_bytes(report.bytes)
    );
    if let Some(p) = &report.predicted {
        out += &format!(
            "planned               horizon p99 {:.3}   svf p99 {:.4}   horizon and sky layers {} ({} directions, {})\n",
            p.horizon_p99_deg,
            p.svf_p99,
            crate::report::human_bytes(p.bytes),
            p.sectors,
            p.encoding.name()
        );
    }
    if let Some(b) = &report.budget {
        out += &format!("\nbudget {b}\n");
        for v in &report.verdicts {
            let achieved = v.achieved.map_or("-".into(), |a| format!("{a:.4}"));
            let verdict = match v.met {
                Some(true) => "met",
                Some(false) => "EXCEEDED",
                None => "not measured by check yet",
            };
            out += &format!(
                "  {:<20} {:>12} <= {:<10} {verdict}\n",
                v.what, achieved, v.limit
            );
        }
    }
    out
}

/// Exit status of `check` when a measured limit is exceeded.
pub const EXIT_OVER_BUDGET: u8 = 4;

/// `terrabake check`: its arguments.
#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  terrabake check dem.tbake\n  \
terrabake check dem.tbake --budget horizon=0.5,svf=0.01 --json\n\n\
Exit status: 0 within budget (or none given), 1 error, 4 a measured limit exceeded.")]
pub struct CheckArgs {
    /// The asset whose horizons and sky-view factors are measured.
    pub asset: std::path::PathBuf,
    /// Random posts to measure; a quarter as many of the highest relief are added.
    #[arg(long, default_value_t = 400, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub samples: u64,
    /// Seed of the posts drawn (the same seed draws the same posts).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Reference directions (exact line horizons, within 0.1 degree of i * 360 / N).
    #[arg(long, default_value_t = 720, value_parser = clap::value_parser!(u64).range(4..=8192))]
    pub directions: u64,
    /// The budget to check: horizon=DEG[,svf=X][,shade=F][,time=S][,bytes=SIZE][,memory=MIB]
    /// (docs/PLANNING.md defines each).
    #[arg(long)]
    pub budget: Option<Budget>,
    /// Measure only: leave the manifest as it is (by default the result is recorded in it).
    #[arg(long)]
    pub no_record: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

impl CheckArgs {
    pub fn run(&self, progress: Progress) -> Result<std::process::ExitCode> {
        let asset = crate::asset::open(&self.asset)?;
        let opts = CheckOptions {
            samples: self.samples as usize,
            seed: self.seed,
            directions: self.directions as usize,
        };
        let report = check(&asset, &opts, self.budget.as_ref(), progress)?;
        drop(asset);
        if !self.no_record {
            record(&self.asset, &report)?;
        }
        if self.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print!("{}", describe(&report));
        }
        Ok(if report.within_budget() {
            std::process::ExitCode::SUCCESS
        } else {
            std::process::ExitCode::from(EXIT_OVER_BUDGET)
        })
    }
}
