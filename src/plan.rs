//! The planner (`terrabake plan`, `terrabake bake --budget`): from the
//! user's error budget to the horizons a scene needs, with the predicted
//! error, time and bytes of each choice and the cheaper choice it rejected
//! (docs/PLANNING.md).
//!
//! **Error model: the scene measures itself.** A pilot ([`Pilot`]) computes
//! exact line horizons in 720 directions at a few hundred posts (random,
//! and those of the highest relief), with a seed apart from `check`'s. For
//! `S` line directions (a divisor of 720, so that each stored direction is
//! a reference direction) the planner keeps the reference at those
//! directions, encodes them as the stage would (u8, u16 or f32), serves
//! every reference azimuth from them as the loader does (linear between
//! the two nearest), and takes the 99th percentile of the absolute error:
//! the prediction is the error of that very bake at those posts. The
//! sky-view factor is predicted the same way, from the `S` stored bands
//! against the 720.
//!
//! **Choice.** The fewest directions whose error between directions (with
//! f32 angles) is within 0.6 of the budget, and the coarsest encoding whose
//! worst error is within a quarter of it; the rest of the budget covers
//! the posts the pilot did not see. Fixed shares keep the plan monotone: a
//! looser budget never gives more directions or a finer encoding, so never
//! more bytes or time. Explicit `--sectors` and `--encoding` are not taken
//! here: `check` says what they achieve.
//!
//! **Cost model.** Time: `posts * S^1.31 / 1.22e7` seconds, fitted by
//! `pipelines/fit_plan_models.sh` to the line stage and the sky stage on
//! the bundled tile (longer grid steps at more directions make a direction
//! cost more than the last); bytes: the layers' raw tiles.
//!
//! What it does not plan yet: the distance limit (every plan is exact to
//! the DEM's edge), sector or sampled methods, cone slices, tile size and
//! codec, sun/shade budgets, and `--needs`.

use std::time::Instant;

use anyhow::{bail, Result};
use serde::Serialize;
use terrabake_format::horizons::AngleEncoding;
use terrabake_format::{Asset, Mmap};

use crate::budget::Budget;
use crate::horizon::sky::{svf_of_horizons, BandIntegrals};
use crate::horizon::{band_bounds, HorizonsStage, Method};
use crate::progress::Progress;
use crate::reference::{quantile_unsorted, Pilot, Sampling};

/// Reference directions of the pilot; candidates divide it.
const PILOT_DIRECTIONS: usize = 720;
/// Direction counts the planner considers (divisors of 720).
const CANDIDATES: [usize; 20] = [
    4, 6, 8, 10, 12, 16, 18, 20, 24, 30, 36, 40, 48, 60, 72, 90, 120, 180, 240, 360,
];
/// The shares of the budget: the error between directions (planned from
/// f32 angles) and the encoding's worst error; the rest (0.15) covers the
/// posts the pilot did not see. Fixed shares make the plan monotone: a
/// looser budget never gives more directions or a finer encoding, so never
/// more bytes or time.
const BUDGET_SHARE_DIRECTIONS: f64 = 0.6;
/// The pilot's quantile that decides the directions (the budget's is 0.99).
const DECISION_QUANTILE: f64 = 0.995;
const BUDGET_SHARE_QUANTISATION: f64 = 0.25;
/// The pilot's seed: apart from `check`'s default, so that a check of a
/// planned bake measures posts the plan never saw.
pub const PILOT_SEED: u64 = 0x504c_414e;
/// Fitted by pipelines/fit_plan_models.sh (docs/PLANNING.md): seconds =
/// posts * S^EXPONENT / RATE on the 2-core reference machine.
pub const TIME_EXPONENT: f64 = 1.31;
pub const TIME_RATE: f64 = 1.22e7;
/// Bytes per post of the sky stage's layers (three f32 and one u16).
const SKY_BYTES_PER_POST: u64 = 14;

/// One count of directions and one encoding, predicted.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Candidate {
    pub sectors: usize,
    pub encoding: AngleEncoding,
    pub horizon_p99_deg: f64,
    pub svf_p99: f64,
    /// Bytes of the horizon and sky layers.
    pub bytes: u64,
    pub seconds: f64,
}

/// What the planner measured of the scene.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Scene {
    pub width: u32,
    pub height: u32,
    pub cell_size: (f64, f64),
    pub relief_m: f64,
    pub nodata_share: f64,
    pub curvature: bool,
    pub pilot_posts: usize,
    pub pilot_seconds: f64,
}

/// One decision and its reason.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Choice {
    pub what: String,
    pub chosen: String,
    pub why: String,
    pub rejected: Option<String>,
}

