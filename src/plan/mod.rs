//! The planner (`terrabake plan`, `terrabake bake --budget`, a recipe's
//! `[plan]`): from what a scene needs and the user's error budget to the
//! stages and layers to bake, with the predicted error, time, bytes and
//! memory of each choice and the cheaper choice it rejected
//! (docs/PLANNING.md).
//!
//! **Error model: the scene measures itself.** A pilot ([`Pilot`]) computes
//! exact line horizons in 720 directions (2880 under a `horizon_max`
//! budget) at a few hundred posts (random,
//! and those of the highest relief), with a seed apart from `check`'s, and
//! keeps each sight line's horizon cut at every candidate distance too
//! (from the line's records: where its running maximum rose). For `S` line
//! directions (up to 360, a divisor of 720; under `horizon_max` up to
//! 1440, at most half the reference's, so that it measures between every
//! two bands), a distance limit and an encoding, the
//! pilot measures the very directions the stage would store (its grid
//! steps at the default tolerance, an eighth of the spacing: seldom
//! reference directions), the planner makes the stored angles the stage
//! would, serves every reference azimuth from them as the loader does
//! (linear between the two nearest), and measures the error: the
//! prediction is the error of that very bake at those posts. The svf and
//! the sun/shade state at the sun positions are predicted the same way.
//! (The bake does not store reference directions: within 0.1 degree of
//! nominal they are grid steps of 20 to 120 crossings, and the stage takes
//! 2.9x to 10x the time at 72 to 16 directions for the same error.)
//!
//! **Choice.** Each decision takes a fixed share of the budget, measured
//! on its own: the directions (interpolation alone, 0.6), the distance
//! limit (the cut alone, 0.05), the encoding (quantisation alone, 0.25);
//! the rest (0.1) covers the posts the pilot did not see. Each decision is
//! monotone in the budget, so a looser budget never gives more directions,
//! a longer reach or a finer encoding: never more bytes or time. The
//! directions' tolerance comes after their count, in the same share: the
//! count is decided at the default tolerance (bytes first), then a fifth,
//! a quarter and a third of the spacing are measured in turn, each taken
//! while its grid steps cost fewer crossings a post and its error still
//! fits (a looser budget never narrows it). The time model is the default
//! tolerance's, an upper bound for a wider one.
//!
//! **Cost models**, fitted by `pipelines/fit_plan_models.sh` on the bundled
//! tile (2 cores), each raised until no fit run took longer: a fixed
//! 0.019 s a bake; unbounded line sweeps `posts * S^1.74 / 3.11e8` s;
//! bounded lines (a walk of each post's reach) `posts * S * (3.20e-8 +
//! 6.49e-9 * D / cell)` s, upper bounds on the machine of the fit only,
//! so scaled to the machine at hand by a timed workload
//! ([`calibration`]; `TERRABAKE_TIME_MODELS` names another machine's fit,
//! [`TimeModels`]), and given as a range ([`SECONDS_RANGE`]); bytes from
//! the layers' tiles; memory from what the horizons stage states it holds
//! (`HorizonsStage::memory_bytes`) and the sky stage's tile row of every
//! band. The bake takes the faster of the two line routes that fits the
//! memory limit.
//!
//! **The method.** Line, sector or sampled: the one that meets the budget
//! in the least predicted time. The pilot measures the other two at its
//! posts as their stages bake them (sector from the whole DEM by a scan of
//! each post's reach, grown until the DEM's highest post could not rise
//! above the horizon found), served and judged as the line's candidates
//! are, at those of [`OTHER_COUNTS`] predicted faster than the line, else
//! once at the line's count to say what they would give. Their time
//! models are the measured rates of [`models`]; line has won on every
//! scene tried.
//!
//! **Limits beyond the errors.** A memory limit can shrink the tiles (the
//! line sweeps hold a tile row of every direction), a bytes limit can make
//! the heights zstd (a sample of tile rows encoded as ingest would); both
//! mean a second ingest, which `recipe::bake` runs. Fast tracing gets
//! 64-slice u16 cone planes, chosen from the bundled tile's measurements,
//! unless a tracing budget (`steps`, `rays`) is given: then [`tracing`]
//! bakes the candidates on the scene and takes the cheapest that meets it.

pub mod budget;
pub mod calibration;
pub mod check;
mod choices;
mod codec;
mod command;
mod models;
mod predict;
pub mod reference;
mod scene;
pub mod total_viewshed;
pub mod tracing;

use choices::{
    cones_choice, distance_choice, encoding_choice, features_choice, method_choice, route_choice,
    tiles_choice, tolerance_choice, tracing_choice, unmet,
};
pub use command::{CalibrateArgs, PlanArgs, RequestArgs};
use models::{
    LineCosts, CONES_BYTES_PER_POST, CONES_SECONDS_PER_POST, CONE_SLICES, PYRAMID_SECONDS_PER_POST,
    SOLAR_SECONDS_PER_POST_DAY,
};
pub use models::{TimeModels, TIME_MODELS_VAR};
use predict::{
    choose_encoding, errors, measure_other, other_count, other_method, predict, Errors, Listed,
    PilotSuns,
};
pub use scene::Scene;
use scene::{describe_scene, sun_positions};

use std::time::Instant;

use anyhow::Result;
use serde::{Deserialize, Serialize};
use terrabake_format::cones::ConeEncoding;
use terrabake_format::horizons::AngleEncoding;
use terrabake_format::{Asset, Codec, Mmap};

