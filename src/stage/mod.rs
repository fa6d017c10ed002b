//! The stage interface: a stage reads layers of an asset and writes new
//! ones, input layers and parameters in, layers out (ingest, the one stage
//! that creates the asset, writes its first layer and its manifest).
//! [`run_stage`] runs one against an asset directory under its writer lock
//! and records it in the manifest (`provenance.stages`, with its parameters,
//! inputs and outputs); a stage whose record already matches its
//! parameters, and whose outputs are all present, is skipped, which makes
//! `bake` resumable.
//!
//! Stages import this module and nothing above it; the registry that knows
//! every stage by name, and recipes, are in [`crate::bake::recipe`].

pub mod args;
pub mod asset;
pub mod same;
pub mod session;
pub mod sight;

use std::path::Path;

use anyhow::{Context, Result};
use terrabake_format::manifest::StageRecord;
use terrabake_format::{commit_manifest, Asset, LayerEntry, Mmap};

use crate::plumbing::progress::Progress;
use crate::stage::asset::{AssetWriter, Wait};

/// One bake stage. A stage's parameters are one typed value: the command's
/// flags (clap's `Args`) and the recipe's `[[stage]]` table (serde, unknown
/// keys refused) both make it, and [`Stage::params`] records its
/// serialisation, so the same parameters give the same record either way.
pub trait Stage {
    /// The stage's name in recipes, on the command line and in the manifest.
    fn name(&self) -> &'static str;
    /// Everything that determines the output (recorded; equal parameters and
    /// present outputs mean the stage is already done).
    fn params(&self) -> serde_json::Value;
    /// Refuses parameters that make no sense together, before any work (a
    /// recipe is checked whole before its first stage runs).
    fn check(&self) -> crate::Result<()> {
        Ok(())
    }
    /// `name@level` of the layers the stage reads (recorded; rewriting one
    /// of them drops this stage's outputs). Most stages read the heights.
    fn inputs(&self) -> Vec<String> {
        vec![format!("{}@0", terrabake_format::HEIGHT_LAYER)]
    }
    /// `name@level` of the layers the stage writes on an asset described
    /// by `manifest` (the runner checks that it wrote exactly these).
    fn outputs(&self, manifest: &terrabake_format::Manifest) -> Vec<String>;
    /// How far beyond a region of the grid the stage must read to compute
    /// that region exactly, on an asset described by `manifest`. The
    /// default is the honest one for a stage that has not said: the whole
    /// DEM.
    fn reach(&self, manifest: &terrabake_format::Manifest) -> Reach {
        let _ = manifest;
        Reach::Whole
    }
    /// How a partitioned bake divides the stage among its parts
    /// (docs/SCALE.md). By default what the reach allows: a stage that
    /// reads a bounded distance splits by rows, one that reads the whole
    /// DEM runs at the join.
    fn split(&self, manifest: &terrabake_format::Manifest) -> Split {
        match self.reach(manifest) {
            Reach::Posts(halo) => Split::Rows { halo },
            Reach::Whole => Split::Join,
        }
    }
    /// Writes the stage's layers into `dir` (with `terrabake_format::LayerWriter`)
    /// and returns their entries, not yet committed. The outputs' chunks in
    /// `share` must be exact; a stage may leave the others at the layers'
    /// fill value (a part of a partitioned bake), or compute them too: a
    /// stage that never splits ignores the share.
    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        share: &Share,
        progress: Progress,
    ) -> crate::Result<Vec<LayerEntry>>;
    /// Bytes the stage holds at once on an asset described by `manifest`
    /// (its working buffers: a tile row of a very wide DEM can be
    /// gigabytes), or `None` where it has not said. The runner refuses,
    /// before the stage allocates, a need over [`Stage::max_memory`], or
    /// over the memory the machine has available.
    fn memory(&self, manifest: &terrabake_format::Manifest) -> Option<u64> {
        let _ = manifest;
        None
    }
    /// The user's memory budget for the stage (`--max-memory`), if it takes one.
    fn max_memory(&self) -> Option<u64> {
        None
    }
    /// Whether the stage creates the asset (ingest) rather than adding to
    /// one: the runner then calls [`Stage::create`], not [`Stage::run`].
    fn creates_asset(&self) -> bool {
        false
    }
    /// For a stage that creates the asset: writes its layers into `dir` and
    /// returns the new asset's manifest (its layers in it, no stage records
    /// yet), not yet committed. Whatever stood there before is replaced at
    /// the commit. Chunks outside `share` may hold the fill value.
    fn create(
        &self,
        dir: &Path,
        share: &Share,
        progress: Progress,
    ) -> crate::Result<terrabake_format::Manifest> {
        let _ = (dir, share, progress);
        crate::error::bail!(
            "stage '{}' adds to an asset; it does not create one",
            self.name()
        )
    }
}

