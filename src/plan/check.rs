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
//! **The DEM's edge.** Where the reference or one of the two bands serving
//! an azimuth has nothing of the DEM ahead (the post faces out over the
//! edge), the true horizon jumps from a real angle to none at an azimuth
//! no band records; no stored sampling can know where. Those samples are
//! counted and their largest error reported apart; the headline figures
//! and the budget's verdicts are over the rest, what the asset claims to
//! know. The largest error leaves out, besides, every sample whose exact
//! horizon the edge *may* cut (terrain beyond it, as high as the DEM's
//! highest post, could rise above it: the test the `horizon_edge` layer
//! counts), or whose serving band it may cut before the distance where
//! the exact horizon is set, and says how many (`Pilot::edge_may_cut`):
//! there the DEM cannot say what the horizon is, and a post near the edge
//! looking along it sees its sight lines leave the DEM at distances that
//! differ between two nearby azimuths.
//!
//! **Sky-view factor reference.** Zakšek's factor from the reference
//! horizons (each direction's band its share of the circle); the error is
//! the stored `svf` minus it, its statistic the 99th percentile over posts.

use std::process::ExitCode;
use std::time::Instant;

use anyhow::Result;
use rayon::prelude::*;
use serde::Serialize;
use terrabake_format::cones::ConePlanes;
use terrabake_format::horizons::{bands_around, HorizonMap, NOTHING_AHEAD};
use terrabake_format::layers::{HEIGHT, HORIZON, SVF};
use terrabake_format::trace::{Method as TraceMethod, Ray, Tracer};
use terrabake_format::{Asset, Mmap};

use crate::error::bail;
use crate::plan::budget::Budget;
pub use crate::plan::reference::{percentile, Pilot, Sampling};
use crate::plan::reference::{shade_differs, solar_error, PilotSun};
use crate::plan::{Baked, Candidate};
use crate::plumbing::progress::Progress;
use crate::stage::session::{Run, Session};
use crate::stages::horizons::HorizonsStage;
use crate::terrain::held::HeldDem;
use crate::terrain::random::SplitMix64;
use crate::terrain::sun::SunPosition;

/// How a check samples (the default: 400 posts and 100 of the highest
/// relief, seed 1, 720 directions).
pub type CheckOptions = Sampling;

/// `check`'s reference directions for `bands` stored ones: the default
/// 720, or twice the bands where more, so that it measures between them.
pub fn reference_directions(bands: usize) -> usize {
    (2 * bands).clamp(Sampling::default().directions, 8192)
}

/// What a check measured of the horizons and what derives from them.
#[derive(Debug, Clone, Serialize)]
pub struct HorizonCheck {
    pub posts: usize,
    pub relief_posts: usize,
    /// Posts around the prominent features ([`crate::plan::reference::FEATURES`])
    /// and how many features they lie around.
    pub feature_posts: usize,
    pub features: usize,
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
    /// Where the largest error is: the post `(col, row)` and the reference
    /// azimuth, degrees.
    pub horizon_max_at: Option<((usize, usize), f64)>,
    /// The largest error at the random and relief posts, and at the posts
    /// around the features, degrees.
    pub horizon_max_random_deg: f64,
    pub horizon_max_feature_deg: f64,
    /// Samples left out of the largest error (only) because the DEM's
    /// edge may cut their horizon (module docs).
    pub horizon_max_edge_may_cut: usize,
    /// Mean signed error (stored minus reference), degrees.
    pub horizon_bias_deg: f64,
    /// (post, azimuth) samples in the figures above (but the largest,
    /// which the posts around the features count for too).
    pub samples: usize,
    /// Samples at the DEM's edge (the reference or a serving band has
    /// nothing ahead), left out of the figures above; the posts they fall
    /// on, and their largest error (degrees, `None` when there are none).
    pub edge_samples: usize,
    pub edge_posts: usize,
    pub edge_max_deg: Option<f64>,
    /// Absolute sky-view factor error over posts (`None`: no svf layer).
    pub svf_p99: Option<f64>,
    pub svf_max: Option<f64>,
    /// The share of (post, sun position) pairs whose sun/shade state the
    /// stored horizons get wrong (`None`: no sun positions).
    pub shade_share: Option<f64>,
    pub sun_positions: usize,
    /// Per cent over posts, where the asset has a solar stage or the
    /// budget a solar limit: the year's beam the stored horizons put in the
    /// wrong sun or shade (`plan::reference::solar_error`), its 99th
    /// percentile and largest.
    pub solar_p99_percent: Option<f64>,
    pub solar_max_percent: Option<f64>,
}

