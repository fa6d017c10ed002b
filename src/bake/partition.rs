//! Partitioned bakes: one recipe cut into `N` independent parts that any
//! scheduler runs on any node (Slurm array tasks, Kubernetes indexed jobs,
//! `make -j`), and the join that makes them one asset without computing
//! anything twice. `docs/SCALE.md` is the long form.
//!
//! ```text
//!  bake --parts N --part I            (N processes, any order, any node)
//!    plan: every stage's Split, from its reach ──► this part's rows and bands
//!    ASSET.parts/part-I-of-N/         its own asset: the heights it needs,
//!                                     its share of every split stage
//!    ASSET.parts/part-I-of-N.json     written last: the part is complete
//!  assemble ASSET                     (once, after all parts)
//!    check every part (present, same recipe and source, checksums)
//!    adopt each chunk from the part that owns it ──► ASSET's layers
//!    commit the manifest once, then run the join's stages (pyramid, cones...)
//! ```
//!
//! **How each stage splits** ([`Stage::split`]). A stage that reads a
//! bounded distance (`Split::Rows`: ingest, bounded horizons, the sky
//! layers but the edge count) is cut into tile rows: part `I` owns tile
//! rows `T I / N .. T (I + 1) / N` of every such layer and computes them
//! (and the rows that a later split stage in the part reads around them)
//! from the heights within reach. A stage whose directions are independent
//! (`Split::Bands`: unbounded horizons) is cut into bands, each part
//! computing its bands over the whole DEM. Everything else, and every stage
//! that reads what a joined or band-split stage writes, runs at the join
//! (`Split::Join`: the pyramid, cones, the edge count).
//!
//! **Bit for bit.** A part computes its share with the same functions and
//! the same whole-DEM geometry as a bake on one machine (its own asset has
//! the whole grid; rows it does not need hold the fill value), and a
//! stage's declared reach promises that rows beyond it cannot change the
//! rows it owns (`tests/stage.rs` holds each stage to it). The join copies
//! stored chunks, so the assembled layers decode to exactly the values of
//! `terrabake bake` on one machine (`tests/parts.rs`, for N = 1, 2, 3, 7).
//!
//! **Idempotent and resumable.** A part's directory is an asset of its own
//! under its own writer lock: a part run again skips what it finished
//! (the stage records), a killed part's leftovers are reclaimed by the
//! next run, and the record `part-I-of-N.json` is written (renamed into
//! place) only once everything else is durable.

use std::ops::Range;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use terrabake_format::{
    Asset, LayerEntry, LayerSpec, LayerWriter, Manifest, Mmap, HEIGHT_LAYER, MANIFEST_FILE,
};

use crate::bake::recipe::Recipe;
use crate::error::bail;
use crate::plumbing::progress::Progress;
use crate::stage::asset::{AssetWriter, Wait};
use crate::stage::{run_share_in, run_stage_in, Share, Split, Stage, StageOutcome};
use crate::stages::ingest::HeightStats;

/// The most parts a bake may be cut into: far more than any scheduler's
/// array runs at once, and few enough that every message naming parts
/// stays short.
pub const MAX_PARTS: u32 = 65_536;

/// Part `index` of `count` (0-based).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Part {
    pub index: u32,
    pub count: u32,
}

impl Part {
    /// `--part I` of `--parts N`, refused unless `0 <= I < N`.
    pub fn new(index: u32, count: u32) -> crate::Result<Self> {
        if !(1..=MAX_PARTS).contains(&count) {
            bail!("--parts {count}: give 1 to {MAX_PARTS} parts");
        }
        if index >= count {
            bail!(
                "--part {index} is outside 0..{count}: parts are numbered from 0 to {} (--parts {count})",
                count - 1
            );
        }
        Ok(Self { index, count })
    }

    fn name(self) -> String {
        format!("part-{}-of-{}", self.index, self.count)
    }

    /// Tile rows `T I / N .. T (I + 1) / N` of `T`, as rows of posts of an
    /// `h`-row grid with tiles of `ts` rows.
    pub(crate) fn own_rows(self, h: usize, ts: usize) -> Range<usize> {
        let tiles = h.div_ceil(ts);
        let at = |i: u32| (tiles * i as usize / self.count as usize * ts).min(h);
        at(self.index)..at(self.index + 1)
    }
}

