//! Predictions at the pilot's posts (docs/PLANNING.md, "How the planner
//! decides"): what a bake would get wrong, its stored angles served at
//! every reference azimuth as the loader serves them (linear between the
//! two nearest bands) against the exact references, for the horizon, the
//! svf, the sun/shade states and the year's beam; and the methods other
//! than line, measured as their stages bake them, with their predicted
//! time and memory ("The method"). Every candidate the planner weighs,
//! of every method, is judged here.

use terrabake_format::features::serve;
use terrabake_format::horizons::{bands_around, AngleEncoding, NOTHING_AHEAD};

use super::models::LineCosts;
use super::{
    Candidate, DECISION_QUANTILE, DISTANCES, OTHERS_MEASURED_UP_TO_VISITS, OTHER_COUNTS,
    SHARE_DIRECTIONS, SHARE_QUANTISATION,
};
use crate::algorithms::horizon::sky::{svf_of_horizons, BandIntegrals};
use crate::algorithms::horizon::Method;
use crate::plan::budget::{Budget, Relax};
use crate::plan::reference::{quantile_unsorted, shade_differs, solar_error, Pilot, PilotSun};
use crate::terrain::Terrain;

/// The suns the pilot weighs: the shade's positions (each weighing 1),
/// and the solar budget's year.
pub(super) struct PilotSuns {
    pub(super) shade: Vec<PilotSun>,
    pub(super) solar: Vec<PilotSun>,
}

/// The errors a bake would make at the pilot's posts: the horizon's
/// (degrees) at every post and reference azimuth, the svf's at every post,
/// and the sun/shade states it gets wrong.
pub(super) struct Errors {
    pub(super) horizon: Vec<f64>,
    /// The largest horizon error away from the DEM's edge (neither the
    /// reference nor a serving direction facing out over it).
    pub(super) horizon_max: f64,
    pub(super) svf: Vec<f64>,
    pub(super) svf_max: f64,
    pub(super) shade_wrong: usize,
    pub(super) shade_pairs: usize,
    /// Per post, per cent ([`solar_error`]); empty without solar.
    pub(super) solar: Vec<f64>,
}

impl Errors {
    /// The horizon's and the svf's errors at quantile `q`, and the share of
    /// wrong sun/shade states (`None` without sun positions).
    pub(super) fn at(&mut self, q: f64) -> (f64, f64, Option<f64>) {
        (
            quantile_unsorted(&mut self.horizon, q),
            quantile_unsorted(&mut self.svf, q),
            (self.shade_pairs > 0).then(|| self.shade_wrong as f64 / self.shade_pairs as f64),
        )
    }

    /// The solar error (per cent) at quantile `q`; `None` without solar.
    pub(super) fn solar_at(&mut self, q: f64) -> Option<f64> {
        (!self.solar.is_empty()).then(|| quantile_unsorted(&mut self.solar, q))
    }

    /// Whether these errors, at the deciding quantile and at their largest,
    /// stay within `share` of every limit the budget sets for them. The
    /// shares add up to the whole budget for the largest error too: the
    /// largest of a sum is at most the sum of the largest.
    pub(super) fn within(&mut self, budget: &Budget, share: f64) -> bool {
        self.over(budget, share).is_empty()
    }

    /// The limits of `budget` these errors pass at `share` of each, with
    /// the least limit each would meet (rounded up at its decimals): what a
    /// refusal names to relax, and nothing the errors already meet.
    pub(super) fn over(&mut self, budget: &Budget, share: f64) -> Vec<Relax> {
        let (horizon, svf, shade) = self.at(DECISION_QUANTILE);
        let solar = self.solar_at(DECISION_QUANTILE);
        [
            ("horizon", Some(budget.horizon), Some(horizon), 3),
            ("horizon_max", budget.horizon_max, Some(self.horizon_max), 3),
            ("svf", budget.svf, Some(svf), 4),
            ("svf_max", budget.svf_max, Some(self.svf_max), 4),
            ("shade", budget.shade, shade, 4),
            ("solar", budget.solar, solar, 2),
        ]
        .into_iter()
        .filter_map(|(limit, set, error, decimals)| match (set, error) {
            (Some(set), Some(error)) if error > share * set => Some(Relax {
                limit,
                at_least: super::round_up(error / share, decimals),
            }),
            _ => None,
        })
        .collect()
    }
}

