//! The commands that run stages: `ingest`, each stage on its own
//! (`pyramid`, `cones`, `horizons`, `sky`, `total-viewshed`), a recipe's
//! `bake` and a partitioned bake's `assemble`. Each is an `Args` type that
//! flattens the stage's own parameter type and implements [`Run`].

use std::path::PathBuf;
use std::process::ExitCode;

use terrabake_format::cones::CONE_APEX;
use terrabake_format::horizons::HORIZON;

use crate::bake::partition::{assemble, bake_part, Part};
use crate::bake::recipe::{bake, Recipe};
use crate::present::report::{horizons_json, ingested};
use crate::stage::asset::{open as open_asset, AssetWriter};
use crate::stage::session::{Run, Session};
use crate::stage::{run_stages_in, Stage};
use crate::stages::cones::ConesStage;
use crate::stages::horizons::HorizonsStage;
use crate::stages::ingest::{IngestOptions, IngestStage};
use crate::stages::sky::SkyStage;
use crate::stages::solar::{SolarLayer, SolarStage};

/// `terrabake ingest`: a new asset from a DEM.
#[derive(clap::Args, Debug)]
pub struct IngestArgs {
    /// The DEM file.
    pub src: PathBuf,
    /// The asset directory to write.
    #[arg(short, long)]
    pub output: PathBuf,
    #[command(flatten)]
    pub options: IngestOptions,
    /// Print the manifest as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

impl Run for IngestArgs {
    /// The asset created, its manifest (with --json) and a summary line.
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let start = std::time::Instant::now();
        let stage = IngestStage {
            src: self.src.clone(),
            options: self.options.clone(),
        };
        let manifest = stage.create_asset(&self.output, s.wait, s.progress)?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&manifest)?);
        }
        s.say(ingested(
            &self.src,
            &self.output,
            &manifest,
            start.elapsed(),
        ));
        Ok(ExitCode::SUCCESS)
    }
}

/// A stage run on its own: the asset, the stage's flags, and what every
/// stage command takes.
#[derive(clap::Args, Debug)]
pub struct StageCommand<S: clap::Args> {
    /// The asset directory (made by `terrabake ingest` or `terrabake bake`).
    pub asset: PathBuf,
    #[command(flatten)]
    pub stage: S,
    /// Recompute even if the asset already has up-to-date layers of this stage.
    #[arg(long)]
    pub force: bool,
    /// Print the stage's record as JSON on stdout (layers written, parameters, seconds).
    #[arg(long)]
    pub json: bool,
}

impl<S: clap::Args + Stage> Run for StageCommand<S> {
    /// The stage's record as JSON (with --json) and its summary line.
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let outcome = s.run_stage(&self.asset, &self.stage, self.force)?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&outcome)?);
        }
        s.say(outcome.to_string());
        Ok(ExitCode::SUCCESS)
    }
}

/// `terrabake cones`: the stage, and how it sliced the planes.
#[derive(clap::Args, Debug)]
pub struct ConesCommand {
    #[command(flatten)]
    pub command: StageCommand<ConesStage>,
}

impl Run for ConesCommand {
    /// The record (with the planes' description under `planes`, with
    /// --json), the summary line and the description.
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let c = &self.command;
        let outcome = s.run_stage(&c.asset, &c.stage, c.force)?;
        let how = open_asset(&c.asset)?
            .manifest()
            .layer(CONE_APEX, 0)
            .map(|l| l.description.clone())
            .unwrap_or_default();
        if c.json {
            let mut v = serde_json::to_value(&outcome)?;
            v["planes"] = serde_json::Value::String(how.clone());
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        s.say(outcome.to_string());
        s.say(how);
        Ok(ExitCode::SUCCESS)
    }
}

/// `terrabake horizons`: the horizons stage and, unless --no-sky, the sky
/// stage after it.
#[derive(clap::Args, Debug)]
pub struct HorizonsCommand {
    #[command(flatten)]
    pub command: StageCommand<HorizonsStage>,
    /// Only the horizon angles: leave out the sky stage (svf, svf_cosine,
    /// openness, horizon_edge), which otherwise runs after it.
    #[arg(long)]
    pub no_sky: bool,
}