/// How far beyond a region a stage reads: a planner or a partitioned bake
/// gives a part its region plus this much of the DEM, and gets that region
/// bit for bit as the whole DEM would have it (`tests/stage.rs` holds each
/// stage to its word).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Reach {
    /// This many posts on every side.
    Posts(u32),
    /// The whole DEM (distance transforms, unbounded horizons).
    Whole,
}

/// How a partitioned bake divides a stage ([`Stage::split`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// Each part computes its own tile rows of every output, reading this
    /// many posts beyond them.
    Rows { halo: u32 },
    /// Each part computes its share of the outputs' bands (directions),
    /// each over the whole DEM.
    Bands,
    /// The join runs the stage whole, once the parts are in.
    Join,
}

/// What one part of a partitioned bake computes of a stage's outputs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Share {
    /// Everything (a bake on one machine).
    All,
    /// Every band of these rows of posts (a stage may compute the rest of
    /// their tile rows too, inexactly: only whole tile rows are adopted).
    Rows(std::ops::Range<usize>),
    /// Bands `count * part / parts .. count * (part + 1) / parts` of a
    /// layer of `count` bands, every row.
    Bands { part: u32, parts: u32 },
}

impl Share {
    /// The rows of a `height`-row layer this share computes.
    pub fn rows(&self, height: usize) -> std::ops::Range<usize> {
        match self {
            Share::Rows(rows) => rows.start.min(height)..rows.end.min(height),
            Share::All | Share::Bands { .. } => 0..height,
        }
    }

    /// The rows of a `height`-row layer this share computes within `area`
    /// (an area of interest's rows; empty where they do not meet).
    pub(crate) fn rows_within(
        &self,
        height: usize,
        area: std::ops::Range<usize>,
    ) -> std::ops::Range<usize> {
        let r = self.rows(height);
        let start = r.start.max(area.start);
        start..r.end.min(area.end).max(start)
    }

    /// The bands of a `count`-band layer this share computes.
    pub fn bands(&self, count: usize) -> std::ops::Range<usize> {
        match *self {
            Share::Bands { part, parts } => {
                let at = |p: u32| count * p as usize / parts as usize;
                at(part)..at(part + 1)
            }
            Share::All | Share::Rows(_) => 0..count,
        }
    }
}

/// What happened to a stage.
#[derive(Debug, Clone, serde::Serialize)]
pub struct StageOutcome {
    pub stage: String,
    pub skipped: bool,
    pub outputs: Vec<String>,
    pub seconds: f64,
}

impl std::fmt::Display for StageOutcome {
    /// The stage, its time (or `up to date`) and its outputs, on one line
    /// whose columns line up with the other stages' lines.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let what = if self.skipped {
            "up to date".to_string()
        } else {
            format!("{:.2} s", self.seconds)
        };
        // As wide as the longest stage name (`total_viewshed`).
        write!(
            f,
            "{:<14} {what:>12}  {}",
            self.stage,
            self.outputs.join(", ")
        )
    }
}

/// The latest record of `stage` in `manifest`.
pub(crate) fn record_of<'m>(
    manifest: &'m terrabake_format::Manifest,
    stage: &str,
) -> Option<&'m StageRecord> {
    manifest
        .provenance
        .stages
        .iter()
        .rev()
        .find(|r| r.stage == stage)
}

/// The parameters of the latest record of `stage`, read as `T`.
pub fn recorded_params<T: serde::de::DeserializeOwned>(
    manifest: &terrabake_format::Manifest,
    stage: &str,
) -> Option<T> {
    serde_json::from_value(record_of(manifest, stage)?.params.clone()).ok()
}

