//! Ingest: a DEM source becomes a new asset whose one layer is `height`
//! (f32 metres, NaN for nodata), streamed one tile row at a time. Peak memory
//! is the source's own unit (a strip or tile row) plus one output tile row
//! (`width x tile_size` f32) and its encoded tiles, whatever the DEM's area.
//!
//! Ingest creates an asset or replaces one: the new height layer and the new
//! manifest are written beside the old ones and the manifest's rename is the
//! commit, so an interrupted ingest leaves the old asset intact (and a new
//! directory that it created is removed). It runs under the asset's writer
//! lock ([`AssetWriter`]).

use std::fs;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use anyhow::{Context, Result};
use serde::Serialize;
use terrabake_format::manifest::{
    CellSize, HeightRange, Nodata, Provenance, Vertical, HEIGHT_LAYER,
};
use terrabake_format::{
    Codec, ElemType, LayerEntry, LayerSpec, LayerWriter, Manifest, FORMAT_VERSION,
};

use crate::error::bail;
use crate::io::source::{self, parse_nodata, ByteOrder, HeightMapping, RawSampleType, RawSpec};
use crate::plumbing::progress::Progress;
use crate::stage::asset::{AssetWriter, Wait};
use crate::stage::{run_stage_in, Share, Stage};
use crate::terrain::tiling::push_tile_row;

/// Default tile edge: 256 x 256 f32 = 256 KiB, a good unit for mmap paging,
/// zstd and GPU upload alike.
pub const DEFAULT_TILE: u32 = 256;

/// Ingest's parameters: `terrabake ingest` flattens them, a recipe's
/// `[ingest]` table deserialises into them (unknown keys refused), and the
/// manifest records their serialisation with the source's identity.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize, clap::Args)]
#[serde(deny_unknown_fields, default)]
pub struct IngestOptions {
    /// Tile edge in posts: a power of two from 16 to 4096.
    #[arg(long = "tile", default_value_t = DEFAULT_TILE, value_parser = crate::stage::args::parse_tile)]
    #[serde(rename = "tile")]
    pub tile_size: u32,
    /// Nodata value of the source, overriding what the file says.
    #[arg(long, allow_hyphen_values = true)]
    pub nodata: Option<f64>,
    /// Post spacing in metres, DX or DX,DY (default: from the georeferencing, else 1 m).
    #[arg(long, value_parser = crate::stage::args::parse_cell_size)]
    pub cell_size: Option<(f64, f64)>,
    /// Heights are `sample * z_scale + z_offset` (for PNG heightmaps, say).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true, value_parser = crate::stage::args::parse_finite)]
    pub z_scale: f64,
    /// Metres added to every height after --z-scale (see there).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = crate::stage::args::parse_finite)]
    pub z_offset: f64,
    /// Tile codec: `raw` (read in place from the mapping) or `zstd` (smaller; decompressed into a cache).
    #[arg(long, value_parser = crate::stage::args::parse_codec, default_value = "raw")]
    pub codec: Codec,
    /// Shape of a headerless raster, WIDTHxHEIGHT.
    #[arg(long, value_parser = crate::stage::args::parse_size, requires = "raw_type")]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub raw_shape: Option<(u32, u32)>,
    /// Sample type of a headerless raster.
    #[arg(long, value_enum, requires = "raw_shape")]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub raw_type: Option<RawSampleType>,
    /// Byte order of a headerless raster.
    #[arg(long, value_enum, default_value = "le")]
    pub byte_order: ByteOrder,
    /// Memory the source's reader may hold at once, MiB. Ingest streams, so
    /// only a DEM stored as a few huge strips or tiles (or an OpenEXR, read
    /// whole) comes near it; such a source is refused from its header. Not
    /// a parameter of the result, so not recorded.
    #[arg(long = "max-memory", value_name = "MIB", default_value = DEFAULT_INGEST_MIB, value_parser = crate::stage::mib::parse)]
    #[serde(
        rename = "max_memory_mib",
        with = "crate::stage::mib",
        skip_serializing
    )]
    pub max_memory: u64,
}

impl IngestOptions {
    /// Defaults for a headerless raster laid out as `spec`.
    pub fn for_raw(spec: RawSpec) -> Self {
        Self {
            raw_shape: Some((spec.width, spec.height)),
            raw_type: Some(spec.sample),
            byte_order: spec.order,
            ..Self::default()
        }
    }

    /// The headerless raster's layout, when one was given.
    pub fn raw(&self) -> Option<RawSpec> {
        let ((width, height), sample) = (self.raw_shape?, self.raw_type?);
        Some(RawSpec {
            width,
            height,
            sample,
            order: self.byte_order,
        })
    }
}

