//! Layers as a CF dataset: the dimensions, coordinates, variables and
//! attributes that the array exports ([`super::zarr`]) write, decided once.
//!
//! The model is the one the Python package's xarray backend gives
//! (`python/terrabake/xarray_backend.py`), so a layer exported to Zarr and
//! the same layer opened with `engine="terrabake"` are the same dataset:
//!
//! - every layer is a variable over `(y, x)`, or `(azimuth, y, x)` for a
//!   directional layer (the recorded band azimuths, degrees clockwise from
//!   north; `azimuth_<layer>` where two layers' azimuths differ), or
//!   `(<layer>_band, y, x)` for other layers of several bands (the solar
//!   stage's periods);
//! - `x` and `y` are the CRS coordinates of the post centres (post indices
//!   without georeferencing), and `spatial_ref` is the CF grid mapping
//!   (`crs_wkt`, GDAL's `GeoTransform`) that rioxarray and GDAL read;
//! - a quantised layer keeps its stored codes, with CF's `scale_factor`,
//!   `add_offset` and `_FillValue` (its nodata code) saying what they
//!   mean, rather than being widened to floats: the u8 horizons of the
//!   demo are a quarter of their float size. The one stored encoding that
//!   is not affine (the u16 half-angle codes of `cone_slope`) is decoded
//!   to `f32`.
//!
//! Chunks are the asset's tiles, one band deep: `(1, tile, tile)`.

use std::borrow::Cow;

use anyhow::anyhow;
use serde_json::{json, Map, Value};
use terrabake_format::layout::{Codec, ElemType};
use terrabake_format::{Asset, Layer, Mmap, StoredChunk};

use super::{cog_for_layer, layer_title, layer_unit};

/// How a variable's values are stored in the export.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    /// The asset's stored elements, chunk for chunk.
    Codes(ElemType),
    /// Decoded to `f32` (nodata NaN): encodings CF cannot describe.
    Decoded,
}

impl Storage {
    /// The element type written.
    pub fn elem(self) -> ElemType {
        match self {
            Storage::Codes(e) => e,
            Storage::Decoded => ElemType::F32,
        }
    }
}

/// One layer as a variable.
#[derive(Debug)]
pub struct Variable<'a> {
    pub name: String,
    pub layer: &'a Layer<Mmap>,
    /// `[band dimension,] y, x`.
    pub dims: Vec<String>,
    pub storage: Storage,
    /// The value of elements no chunk holds and of padding past the edge.
    pub fill: f64,
    pub attrs: Map<String, Value>,
}

impl Variable<'_> {
    /// The array's shape: `[bands,] height, width`.
    pub fn shape(&self) -> Vec<u64> {
        let l = self.layer;
        self.with_band(u64::from(l.bands()), [l.height(), l.width()].map(u64::from))
    }

    /// A chunk's shape: one tile, one band deep (`[1,] tile, tile`).
    pub fn chunk_shape(&self) -> Vec<u64> {
        let t = u64::from(self.layer.tile_size());
        self.with_band(1, [t, t])
    }

    /// Where chunk `(band, ty, tx)` starts, in elements.
    pub fn chunk_offsets(&self, band: u32, ty: u32, tx: u32) -> Vec<u64> {
        let t = u64::from(self.layer.tile_size());
        self.with_band(u64::from(band), [u64::from(ty) * t, u64::from(tx) * t])
    }

    /// `yx`, after `band` where the variable has a band dimension.
    fn with_band(&self, band: u64, yx: [u64; 2]) -> Vec<u64> {
        if self.dims.len() == 3 {
            vec![band, yx[0], yx[1]]
        } else {
            yx.to_vec()
        }
    }
}

/// A coordinate variable (one dimension, or none for `spatial_ref`).
#[derive(Debug, Clone, PartialEq)]
pub struct Coordinate {
    pub name: String,
    pub dims: Vec<String>,
    pub values: CoordinateValues,
    pub attrs: Map<String, Value>,
}