/// Whether `stages` already holds a record of `stage` with `params` whose
/// outputs the asset still has.
pub(crate) fn already_done(
    manifest: &terrabake_format::Manifest,
    stage: &str,
    params: &serde_json::Value,
) -> Option<Vec<String>> {
    let record = record_of(manifest, stage)?;
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
) -> crate::Result<StageOutcome> {
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
) -> crate::Result<StageOutcome> {
    Ok(run_share_in(writer, stage, &Share::All, force, progress)?)
}

/// [`run_stage_in`] for one share of the stage's outputs (a part of a
/// partitioned bake, in the part's own asset).
pub(crate) fn run_share_in(
    writer: &AssetWriter,
    stage: &dyn Stage,
    share: &Share,
    force: bool,
    progress: Progress,
) -> Result<StageOutcome> {
    let result = write_stage(writer, stage, share, force, None, progress).and_then(|w| {
        if let Some(manifest) = &w.manifest {
            commit_manifest(writer.lock_held(), manifest)?;
        }
        Ok(w.outcome)
    });
    if result.is_err() {
        writer.fail();
    }
    result
}

/// Runs `stages` in order (each with its `force`) under one writer,
/// committing after each, with one exception that keeps readers whole: a
/// stage whose commit would drop layers that a later stage of the list
/// writes again (the horizons, dropping the sky layers derived from the
/// old ones) holds its commit until that stage has run, and both commit
/// at once. A reader never finds `svf` missing during `horizons --force`.
/// `on_stage` hears of each stage as it is done; an error from a stage or
/// from it commits what is held (as if each stage had committed alone),
/// removes the failed stage's files and returns the error.
pub fn run_stages_in(
    writer: &AssetWriter,
    stages: &[(&dyn Stage, bool)],
    progress: Progress,
    on_stage: &mut dyn FnMut(&StageOutcome) -> crate::Result<()>,
) -> crate::Result<Vec<StageOutcome>> {
    let mut held: Option<terrabake_format::Manifest> = None;
    let mut outcomes = Vec::new();
    let mut run = || -> Result<()> {
        for (i, &(stage, force)) in stages.iter().enumerate() {
            let written = write_stage(writer, stage, &Share::All, force, held.as_ref(), progress)?;
            if let Some(manifest) = written.manifest {
                let rewritten_later = stages[i + 1..].iter().any(|(later, _)| {
                    later
                        .outputs(&manifest)
                        .iter()
                        .any(|key| written.dropped.contains(key))
                });
                if rewritten_later {
                    held = Some(manifest);
                } else {
                    commit_manifest(writer.lock_held(), &manifest)?;
                    held = None;
                }
            }
            on_stage(&written.outcome)?;
            outcomes.push(written.outcome);
        }
        Ok(())
    };
    let result = run();
    let committed = match held.take() {
        Some(manifest) => commit_manifest(writer.lock_held(), &manifest).map(drop),
        None => Ok(()),
    };
    if result.is_err() || committed.is_err() {
        writer.fail();
    }
    result?;
    committed?;
    Ok(outcomes)
}

/// What [`write_stage`] did: its outcome, and unless it was skipped the
/// manifest to commit and the layers that manifest drops (derived from
/// what the stage rewrote, and not rewritten by it).
struct Written {
    outcome: StageOutcome,
    manifest: Option<terrabake_format::Manifest>,
    dropped: Vec<String>,
}