/// Default of [`IngestOptions::max_memory`]: 1 GiB. Ingest streams, so
/// only a source cut into huge strips or tiles (or an EXR) comes near it.
pub const DEFAULT_INGEST_MEMORY: u64 = 1 << 30;
/// [`DEFAULT_INGEST_MEMORY`] as `--max-memory` gives it, MiB.
pub const DEFAULT_INGEST_MIB: &str = "1024";

impl Default for IngestOptions {
    fn default() -> Self {
        Self {
            tile_size: DEFAULT_TILE,
            nodata: None,
            cell_size: None,
            z_scale: 1.0,
            z_offset: 0.0,
            codec: Codec::Raw,
            raw_shape: None,
            raw_type: None,
            byte_order: ByteOrder::Le,
            max_memory: DEFAULT_INGEST_MEMORY,
        }
    }
}

/// The parameters recorded for ingest: the options plus the source's
/// identity, so that `bake` can tell whether an existing asset already is
/// this ingest, and the parts of a partitioned bake that they read one
/// DEM. The identity is the content (`source_xxh3`, a hash of the whole
/// file), besides its path, length and modification time: a file replaced
/// by another of the same length, its time set back, is another source.
pub(crate) fn ingest_params(src: &Path, opts: &IngestOptions) -> Result<serde_json::Value> {
    let meta = fs::metadata(src).with_context(|| format!("{}: cannot read", src.display()))?;
    let mtime = meta
        .modified()
        .ok()
        .and_then(|t| t.duration_since(SystemTime::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_secs());
    let mut params = serde_json::to_value(opts)?;
    params["source"] = src.display().to_string().into();
    params["source_len"] = meta.len().into();
    params["source_mtime"] = mtime.into();
    params["source_xxh3"] = source_hash(src, &meta)?.into();
    Ok(params)
}

/// The fields of [`ingest_params`] that name where the source was, not
/// what it holds: the same file as `dem.tif` and as `/data/dem.tif`, or
/// copied with a new time, is the same source.
pub const SOURCE_LOCATION_FIELDS: [&str; 2] = ["source", "source_mtime"];

/// The xxh3 of the whole file `src`, read once per process and file (a
/// bake asks for its ingest's parameters several times): one sequential
/// read, cheaper than the ingest that follows it.
fn source_hash(src: &Path, meta: &fs::Metadata) -> Result<String> {
    use std::collections::HashMap;
    use std::io::Read;
    use std::os::unix::fs::MetadataExt;
    use std::sync::Mutex;
    type Key = (u64, u64, u64, i64, i64, i64, i64);
    static HASHES: Mutex<Option<HashMap<Key, String>>> = Mutex::new(None);
    // Any change to the file changes its ctime, `touch -d` included.
    let key = (
        meta.dev(),
        meta.ino(),
        meta.len(),
        meta.mtime(),
        meta.mtime_nsec(),
        meta.ctime(),
        meta.ctime_nsec(),
    );
    let cached = |h: &Mutex<Option<HashMap<Key, String>>>| {
        h.lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
            .and_then(|m| m.get(&key).cloned())
    };
    if let Some(hash) = cached(&HASHES) {
        return Ok(hash);
    }
    let mut file = fs::File::open(src)
        .with_context(|| format!("{}: cannot read the source", src.display()))?;
    let mut hasher = xxhash_rust::xxh3::Xxh3::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file
            .read(&mut buf)
            .with_context(|| format!("{}: cannot read the source", src.display()))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    let hash = format!("{:016x}", hasher.digest());
    HASHES
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .get_or_insert_with(HashMap::new)
        .insert(key, hash.clone());
    Ok(hash)
}

/// The ingest stage: `src` read with `options` into a new asset's `height`
/// layer.
#[derive(Debug, Clone, PartialEq)]
pub struct IngestStage {
    pub src: PathBuf,
    pub options: IngestOptions,
}

impl Stage for IngestStage {
    fn name(&self) -> &'static str {
        "ingest"
    }

    /// The options and the source's identity ([`ingest_params`]), so that
    /// `bake` can tell whether an asset already is this ingest.
    /// ([`Stage::check`] has made sure the source can be read.)
    fn params(&self) -> serde_json::Value {
        ingest_params(&self.src, &self.options).unwrap_or_default()
    }

    fn inputs(&self) -> Vec<String> {
        Vec::new()
    }

    fn outputs(&self, _: &Manifest) -> Vec<String> {
        vec![format!("{HEIGHT_LAYER}@0")]
    }

    /// Each tile row of heights is its own rows of the source.
    fn reach(&self, _: &Manifest) -> crate::stage::Reach {
        crate::stage::Reach::Posts(0)
    }

    fn check(&self) -> crate::Result<()> {
        check_options(&self.options)?;
        ingest_params(&self.src, &self.options)?;
        Ok(())
    }

    fn creates_asset(&self) -> bool {
        true
    }

    /// Never called: the runner calls [`Stage::create`] for a stage that
    /// creates the asset.
    fn run(
        &self,
        _: &terrabake_format::Asset<terrabake_format::Mmap>,
        _: &Path,
        _: &Share,
        _: Progress,
    ) -> crate::Result<Vec<LayerEntry>> {
        bail!("ingest creates an asset: it runs through Stage::create")
    }

    /// Rows outside the share are not read (but for PNG, which has no
    /// index) and hold NaN, counted as nodata.
    fn create(&self, dir: &Path, share: &Share, progress: Progress) -> crate::Result<Manifest> {
        Ok(write_heights(
            dir,
            &self.src,
            &self.options,
            share,
            progress,
        )?)
    }
}

