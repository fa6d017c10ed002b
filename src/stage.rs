//! Bake stages and recipes.
//!
//! A stage reads layers of an asset and writes new ones: input layers and
//! parameters in, layers out. [`run_stage`] runs one against an asset
//! directory and records it in the manifest (`provenance.stages`, with its
//! parameters and outputs); a stage whose record already matches its
//! parameters, and whose outputs are all present, is skipped, which makes
//! `bake` resumable. Ingest is the stage that creates the asset, so it is run
//! by [`bake`] directly rather than through the trait.
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
//! name = "pyramid"   # later stages: pyramid, cones, horizons
//! ```

use std::path::Path;

use anyhow::{bail, Context, Result};
use serde::Deserialize;
use terrabake_format::manifest::StageRecord;
use terrabake_format::{commit_manifest, Asset, Codec, LayerEntry, Mmap};

use crate::asset::{AssetWriter, Wait};
use crate::ingest::{ingest_into, ingest_params, unix_now, IngestOptions};
use crate::progress::Progress;

/// One bake stage.
pub trait Stage {
    /// The stage's name in recipes, on the command line and in the manifest.
    fn name(&self) -> &'static str;
    /// Everything that determines the output (recorded; equal parameters and
    /// present outputs mean the stage is already done).
    fn params(&self) -> serde_json::Value;
    /// Writes the stage's layers into `dir` (with `terrabake_format::LayerWriter`)
    /// and returns their entries, not yet committed.
    fn run(&self, asset: &Asset<Mmap>, dir: &Path, progress: Progress) -> Result<Vec<LayerEntry>>;
}

/// What happened to a stage.
#[derive(Debug, Clone, serde::Serialize)]
pub struct StageOutcome {
    pub stage: String,
    pub skipped: bool,
    pub outputs: Vec<String>,
    pub seconds: f64,
}

/// Whether `stages` already holds a record of `stage` with `params` whose
/// outputs the asset still has.
fn already_done(
    manifest: &terrabake_format::Manifest,
    stage: &str,
    params: &serde_json::Value,
) -> Option<Vec<String>> {
    let record = manifest
        .provenance
        .stages
        .iter()
        .rev()
        .find(|r| r.stage == stage)?;
    let present = record
        .outputs
        .iter()
        .all(|key| manifest.layers.iter().any(|l| &l.key() == key));
    (record.params == *params && present).then(|| record.outputs.clone())
}

/// Runs `stage` on the asset in `dir` unless it is already done (or
/// `force`), waiting for another writer if one holds the asset.
pub fn run_stage(
    dir: &Path,
    stage: &dyn Stage,
    force: bool,
    progress: Progress,
) -> Result<StageOutcome> {
    let writer = AssetWriter::open(dir, Wait::Wait)?;
    run_stage_in(&writer, stage, force, progress)
}

/// [`run_stage`] under a writer the caller holds. A stage that fails
/// leaves nothing behind: its files are reclaimed before the error returns.
pub fn run_stage_in(
    writer: &AssetWriter,
    stage: &dyn Stage,
    force: bool,
    progress: Progress,
) -> Result<StageOutcome> {
    let result = write_stage(writer, stage, force, progress);
    if result.is_err() {
        writer.fail();
    }
    result
}