/// Whether a candidate's bands are served with the pilot's listed features
/// (`Pilot::list_features`), as the loader serves a line bake that lists
/// them: cut at the bands' distance limit (metres), with the encoding's
/// tolerance. Other methods list none.
#[derive(Debug, Clone, Copy)]
pub(super) enum Listed {
    No,
    Line(Option<f64>, AngleEncoding),
}

/// The errors at the pilot's posts of storing, in the measured directions
/// `stored` (ascending azimuths), `stored(post, direction)` degrees,
/// served at every reference azimuth as the loader serves it (linear
/// between the two nearest stored directions, and the `listed` features
/// where they are higher).
pub(super) fn errors(
    pilot: &Pilot,
    stored: &[usize],
    suns: &PilotSuns,
    listed: Listed,
    value: impl Fn(usize, usize) -> f64,
) -> Errors {
    let azimuths: Vec<f64> = stored.iter().map(|&j| pilot.azimuth(j)).collect();
    errors_at(pilot, (&azimuths, Some(stored)), suns, listed, |post, k| {
        value(post, stored[k])
    })
}

/// [`errors`] of bands at `azimuths` (ascending) that need not be measured
/// directions (another method's; else `measured`, their indices):
/// `value(post, k)` is band `k`'s angle.
pub(super) fn errors_at(
    pilot: &Pilot,
    (azimuths, measured): (&[f64], Option<&[usize]>),
    suns: &PilotSuns,
    listed: Listed,
    value: impl Fn(usize, usize) -> f64,
) -> Errors {
    let integrals = BandIntegrals::of_azimuths(azimuths);
    let mut e = Errors {
        horizon: Vec::new(),
        horizon_max: 0.0,
        svf: Vec::new(),
        svf_max: 0.0,
        shade_wrong: 0,
        shade_pairs: 0,
        solar: Vec::new(),
    };
    let (cut, tolerance) = match listed {
        Listed::Line(cut, encoding) if pilot.listed.is_some() => {
            (Some(cut), encoding.feature_tolerance())
        }
        _ => (None, 0.0),
    };
    let mut served = vec![0.0; pilot.reference.len()];
    // The posts around features count for the largest errors only: they
    // are chosen where errors are large, and would bias the percentiles,
    // which are over the scene's posts.
    for (post, exact) in pilot.exact.iter().enumerate() {
        let sampled = post < pilot.scene_posts();
        let kept: Vec<f64> = (0..azimuths.len()).map(|k| value(post, k)).collect();
        let feature = |azimuth: f64| cut.and_then(|d| pilot.feature_horizon(post, azimuth, d));
        // Reference directions' crossings are kept; the others' walked.
        let at_band: Vec<Option<f64>> = (0..azimuths.len())
            .map(|k| match measured.map(|m| m[k]) {
                Some(j) if j < pilot.reference.len() => {
                    cut.and_then(|d| pilot.feature_horizon_in_reference(post, j, d))
                }
                _ => feature(azimuths[k]),
            })
            .collect();
        for (r, ((band, &truth), out)) in pilot
            .reference
            .iter()
            .zip(exact)
            .zip(&mut served)
            .enumerate()
        {
            let here = cut.and_then(|d| pilot.feature_horizon_in_reference(post, r, d));
            let s = serve::<std::convert::Infallible>(
                azimuths,
                band.azimuth,
                |k| Ok(Some(kept[k])),
                (|k| at_band[k], here),
                tolerance,
            )
            .unwrap_or_else(|never| match never {})
            .expect("every band has an angle");
            *out = s.angle;
            // Where nothing lies ahead, of the reference or of a serving
            // band, the DEM's edge cuts the horizon: `check` leaves those
            // out (its "at the DEM's edge"), and so does the prediction.
            // The largest error leaves out, as well, the samples whose
            // error the edge may have made (`Pilot::edge_may_cut`).
            if out.is_finite() && truth.is_finite() && truth != NOTHING_AHEAD && !s.at_edge {
                let error = (*out - truth).abs();
                if sampled {
                    e.horizon.push(error);
                }
                let (i, j, _) = bands_around(azimuths, band.azimuth);
                let bands = [(azimuths[i], kept[i]), (azimuths[j], kept[j])];
                if error > e.horizon_max && !pilot.edge_may_cut((post, r), truth, bands) {
                    e.horizon_max = error;
                }
            }
        }
        let s = svf_of_horizons(&integrals, kept.iter().copied());
        let truth = pilot.svf(exact);
        if s.is_finite() && truth.is_finite() {
            e.svf_max = e.svf_max.max((s - truth).abs());
            if sampled {
                e.svf.push((s - truth).abs());
            }
        }
        if !sampled {
            continue;
        }
        e.shade_pairs += suns.shade.len();
        e.shade_wrong += suns
            .shade
            .iter()
            .filter(|sun| shade_differs(sun.elevation, served[sun.direction], exact[sun.direction]))
            .count();
        if !suns.solar.is_empty() {
            e.solar.push(solar_error(&suns.solar, &served, exact));
        }
    }
    e
}