/// Ingests `src` into the asset directory `asset_dir` (waiting for another
/// writer, if one holds it) and returns the committed manifest.
pub fn ingest(
    src: &Path,
    asset_dir: &Path,
    opts: &IngestOptions,
    progress: Progress,
) -> crate::Result<Manifest> {
    let stage = IngestStage {
        src: src.to_path_buf(),
        options: opts.clone(),
    };
    stage.create_asset(asset_dir, Wait::Wait, progress)
}

impl IngestStage {
    /// Runs the ingest into the asset directory `asset_dir` under its
    /// writer lock (waiting for another writer unless `wait` says not) and
    /// returns the committed manifest.
    pub fn create_asset(
        &self,
        asset_dir: &Path,
        wait: Wait,
        progress: Progress,
    ) -> crate::Result<Manifest> {
        let writer = AssetWriter::create(asset_dir, wait)?;
        run_stage_in(&writer, self, true, progress)?;
        Ok(terrabake_format::Asset::open(asset_dir)?.manifest().clone())
    }
}

fn check_options(opts: &IngestOptions) -> Result<()> {
    if !opts.tile_size.is_power_of_two() || !(16..=4096).contains(&opts.tile_size) {
        bail!(
            "--tile {} is not a power of two between 16 and 4096",
            opts.tile_size
        );
    }
    Ok(())
}

/// Writes the height layer of `src` into `asset_dir` and returns the new
/// asset's manifest, not yet committed (the runner commits it).
fn write_heights(
    asset_dir: &Path,
    src: &Path,
    opts: &IngestOptions,
    share: &Share,
    progress: Progress,
) -> Result<Manifest> {
    let mut source = source::open(src, opts.raw().as_ref(), opts.tile_size, opts.max_memory)?;
    let info = source.info().clone();
    let mut manifest = describe(src, &info, opts)?;
    {
        let map = HeightMapping {
            nodata: manifest
                .nodata
                .source_value
                .as_deref()
                .and_then(parse_nodata),
            scale: opts.z_scale,
            offset: opts.z_offset,
        };
        let spec = LayerSpec {
            name: HEIGHT_LAYER.into(),
            level: 0,
            elem: ElemType::F32,
            bands: 1,
            width: info.width,
            height: info.height,
            tile_size: opts.tile_size,
            codec: opts.codec,
            fill_bits: u64::from(f32::NAN.to_bits()),
            stage: "ingest".into(),
            description: "terrain height, metres above the source's datum; NaN = nodata".into(),
        };
        let mut layer = LayerWriter::create(asset_dir, spec)?;
        let (width, ts) = (info.width as usize, opts.tile_size);
        let mut band = vec![0f32; width * ts.min(info.height) as usize];
        let mut stats = HeightStats::default();
        let wanted = share.rows(info.height as usize);
        let bar = progress.bar(u64::from(info.height), "ingest", "rows");
        for y0 in (0..info.height).step_by(ts as usize) {
            let rows = ts.min(info.height - y0) as usize;
            if y0 as usize >= wanted.end || y0 as usize + rows <= wanted.start {
                stats.nodata += (rows * width) as u64;
                crate::terrain::tiling::push_fill_row(&mut layer)?;
                bar.inc(rows as u64);
                continue;
            }
            let band = &mut band[..rows * width];
            // Only the wanted rows of a tile row the share cuts (NaN above
            // and below them).
            let (r0, r1) = (
                wanted.start.max(y0 as usize),
                wanted.end.min(y0 as usize + rows),
            );
            let (above, read) = band.split_at_mut((r0 - y0 as usize) * width);
            let (read, below) = read.split_at_mut((r1 - r0) * width);
            source
                .read_rows(r0 as u32, read, &map)
                .with_context(|| format!("{}: reading rows {r0}..{r1}", src.display()))
                .map_err(|e| crate::error::mark(crate::ErrorKind::Source, e))?;
            above.fill(f32::NAN);
            below.fill(f32::NAN);
            stats.add(band);
            push_tile_row(&mut layer, band, width, f32::NAN)?;
            bar.inc(rows as u64);
        }
        bar.finish_and_clear();
        if *share == Share::All && stats.range().is_none() {
            bail!(
                "{}: every post is nodata once read (nodata {:?}, z_scale {}, z_offset {}): heights past f32's range are nodata too; nothing to bake",
                src.display(),
                opts.nodata,
                opts.z_scale,
                opts.z_offset
            );
        }
        manifest.layers = vec![layer.finish()?];
        manifest.nodata.count = stats.nodata;
        manifest.height_range = stats.range();
        Ok(manifest)
    }
}