/// A coordinate's values.
#[derive(Debug, Clone, PartialEq)]
pub enum CoordinateValues {
    F64(Vec<f64>),
    I64(Vec<i64>),
}

impl CoordinateValues {
    pub fn len(&self) -> usize {
        match self {
            CoordinateValues::F64(v) => v.len(),
            CoordinateValues::I64(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The values as little-endian 8-byte elements.
    pub fn le_bytes(&self) -> Vec<u8> {
        match self {
            CoordinateValues::F64(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            CoordinateValues::I64(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        }
    }
}

/// Layers of one grid as a CF dataset.
#[derive(Debug)]
pub struct Dataset<'a> {
    pub width: u32,
    pub height: u32,
    pub coordinates: Vec<Coordinate>,
    pub variables: Vec<Variable<'a>>,
    pub attrs: Map<String, Value>,
    /// GeoZarr's spatial and projection attributes of the group: Zarr's
    /// alone, the NetCDF export has CF's grid mapping.
    pub geozarr: Map<String, Value>,
}

impl Dataset<'_> {
    /// Chunks of every variable: a tile of a band each.
    pub fn chunk_count(&self) -> u64 {
        self.variables
            .iter()
            .map(|v| u64::from(v.layer.bands()) * u64::from(v.layer.tiles_x() * v.layer.tiles_y()))
            .sum()
    }
}

/// The dataset of `layers` (one grid: one level of one asset).
pub fn dataset<'a>(asset: &Asset<Mmap>, layers: &[&'a Layer<Mmap>]) -> crate::Result<Dataset<'a>> {
    let first = layers.first().ok_or_else(|| anyhow!("no layer to write"))?;
    let (width, height, level) = (first.width(), first.height(), first.entry().level);
    for layer in layers {
        crate::error::ensure!(
            (layer.width(), layer.height(), layer.entry().level) == (width, height, level),
            "layers {} and {} are on different grids; one dataset holds one grid (export each level apart)",
            first.entry().key(),
            layer.entry().key()
        );
    }
    let manifest = asset.manifest();
    let georef = manifest.georef.as_ref();
    let scale = f64::from(1u32 << level.min(30));
    let corner = georef.map(|g| g.corner_geotransform());
    let axis = |n: u32, origin: f64, step: f64| -> Vec<f64> {
        (0..n)
            .map(|i| origin + (f64::from(i) + 0.5) * step)
            .collect()
    };
    let (xs, ys) = match corner {
        Some(t) => (
            axis(width, t[0], t[1] * scale),
            axis(height, t[3], t[5] * scale),
        ),
        None => (
            (0..width).map(|i| f64::from(i) * scale).collect(),
            (0..height).map(|i| f64::from(i) * scale).collect(),
        ),
    };
    let geographic =
        georef.is_some_and(|g| g.crs_kind == terrabake_format::manifest::CrsKind::Geographic);
    let axis_attrs = |axis: &str| {
        let mut a = Map::new();
        let (standard, long, units) = match (geographic, axis, georef.is_some()) {
            (_, _, false) => ("", format!("{axis} post index"), "1"),
            (true, "x", _) => ("longitude", "longitude".into(), "degrees_east"),
            (true, _, _) => ("latitude", "latitude".into(), "degrees_north"),
            (false, "x", _) => (
                "projection_x_coordinate",
                "x coordinate of projection".into(),
                "m",
            ),
            (false, _, _) => (
                "projection_y_coordinate",
                "y coordinate of projection".into(),
                "m",
            ),
        };
        if !standard.is_empty() {
            a.insert("standard_name".into(), standard.into());
        }
        a.insert("long_name".into(), long.into());
        a.insert("units".into(), units.into());
        a.insert("axis".into(), axis.to_uppercase().into());
        a
    };
    let mut coordinates = vec![
        Coordinate {
            name: "y".into(),
            dims: vec!["y".into()],
            values: CoordinateValues::F64(ys),
            attrs: axis_attrs("y"),
        },
        Coordinate {
            name: "x".into(),
            dims: vec!["x".into()],
            values: CoordinateValues::F64(xs),
            attrs: axis_attrs("x"),
        },
    ];
    let grid_mapping = georef.zip(corner).map(|(g, t)| {
        let t = [
            t[0],
            t[1] * scale,
            t[2] * scale,
            t[3],
            t[4] * scale,
            t[5] * scale,
        ];
        let mut a = Map::new();
        if let Some(wkt) = g.epsg.and_then(crate::terrain::geo::wkt) {
            a.insert("crs_wkt".into(), wkt.clone().into());
            a.insert("spatial_ref".into(), wkt.into());
        }
        if let Some(epsg) = g.epsg {
            a.insert("epsg_code".into(), format!("EPSG:{epsg}").into());
        }
        // CF's own grid mapping too, for the readers that know no WKT.
        for (key, value) in g
            .epsg
            .and_then(crate::terrain::geo::cf_grid_mapping)
            .unwrap_or_default()
        {
            use crate::terrain::geo::CfValue;
            let value = match value {
                CfValue::Number(x) => json!(x),
                CfValue::Numbers(v) => json!(v),
                CfValue::Text(t) => t.into(),
            };
            a.insert(key.into(), value);
        }
        a.insert(
            "GeoTransform".into(),
            t.iter()
                .map(|v| format!("{v:?}"))
                .collect::<Vec<_>>()
                .join(" ")
                .into(),
        );
        (a, t)
    });
    let mut attrs = Map::new();
    attrs.insert("Conventions".into(), "CF-1.8".into());
    attrs.insert("source".into(), manifest.provenance.source.clone().into());
    attrs.insert(
        "history".into(),
        format!("terrabake {} export", env!("CARGO_PKG_VERSION")).into(),
    );
    let mut geozarr = Map::new();
    if let Some((gm, t)) = &grid_mapping {
        coordinates.push(Coordinate {
            name: "spatial_ref".into(),
            dims: vec![],
            values: CoordinateValues::I64(vec![0]),
            attrs: gm.clone(),
        });
        geozarr = geozarr_attributes(georef.and_then(|g| g.epsg), t, width, height);
    }