/// The encoding: the coarsest whose worst error is within its share of
/// the budget, in degrees and (for the svf, which a change of h radians in
/// every direction moves by at most h) in radians, and whose rounding alone
/// flips few enough sun/shade states.
pub(super) fn choose_encoding(pilot: &Pilot, suns: &PilotSuns, budget: &Budget) -> AngleEncoding {
    let share = SHARE_QUANTISATION;
    let every_reference: Vec<usize> = (0..pilot.reference.len()).collect();
    [AngleEncoding::U8, AngleEncoding::U16, AngleEncoding::F32]
        .into_iter()
        .find(|&e| {
            let svf_limit = budget
                .svf
                .into_iter()
                .chain(budget.svf_max)
                .reduce(f64::min);
            e.max_error_deg() <= share * budget.horizon
                && svf_limit.is_none_or(|s| e.max_error_deg().to_radians() <= share * s)
                && ((budget.shade.is_none() && budget.solar.is_none())
                    || errors(
                        pilot,
                        &every_reference,
                        suns,
                        Listed::Line(None, e),
                        |i, j| stored_as(e, pilot.exact[i][j]),
                    )
                    .within(budget, share))
        })
        .unwrap_or(AngleEncoding::F32)
}

/// `deg` stored as `encoding` and read back.
pub(super) fn stored_as(encoding: AngleEncoding, deg: f64) -> f64 {
    encoding.decode(encoding.encode(deg)).unwrap_or(f64::NAN)
}

/// The errors of the measured directions `stored` cut at
/// `DISTANCES[distance]`, stored as `encoding`, served with the pilot's
/// listed features where `features` (the line bake that lists them) or
/// without (the bands alone).
pub(super) fn predict(
    pilot: &Pilot,
    suns: &PilotSuns,
    stored: &[usize],
    (distance, encoding): (Option<usize>, AngleEncoding),
    features: bool,
) -> Errors {
    let listed = match features {
        true => Listed::Line(distance.map(|k| DISTANCES[k]), encoding),
        false => Listed::No,
    };
    errors(pilot, stored, suns, listed, |i, j| {
        let angle = distance.map_or(pilot.exact[i][j], |k| pilot.bounded(i, j, k));
        stored_as(encoding, angle)
    })
}