use crate::algorithms::horizon::line::{default_tolerance, Stencil};
use crate::algorithms::horizon::{Band, BandKind, Method};
use crate::error::bail;
use crate::plan::budget::{Budget, Need, Needs, Request};
use crate::plan::reference::{solar_year, Pilot, Sampling};
use crate::plumbing::progress::Progress;
use crate::stage::Stage;
use crate::stages::horizons::HorizonsStage;
use crate::stages::sky::{SkyLayer, SkyStage};
use crate::stages::viewshed::stage::TotalViewshedStage;
use crate::terrain::sun::SunPosition;
use crate::terrain::Terrain;

/// Reference directions of the pilot; candidates divide it.
const PILOT_DIRECTIONS: usize = 720;
/// Reference directions of the pilot under a `horizon_max` budget: a wall
/// of a lidar DSM turns the horizon of the posts near it by tens of
/// degrees within one degree of azimuth, which takes 1440 bands to follow
/// within a few degrees (docs/PLANNING.md), and the reference must lie
/// between those bands to see what they miss.
const PILOT_DIRECTIONS_LARGEST: usize = 2880;

/// The pilot's reference directions for `budget`.
fn pilot_directions(budget: &Budget) -> usize {
    if budget.horizon_max.is_some() {
        PILOT_DIRECTIONS_LARGEST
    } else {
        PILOT_DIRECTIONS
    }
}
/// Counts at which the planner measures the methods other than line
/// where they are predicted faster than the line's (each a scan of the
/// pilot posts' reach): a coarser ladder, as neither has ever met a budget
/// faster than line (docs/PLANNING.md, "The method").
pub const OTHER_COUNTS: [usize; 5] = [4, 8, 16, 32, 64];
/// The most posts a method no count of which is predicted faster than the
/// line may visit at the pilot's posts to be measured anyway, to say what
/// it would give (`predict::pilot_visits`): the sector's scans reach across much
/// of the DEM where horizons are low, 0.6-0.7 s on the 1201 x 1201 tiles
/// (5.6e8 visits at most) but 33 s on an 8192 x 8192 fractal (2.6e10),
/// whose whole pilot took 16 s before.
pub const OTHERS_MEASURED_UP_TO_VISITS: f64 = 2e9;
/// Direction counts the planner considers (divisors of the pilot's
/// reference, at most half of it: 360 at most, or 1440 under `horizon_max`).
const CANDIDATES: [usize; 22] = [
    4, 6, 8, 10, 12, 16, 18, 20, 24, 30, 36, 40, 48, 60, 72, 90, 120, 180, 240, 360, 720, 1440,
];
/// Distance limits the planner considers, metres.
const DISTANCES: [f64; 18] = [
    250.0, 500.0, 1e3, 1.5e3, 2e3, 3e3, 5e3, 7.5e3, 1e4, 1.5e4, 2e4, 3e4, 5e4, 7.5e4, 1e5, 1.5e5,
    2e5, 3e5,
];
/// The most spikes a plan lists with the line's angles: each query of the
/// loader looks at those near its sight line, so the list stays short.
const PLANNED_FEATURES: usize = 256;
/// The shares of the budget: interpolation between directions, the
/// distance limit, quantisation; the rest (0.1) covers the posts the pilot
/// did not see.
pub const SHARE_DIRECTIONS: f64 = 0.6;
const SHARE_DISTANCE: f64 = 0.05;
const SHARE_QUANTISATION: f64 = 0.25;
/// The shares a baked candidate (encoded, and cut where it is bounded) is
/// judged against: all but the unseen posts' tenth.
const SHARE_BAKED: f64 = SHARE_DIRECTIONS + SHARE_DISTANCE + SHARE_QUANTISATION;
/// Tolerances the planner tries beyond the stage's default (an eighth of
/// the spacing), as divisors of the spacing, narrowest first; up to a
/// third, short of the half at which two directions could take one step.
const WIDER_TOLERANCES: [f64; 3] = [5.0, 4.0, 3.0];
/// The predicted range as factors of the calibrated prediction, whose top
/// is then widened by the calibration's spread: over `bench_plan.sh`'s 38
/// planned bakes the bake took 0.20x (a smooth bowl, which sweeps in a
/// fifth of the fit tile's time) to 1.22x of it, the calibration's spread
/// then 1.37x (docs/BENCHMARKS.md, "Planned bakes").
pub const SECONDS_RANGE: (f64, f64) = (0.2, 1.0);
/// The pilot's quantile that decides (the budget's is 0.99): where a lone
/// spike is seen in about 1 % of the azimuths, the 99th sits on a knife's
/// edge and a pilot can find it small where a check finds it large.
const DECISION_QUANTILE: f64 = 0.995;
/// The pilot's seed: apart from `check`'s default, so that a check of a
/// planned bake measures posts the plan never saw.
pub const PILOT_SEED: u64 = 0x504c_414e;
/// One count of directions, distance limit and encoding, predicted.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Candidate {
    /// How the horizons are computed (line in plans recorded before the
    /// method was planned).
    #[serde(default = "line_method")]
    pub method: Method,
    pub sectors: usize,
    pub encoding: AngleEncoding,
    /// The distance limit baked, metres (`None`: the whole DEM).
    #[serde(default)]
    pub max_distance: Option<f64>,
    pub horizon_p99_deg: f64,
    pub svf_p99: f64,
    /// The largest horizon error away from the DEM's edge, degrees, and
    /// the largest svf error, at the pilot's posts (features' included).
    #[serde(default)]
    pub horizon_max_deg: f64,
    #[serde(default)]
    pub svf_max: f64,
    /// The share of (post, sun position) pairs whose sun/shade state is
    /// wrong, when the scene needs the sun.
    #[serde(default)]
    pub shade_share: Option<f64>,
    /// Per cent: the 99th percentile over posts of the year's beam put in
    /// the wrong sun or shade, when the scene needs solar.
    #[serde(default)]
    pub solar_p99_percent: Option<f64>,
    /// Bytes of the horizon and sky layers.
    pub bytes: u64,
    /// Seconds of the horizons and sky stages.
    pub seconds: f64,
    /// How far (degrees) a stored direction may sit from `i * 360 / S`
    /// (`None`: the stage's default, an eighth of the spacing).
    #[serde(default)]
    pub direction_tolerance: Option<f64>,
    /// Whether its errors meet the budget (within the directions' share,
    /// f32; of the chosen, the whole budget). False in plans recorded
    /// before it was.
    #[serde(default)]
    pub meets: bool,
    /// The spikes listed with the line's angles, served exactly between
    /// bands (`terrabake_format::features`), and the least rise above
    /// their neighbours listed, metres; 0 for none.
    #[serde(default, skip_serializing_if = "crate::stage::args::is_default")]
    pub features: usize,
    #[serde(default, skip_serializing_if = "crate::stage::args::is_default")]
    pub feature_rise_m: f64,
}

