//! The total viewshed planned (`--needs total_viewshed`, budget
//! `total_viewshed=PERCENT`) and checked: the direction count `K` from the
//! scene's own error-against-`K` curve (docs/PLANNING.md, "The total
//! viewshed").
//!
//! Timonen's total viewshed (2013, sec. 3) sums, at every post, the area
//! seen along `K` azimuthal lines, each standing for its share of the
//! circle; between lines it sees nothing, so the error is the sampling of
//! azimuth alone, and it falls as `K` grows. The planner measures that
//! fall where the bake will be: at [`PILOT_POSTS`] random posts it walks
//! each post's lines ([`total_viewshed_at`], the areas the stage's sweep
//! gives there, to rounding) for every candidate `K` and for
//! [`REFERENCE_DIRECTIONS`], and takes the fewest directions whose 99.5th
//! percentile of the relative error stays within the budget. The
//! reference is a denser sampling, not the continuum: the plan reports
//! the gap between it and half as many directions, a bound on how far
//! it may itself sit from the limit. `check` measures a baked layer the
//! same way at posts of its own seed.
//!
//! The eye and the curvature are the stage's defaults, the reach the
//! request's `viewshed_distance` (a recipe's explicit `total_viewshed`
//! stage replaces the plan's, and `check` measures what it achieved).

use anyhow::Result;
use serde::{Deserialize, Serialize};
use terrabake_format::{Asset, Mmap};

use crate::algorithms::viewshed::total::{total_viewshed_at, Method, TotalOptions};
use crate::plan::reference::quantile_unsorted;
use crate::terrain::held::HeldDem;
use crate::terrain::random::SplitMix64;

/// The stage's time per post against the pilot's walk per post at the
/// same directions, where the stage walks too (a short reach): its lines
/// share one profile per line of the grid. Measured on the SRTM tile at
/// 5 km (2 cores, 2026-12-03): 54.5 s against the walk's 172 s at 96
/// directions, 156.9 s against 520 s at 180.
const NAIVE_PER_PILOT_WALK: f64 = 0.31;
/// The stage's hull-tree sweeps (a long reach, or the whole DEM), seconds
/// per post and profile vertex (the crossings of each direction's grid
/// step, [`crossings`]) on the machine the time models were fitted on:
/// 31.1 s for the SRTM tile's 1.44 M posts at 32 directions (210
/// crossings), the whole DEM, with the safe zone (2 cores, 2026-12-03);
/// the calibration scales it to the machine at hand.
const HULL_TREE_SECONDS_PER_POST_CROSSING: f64 = 1.03e-7;
/// Directions of the reference.
pub const REFERENCE_DIRECTIONS: usize = 720;
/// Direction counts the planner considers.
const CANDIDATES: [usize; 14] = [4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 180, 240, 360];
/// Posts the pilot walks, and at least as many `check` does: a 99th
/// percentile over 400 posts of the SRTM tile varied from 2.97 to 4.71 %
/// between seeds, over 2000 from 3.19 to 3.30 %.
pub const PILOT_POSTS: usize = 2000;
/// The share of the budget the pilot's quantile may take: the 99th
/// percentile over [`PILOT_POSTS`] posts is itself a sample (with 200
/// posts and the whole budget, a 2 % budget on the SRTM tile at 5 km chose
/// 240 directions and `check` measured 2.12 %).
pub(super) const BUDGET_SHARE: f64 = 0.9;

/// What the plan chose for the total viewshed.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TotalViewshedPlan {
    pub directions: usize,
    /// How far each eye sees, metres (`None`: the whole DEM).
    #[serde(default)]
    pub max_distance: Option<f64>,
    /// Per cent: the 99th percentile of the relative error at the pilot's
    /// posts, and its largest.
    pub predicted_p99_percent: f64,
    pub predicted_max_percent: f64,
    /// Per cent: the reference against half its directions (99th
    /// percentile): how far the reference may sit from the limit.
    pub reference_gap_percent: f64,
    /// Every candidate tried: directions and its 99th percentile, per cent.
    pub curve: Vec<(usize, f64)>,
    pub seconds: f64,
    /// What the stage holds (the DEM and an area per post for each worker
    /// thread and the sum), MiB.
    pub memory_mib: f64,
}

