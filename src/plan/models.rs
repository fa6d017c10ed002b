//! The planner's cost models: the time models of the horizons and sky
//! stages (the defaults, or the machine's own from [`TIME_MODELS_VAR`]),
//! and the time, memory and bytes of the other stages (docs/PLANNING.md,
//! "Cost models").

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};

use super::{layer_bytes, HorizonsStage};

use crate::error::bail;

/// The environment variable naming a JSON file of [`TimeModels`] fitted on
/// the machine that bakes (`OUT=FILE pipelines/fit_plan_models.sh` writes
/// one); unset or empty, the planner takes the defaults.
pub const TIME_MODELS_VAR: &str = "TERRABAKE_TIME_MODELS";

/// The time models of the horizons and sky stages (docs/PLANNING.md, "Cost
/// models"): `fixed_seconds` and, for sweeps to the edge, `posts *
/// S^sweep_exponent / sweep_rate` seconds, for bounded lines `posts * S *
/// (bounded_per_line + bounded_per_cell * D / cell)`. Each is fitted by
/// `pipelines/fit_plan_models.sh` and raised until no fit run took longer,
/// so it is an upper bound on the machine it was fitted on, not on every
/// machine (the calibration scales it to another): the defaults are the
/// Zen 4 machine's (2 cores, 2026-12-03).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeModels {
    /// What a bake of a few posts takes: starting, opening, writing.
    pub fixed_seconds: f64,
    pub sweep_exponent: f64,
    pub sweep_rate: f64,
    pub bounded_per_line: f64,
    pub bounded_per_cell: f64,
    /// Seconds of the calibration workload ([`super::calibration`]) on the
    /// machine of the fit: what scales these models to another machine.
    /// `None` (files fitted before it was recorded): this machine's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_seconds: Option<f64>,
}

/// The calibration workload on the machine of the default fit, measured
/// by the fit (AMD EPYC, Zen 4, 2 cores, 2026-12-03).
pub const DEFAULT_CALIBRATION_SECONDS: f64 = 0.2148;

impl Default for TimeModels {
    fn default() -> Self {
        Self {
            fixed_seconds: 0.01904,
            sweep_exponent: 1.74189,
            sweep_rate: 3.11169e8,
            bounded_per_line: 3.20234e-8,
            bounded_per_cell: 6.48818e-9,
            calibration_seconds: Some(DEFAULT_CALIBRATION_SECONDS),
        }
    }
}

impl TimeModels {
    /// The models with every time multiplied by `scale` (a calibration's).
    pub fn scaled(self, scale: f64) -> Self {
        Self {
            fixed_seconds: self.fixed_seconds * scale,
            sweep_rate: self.sweep_rate / scale,
            bounded_per_line: self.bounded_per_line * scale,
            bounded_per_cell: self.bounded_per_cell * scale,
            ..self
        }
    }

    /// The models [`TIME_MODELS_VAR`] names, else the defaults; once read,
    /// kept for the process, so that the check before an ingest, the plans
    /// after it and `terrabake-bench plan`'s plans all use the same file's models. A
    /// file that fails is not kept: its error ends the command.
    pub(crate) fn from_env() -> Result<Self> {
        static MODELS: std::sync::OnceLock<TimeModels> = std::sync::OnceLock::new();
        if let Some(models) = MODELS.get() {
            return Ok(*models);
        }
        let models = match std::env::var_os(TIME_MODELS_VAR).filter(|v| !v.is_empty()) {
            None => Self::default(),
            Some(path) => Self::read(std::path::Path::new(&path))?,
        };
        Ok(*MODELS.get_or_init(|| models))
    }

    /// The models in the JSON file `path`: every field given, each a
    /// positive number (the fixed seconds may be 0).
    pub fn read(path: &std::path::Path) -> crate::Result<Self> {
        // A file of five numbers; anything larger is not one.
        const MAX_BYTES: u64 = 64 << 10;
        let named = || format!("{} ({TIME_MODELS_VAR})", path.display());
        // A regular file only: a FIFO there would hang the plan.
        let bytes = terrabake_format::fsio::read_regular(path, MAX_BYTES + 1)
            .with_context(|| format!("{}: cannot read the time models", named()))?;
        if bytes.len() as u64 > MAX_BYTES {
            bail!("{}: over {MAX_BYTES} bytes, not time models", named());
        }
        let models: Self = serde_json::from_slice(&bytes).with_context(|| {
            format!(
                "{}: not time models as fit_plan_models.sh writes them",
                named()
            )
        })?;
        let m = &models;
        for (key, value, may_be_zero) in [
            ("fixed_seconds", m.fixed_seconds, true),
            ("sweep_exponent", m.sweep_exponent, false),
            ("sweep_rate", m.sweep_rate, false),
            ("bounded_per_line", m.bounded_per_line, false),
            ("bounded_per_cell", m.bounded_per_cell, false),
            (
                "calibration_seconds",
                m.calibration_seconds.unwrap_or(1.0),
                false,
            ),
        ] {
            if !(value.is_finite() && (value > 0.0 || may_be_zero && value == 0.0)) {
                let least = if may_be_zero { "0 or more" } else { "positive" };
                bail!("{}: {key} is {value}; it must be {least}", named());
            }
        }
        Ok(models)
    }
}