/// What a check measured of the tracing layers, by brute force.
#[derive(Debug, Clone, Serialize)]
pub struct TracingCheck {
    /// Cells whose cone was checked against every cell of the DEM.
    pub cone_cells: usize,
    /// Cells whose stored cone holds terrain (must be 0).
    pub cone_violations: usize,
    /// Mean, over the checked cells, of the stored slope over the widest
    /// slope its apex allows (1: as wide as can be); measured on DEMs of up
    /// to 4 M cells.
    pub cone_tightness: Option<f64>,
    /// Random rays traced by each method and by the brute force.
    pub rays: usize,
    /// Per method, the rays whose hit differs from the brute force's (must
    /// be 0).
    pub mismatches: Vec<(String, usize)>,
    /// The fastest method the asset serves (parametric where it has cone
    /// planes), over the built-in views on one thread: what the `steps`
    /// and `rays` budgets are judged by.
    pub method: String,
    pub speed: crate::plan::tracing::TracingSpeed,
}

/// What a check measured.
#[derive(Debug, Clone, Serialize)]
pub struct CheckReport {
    pub horizons: Option<HorizonCheck>,
    pub tracing: Option<TracingCheck>,
    /// The total viewshed against 720 directions, where the asset has one.
    pub total_viewshed: Option<crate::plan::total_viewshed::TotalViewshedCheck>,
    /// Bytes of the asset on disk: the manifest and the layer files it
    /// names.
    pub bytes: u64,
    pub seconds: f64,
    pub seed: u64,
    /// The budget checked against (given, or the recorded plan's), and
    /// each limit's verdict.
    pub budget: Option<Budget>,
    /// What the recorded plan predicted for the horizons, if any.
    pub predicted: Option<Candidate>,
    /// What the recorded plan predicted the whole bake after ingest would
    /// take, seconds (the calibrated models' upper bound), the range it
    /// should fall in, and the plan's peak memory, MiB.
    pub planned_seconds: Option<f64>,
    pub planned_seconds_range: Option<(f64, f64)>,
    pub planned_memory_mib: Option<f64>,
    /// What the planned bake measured of itself (time, peak memory).
    pub baked: Option<Baked>,
    pub verdicts: Vec<Verdict>,
}

/// One limit of the budget against what was achieved.
#[derive(Debug, Clone, Serialize)]
pub struct Verdict {
    pub what: &'static str,
    pub achieved: Option<f64>,
    pub limit: f64,
    /// The limit is a floor (rays per second), not a ceiling.
    #[serde(default)]
    pub at_least: bool,
    /// `None`: not measured.
    pub met: Option<bool>,
}

impl CheckReport {
    /// Whether every measured limit was met, and the tracing layers are
    /// exact.
    pub fn within_budget(&self) -> bool {
        self.verdicts.iter().all(|v| v.met != Some(false))
            && self
                .tracing
                .as_ref()
                .is_none_or(|t| t.cone_violations == 0 && t.mismatches.iter().all(|(_, n)| *n == 0))
    }
}

/// Bytes of the asset: the files its manifest names (retired generations
/// and leftovers that writers delete are not the asset) and the manifest.
fn asset_bytes(asset: &Asset<Mmap>) -> u64 {
    let manifest =
        std::fs::metadata(asset.dir().join(terrabake_format::MANIFEST_FILE)).map_or(0, |m| m.len());
    manifest
        + asset
            .manifest()
            .layers
            .iter()
            .map(|l| l.file_len)
            .sum::<u64>()
}

