//! The manifest: everything about an asset that is not a tile. Self-describing
//! JSON, so that fields can be added without a format version bump (readers
//! ignore fields they do not know; every field added later has a default).

use serde::{Deserialize, Serialize};

use crate::layout::{Codec, ElemType};

/// Name of the height layer that ingest writes; every stage reads it.
pub const HEIGHT_LAYER: &str = crate::layers::HEIGHT;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format_version: u32,
    /// DEM shape in posts (samples): columns and rows.
    pub width: u32,
    pub height: u32,
    /// Tile edge in elements for every layer of this asset (a power of two).
    pub tile_size: u32,
    pub cell_size: CellSize,
    /// `None` when the source carried no georeferencing.
    pub georef: Option<Georef>,
    pub vertical: Vertical,
    pub nodata: Nodata,
    /// Range of the valid heights; `None` when every post is nodata.
    pub height_range: Option<HeightRange>,
    pub provenance: Provenance,
    pub layers: Vec<LayerEntry>,
    /// Layer files that an earlier manifest named and this one does not,
    /// kept for a grace period after the commit that retired them so that a
    /// reader that read the earlier manifest still finds them. Readers never
    /// open them; writers remove them once the grace has passed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub retired: Vec<Retired>,
}

/// A layer file kept after the commit that stopped naming it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Retired {
    pub file: String,
    /// Seconds since the Unix epoch of the commit that retired it.
    pub since_unix: u64,
}

/// Horizontal post spacing in metres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CellSize {
    pub dx: f64,
    pub dy: f64,
    /// How dx and dy were found: `given` (command line), `projected` (pixel
    /// scale of a metric CRS), `geographic-centre` (pixel scale in degrees,
    /// converted at the DEM's centre latitude on the WGS84 ellipsoid; the
    /// spacing changes with latitude, see `Georef`), or `assumed` (1 m).
    pub source: String,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[non_exhaustive]