/// Where the parts of `asset` are written: `ASSET.parts/` beside it.
pub fn parts_dir(asset: &Path) -> PathBuf {
    let mut name = asset.file_name().unwrap_or_default().to_os_string();
    name.push(".parts");
    asset.with_file_name(name)
}

/// The part's record: what it baked, for the join to check. Written last.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PartRecord {
    part: u32,
    parts: u32,
    /// Everything the parts must agree on: the ingest's parameters (with
    /// the source's identity) and each stage's name, parameters and split.
    plan: serde_json::Value,
    /// The recipe as written, for the join's stages.
    recipe: String,
    /// Nodata posts and the height range over the rows this part owns.
    nodata: u64,
    height_range: Option<terrabake_format::manifest::HeightRange>,
    tool: String,
}

/// The recipe's stages with the split each takes in a partitioned bake of
/// a DEM described by `m` (the same for every part).
struct Plan {
    stages: Vec<(Box<dyn Stage>, Split)>,
}

impl Plan {
    fn new(recipe: &Recipe, m: &Manifest) -> Result<Self> {
        let mut stages: Vec<(Box<dyn Stage>, Split)> = Vec::new();
        for stage in recipe.resolve_stages()? {
            let mut split = stage.split(m);
            for input in stage.inputs() {
                // The latest earlier stage that writes this input (none:
                // the heights, which every part ingests as it needs them).
                let producer = stages
                    .iter()
                    .rev()
                    .find(|(s, _)| s.outputs(m).contains(&input))
                    .map(|(_, split)| *split);
                split = match (split, producer) {
                    (_, Some(Split::Join)) => Split::Join,
                    // Rows need every band of their input; bands need
                    // every row of it.
                    (Split::Rows { .. }, Some(Split::Bands)) => Split::Join,
                    (Split::Bands, Some(_)) => Split::Join,
                    (split, _) => split,
                };
            }
            stages.push((stage, split));
        }
        Ok(Self { stages })
    }

    /// What the parts must agree on, with the ingest's parameters: the
    /// source by its content, not by the path or time it had in each part.
    fn fingerprint(&self, mut ingest: serde_json::Value) -> serde_json::Value {
        if let Some(fields) = ingest.as_object_mut() {
            for location in crate::stages::ingest::SOURCE_LOCATION_FIELDS {
                fields.remove(location);
            }
        }
        serde_json::json!({
            "ingest": ingest,
            "stages": self.stages.iter().map(|(s, split)| serde_json::json!({
                "name": s.name(),
                "params": s.params(),
                "split": split,
            })).collect::<Vec<_>>(),
        })
    }

    /// For `part` of a DEM described by `m`: the rows each split stage
    /// computes (its own rows and what later split stages read around
    /// them) and the rows of heights the part must ingest.
    fn rows(&self, m: &Manifest, part: Part) -> (Vec<Range<usize>>, Range<usize>) {
        let (h, ts) = (m.height as usize, m.tile_size as usize);
        let own = part.own_rows(h, ts);
        let all = 0..h;
        // Exact rows, not whole tiles: a part reads no more of the DEM than
        // the reach asks (a tile it fills partly is not one it owns).
        let widen = |r: &Range<usize>, halo: u32| {
            if r.is_empty() {
                return r.clone();
            }
            r.start.saturating_sub(halo as usize)..(r.end + halo as usize).min(h)
        };
        let hull = |a: Range<usize>, b: Range<usize>| match (a.is_empty(), b.is_empty()) {
            (true, _) => b,
            (_, true) => a,
            _ => a.start.min(b.start)..a.end.max(b.end),
        };
        let n = self.stages.len();
        let mut computes: Vec<Range<usize>> = vec![0..0; n];
        for j in (0..n).rev() {
            let (stage, split) = &self.stages[j];
            computes[j] = match split {
                Split::Join => 0..0,
                Split::Bands => all.clone(),
                Split::Rows { .. } => {
                    let outputs = stage.outputs(m);
                    let mut need = own.clone();
                    for (k, (later, later_split)) in self.stages.iter().enumerate().skip(j + 1) {
                        if let Split::Rows { halo } = later_split {
                            if later.inputs().iter().any(|i| outputs.contains(i)) {
                                need = hull(need, widen(&computes[k], *halo));
                            }
                        }
                    }
                    need
                }
            };
        }
        let height_key = format!("{HEIGHT_LAYER}@0");
        let mut heights = own.clone();
        for ((stage, split), rows) in self.stages.iter().zip(&computes) {
            if stage.inputs().contains(&height_key) {
                heights = match split {
                    Split::Rows { halo } => hull(heights, widen(rows, *halo)),
                    Split::Bands => all.clone(),
                    Split::Join => heights,
                };
            }
        }
        (computes, heights)
    }
}