/// What `check` measured of a baked total viewshed.
#[derive(Debug, Clone, Serialize)]
pub struct TotalViewshedCheck {
    pub directions: usize,
    pub posts: usize,
    pub p99_percent: f64,
    pub max_percent: f64,
}

/// Profile vertices a post costs over `k` directions: the crossings of each
/// direction's grid step, which grow with its length (farther directions
/// take longer steps).
fn crossings(terrain: &crate::terrain::Terrain, k: usize) -> usize {
    crate::algorithms::viewshed::total::directions(terrain, k)
        .iter()
        .map(|(dir, _)| crate::algorithms::horizon::line::Stencil::new(dir.step).len())
        .sum()
}

/// The stage the plan bakes or `check` measures, as the pilot walks it:
/// its options (the eye, the reach, and the method its `auto` takes on
/// this grid), the curvature, and the bytes it holds per post. The planner
/// reads them off the stage (`plan::walked`), so that this
/// module needs only the algorithm.
pub(super) struct Walked {
    pub(super) options: TotalOptions,
    pub(super) curvature: f64,
    pub(super) bytes_per_post: u64,
}

impl Walked {
    /// The walk's options at `directions`.
    fn at(&self, directions: usize) -> TotalOptions {
        TotalOptions {
            directions,
            method: Method::Naive,
            ..self.options
        }
    }
}

/// Up to `n` distinct random posts with a height.
fn sample(dem: &HeldDem, n: usize, seed: u64) -> Vec<(usize, usize)> {
    let mut rng = SplitMix64(seed);
    let mut seen = std::collections::HashSet::new();
    (0..n * 4)
        .map(|_| (rng.below(dem.width), rng.below(dem.height)))
        .filter(|&(c, r)| !dem.z()[r * dem.width + c].is_nan() && seen.insert((c, r)))
        .take(n)
        .collect()
}

/// Per cent: `got` against `reference` at each post, relative to the
/// reference (at least one cell's area, so that an eye that sees next to
/// nothing does not divide by nothing).
fn errors(got: &[f64], reference: &[f64], cell_area: f64) -> Vec<f64> {
    got.iter()
        .zip(reference)
        .filter(|(g, r)| g.is_finite() && r.is_finite())
        .map(|(g, r)| 100.0 * (g - r).abs() / r.max(cell_area))
        .collect()
}

fn largest(e: &[f64]) -> f64 {
    e.iter().copied().fold(0.0, f64::max)
}

