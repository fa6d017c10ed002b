//! The registry of stages and the recipes that run them.
//!
//! A recipe (`pipelines/NAME.toml`) names the ingest options and the stages
//! to run after it, in order:
//!
//! ```toml
//! [ingest]
//! tile = 256
//! codec = "raw"      # or "zstd"
//!
//! [[stage]]
//! name = "pyramid"   # later stages: pyramid, cones, horizons, sky
//! ```
//!
//! or, instead of (or besides) the stages, what the scene needs and how
//! well, for the planner to choose them (`crate::plan`):
//!
//! ```toml
//! [plan]
//! needs = ["horizons", "svf"]
//! budget = { horizon = 0.5, svf = 0.01 }
//! ```
//!
//! This module sits above the stages: it imports each of them, and none of
//! them imports it. Ingest is the stage that creates the asset, so [`bake`]
//! runs it before the others, under the same hold of the writer lock.

use std::path::Path;

use anyhow::{Context, Result};
use serde::Deserialize;

use crate::error::bail;
use crate::plumbing::progress::Progress;
use crate::stage::asset::{AssetWriter, Wait};
use crate::stage::{run_stage_in, run_stages_in, Stage, StageOutcome};
use crate::stages::ingest::{IngestOptions, IngestStage};

/// A recipe file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    /// Where the recipe was read from (for messages).
    #[serde(skip)]
    pub path: std::path::PathBuf,
    /// The recipe as written (a partitioned bake's parts carry it to the
    /// join, which reads it again).
    #[serde(skip)]
    pub text: String,
    #[serde(default)]
    pub description: String,
    #[serde(default)]
    pub ingest: IngestOptions,
    #[serde(default, rename = "stage")]
    pub stages: Vec<RecipeStage>,
    /// A budget and needs instead of (or besides) explicit stages: the
    /// planner chooses the stages; a stage given explicitly wins over the
    /// planned one of its name (docs/PLANNING.md).
    #[serde(default)]
    pub plan: Option<crate::plan::budget::Request>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct RecipeStage {
    pub name: String,
    #[serde(flatten)]
    pub params: toml::Table,
}

impl Recipe {
    pub fn load(path: &Path) -> crate::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read recipe", path.display()))?;
        Self::parse(path, text)
    }

    /// The recipe `text`, read from `path` (named in messages).
    pub fn parse(path: &Path, text: String) -> crate::Result<Self> {
        let invalid = || format!("{}: invalid recipe", path.display());
        let mut recipe: Recipe = toml::from_str(&text).with_context(invalid)?;
        // TOML has `nan` and `inf`; no parameter of any stage means either.
        let table: toml::Table = toml::from_str(&text).with_context(invalid)?;
        if let Some(key) = non_finite_key(&toml::Value::Table(table), "") {
            bail!(
                "{}: invalid recipe: `{key}` is not a finite number",
                path.display()
            );
        }
        recipe.path = path.to_path_buf();
        recipe.text = text;
        Ok(recipe)
    }

    /// The ingest stage of this recipe for `src`.
    pub(crate) fn ingest_stage(&self, src: &Path) -> IngestStage {
        IngestStage {
            src: src.to_path_buf(),
            options: self.ingest.clone(),
        }
    }

    /// The recipe's ingest of `src`, checked, and the manifest it will
    /// write, from the source's header alone.
    pub(crate) fn describe(&self, src: &Path) -> Result<(IngestStage, terrabake_format::Manifest)> {
        let ingest = self.ingest_stage(src);
        ingest
            .check()
            .map_err(|e| crate::error::mark(crate::ErrorKind::Parameters, e))?;
        let opts = &self.ingest;
        let source =
            crate::io::source::open(src, opts.raw().as_ref(), opts.tile_size, opts.max_memory)?;
        let m = crate::stages::ingest::describe(src, source.info(), opts)?;
        Ok((ingest, m))
    }

    /// Refuses `stages` (this recipe's, resolved) in an order where one
    /// reads a layer that a later one writes (`sky` before `horizons`):
    /// the bake would ingest and then fail. `m` describes the DEM.
    pub(crate) fn check_order(
        &self,
        stages: &[Box<dyn Stage>],
        m: &terrabake_format::Manifest,
    ) -> Result<()> {
        for (i, reader) in stages.iter().enumerate() {
            for writer in &stages[i + 1..] {
                let outputs = writer.outputs(m);
                if let Some(layer) = reader.inputs().into_iter().find(|l| outputs.contains(l)) {
                    bail!(
                        "{}: stage '{}' reads {layer}, which stage '{}' writes after it; put '{}' first",
                        self.path.display(),
                        reader.name(),
                        writer.name(),
                        writer.name()
                    );
                }
            }
        }
        Ok(())
    }

    /// Every stage of the recipe, resolved before any work so that a typo
    /// fails in a second; errors name the file, the step and the key.
    pub fn resolve_stages(&self) -> crate::Result<Vec<Box<dyn Stage>>> {
        self.stages
            .iter()
            .enumerate()
            .map(|(i, step)| {
                stage_from_recipe(step).with_context(|| {
                    format!(
                        "{}: [[stage]] number {} (name = \"{}\")",
                        self.path.display(),
                        i + 1,
                        step.name
                    )
                })
            })
            .collect::<Result<_>>()
            .map_err(Into::into)
    }
}