/// Bakes `part` of `recipe` for `src` into `ASSET.parts/` (never touching
/// `asset` itself). Returns what each stage did; a part already complete
/// with this plan does nothing.
pub fn bake_part(
    src: &Path,
    asset: &Path,
    recipe: &Recipe,
    part: Part,
    wait: Wait,
    progress: Progress,
) -> crate::Result<Vec<StageOutcome>> {
    // The work in anyhow, its causes kept; the kind at the surface.
    let run = move || -> Result<Vec<StageOutcome>> {
        if recipe.plan.is_some() {
            bail!(
                "{}: a recipe with a [plan] bakes on one machine (the plan measures the whole scene); run `terrabake plan`, then write the stages it chooses into the recipe to bake it in parts",
                recipe.path.display()
            );
        }
        let (ingest, m) = recipe.describe(src)?;
        let plan = Plan::new(recipe, &m)?;
        let fingerprint = plan.fingerprint(ingest.params());
        let parts = parts_dir(asset);
        std::fs::create_dir_all(&parts)
            .with_context(|| format!("{}: cannot create the parts directory", parts.display()))?;
        let dir = parts.join(part.name());
        let record_path = parts.join(format!("{}.json", part.name()));
        // Every chunk checksummed: a part whose files were damaged since is
        // baked again, not trusted.
        let intact = || Asset::open(&dir).is_ok_and(|a| a.verify().problems.is_empty());
        if read_record(&record_path).is_ok_and(|r| r.plan == fingerprint) && intact() {
            return Ok(Vec::new());
        }
        // From here on the part is unfinished until its record is back.
        match std::fs::remove_file(&record_path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("{}: cannot remove", record_path.display()))
            }
            _ => {}
        }
        let (computes, heights) = plan.rows(&m, part);
        let writer = AssetWriter::create(&dir, wait)?;
        if dir.join(MANIFEST_FILE).exists() && !intact() {
            // Damaged: nothing in it is kept (the next commit reclaims its files).
            std::fs::remove_file(dir.join(MANIFEST_FILE))
                .with_context(|| format!("{}: cannot reset a damaged part", dir.display()))?;
        }
        let mut outcomes = vec![run_share_in(
            &writer,
            &ingest,
            &Share::Rows(heights),
            false,
            progress,
        )?];
        for ((stage, split), rows) in plan.stages.iter().zip(computes) {
            let share = match split {
                Split::Join => continue,
                Split::Rows { .. } => Share::Rows(rows),
                Split::Bands => Share::Bands {
                    part: part.index,
                    parts: part.count,
                },
            };
            outcomes.push(run_share_in(
                &writer,
                stage.as_ref(),
                &share,
                false,
                progress,
            )?);
        }
        // The part's own asset says which part it is: a directory copied
        // over another part's is refused at the join, whatever its record says.
        crate::stage::record_measurement_in(
            &writer,
            PART_RECORD,
            identity(part, &fingerprint),
            vec![format!("{HEIGHT_LAYER}@0")],
        )?;
        let stats = own_height_stats(&Asset::open(&dir)?, part)?;
        drop(writer);
        write_record(
            &record_path,
            &PartRecord {
                part: part.index,
                parts: part.count,
                plan: fingerprint,
                recipe: recipe.text.clone(),
                nodata: stats.nodata,
                height_range: stats.range(),
                tool: crate::tool_version(),
            },
        )?;
        Ok(outcomes)
    };
    Ok(run()?)
}

/// The name of the record, in a part's own manifest, of which part it is.
const PART_RECORD: &str = "part";

/// What a part's own manifest records of it ([`PART_RECORD`]).
fn identity(part: Part, fingerprint: &serde_json::Value) -> serde_json::Value {
    serde_json::json!({ "part": part.index, "parts": part.count, "plan": fingerprint })
}