pub enum CrsKind {
    Geographic,
    Projected,
    Unknown,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RasterType {
    /// A value stands for the area of its pixel (GeoTIFF's PixelIsArea).
    Area,
    /// A value stands for a point at the pixel's corner (PixelIsPoint).
    Point,
}

/// Georeferencing as the source gave it, kept so that exports round-trip.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Georef {
    pub crs_kind: CrsKind,
    /// EPSG code of the CRS when the source named one.
    pub epsg: Option<u32>,
    /// GDAL-style geotransform of the pixel grid, in CRS units:
    /// `x = t[0] + col * t[1] + row * t[2]`, `y = t[3] + col * t[4] + row * t[5]`
    /// for the pixel's top-left corner; post (col, row) lies at the pixel's
    /// centre `(col + 0.5, row + 0.5)` when `raster_type` is `area`, and at
    /// `(col, row)` when it is `point`.
    pub geotransform: [f64; 6],
    pub raster_type: RasterType,
    /// The GeoTIFF GeoKeyDirectory, GeoDoubleParams and GeoAsciiParams tags,
    /// verbatim (empty when the source was not a GeoTIFF).
    #[serde(default)]
    pub geo_key_directory: Vec<u16>,
    #[serde(default)]
    pub geo_double_params: Vec<f64>,
    #[serde(default)]
    pub geo_ascii_params: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Vertical {
    pub units: String,
    /// Heights in the asset are `source * scale + offset`.
    pub scale: f64,
    pub offset: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Nodata {
    /// The source's nodata value as text (GDAL's convention: "-32767", "nan").
    pub source_value: Option<String>,
    /// Posts that are nodata in the asset: the source's nodata, NaN and
    /// infinities. In f32 layers they are stored as NaN.
    pub count: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HeightRange {
    pub min: f32,
    pub max: f32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// The source file as given on the command line.
    pub source: String,
    pub source_len: u64,
    /// Source format, e.g. `geotiff`, `hgt`, `raw`, `png`, `exr`.
    pub source_format: String,
    /// `terrabake <version>` of the tool that created the asset.
    pub tool: String,
    /// Every stage that wrote layers, in order, with its parameters.
    pub stages: Vec<StageRecord>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageRecord {
    pub stage: String,
    pub params: serde_json::Value,
    pub tool: String,
    /// Seconds since the Unix epoch when the stage finished.
    pub finished_unix: u64,
    /// `name@level` of every layer the stage wrote.
    pub outputs: Vec<String>,
    /// `name@level` of every layer the stage read. When a later run
    /// rewrites one of them, this record and its outputs are dropped, so a
    /// derived layer never outlives what it was derived from.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inputs: Vec<String>,
}

/// One layer: where its file is and what it holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LayerEntry {
    pub name: String,
    pub level: u32,
    pub elem: ElemType,
    pub bands: u32,
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    /// The codec asked for; `raw` tiles may still be deduplicated constants.
    pub codec: Codec,
    /// File name inside the asset directory.
    pub file: String,
    pub file_len: u64,
    /// The layer footer's `index_xxh3`, as 16 hex digits: binds this entry to
    /// exactly one file version.
    pub index_xxh3: String,
    pub chunks: u64,
    /// Chunks that are constant and share one stored copy per value.
    pub constant_chunks: u64,
    /// Bytes of chunk data on disk, after deduplication and compression.
    pub stored_bytes: u64,
    /// The stage that wrote the layer.
    pub stage: String,
    /// What the values mean (units, encoding); free text for people.
    #[serde(default)]
    pub description: String,
    /// For quantised layers: how stored values map to real ones.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quantization: Option<Quantization>,
    /// For layers with one band per direction (horizon angles): the compass
    /// azimuth of each band, in degrees clockwise from north.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub band_azimuths: Vec<f64>,
    /// For the `horizon` layer: the posts whose horizon the reader serves
    /// exactly between bands ([`crate::features`]). A reader that does not
    /// know them serves the bands alone, as before they were.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub features: Option<crate::features::HorizonFeatures>,
}

/// An affine map from stored to real values: `real = offset + scale * stored`
/// (`stored` being the element read as a number: a `u16` as an integer, an
/// `f16` as its float value), with an optional stored value that means
/// nodata (horizon angles keep code 0 for it).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quantization {
    pub offset: f64,
    pub scale: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nodata: Option<u64>,
}

impl Quantization {
    /// The real value of integer code `code`; `None` for the nodata code.
    pub fn value(&self, code: u64) -> Option<f64> {
        (self.nodata != Some(code)).then_some(self.offset + self.scale * code as f64)
    }
}

impl LayerEntry {
    pub fn key(&self) -> String {
        format!("{}@{}", self.name, self.level)
    }

    /// What [`Manifest::validate`] checks of one layer.
    fn validate(&self, m: &Manifest) -> std::result::Result<(), String> {
        let bad = |what: String| Err(format!("layer {}: {what}", self.key()));
        let name_ok = !self.name.is_empty()
            && self
                .name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
        if !name_ok {
            return bad("names use only letters, digits, '_' and '-'".into());
        }
        if let Err(e) = crate::fsio::check_file_name(&self.file) {
            return bad(e);
        }
        if self.width == 0 || self.height == 0 || self.bands == 0 {
            return bad(format!(
                "empty grid {} x {} x {}",
                self.width, self.height, self.bands
            ));
        }
        if self.width > m.width || self.height > m.height {
            return bad(format!(
                "{} x {} is larger than the asset's {} x {}",
                self.width, self.height, m.width, m.height
            ));
        }
        if self.tile_size != m.tile_size {
            return bad(format!(
                "tile_size {} is not the asset's {}",
                self.tile_size, m.tile_size
            ));
        }
        let tiles = u64::from(self.width.div_ceil(self.tile_size))
            * u64::from(self.height.div_ceil(self.tile_size));
        if self.chunks != u64::from(self.bands) * tiles || self.constant_chunks > self.chunks {
            return bad(format!(
                "{} chunks ({} constant) for {} bands of {tiles} tiles",
                self.chunks, self.constant_chunks, self.bands
            ));
        }
        if let Some(q) = &self.quantization {
            if !(q.offset.is_finite() && q.scale.is_finite() && q.scale != 0.0) {
                return bad("quantization offset and scale must be finite, scale non-zero".into());
            }
        }
        if !self.band_azimuths.is_empty()
            && (self.band_azimuths.len() != self.bands as usize
                || self.band_azimuths.iter().any(|a| !(0.0..360.0).contains(a)))
        {
            return bad(format!(
                "{} band_azimuths for {} bands, or one outside [0, 360)",
                self.band_azimuths.len(),
                self.bands
            ));
        }
        // Every reader finds the bands around an azimuth by bisection
        // (`horizons::bands_around`, the GPU shader), so out of order they
        // would serve wrong angles without a word. Bakes of over about 800
        // line bands before 2026-12-07 put the step at 0 last.
        if let Some(k) = self.band_azimuths.windows(2).position(|p| p[1] < p[0]) {
            return bad(format!(
                "band_azimuths out of compass order: band {} at {} after band {k} at {}; bake the horizons again",
                k + 1,
                self.band_azimuths[k + 1],
                self.band_azimuths[k]
            ));
        }
        if let Some(features) = &self.features {
            if self.band_azimuths.is_empty() {
                return bad("features on a layer without band_azimuths".into());
            }
            features.validate((self.width, self.height)).or_else(bad)?;
        }
        Ok(())
    }
}

/// The post spacings, in metres, a manifest may state. Tracers divide by
/// them and step with them: a spacing outside this range (a picometre, a
/// light year) is a corrupt or hostile manifest, not a DEM.
pub const CELL_SIZE_RANGE: (f64, f64) = (1e-6, 1e7);

impl Manifest {
    /// Checks every field a reader relies on, before any file is opened:
    /// the shape, the spacing a tracer divides by, the height range, the
    /// nodata count, every layer's name, file name, shape, tiling and
    /// encoding, and that the height layer is there. Returns what is wrong.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let (w, h, ts) = (self.width, self.height, self.tile_size);
        if w == 0 || h == 0 {
            return Err(format!("empty grid {w} x {h}"));
        }
        if !ts.is_power_of_two() || !(16..=4096).contains(&ts) {
            return Err(format!("tile_size {ts} is not a power of two in 16..=4096"));
        }
        let (lo, hi) = CELL_SIZE_RANGE;
        for (axis, d) in [("dx", self.cell_size.dx), ("dy", self.cell_size.dy)] {
            if !(lo..=hi).contains(&d) {
                return Err(format!(
                    "cell_size.{axis} = {d} m is outside {lo:e}..={hi:e} m"
                ));
            }
        }
        if !(self.vertical.scale.is_finite() && self.vertical.offset.is_finite()) {
            return Err("vertical scale and offset must be finite".into());
        }
        if let Some(g) = &self.georef {
            // JSON has no NaN: a writer would store null, which no reader parses.
            let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
            if !finite(&g.geotransform) || !finite(&g.geo_double_params) {
                return Err(
                    "georef.geotransform or geo_double_params has a value that is not finite"
                        .into(),
                );
            }
        }
        if let Some(r) = self.height_range {
            if !(r.min.is_finite() && r.max.is_finite() && r.min <= r.max) {
                return Err(format!(
                    "height_range {}..{} is not a finite range with min <= max",
                    r.min, r.max
                ));
            }
        }
        let posts = u64::from(w) * u64::from(h);
        if self.nodata.count > posts {
            return Err(format!(
                "nodata.count {} exceeds the grid's {posts} posts",
                self.nodata.count
            ));
        }
        if self.nodata.count < posts && self.height_range.is_none() {
            return Err("height_range is missing though some posts have data".into());
        }
        let mut keys = std::collections::HashSet::new();
        let mut files = std::collections::HashSet::new();
        for l in &self.layers {
            l.validate(self)?;
            if !keys.insert((l.name.as_str(), l.level)) {
                return Err(format!("layer {} is listed twice", l.key()));
            }
            if !files.insert(l.file.as_str()) {
                return Err(format!("file {} is named by two layers", l.file));
            }
        }
        for r in &self.retired {
            crate::fsio::check_file_name(&r.file)?;
        }
        match self.layer(HEIGHT_LAYER, 0) {
            None => Err(format!("no {HEIGHT_LAYER}@0 layer")),
            Some(l) if l.elem != ElemType::F32 || (l.width, l.height) != (w, h) => Err(format!(
                "{HEIGHT_LAYER}@0 is {} x {} {}, not the grid's {w} x {h} f32",
                l.width,
                l.height,
                l.elem.name()
            )),
            Some(_) => Ok(()),
        }
    }

    pub fn layer(&self, name: &str, level: u32) -> Option<&LayerEntry> {
        self.layers
            .iter()
            .find(|l| l.name == name && l.level == level)
    }

    /// Replaces the entry with the same name and level, or appends.
    pub fn upsert_layer(&mut self, entry: LayerEntry) {
        match self
            .layers
            .iter_mut()
            .find(|l| l.name == entry.name && l.level == entry.level)
        {
            Some(slot) => *slot = entry,
            None => self.layers.push(entry),
        }
    }
}

impl Georef {
    /// The offset, in pixels, from a pixel's top-left corner to its post.
    fn post_offset(&self) -> f64 {
        match self.raster_type {
            RasterType::Area => 0.5,
            RasterType::Point => 0.0,
        }
    }

