//! Layers as a Zarr v3 group (`terrabake export A --layer all -o A.zarr`),
//! for xarray, zarr-python, GDAL and the cloud tools that read Zarr.
//!
//! ```text
//! A.zarr/
//! ├── zarr.json              group: CF and GeoZarr attributes, and every
//! │                          array's metadata consolidated inline
//! ├── y/   x/   azimuth/     coordinates: zarr.json and one chunk, c/0
//! ├── spatial_ref/           the CF grid mapping: a scalar, chunk c
//! └── horizon/               a layer: zarr.json and a chunk per asset tile,
//!     └── c/<band>/<ty>/<tx>   one band deep (c/<ty>/<tx> for one band)
//! ```
//!
//! The dataset (dimensions, coordinates, attributes) is
//! [`super::dataset`]'s. Every array's codecs are `bytes` (little-endian)
//! then `zstd`, so a tile the asset stores compressed is copied as it is
//! stored, with no decode and no re-encode; a raw tile is compressed at
//! level 3. Edge chunks are whole tiles padded with the layer's fill
//! value, as Zarr's regular grid has them.
//!
//! The group is written in a fresh directory beside the output and
//! exchanged with it at the end ([`write_dir_atomically`]): a failed or
//! interrupted export leaves the store that was there before.

use std::fs;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::Context;
use rayon::prelude::*;
use serde_json::{json, Map, Value};
use terrabake_format::layout::{Codec, ElemType};
use terrabake_format::{Asset, Layer, Mmap};

use super::dataset::{
    dataset, stored_codes, tile_bytes, Coordinate, CoordinateValues, Dataset, Storage, Variable,
};
use crate::plumbing::output::write_dir_atomically;
use crate::plumbing::progress::Progress;

/// The zstd level of chunks the asset stores raw.
const ZSTD_LEVEL: i32 = 3;

/// What an export wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ZarrReport {
    pub arrays: usize,
    pub chunks: u64,
    /// Chunks copied as the asset stores them (already zstd).
    pub copied: u64,
    pub bytes: u64,
}

/// Writes `layers` (one grid) as a Zarr v3 group at `out`.
pub fn export_zarr(
    asset: &Asset<Mmap>,
    layers: &[&Layer<Mmap>],
    out: &Path,
    progress: Progress,
) -> crate::Result<ZarrReport> {
    let ds = dataset(asset, layers)?;
    let chunks_total = ds.chunk_count();
    let bar = progress.bar(chunks_total, "export", "chunks");
    let counts = [AtomicU64::new(0), AtomicU64::new(0)];
    let bytes = AtomicU64::new(0);
    write_dir_atomically(out, "a Zarr store", is_zarr_store, |dir| {
        let mut consolidated = Map::new();
        for c in &ds.coordinates {
            let meta = coordinate_metadata(c);
            let raw = c.values.le_bytes();
            let key = if c.dims.is_empty() { "c" } else { "c/0" };
            let stored = zstd::bulk::compress(&raw, ZSTD_LEVEL)?;
            write_array(dir, &c.name, &meta, &[(key.to_string(), stored)])?;
            consolidated.insert(c.name.clone(), meta);
        }
        for v in &ds.variables {
            let meta = variable_metadata(&ds, v)?;
            write_array(dir, &v.name, &meta, &[])?;
            write_chunks(dir, v, &counts, &bytes, || bar.inc(1))?;
            consolidated.insert(v.name.clone(), meta);
        }
        let mut attributes = ds.attrs.clone();
        attributes.extend(ds.geozarr.clone());
        let group = json!({
            "zarr_format": 3,
            "node_type": "group",
            "attributes": attributes,
            "consolidated_metadata": {
                "kind": "inline",
                "must_understand": false,
                "metadata": consolidated,
            },
        });
        write_json(&dir.join("zarr.json"), &group)
    })?;
    bar.finish_and_clear();
    Ok(ZarrReport {
        arrays: ds.coordinates.len() + ds.variables.len(),
        chunks: counts[0].load(Ordering::Relaxed),
        copied: counts[1].load(Ordering::Relaxed),
        bytes: bytes.load(Ordering::Relaxed),
    })
}

/// A directory this export may replace: a Zarr store (its root
/// `zarr.json`), never someone's other directory.
fn is_zarr_store(dir: &Path) -> bool {
    fs::symlink_metadata(dir.join("zarr.json")).is_ok_and(|m| m.is_file())
}

/// Array `name`'s directory, its `zarr.json` and the chunks given.
fn write_array(
    dir: &Path,
    name: &str,
    meta: &Value,
    chunks: &[(String, Vec<u8>)],
) -> anyhow::Result<()> {
    let array = dir.join(name);
    fs::create_dir(&array).with_context(|| format!("{}: cannot create", array.display()))?;
    write_json(&array.join("zarr.json"), meta)?;
    for (key, bytes) in chunks {
        let path = array.join(key);
        if let Some(parent) = path.parent() {
            fs::create_dir_all(parent)?;
        }
        fs::write(&path, bytes).with_context(|| format!("{}: cannot write", path.display()))?;
    }
    Ok(())
}

fn write_json(path: &Path, value: &Value) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    fs::write(path, text).with_context(|| format!("{}: cannot write", path.display()))
}