impl Run for HorizonsCommand {
    /// Both stages in one run: the sky layers the new horizons drop are
    /// committed again with them, so no reader finds them missing
    /// meanwhile. The horizons' record (with the layer's encoding and
    /// azimuths, with --json), then a line per stage.
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let c = &self.command;
        let sky = SkyStage::default();
        let mut stages: Vec<(&dyn Stage, bool)> = vec![(&c.stage, c.force)];
        if !self.no_sky {
            stages.push((&sky, false));
        }
        let writer = AssetWriter::open(&c.asset, s.wait)?;
        let outcomes = run_stages_in(&writer, &stages, s.progress, &mut |_| Ok(()))?;
        drop(writer);
        let outcome = &outcomes[0];
        let entry = open_asset(&c.asset)?.manifest().layer(HORIZON, 0).cloned();
        if c.json {
            let v = horizons_json(outcome, entry.as_ref())?;
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        s.say(outcome.to_string());
        if let Some(e) = entry {
            s.say(e.description);
        }
        outcomes[1..].iter().for_each(|o| s.say(o.to_string()));
        Ok(ExitCode::SUCCESS)
    }
}

/// `terrabake solar`: the solar stage (after the sky stage where the
/// asset has no `svf_cosine`), and its layers as one GeoTIFF.
#[derive(clap::Args, Debug)]
pub struct SolarCommand {
    #[command(flatten)]
    pub command: StageCommand<SolarStage>,
    /// Every day of the year, 1-365: the default, the same as --days year.
    #[arg(long, conflicts_with = "days")]
    pub year: bool,
    /// The GeoTIFF to write: the five layers (global, beam, diffuse, reflected, sun hours),
    /// a band per layer and period, each named with its unit and period.
    #[arg(short, long)]
    pub output: Option<std::path::PathBuf>,
    /// Instead of the days: HORAYZON's terrain correction factor for direct shortwave with
    /// the sun at AZIMUTH,ELEVATION (true azimuth clockwise from north, degrees; repeat for a
    /// lookup table's positions), one band per sun in --output: the direct irradiance on each
    /// post's surface over that on a flat open plane, 0 in shadow. No layer is baked.
    #[arg(long, value_name = "AZ,EL", value_parser = crate::stage::args::parse_sun,
          allow_negative_numbers = true, conflicts_with_all = ["days", "year", "monthly", "between"],
          requires = "output")]
    pub sun: Vec<crate::terrain::sun::Sun>,
    /// With --sun: times HORAYZON's surface enlargement factor (1 / cos slope), the direct
    /// flux per unit of horizontal area, as grid-cell models take it.
    #[arg(long, requires = "sun")]
    pub per_horizontal_area: bool,
}

impl Run for SolarCommand {
    /// The stages in one run under one writer, then the GeoTIFF; the
    /// solar stage's record (with `output`, with --json) and a line per
    /// stage.
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let c = &self.command;
        if let (false, Some(out)) = (self.sun.is_empty(), &self.output) {
            let asset = open_asset(&c.asset)?;
            crate::export::correction::write_direct_correction(
                &asset,
                &self.sun,
                self.per_horizontal_area,
                out,
                s.progress,
            )?;
            if c.json {
                let suns: Vec<[f64; 2]> =
                    self.sun.iter().map(|s| [s.azimuth, s.elevation]).collect();
                let v = serde_json::json!({
                    "output": out.display().to_string(),
                    "layer": "direct_correction",
                    "suns": suns,
                    "per_horizontal_area": self.per_horizontal_area,
                });
                println!("{}", serde_json::to_string_pretty(&v)?);
            }
            s.say(format!(
                "wrote {} (direct shortwave correction factor, {} sun positions)",
                out.display(),
                self.sun.len()
            ));
            return Ok(ExitCode::SUCCESS);
        }
        let outcomes =
            crate::bake::recipe::solar_after_sky(&c.asset, &c.stage, c.force, s.wait, s.progress)?;
        if let Some(out) = &self.output {
            let asset = open_asset(&c.asset)?;
            let layers: Vec<&str> = SolarLayer::ALL.iter().map(|l| l.name()).collect();
            crate::export::export_stack(
                &asset,
                &layers,
                out,
                &crate::export::TiffOptions::default(),
                s.progress,
            )?;
        }
        let outcome = outcomes.last().expect("the solar stage ran");
        if c.json {
            let mut v = serde_json::to_value(outcome)?;
            if let Some(out) = &self.output {
                v["output"] = serde_json::Value::String(out.display().to_string());
            }
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        outcomes.iter().for_each(|o| s.say(o.to_string()));
        if let Some(out) = &self.output {
            s.say(format!("wrote {}", out.display()));
        }
        Ok(ExitCode::SUCCESS)
    }
}