/// Seconds per post of the pyramid and of the cone planes at
/// CONE_SLICES slices, measured on the bundled tile (2 cores, 0.13 s and
/// 0.46 s; docs/BENCHMARKS.md, cone planes).
pub(super) const PYRAMID_SECONDS_PER_POST: f64 = 9.0e-8;
pub(super) const CONES_SECONDS_PER_POST: f64 = 3.2e-7;
/// Seconds per post and day of the solar stage at 15-minute steps,
/// measured on the bundled tile (2 cores: a year in 12.2 s;
/// docs/BENCHMARKS.md, solar).
pub(super) const SOLAR_SECONDS_PER_POST_DAY: f64 = 2.3e-8;
/// The cone planes' slices: within 6 % of the exact cones' steps per ray on
/// the bundled tile at 40 % of the bake time of 256 slices (1.3 %).
pub(super) const CONE_SLICES: usize = 64;
/// Peak memory, measured on the bundled tile: a base of 30 MiB, per worker
/// thread [`WORKER_MIB`] and [`WORKER_BYTES_PER_ROW_POST`]; beyond it, what
/// the horizons stage says it holds (its steps in flight, the state its
/// line sweeps carry from band to band: `HorizonsStage::memory_bytes`) or,
/// where sky layers are baked, the sky stage's tile row of every band
/// mapped and of every sky layer, whichever is more; 32 bytes a post for
/// in-core cone planes; the pilot's own is counted exactly (`plan`).
pub(super) const BASE_MIB: f64 = 30.0;
/// Each worker thread's allocator arena keeps its high water: about 5 MiB
/// on a small DEM, and 16 bytes per post of a tile row (the sweep's window
/// of heights and tile row of angles, f32), measured at 2, 8 and 16 threads
/// on 64 x 48 to 2048 x 2048 fractals (2 to 13 MiB a thread). The plan
/// counts the threads of the machine that plans, which is the one that
/// bakes.
pub(super) const WORKER_MIB: f64 = 5.0;
pub(super) const WORKER_BYTES_PER_ROW_POST: f64 = 16.0;
pub(super) const CONES_BYTES_PER_POST: f64 = 32.0;

/// The other methods' time, fitted to the slowest of two runs each on
/// the 1201 x 1201 tile (4, 16 and 64 sectors) and a 2048 x 2048 fractal
/// (16), `horizons --encoding f32 --no-sky` (the horizons alone), on an
/// Intel Xeon (2 cores, 2026-12-04) whose calibration is 1.062 of the
/// default models' machine, divided by that to be its: Stewart's sector
/// tree over the whole DEM takes `posts * S^SECTOR_EXPONENT * (posts /
/// 1.44e6)^SECTOR_SIZE_EXPONENT * SECTOR_SECONDS` (its sorts and the
/// tree's height grow with the DEM); centre-line sampling to the edge
/// [`SAMPLED_SECONDS`] a sample, of a mean of a quarter of the DEM's width
/// and height samples a post and direction (34 s for 4 directions on the
/// tile). Scaled like the line's by the calibration (docs/PLANNING.md,
/// "The method").
pub(super) const SECTOR_SECONDS: f64 = 3.65e-7;
pub(super) const SECTOR_EXPONENT: f64 = 0.85;
pub(super) const SECTOR_SIZE_EXPONENT: f64 = 0.3;
pub(super) const SAMPLED_SECONDS: f64 = 1.0e-8;
/// Peak memory of the sector tree over the whole DEM, bytes a post
/// (docs/BENCHMARKS.md, "Time and peak memory against DEM size": 152 to
/// 162 at 1024^2 to 4096^2).
pub(super) const SECTOR_BYTES_PER_POST: f64 = 165.0;