    // One azimuth dimension where every directional layer shares it.
    let directional =
        |l: &Layer<Mmap>| l.bands() > 1 && l.entry().band_azimuths.len() == l.bands() as usize;
    let mut azimuth_sets: Vec<&[f64]> = layers
        .iter()
        .filter(|l| directional(l))
        .map(|l| l.entry().band_azimuths.as_slice())
        .collect();
    azimuth_sets.dedup();
    let shared = azimuth_sets.len() <= 1;
    let mut variables = Vec::new();
    for layer in layers {
        let entry = layer.entry();
        let name = entry.name.clone();
        let mut dims = vec!["y".to_string(), "x".to_string()];
        if layer.bands() > 1 {
            let dim = if directional(layer) {
                let dim = if shared {
                    "azimuth".to_string()
                } else {
                    format!("azimuth_{name}")
                };
                let mut a = Map::new();
                a.insert("units".into(), "degree".into());
                a.insert(
                    "long_name".into(),
                    "compass azimuth, clockwise from north".into(),
                );
                push_coordinate(
                    &mut coordinates,
                    &dim,
                    CoordinateValues::F64(entry.band_azimuths.clone()),
                    a,
                );
                dim
            } else {
                let dim = format!("{name}_band");
                let mut a = Map::new();
                a.insert("long_name".into(), format!("band of {name}").into());
                push_coordinate(
                    &mut coordinates,
                    &dim,
                    CoordinateValues::I64((0..i64::from(layer.bands())).collect()),
                    a,
                );
                dim
            };
            dims.insert(0, dim);
        }
        let (storage, mut attrs) = variable_attributes(asset, layer)?;
        if grid_mapping.is_some() {
            attrs.insert("grid_mapping".into(), "spatial_ref".into());
            attrs.insert("coordinates".into(), "spatial_ref".into());
        }
        let fill = match storage {
            Storage::Decoded => f64::NAN,
            Storage::Codes(elem) => fill_value(elem, layer.fill_bits()),
        };
        variables.push(Variable {
            name,
            layer,
            dims,
            storage,
            fill,
            attrs,
        });
    }
    Ok(Dataset {
        width,
        height,
        coordinates,
        variables,
        attrs,
        geozarr,
    })
}