/// The dotted key of the first non-finite float in `value` (`stage.2.refraction`).
fn non_finite_key(value: &toml::Value, at: &str) -> Option<String> {
    let key = |k: &dyn std::fmt::Display| {
        if at.is_empty() {
            k.to_string()
        } else {
            format!("{at}.{k}")
        }
    };
    let means_something = at
        .rsplit('.')
        .next()
        .is_some_and(|k| crate::stage::args::NAN_MEANS_SOMETHING.contains(&k));
    match value {
        toml::Value::Float(f) if !f.is_finite() && !means_something => Some(at.to_string()),
        toml::Value::Table(t) => t.iter().find_map(|(k, v)| non_finite_key(v, &key(k))),
        toml::Value::Array(a) => a
            .iter()
            .enumerate()
            .find_map(|(i, v)| non_finite_key(v, &key(&(i + 1)))),
        _ => None,
    }
}

/// The stages this build provides, by recipe name.
pub const STAGES: [&str; 7] = [
    "pyramid",
    "cones",
    "horizons",
    "sky",
    "viewshed",
    "total_viewshed",
    "solar",
];

/// The stage a recipe step names, its table deserialised into the stage's
/// parameter type (unknown keys refused by name) and checked.
pub(crate) fn stage_from_recipe(step: &RecipeStage) -> Result<Box<dyn Stage>> {
    fn typed<T>(table: &toml::Table) -> Result<Box<dyn Stage>>
    where
        T: Stage + serde::de::DeserializeOwned + 'static,
    {
        let stage: T = toml::Value::Table(table.clone()).try_into()?;
        stage
            .check()
            .map_err(|e| crate::error::mark(crate::ErrorKind::Parameters, e))?;
        Ok(Box::new(stage))
    }
    match step.name.as_str() {
        "pyramid" => {
            if let Some(key) = step.params.keys().next() {
                bail!("unknown field `{key}`: the pyramid stage takes no parameters");
            }
            Ok(Box::new(crate::stages::pyramid::PyramidStage))
        }
        "cones" => typed::<crate::stages::cones::ConesStage>(&step.params),
        "horizons" => typed::<crate::stages::horizons::HorizonsStage>(&step.params),
        "sky" => typed::<crate::stages::sky::SkyStage>(&step.params),
        "viewshed" => typed::<crate::stages::viewshed::stage::ViewshedStage>(&step.params),
        "total_viewshed" => {
            typed::<crate::stages::viewshed::stage::TotalViewshedStage>(&step.params)
        }
        "solar" => typed::<crate::stages::solar::SolarStage>(&step.params),
        other => bail!(
            "no stage '{other}' in this build of terrabake (after ingest: {})",
            STAGES.join(", ")
        ),
    }
}