impl Candidate {
    /// The horizons stage that bakes this candidate (raw tiles, the
    /// stage's memory limit).
    pub(crate) fn stage(&self) -> HorizonsStage {
        HorizonsStage {
            method: self.method,
            features: self.features,
            feature_rise: self.feature_rise_m,
            ..line_bake(
                (self.sectors, self.direction_tolerance),
                self.max_distance,
                self.encoding,
            )
        }
    }

    /// `sectors` bands of `method` stored as `encoding`, with the `errors`
    /// the pilot measured of them and `costs`' bytes and seconds, from the
    /// whole DEM at the stage's default tolerance; not yet judged
    /// (`meets` false).
    fn predicted(
        (method, sectors, encoding): (Method, usize, AngleEncoding),
        errors: &mut Errors,
        costs: &LineCosts,
    ) -> Self {
        Self {
            method,
            sectors,
            encoding,
            max_distance: None,
            horizon_p99_deg: 0.0,
            svf_p99: 0.0,
            horizon_max_deg: 0.0,
            svf_max: 0.0,
            shade_share: None,
            solar_p99_percent: None,
            bytes: costs.horizon_bytes(&HorizonsStage {
                method,
                ..line_bake((sectors, None), None, encoding)
            }),
            seconds: predict::seconds(costs, method, sectors),
            direction_tolerance: None,
            meets: false,
            features: 0,
            feature_rise_m: 0.0,
        }
        .with_errors(errors)
    }

    /// Itself with the predicted `errors` (not judged: `meets` unchanged).
    fn with_errors(self, errors: &mut Errors) -> Self {
        let (horizon_p99_deg, svf_p99, shade_share) = errors.at(0.99);
        Self {
            horizon_p99_deg,
            svf_p99,
            horizon_max_deg: errors.horizon_max,
            svf_max: errors.svf_max,
            shade_share,
            solar_p99_percent: errors.solar_at(0.99),
            ..self
        }
    }

    /// Its predicted errors, for a reason: "horizon p99 .. deg, svf p99
    /// ..[, shade ..]".
    fn errors_text(&self) -> String {
        format!(
            "horizon p99 {:.3} deg (max {:.3}), svf p99 {:.4} (max {:.4}){}",
            self.horizon_p99_deg,
            self.horizon_max_deg,
            self.svf_p99,
            self.svf_max,
            self.shade_share
                .map_or(String::new(), |s| format!(", shade {s:.4}")),
        ) + &self
            .solar_p99_percent
            .map_or(String::new(), |s| format!(", solar p99 {s:.3} %"))
    }
}

/// One decision and its reason.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Choice {
    pub what: String,
    pub chosen: String,
    pub why: String,
    pub rejected: Option<String>,
}

/// What the planned bake measured of itself (recorded by the bake).
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct Baked {
    /// Wall seconds of the stages after ingest.
    pub seconds: f64,
    /// Peak resident memory of the bake's process, MiB.
    pub peak_memory_mib: f64,
}