/// Plans the direction count for a budget of `percent`, or says which
/// budget 360 directions would meet.
pub(super) fn plan(
    asset: &Asset<Mmap>,
    dem: &HeldDem,
    percent: f64,
    stage: &Walked,
    (seed, scale): (u64, f64),
) -> crate::Result<TotalViewshedPlan> {
    let m = asset.manifest();
    let terrain = dem.terrain(stage.curvature);
    let posts = sample(dem, PILOT_POSTS, seed);
    let cell_area = m.cell_size.dx * m.cell_size.dy;
    let reference = total_viewshed_at(&terrain, &stage.at(REFERENCE_DIRECTIONS), &posts);
    let half = total_viewshed_at(&terrain, &stage.at(REFERENCE_DIRECTIONS / 2), &posts);
    let reference_gap_percent = quantile_unsorted(&mut errors(&half, &reference, cell_area), 0.99);
    let mut curve = Vec::new();
    let mut chosen = None;
    for k in CANDIDATES {
        let started = std::time::Instant::now();
        let got = total_viewshed_at(&terrain, &stage.at(k), &posts);
        let walked = started.elapsed().as_secs_f64();
        let mut e = errors(&got, &reference, cell_area);
        let p99 = quantile_unsorted(&mut e, 0.99);
        curve.push((k, p99));
        if p99 <= BUDGET_SHARE * percent {
            let posts_all = (m.width as f64) * (m.height as f64);
            let seconds = match stage.options.method {
                Method::Naive => {
                    NAIVE_PER_PILOT_WALK * walked / posts.len().max(1) as f64 * posts_all
                }
                Method::HullTree { .. } => {
                    scale
                        * HULL_TREE_SECONDS_PER_POST_CROSSING
                        * posts_all
                        * crossings(&terrain, k) as f64
                }
            };
            chosen = Some((k, p99, largest(&e), seconds));
            break;
        }
    }
    let Some((directions, p99, max, seconds)) = chosen else {
        let (_, at_most) = curve.last().copied().unwrap_or((0, f64::NAN));
        crate::error::bail!(
            "budget total_viewshed={percent}: cannot be met with up to 360 directions on this scene: 360 leave a relative error p99 of {at_most:.3} % at the pilot's posts; relax total_viewshed to at least {:.3}, or give a shorter --viewshed-distance",
            at_most / BUDGET_SHARE
        );
    };
    Ok(TotalViewshedPlan {
        directions,
        max_distance: stage.options.max_distance,
        predicted_p99_percent: p99,
        predicted_max_percent: max,
        reference_gap_percent,
        curve,
        seconds,
        memory_mib: (stage.bytes_per_post * u64::from(m.width) * u64::from(m.height)) as f64
            / 1048576.0,
    })
}

/// Measures `asset`'s total viewshed layer, baked by `stage` in
/// `directions`, at `samples` (at least [`PILOT_POSTS`]) random posts of
/// `seed` against [`REFERENCE_DIRECTIONS`].
pub(super) fn check(
    asset: &Asset<Mmap>,
    dem: &HeldDem,
    (stage, directions): (&Walked, usize),
    samples: usize,
    seed: u64,
) -> Result<TotalViewshedCheck> {
    let m = asset.manifest();
    let layer = asset.layer(terrabake_format::layers::TOTAL_VIEWSHED, 0)?;
    let mut cursor = layer.cursor::<f32>(0);
    let posts = sample(dem, samples.max(PILOT_POSTS), seed);
    let terrain = dem.terrain(stage.curvature);
    let reference = total_viewshed_at(&terrain, &stage.at(REFERENCE_DIRECTIONS), &posts);
    let baked: Vec<f64> = posts
        .iter()
        .map(|&(c, r)| cursor.get(c as u32, r as u32).map(f64::from))
        .collect::<terrabake_format::Result<_>>()?;
    let mut e = errors(&baked, &reference, m.cell_size.dx * m.cell_size.dy);
    Ok(TotalViewshedCheck {
        directions,
        posts: e.len(),
        p99_percent: quantile_unsorted(&mut e, 0.99),
        max_percent: largest(&e),
    })
}

/// Why the total viewshed has the directions it has.
pub(super) fn choice(t: &TotalViewshedPlan, percent: f64) -> super::Choice {
    let below = t.curve.iter().rev().nth(1).map(|&(k, p99)| {
        format!(
            "{k} directions: relative error p99 {p99:.3} % at the pilot's posts, over the budget"
        )
    });
    super::Choice {
        what: "viewshed".into(),
        chosen: format!("total viewshed, {} directions", t.directions),
        why: format!(
            "the fewest whose relative error against the area {} directions see, p99 over {} pilot posts, stays within {:.0} % of the {percent} % budget (p99 {:.3} %, max {:.3} %; the reference against half its directions: {:.3} %)",
            REFERENCE_DIRECTIONS,
            PILOT_POSTS,
            100.0 * BUDGET_SHARE,
            t.predicted_p99_percent,
            t.predicted_max_percent,
            t.reference_gap_percent
        ),
        rejected: below,
    }
}