/// Measures `asset`'s horizons, sky-view factors, sun/shade states and
/// tracing layers against exact references, and `budget`'s limits against
/// them. The sun positions are `sun`, else the recorded plan's.
pub fn check(
    asset: &Asset<Mmap>,
    opts: &CheckOptions,
    budget: Option<&Budget>,
    sun: &[SunPosition],
    progress: Progress,
) -> crate::Result<CheckReport> {
    // The work in anyhow, its causes kept; the kind at the surface.
    let run = move || -> Result<CheckReport> {
        let start = Instant::now();
        let dir = asset.dir();
        let plan = crate::plan::recorded(asset);
        let sun = if sun.is_empty() {
            plan.as_ref().map_or(&[][..], |p| &p.sun[..])
        } else {
            sun
        };
        if budget.is_some_and(|b| b.shade.is_some()) && sun.is_empty() {
            bail!(
                "{}: a shade budget needs sun positions, and neither --sun nor a recorded plan gives any (--sun AZ,EL;AZ,EL)",
                dir.display()
            );
        }
        // The year's sun where the asset bakes it or the budget asks.
        let m = asset.manifest();
        let solar = if budget.is_some_and(|b| b.solar.is_some())
            || crate::stage::recorded_params::<serde_json::Value>(m, "solar").is_some()
        {
            let latitude = m
                .georef
                .as_ref()
                .and_then(|g| crate::terrain::geo::central_latitude(g, m.width, m.height));
            match latitude {
                Some(latitude) => crate::plan::reference::solar_year(latitude),
                None if budget.is_some_and(|b| b.solar.is_some()) => bail!(
                    "{}: a solar budget needs the scene's latitude, and this DEM is neither geographic nor WGS 84 UTM",
                    dir.display()
                ),
                None => Vec::new(),
            }
        } else {
            Vec::new()
        };
        // The heights, read once for both references.
        let dem = HeldDem::read_within(asset, plan.as_ref().and_then(|p| p.budget.memory_bytes()))?;
        let horizons = match HorizonMap::open(asset) {
            Ok(map) => Some(check_horizons(
                asset,
                &dem,
                &map,
                opts,
                (sun, &solar),
                progress,
            )?),
            Err(_) => None,
        };
        let tracing = check_tracing(asset, &dem, opts)?;
        let total_viewshed = crate::stage::recorded_params::<
            crate::stages::viewshed::stage::TotalViewshedStage,
        >(asset.manifest(), "total_viewshed")
        .map(|stage| {
            let walked = crate::plan::walked(&stage, asset.manifest());
            crate::plan::total_viewshed::check(
                asset,
                &dem,
                (&walked, stage.directions),
                opts.samples,
                opts.seed,
            )
        })
        .transpose()?;
        if horizons.is_none() && tracing.is_none() && total_viewshed.is_none() {
            bail!(
                "{}: nothing to check: the asset has no horizon layer, pyramid, cone planes or total viewshed (terrabake horizons {})",
                dir.display(),
                dir.display()
            );
        }
        let mut report = CheckReport {
            horizons,
            tracing,
            total_viewshed,
            bytes: asset_bytes(asset),
            seconds: start.elapsed().as_secs_f64(),
            seed: opts.seed,
            budget: budget.copied(),
            predicted: None,
            planned_seconds: None,
            planned_seconds_range: None,
            planned_memory_mib: None,
            baked: None,
            verdicts: Vec::new(),
        };
        if report.budget.is_none() {
            report.budget = plan.as_ref().map(|p| p.budget);
        }
        if let Some(plan) = plan {
            report.predicted = plan.chosen;
            report.planned_seconds = Some(plan.seconds);
            // Plans recorded before the range was have none.
            report.planned_seconds_range =
                Some(plan.seconds_range).filter(|&(low, high)| 0.0 < low && low <= high);
            report.planned_memory_mib = Some(plan.memory_mib);
            report.baked = plan.baked;
        }
        if let Some(b) = report.budget {
            report.verdicts = verdicts(&report, &b);
        }
        Ok(report)
    };
    Ok(run()?)
}