/// Costs of the horizons and sky stages.
#[derive(Clone, Copy)]
pub(super) struct LineCosts {
    pub(super) posts: f64,
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) tile: usize,
    /// Sky layers baked from the horizons.
    pub(super) sky_layers: usize,
    /// Mean post spacing, metres.
    pub(super) cell: f64,
    /// Post spacing east-west and north-south, metres, as the stages take it.
    pub(super) spacing: (f64, f64),
    /// Whether the DEM has nodata posts (the sweeps then carry more).
    pub(super) nodata: bool,
    /// The horizons stage's `--max-memory`: the budget's limit, or its
    /// default.
    pub(super) max_memory: u64,
    pub(super) models: TimeModels,
    /// The calibration's scale of the fitted models to this machine.
    pub(super) scale: f64,
}

impl LineCosts {
    /// Posts of a tile row (edge tiles whole).
    pub(super) fn row_posts(&self) -> f64 {
        (self.width.div_ceil(self.tile) * self.tile * self.tile) as f64
    }

    pub(super) fn layer_bytes(&self, size: usize, bands: usize) -> u64 {
        layer_bytes(self.width, self.height, self.tile, size, bands)
    }

    /// Bytes of the horizon layer `stage` bakes (its bands, each grid step
    /// once) and of the sky layers from it.
    pub(super) fn horizon_bytes(&self, stage: &HorizonsStage) -> u64 {
        self.layer_bytes(stage.angle_encoding().elem().size(), self.bands(stage))
            + self.layer_bytes(4, self.sky_layers)
    }

    /// The bands `stage` bakes on this DEM (each grid step once: fewer
    /// than its directions where neighbouring ones share a step).
    fn bands(&self, stage: &HorizonsStage) -> usize {
        stage.bands(self.spacing.0, self.spacing.1).len()
    }

    pub(super) fn seconds(&self, sectors: usize, distance: Option<f64>) -> f64 {
        let (s, m) = (sectors as f64, &self.models);
        let work = match distance {
            None => self.posts * s.powf(m.sweep_exponent) / m.sweep_rate,
            Some(d) => self.posts * s * (m.bounded_per_line + m.bounded_per_cell * d / self.cell),
        };
        m.fixed_seconds + work
    }

    /// Peak memory of line horizons baked as `stage` (its directions,
    /// tolerance, reach and encoding; the memory limit as this plan's) and
    /// of the sky layers from them, MiB ([`BASE_MIB`]).
    pub(super) fn memory_mib(&self, stage: &HorizonsStage) -> f64 {
        let stage = HorizonsStage {
            max_memory: self.max_memory,
            ..stage.clone()
        };
        let horizons = stage.memory_bytes(
            (self.width, self.height, self.tile),
            self.spacing,
            self.nodata,
        ) as f64;
        let sky = if self.sky_layers == 0 {
            0.0
        } else {
            let per_post =
                self.bands(&stage) * stage.angle_encoding().elem().size() + 4 * self.sky_layers;
            self.row_posts() * per_post as f64
        };
        self.base_mib() + horizons.max(sky) / 1048576.0
    }

    /// Seconds of Stewart's sector tree of `sectors` over the whole DEM
    /// ([`SECTOR_SECONDS`]).
    pub(super) fn sector_seconds(&self, sectors: usize) -> f64 {
        let work = self.posts
            * (sectors as f64).powf(SECTOR_EXPONENT)
            * (self.posts / 1.44e6).powf(SECTOR_SIZE_EXPONENT)
            * SECTOR_SECONDS;
        self.models.fixed_seconds + work * self.scale
    }

    /// Seconds of centre-line sampling in `sectors` directions to the
    /// edge ([`SAMPLED_SECONDS`]).
    pub(super) fn sampled_seconds(&self, sectors: usize) -> f64 {
        let samples = (self.width + self.height) as f64 / 4.0;
        let work = self.posts * sectors as f64 * samples * SAMPLED_SECONDS;
        self.models.fixed_seconds + work * self.scale
    }

    /// Peak memory of the sector tree over the whole DEM, MiB.
    pub(super) fn sector_memory_mib(&self) -> f64 {
        self.base_mib() + SECTOR_BYTES_PER_POST * self.posts / 1048576.0
    }

    /// Peak memory of sampling `sectors` directions, MiB: the DEM and a
    /// whole layer of every band in flight, one a thread.
    pub(super) fn sampled_memory_mib(&self, sectors: usize) -> f64 {
        let threads = rayon::current_num_threads().min(sectors) as f64;
        self.base_mib() + 4.0 * self.posts * (1.0 + threads) / 1048576.0
    }

    /// What every bake holds, MiB, whatever it bakes: the base and the
    /// worker threads' own.
    pub(super) fn base_mib(&self) -> f64 {
        let threads = rayon::current_num_threads() as f64;
        let worker =
            WORKER_MIB + WORKER_BYTES_PER_ROW_POST * (self.width * self.tile) as f64 / 1048576.0;
        BASE_MIB + threads * worker
    }
}