/// Nodata posts and the height range over the rows `part` owns, read from
/// its asset's heights.
fn own_height_stats(baked: &Asset<Mmap>, part: Part) -> Result<HeightStats> {
    let m = baked.manifest();
    let own = part.own_rows(m.height as usize, m.tile_size as usize);
    let mut stats = HeightStats::default();
    let height = baked.height()?;
    let w = m.width as usize;
    // A band of rows at a time: a part of a large DEM is not held whole.
    let rows = ((4 << 20) / w.max(1)).clamp(1, own.len().max(1));
    let mut z = vec![0f32; rows * w];
    for y0 in own.clone().step_by(rows) {
        let n = rows.min(own.end - y0) * w;
        height.read_rows_f32(0, y0 as u32, &mut z[..n])?;
        stats.add(&z[..n]);
    }
    Ok(stats)
}

/// Where two JSON values differ, as dotted paths (`ingest.source_xxh3`),
/// for a message that says which setting two parts disagree on.
fn json_differences(a: &serde_json::Value, b: &serde_json::Value, at: &str) -> Vec<String> {
    use serde_json::Value;
    let key = |k: &str| {
        if at.is_empty() {
            k.to_string()
        } else {
            format!("{at}.{k}")
        }
    };
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter()
                .flat_map(|k| {
                    let (va, vb) = (x.get(k), y.get(k));
                    match (va, vb) {
                        (Some(va), Some(vb)) => json_differences(va, vb, &key(k)),
                        _ => vec![key(k)],
                    }
                })
                .collect()
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .flat_map(|(i, (va, vb))| json_differences(va, vb, &key(&i.to_string())))
            .collect(),
        _ if a == b => Vec::new(),
        _ => vec![at.to_string()],
    }
}

fn read_record(path: &Path) -> Result<PartRecord> {
    let bytes = terrabake_format::fsio::read_regular(path, 1 << 24)
        .with_context(|| format!("{}: cannot read the part's record", path.display()))?;
    serde_json::from_slice(&bytes)
        .with_context(|| format!("{}: not a part record of this terrabake", path.display()))
}

/// Writes `record` to `path` durably and at once (a temporary renamed).
fn write_record(path: &Path, record: &PartRecord) -> Result<()> {
    use std::io::Write;
    let (mut file, tmp) = terrabake_format::fsio::create_temp(path)
        .with_context(|| format!("{}: cannot create", path.display()))?;
    let written = file
        .write_all(&serde_json::to_vec_pretty(record)?)
        .and_then(|()| file.sync_all())
        .and_then(|()| std::fs::rename(&tmp, path))
        .and_then(|()| terrabake_format::fsio::sync_dir(path.parent().unwrap_or(Path::new("."))));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.with_context(|| format!("{}: cannot write the part's record", path.display()))
}

/// The parts found for `asset`, checked: all `N` present and complete,
/// one partition, one plan. Errors name the parts.
fn check_parts(asset: &Path) -> Result<Vec<(PartRecord, Asset<Mmap>)>> {
    let dir = parts_dir(asset);
    let entries = std::fs::read_dir(&dir).with_context(|| {
        format!(
            "{}: no parts to assemble (run `terrabake bake SRC -o {} --recipe R --parts N --part I` for every I first)",
            dir.display(),
            asset.display()
        )
    })?;
    let mut found: Vec<Part> = entries
        .flatten()
        .filter_map(|e| parse_part_name(&e.file_name().to_string_lossy()))
        .collect();
    found.sort_by_key(|p| (p.count, p.index));
    found.dedup();
    let Some(first) = found.first().copied() else {
        bail!(
            "{}: no parts to assemble (run `terrabake bake SRC -o {} --recipe R --parts N --part I` for every I first)",
            dir.display(),
            asset.display()
        );
    };
    if let Some(other) = found.iter().find(|p| p.count != first.count) {
        bail!(
            "{}: parts of two partitions: {} (--parts {}) and {} (--parts {}); remove the stale ones and assemble again",
            dir.display(),
            first.name(),
            first.count,
            other.name(),
            other.count
        );
    }
    let n = first.count;
    let mut parts = Vec::new();
    let mut missing = Vec::new();
    for index in 0..n {
        let part = Part { index, count: n };
        let record_path = dir.join(format!("{}.json", part.name()));
        if !record_path.exists() {
            missing.push(index);
            continue;
        }
        let record = read_record(&record_path)?;
        if (record.part, record.parts) != (index, n) {
            bail!(
                "{}: records part {} of {}, not {}",
                record_path.display(),
                record.part,
                record.parts,
                part.name()
            );
        }
        let baked = Asset::open(dir.join(part.name()))
            .with_context(|| format!("{}: damaged; bake it again", part.name()))?;
        let claims = crate::stage::record_of(baked.manifest(), PART_RECORD).map(|r| &r.params);
        if claims != Some(&identity(part, &record.plan)) {
            bail!(
                "{}: its asset is not the {} its record names (a copy of another part, or baked with another plan); bake it again",
                dir.join(part.name()).display(),
                part.name()
            );
        }
        // The join commits counts it has read, not what a record claims.
        let stats = own_height_stats(&baked, part)
            .with_context(|| format!("{}: damaged; bake it again", part.name()))?;
        if (stats.nodata, stats.range()) != (record.nodata, record.height_range) {
            bail!(
                "{}: records {} nodata posts and heights {:?}, its rows hold {} and {:?}; bake it again",
                record_path.display(),
                record.nodata,
                record.height_range,
                stats.nodata,
                stats.range()
            );
        }
        parts.push((record, baked));
    }
    if !missing.is_empty() {
        let missing = index_ranges(&missing);
        bail!(
            "{}: part {missing} of {n} missing or unfinished (no record); nothing was assembled. Run `terrabake bake SRC -o {} --recipe R --parts {n} --part I` for I = {missing}",
            dir.display(),
            asset.display(),
        );
    }
    let plan = &parts[0].0.plan;
    if let Some((record, _)) = parts.iter().find(|(r, _)| &r.plan != plan) {
        bail!(
            "{}: part-{}-of-{n} was baked with a different recipe or source than part-0-of-{n} ({} differ); bake it again with the same ones",
            dir.display(),
            record.part,
            json_differences(plan, &record.plan, "").join(", ")
        );
    }
    Ok(parts)
}