/// Seconds of the horizons (and the sky) of `sectors` bands by `method`
/// over the whole DEM; for line, to the edge.
pub(super) fn seconds(costs: &LineCosts, method: Method, sectors: usize) -> f64 {
    match method {
        Method::Line => costs.seconds(sectors, None),
        Method::Sector => costs.sector_seconds(sectors),
        Method::Sampled => costs.sampled_seconds(sectors),
    }
}

/// Peak memory of baking `c`, MiB: line's by its route (the DEM held
/// where its reach is bounded), the others' over the whole DEM.
pub(super) fn memory_mib(costs: &LineCosts, c: &Candidate) -> f64 {
    match c.method {
        Method::Line => costs.memory_mib(&c.stage()),
        Method::Sector => costs.sector_memory_mib(),
        Method::Sampled => costs.sampled_memory_mib(c.sectors),
    }
}

/// The most posts `method` visits at `pilot_posts` posts in `count` bands:
/// the whole DEM for the sector's scans, a walk to the far edge for each
/// sampled direction.
pub(super) fn pilot_visits(
    costs: &LineCosts,
    pilot_posts: usize,
    (method, count): (Method, usize),
) -> f64 {
    let per_post = match method {
        Method::Line | Method::Sector => costs.posts,
        Method::Sampled => count as f64 * (costs.width + costs.height) as f64,
    };
    pilot_posts as f64 * per_post
}

/// `method`'s (sector or sampled) candidate beside `line`'s: the fewest
/// of [`OTHER_COUNTS`] predicted faster than the line whose error (f32,
/// from the whole DEM) meets the budget within the directions' share, as
/// the line's count is chosen; where none does, the method at the line's
/// own count (the same bytes; at most the ladder's last), to say what it
/// would give, where that visits at most [`OTHERS_MEASURED_UP_TO_VISITS`]
/// posts (`None` beyond). Counts slower than the line are not measured: they cannot
/// be chosen, and each costs the pilot a scan of its posts' reach.
pub(super) fn other_method(
    pilot: &Pilot,
    terrain: &Terrain,
    suns: &PilotSuns,
    budget: &Budget,
    costs: &LineCosts,
    (method, line): (Method, &Candidate),
) -> Option<Candidate> {
    let faster = OTHER_COUNTS
        .into_iter()
        .take_while(|&count| seconds(costs, method, count) < line.seconds);
    let judged = |count: usize| {
        let (c, mut e) = measure_other(
            pilot,
            terrain,
            suns,
            (costs, method, count),
            AngleEncoding::F32,
        );
        Candidate {
            meets: e.within(budget, SHARE_DIRECTIONS),
            ..c
        }
    };
    for count in faster {
        let c = judged(count);
        if c.meets {
            return Some(c);
        }
    }
    let count = other_count(line);
    (pilot_visits(costs, pilot.posts.len(), (method, count)) <= OTHERS_MEASURED_UP_TO_VISITS)
        .then(|| judged(count))
}

/// The count another method is measured at, or predicted at, to say what
/// it would give beside `line`: the line's, at most the ladder's last.
pub(super) fn other_count(line: &Candidate) -> usize {
    line.sectors.min(OTHER_COUNTS[OTHER_COUNTS.len() - 1])
}

/// `count` bands of `method` at the pilot's posts, stored as `encoding`:
/// the candidate and its errors.
pub(super) fn measure_other(
    pilot: &Pilot,
    terrain: &Terrain,
    suns: &PilotSuns,
    (costs, method, count): (&LineCosts, Method, usize),
    encoding: AngleEncoding,
) -> (Candidate, Errors) {
    let values = pilot.measure_method(terrain, method, count);
    let azimuths: Vec<f64> = (0..count)
        .map(|i| i as f64 * 360.0 / count as f64)
        .collect();
    let mut e = errors_at(pilot, (&azimuths, None), suns, Listed::No, |post, k| {
        stored_as(encoding, values[post][k])
    });
    let candidate = Candidate::predicted((method, count, encoding), &mut e, costs);
    (candidate, e)
}
