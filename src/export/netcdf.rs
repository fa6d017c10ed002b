//! Layers as a NetCDF-4 file (`terrabake export A --layer all -o A.nc`),
//! CF-1.8, for the climate, snow and NWP tools that read NetCDF (xarray,
//! netCDF4-python, GDAL, CDO, NCO, Panoply) and as HORAYZON writes its
//! horizons.
//!
//! The dataset (dimensions, coordinates, attributes) is
//! [`super::dataset`]'s, the one the Zarr export writes, so `ncdump -h` of
//! the demo's horizons reads
//!
//! ```text
//! dimensions: y = 1201 ; x = 1201 ; azimuth = 32 ;
//! variables:
//!     double y(y) ; double x(x) ; double azimuth(azimuth) ;
//!     int64 spatial_ref ;           crs_wkt, GeoTransform
//!     ubyte horizon(azimuth, y, x) ; scale_factor, add_offset, _FillValue,
//!                                    grid_mapping = "spatial_ref"
//! ```
//!
//! A NetCDF-4 file is an HDF5 file that follows netCDF's conventions, and
//! this module maps the dataset onto them; [`super::hdf5`] writes the HDF5.
//! Each dimension is a coordinate variable that is also an HDF5 dimension
//! scale (`CLASS`, `NAME`, `_Netcdf4Dimid`, and a `REFERENCE_LIST` of the
//! variables that use it), and each variable names its dimensions in a
//! `DIMENSION_LIST`, as netCDF-C itself writes them. Chunks are the
//! asset's tiles, one band deep, through HDF5's shuffle and deflate
//! filters (zlib, level [`DEFLATE_LEVEL`]): NetCDF's zstd needs a filter
//! plugin most readers lack, so the asset's zstd tiles are decoded and
//! deflated. Quantised layers keep their codes with `scale_factor` and
//! `add_offset`; `f16` layers, which NetCDF has no type for, are widened
//! to `f32`.
//!
//! The file is written beside the output and renamed over it
//! ([`write_atomically`]).

use std::io::{Seek, Write};

use rayon::prelude::*;
use serde_json::{Map, Value as Json};
use terrabake_format::layout::ElemType;
use terrabake_format::{Asset, Layer, Mmap};

use super::dataset::{dataset, tile_bytes, CoordinateValues, Dataset, Storage, Variable};
use super::hdf5::{
    self, Attribute, ChunkRef, Dataspace, Dtype, Filter, Layout, Object, ObjectKind, Value,
};
use crate::plumbing::output::write_atomically;
use crate::plumbing::progress::Progress;

/// Deflate's level: about the ratio of level 9 at a few times its speed.
pub const DEFLATE_LEVEL: u32 = 4;

/// Tiles compressed at once, in parallel, before they are written in order.
const BATCH: usize = 64;

/// What an export wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NetcdfReport {
    pub variables: usize,
    pub chunks: u64,
    pub bytes: u64,
}

/// Writes `layers` (one grid) as a NetCDF-4 file at `out`.
pub fn export_netcdf(
    asset: &Asset<Mmap>,
    layers: &[&Layer<Mmap>],
    out: &std::path::Path,
    progress: Progress,
) -> crate::Result<NetcdfReport> {
    let ds = dataset(asset, layers)?;
    let chunks_total = ds.chunk_count();
    let bar = progress.bar(chunks_total, "export", "chunks");
    let mut bytes = 0;
    write_atomically(out, |file| {
        let mut f = hdf5::File::new(file)?;
        let mut chunked = Vec::new();
        for v in &ds.variables {
            chunked.push(write_variable_chunks(&mut f, v, || bar.inc(1))?);
        }
        f.objects = objects(&mut f, &ds, &chunked)?;
        bytes = f.finish()?.1;
        Ok(())
    })?;
    bar.finish_and_clear();
    Ok(NetcdfReport {
        variables: ds.coordinates.len() + ds.variables.len(),
        chunks: chunks_total,
        bytes,
    })
}

/// How a variable is written: NetCDF has no `f16`, so those are decoded.
fn storage(v: &Variable<'_>) -> Storage {
    match v.storage {
        Storage::Codes(ElemType::F16) => Storage::Decoded,
        s => s,
    }
}