/// The horizons against exact line horizons at sampled posts.
fn check_horizons(
    asset: &Asset<Mmap>,
    dem: &HeldDem,
    map: &HorizonMap<'_, Mmap>,
    opts: &CheckOptions,
    (sun, solar): (&[SunPosition], &[(SunPosition, f64)]),
    progress: Progress,
) -> Result<HorizonCheck> {
    let dir = asset.dir();
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
        dem,
        stage.sight.curvature_coefficient(asset.manifest()),
        area,
        opts,
        progress,
    )?;
    let svf_layer = asset.layer(SVF, 0).ok();
    // Each sun at the nearest reference direction, where both the exact
    // and the served horizon are known.
    let suns: Vec<(usize, f64)> = sun
        .iter()
        .map(|&[az, el]| (pilot.nearest_direction(az), el))
        .collect();
    let solar: Vec<PilotSun> = solar
        .iter()
        .map(|&(position, weight)| pilot.sun(position, weight))
        .collect();
    // Per post: the signed horizon errors at every reference azimuth (those
    // at the DEM's edge apart), the svf error, and the wrong sun/shade
    // states.
    type PostErrors = (
        Vec<f64>,
        Vec<f64>,
        Option<f64>,
        usize,
        Option<f64>,
        (f64, f64),
        usize,
    );
    let per_post: Vec<Result<PostErrors>> = pilot
        .posts
        .par_iter()
        .zip(&pilot.exact)
        .enumerate()
        .map(|(i, (&(c, r), exact))| {
            let (mut errors, mut at_edge) = (Vec::with_capacity(exact.len()), Vec::new());
            let (mut largest, mut edge_may_cut) = ((0.0f64, 0.0), 0);
            let mut served = vec![None; exact.len()];
            for (j, ((band, &truth), out)) in pilot
                .reference
                .iter()
                .zip(exact)
                .zip(&mut served)
                .enumerate()
            {
                let Some(s) = map.served_at(c as u32, r as u32, band.azimuth)? else {
                    continue;
                };
                *out = Some(s.angle);
                if s.at_edge || truth == NOTHING_AHEAD {
                    at_edge.push(s.angle - truth);
                    continue;
                }
                errors.push(s.angle - truth);
                // The largest error is bounded only where the DEM's edge
                // cannot cut the horizon (the pilot's rule).
                let (k, l, _) = bands_around(map.azimuths(), band.azimuth);
                let angle = |k: usize| -> Result<f64> {
                    Ok(map.angle(c as u32, r as u32, k as u32)?.unwrap_or(f64::NAN))
                };
                let bands = [
                    (map.azimuths()[k], angle(k)?),
                    (map.azimuths()[l], angle(l)?),
                ];
                if pilot.edge_may_cut((i, j), truth, bands) {
                    edge_may_cut += 1;
                } else if (s.angle - truth).abs() > largest.0 {
                    largest = ((s.angle - truth).abs(), band.azimuth);
                }
            }
            let wrong = suns
                .iter()
                .filter(|&&(j, el)| served[j].is_some_and(|s| shade_differs(el, s, exact[j])))
                .count();
            let svf_error = match &svf_layer {
                Some(layer) => {
                    let stored = layer.get::<f32>(0, c as u32, r as u32)?;
                    (!stored.is_nan()).then(|| f64::from(stored) - pilot.svf(exact))
                }
                None => None,
            };
            let solar_error = (!solar.is_empty()).then(|| {
                let served: Vec<f64> = served.iter().map(|s| s.unwrap_or(f64::NAN)).collect();
                solar_error(&solar, &served, exact)
            });
            Ok((
                errors,
                at_edge,
                svf_error,
                wrong,
                solar_error,
                largest,
                edge_may_cut,
            ))
        })
        .collect();
    let (mut horizon, mut svf, mut wrong, mut solar_errors) =
        (Vec::new(), Vec::new(), 0, Vec::new());
    let (mut edge_samples, mut edge_posts, mut edge_max) = (0, 0, None::<f64>);
    let mut edge_may_cut = 0;
    let scene_posts = pilot.scene_posts();
    let (mut max_at, mut max_random, mut max_feature) = (None, 0.0f64, 0.0f64);
    let mut svf_max = None::<f64>;
    for (i, post) in per_post.into_iter().enumerate() {
        let (errors, at_edge, svf_error, w, solar_error, largest, may_cut) = post?;
        edge_may_cut += may_cut;
        if largest.0 > max_at.map_or(0.0, |(e, _)| e) {
            max_at = Some((largest.0, (pilot.posts[i], largest.1)));
        }
        if let Some(e) = svf_error {
            svf_max = Some(svf_max.map_or(e.abs(), |m| m.max(e.abs())));
        }
        // The posts around features count for the largest errors only
        // (they are chosen where errors are large; the percentiles are
        // over the scene's posts).
        if i >= scene_posts {
            max_feature = max_feature.max(largest.0);
            continue;
        }
        max_random = max_random.max(largest.0);
        solar_errors.extend(solar_error);
        horizon.extend(errors);
        if !at_edge.is_empty() {
            edge_samples += at_edge.len();
            edge_posts += 1;
            let largest = at_edge.iter().fold(0.0f64, |m, e| m.max(e.abs()));
            edge_max = Some(edge_max.map_or(largest, |m| m.max(largest)));
        }
        svf.extend(svf_error.map(f64::abs));
        wrong += w;
    }
    let bias = horizon.iter().sum::<f64>() / horizon.len().max(1) as f64;
    let mut horizon: Vec<f64> = horizon.into_iter().map(f64::abs).collect();
    horizon.sort_unstable_by(f64::total_cmp);
    svf.sort_unstable_by(f64::total_cmp);
    solar_errors.sort_unstable_by(f64::total_cmp);
    let layer = asset.layer(HORIZON, 0)?;
    Ok(HorizonCheck {
        posts: pilot.posts.len(),
        relief_posts: pilot.relief_posts,
        feature_posts: pilot.feature_posts,
        features: pilot.features.len(),
        reference_directions: pilot.reference.len(),
        method: stage.method.name().into(),
        bands: layer.bands() as usize,
        encoding: map.encoding().name().into(),
        max_distance: stage.sight.max_distance,
        horizon_p50_deg: percentile(&horizon, 50),
        horizon_p99_deg: percentile(&horizon, 99),
        horizon_max_deg: max_random.max(max_feature),
        horizon_max_at: max_at.map(|(_, at)| at),
        horizon_max_random_deg: max_random,
        horizon_max_feature_deg: max_feature,
        horizon_max_edge_may_cut: edge_may_cut,
        horizon_bias_deg: bias,
        samples: horizon.len(),
        edge_samples,
        edge_posts,
        edge_max_deg: edge_max,
        svf_p99: (!svf.is_empty()).then(|| percentile(&svf, 99)),
        svf_max,
        shade_share: (!suns.is_empty()).then(|| wrong as f64 / (suns.len() * scene_posts) as f64),
        sun_positions: suns.len(),
        solar_p99_percent: (!solar_errors.is_empty()).then(|| percentile(&solar_errors, 99)),
        solar_max_percent: solar_errors.last().copied(),
    })
}