/// The plan: the stages to run, why, and what they will cost.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Plan {
    pub budget: Budget,
    #[serde(default)]
    pub needs: Needs,
    /// The sun positions the shade is planned for, degrees.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sun: Vec<SunPosition>,
    pub scene: Scene,
    /// The horizons, when a need derives from them.
    pub chosen: Option<Candidate>,
    /// Beyond this distance (metres) terrain moves the horizon by less than
    /// its share of the budget at the pilot's posts: the reach of a bounded
    /// bake, a partitioned bake's halo (`None`: every distance matters).
    #[serde(default)]
    pub safe_distance: Option<f64>,
    #[serde(default)]
    pub sky_layers: Vec<SkyLayer>,
    /// The tile size the plan bakes with (smaller than the ingest's when
    /// the memory limit needs it: the bake ingests again).
    #[serde(default)]
    pub tile: u32,
    /// The heights' codec the plan bakes with: the ingest's, or zstd when
    /// only that fits the bytes limit (the bake ingests again).
    #[serde(default = "raw_codec")]
    pub codec: Codec,
    /// The horizon and sky layers' codec: raw, or zstd when only that
    /// fits the bytes limit.
    #[serde(default = "raw_codec")]
    pub derived_codec: Codec,
    /// The total viewshed, when the needs take it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub total_viewshed: Option<total_viewshed::TotalViewshedPlan>,
    #[serde(default)]
    pub pyramid: bool,
    #[serde(default)]
    pub cones: bool,
    /// The cone planes' slices.
    #[serde(default = "cone_slices")]
    pub cone_slices: usize,
    /// What a tracing budget (`steps`, `rays`) measured and chose.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tracing: Option<tracing::TracingPlan>,
    /// Predicted for the whole bake after ingest.
    #[serde(default)]
    pub seconds: f64,
    /// Where the bake's time should fall, seconds: `seconds` widened by
    /// the models' measured reach ([`SECONDS_RANGE`]) and the calibration's
    /// spread (`(0, 0)` in plans recorded before it was).
    #[serde(default)]
    pub seconds_range: (f64, f64),
    /// The models that predicted the horizons' and sky's seconds, as
    /// fitted (before the calibration's scale).
    #[serde(default)]
    pub time_models: TimeModels,
    /// This machine against the models' (`None`: not calibrated, scale 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<calibration::Calibration>,
    #[serde(default)]
    pub bytes: u64,
    #[serde(default)]
    pub memory_mib: f64,
    pub choices: Vec<Choice>,
    /// Every candidate the planner predicted, fewest directions first
    /// (each at the default tolerance, then the chosen count's wider
    /// tolerances in the order tried; f32 and to the edge).
    pub candidates: Vec<Candidate>,
    /// The other methods, measured like the line's candidates (f32, from
    /// the whole DEM): each one's fewest count (of [`OTHER_COUNTS`])
    /// predicted faster than the line's that meets the budget, or where
    /// none does, its candidate at the line's count (at most the last of
    /// [`OTHER_COUNTS`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub methods: Vec<Candidate>,
    /// Stages a recipe gave explicitly: they were baked instead of the
    /// plan's, and `check` measures what they achieved.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub overridden: Vec<String>,
    #[serde(default)]
    pub baked: Option<Baked>,
}

impl Plan {
    /// The horizons stage that bakes the plan, if the needs take one.
    pub fn horizons_stage(&self) -> Option<HorizonsStage> {
        let mut stage = HorizonsStage {
            codec: self.derived_codec,
            ..self.chosen.as_ref()?.stage()
        };
        if let Some(bytes) = self.budget.memory_bytes() {
            stage.max_memory = bytes;
        }
        Some(stage)
    }

    /// Every stage the plan bakes after ingest, in the order they run.
    pub fn stages(&self) -> Vec<Box<dyn Stage>> {
        let mut stages: Vec<Box<dyn Stage>> = Vec::new();
        if self.pyramid {
            stages.push(Box::new(crate::stages::pyramid::PyramidStage));
        }
        if self.cones {
            let mut cones = crate::stages::cones::ConesStage {
                slices: crate::stages::cones::SliceChoice::Count(self.cone_slices),
                encoding: ConeEncoding::U16,
                ..Default::default()
            };
            if let Some(bytes) = self.budget.memory_bytes() {
                cones.max_memory = bytes;
            }
            stages.push(Box::new(cones));
        }
        if let Some(h) = self.horizons_stage() {
            stages.push(Box::new(h));
        }
        if !self.sky_layers.is_empty() {
            stages.push(Box::new(SkyStage {
                layers: self.sky_layers.clone(),
                codec: self.derived_codec,
            }));
        }
        if self.needs.has(Need::Solar) {
            stages.push(Box::new(crate::stages::solar::SolarStage::default()));
        }
        if let Some(t) = &self.total_viewshed {
            let mut stage = total_viewshed_stage(t.directions, t.max_distance);
            if let Some(bytes) = self.budget.memory_bytes() {
                stage.max_memory = bytes;
            }
            stages.push(Box::new(stage));
        }
        stages
    }
}

fn raw_codec() -> Codec {
    Codec::Raw
}

fn cone_slices() -> usize {
    CONE_SLICES
}

fn line_method() -> Method {
    Method::Line
}

/// The total viewshed stage the need bakes, with `directions` and the
/// reach; the eye is the stage's default.
fn total_viewshed_stage(directions: usize, max_distance: Option<f64>) -> TotalViewshedStage {
    let mut stage = TotalViewshedStage {
        directions,
        ..Default::default()
    };
    stage.sight.max_distance = max_distance;
    stage
}

/// `stage` on `m`'s grid as the total viewshed's pilot and check walk it.
fn walked(stage: &TotalViewshedStage, m: &terrabake_format::Manifest) -> total_viewshed::Walked {
    total_viewshed::Walked {
        options: stage.options(m.cell_size.dx.min(m.cell_size.dy)),
        curvature: stage.sight.curvature_coefficient(m),
        bytes_per_post: TotalViewshedStage::bytes_per_post(),
    }
}

/// The horizons stage a plan of `sectors` line directions within
/// `tolerance` (`None`: the stage's default) bakes, before its encoding
/// and distance: its bands are those the pilot measures
/// ([`HorizonsStage::bands`]).
fn line_stage(sectors: usize, tolerance: Option<f64>) -> HorizonsStage {
    HorizonsStage {
        sectors,
        method: Method::Line,
        direction_tolerance: tolerance,
        ..Default::default()
    }
}