/// Sorted indices as runs (`0-3, 7, 9, 10, 12-999999`): a message about a million
/// missing parts stays one short line.
fn index_ranges(indices: &[u32]) -> String {
    let mut runs: Vec<(u32, u32)> = Vec::new();
    for &i in indices {
        match runs.last_mut() {
            Some((_, end)) if *end + 1 == i => *end = i,
            _ => runs.push((i, i)),
        }
    }
    let shown: Vec<String> = runs
        .iter()
        .take(8)
        .map(|&(a, b)| match b - a {
            0 => a.to_string(),
            1 => format!("{a}, {b}"),
            _ => format!("{a}-{b}"),
        })
        .collect();
    let more = runs.len().saturating_sub(shown.len());
    if more > 0 {
        format!("{} and {more} more runs", shown.join(", "))
    } else {
        shown.join(", ")
    }
}

fn parse_part_name(name: &str) -> Option<Part> {
    let rest = name.strip_prefix("part-")?.strip_suffix(".json")?;
    let (i, n) = rest.split_once("-of-")?;
    Part::new(i.parse().ok()?, n.parse().ok()?).ok()
}

/// Joins the parts of `asset` (`ASSET.parts/`) into it: checks them all,
/// adopts each layer's chunks from the part that computed them, commits
/// one manifest, runs the stages left to the join, and removes the parts
/// (unless `keep`). Nothing is committed when a part is missing or bad.
///
/// Idempotent: everything happens under the asset's writer lock, taken
/// before the parts are read, and the commit records the join
/// ([`ASSEMBLE_RECORD`]). Run again, after a success or a kill at any
/// point, it finishes what is left (the join's stages, the parts' removal)
/// or says the asset is assembled; a second assemble waiting on the first
/// finds the join done.
pub fn assemble(
    asset: &Path,
    keep: bool,
    wait: Wait,
    progress: Progress,
) -> crate::Result<Vec<StageOutcome>> {
    // The work in anyhow, its causes kept; the kind at the surface.
    let run = move || -> Result<Vec<StageOutcome>> {
        let writer = AssetWriter::create(asset, wait)?;
        let joined = joined_plan(asset);
        let dir = parts_dir(asset);
        let result = (|| -> Result<Vec<StageOutcome>> {
            remove_removed_parts(asset)?;
            if joined.is_some() && !dir.exists() {
                return Ok(vec![StageOutcome {
                    stage: "assemble".into(),
                    skipped: true,
                    outputs: Vec::new(),
                    seconds: 0.0,
                }]);
            }
            let parts = check_parts(asset)?;
            let n = parts.len();
            let first = &parts[0];
            let recipe = Recipe::parse(
                &dir.join(format!("part-0-of-{n}.json")),
                first.0.recipe.clone(),
            )?;
            let m = first.1.manifest();
            let plan = Plan::new(&recipe, m)?;
            let ingest =
                crate::stage::record_of(m, "ingest").context("part 0 has no ingest record")?;
            if plan.fingerprint(ingest.params.clone()) != first.0.plan {
                bail!(
                    "{}: the parts' records and their assets disagree; bake the parts again",
                    dir.display()
                );
            }
            let identity = joined_identity(n, &first.0.plan);
            if joined.as_ref() != Some(&identity) {
                commit_parts(&writer, &parts, &plan, identity, progress)?;
            }
            let mut outcomes = Vec::new();
            for (stage, split) in &plan.stages {
                if *split == Split::Join {
                    outcomes.push(run_stage_in(&writer, stage.as_ref(), false, progress)?);
                }
            }
            Ok(outcomes)
        })();
        if result.is_err() {
            writer.fail();
        }
        let outcomes = result?;
        if !keep {
            remove_parts(asset)?;
        }
        drop(writer);
        Ok(outcomes)
    };
    Ok(run()?)
}

