//! The planner for people and the command line: the plan as a table, and
//! the flags of `terrabake plan` and `bake --budget`.

use std::process::ExitCode;

use super::budget::{Budget, Needs, Request};
use super::{calibration, plan, Plan, TimeModels, PILOT_DIRECTIONS, TIME_MODELS_VAR};
use crate::stage::session::{Run, Session};

/// The plan as a table for people.
pub(crate) fn describe(plan: &Plan) -> String {
    let s = &plan.scene;
    let mut out = format!(
        "budget {}\nneeds  {}{}\nscene  {} x {} posts, cells {:.1} x {:.1} m, relief {:.0} m, nodata {:.2} %, curvature {}\n",
        plan.budget,
        plan.needs,
        if plan.sun.is_empty() {
            String::new()
        } else {
            format!(" ({} sun positions)", plan.sun.len())
        },
        s.width,
        s.height,
        s.cell_size.0,
        s.cell_size.1,
        s.relief_m,
        100.0 * s.nodata_share,
        if s.curvature { "on" } else { "off" },
    );
    if let (Some(p50), Some(p90), Some((top, bottom))) =
        (s.slope_p50_deg, s.slope_p90_deg, s.dx_range_m)
    {
        out += &format!(
            "       slope p50 {p50:.1} deg, p90 {p90:.1} deg at the pilot's posts; east-west spacing {top:.1} m (first row) to {bottom:.1} m (last)\n"
        );
    }
    if s.pilot_posts > 0 {
        // (A plan recorded before the pilot measured the stored
        // directions too says 0 for them.)
        let reference = match s.pilot_reference_directions {
            0 => PILOT_DIRECTIONS,
            n => n,
        };
        let stored = s.pilot_directions.saturating_sub(reference);
        out += &format!(
            "pilot  exact horizons in {reference} reference directions and {stored} that the candidates store, at {} posts ({:.1} s)\n",
            s.pilot_posts, s.pilot_seconds,
        );
        if s.pilot_feature_posts > 0 {
            let prominence: Vec<String> = s
                .feature_prominence_m
                .iter()
                .map(|p| format!("{p:.0}"))
                .collect();
            out += &format!(
                "       of them {} around the {} most prominent features (rising {} m above their surroundings)\n",
                s.pilot_feature_posts,
                prominence.len(),
                prominence.join(", ")
            );
        }
    }
    out += "\n";
    // Columns as wide as their longest entry, so that every reason and
    // rejection starts in one column.
    let what = plan.choices.iter().map(|c| c.what.len()).max().unwrap_or(0);
    let chosen = plan
        .choices
        .iter()
        .map(|c| c.chosen.len())
        .max()
        .unwrap_or(0);
    for c in &plan.choices {
        out += &format!("{:<what$} {:<chosen$} {}\n", c.what, c.chosen, c.why);
        if let Some(r) = &c.rejected {
            out += &format!("{:<what$} {:<chosen$} rejected: {r}\n", "", "");
        }
    }
    let mut predicted = Vec::new();
    if let Some(c) = &plan.chosen {
        predicted.push(format!(
            "horizon p99 {:.3} deg (max {:.3})",
            c.horizon_p99_deg, c.horizon_max_deg
        ));
        predicted.push(format!("svf p99 {:.4} (max {:.4})", c.svf_p99, c.svf_max));
        if let Some(share) = c.shade_share {
            predicted.push(format!("shade {share:.4}"));
        }
    }
    if let Some(t) = &plan.total_viewshed {
        predicted.push(format!(
            "total viewshed p99 {:.3} % (max {:.3})",
            t.predicted_p99_percent, t.predicted_max_percent
        ));
    }
    let (low, high) = plan.seconds_range;
    let models = if plan.time_models == TimeModels::default() {
        "the default models".to_string()
    } else {
        format!("{TIME_MODELS_VAR}'s models")
    };
    predicted.push(match &plan.calibration {
        Some(c) => format!(
            "time {low:.1}-{high:.1} s ({models} x {:.2}, this machine's calibration)",
            c.scale()
        ),
        None => format!("time {low:.1}-{high:.1} s ({models}, not calibrated)"),
    });
    predicted.push(format!("bytes {:.1} MiB", plan.bytes as f64 / 1048576.0));
    predicted.push(format!("memory {:.0} MiB", plan.memory_mib));
    out + "\npredicted  " + &predicted.join("   ") + "\n"
}

/// The request of a command line: `--budget`, `--needs`, `--sun`,
/// `--sun-day`.
#[derive(clap::Args, Debug, Clone)]
pub struct RequestArgs {
    /// The budget: horizon=DEG[,horizon_max=DEG][,svf=X][,svf_max=X][,shade=FRACTION][,solar=PERCENT][,total_viewshed=PERCENT][,steps=N][,rays=N][,time=SECONDS][,bytes=SIZE][,memory=MIB].
    #[arg(long)]
    pub budget: Option<Budget>,
    /// What the scene needs, a comma list: horizons, svf, sky, sun, tracing, fast_tracing,
    /// solar, total_viewshed (default: horizons,svf).
    #[arg(long, requires = "budget")]
    pub needs: Option<Needs>,
    /// Sun positions for `sun` and the shade budget: AZ,EL;AZ,EL;... degrees (azimuth
    /// clockwise from north).
    #[arg(long, requires = "budget", allow_hyphen_values = true)]
    pub sun: Option<crate::plan::budget::SunPositions>,
    /// A day of the year (1-366) for `sun`: the sun every 15 minutes while it is up, at the
    /// scene's central latitude.
    #[arg(long, requires = "budget", value_parser = clap::value_parser!(u32).range(1..=366))]
    pub sun_day: Option<u32>,
    /// For total_viewshed: how far each eye sees, metres (default: the whole DEM).
    #[arg(long, requires = "budget", value_name = "METRES")]
    pub viewshed_distance: Option<f64>,
}