/// `terrabake bake`: ingest and a recipe's stages, or a budget's plan.
#[derive(clap::Args, Debug)]
pub struct BakeArgs {
    /// The DEM (GeoTIFF, SRTM .hgt, raw, 16-bit PNG, OpenEXR).
    pub src: PathBuf,
    /// The asset directory to write (created, or brought up to date).
    #[arg(short, long)]
    pub output: PathBuf,
    /// A recipe from pipelines/ (TOML): ingest options and stages.
    #[arg(long, conflicts_with = "budget")]
    pub recipe: Option<PathBuf>,
    /// Instead of a recipe, an error budget and what the scene needs (--budget, --needs,
    /// --sun, --sun-day): ingests, bakes the stages `terrabake plan` chooses, and records the
    /// plan; `terrabake check` then measures it (docs/PLANNING.md).
    #[command(flatten)]
    pub request: crate::plan::RequestArgs,
    /// Cut the bake into this many parts (with --part).
    #[arg(long, value_name = "N", requires = "part", conflicts_with = "budget",
          value_parser = clap::value_parser!(u32).range(1..=i64::from(crate::bake::partition::MAX_PARTS)))]
    pub parts: Option<u32>,
    /// Bake only this part, 0 to N - 1 (with --parts).
    #[arg(long, value_name = "I", requires = "parts")]
    pub part: Option<u32>,
    /// Print one record per stage as JSON on stdout (what ran, what was up to date, seconds).
    #[arg(long)]
    pub json: bool,
}

impl Run for BakeArgs {
    /// A record per stage (with --json), a line each.
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let (src, output) = (&self.src, &self.output);
        let outcomes = match (&self.recipe, self.part.zip(self.parts)) {
            (Some(r), Some((i, n))) => {
                let recipe = Recipe::load(r)?;
                bake_part(src, output, &recipe, Part::new(i, n)?, s.wait, s.progress)?
            }
            (Some(r), None) => bake(src, output, &Recipe::load(r)?, s.wait, s.progress)?,
            (None, _) => {
                let recipe = Recipe {
                    plan: self.request.request(),
                    ..Default::default()
                };
                bake(src, output, &recipe, s.wait, s.progress)?
            }
        };
        s.report_all(&outcomes, self.json)?;
        Ok(ExitCode::SUCCESS)
    }
}

/// `terrabake assemble`: a partitioned bake's parts joined.
#[derive(clap::Args, Debug)]
pub struct AssembleArgs {
    /// The asset the parts were baked for (their OUTPUT).
    pub asset: PathBuf,
    /// Keep OUTPUT.parts/ after a successful join.
    #[arg(long)]
    pub keep_parts: bool,
    /// Print one record per joined stage as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

impl Run for AssembleArgs {
    /// A record per joined stage (with --json), a line each.
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let outcomes = assemble(&self.asset, self.keep_parts, s.wait, s.progress)?;
        s.report_all(&outcomes, self.json)?;
        Ok(ExitCode::SUCCESS)
    }
}