/// The horizons stage of `sectors` line directions at `tolerance`, to
/// `distance` (the whole DEM: `None`), stored as `encoding`.
fn line_bake(
    (sectors, tolerance): (usize, Option<f64>),
    distance: Option<f64>,
    encoding: AngleEncoding,
) -> HorizonsStage {
    let mut stage = HorizonsStage {
        encoding: Some(encoding),
        ..line_stage(sectors, tolerance)
    };
    stage.sight.max_distance = distance;
    stage
}

/// Profile vertices a post costs in the line sweeps of `bands` (the
/// crossings of each direction's grid step and its next post): the
/// sweep's work, which a wider tolerance cuts by taking shorter steps.
fn crossings(bands: &[Band]) -> usize {
    bands
        .iter()
        .map(|band| match &band.kind {
            BandKind::Line(direction) => Stencil::new(direction.step).len(),
            _ => 0,
        })
        .sum()
}

/// `x` rounded up at `decimals` decimals: a limit to relax to that,
/// printed, still suffices.
pub(super) fn round_up(x: f64, decimals: i32) -> f64 {
    let scale = 10f64.powi(decimals);
    (x * scale).ceil() / scale
}

/// Bytes of a layer of `bands` elements of `size` bytes per post on a
/// `w x h` grid in `tile`-post tiles (raw; edge tiles are whole).
fn layer_bytes(w: usize, h: usize, tile: usize, size: usize, bands: usize) -> u64 {
    (w.div_ceil(tile) * h.div_ceil(tile) * tile * tile * size * bands) as u64
}