/// Tile `(tx, ty)` of band `band` of `layer`, whole (padded past the edge
/// with the layer's fill, NaN where decoded), as the little-endian
/// elements of `storage`.
pub fn tile_bytes(
    layer: &Layer<Mmap>,
    storage: Storage,
    band: u32,
    tx: u32,
    ty: u32,
) -> anyhow::Result<Vec<u8>> {
    match storage {
        Storage::Codes(_) => {
            let chunk = layer.stored_tile(band, tx, ty)?;
            Ok(stored_codes(layer, &chunk, storage)?.into_owned())
        }
        Storage::Decoded => decoded_tile(layer, band, tx, ty),
    }
}

/// A stored tile's codes, decoded from its codec (borrowed where stored
/// raw): what [`tile_bytes`] gives for [`Storage::Codes`], for a caller
/// that has the stored tile already.
pub fn stored_codes<'c>(
    layer: &Layer<Mmap>,
    chunk: &StoredChunk<'c>,
    storage: Storage,
) -> anyhow::Result<Cow<'c, [u8]>> {
    let chunk_len = (layer.tile_size() as usize).pow(2) * storage.elem().size();
    anyhow::ensure!(
        chunk.raw_len as usize == chunk_len,
        "layer {}: a tile holds {} bytes, not a whole tile's {chunk_len}",
        layer.entry().key(),
        chunk.raw_len
    );
    if chunk.codec == Codec::Raw {
        return Ok(Cow::Borrowed(chunk.bytes));
    }
    let mut codes = vec![0u8; chunk_len];
    let n = chunk.decode_into(storage.elem().size(), &mut codes)?;
    anyhow::ensure!(
        n == chunk_len,
        "layer {}: a tile decoded to {n} bytes, not {chunk_len}",
        layer.entry().key()
    );
    Ok(Cow::Owned(codes))
}

/// A tile decoded to `f32` (NaN past the edge), little-endian.
fn decoded_tile(layer: &Layer<Mmap>, band: u32, tx: u32, ty: u32) -> anyhow::Result<Vec<u8>> {
    let tile = layer.tile_size();
    let (x0, y0) = (tx * tile, ty * tile);
    let (w, h) = (tile.min(layer.width() - x0), tile.min(layer.height() - y0));
    let mut window = vec![0f32; (w * h) as usize];
    layer.read_window_f32(band, [x0, y0, w, h], &mut window)?;
    let mut raw = vec![0u8; (tile as usize).pow(2) * 4];
    for (r, cells) in raw.chunks_exact_mut(tile as usize * 4).enumerate() {
        for (c, cell) in cells.chunks_exact_mut(4).enumerate() {
            let v = if (r as u32) < h && (c as u32) < w {
                window[r * w as usize + c]
            } else {
                f32::NAN
            };
            cell.copy_from_slice(&v.to_le_bytes());
        }
    }
    Ok(raw)
}

/// Adds coordinate `name` unless a layer before added it.
fn push_coordinate(
    coordinates: &mut Vec<Coordinate>,
    name: &str,
    values: CoordinateValues,
    attrs: Map<String, Value>,
) {
    if coordinates.iter().all(|c| c.name != name) {
        coordinates.push(Coordinate {
            name: name.into(),
            dims: vec![name.into()],
            values,
            attrs,
        });
    }
}

