//! Ingest: a DEM source becomes a new asset whose one layer is `height`
//! (f32 metres, NaN for nodata), streamed one tile row at a time. Peak memory
//! is the source's own unit (a strip or tile row) plus one output tile row
//! (`width x tile_size` f32) and its encoded tiles, whatever the DEM's area.
//!
//! Ingest creates an asset or replaces one: the new height layer and the new
//! manifest are written beside the old ones and the manifest's rename is the
//! commit, so an interrupted ingest leaves the old asset intact (and a new
//! directory that it created is removed).

use std::fs;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use anyhow::{bail, Context, Result};
use serde::Serialize;
use terrabake_format::manifest::{
    CellSize, HeightRange, Nodata, Provenance, StageRecord, Vertical, HEIGHT_LAYER,
};
use terrabake_format::{
    commit_manifest, remove_unreferenced, Codec, ElemType, LayerSpec, LayerWriter, Manifest,
    FORMAT_VERSION, MANIFEST_FILE,
};

use crate::progress::Progress;
use crate::source::{self, parse_nodata, HeightMapping, RawSpec};
use crate::tiling::push_tile_row;

/// Default tile edge: 256 x 256 f32 = 256 KiB, a good unit for mmap paging,
/// zstd and GPU upload alike.
pub const DEFAULT_TILE: u32 = 256;

#[derive(Debug, Clone, Serialize)]
pub struct IngestOptions {
    pub tile_size: u32,
    /// Overrides the source's nodata value.
    pub nodata: Option<f64>,
    /// Overrides the post spacing, metres.
    pub cell_size: Option<(f64, f64)>,
    pub z_scale: f64,
    pub z_offset: f64,
    pub codec: Codec,
    pub raw: Option<RawSpec>,
}

impl Default for IngestOptions {
    fn default() -> Self {
        Self {
            tile_size: DEFAULT_TILE,
            nodata: None,
            cell_size: None,
            z_scale: 1.0,
            z_offset: 0.0,
            codec: Codec::Raw,
            raw: None,
        }
    }
}

/// The parameters recorded for ingest: the options plus the source's
/// identity (path, length, modification time), so that `bake` can tell
/// whether an existing asset already is this ingest.
pub fn ingest_params(src: &Path, opts: &IngestOptions) -> Result<serde_json::Value> {
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
    Ok(params)
}

/// Ingests `src` into the asset directory `asset_dir` and returns the
/// committed manifest.
pub fn ingest(
    src: &Path,
    asset_dir: &Path,
    opts: &IngestOptions,
    progress: Progress,
) -> Result<Manifest> {
    if !opts.tile_size.is_power_of_two() || !(16..=4096).contains(&opts.tile_size) {
        bail!(
            "--tile {} is not a power of two between 16 and 4096",
            opts.tile_size
        );
    }
    let params = ingest_params(src, opts)?;
    let mut source = source::open(src, opts.raw.as_ref())?;
    let info = source.info().clone();
    let target = AssetDir::prepare(asset_dir)?;
    let result = (|| -> Result<Manifest> {
        let nodata_text = match opts.nodata {
            Some(v) => Some(v.to_string()),
            None => info.nodata.clone(),
        };
        let map = HeightMapping {
            nodata: nodata_text.as_deref().and_then(parse_nodata),
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
        let mut writer = LayerWriter::create(asset_dir, spec)?;
        let (width, ts) = (info.width as usize, opts.tile_size);
        let mut band = vec![0f32; width * ts as usize];
        let (mut nodata_count, mut min, mut max) = (0u64, f32::INFINITY, f32::NEG_INFINITY);
        let bar = progress.bar(u64::from(info.height), "ingest", "rows");
        for y0 in (0..info.height).step_by(ts as usize) {
            let rows = ts.min(info.height - y0) as usize;
            let band = &mut band[..rows * width];
            source.read_rows(y0, band, &map).with_context(|| {
                format!(
                    "{}: reading rows {y0}..{}",
                    src.display(),
                    y0 as usize + rows
                )
            })?;
            for &z in band.iter() {
                if z.is_nan() {
                    nodata_count += 1;
                } else {
                    min = min.min(z);
                    max = max.max(z);
                }
            }
            push_tile_row(&mut writer, band, width, f32::NAN, opts.codec)?;
            bar.inc(rows as u64);
        }
        bar.finish_and_clear();
        let entry = writer.finish()?;
        let cell_size = match (opts.cell_size, &info.georef) {
            (Some((dx, dy)), _) => CellSize {
                dx,
                dy,
                source: "given".into(),
            },
            (None, Some(g)) => crate::geo::cell_size(g, info.height, info.linear_unit_m),
            (None, None) => CellSize {
                dx: 1.0,
                dy: 1.0,
                source: "assumed".into(),
            },
        };
        let manifest = Manifest {
            format_version: FORMAT_VERSION,
            width: info.width,
            height: info.height,
            tile_size: ts,
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
                count: nodata_count,
            },
            height_range: (min <= max).then_some(HeightRange { min, max }),
            provenance: Provenance {
                source: src.display().to_string(),
                source_len: params["source_len"].as_u64().unwrap_or(0),
                source_format: info.format.into(),
                tool: crate::tool_version(),
                stages: vec![StageRecord {
                    stage: "ingest".into(),
                    params,
                    tool: crate::tool_version(),
                    finished_unix: unix_now(),
                    outputs: vec![entry.key()],
                }],
            },
            layers: vec![entry],
        };
        commit_manifest(asset_dir, &manifest)?;
        Ok(manifest)
    })();
    match result {
        Ok(manifest) => {
            remove_unreferenced(asset_dir, &manifest)?;
            Ok(manifest)
        }
        Err(e) => {
            target.abandon();
            Err(e)
        }
    }
}

pub fn unix_now() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// The output directory of an ingest, and whether we created it.
struct AssetDir {
    path: PathBuf,
    created: bool,
}

impl AssetDir {
    /// Accepts a missing path, an empty directory, or an existing asset;
    /// refuses anything else rather than writing into a stranger's folder.
    fn prepare(path: &Path) -> Result<Self> {
        match fs::metadata(path) {
            Err(_) => {
                fs::create_dir_all(path).with_context(|| {
                    format!("{}: cannot create the asset directory", path.display())
                })?;
                Ok(Self {
                    path: path.into(),
                    created: true,
                })
            }
            Ok(m) if !m.is_dir() => {
                bail!("{}: exists and is not an asset directory", path.display())
            }
            Ok(_) => {
                let is_asset = path.join(MANIFEST_FILE).exists();
                let empty = fs::read_dir(path)?.next().is_none();
                if !is_asset && !empty {
                    bail!(
                        "{}: is a non-empty directory without {MANIFEST_FILE}; refusing to write an asset into it",
                        path.display()
                    );
                }
                Ok(Self {
                    path: path.into(),
                    created: false,
                })
            }
        }
    }

    fn abandon(self) {
        if self.created {
            let _ = fs::remove_dir_all(&self.path);
        }
    }
}