/// Every chunk of variable `v`, in parallel: the asset's zstd tiles as they
/// are stored, raw tiles compressed, decoded tiles (see
/// [`Storage::Decoded`]) padded with NaN and compressed.
fn write_chunks(
    dir: &Path,
    v: &Variable<'_>,
    counts: &[AtomicU64; 2],
    bytes: &AtomicU64,
    tick: impl Fn() + Sync,
) -> anyhow::Result<()> {
    let layer = v.layer;
    let (bands, tx_n, ty_n) = (layer.bands(), layer.tiles_x(), layer.tiles_y());
    let several = v.dims.len() == 3;
    let array = dir.join(&v.name);
    for b in 0..bands {
        for ty in 0..ty_n {
            let row = if several {
                array.join(format!("c/{b}/{ty}"))
            } else {
                array.join(format!("c/{ty}"))
            };
            fs::create_dir_all(&row)
                .with_context(|| format!("{}: cannot create", row.display()))?;
        }
    }
    let chunk_len = (layer.tile_size() as usize).pow(2) * v.storage.elem().size();
    (0..u64::from(bands) * u64::from(ty_n) * u64::from(tx_n))
        .into_par_iter()
        .try_for_each(|i| -> anyhow::Result<()> {
            let tx = (i % u64::from(tx_n)) as u32;
            let ty = ((i / u64::from(tx_n)) % u64::from(ty_n)) as u32;
            let b = (i / (u64::from(tx_n) * u64::from(ty_n))) as u32;
            // One read of the stored tile: copied where it is zstd already.
            let (stored, copied) = match v.storage {
                Storage::Codes(_) => {
                    let chunk = layer.stored_tile(b, tx, ty)?;
                    if chunk.codec == Codec::Zstd && chunk.raw_len as usize == chunk_len {
                        (chunk.bytes.to_vec(), true)
                    } else {
                        let codes = stored_codes(layer, &chunk, v.storage)?;
                        (zstd::bulk::compress(&codes, ZSTD_LEVEL)?, false)
                    }
                }
                Storage::Decoded => (
                    zstd::bulk::compress(&tile_bytes(layer, v.storage, b, tx, ty)?, ZSTD_LEVEL)?,
                    false,
                ),
            };
            let key = if several {
                format!("c/{b}/{ty}/{tx}")
            } else {
                format!("c/{ty}/{tx}")
            };
            let path = array.join(key);
            fs::write(&path, &stored)
                .with_context(|| format!("{}: cannot write", path.display()))?;
            counts[0].fetch_add(1, Ordering::Relaxed);
            counts[1].fetch_add(u64::from(copied), Ordering::Relaxed);
            bytes.fetch_add(stored.len() as u64, Ordering::Relaxed);
            tick();
            Ok(())
        })
}

/// Zarr v3's name of an element type.
fn data_type(elem: ElemType) -> anyhow::Result<&'static str> {
    Ok(match elem {
        ElemType::F32 => "float32",
        ElemType::F16 => "float16",
        ElemType::U8 => "uint8",
        ElemType::U16 => "uint16",
        ElemType::I16 => "int16",
        ElemType::U32 => "uint32",
        other => anyhow::bail!("{} elements have no Zarr data type here", other.name()),
    })
}

/// A fill value as Zarr v3's JSON has it (non-finite floats by name).
fn fill_json(v: f64, elem: ElemType) -> Value {
    match elem {
        ElemType::F32 | ElemType::F16 if v.is_nan() => "NaN".into(),
        ElemType::F32 | ElemType::F16 if v.is_infinite() => {
            if v > 0.0 { "Infinity" } else { "-Infinity" }.into()
        }
        ElemType::F32 | ElemType::F16 => json!(v),
        _ => json!(v as i64),
    }
}

/// The codec chain: little-endian bytes (no endianness for one-byte
/// elements), then zstd.
fn codecs(elem_size: usize) -> Value {
    let bytes = if elem_size > 1 {
        json!({"name": "bytes", "configuration": {"endian": "little"}})
    } else {
        json!({"name": "bytes"})
    };
    json!([bytes, {"name": "zstd", "configuration": {"level": ZSTD_LEVEL, "checksum": false}}])
}

fn array_metadata(
    shape: Vec<u64>,
    chunk_shape: Vec<u64>,
    data_type: &str,
    elem_size: usize,
    fill: Value,
    dims: &[String],
    attrs: &Map<String, Value>,
) -> Value {
    json!({
        "zarr_format": 3,
        "node_type": "array",
        "shape": shape,
        "data_type": data_type,
        "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": chunk_shape}},
        "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
        "fill_value": fill,
        "codecs": codecs(elem_size),
        "attributes": attrs,
        "dimension_names": dims,
    })
}

fn coordinate_metadata(c: &Coordinate) -> Value {
    let shape: Vec<u64> = if c.dims.is_empty() {
        vec![]
    } else {
        vec![c.values.len() as u64]
    };
    let (data_type, fill) = match c.values {
        CoordinateValues::F64(_) => ("float64", json!("NaN")),
        CoordinateValues::I64(_) => ("int64", json!(0)),
    };
    array_metadata(shape.clone(), shape, data_type, 8, fill, &c.dims, &c.attrs)
}

fn variable_metadata(ds: &Dataset<'_>, v: &Variable<'_>) -> anyhow::Result<Value> {
    let elem = v.storage.elem();
    let mut attrs = v.attrs.clone();
    if ds.geozarr.contains_key("spatial:transform") {
        attrs.insert("spatial:dimensions".into(), json!(["y", "x"]));
    }
    Ok(array_metadata(
        v.shape(),
        v.chunk_shape(),
        data_type(elem)?,
        elem.size(),
        fill_json(v.fill, elem),
        &v.dims,
        &attrs,
    ))
}
