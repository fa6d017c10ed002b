//! Why the plan chose what it chose: each decision's [`Choice`], with the
//! reasons for it and against what it rejected, and the refusal when no
//! count of directions meets the budget.

use terrabake_format::horizons::AngleEncoding;

use super::budget::{Budget, Relax};
use super::models::{LineCosts, CONES_SECONDS_PER_POST, CONE_SLICES};
use super::{
    Candidate, Choice, HorizonsStage, Scene, DECISION_QUANTILE, DISTANCES,
    OTHERS_MEASURED_UP_TO_VISITS, SHARE_DIRECTIONS, SHARE_DISTANCE, SHARE_QUANTISATION,
};
use crate::algorithms::horizon::line::default_tolerance;
use crate::algorithms::horizon::Method;

/// Why the plan traces with the pyramid alone, or with the cone planes too.
pub(super) fn tracing_choice(cones: bool, cones_bytes: u64, posts: u64) -> Choice {
    Choice {
        what: "tracing".into(),
        chosen: if cones {
            "pyramid and cone planes".into()
        } else {
            "max/min pyramid".into()
        },
        why: if cones {
            "fast tracing: parametric steps through the cone planes, the pyramid's exact hits in fewer steps".into()
        } else {
            "exact hierarchical tracing needs only the pyramid".into()
        },
        rejected: Some(if cones {
            "the pyramid alone: the same hits, more steps per ray (docs/TRACING.md)".into()
        } else {
            format!(
                "cone planes as well: faster rays for {:.1} MiB more and {:.1} s (ask for fast_tracing)",
                cones_bytes as f64 / 1048576.0,
                posts as f64 * CONES_SECONDS_PER_POST
            )
        }),
    }
}

/// Why the cone planes have the slices and encoding they have; `f32_more`
/// is what f32 planes would add, bytes.
pub(super) fn cones_choice(f32_more: u64) -> Choice {
    Choice {
        what: "cone planes".into(),
        chosen: format!("{CONE_SLICES} slices, u16"),
        why: format!(
            "{CONE_SLICES} slices step within 6 % of the exact cones on the bundled tile; u16 planes (conservative) step and trace as f32 do, in half the bytes (docs/BENCHMARKS.md, cone planes)"
        ),
        rejected: Some(format!(
            "256 slices: within 1.3 % of exact, 2.7x the bake; f32 planes: {:.1} MiB more for the same steps",
            f32_more as f64 / 1048576.0
        )),
    }
}

/// Why the tiles are the ingest's, or smaller (`costs.tile`) for the line
/// sweeps' tile rows to fit the memory limit.
pub(super) fn tiles_choice(
    costs: &LineCosts,
    chosen: Option<&Candidate>,
    ingested_tile: usize,
) -> Choice {
    let tile = costs.tile;
    let line_row = |t: usize| {
        let at = LineCosts { tile: t, ..*costs };
        chosen.map_or(0.0, |c| at.memory_mib(&c.stage()))
    };
    if tile == ingested_tile {
        Choice {
            what: "tiles".into(),
            chosen: format!("{tile} posts"),
            why: "the ingest's: the line sweeps' tile rows fit the memory".into(),
            rejected: None,
        }
    } else {
        Choice {
            what: "tiles".into(),
            chosen: format!("{tile} posts (ingest again)"),
            why: format!(
                "the line sweeps hold a tile row of every direction: {:.0} MiB at {tile} posts fits the memory limit",
                line_row(tile)
            ),
            rejected: Some(format!(
                "{ingested_tile} posts (the ingest's): {:.0} MiB, over the limit",
                line_row(ingested_tile)
            )),
        }
    }
}

