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
//! This module sits above the stages: it imports each of them, and none of
//! them imports it. Ingest is the stage that creates the asset, so [`bake`]
//! runs it before the others, under the same hold of the writer lock.

use std::path::Path;

use anyhow::{bail, Context, Result};
use serde::Deserialize;

use crate::asset::{AssetWriter, Wait};
use crate::ingest::{IngestOptions, IngestStage};
use crate::progress::Progress;
use crate::stage::{run_stage_in, Stage, StageOutcome};

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
        Self::parse(path, text)
    }

    /// The recipe `text`, read from `path` (named in messages).
    pub fn parse(path: &Path, text: String) -> Result<Self> {
        let mut recipe: Recipe =
            toml::from_str(&text).with_context(|| format!("{}: invalid recipe", path.display()))?;
        recipe.path = path.to_path_buf();
        recipe.text = text;
        Ok(recipe)
    }

    /// The ingest stage of this recipe for `src`.
    pub fn ingest_stage(&self, src: &Path) -> IngestStage {
        IngestStage {
            src: src.to_path_buf(),
            options: self.ingest.clone(),
        }
    }

    /// Every stage of the recipe, resolved before any work so that a typo
    /// fails in a second; errors name the file, the step and the key.
    pub fn resolve_stages(&self) -> Result<Vec<Box<dyn Stage>>> {
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
            .collect()
    }
}

/// The stages this build provides, by recipe name.
pub const STAGES: [&str; 6] = [
    "pyramid",
    "cones",
    "horizons",
    "sky",
    "viewshed",
    "total_viewshed",
];

/// The stage a recipe step names, its table deserialised into the stage's
/// parameter type (unknown keys refused by name) and checked.
pub fn stage_from_recipe(step: &RecipeStage) -> Result<Box<dyn Stage>> {
    fn typed<T>(table: &toml::Table) -> Result<Box<dyn Stage>>
    where
        T: Stage + serde::de::DeserializeOwned + 'static,
    {
        let stage: T = toml::Value::Table(table.clone()).try_into()?;
        stage.check()?;
        Ok(Box::new(stage))
    }
    match step.name.as_str() {
        "pyramid" => {
            if let Some(key) = step.params.keys().next() {
                bail!("unknown field `{key}`: the pyramid stage takes no parameters");
            }
            Ok(Box::new(crate::pyramid::PyramidStage))
        }
        "cones" => typed::<crate::cones::ConesStage>(&step.params),
        "horizons" => typed::<crate::horizon::HorizonsStage>(&step.params),
        "sky" => typed::<crate::sky::SkyStage>(&step.params),
        "viewshed" => typed::<crate::viewshed::stage::ViewshedStage>(&step.params),
        "total_viewshed" => typed::<crate::viewshed::stage::TotalViewshedStage>(&step.params),
        other => bail!(
            "no stage '{other}' in this build of terrabake (after ingest: {})",
            STAGES.join(", ")
        ),
    }
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
    let ingest = recipe.ingest_stage(src);
    ingest.check()?;
    let stages = recipe.resolve_stages()?;
    let writer = AssetWriter::create(dir, wait)?;
    let mut outcomes = Vec::new();
    for stage in std::iter::once(&ingest as &dyn Stage).chain(stages.iter().map(|s| s.as_ref())) {
        outcomes.push(run_stage_in(&writer, stage, false, progress)?);
    }
    Ok(outcomes)
}