/// How a layer is stored in the export, and its CF attributes: units,
/// names, what the GeoTIFF export's metadata says of it (stage, method,
/// parameters, each band's description), and the CF packing attributes
/// of quantised codes.
pub fn variable_attributes(
    asset: &Asset<Mmap>,
    layer: &Layer<Mmap>,
) -> crate::Result<(Storage, Map<String, Value>)> {
    let entry = layer.entry();
    let name = entry.name.as_str();
    let mut attrs = Map::new();
    attrs.insert("long_name".into(), layer_title(name, 0, 1).into());
    attrs.insert("units".into(), cf_units(layer_unit(name)).into());
    let cog = cog_for_layer(asset, layer, &Default::default())?;
    for (key, value) in &cog.metadata.dataset {
        let key = key.to_lowercase();
        if !matches!(key.as_str(), "terrabake_version" | "terrabake_source") {
            attrs.insert(key, value.clone().into());
        }
    }
    if layer.bands() > 1 {
        let descriptions: Vec<Value> = cog
            .metadata
            .bands
            .iter()
            .map(|b| b.description.clone().into())
            .collect();
        attrs.insert("band_descriptions".into(), descriptions.into());
    }
    let affine = !(entry.elem == ElemType::U16 && name == terrabake_format::layers::CONE_SLOPE);
    if !affine {
        attrs.insert(
            "comment".into(),
            "decoded from the asset's u16 half-angle codes".into(),
        );
        return Ok((Storage::Decoded, attrs));
    }
    if let Some(q) = entry.quantization {
        attrs.insert("scale_factor".into(), json!(q.scale));
        attrs.insert("add_offset".into(), json!(q.offset));
        if let Some(code) = q.nodata {
            attrs.insert("_FillValue".into(), json!(code));
        }
    }
    Ok((Storage::Codes(entry.elem), attrs))
}

/// The value behind a layer's fill bits.
fn fill_value(elem: ElemType, bits: u64) -> f64 {
    match elem {
        ElemType::F32 => f64::from(f32::from_bits(bits as u32)),
        ElemType::F16 => half::f16::from_bits(bits as u16).to_f64(),
        ElemType::U8 => (bits & 0xff) as f64,
        ElemType::U16 => (bits & 0xffff) as f64,
        ElemType::I16 => f64::from(bits as u16 as i16),
        ElemType::U32 => (bits & 0xffff_ffff) as f64,
        _ => f64::NAN,
    }
}

/// A unit as UDUNITS (CF) writes it.
fn cf_units(unit: &str) -> &str {
    match unit {
        "deg" => "degree",
        "Wh/m2" => "W h m-2",
        "" => "1",
        u => u,
    }
}

/// GeoZarr's `spatial:` and `proj:` conventions (v1), registered in
/// `zarr_conventions`: the affine transform (x resolution, 0, x of the
/// upper-left corner, 0, y resolution, y of the corner), the grid's shape
/// and its EPSG code.
fn geozarr_attributes(
    epsg: Option<u32>,
    t: &[f64; 6],
    width: u32,
    height: u32,
) -> Map<String, Value> {
    let mut conventions = vec![json!({
        "schema_url": "https://raw.githubusercontent.com/zarr-conventions/spatial/refs/tags/v1/schema.json",
        "spec_url": "https://github.com/zarr-conventions/spatial/blob/v1/README.md",
        "uuid": "689b58e2-cf7b-45e0-9fff-9cfc0883d6b4",
        "name": "spatial",
        "description": "Spatial coordinate information",
    })];
    let mut a = Map::new();
    a.insert("spatial:dimensions".into(), json!(["y", "x"]));
    a.insert("spatial:transform_type".into(), "affine".into());
    a.insert(
        "spatial:transform".into(),
        json!([t[1], t[2], t[0], t[4], t[5], t[3]]),
    );
    a.insert("spatial:shape".into(), json!([height, width]));
    a.insert("spatial:registration".into(), "pixel".into());
    if let Some(epsg) = epsg {
        conventions.push(json!({
            "schema_url": "https://raw.githubusercontent.com/zarr-conventions/geo-proj/refs/tags/v1/schema.json",
            "spec_url": "https://github.com/zarr-conventions/geo-proj/blob/v1/README.md",
            "uuid": "f17cb550-5864-4468-aeb7-f3180cfb622f",
            "name": "proj",
            "description": "Coordinate reference system information for geospatial data",
        }));
        a.insert("proj:code".into(), format!("EPSG:{epsg}").into());
    }
    a.insert("zarr_conventions".into(), conventions.into());
    a
}