/// Why the horizons are `chosen`'s method: of the line's candidate
/// (`line`) and the other methods' (`measured`: each one's fewest count
/// predicted faster than the line that meets the budget, or its candidate
/// at the line's count; `unmeasured`: method, count and predicted seconds
/// of those too slow to measure on this DEM), the fastest to meet the
/// budget. The rejected name the runner-up first.
pub(super) fn method_choice(
    chosen: &Candidate,
    line: &Candidate,
    (measured, unmeasured): (&[Candidate], &[(Method, usize, f64)]),
) -> Choice {
    let what = |method: Method, sectors: usize| match method {
        Method::Line => format!("{sectors} line directions"),
        Method::Sector => format!("{sectors} sectors"),
        Method::Sampled => format!("{sectors} sampled directions"),
    };
    let ratio = |seconds: f64| seconds / chosen.seconds.max(1e-9);
    let same_bytes = |sectors: usize| {
        if sectors == line.sectors {
            " (the same bytes)"
        } else {
            ""
        }
    };
    let mut rejected: Vec<&Candidate> = std::iter::once(line)
        .chain(measured)
        .filter(|c| c.method != chosen.method)
        .collect();
    rejected.sort_by(|a, b| b.meets.cmp(&a.meets).then(a.seconds.total_cmp(&b.seconds)));
    let rejected = rejected
        .into_iter()
        .map(|c| {
            if c.meets {
                format!(
                    "{}: {} meet the budget in {:.1} s predicted ({:.1}x), {}",
                    c.method.name(),
                    what(c.method, c.sectors),
                    c.seconds,
                    ratio(c.seconds),
                    c.errors_text()
                )
            } else {
                format!(
                    "{}: no count predicted faster meets the budget; {}{} leave {} in {:.1} s predicted ({:.1}x)",
                    c.method.name(),
                    what(c.method, c.sectors),
                    same_bytes(c.sectors),
                    c.errors_text(),
                    c.seconds,
                    ratio(c.seconds),
                )
            }
        })
        .chain(unmeasured.iter().map(|&(method, sectors, seconds)| {
            format!(
                "{}: no count predicted faster; {}{} would take {seconds:.1} s predicted ({:.1}x), not measured (its scans at the pilot's posts would visit over {OTHERS_MEASURED_UP_TO_VISITS:.0e} posts)",
                method.name(),
                what(method, sectors),
                same_bytes(sectors),
                ratio(seconds),
            )
        }))
        .collect::<Vec<_>>();
    Choice {
        what: "method".into(),
        chosen: match chosen.method {
            Method::Line => "line (exact sight lines)".into(),
            Method::Sector => "sector (Stewart's wedges)".into(),
            Method::Sampled => "sampled (centre-line samples)".into(),
        },
        why: format!(
            "the fastest of the three methods to meet the budget, each measured at the pilot's posts against the exact references: {} in {:.1} s predicted",
            what(chosen.method, chosen.sectors),
            chosen.seconds
        ),
        rejected: (!rejected.is_empty()).then(|| rejected.join("; ")),
    }
}

/// Why the directions' tolerance is what it is: `tolerance` (degrees, and
/// the crossings a post its grid steps cost) against `at_default`
/// crossings at the default, and the first wider one over the budget.
pub(super) fn tolerance_choice(
    sectors: usize,
    tolerance: (f64, usize),
    at_default: usize,
    too_wide: Option<(f64, usize, f64, f64)>,
) -> Choice {
    Choice {
        what: "tolerance".into(),
        chosen: format!("{:.2} deg", tolerance.0),
        why: if tolerance.1 < at_default {
            format!(
                "the widest up to a third of the spacing whose error between directions stays within {SHARE_DIRECTIONS} of the budget: its grid steps cost {} crossings a post, against {at_default} within {:.2} deg (the default)",
                tolerance.1,
                default_tolerance(sectors),
            )
        } else {
            format!(
                "the stage's default, an eighth of the spacing: {at_default} crossings a post, and no wider tolerance up to a third both costs fewer and stays within {SHARE_DIRECTIONS} of the budget"
            )
        },
        rejected: too_wide.map(|(tol, cost, horizon, svf)| {
            format!(
                "{tol:.2} deg: {cost} crossings a post, but its error between directions at p99.5, the quantile that decides (horizon {horizon:.3} deg, svf {svf:.4}), is over the share"
            )
        }),
    }
}

/// Why the angles are stored as `encoding`, and the coarser ones over the
/// budget.
pub(super) fn encoding_choice(encoding: AngleEncoding) -> Choice {
    let finer = [AngleEncoding::U8, AngleEncoding::U16]
        .into_iter()
        .filter(|e| e.max_error_deg() > encoding.max_error_deg())
        .map(|e| {
            format!(
                "{} (worst error {:.3} deg: over its share of the budget)",
                e.name(),
                e.max_error_deg()
            )
        })
        .collect::<Vec<_>>();
    Choice {
        what: "encoding".into(),
        chosen: encoding.name().into(),
        why: format!(
            "the coarsest whose worst error ({:.4} deg) is within {SHARE_QUANTISATION} of the budget",
            encoding.max_error_deg()
        ),
        rejected: (!finer.is_empty()).then(|| finer.join("; ")),
    }
}

/// Why the horizons look no farther than `safe_distance` (or to the edge).
pub(super) fn distance_choice(scene: &Scene, curvature: f64, safe_distance: Option<f64>) -> Choice {
    // Relief and curvature bound what lies beyond D: no post sees terrain
    // there above atan(relief / D - c D); past sqrt(relief / c) it lies
    // below every post's horizontal plane.
    let relief = scene.relief_m;
    let bound = |d: f64| (relief / d - curvature * d).atan().to_degrees();
    let below_horizontal = (curvature > 0.0).then(|| (relief / curvature).sqrt());
    let distance_why = match safe_distance {
        Some(d) => format!(
            "beyond {:.1} km the terrain moves the pilot's horizons by at most {} of the budget (p99.5); relief and curvature allow at most {:.2} deg there{}",
            d / 1000.0,
            SHARE_DISTANCE,
            bound(d),
            below_horizontal.map_or(String::new(), |b| format!(
                ", and nothing past {:.0} km rises above a post's horizontal",
                b / 1000.0
            )),
        ),
        None => "every distance within the DEM moves some horizon by more than its share of the budget".into(),
    };
    Choice {
        what: "distance".into(),
        chosen: safe_distance.map_or("the whole DEM".into(), |d| format!("{:.1} km", d / 1000.0)),
        why: distance_why,
        rejected: safe_distance
            .and_then(|d| DISTANCES.into_iter().rev().find(|&x| x < d))
            .map(|d| format!("{:.2} km: the terrain beyond moves the horizons by more than {SHARE_DISTANCE} of the budget", d / 1000.0)),
    }
}