/// The manifest an ingest of `src` (header `info`) with `opts` writes,
/// before its layer and the heights' statistics: geometry, georeferencing,
/// vertical units and provenance, from the header alone. A partitioned bake
/// plans its parts from it before any part reads a row.
pub(crate) fn describe(
    src: &Path,
    info: &source::SourceInfo,
    opts: &IngestOptions,
) -> Result<Manifest> {
    let nodata_text = match opts.nodata {
        Some(v) => Some(v.to_string()),
        None => info.nodata.clone(),
    };
    let cell_size = match (opts.cell_size, &info.georef) {
        (Some((dx, dy)), _) => CellSize {
            dx,
            dy,
            source: "given".into(),
        },
        (None, Some(g)) => crate::terrain::geo::cell_size(g, info.height, info.linear_unit_m),
        (None, None) => CellSize {
            dx: 1.0,
            dy: 1.0,
            source: "assumed".into(),
        },
    };
    let (lo, hi) = terrabake_format::manifest::CELL_SIZE_RANGE;
    if !(lo..=hi).contains(&cell_size.dx) || !(lo..=hi).contains(&cell_size.dy) {
        bail!(
            "{}: post spacing {} x {} m ({}) is outside {lo:e}..={hi:e} m; give the spacing with --cell-size",
            src.display(),
            cell_size.dx,
            cell_size.dy,
            cell_size.source
        );
    }
    Ok(Manifest {
        format_version: FORMAT_VERSION,
        width: info.width,
        height: info.height,
        tile_size: opts.tile_size,
        cell_size,
        georef: info.georef.clone(),
        vertical: Vertical {
            units: info
                .vertical_units
                .clone()
                .unwrap_or_else(|| "metre".into()),
            scale: opts.z_scale,
            offset: opts.z_offset,
        },
        nodata: Nodata {
            source_value: nodata_text,
            count: 0,
        },
        height_range: None,
        provenance: Provenance {
            source: src.display().to_string(),
            source_len: fs::metadata(src)
                .with_context(|| format!("{}: cannot read", src.display()))?
                .len(),
            source_format: info.format.into(),
            tool: crate::tool_version(),
            // The runner records the stage when it commits.
            stages: Vec::new(),
        },
        layers: Vec::new(),
        retired: Vec::new(),
    })
}

/// Nodata count and height range of heights seen so far (the manifest's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeightStats {
    pub nodata: u64,
    pub min: f32,
    pub max: f32,
}

impl Default for HeightStats {
    fn default() -> Self {
        Self {
            nodata: 0,
            min: f32::INFINITY,
            max: f32::NEG_INFINITY,
        }
    }
}

impl HeightStats {
    pub fn add(&mut self, heights: &[f32]) {
        for &z in heights {
            if z.is_nan() {
                self.nodata += 1;
            } else {
                self.min = self.min.min(z);
                self.max = self.max.max(z);
            }
        }
    }

    pub(crate) fn merge(self, other: Self) -> Self {
        Self {
            nodata: self.nodata.saturating_add(other.nodata),
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// Statistics of `nodata` nodata posts and heights over `range`.
    pub(crate) fn from_range(nodata: u64, range: Option<HeightRange>) -> Self {
        let (min, max) = range.map_or((f32::INFINITY, f32::NEG_INFINITY), |r| (r.min, r.max));
        Self { nodata, min, max }
    }

    /// The manifest's height range (none when every post is nodata).
    pub fn range(&self) -> Option<HeightRange> {
        (self.min <= self.max).then_some(HeightRange {
            min: self.min,
            max: self.max,
        })
    }
}
