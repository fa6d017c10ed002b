//! `terrabake check`: the error a bake achieved, measured against exact
//! references computed from the heights alone, never from the baked layers
//! (docs/PLANNING.md).
//!
//! **Posts.** `samples` posts drawn uniformly (seeded, so a check repeats)
//! from the area the horizons stage computed, and a quarter as many again
//! of the highest local relief (the largest height range within four posts,
//! among twenty random candidates each): where horizons are steep, errors
//! are largest.
//!
//! **Horizon reference.** At each post, the exact line horizon
//! (`horizon::brute::line_horizon`: every crossing of the sight line with
//! the grid, on the two-triangle surface, with the stage's curvature and
//! refraction, and no distance limit) in `directions` grid directions, each
//! within 0.1 degree of `i * 360 / directions`. **Error** at each post and
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
use crate::horizon::sky::{svf_of_horizons, BandIntegrals};
use crate::horizon::terrain::{RowScale, Terrain};
use crate::horizon::{brute, plan_bands, read_heights, BandKind, HorizonsStage, Method};
use crate::progress::Progress;

/// How a check samples.
#[derive(Debug, Clone, Copy)]
pub struct CheckOptions {
    /// Random posts; a quarter as many of the highest relief are added.
    pub samples: usize,
    pub seed: u64,
    /// Reference directions.
    pub directions: usize,
}

impl Default for CheckOptions {
    fn default() -> Self {
        Self {
            samples: 400,
            seed: 1,
            directions: 720,
        }
    }
}

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
    /// The budget checked against, and each limit's verdict.
    pub budget: Option<Budget>,
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

/// A SplitMix64 stream: seeded, so that a check repeats.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// The sampled posts `(col, row)`: random ones, then those of the highest
/// relief; no nodata post, none twice.
fn sample_posts(
    z: &[f32],
    w: usize,
    [x0, y0, x1, y1]: [usize; 4],
    opts: &CheckOptions,
) -> (Vec<(usize, usize)>, usize) {
    let mut rng = Rng(opts.seed);
    let draw = |rng: &mut Rng| -> Option<(usize, usize)> {
        (0..32).find_map(|_| {
            let (c, r) = (x0 + rng.below(x1 - x0), y0 + rng.below(y1 - y0));
            (!z[r * w + c].is_nan()).then_some((c, r))
        })
    };
    let mut posts: Vec<(usize, usize)> = (0..opts.samples).filter_map(|_| draw(&mut rng)).collect();
    let h = z.len() / w;
    let relief = |(c, r): (usize, usize)| -> f32 {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for rr in r.saturating_sub(4)..(r + 5).min(h) {
            for cc in c.saturating_sub(4)..(c + 5).min(w) {
                let v = z[rr * w + cc];
                if !v.is_nan() {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
            }
        }
        hi - lo
    };
    let wanted = opts.samples / 4;
    let mut candidates: Vec<(f32, (usize, usize))> = (0..wanted * 20)
        .filter_map(|_| draw(&mut rng))
        .map(|p| (relief(p), p))
        .collect();
    candidates.sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
    let before = posts.len();
    for (_, p) in candidates {
        if posts.len() - before == wanted {
            break;
        }
        if !posts.contains(&p) {
            posts.push(p);
        }
    }
    let relief_posts = posts.len() - before;
    (posts, relief_posts)
}

/// The value at `p` percent of sorted `v` (0 when empty).
fn percentile(v: &[f64], p: usize) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v[(v.len() * p / 100).min(v.len() - 1)]
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
    if opts.samples == 0 || opts.directions < 4 {
        bail!("a check needs at least one sample and four reference directions");
    }
    let (z, w, h) = read_heights(asset)?;
    let m = asset.manifest();
    let row_scale = crate::geo::row_scale(m.georef.as_ref(), h as u32);
    let terrain = Terrain::new(&z, w, h, m.cell_size.dx, m.cell_size.dy)
        .with_row_scale(RowScale::new(&row_scale))
        .with_curvature(stage.curvature_coefficient(asset));
    let (posts, relief_posts) = sample_posts(&z, w, stage.area(w, h), opts);
    if posts.is_empty() {
        bail!(
            "{}: the area holds no post with a height to check",
            dir.display()
        );
    }
    let reference = plan_bands(
        Method::Line,
        opts.directions,
        m.cell_size.dx,
        m.cell_size.dy,
        Some(0.1),
    );
    let integrals: Vec<BandIntegrals> = reference
        .iter()
        .map(|b| BandIntegrals::new(b.lo, b.hi))
        .collect();
    let svf_layer = asset.layer(SVF, 0).ok();
    let bar = progress.bar(posts.len() as u64, "check", "posts");
    // Per post: the signed horizon errors at every reference azimuth, and
    // the svf error.
    let per_post: Vec<Result<(Vec<f64>, Option<f64>)>> = posts
        .par_iter()
        .map(|&(c, r)| {
            let mut errors = Vec::with_capacity(reference.len());
            let mut exact = Vec::with_capacity(reference.len());
            for band in &reference {
                let BandKind::Line(direction) = &band.kind else {
                    unreachable!("reference bands are lines")
                };
                let truth = f64::from(brute::line_horizon(&terrain, (c, r), direction.step, None));
                exact.push(truth);
                if let Some(stored) = map.horizon_at(c as u32, r as u32, band.azimuth)? {
                    errors.push(stored - truth);
                }
            }
            let svf_error = match &svf_layer {
                Some(layer) => {
                    let stored = layer.get::<f32>(0, c as u32, r as u32)?;
                    (!stored.is_nan())
                        .then(|| f64::from(stored) - svf_of_horizons(&integrals, exact))
                }
                None => None,
            };
            bar.inc(1);
            Ok((errors, svf_error))
        })
        .collect();
    bar.finish_and_clear();
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
        posts: posts.len(),
        relief_posts,
        reference_directions: reference.len(),
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
        verdicts: Vec::new(),
    };
    if let Some(b) = budget {
        report.verdicts = verdicts(&report, b);
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