/// DEMs of up to this many cells have every cell scanned for each checked
/// cone (the tightness); larger ones only the window where terrain could
/// enter it.
const FULL_SCAN_CELLS: usize = 4_000_000;

/// The cone planes and the tracers against brute force: `samples` random
/// cells' cones against every cell of the DEM, and `4 * samples` random
/// rays traced by every method the asset serves and by the brute force.
/// `None` when the asset has neither a pyramid nor cone planes.
fn check_tracing(
    asset: &Asset<Mmap>,
    dem: &HeldDem,
    opts: &CheckOptions,
) -> Result<Option<TracingCheck>> {
    let tracer = Tracer::new(asset)?;
    if !tracer.has_pyramid() && !tracer.has_cones() {
        return Ok(None);
    }
    let (w, h) = (dem.width, dem.height);
    let (cw, ch) = (w - 1, h - 1);
    let mut rng = SplitMix64(opts.seed ^ 0x7472_6163);
    // Each cell's tallest corner (-inf without surface), as the pyramid's
    // level 0 bounds it, from the heights rather than the baked layer.
    let mut tall = vec![0f32; cw * ch];
    let mut low = vec![0f32; cw];
    for (r, max) in tall.chunks_exact_mut(cw).enumerate() {
        let rows = &dem.z()[r * w..(r + 2) * w];
        crate::stages::pyramid::cell_bounds_row(&rows[..w], &rows[w..], max, &mut low);
    }
    let (mut cone_cells, mut cone_violations, mut tightness) = (0, 0, None);
    if let Some(planes) = ConePlanes::open(asset)? {
        let cells: Vec<usize> = (0..opts.samples.min(cw * ch))
            .map(|_| rng.below(cw * ch))
            .collect();
        // Distance between the closed squares of two cells.
        let gap = |a: usize, b: usize| (a.abs_diff(b).saturating_sub(1)) as f64;
        // Terrain can enter a cone only within `slope * (top - apex)` of
        // its cell, so that window is exact for violations; the tightness
        // needs every taller cell, so it is measured on DEMs of up to
        // FULL_SCAN_CELLS cells only.
        let top = tall.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let full = cw * ch <= FULL_SCAN_CELLS;
        let found: Vec<Result<(bool, Option<f64>)>> = cells
            .par_iter()
            .map(|&i| {
                let cone = planes.cone((i % cw) as u32, (i / cw) as u32)?;
                let (ci, ri) = (i % cw, i / cw);
                let reach = |cell: f64, n: usize| {
                    let r = (cone.slope * (f64::from(top) - cone.apex).max(0.0) / cell).ceil();
                    if full || !r.is_finite() || r >= n as f64 {
                        n
                    } else {
                        r as usize + 1
                    }
                };
                let (rx, ry) = (reach(dem.dx, cw), reach(dem.dy, ch));
                let (mut holds_terrain, mut widest) = (false, f64::INFINITY);
                for rj in ri.saturating_sub(ry)..(ri + ry + 1).min(ch) {
                    for cj in ci.saturating_sub(rx)..(ci + rx + 1).min(cw) {
                        let rise = f64::from(tall[rj * cw + cj]) - cone.apex;
                        if rise > 0.0 {
                            let d = (gap(ci, cj) * dem.dx).hypot(gap(ri, rj) * dem.dy);
                            holds_terrain |= d < cone.slope * rise;
                            widest = widest.min(d / rise);
                        }
                    }
                }
                Ok((
                    holds_terrain,
                    (full && widest.is_finite() && widest > 0.0).then(|| cone.slope / widest),
                ))
            })
            .collect();
        let mut ratios = Vec::new();
        for f in found {
            let (bad, ratio) = f?;
            cone_cells += 1;
            cone_violations += usize::from(bad);
            ratios.extend(ratio);
        }
        tightness = (!ratios.is_empty()).then(|| ratios.iter().sum::<f64>() / ratios.len() as f64);
    }
    // Rays from anywhere above the lowest post, in any direction.
    let (xm, ym) = tracer.extent();
    let m = asset.manifest();
    let (lo, hi) = m
        .height_range
        .map_or((0.0, 1.0), |r| (f64::from(r.min), f64::from(r.max)));
    let span = (hi - lo).max(1.0);
    let rays: Vec<Ray> = (0..4 * opts.samples)
        .map(|_| {
            let origin = [
                rng.unit() * xm,
                rng.unit() * ym,
                lo + rng.unit() * 1.5 * span,
            ];
            let (z, phi) = (2.0 * rng.unit() - 1.0, rng.unit() * std::f64::consts::TAU);
            let s = (1.0 - z * z).sqrt();
            Ray {
                origin,
                dir: [s * phi.cos(), s * phi.sin(), z],
                t_min: 0.0,
                t_max: f64::INFINITY,
            }
        })
        .collect();
    let mut methods = Vec::new();
    if tracer.has_pyramid() {
        methods.push(TraceMethod::Hierarchical);
    }
    if tracer.has_cones() {
        methods.push(TraceMethod::Parametric);
    }
    let fastest = *methods.last().expect("a pyramid or cone planes");
    let speed = crate::plan::tracing::speed(asset, fastest)?;
    let mut mismatches = Vec::new();
    let reference: Vec<_> = rays
        .par_iter()
        .map(|ray| {
            tracer
                .trace(ray, TraceMethod::BruteForce)
                .map(|(hit, _)| hit)
        })
        .collect::<Result<_, _>>()?;
    for method in methods {
        // The same point: both miss, or `t` agrees to 1e-5 relative, the
        // tracer tests' bar (a hit on an edge may name either cell that
        // holds it, so cells are not compared).
        let wrong = rays
            .par_iter()
            .zip(&reference)
            .map(|(ray, want)| {
                let (got, _) = tracer.trace(ray, method)?;
                Ok(usize::from(match (got, want) {
                    (None, None) => false,
                    (Some(a), Some(b)) => (a.t - b.t).abs() > 1e-5 * b.t.abs().max(1.0),
                    _ => true,
                }))
            })
            .collect::<Result<Vec<usize>>>()?
            .into_iter()
            .sum();
        mismatches.push((method.name().to_string(), wrong));
    }
    Ok(Some(TracingCheck {
        cone_cells,
        cone_violations,
        cone_tightness: tightness,
        rays: rays.len(),
        mismatches,
        method: fastest.name().into(),
        speed,
    }))
}

