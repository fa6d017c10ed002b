//! DEM sources, read row band by row band so that ingest never holds a whole
//! DEM: each reader keeps at most one of its format's natural units (a TIFF
//! strip or tile row, a PNG row, a raw row band) besides the caller's buffer.
//!
//! Every reader turns samples into heights the same way
//! ([`HeightMapping::height`]): the source's nodata value, NaN and infinities
//! become NaN (nodata), everything else `value * scale + offset`.

mod exr;
mod geotiff;
mod hgt;
mod png;
mod raw;

use std::path::Path;

use anyhow::{Context, Result};
use terrabake_format::manifest::Georef;

use crate::error::bail;

pub use crate::io::source::raw::{ByteOrder, RawSampleType, RawSpec};

/// What a source says about itself besides its samples.
#[derive(Debug, Clone)]
pub struct SourceInfo {
    /// `geotiff`, `hgt`, `raw`, `png`, `exr`.
    pub format: &'static str,
    pub width: u32,
    pub height: u32,
    pub georef: Option<Georef>,
    /// Nodata as the source states it (GDAL's text form).
    pub nodata: Option<String>,
    /// Vertical units when the source says, else metres are assumed.
    pub vertical_units: Option<String>,
    /// Linear unit of a projected CRS in metres (1 for metre).
    pub linear_unit_m: f64,
    /// Human description of the sample type, e.g. `int16`.
    pub sample_type: String,
}

/// A DEM that yields rows of heights in order.
pub trait RasterSource {
    fn info(&self) -> &SourceInfo;
    /// Fills `out` with rows `y0 .. y0 + out.len() / width` as heights
    /// (NaN for nodata). Calls come with increasing `y0`.
    fn read_rows(&mut self, y0: u32, out: &mut [f32], map: &HeightMapping) -> Result<()>;
}

/// How raw samples become heights.
#[derive(Debug, Clone, Copy)]
pub struct HeightMapping {
    pub nodata: Option<f64>,
    pub scale: f64,
    pub offset: f64,
}

impl HeightMapping {
    /// Height of one sample; `single` says the source sample is an f32, so
    /// that its nodata compares in f32 (GDAL writes `-3.4028235e+38`, which
    /// is f32::MIN only after rounding to f32).
    #[inline]
    pub fn height(&self, value: f64, single: bool) -> f32 {
        let is_nodata = match self.nodata {
            Some(nd) if single => value as f32 == nd as f32 || (nd.is_nan() && value.is_nan()),
            Some(nd) => value == nd || (nd.is_nan() && value.is_nan()),
            None => false,
        };
        let z = value * self.scale + self.offset;
        if is_nodata || !z.is_finite() || !(z as f32).is_finite() {
            f32::NAN
        } else {
            z as f32
        }
    }
}

/// Parses GDAL's textual nodata ("-32767", "nan", "-3.4028234663852886e+38").
/// A value within the rounding of a 7-digit spelling of +-FLT_MAX (one part
/// in a million) is +-FLT_MAX: lidar products write `-3.402823e+38` for
/// holes of exactly -FLT_MAX, which as written is 23 f32 steps from it, and
/// GDAL masks those holes.
pub(crate) fn parse_nodata(text: &str) -> Option<f64> {
    let t = text.trim().trim_end_matches('\0');
    if t.eq_ignore_ascii_case("nan") {
        return Some(f64::NAN);
    }
    let v = t.parse::<f64>().ok()?;
    let float_max = f64::from(f32::MAX);
    Some(if (v.abs() / float_max - 1.0).abs() <= 1e-6 {
        float_max.copysign(v)
    } else {
        v
    })
}

/// Opens `path` by its content (TIFF magic) or extension. Every reader
/// works out from the header alone what it will hold at once (a strip, a
/// tile row, a whole EXR image) and refuses, before allocating anything,
/// a source that needs more than `budget` bytes for the `rows` output rows
/// that ingest reads at a time.
pub fn open(
    path: &Path,
    raw: Option<&RawSpec>,
    rows: u32,
    budget: u64,
) -> crate::Result<Box<dyn RasterSource>> {
    open_unmarked(path, raw, rows, budget)
        .map_err(|e| crate::error::mark(crate::ErrorKind::Source, e).into())
}