/// Ingest (unless the asset already is this ingest) and every recipe stage,
/// all under one hold of the writer lock. A recipe with a `[plan]` is
/// planned after ingest (a budget the scene cannot meet is refused before
/// anything is baked from the heights); the plan, with what the bake
/// measured of itself, is recorded in the manifest for `check`. A planned
/// bake that fails removes the asset if this call created it: what it
/// would leave is an asset that meets no budget.
pub fn bake(
    src: &Path,
    dir: &Path,
    recipe: &Recipe,
    wait: Wait,
    progress: Progress,
) -> crate::Result<Vec<StageOutcome>> {
    bake_with(src, dir, recipe, wait, progress, &mut |_, _, _| Ok(()))
}

/// [`bake`], telling `on_stage(outcome, done, total)` as each stage is
/// done (ingest is stage 1; `total` counts the planned stages once the
/// plan is known). An error from it stops the bake there: the stages done
/// stay committed (a planned bake's too), and the bake resumes from them
/// when run again.
pub fn bake_with(
    src: &Path,
    dir: &Path,
    recipe: &Recipe,
    wait: Wait,
    progress: Progress,
    on_stage: &mut dyn FnMut(&StageOutcome, usize, usize) -> crate::Result<()>,
) -> crate::Result<Vec<StageOutcome>> {
    // The work in anyhow, its causes kept; the kind at the surface.
    let mut run = move || -> Result<Vec<StageOutcome>> {
        let (ingest, described) = recipe.describe(src)?;
        let resolved = recipe.resolve_stages()?;
        recipe.check_order(&resolved, &described)?;
        let mut explicit: Vec<Option<Box<dyn Stage>>> = resolved.into_iter().map(Some).collect();
        if let Some(request) = &recipe.plan {
            request
                .validate()
                .map_err(anyhow::Error::msg)
                .with_context(|| format!("{}: [plan]", recipe.path.display()))?;
            // The planner's time models, checked before the ingest as the plan is.
            crate::plan::TimeModels::from_env()?;
        }
        let created = !dir.exists();
        let writer = AssetWriter::create(dir, wait)?;
        let mut outcomes = vec![run_stage_in(&writer, &ingest, false, progress)?];
        let planned = recipe
            .plan
            .as_ref()
            .map(|request| {
                plan_ingested(dir, recipe, src, request, &writer, &mut outcomes, progress)
            })
            .transpose();
        let mut plan = match planned {
            Ok(plan) => plan,
            Err(e) => {
                abandon(writer, dir, created);
                return Err(e);
            }
        };
        if plan.is_some() {
            // The bake's peak is then the stages', which the plan predicted,
            // not the pilot's residue on top of them.
            crate::plumbing::resources::release_freed_memory();
        }
        // The planned stages, each replaced by an explicit one of its name,
        // then the explicit stages the plan does not name, in recipe order.
        let mut stages: Vec<Box<dyn Stage>> = Vec::new();
        for planned in plan.as_ref().map(|p| p.stages()).unwrap_or_default() {
            let given = explicit
                .iter_mut()
                .find(|s| s.as_ref().is_some_and(|s| s.name() == planned.name()))
                .and_then(Option::take);
            match given {
                Some(stage) => {
                    if let Some(p) = plan.as_mut() {
                        p.overridden.push(stage.name().to_string());
                    }
                    stages.push(stage);
                }
                None => stages.push(planned),
            }
        }
        stages.extend(explicit.into_iter().flatten());
        let start = std::time::Instant::now();
        let total = outcomes.len() + stages.len();
        for (i, outcome) in outcomes.iter().enumerate() {
            on_stage(outcome, i + 1, total)?;
        }
        let sequence: Vec<(&dyn Stage, bool)> =
            stages.iter().map(|s| (s.as_ref(), false)).collect();
        let mut n = outcomes.len();
        let mut stopped_by_caller = false;
        let ran = run_stages_in(&writer, &sequence, progress, &mut |outcome| {
            if plan.is_some() {
                // Nor a stage's on top of the next one's: a sweep's small
                // hulls stay in the allocator's arenas once freed, and the
                // sky stage's tile rows landed beside them (92 MiB against
                // its own 65 on the bundled tile at 48 directions).
                crate::plumbing::resources::release_freed_memory();
            }
            n += 1;
            let told = on_stage(outcome, n, total);
            stopped_by_caller = told.is_err();
            told
        })
        .map_err(crate::Error::into_anyhow);
        match ran {
            Ok(ran) => outcomes.extend(ran),
            Err(e) => {
                if created && plan.is_some() && !stopped_by_caller {
                    abandon(writer, dir, created);
                    return Err(e.context(format!(
                        "{}: removed the asset this planned bake created",
                        dir.display()
                    )));
                }
                return Err(e);
            }
        }
        if let Some(mut plan) = plan {
            plan.baked = Some(crate::plan::Baked {
                seconds: start.elapsed().as_secs_f64(),
                peak_memory_mib: crate::plumbing::resources::peak_memory().unwrap_or(0) as f64
                    / 1048576.0,
            });
            // Under the lock the bake holds: `--no-wait` is not waited past.
            crate::stage::record_measurement_in(
                &writer,
                "plan",
                serde_json::to_value(&plan)?,
                vec![format!("{}@0", terrabake_format::layers::HEIGHT)],
            )?;
        }
        Ok(outcomes)
    };
    Ok(run()?)
}