/// Runs `stage` against the committed asset, or against `held`, a
/// manifest an earlier stage of the same run wrote and has not committed.
fn write_stage(
    writer: &AssetWriter,
    stage: &dyn Stage,
    share: &Share,
    force: bool,
    held: Option<&terrabake_format::Manifest>,
    progress: Progress,
) -> Result<Written> {
    let dir = writer.dir();
    let _doing = crate::plumbing::interrupt::Doing::now(format!(
        "stage '{}' of {}",
        stage.name(),
        dir.display()
    ));
    let start = std::time::Instant::now();
    stage
        .check()
        .map_err(|e| crate::error::mark(crate::ErrorKind::Parameters, e))?;
    let opened = match held {
        Some(m) => Asset::open_uncommitted(dir, m.clone()),
        None => Asset::open(dir),
    };
    let params = stage.params();
    if !force {
        let done = opened
            .as_ref()
            .ok()
            .and_then(|a| already_done(a.manifest(), stage.name(), &params));
        if let Some(outputs) = done {
            return Ok(Written {
                outcome: StageOutcome {
                    stage: stage.name().into(),
                    skipped: true,
                    outputs,
                    seconds: 0.0,
                },
                manifest: None,
                dropped: Vec::new(),
            });
        }
    }
    let failed = || format!("{}: stage '{}' failed", dir.display(), stage.name());
    let (mut manifest, entries) = if stage.creates_asset() {
        drop(opened);
        let mut manifest = stage.create(dir, share, progress).with_context(failed)?;
        let entries = std::mem::take(&mut manifest.layers);
        (manifest, entries)
    } else {
        let asset = opened.with_context(|| format!("{}: cannot open asset", dir.display()))?;
        check_memory(stage, asset.manifest())?;
        let entries = stage
            .run(&asset, dir, share, progress)
            .with_context(failed)?;
        (asset.manifest().clone(), entries)
    };
    let outputs: Vec<String> = entries.iter().map(LayerEntry::key).collect();
    let declared = stage.outputs(&manifest);
    crate::error::ensure!(
        outputs == declared,
        "stage '{}' wrote {outputs:?}, not the {declared:?} it declares",
        stage.name()
    );
    let before: Vec<String> = manifest.layers.iter().map(LayerEntry::key).collect();
    drop_dependents(&mut manifest, stage.name(), &outputs);
    for entry in entries {
        manifest.upsert_layer(entry);
    }
    let dropped = before
        .into_iter()
        .filter(|key| !manifest.layers.iter().any(|l| &l.key() == key))
        .collect();
    put_record(
        &mut manifest,
        stage.name(),
        params,
        outputs.clone(),
        stage.inputs(),
    );
    Ok(Written {
        outcome: StageOutcome {
            stage: stage.name().into(),
            skipped: false,
            outputs,
            seconds: start.elapsed().as_secs_f64(),
        },
        manifest: Some(manifest),
        dropped,
    })
}

/// Refuses to run `stage` on an asset described by `m` when what it says
/// it holds at once ([`Stage::memory`]) is over its `--max-memory`, or
/// over the memory this machine has available: a clear error before any
/// allocation, not an abort in the middle of one.
fn check_memory(stage: &dyn Stage, m: &terrabake_format::Manifest) -> Result<()> {
    let Some(need) = stage.memory(m) else {
        return Ok(());
    };
    let what = format!(
        "stage '{}' on this {} x {} asset (tiles of {}; a tile row of it is {} MiB)",
        stage.name(),
        m.width,
        m.height,
        m.tile_size,
        (u64::from(m.width) * u64::from(m.tile_size) * 4) >> 20
    );
    if let Some(budget) = stage.max_memory() {
        crate::error::ensure!(
            need <= budget,
            "{what} holds about {} MiB at once, over --max-memory {} MiB; ingest with a smaller --tile, or raise --max-memory",
            need >> 20,
            budget >> 20
        );
    }
    if let Some(available) = crate::plumbing::resources::available_memory() {
        crate::error::ensure!(
            need <= available,
            "{what} holds about {} MiB at once, and {} MiB is available; ingest with a smaller --tile, or bake on a machine with more memory",
            need >> 20,
            available >> 20
        );
    }
    Ok(())
}

/// Drops, transitively, every other stage's record that read one of
/// `rewritten`, and the layers it wrote: they were derived from what is
/// about to change (the sky layers when the horizons are recomputed).
fn drop_dependents(manifest: &mut terrabake_format::Manifest, stage: &str, rewritten: &[String]) {
    let mut changed: Vec<String> = rewritten.to_vec();
    while let Some(i) = manifest
        .provenance
        .stages
        .iter()
        .position(|r| r.stage != stage && r.inputs.iter().any(|input| changed.contains(input)))
    {
        let record = manifest.provenance.stages.remove(i);
        manifest
            .layers
            .retain(|l| !record.outputs.contains(&l.key()) || rewritten.contains(&l.key()));
        changed.extend(record.outputs);
    }
}