/// A variable's chunks, written; returns its B-tree's address.
fn write_variable_chunks<W: Write + Seek>(
    f: &mut hdf5::File<W>,
    v: &Variable<'_>,
    tick: impl Fn() + Sync,
) -> anyhow::Result<u64> {
    let layer = v.layer;
    let storage = storage(v);
    let elem_size = storage.elem().size();
    let (bands, tx_n, ty_n) = (layer.bands(), layer.tiles_x(), layer.tiles_y());
    let all: Vec<(u32, u32, u32)> = (0..bands)
        .flat_map(|b| (0..ty_n).flat_map(move |ty| (0..tx_n).map(move |tx| (b, ty, tx))))
        .collect();
    let mut refs = Vec::with_capacity(all.len());
    for batch in all.chunks(BATCH) {
        let compressed: Vec<Vec<u8>> = batch
            .par_iter()
            .map(|&(b, ty, tx)| -> anyhow::Result<Vec<u8>> {
                let raw = tile_bytes(layer, storage, b, tx, ty)?;
                let shuffled = hdf5::shuffle(&raw, elem_size);
                let mut z = flate2::write::ZlibEncoder::new(
                    Vec::with_capacity(raw.len() / 2),
                    flate2::Compression::new(DEFLATE_LEVEL),
                );
                z.write_all(&shuffled)?;
                let out = z.finish()?;
                tick();
                Ok(out)
            })
            .collect::<anyhow::Result<_>>()?;
        for (&(b, ty, tx), bytes) in batch.iter().zip(compressed) {
            let address = f.write_raw(&bytes)?;
            refs.push(ChunkRef {
                offsets: v.chunk_offsets(b, ty, tx),
                address,
                size: bytes.len() as u32,
            });
        }
    }
    Ok(f.write_chunk_btree(&refs, &v.chunk_shape(), elem_size as u32)?)
}

/// The file's objects: the root group (the dataset's attributes and a link
/// to every variable), the coordinates (dimension scales where they have
/// a dimension), then the layers' variables, whose chunks lie at
/// `btrees`. Coordinates' values are written here.
fn objects<W: Write + Seek>(
    f: &mut hdf5::File<W>,
    ds: &Dataset<'_>,
    btrees: &[u64],
) -> anyhow::Result<Vec<Object>> {
    let first_variable = 1 + ds.coordinates.len();
    let dimensions: Vec<&str> = ds
        .coordinates
        .iter()
        .filter(|c| !c.dims.is_empty())
        .map(|c| c.name.as_str())
        .collect();
    let object_of_dim = |dim: &str| {
        1 + ds
            .coordinates
            .iter()
            .position(|c| c.name == dim)
            .expect("every dimension has its coordinate")
    };

    let mut root_attrs = vec![Attribute::text(
        "_NCProperties",
        &format!("version=2,terrabake={}", env!("CARGO_PKG_VERSION")),
    )];
    root_attrs.extend(attributes(&ds.attrs)?);
    let mut links = Vec::new();
    let mut objects = vec![Object {
        kind: ObjectKind::Group { links: vec![] },
        attrs: root_attrs,
    }];

    for c in &ds.coordinates {
        let dtype = match &c.values {
            CoordinateValues::F64(_) => Dtype::Float { size: 8 },
            CoordinateValues::I64(_) => Dtype::Int {
                size: 8,
                signed: true,
            },
        };
        let raw = c.values.le_bytes();
        let mut attrs = Vec::new();
        let (space, layout) = if c.dims.is_empty() {
            (Dataspace::Scalar, Layout::Compact(raw))
        } else {
            let address = f.write_raw(&raw)?;
            // A dimension scale, as netCDF-C writes one.
            let dimid = dimensions.iter().position(|d| *d == c.name).unwrap_or(0);
            attrs.push(Attribute::c_string("CLASS", "DIMENSION_SCALE"));
            attrs.push(Attribute::c_string("NAME", &c.name));
            let users: Vec<(usize, u32)> = ds
                .variables
                .iter()
                .enumerate()
                .flat_map(|(i, v)| {
                    v.dims
                        .iter()
                        .enumerate()
                        .filter(|(_, d)| **d == c.name)
                        .map(move |(k, _)| (first_variable + i, k as u32))
                })
                .collect();
            if !users.is_empty() {
                attrs.push(Attribute {
                    name: "REFERENCE_LIST".into(),
                    value: Value::RefIndexPairs(users),
                });
            }
            attrs.push(Attribute::numbers(
                "_Netcdf4Dimid",
                Dtype::Int {
                    size: 4,
                    signed: true,
                },
                (dimid as i32).to_le_bytes().to_vec(),
            ));
            let size = raw.len() as u64;
            (
                Dataspace::Simple(vec![c.values.len() as u64]),
                Layout::Contiguous { address, size },
            )
        };
        attrs.extend(attributes(&c.attrs)?);
        links.push((c.name.clone(), objects.len()));
        objects.push(Object {
            kind: ObjectKind::Dataset {
                dtype,
                space,
                layout,
                fill: None,
                filters: vec![],
            },
            attrs,
        });
    }

    for (v, &btree) in ds.variables.iter().zip(btrees) {
        let storage = storage(v);
        let elem = storage.elem();
        let dtype = dtype_of(elem)?;
        // The code that means nodata (CF's _FillValue, in the variable's
        // type), or NaN for floats; integers with no nodata code get none,
        // so that no reader masks a value the layer holds.
        let fill = match (storage, v.attrs.get("_FillValue").and_then(Json::as_f64)) {
            (Storage::Decoded, _) => Some(f64::NAN),
            (_, Some(code)) => Some(code),
            (_, None) if matches!(elem, ElemType::F32) && v.fill.is_nan() => Some(f64::NAN),
            _ => None,
        }
        .map(|x| value_bytes(x, elem));
        let mut attrs = vec![Attribute {
            name: "DIMENSION_LIST".into(),
            value: Value::ObjectRefLists(v.dims.iter().map(|d| vec![object_of_dim(d)]).collect()),
        }];
        let mut rest = v.attrs.clone();
        rest.remove("_FillValue");
        attrs.extend(attributes(&rest)?);
        if let Some(bytes) = &fill {
            attrs.push(Attribute::numbers(
                "_FillValue",
                dtype.clone(),
                bytes.clone(),
            ));
        }
        let mut filters = Vec::new();
        if elem.size() > 1 {
            filters.push(Filter::Shuffle {
                elem_size: elem.size() as u32,
            });
        }
        filters.push(Filter::Deflate {
            level: DEFLATE_LEVEL,
        });
        links.push((v.name.clone(), objects.len()));
        objects.push(Object {
            kind: ObjectKind::Dataset {
                dtype,
                space: Dataspace::Simple(v.shape()),
                layout: Layout::Chunked {
                    btree,
                    chunk: v.chunk_shape(),
                },
                fill,
                filters,
            },
            attrs,
        });
    }
    objects[0].kind = ObjectKind::Group { links };
    Ok(objects)
}