fn write_stage(
    writer: &AssetWriter,
    stage: &dyn Stage,
    force: bool,
    progress: Progress,
) -> Result<StageOutcome> {
    let dir = writer.dir();
    let start = std::time::Instant::now();
    let asset =
        Asset::open(dir).with_context(|| format!("{}: cannot open asset", dir.display()))?;
    let params = stage.params();
    if !force {
        if let Some(outputs) = already_done(asset.manifest(), stage.name(), &params) {
            return Ok(StageOutcome {
                stage: stage.name().into(),
                skipped: true,
                outputs,
                seconds: 0.0,
            });
        }
    }
    let entries = stage
        .run(&asset, dir, progress)
        .with_context(|| format!("{}: stage '{}' failed", dir.display(), stage.name()))?;
    let mut manifest = asset.manifest().clone();
    drop(asset);
    let outputs: Vec<String> = entries.iter().map(LayerEntry::key).collect();
    for entry in entries {
        manifest.upsert_layer(entry);
    }
    manifest
        .provenance
        .stages
        .retain(|r| r.stage != stage.name());
    manifest.provenance.stages.push(StageRecord {
        stage: stage.name().into(),
        params,
        tool: crate::tool_version(),
        finished_unix: unix_now(),
        outputs: outputs.clone(),
    });
    commit_manifest(writer.lock_held(), &manifest)?;
    Ok(StageOutcome {
        stage: stage.name().into(),
        skipped: false,
        outputs,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// A recipe file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    #[serde(default)]
    pub description: String,
    #[serde(default)]
    pub ingest: RecipeIngest,
    #[serde(default, rename = "stage")]
    pub stages: Vec<RecipeStage>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecipeIngest {
    #[serde(default = "default_tile")]
    pub tile: u32,
    #[serde(default = "default_codec")]
    pub codec: Codec,
    pub nodata: Option<f64>,
    pub cell_size: Option<[f64; 2]>,
    #[serde(default = "one")]
    pub z_scale: f64,
    #[serde(default)]
    pub z_offset: f64,
}

fn default_tile() -> u32 {
    crate::ingest::DEFAULT_TILE
}
fn default_codec() -> Codec {
    Codec::Raw
}
fn one() -> f64 {
    1.0
}

impl Default for RecipeIngest {
    fn default() -> Self {
        Self {
            tile: default_tile(),
            codec: default_codec(),
            nodata: None,
            cell_size: None,
            z_scale: 1.0,
            z_offset: 0.0,
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
pub struct RecipeStage {
    pub name: String,
    #[serde(flatten)]
    pub params: toml::Table,
}

impl Recipe {
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read recipe", path.display()))?;
        toml::from_str(&text).with_context(|| format!("{}: invalid recipe", path.display()))
    }

    pub fn ingest_options(&self) -> IngestOptions {
        let i = &self.ingest;
        IngestOptions {
            tile_size: i.tile,
            nodata: i.nodata,
            cell_size: i.cell_size.map(|[dx, dy]| (dx, dy)),
            z_scale: i.z_scale,
            z_offset: i.z_offset,
            codec: i.codec,
            raw: None,
            ..IngestOptions::default()
        }
    }
}

/// The stages this build provides, by recipe name.
pub fn stage_from_recipe(step: &RecipeStage) -> Result<Box<dyn Stage>> {
    let no_params = |stage: Box<dyn Stage>| -> Result<Box<dyn Stage>> {
        if let Some(key) = step.params.keys().next() {
            bail!("stage '{}' takes no parameter '{key}'", step.name);
        }
        Ok(stage)
    };
    match step.name.as_str() {
        "pyramid" => no_params(Box::new(crate::pyramid::PyramidStage)),
        "cones" => cones_from_recipe(&step.params).map(|s| Box::new(s) as Box<dyn Stage>),
        "horizons" => {
            crate::horizon::from_recipe(&step.params).map(|s| Box::new(s) as Box<dyn Stage>)
        }
        other => bail!("stage '{other}' is not available in this build of terrabake (available after ingest: pyramid, cones, horizons)"),
    }
}

/// `[[stage]] name = "cones"` with optional `slices` (a count, "auto" or
/// "exact"), `apex_gap` (metres, with auto), `encoding` ("f32", "f16",
/// "u16") and `max_memory_mib`.
fn cones_from_recipe(params: &toml::Table) -> Result<crate::cones::ConesStage> {
    use crate::cones::{ConesStage, SliceChoice};
    let mut stage = ConesStage::default();
    let mut apex_gap = None;
    for (key, value) in params {
        let bad = || anyhow::anyhow!("stage 'cones': invalid {key} = {value}");
        match key.as_str() {
            "slices" => {
                let text = match value {
                    toml::Value::Integer(k) => k.to_string(),
                    toml::Value::String(s) => s.clone(),
                    _ => return Err(bad()),
                };
                stage.slices = text.parse().map_err(|e: String| anyhow::anyhow!("stage 'cones': {e}"))?;
            }
            "apex_gap" => apex_gap = Some(value.as_float().filter(|g| *g > 0.0).ok_or_else(bad)?),
            "encoding" => {
                stage.encoding = value
                    .as_str()
                    .ok_or_else(bad)?
                    .parse()
                    .map_err(|e: String| anyhow::anyhow!("stage 'cones': {e}"))?;
            }
            "max_memory_mib" => {
                stage.max_memory = value.as_integer().filter(|m| *m > 0).ok_or_else(bad)? as u64 * (1 << 20);
            }
            other => bail!("stage 'cones' takes no parameter '{other}' (slices, apex_gap, encoding, max_memory_mib)"),
        }
    }
    if let Some(gap) = apex_gap {
        let SliceChoice::Auto { apex_gap } = &mut stage.slices else {
            bail!("stage 'cones': apex_gap goes with slices = \"auto\"");
        };
        *apex_gap = Some(gap);
    }
    Ok(stage)
}

/// Ingest (unless the asset already is this ingest) and every recipe stage,
/// all under one hold of the writer lock.
pub fn bake(
    src: &Path,
    dir: &Path,
    recipe: &Recipe,
    wait: Wait,
    progress: Progress,
) -> Result<Vec<StageOutcome>> {
    // Resolve every stage before any work, so a typo fails in a second.
    let stages = recipe
        .stages
        .iter()
        .map(stage_from_recipe)
        .collect::<Result<Vec<_>>>()?;
    let opts = recipe.ingest_options();
    let params = ingest_params(src, &opts)?;
    let writer = AssetWriter::create(dir, wait)?;
    let current = Asset::open(dir)
        .ok()
        .and_then(|a| already_done(a.manifest(), "ingest", &params));
    let mut outcomes = Vec::new();
    match current {
        Some(outputs) => outcomes.push(StageOutcome {
            stage: "ingest".into(),
            skipped: true,
            outputs,
            seconds: 0.0,
        }),
        None => {
            let start = std::time::Instant::now();
            let manifest =
                ingest_into(&writer, src, &opts, progress).inspect_err(|_| writer.fail())?;
            outcomes.push(StageOutcome {
                stage: "ingest".into(),
                skipped: false,
                outputs: manifest.layers.iter().map(LayerEntry::key).collect(),
                seconds: start.elapsed().as_secs_f64(),
            });
        }
    }
    for stage in stages {
        outcomes.push(run_stage_in(&writer, stage.as_ref(), false, progress)?);
    }
    Ok(outcomes)
}