/// Plans what `asset` needs for `request`.
pub fn plan(asset: &Asset<Mmap>, request: &Request, progress: Progress) -> crate::Result<Plan> {
    request
        .validate()
        .map_err(|e| crate::error::mark(crate::ErrorKind::Parameters, anyhow::Error::msg(e)))?;
    let time_models = TimeModels::from_env()?;
    let calibration = calibration::for_models(&time_models);
    // Every predicted time is this machine's: the fitted models scaled.
    let scale = calibration.map_or(1.0, |c| c.scale());
    let budget = &request.budget;
    let needs = &request.needs;
    let m = asset.manifest();
    let (w, h) = (m.width as usize, m.height as usize);
    let posts = (w * h) as u64;
    let heights = m.layer(terrabake_format::HEIGHT_LAYER, 0);
    let tile = heights.map_or(256, |l| l.tile_size as usize);
    let curvature = HorizonsStage::default()
        .sight
        .curvature_coefficient(asset.manifest());
    let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
    let start = Instant::now();
    let dem = (needs.horizons() || needs.has(Need::TotalViewshed))
        .then(|| crate::terrain::held::HeldDem::read_within(asset, budget.memory_bytes()))
        .transpose()?;
    let sampling = Sampling {
        samples: 240,
        seed: PILOT_SEED,
        directions: pilot_directions(budget),
        cuts: &DISTANCES,
    };
    let mut pilot = dem
        .as_ref()
        .filter(|_| needs.horizons())
        .map(|dem| Pilot::measure(asset, dem, curvature, [0, 0, w, h], &sampling, progress))
        .transpose()?;
    let mut scene = describe_scene(
        asset,
        pilot.as_ref(),
        curvature,
        start.elapsed().as_secs_f64(),
    );
    let sun = sun_positions(asset, request, &scene)?;
    let solar_suns = match (needs.has(Need::Solar), scene.latitude_deg) {
        (false, _) => Vec::new(),
        (true, Some(latitude)) => solar_year(latitude),
        (true, None) => bail!(
            "{}: --needs solar needs the scene's latitude, and this DEM is neither geographic nor WGS 84 UTM; bake the solar stage with a recipe and its latitude instead",
            asset.dir().display()
        ),
    };
    let mut sky_layers = Vec::new();
    if needs.svf() {
        sky_layers.push(SkyLayer::Svf);
    }
    if needs.has(Need::Sky) || needs.has(Need::Solar) {
        sky_layers.push(SkyLayer::SvfCosine);
    }
    let mut costs = LineCosts {
        posts: posts as f64,
        width: w,
        height: h,
        tile,
        sky_layers: sky_layers.len(),
        cell: (dx + dy) / 2.0,
        spacing: (dx, dy),
        nodata: m.nodata.count > 0,
        max_memory: budget
            .memory_bytes()
            .unwrap_or(HorizonsStage::default().max_memory),
        models: time_models.scaled(scale),
        scale,
    };
    let (mut chosen, mut safe_distance) = (None, None);
    let (mut choices, mut candidates, mut methods) = (Vec::new(), Vec::new(), Vec::new());
    if let (Some(pilot), Some(dem)) = (&mut pilot, &dem) {
        let suns = PilotSuns {
            shade: sun
                .iter()
                .map(|&position| pilot.sun(position, 1.0))
                .collect(),
            solar: solar_suns
                .iter()
                .map(|&(position, weight)| pilot.sun(position, weight))
                .collect(),
        };
        let added = Instant::now();
        let terrain = dem.terrain(curvature);
        let plan = plan_horizons(pilot, &terrain, &suns, budget, &costs, &scene, curvature)?;
        scene.pilot_seconds += added.elapsed().as_secs_f64();
        scene.pilot_directions = pilot.directions_measured();
        candidates = plan.candidates;
        methods = plan.methods;
        choices = plan.choices;
        chosen = Some(plan.chosen);
        safe_distance = plan.safe_distance;
    }
    // The tile size: the ingest's, unless the tile row of every direction
    // that the line sweeps hold would not fit the memory limit; then the
    // largest smaller power of two (down to 32) that fits, for a re-ingest.
    let ingested_tile = tile;
    if let (Some(c), Some(limit)) = (chosen.as_mut(), budget.memory) {
        while c.method == Method::Line
            && costs.memory_mib(&c.stage()) > limit as f64
            && costs.tile > 32
        {
            costs.tile /= 2;
        }
        c.bytes = costs.horizon_bytes(&c.stage());
    }
    let tile = costs.tile;
    let pyramid = needs.has(Need::Tracing) || needs.has(Need::FastTracing);
    // A tracing budget measures the layers on the scene; without one, fast
    // tracing takes the bundled tile's choice.
    let tracing = if pyramid && (budget.steps.is_some() || budget.rays.is_some()) {
        let started = Instant::now();
        let t = tracing::plan(asset, budget, needs.has(Need::FastTracing), progress)?;
        scene.pilot_seconds += started.elapsed().as_secs_f64();
        Some(t)
    } else {
        None
    };
    let chosen_slices = tracing.as_ref().map(|t| t.chosen().slices);
    let cones = chosen_slices.map_or(needs.has(Need::FastTracing), |k| k.is_some());
    let cone_slices = chosen_slices.flatten().unwrap_or(CONE_SLICES);
    // The pyramid: max and min planes of every stored level.
    let pyramid_bytes = crate::stages::pyramid::level_dims(w as u32, h as u32, tile as u32)
        .into_iter()
        .map(|(lw, lh)| 2 * layer_bytes(lw as usize, lh as usize, tile, 4, 1))
        .sum::<u64>();
    let cells = (w.saturating_sub(1), h.saturating_sub(1));
    let planes = |size: usize| 2 * layer_bytes(cells.0, cells.1, tile, size, 1);
    let cones_bytes = planes(2);
    match &tracing {
        Some(t) => choices.push(tracing::choice(t, budget)),
        None if pyramid => choices.push(tracing_choice(cones, cones_bytes, posts)),
        None => {}
    }
    // Seconds per post of the stages timed on the bundled tile, scaled to
    // this machine below as the line stages' models are.
    let mut per_post = 0.0;
    let mut seconds = 0.0;
    // The asset on disk: the heights (as stored, when they are zstd) and
    // every planned layer.
    let mut bytes = heights
        .filter(|l| l.codec == Codec::Zstd && l.tile_size as usize == tile)
        .map_or(layer_bytes(w, h, tile, 4, 1), |l| l.file_len);
    let mut memory_mib = costs.base_mib()
        + pilot
            .as_ref()
            .zip(dem.as_ref())
            .map_or(0.0, |(p, d)| p.memory_mib(d.held_bytes()));
    if let Some(c) = &chosen {
        seconds += c.seconds;
        bytes += c.bytes;
        memory_mib = memory_mib.max(predict::memory_mib(&costs, c));
    }
    if needs.has(Need::Solar) {
        let days = crate::stages::solar::Days::YEAR;
        per_post += f64::from(days.last - days.first + 1) * SOLAR_SECONDS_PER_POST_DAY;
        bytes += layer_bytes(w, h, tile, 4, crate::stages::solar::SolarLayer::ALL.len());
    }
    if pyramid {
        per_post += PYRAMID_SECONDS_PER_POST;
        bytes += pyramid_bytes;
    }
    if cones {
        match &tracing {
            // Measured on this machine: not scaled again.
            Some(t) => seconds += t.chosen().bake_seconds,
            None => {
                choices.push(cones_choice(planes(4) - cones_bytes));
                per_post += CONES_SECONDS_PER_POST;
            }
        }
        bytes += cones_bytes;
        let in_core = costs.base_mib() + CONES_BYTES_PER_POST * posts as f64 / 1048576.0;
        // Cones bake in windows within a memory limit.
        memory_mib = memory_mib.max(budget.memory.map_or(in_core, |l| in_core.min(l as f64)));
    }
    seconds += scale * per_post * posts as f64;
    let total_viewshed = match (&dem, budget.total_viewshed) {
        (Some(dem), Some(percent)) if needs.has(Need::TotalViewshed) => {
            let started = Instant::now();
            let stage = walked(&total_viewshed_stage(0, request.viewshed_distance), m);
            let t = total_viewshed::plan(asset, dem, percent, &stage, (PILOT_SEED, scale))?;
            scene.pilot_seconds += started.elapsed().as_secs_f64();
            choices.push(total_viewshed::choice(&t, percent));
            seconds += t.seconds;
            bytes += layer_bytes(w, h, tile, 4, 1);
            memory_mib = memory_mib.max(costs.base_mib() + t.memory_mib);
            Some(t)
        }
        _ => None,
    };
    choices.push(tiles_choice(&costs, chosen.as_ref(), ingested_tile));
    let derived = match (&dem, &chosen) {
        (Some(dem), Some(chosen)) => Some(codec::Derived {
            dem,
            curvature,
            chosen,
            sky_layers: sky_layers.len(),
        }),
        _ => None,
    };
    let (codecs, bytes) = codec::choose(asset, budget, (w, h, tile), bytes, derived, &mut choices)?;
    memory_mib += codecs.cache_mib;
    let spread = calibration.map_or(1.0, |c| c.spread());
    let seconds_range = (
        seconds * SECONDS_RANGE.0,
        seconds * SECONDS_RANGE.1 * spread,
    );
    check_limits(budget, chosen.is_some(), bytes, seconds_range.1, memory_mib)?;
    Ok(Plan {
        budget: *budget,
        needs: needs.clone(),
        sun,
        scene,
        chosen,
        safe_distance,
        sky_layers,
        tile: tile as u32,
        codec: codecs.heights,
        derived_codec: codecs.derived,
        total_viewshed,
        pyramid,
        cones,
        cone_slices,
        tracing,
        seconds,
        seconds_range,
        time_models,
        calibration,
        bytes,
        memory_mib,
        choices,
        candidates,
        methods,
        overridden: Vec::new(),
        baked: None,
    })
}