/// The plan: the stage to run and why.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Plan {
    pub budget: Budget,
    pub scene: Scene,
    pub chosen: Candidate,
    pub choices: Vec<Choice>,
    /// Every candidate the planner predicted, cheapest first per encoding.
    pub candidates: Vec<Candidate>,
}

impl Plan {
    /// The horizons stage that bakes the plan.
    pub fn horizons_stage(&self) -> HorizonsStage {
        let mut stage = HorizonsStage {
            sectors: self.chosen.sectors,
            method: Method::Line,
            direction_tolerance: Some(0.1),
            encoding: Some(self.chosen.encoding),
            ..Default::default()
        };
        if let Some(mib) = self.budget.memory {
            stage.max_memory = mib << 20;
        }
        stage
    }
}

/// The absolute errors a bake would make at the pilot's posts: the
/// horizon's (degrees) at every post and reference azimuth, the svf's at
/// every post.
struct Errors {
    horizon: Vec<f64>,
    svf: Vec<f64>,
}

impl Errors {
    /// The horizon's and the svf's errors at quantile `q`.
    fn at(&mut self, q: f64) -> (f64, f64) {
        (
            quantile_unsorted(&mut self.horizon, q),
            quantile_unsorted(&mut self.svf, q),
        )
    }
}

/// The errors of `sectors` directions stored as `encoding`.
fn predict(pilot: &Pilot, sectors: usize, encoding: AngleEncoding) -> Errors {
    let every = PILOT_DIRECTIONS / sectors;
    let azimuths: Vec<f64> = (0..sectors)
        .map(|i| pilot.reference[i * every].azimuth)
        .collect();
    let integrals: Vec<BandIntegrals> = band_bounds(&azimuths)
        .into_iter()
        .map(|(lo, hi)| BandIntegrals::new(lo, hi))
        .collect();
    let stored_value = |deg: f64| encoding.decode(encoding.encode(deg)).unwrap_or(f64::NAN);
    let (mut horizon, mut svf) = (Vec::new(), Vec::new());
    for exact in &pilot.exact {
        let stored: Vec<f64> = (0..sectors)
            .map(|i| stored_value(exact[i * every]))
            .collect();
        for (band, &truth) in pilot.reference.iter().zip(exact) {
            let (i, j, f) = terrabake_format::horizons::bands_around(&azimuths, band.azimuth);
            let served = stored[i] + f * (stored[j] - stored[i]);
            if served.is_finite() && truth.is_finite() {
                horizon.push((served - truth).abs());
            }
        }
        let s = svf_of_horizons(&integrals, stored.iter().copied());
        let truth = pilot.svf(exact);
        if s.is_finite() && truth.is_finite() {
            svf.push((s - truth).abs());
        }
    }
    Errors { horizon, svf }
}

/// `x` rounded up at `decimals` decimals: a limit to relax to that,
/// printed, still suffices.
fn round_up(x: f64, decimals: i32) -> f64 {
    let scale = 10f64.powi(decimals);
    (x * scale).ceil() / scale
}