/// Releases the writer lock of a planned bake that failed and removes the
/// asset if the bake `created` it: what it would leave meets no budget.
fn abandon(writer: AssetWriter, dir: &Path, created: bool) {
    drop(writer);
    if created {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// Plans the ingested asset for `request`. When the plan needs other
/// tiles than the ingest's (smaller ones for the memory limit, zstd heights
/// for the bytes limit), ingests again with them and plans again, unless
/// the recipe set them itself: explicit parameters win, so that is refused
/// naming both ways out.
fn plan_ingested(
    dir: &Path,
    recipe: &Recipe,
    src: &Path,
    request: &crate::plan::budget::Request,
    writer: &AssetWriter,
    outcomes: &mut Vec<StageOutcome>,
    progress: Progress,
) -> Result<crate::plan::Plan> {
    let plan = crate::plan::plan(&crate::stage::asset::open(dir)?, request, progress)?;
    let written = toml::from_str::<toml::Table>(&recipe.text).ok();
    let given = |key: &str| {
        written
            .as_ref()
            .and_then(|t| t.get("ingest")?.get(key))
            .is_some()
    };
    let ingest = &recipe.ingest;
    for (key, differs, limit, wanted) in [
        (
            "tile",
            plan.tile != ingest.tile_size,
            "memory",
            plan.tile.to_string(),
        ),
        (
            "codec",
            plan.codec != ingest.codec,
            "bytes",
            serde_json::to_string(&plan.codec).expect("a codec serialises"),
        ),
    ] {
        if differs && given(key) {
            bail!(
                "{}: the [ingest] {key} leaves the plan over its {limit} limit; set {key} = {wanted} or relax {limit}",
                recipe.path.display(),
            );
        }
    }
    if plan.tile == ingest.tile_size && plan.codec == ingest.codec {
        return Ok(plan);
    }
    let mut again = recipe.ingest_stage(src);
    again.options.tile_size = plan.tile;
    again.options.codec = plan.codec;
    outcomes.push(run_stage_in(writer, &again, false, progress)?);
    Ok(crate::plan::plan(
        &crate::stage::asset::open(dir)?,
        request,
        progress,
    )?)
}

/// The solar stage on the asset at `dir`, after the sky stage where the
/// asset has no `svf_cosine` yet, under one writer: what `terrabake solar`
/// and Python's `terrabake.solar` run. The outcomes in order, the solar
/// stage's last.
pub fn solar_after_sky(
    dir: &Path,
    stage: &crate::stages::solar::SolarStage,
    force: bool,
    wait: Wait,
    progress: Progress,
) -> crate::Result<Vec<StageOutcome>> {
    let has_svf_cosine = crate::stage::asset::open(dir)?
        .manifest()
        .layer(terrabake_format::layers::SVF_COSINE, 0)
        .is_some();
    let sky = crate::stages::sky::SkyStage::default();
    let mut stages: Vec<(&dyn Stage, bool)> = Vec::new();
    if !has_svf_cosine {
        stages.push((&sky, false));
    }
    stages.push((stage, force));
    let writer = AssetWriter::open(dir, wait)?;
    run_stages_in(&writer, &stages, progress, &mut |_| Ok(()))
}