impl RequestArgs {
    /// The request, when a budget was given.
    pub fn request(&self) -> Option<Request> {
        Some(Request {
            budget: self.budget?,
            needs: self.needs.clone().unwrap_or_default(),
            sun: self.sun.clone().map(|s| s.0).unwrap_or_default(),
            sun_day: self.sun_day,
            viewshed_distance: self.viewshed_distance,
        })
    }
}

/// `terrabake plan`: its arguments.
#[derive(clap::Args, Debug)]
#[command(
    mut_arg("budget", |a| a.required(true)),
    after_help = "Examples:\n  terrabake plan dem.tif --budget horizon=0.5,svf=0.01\n  \
terrabake plan dem.tbake --budget horizon=1,shade=0.01 --needs horizons,sun --sun-day 172\n  \
terrabake bake dem.tif -o dem.tbake --budget horizon=0.5   # bake what the plan says\n\n\
The budget (docs/PLANNING.md): horizon=DEG is the 99th percentile over posts and azimuths of the \
absolute horizon angle error, interpolation between stored directions included; horizon_max=DEG \
its largest away from the DEM's edge, measured also around the scene's most prominent features \
(lone spikes, peaks, cliffs), where a percentile is blind; svf=X the 99th percentile over posts of \
the absolute sky-view factor error, svf_max=X its largest; shade=F the share of (post, sun \
position) pairs whose sun/shade state is wrong; bytes=SIZE, time=SECONDS and memory=MIB limit the \
bake. Its time is predicted by models fitted on a 2-core machine; on another, \
OUT=models.json pipelines/fit_plan_models.sh fits that machine's, and TERRABAKE_TIME_MODELS=models.json \
makes the planner use them."
)]
pub struct PlanArgs {
    /// A DEM (ingested into a temporary asset to be measured) or an ingested asset.
    pub src: std::path::PathBuf,
    #[command(flatten)]
    pub request: RequestArgs,
    /// Print the plan as JSON (every candidate with its predicted error, time and bytes).
    #[arg(long)]
    pub json: bool,
}

impl Run for PlanArgs {
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let progress = s.progress;
        let request = self.request.request().expect("clap requires --budget");
        // The time models are checked before a source DEM's ingest.
        TimeModels::from_env()?;
        let plan = if self.src.is_dir() {
            plan(&crate::stage::asset::open(&self.src)?, &request, progress)?
        } else {
            // A source DEM: measured through a temporary ingest (default
            // options), removed afterwards.
            let scratch = tempfile::Builder::new()
                .prefix("terrabake-plan")
                .tempdir()?;
            crate::plumbing::interrupt::scratch(scratch.path().to_path_buf());
            let dir = scratch.path().join("scene.tbake");
            crate::stages::ingest::ingest(&self.src, &dir, &Default::default(), progress)?;
            plan(&crate::stage::asset::open(&dir)?, &request, progress)?
        };
        if self.json {
            println!("{}", serde_json::to_string_pretty(&plan)?);
        } else {
            print!("{}", describe(&plan));
        }
        Ok(ExitCode::SUCCESS)
    }
}

/// `terrabake calibrate`: its arguments.
#[derive(clap::Args, Debug)]
#[command(
    after_help = "The planner predicts a bake's time from models fitted on one machine \
(docs/PLANNING.md, \"Time on this machine\"). Before it plans it times a fixed workload (the line \
sweep of 384 x 384 posts in 48 directions on every core) and scales the models by it; the \
result is cached per machine and binary, so this costs 1.5 seconds once. This command shows \
the calibration, or measures it again with --fresh. TERRABAKE_CALIBRATION=off plans with the \
models unscaled."
)]
pub struct CalibrateArgs {
    /// Measure again, and replace the cached calibration.
    #[arg(long)]
    pub fresh: bool,
    /// Print the calibration as JSON.
    #[arg(long)]
    pub json: bool,
}

impl Run for CalibrateArgs {
    fn run(&self, _: &Session) -> crate::Result<ExitCode> {
        let models = TimeModels::from_env()?;
        let c = calibration::measured(self.fresh);
        let scale = models.calibration_seconds.map(|r| c.seconds / r);
        if self.json {
            let mut v = serde_json::to_value(c)?;
            v["reference_seconds"] = serde_json::json!(models.calibration_seconds);
            v["scale"] = serde_json::json!(scale);
            println!("{}", serde_json::to_string_pretty(&v)?);
            return Ok(ExitCode::SUCCESS);
        }
        println!(
            "workload     line sweep of {0} x {0} posts in {1} directions, {2} runs: fastest {3:.3} s, slowest {4:.3} s",
            calibration::SIZE,
            calibration::DIRECTIONS,
            calibration::RUNS,
            c.seconds,
            c.slowest
        );
        println!("machine      {}", c.machine);
        match (models.calibration_seconds, scale) {
            (Some(r), Some(k)) => println!(
                "models       fitted where it took {r:.3} s: this machine's times are theirs x {k:.2}"
            ),
            _ => println!(
                "models       {TIME_MODELS_VAR}'s carry no calibration time: taken as this machine's own (x 1)"
            ),
        }
        println!(
            "cache        {}",
            calibration::cache_path().map_or("none (no HOME)".into(), |p| p.display().to_string())
        );
        Ok(ExitCode::SUCCESS)
    }
}