/// Plans the horizons of `asset` for `budget`.
pub fn plan(asset: &Asset<Mmap>, budget: &Budget, progress: Progress) -> Result<Plan> {
    budget.validate().map_err(anyhow::Error::msg)?;
    let m = asset.manifest();
    let (w, h) = (m.width as usize, m.height as usize);
    let posts = (w * h) as u64;
    let curvature = HorizonsStage::default().curvature_coefficient(asset);
    let start = Instant::now();
    let pilot = Pilot::measure(
        asset,
        curvature,
        [0, 0, w, h],
        &Sampling {
            samples: 240,
            seed: PILOT_SEED,
            directions: PILOT_DIRECTIONS,
        },
        progress,
    )?;
    let scene = Scene {
        width: m.width,
        height: m.height,
        cell_size: (m.cell_size.dx, m.cell_size.dy),
        relief_m: m
            .height_range
            .map_or(0.0, |r| f64::from(r.max) - f64::from(r.min)),
        nodata_share: m.nodata.count as f64 / posts.max(1) as f64,
        curvature: curvature > 0.0,
        pilot_posts: pilot.posts.len(),
        pilot_seconds: start.elapsed().as_secs_f64(),
    };
    // The encoding: the coarsest whose worst error is a quarter of the
    // budget, in degrees and (for the svf, which a change of h radians in
    // every direction moves by at most h) in radians.
    let share = BUDGET_SHARE_QUANTISATION;
    let encoding = [AngleEncoding::U8, AngleEncoding::U16, AngleEncoding::F32]
        .into_iter()
        .find(|e| {
            e.max_error_deg() <= share * budget.horizon
                && budget
                    .svf
                    .is_none_or(|s| e.max_error_deg().to_radians() <= share * s)
        })
        .unwrap_or(AngleEncoding::F32);
    // The directions: the fewest whose error between directions alone
    // (f32 angles) is within the share of the budget left to it.
    let candidate = |sectors: usize, encoding: AngleEncoding, errors: &mut Errors| {
        let (horizon_p99_deg, svf_p99) = errors.at(0.99);
        Candidate {
            sectors,
            encoding,
            horizon_p99_deg,
            svf_p99,
            bytes: posts * ((sectors * encoding.elem().size()) as u64 + SKY_BYTES_PER_POST),
            seconds: posts as f64 * (sectors as f64).powf(TIME_EXPONENT) / TIME_RATE,
        }
    };
    let mut candidates = Vec::new();
    let (mut sectors, mut deciding) = (None, (0.0, 0.0));
    for &s in &CANDIDATES {
        let mut errors = predict(&pilot, s, AngleEncoding::F32);
        let exact = candidate(s, AngleEncoding::F32, &mut errors);
        // Decided on the 99.5th percentile: where a lone spike is seen in
        // about 1 % of the azimuths, the 99th sits on a knife's edge and a
        // pilot can find it small where a check finds it large.
        let (horizon, svf) = errors.at(DECISION_QUANTILE);
        deciding = (horizon, svf);
        let meets = horizon <= BUDGET_SHARE_DIRECTIONS * budget.horizon
            && budget
                .svf
                .is_none_or(|v| svf <= BUDGET_SHARE_DIRECTIONS * v);
        candidates.push(exact);
        if meets {
            sectors = Some(s);
            break;
        }
    }
    let Some(sectors) = sectors else {
        let closest = candidates.last().expect("candidates");
        // What to relax to: what the most directions leave, at the
        // quantile that decides, over the share of the budget it gets.
        bail!(
            "budget {budget} cannot be met with up to {} line directions on this scene: {} directions leave a horizon p99 of {:.3} degrees and an svf p99 of {:.4} between them; relax horizon to at least {:.3}{}",
            closest.sectors,
            closest.sectors,
            closest.horizon_p99_deg,
            closest.svf_p99,
            round_up(deciding.0 / BUDGET_SHARE_DIRECTIONS, 3),
            budget.svf.map_or(String::new(), |_| format!(
                " and svf to at least {:.4}",
                round_up(deciding.1 / BUDGET_SHARE_DIRECTIONS, 4)
            )),
        );
    };
    let chosen = candidate(sectors, encoding, &mut predict(&pilot, sectors, encoding));
    for (what, limit, predicted) in [
        ("bytes", budget.bytes.map(|b| b as f64), chosen.bytes as f64),
        ("time", budget.time, chosen.seconds),
    ] {
        if let Some(limit) = limit {
            if predicted > limit {
                bail!(
                    "budget {budget}: the plan that meets the error budget ({} directions, {}) needs {what} {predicted:.0}, over the limit {limit:.0}; relax {what}, or horizon (fewer directions)",
                    chosen.sectors,
                    chosen.encoding.name()
                );
            }
        }
    }
    let fewer = candidates.iter().rev().nth(1);
    let finer = [AngleEncoding::U8, AngleEncoding::U16]
        .into_iter()
        .filter(|e| e.max_error_deg() > encoding.max_error_deg())
        .map(|e| {
            format!(
                "{} (worst error {:.3} deg, over a quarter of the budget)",
                e.name(),
                e.max_error_deg()
            )
        })
        .collect::<Vec<_>>();
    let choices = vec![
        Choice {
            what: "method".into(),
            chosen: "line (exact sight lines)".into(),
            why: "exact at every stored direction, out of core; the only error left is between directions".into(),
            rejected: Some("sector and sampled: not planned yet".into()),
        },
        Choice {
            what: "directions".into(),
            chosen: chosen.sectors.to_string(),
            why: format!(
                "the fewest whose error between directions (horizon p99 {:.3} deg, svf p99 {:.4}, f32) is within {BUDGET_SHARE_DIRECTIONS} of the budget",
                candidates.last().expect("chosen").horizon_p99_deg,
                candidates.last().expect("chosen").svf_p99
            ),
            rejected: fewer.map(|c| {
                format!(
                    "{} directions: horizon p99 {:.3} deg, svf p99 {:.4}",
                    c.sectors, c.horizon_p99_deg, c.svf_p99
                )
            }),
        },
        Choice {
            what: "encoding".into(),
            chosen: chosen.encoding.name().into(),
            why: format!(
                "the coarsest whose worst error ({:.4} deg) is within {BUDGET_SHARE_QUANTISATION} of the budget",
                encoding.max_error_deg()
            ),
            rejected: (!finer.is_empty()).then(|| finer.join("; ")),
        },
        Choice {
            what: "distance".into(),
            chosen: "the whole DEM".into(),
            why: "exact to the edge (a distance limit is not planned yet)".into(),
            rejected: None,
        },
    ];
    Ok(Plan {
        budget: *budget,
        scene,
        chosen,
        choices,
        candidates,
    })
}