/// The record, in an assembled asset's manifest, of the join that made it.
const ASSEMBLE_RECORD: &str = "assemble";

/// What [`ASSEMBLE_RECORD`] holds: how many parts, and their plan.
fn joined_identity(parts: usize, plan: &serde_json::Value) -> serde_json::Value {
    serde_json::json!({ "parts": parts, "plan": plan })
}

/// The join the committed asset records, if it was assembled.
fn joined_plan(asset: &Path) -> Option<serde_json::Value> {
    let opened = Asset::open(asset).ok()?;
    crate::stage::record_of(opened.manifest(), ASSEMBLE_RECORD).map(|r| r.params.clone())
}

/// Where the parts go while they are removed: one rename takes them out
/// of `ASSET.parts/` at once, so a kill during the removal leaves either
/// every part or none under that name.
fn removed_parts_dir(asset: &Path) -> PathBuf {
    let mut name = parts_dir(asset)
        .file_name()
        .unwrap_or_default()
        .to_os_string();
    name.push(format!(".removed-{}", std::process::id()));
    asset.with_file_name(name)
}

/// Removes `ASSET.parts/`, first renamed out of the way.
fn remove_parts(asset: &Path) -> Result<()> {
    let (dir, gone) = (parts_dir(asset), removed_parts_dir(asset));
    match std::fs::rename(&dir, &gone) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        renamed => renamed.and_then(|()| std::fs::remove_dir_all(&gone)),
    }
    .with_context(|| format!("{}: cannot remove", dir.display()))
}

/// Removes what a killed removal left (`ASSET.parts.removed-<pid>/`); no
/// other name is touched.
fn remove_removed_parts(asset: &Path) -> Result<()> {
    let parent = match asset.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let prefix = format!(
        "{}.removed-",
        parts_dir(asset)
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
    );
    for entry in std::fs::read_dir(parent).into_iter().flatten().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let ours = name
            .strip_prefix(&prefix)
            .is_some_and(|pid| !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()));
        if ours && entry.file_type().is_ok_and(|t| t.is_dir()) {
            std::fs::remove_dir_all(entry.path())
                .with_context(|| format!("{}: cannot remove", entry.path().display()))?;
        }
    }
    Ok(())
}