/// Each limit of `b` against `report`.
fn verdicts(report: &CheckReport, b: &Budget) -> Vec<Verdict> {
    let measured = |what, achieved: Option<f64>, limit: f64| Verdict {
        what,
        achieved,
        limit,
        at_least: false,
        met: achieved.map(|a| a <= limit),
    };
    let h = report.horizons.as_ref();
    let mut v = Vec::new();
    if let Some(h) = h {
        v.push(measured(
            "horizon p99 (deg)",
            Some(h.horizon_p99_deg),
            b.horizon,
        ));
    }
    // The other limits: asked for and not measured is not met.
    let required = [
        (
            "horizon max (deg)",
            b.horizon_max,
            h.map(|h| h.horizon_max_deg),
        ),
        ("svf max", b.svf_max, h.and_then(|h| h.svf_max)),
        ("svf p99", b.svf, h.and_then(|h| h.svf_p99)),
        ("shade share", b.shade, h.and_then(|h| h.shade_share)),
        (
            "solar p99 (%)",
            b.solar,
            h.and_then(|h| h.solar_p99_percent),
        ),
        (
            "total viewshed p99 (%)",
            b.total_viewshed,
            report.total_viewshed.as_ref().map(|t| t.p99_percent),
        ),
    ];
    for (what, limit, achieved) in required {
        if let Some(limit) = limit {
            let mut verdict = measured(what, achieved, limit);
            verdict.met = Some(verdict.met == Some(true));
            v.push(verdict);
        }
    }
    let speed = report.tracing.as_ref().map(|t| t.speed);
    if let Some(limit) = b.steps {
        let mut verdict = measured("steps per ray", speed.map(|s| s.mean_steps), limit);
        verdict.met = Some(verdict.met == Some(true));
        v.push(verdict);
    }
    if let Some(limit) = b.rays {
        let achieved = speed.map(|s| s.rays_per_second);
        v.push(Verdict {
            what: "rays/s per thread",
            achieved,
            limit,
            at_least: true,
            met: Some(achieved.is_some_and(|a| a >= limit)),
        });
    }
    if let Some(limit) = b.bytes {
        v.push(measured("bytes", Some(report.bytes as f64), limit as f64));
    }
    let baked = report.baked.as_ref();
    if let Some(limit) = b.time {
        v.push(measured("time (s)", baked.map(|b| b.seconds), limit));
    }
    if let Some(limit) = b.memory {
        v.push(measured(
            "memory (MiB)",
            baked.map(|b| b.peak_memory_mib),
            limit as f64,
        ));
    }
    v
}