/// The plan as a table for people.
pub fn describe(plan: &Plan) -> String {
    let s = &plan.scene;
    let mut out = format!(
        "budget {}\nscene  {} x {} posts, cells {:.1} x {:.1} m, relief {:.0} m, nodata {:.2} %, curvature {}\n\
         pilot  exact horizons in {PILOT_DIRECTIONS} directions at {} posts ({:.1} s)\n\n",
        plan.budget,
        s.width,
        s.height,
        s.cell_size.0,
        s.cell_size.1,
        s.relief_m,
        100.0 * s.nodata_share,
        if s.curvature { "on" } else { "off" },
        s.pilot_posts,
        s.pilot_seconds,
    );
    for c in &plan.choices {
        out += &format!("{:<11} {:<26} {}\n", c.what, c.chosen, c.why);
        if let Some(r) = &c.rejected {
            out += &format!("{:<11} {:<26} rejected: {r}\n", "", "");
        }
    }
    let c = &plan.chosen;
    out += &format!(
        "\npredicted  horizon p99 {:.3} deg   svf p99 {:.4}   time {:.1} s (2 cores)   bytes {}\n",
        c.horizon_p99_deg,
        c.svf_p99,
        c.seconds,
        crate::report::human_bytes(c.bytes)
    );
    out
}

/// Ingests `src` into `dir` (default ingest options), plans its horizons
/// for `budget`, bakes them and the sky layers, and records the plan in the
/// manifest (`check` then measures against its budget and shows the
/// prediction beside what was achieved).
pub fn bake_to_budget(
    src: &std::path::Path,
    dir: &std::path::Path,
    budget: &Budget,
    wait: crate::asset::Wait,
    progress: Progress,
) -> Result<Vec<crate::stage::StageOutcome>> {
    use crate::stage::{run_stage_in, Stage};
    budget.validate().map_err(anyhow::Error::msg)?;
    let ingest = crate::ingest::IngestStage {
        src: src.to_path_buf(),
        options: Default::default(),
    };
    ingest.check()?;
    let created = !dir.exists();
    let writer = crate::asset::AssetWriter::create(dir, wait)?;
    let mut outcomes = vec![run_stage_in(&writer, &ingest, false, progress)?];
    // A budget the scene cannot meet is refused before anything is baked
    // from the heights; an asset this call created is removed again.
    let plan = match plan(&crate::asset::open(dir)?, budget, progress) {
        Ok(plan) => plan,
        Err(e) => {
            drop(writer);
            if created {
                let _ = std::fs::remove_dir_all(dir);
            }
            return Err(e);
        }
    };
    for stage in [
        &plan.horizons_stage() as &dyn Stage,
        &crate::sky::SkyStage::default(),
    ] {
        outcomes.push(run_stage_in(&writer, stage, false, progress)?);
    }
    drop(writer);
    crate::stage::record_measurement(
        dir,
        "plan",
        serde_json::to_value(&plan)?,
        vec![format!("{}@0", terrabake_format::layers::HEIGHT)],
    )?;
    Ok(outcomes)
}

/// The plan recorded by `bake --budget`, if the heights are still those it
/// planned for.
pub fn recorded(asset: &Asset<Mmap>) -> Option<Plan> {
    crate::stage::recorded_params(asset.manifest(), "plan")
}

/// `terrabake plan`: its arguments.
#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  terrabake plan dem.tbake --budget horizon=0.5,svf=0.01\n  \
terrabake bake dem.tif -o dem.tbake --budget horizon=0.5   # bake what the plan says\n\n\
The budget (docs/PLANNING.md): horizon=DEG is the 99th percentile over posts and azimuths of the \
absolute horizon angle error, interpolation between stored directions included; svf=X the 99th \
percentile over posts of the absolute sky-view factor error; bytes=SIZE and time=SECONDS limit the \
bake."
)]
pub struct PlanArgs {
    /// An ingested asset (terrabake ingest DEM -o ASSET) whose horizons to plan.
    pub asset: std::path::PathBuf,
    /// The budget: horizon=DEG[,svf=X][,time=SECONDS][,bytes=SIZE][,memory=MIB].
    #[arg(long)]
    pub budget: Budget,
    /// Print the plan as JSON (every candidate with its predicted error, time and bytes).
    #[arg(long)]
    pub json: bool,
}

impl PlanArgs {
    pub fn run(&self, progress: Progress) -> Result<()> {
        let plan = plan(&crate::asset::open(&self.asset)?, &self.budget, progress)?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&plan)?);
        } else {
            print!("{}", describe(&plan));
        }
        Ok(())
    }
}