/// Adopts the layers the parts computed into the asset and commits its
/// manifest: the asset as one machine's bake has it after the split stages.
fn commit_parts(
    writer: &AssetWriter,
    parts: &[(PartRecord, Asset<Mmap>)],
    plan: &Plan,
    identity: serde_json::Value,
    progress: Progress,
) -> Result<()> {
    let n = parts.len() as u32;
    let m = parts[0].1.manifest();
    let (h, ts) = (m.height as usize, m.tile_size as usize);
    let row_owner = owners(n, h.div_ceil(ts), |part| {
        let rows = part.own_rows(h, ts);
        rows.start / ts..rows.end.div_ceil(ts)
    });
    // The layers the parts computed, each with how its chunks are owned.
    let mut adopted = vec![(format!("{HEIGHT_LAYER}@0"), Split::Rows { halo: 0 })];
    for (stage, split) in &plan.stages {
        if *split != Split::Join {
            adopted.extend(stage.outputs(m).into_iter().map(|key| (key, *split)));
        }
    }
    let mut entries = Vec::new();
    for (key, split) in &adopted {
        let (name, level) = key.rsplit_once('@').context("layer key")?;
        let level: u32 = level.parse()?;
        let layers: Vec<_> = parts
            .iter()
            .map(|(r, a)| {
                a.layer(name, level)
                    .with_context(|| format!("part-{}-of-{n}: damaged; bake it again", r.part))
            })
            .collect::<Result<_>>()?;
        entries.push(adopt(
            writer.dir(),
            &layers,
            *split,
            &row_owner,
            n,
            progress,
        )?);
    }
    let mut manifest = m.clone();
    let stats = parts
        .iter()
        .map(|(r, _)| HeightStats::from_range(r.nodata, r.height_range))
        .fold(HeightStats::default(), HeightStats::merge);
    manifest.nodata.count = stats.nodata;
    manifest.height_range = stats.range();
    manifest.layers = entries;
    manifest.retired = Vec::new();
    manifest.provenance.stages.retain(|r| {
        r.stage == "ingest"
            || plan
                .stages
                .iter()
                .any(|(s, split)| s.name() == r.stage && *split != Split::Join)
    });
    crate::stage::put_record(
        &mut manifest,
        ASSEMBLE_RECORD,
        identity,
        Vec::new(),
        vec![format!("{HEIGHT_LAYER}@0")],
    );
    terrabake_format::commit_manifest(writer.lock_held(), &manifest)?;
    Ok(())
}

/// One layer of the assembled asset: each chunk copied, checksummed and
/// undecoded, from the part that owns it (by tile row or by band).
fn adopt(
    dir: &Path,
    layers: &[&terrabake_format::Layer<Mmap>],
    split: Split,
    row_owner: &[usize],
    n: u32,
    progress: Progress,
) -> Result<LayerEntry> {
    let first = layers[0];
    let e = first.entry();
    let spec = LayerSpec {
        name: e.name.clone(),
        level: e.level,
        elem: e.elem,
        bands: e.bands,
        width: e.width,
        height: e.height,
        tile_size: e.tile_size,
        codec: e.codec,
        fill_bits: first.fill_bits(),
        stage: e.stage.clone(),
        description: e.description.clone(),
    };
    fn layout(l: &terrabake_format::Layer<Mmap>) -> (crate::stage::same::Meaning<'_>, u32, u64) {
        (
            crate::stage::same::meaning(l.entry()),
            l.tile_size(),
            l.fill_bits(),
        )
    }
    if layers[1..].iter().any(|&l| layout(l) != layout(first)) {
        bail!(
            "layer {}: the parts disagree on its shape; bake them again",
            e.key()
        );
    }
    if split != Split::Bands && row_owner.len() != first.tiles_y() as usize {
        bail!(
            "layer {}: split by rows, but not on the heights' tile rows",
            e.key()
        );
    }
    let (tx, ty) = (first.tiles_x() as u64, first.tiles_y() as u64);
    let mut writer = LayerWriter::create(dir, spec)?;
    let bar = progress.bar(
        writer.spec().chunk_count(),
        &format!("assemble {}", e.key()),
        "chunks",
    );
    let band_owner = owners(n, e.bands as usize, |part| {
        Share::Bands {
            part: part.index,
            parts: part.count,
        }
        .bands(e.bands as usize)
    });
    for chunk in 0..writer.spec().chunk_count() {
        let (band, row) = ((chunk / (tx * ty)) as usize, ((chunk / tx) % ty) as usize);
        let owner = match split {
            Split::Rows { .. } => row_owner[row],
            Split::Bands => band_owner[band],
            Split::Join => unreachable!("joined stages are not adopted"),
        };
        let stored = layers[owner].stored_chunk(chunk).with_context(|| {
            format!("part-{owner}-of-{n} is damaged; bake it again (the same command) and assemble")
        })?;
        writer.adopt_at(chunk, stored)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut entry = writer.finish()?;
    entry.quantization = e.quantization;
    entry.band_azimuths = e.band_azimuths.clone();
    entry.features = e.features.clone();
    Ok(entry)
}

/// For each of `len` tile rows or bands, the part of `n` whose share
/// (`share_of`) holds it.
fn owners(n: u32, len: usize, share_of: impl Fn(Part) -> Range<usize>) -> Vec<usize> {
    let mut owner = vec![0; len];
    for index in 0..n {
        for i in share_of(Part { index, count: n }) {
            owner[i] = index as usize;
        }
    }
    owner
}