fn dtype_of(elem: ElemType) -> anyhow::Result<Dtype> {
    let int = |size, signed| Dtype::Int { size, signed };
    Ok(match elem {
        ElemType::F32 => Dtype::Float { size: 4 },
        ElemType::U8 => int(1, false),
        ElemType::U16 => int(2, false),
        ElemType::I16 => int(2, true),
        ElemType::U32 => int(4, false),
        other => anyhow::bail!("{} elements have no NetCDF type here", other.name()),
    })
}

/// `x` as one little-endian element of `elem`.
fn value_bytes(x: f64, elem: ElemType) -> Vec<u8> {
    match elem {
        ElemType::U8 => vec![x as u8],
        ElemType::U16 => (x as u16).to_le_bytes().to_vec(),
        ElemType::I16 => (x as i16).to_le_bytes().to_vec(),
        ElemType::U32 => (x as u32).to_le_bytes().to_vec(),
        _ => (x as f32).to_le_bytes().to_vec(),
    }
}

/// CF attributes as NetCDF's: text as `char`, integers as `int` (`int64`
/// past its range), other numbers as `double`, lists of text as `string`
/// arrays, lists of numbers as arrays; anything else as its JSON text.
fn attributes(map: &Map<String, Json>) -> anyhow::Result<Vec<Attribute>> {
    let int = |size| Dtype::Int { size, signed: true };
    let numbers = |name: &str, values: &[Json]| -> Option<Attribute> {
        if values
            .iter()
            .all(|v| v.as_i64().is_some_and(|i| i32::try_from(i).is_ok()))
        {
            let b = values
                .iter()
                .flat_map(|v| (v.as_i64().unwrap_or(0) as i32).to_le_bytes())
                .collect();
            Some(Attribute::numbers(name, int(4), b))
        } else if values.iter().all(Json::is_i64) {
            let b = values
                .iter()
                .flat_map(|v| v.as_i64().unwrap_or(0).to_le_bytes())
                .collect();
            Some(Attribute::numbers(name, int(8), b))
        } else if values.iter().all(Json::is_number) {
            let b = values
                .iter()
                .flat_map(|v| v.as_f64().unwrap_or(f64::NAN).to_le_bytes())
                .collect();
            Some(Attribute::numbers(name, Dtype::Float { size: 8 }, b))
        } else {
            None
        }
    };
    let mut out = Vec::new();
    for (name, value) in map {
        let attr = match value {
            Json::String(s) => Attribute::text(name, s),
            Json::Number(_) => numbers(name, std::slice::from_ref(value))
                .unwrap_or_else(|| Attribute::text(name, &value.to_string())),
            Json::Array(items) if !items.is_empty() && items.iter().all(Json::is_string) => {
                Attribute {
                    name: name.clone(),
                    value: Value::Strings(
                        items
                            .iter()
                            .map(|s| s.as_str().unwrap_or_default().to_string())
                            .collect(),
                    ),
                }
            }
            Json::Array(items) if !items.is_empty() => {
                numbers(name, items).unwrap_or_else(|| Attribute::text(name, &value.to_string()))
            }
            other => Attribute::text(name, &other.to_string()),
        };
        anyhow::ensure!(
            attr.message_len() <= hdf5::MAX_MESSAGE_LEN,
            "attribute {name} is too long for a NetCDF-4 header (64 KiB)"
        );
        out.push(attr);
    }
    Ok(out)
}