fn open_unmarked(
    path: &Path,
    raw: Option<&RawSpec>,
    rows: u32,
    budget: u64,
) -> Result<Box<dyn RasterSource>> {
    let memory = Memory { rows, budget };
    let meta =
        std::fs::metadata(path).with_context(|| format!("{}: cannot read", path.display()))?;
    if meta.is_dir() {
        bail!("{}: is a directory, not a DEM file", path.display());
    }
    if let Some(spec) = raw {
        return Ok(Box::new(raw::RawSource::open(path, spec, memory)?));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let mut magic = [0u8; 8];
    {
        use std::io::Read;
        let mut f = std::fs::File::open(path)
            .with_context(|| format!("{}: cannot open", path.display()))?;
        f.read(&mut magic)
            .with_context(|| format!("{}: cannot read", path.display()))?;
    }
    let source: Box<dyn RasterSource> = if magic.starts_with(b"II*\0")
        || magic.starts_with(b"MM\0*")
        || magic.starts_with(b"II+\0")
        || magic.starts_with(b"MM\0+")
    {
        Box::new(geotiff::GeoTiffSource::open(path, memory)?)
    } else if magic.starts_with(b"\x89PNG") {
        Box::new(png::PngSource::open(path, memory)?)
    } else if magic.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        Box::new(exr::ExrSource::open(path, memory)?)
    } else if ext == "hgt" {
        Box::new(hgt::HgtSource::open(path, memory)?)
    } else if matches!(ext.as_str(), "tif" | "tiff") {
        bail!(
            "{}: not a TIFF file (no TIFF byte-order mark)",
            path.display()
        )
    } else if matches!(ext.as_str(), "f32" | "i16" | "r16" | "raw" | "bin") {
        bail!(
            "{}: raw heights need --raw-shape WxH and --raw-type (and --byte-order)",
            path.display()
        )
    } else {
        bail!(
            "{}: unknown DEM format (expected GeoTIFF, .hgt, PNG, OpenEXR, or raw with --raw-shape)",
            path.display()
        )
    };
    Ok(source)
}

/// What a reader may hold at once: output rows per read and the budget.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Memory {
    pub rows: u32,
    pub budget: u64,
}

impl Memory {
    /// Refuses a source whose reading would hold more than the budget:
    /// `held` bytes in the reader (`what` says what they are) plus the
    /// caller's `rows` rows of f32 heights.
    pub fn check(
        &self,
        path: &Path,
        width: u64,
        height: u64,
        held: u64,
        what: &str,
    ) -> crate::Result<()> {
        let rows = u64::from(self.rows).min(height);
        let need = held.saturating_add(width.saturating_mul(rows).saturating_mul(4));
        if need > self.budget {
            bail!(
                "{}: reading it needs about {} MiB at once ({what}, and {rows} rows of {width} heights), more than the memory budget of {} MiB; raise --max-memory, or rewrite the DEM in smaller strips or tiles (gdal_translate -co TILED=YES)",
                path.display(),
                need.div_ceil(1 << 20),
                self.budget >> 20
            );
        }
        Ok(())
    }
}

/// Checks a DEM shape before anything is allocated for it.
pub(crate) fn check_shape(path: &Path, width: u64, height: u64) -> Result<()> {
    if width == 0 || height == 0 {
        bail!("{}: empty raster ({width} x {height})", path.display());
    }
    if width > u64::from(u32::MAX / 2) || height > u64::from(u32::MAX / 2) {
        bail!(
            "{}: raster {width} x {height} is larger than terrabake supports (2^31 - 1 per side)",
            path.display()
        );
    }
    if width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(8))
        .is_none()
    {
        bail!("{}: raster {width} x {height} overflows", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodata_nan_and_infinities_become_nan() {
        let map = HeightMapping {
            nodata: Some(-32767.0),
            scale: 1.0,
            offset: 0.0,
        };
        assert!(map.height(-32767.0, false).is_nan());
        assert!(map.height(f64::INFINITY, true).is_nan());
        assert!(map.height(f64::NEG_INFINITY, true).is_nan());
        assert!(map.height(f64::NAN, true).is_nan());
        assert_eq!(map.height(-32766.0, false), -32766.0);
        // GDAL's textual float32 minimum matches the f32 sample after rounding.
        let min = HeightMapping {
            nodata: parse_nodata("-3.4028235e+38"),
            scale: 1.0,
            offset: 0.0,
        };
        assert!(min.height(f64::from(f32::MIN), true).is_nan());
        // Rounded spellings of -FLT_MAX (lidar DSMs) are -FLT_MAX, for f32
        // and f64 samples alike; a value merely near it is not.
        for tag in ["-3.402823e+38", "-3.4028235e38", "-3.4028234663852886e+38"] {
            let rounded = HeightMapping {
                nodata: parse_nodata(tag),
                scale: 1.0,
                offset: 0.0,
            };
            assert!(rounded.height(f64::from(f32::MIN), true).is_nan(), "{tag}");
            assert!(rounded.height(f64::from(f32::MIN), false).is_nan(), "{tag}");
            assert_eq!(rounded.height(131.1, true), 131.1, "{tag}");
        }
        assert_eq!(parse_nodata("-3.3e38"), Some(-3.3e38));
        // A value that overflows f32 after scaling is nodata, not infinity.
        let big = HeightMapping {
            nodata: None,
            scale: 1e300,
            offset: 0.0,
        };
        assert!(big.height(1e10, false).is_nan());
        assert!(parse_nodata(" nan\0").unwrap().is_nan());
        assert_eq!(parse_nodata("-9999\0"), Some(-9999.0));
        assert_eq!(parse_nodata("none"), None);
    }
}