/// Why the sweeps run bounded in core, or to the edge out of core.
pub(super) fn route_choice(
    costs: &LineCosts,
    line: &HorizonsStage,
    safe_distance: Option<f64>,
    bounded: Option<f64>,
) -> Choice {
    let sectors = line.sectors;
    let memory_mib = |distance: Option<f64>| {
        let mut at = line.clone();
        at.sight.max_distance = distance;
        costs.memory_mib(&at)
    };
    let route_rejected = match (safe_distance, bounded) {
        (Some(d), None) => Some(format!(
            "bounded to {:.1} km: {:.1} s and {:.0} MiB (the DEM held) against {:.1} s and {:.0} MiB to the edge",
            d / 1000.0,
            costs.seconds(sectors, Some(d)),
            memory_mib(Some(d)),
            costs.seconds(sectors, None),
            memory_mib(None),
        )),
        (_, Some(d)) => Some(format!(
            "sweeps to the edge: {:.1} s against {:.1} s bounded to {:.1} km",
            costs.seconds(sectors, None),
            costs.seconds(sectors, Some(d)),
            d / 1000.0
        )),
        (None, None) => None,
    };
    Choice {
        what: "route".into(),
        chosen: match bounded {
            Some(d) => format!("bounded lines, {:.1} km, in core", d / 1000.0),
            None => "line sweeps to the edge, out of core".into(),
        },
        why: match bounded {
            Some(_) => {
                "faster than the sweeps: each post walks only its reach (the DEM held in memory)"
                    .into()
            }
            None => "the sweeps stream tile rows: memory grows with the width, not the DEM".into(),
        },
        rejected: route_rejected,
    }
}

/// Why no count of directions meets the budget: what the most directions
/// (`closest`) leave between them, and the limits they pass (`over`, at
/// the directions' share of each), each with the least value that would
/// do.
pub(super) fn unmet(budget: &Budget, closest: &Candidate, over: &[Relax]) -> anyhow::Error {
    let largest = match (budget.horizon_max, budget.svf_max) {
        (None, None) => String::new(),
        _ => format!(
            " (the largest: {:.3} degrees, {:.4} svf)",
            closest.horizon_max_deg, closest.svf_max
        ),
    };
    let relax: Vec<String> = over.iter().map(Relax::to_string).collect();
    anyhow::anyhow!(
        "budget {budget} cannot be met with up to {} line directions on this scene: {} directions leave a horizon p99 of {:.3} degrees and an svf p99 of {:.4} between them{largest}{}; relax {} (what the errors at the {}th percentile or at their largest need, {SHARE_DIRECTIONS} of each limit going to the directions)",
        closest.sectors,
        closest.sectors,
        closest.horizon_p99_deg,
        closest.svf_p99,
        closest
            .shade_share
            .map_or(String::new(), |s| format!(", and {:.4} of the sun/shade states wrong", s)),
        relax.join(" and "),
        DECISION_QUANTILE * 100.0,
    )
}

/// Why the line's angles list the spikes they list (`horizon_max` plans
/// only): `(found, with)` how many the scene has and the largest error at
/// the pilot's posts with them served, `without` with the bands alone.
pub(super) fn features_choice(
    chosen: &Candidate,
    (found, with): (usize, f64),
    (without, without_meets): (f64, bool),
) -> Choice {
    let spikes = |n: usize| match n {
        1 => "1 spike".to_string(),
        n => format!("{n} spikes"),
    };
    let rise = chosen.feature_rise_m;
    match (found, chosen.features) {
        (0, _) => Choice {
            what: "features".into(),
            chosen: "none".into(),
            why: "no post rises far enough above its eight neighbours to move a neighbour's horizon by the directions' share of horizon_max (or the grid is latitude/longitude)".into(),
            rejected: None,
        },
        (found, 0) => Choice {
            what: "features".into(),
            chosen: "none".into(),
            why: format!(
                "the bands alone leave a largest error of {without:.3} deg at the pilot's posts, no more than with the scene's {} listed ({with:.3}): behind a band a spike sets, the terrain is estimated from the bands beyond",
                spikes(found)
            ),
            rejected: Some(format!("{} listed: largest error {with:.3} deg", spikes(found))),
        },
        (_, n) => Choice {
            what: "features".into(),
            chosen: spikes(n),
            why: format!(
                "the posts rising at least {rise:.2} m above their eight neighbours (the least that can move a neighbour's horizon by {SHARE_DIRECTIONS} of horizon_max), the highest first: the loader serves their exact horizon between the {} directions (largest error {with:.3} deg at the pilot's posts)",
                chosen.sectors
            ),
            rejected: Some(format!(
                "the bands alone: largest error {without:.3} deg{}",
                if without_meets {
                    ""
                } else {
                    ", and they miss the budget"
                }
            )),
        },
    }
}