/// Records `report` in the asset's manifest (a `check` record, dropped when
/// the heights, horizons or sky-view factors are baked again).
pub fn record(dir: &std::path::Path, report: &CheckReport) -> crate::Result<()> {
    Ok(crate::stage::record_measurement(
        dir,
        "check",
        serde_json::to_value(report)?,
        vec![
            format!("{HEIGHT}@0"),
            format!("{HORIZON}@0"),
            format!("{SVF}@0"),
        ],
    )?)
}

/// The report as a table for people.
pub(crate) fn describe(report: &CheckReport) -> String {
    let mut out = String::new();
    if let Some(h) = &report.horizons {
        out += &format!(
            "checked {} posts ({} of the highest relief, {} around the {} most prominent features) against exact line horizons in {} directions\n\
             baked: {} horizons, {} bands, {}{}\n\n",
            h.posts,
            h.relief_posts,
            h.feature_posts,
            h.features,
            h.reference_directions,
            h.method,
            h.bands,
            h.encoding,
            h.max_distance
                .map_or(String::new(), |d| format!(", max distance {d} m")),
        );
        out += &format!(
            "horizon error (deg)   p50 {:.3}   p99 {:.3}   max {:.3}   bias {:+.3}   ({} post-azimuth samples)\n",
            h.horizon_p50_deg, h.horizon_p99_deg, h.horizon_max_deg, h.horizon_bias_deg, h.samples
        );
        if let Some(((c, r), az)) = h.horizon_max_at {
            out += &format!(
                "largest error         {:.3} at post ({c}, {r}), azimuth {az:.1}; {:.3} at random and relief posts, {:.3} around features; \
                 {} samples the DEM's edge may cut left out\n",
                h.horizon_max_deg, h.horizon_max_random_deg, h.horizon_max_feature_deg, h.horizon_max_edge_may_cut
            );
        }
        if let Some(max) = h.edge_max_deg {
            out += &format!(
                "at the DEM's edge     {} samples at {} posts look out over the edge (nothing ahead on one side \
                 of the azimuth): max {max:.3}, left out of the figures above\n",
                h.edge_samples, h.edge_posts
            );
        }
        if let (Some(p99), Some(max)) = (h.svf_p99, h.svf_max) {
            out += &format!("svf error             p99 {p99:.4}   max {max:.4}\n");
        }
        if let Some(share) = h.shade_share {
            out += &format!(
                "sun/shade wrong       {share:.4} of {} posts x {} sun positions\n",
                h.posts, h.sun_positions
            );
        }
        if let (Some(p99), Some(max)) = (h.solar_p99_percent, h.solar_max_percent) {
            out += &format!(
                "solar (year's beam)   p99 {p99:.3} %   max {max:.3} % in the wrong sun or shade\n"
            );
        }
    }
    if let Some(t) = &report.tracing {
        if t.cone_cells > 0 {
            out += &format!(
                "cone planes           {} cells against every cell: {} hold terrain, {}\n",
                t.cone_cells,
                t.cone_violations,
                t.cone_tightness
                    .map_or("no taller terrain".into(), |r| format!(
                        "mean slope {:.1} % of the widest its apex allows",
                        100.0 * r
                    )),
            );
        }
        for (method, wrong) in &t.mismatches {
            out += &format!(
                "rays, {method:<13}  {} random rays against the brute force: {wrong} differ\n",
                t.rays
            );
        }
        out += &format!(
            "tracing speed         {}: {:.2} steps a ray, {:.0} rays/s on one thread over the built-in views\n",
            t.method, t.speed.mean_steps, t.speed.rays_per_second
        );
    }
    if let Some(t) = &report.total_viewshed {
        out += &format!(
            "total viewshed        {} directions: relative error p99 {:.3} %, max {:.3} % against {} directions at {} posts\n",
            t.directions,
            t.p99_percent,
            t.max_percent,
            crate::plan::total_viewshed::REFERENCE_DIRECTIONS,
            t.posts
        );
    }
    out += &format!(
        "bytes on disk         {}\nchecked in            {:.1} s\n",
        crate::plumbing::resources::human_bytes(report.bytes),
        report.seconds
    );
    if let Some(b) = &report.baked {
        out += &format!(
            "baked in              {:.1} s, peak memory {:.0} MiB",
            b.seconds, b.peak_memory_mib
        );
        // Where the bake fell against the plan's range and memory.
        if let (Some(t), Some(m)) = (report.planned_seconds, report.planned_memory_mib) {
            if t > 0.0 && m > 0.0 {
                let (low, high) = report.planned_seconds_range.unwrap_or((t, t));
                let time = if b.seconds > high {
                    format!(
                        "{:.0} % over the planned {low:.1}-{high:.1} s: a busy machine, or one the calibration misjudged (terrabake calibrate --fresh measures it again; pipelines/fit_plan_models.sh fits this machine's own models)",
                        100.0 * (b.seconds / high - 1.0)
                    )
                } else if b.seconds < low {
                    format!("under the planned {low:.1}-{high:.1} s")
                } else {
                    format!("within the planned {low:.1}-{high:.1} s")
                };
                out += &format!(
                    " ({time}; {:.0} % of the planned {m:.0} MiB)",
                    100.0 * b.peak_memory_mib / m,
                );
            }
        }
        out += "\n";
    }
    if let Some(p) = &report.predicted {
        out += &format!(
            "planned               horizon p99 {:.3} (max {:.3})   svf p99 {:.4} (max {:.4}){}   horizon and sky layers {} ({} directions, {}{})\n",
            p.horizon_p99_deg,
            p.horizon_max_deg,
            p.svf_p99,
            p.svf_max,
            p.shade_share.map_or(String::new(), |s| format!("   shade {s:.4}")),
            crate::plumbing::resources::human_bytes(p.bytes),
            p.sectors,
            p.encoding.name(),
            p.max_distance.map_or(String::new(), |d| format!(", within {:.1} km", d / 1000.0)),
        );
    }
    if let Some(b) = &report.budget {
        out += &format!("\nbudget {b}\n");
        for v in &report.verdicts {
            let achieved = v.achieved.map_or("-".into(), |a| format!("{a:.4}"));
            let verdict = match v.met {
                Some(true) => "met",
                Some(false) if v.at_least => "SHORT",
                Some(false) => "EXCEEDED",
                None => "not measured (time and memory are measured by a planned bake)",
            };
            out += &format!(
                "  {:<20} {:>12} {} {:<10} {verdict}\n",
                v.what,
                achieved,
                if v.at_least { ">=" } else { "<=" },
                v.limit
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
    /// Reference directions (exact line horizons, within 0.1 degree of i * 360 / N) [default:
    /// 720, or twice the stored bands where more, so that it measures between them]
    #[arg(long, value_parser = clap::value_parser!(u64).range(4..=8192))]
    pub directions: Option<u64>,
    /// The budget to check: horizon=DEG[,svf=X][,shade=F][,time=S][,bytes=SIZE][,memory=MIB]
    /// (docs/PLANNING.md defines each).
    #[arg(long)]
    pub budget: Option<Budget>,
    /// Sun positions for the shade share: AZ,EL;AZ,EL;... degrees (default: the recorded
    /// plan's).
    #[arg(long, allow_hyphen_values = true)]
    pub sun: Option<crate::plan::budget::SunPositions>,
    /// Measure only: leave the manifest as it is (by default the result is recorded in it).
    #[arg(long)]
    pub no_record: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

impl Run for CheckArgs {
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let progress = s.progress;
        let asset = crate::stage::asset::open(&self.asset)?;
        let opts = CheckOptions {
            samples: self.samples as usize,
            seed: self.seed,
            directions: self.directions.map_or_else(
                || reference_directions(asset.layer(HORIZON, 0).map_or(0, |l| l.bands() as usize)),
                |d| d as usize,
            ),
            cuts: &[],
        };
        let sun = self.sun.clone().map(|s| s.0).unwrap_or_default();
        let report = check(&asset, &opts, self.budget.as_ref(), &sun, progress)?;
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
            ExitCode::SUCCESS
        } else {
            ExitCode::from(EXIT_OVER_BUDGET)
        })
    }
}