/// Records a measurement of the asset that writes no layer (`terrabake
/// check`): one record named `name` replacing any earlier one, with
/// `inputs` so that rewriting any of them drops it, committed under the
/// writer lock.
pub(crate) fn record_measurement(
    dir: &Path,
    name: &str,
    params: serde_json::Value,
    inputs: Vec<String>,
) -> Result<()> {
    let writer = AssetWriter::open(dir, crate::stage::asset::Wait::Wait)?;
    record_measurement_in(&writer, name, params, inputs)
}

/// [`record_measurement`] under a writer the caller holds.
pub(crate) fn record_measurement_in(
    writer: &AssetWriter,
    name: &str,
    params: serde_json::Value,
    inputs: Vec<String>,
) -> Result<()> {
    let dir = writer.dir();
    let asset =
        Asset::open(dir).with_context(|| format!("{}: cannot open asset", dir.display()))?;
    let mut manifest = asset.manifest().clone();
    drop(asset);
    put_record(&mut manifest, name, params, Vec::new(), inputs);
    commit_manifest(writer.lock_held(), &manifest)?;
    Ok(())
}

/// Replaces the record of `stage` in `manifest` with one made now.
pub(crate) fn put_record(
    manifest: &mut terrabake_format::Manifest,
    stage: &str,
    params: serde_json::Value,
    outputs: Vec<String>,
    inputs: Vec<String>,
) {
    manifest.provenance.stages.retain(|r| r.stage != stage);
    manifest.provenance.stages.push(StageRecord {
        stage: stage.into(),
        params,
        tool: crate::tool_version(),
        finished_unix: unix_now(),
        outputs,
        inputs,
    });
}

/// Seconds since the Unix epoch (stage records).
pub(crate) fn unix_now() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// A layer of the stage: one element per post, tiles in the stage's codec.
pub(crate) fn post_layer(
    (name, stage): (&str, &str),
    elem: terrabake_format::ElemType,
    bands: u32,
    (w, h, ts): (usize, usize, usize),
    description: String,
    codec: terrabake_format::Codec,
) -> terrabake_format::LayerSpec {
    terrabake_format::LayerSpec {
        name: name.into(),
        level: 0,
        elem,
        bands,
        width: w as u32,
        height: h as u32,
        tile_size: ts as u32,
        codec,
        // What the tiles are padded with: NaN for f32 values, code 0
        // (nodata, or a zero count) for integers.
        fill_bits: if elem == terrabake_format::ElemType::F32 {
            u64::from(f32::NAN.to_bits())
        } else {
            0
        },
        stage: stage.into(),
        description,
    }
}

/// Memory budgets: bytes in the stage, MiB on the command line, in recipes
/// (`max_memory_mib`) and in the manifest record.
pub mod mib {
    use serde::{Deserialize, Deserializer, Serializer};

    /// The working memory a stage takes unless told (`--max-memory`, MiB):
    /// 8 GiB. [`STAGE_DEFAULT_BYTES`] is the same in bytes, for `Default`.
    pub const STAGE_DEFAULT: &str = "8192";
    pub const STAGE_DEFAULT_BYTES: u64 = 8192 << 20;

    /// `--max-memory MIB` as bytes.
    pub fn parse(s: &str) -> Result<u64, String> {
        match s.trim().parse::<u64>() {
            Ok(m) if m > 0 && m < 1 << 40 => Ok(m << 20),
            _ => Err(format!("{s:?} is not a positive number of MiB")),
        }
    }

    pub(crate) fn serialize<S: Serializer>(bytes: &u64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(*bytes as f64 / (1u64 << 20) as f64)
    }

    pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        let mib = f64::deserialize(d)?;
        if !(mib > 0.0 && mib < (1u64 << 40) as f64) {
            return Err(serde::de::Error::custom(format!(
                "{mib} is not a positive number of MiB"
            )));
        }
        Ok((mib * (1u64 << 20) as f64) as u64)
    }
}