/// Refuses a plan whose predicted bytes, time or memory pass the budget's
/// limits, naming what to relax.
fn check_limits(
    budget: &Budget,
    horizons: bool,
    bytes: u64,
    seconds: f64,
    memory_mib: f64,
) -> Result<()> {
    let what_to_relax = if horizons {
        ", or horizon (fewer directions)"
    } else {
        ", or drop fast_tracing"
    };
    for (what, limit, predicted) in [
        ("bytes", budget.bytes.map(|b| b as f64), bytes as f64),
        ("time", budget.time, seconds),
        ("memory", budget.memory.map(|m| m as f64), memory_mib),
    ] {
        if let Some(limit) = limit {
            if predicted > limit {
                bail!(
                    "budget {budget}: the plan that meets the error budget needs {what} {predicted:.0}, over the limit {limit:.0}; relax {what}{what_to_relax}",
                );
            }
        }
    }
    Ok(())
}

/// What [`plan_horizons`] decided.
struct HorizonPlan {
    chosen: Candidate,
    safe_distance: Option<f64>,
    choices: Vec<Choice>,
    candidates: Vec<Candidate>,
    methods: Vec<Candidate>,
}

/// The horizons: encoding, distance limit, directions and route, each from
/// its share of the budget (module docs).
fn plan_horizons(
    pilot: &mut Pilot,
    terrain: &Terrain,
    suns: &PilotSuns,
    budget: &Budget,
    costs: &LineCosts,
    scene: &Scene,
    curvature: f64,
) -> Result<HorizonPlan> {
    let (features, feature_rise_m) = budget
        .horizon_max
        .map_or((0, 0.0), |max| pilot.list_features(terrain, max));
    let encoding = choose_encoding(pilot, suns, budget);
    let every_reference: Vec<usize> = (0..pilot.reference.len()).collect();
    // The distance: the shortest beyond which the terrain moves the
    // horizons (in all 720 directions, f32) by at most its share.
    let safe_cut = (0..DISTANCES.len())
        .take_while(|&k| DISTANCES[k] < scene.extent_m)
        .find(|&k| {
            let cut = Listed::Line(Some(DISTANCES[k]), AngleEncoding::F32);
            errors(pilot, &every_reference, suns, cut, |i, j| {
                pilot.bounded(i, j, k)
            })
            .within(budget, SHARE_DISTANCE)
        });
    let safe_distance = safe_cut.map(|k| DISTANCES[k]);
    // The directions: the fewest whose error between directions alone
    // (exact to the edge, f32) is within their share.
    let mut candidates = Vec::new();
    let candidate = |(sectors, tolerance): (usize, Option<f64>),
                     distance: Option<f64>,
                     encoding,
                     errors: &mut Errors| {
        // The count's and tolerance's candidates measure the
        // directions' share; the chosen one (encoded and cut) all of
        // the budget but the unseen posts' tenth.
        let share = if encoding == AngleEncoding::F32 && distance.is_none() {
            SHARE_DIRECTIONS
        } else {
            SHARE_BAKED
        };
        let meets = errors.within(budget, share);
        Candidate {
            meets,
            features,
            feature_rise_m,
            max_distance: distance,
            bytes: costs.horizon_bytes(&line_bake((sectors, tolerance), distance, encoding)),
            seconds: costs.seconds(sectors, distance),
            direction_tolerance: tolerance,
            ..Candidate::predicted((Method::Line, sectors, encoding), errors, costs)
        }
    };
    let (dx, dy) = scene.cell_size;
    let mut sectors = None;
    // The errors of the last count that failed: what a refusal names.
    let mut failed = None;
    let mut stored = Vec::new();
    let finest = pilot_directions(budget) / 2;
    for &s in CANDIDATES.iter().filter(|&&s| s <= finest) {
        // Its buffers go before the next count's are made.
        drop(failed.take());
        // The directions the stage would store, measured at the pilot's
        // posts: at its default tolerance they are seldom reference
        // directions, and far cheaper to sweep than those would be.
        stored = pilot.measure_directions(terrain, &line_stage(s, None).bands(dx, dy), || ());
        let mut e = predict(pilot, suns, &stored, (None, AngleEncoding::F32), true);
        let c = candidate((s, None), None, AngleEncoding::F32, &mut e);
        let meets = c.meets;
        candidates.push(c);
        if meets {
            sectors = Some(s);
            break;
        }
        failed = Some(e);
    }
    let Some(sectors) = sectors else {
        let closest = candidates.last().expect("candidates");
        let over = failed.map_or_else(Vec::new, |mut e: Errors| e.over(budget, SHARE_DIRECTIONS));
        return Err(unmet(budget, closest, &over));
    };
    // The tolerance: of those directions' grid steps within ever wider
    // tolerances, the ones a post sweeps in the fewest crossings whose
    // error between directions stays within the same share (the default
    // met it). A wider tolerance takes shorter steps, and widens the gaps
    // the loader interpolates across only a little (module docs).
    let (found, fewer) = (
        candidates.last().cloned().expect("chosen"),
        candidates.iter().rev().nth(1).cloned(),
    );
    let spacing = 360.0 / sectors as f64;
    let at_default = crossings(&line_stage(sectors, None).bands(dx, dy));
    let mut tolerance = (default_tolerance(sectors), at_default);
    let mut too_wide = None;
    for divisor in WIDER_TOLERANCES {
        let tol = spacing / divisor;
        let bands = line_stage(sectors, Some(tol)).bands(dx, dy);
        let cost = crossings(&bands);
        if cost >= tolerance.1 {
            continue;
        }
        let measured = pilot.measure_directions(terrain, &bands, || ());
        let mut e = predict(pilot, suns, &measured, (None, AngleEncoding::F32), true);
        let c = candidate((sectors, Some(tol)), None, AngleEncoding::F32, &mut e);
        let meets = c.meets;
        candidates.push(c);
        if meets {
            (tolerance, stored) = ((tol, cost), measured);
        } else {
            let (horizon, svf, _) = e.at(DECISION_QUANTILE);
            too_wide = Some((tol, cost, horizon, svf));
            break;
        }
    }
    // The route: bounded lines (walk each post's reach, the DEM in memory)
    // when that is faster and fits the memory limit, else the sweeps to
    // the edge (out of core).
    let fits = |d: Option<f64>| {
        budget.memory.is_none_or(|l| {
            costs.memory_mib(&line_bake((sectors, Some(tolerance.0)), d, encoding)) <= l as f64
        })
    };
    let bounded_cut = safe_cut.filter(|&k| {
        let d = Some(DISTANCES[k]);
        costs.seconds(sectors, d) < costs.seconds(sectors, None) && fits(d)
    });
    let bounded = bounded_cut.map(|k| DISTANCES[k]);
    let line = candidate(
        (sectors, Some(tolerance.0)),
        bounded,
        encoding,
        &mut predict(pilot, suns, &stored, (bounded_cut, encoding), true),
    );
    // The method: the line's, unless another meets the budget in less
    // time (and fits the memory limit).
    let (mut methods, mut unmeasured) = (Vec::new(), Vec::new());
    for method in [Method::Sector, Method::Sampled] {
        match other_method(pilot, terrain, suns, budget, costs, (method, &line)) {
            Some(c) => methods.push(c),
            None => {
                let count = other_count(&line);
                unmeasured.push((method, count, predict::seconds(costs, method, count)));
            }
        }
    }
    let faster = methods
        .iter()
        .filter(|c| c.meets && c.seconds < line.seconds)
        .filter(|c| {
            budget
                .memory
                .is_none_or(|l| predict::memory_mib(costs, c) <= l as f64)
        })
        .min_by(|a, b| a.seconds.total_cmp(&b.seconds));
    if let Some(other) = faster {
        let (c, mut e) = measure_other(
            pilot,
            terrain,
            suns,
            (costs, other.method, other.sectors),
            encoding,
        );
        let chosen = Candidate {
            meets: e.within(budget, SHARE_BAKED),
            ..c
        };
        let choices = vec![
            method_choice(&chosen, &line, (&methods, &unmeasured)),
            encoding_choice(encoding),
            Choice {
                what: "distance".into(),
                chosen: "the whole DEM".into(),
                why: format!(
                    "{} is predicted from its route over the whole DEM",
                    chosen.method.name()
                ),
                rejected: None,
            },
        ];
        return Ok(HorizonPlan {
            chosen,
            safe_distance,
            choices,
            candidates,
            methods,
        });
    }
    // The spikes stay listed where they lower the largest error, or where
    // the plan meets its budget only with them (a percentile too): behind
    // a band they set the terrain is estimated, which rough terrain can
    // miss.
    let mut chosen = line;
    let listed = budget.horizon_max.map(|_| {
        let mut without = predict(pilot, suns, &stored, (bounded_cut, encoding), false);
        let with = (chosen.features, chosen.horizon_max_deg);
        let meets = without.within(budget, SHARE_BAKED);
        if chosen.features > 0
            && without.horizon_max <= chosen.horizon_max_deg
            && (meets || !chosen.meets)
        {
            chosen = Candidate {
                meets,
                features: 0,
                feature_rise_m: 0.0,
                ..chosen.clone().with_errors(&mut without)
            };
        }
        (with, (without.horizon_max, meets))
    });
    let mut choices = vec![
        method_choice(&chosen, &chosen, (&methods, &unmeasured)),
        Choice {
            what: "directions".into(),
            chosen: sectors.to_string(),
            why: format!(
                "the fewest whose error between directions ({}, f32) is within {SHARE_DIRECTIONS} of the budget",
                found.errors_text()
            ),
            rejected: fewer.map(|c| format!("{} directions: {}", c.sectors, c.errors_text())),
        },
        tolerance_choice(sectors, tolerance, at_default, too_wide),
        encoding_choice(encoding),
        distance_choice(scene, curvature, safe_distance),
        route_choice(costs, &chosen.stage(), safe_distance, bounded),
    ];
    if let Some((with, without)) = listed {
        choices.push(features_choice(&chosen, with, without));
    }
    Ok(HorizonPlan {
        chosen,
        safe_distance,
        choices,
        candidates,
        methods,
    })
}

/// The plan recorded by a planned bake, if the heights are still those it
/// planned for.
pub fn recorded(asset: &Asset<Mmap>) -> Option<Plan> {
    crate::stage::recorded_params(asset.manifest(), "plan")
}