    /// The geotransform of pixel corners (GDAL's pixel-is-area form, what
    /// rioxarray, CF's `GeoTransform` and GeoZarr take), whatever the raster
    /// type: a pixel-is-point origin moved back half a pixel.
    pub fn corner_geotransform(&self) -> [f64; 6] {
        let mut t = self.geotransform;
        let shift = self.post_offset() - 0.5;
        t[0] += shift * (t[1] + t[2]);
        t[3] += shift * (t[4] + t[5]);
        t
    }

    /// CRS coordinates of post `(col, row)` (fractional posts allowed).
    pub fn post_to_world(&self, col: f64, row: f64) -> (f64, f64) {
        let t = &self.geotransform;
        let (c, r) = (col + self.post_offset(), row + self.post_offset());
        (t[0] + c * t[1] + r * t[2], t[3] + c * t[4] + r * t[5])
    }

    /// Grid coordinates (in posts) of the CRS point `(x, y)`; `None` when the
    /// geotransform is singular.
    pub fn world_to_post(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let t = &self.geotransform;
        let det = t[1] * t[5] - t[2] * t[4];
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let (dx, dy) = (x - t[0], y - t[3]);
        let col = (t[5] * dx - t[2] * dy) / det;
        let row = (t[1] * dy - t[4] * dx) / det;
        Some((col - self.post_offset(), row - self.post_offset()))
    }
}
