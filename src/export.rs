//! Layers out of an asset: GeoTIFF (georeferencing and nodata kept, so GDAL
//! and QGIS read back the same geotransform), OpenEXR (float, for engines),
//! and PNG previews for people.
//!
//! Every writer here writes to a fresh, exclusively created temporary file
//! beside the output and renames it on success, so a failed export never
//! leaves a half-written file where a good one stood, and a link planted at
//! a temporary name is never written through.

use std::fs::{self, File};
use std::io::{BufWriter, Seek, Write};
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use terrabake_format::manifest::Georef;
use terrabake_format::{Asset, Layer, Mmap};
use tiff::encoder::{colortype, TiffEncoder, TiffKind, TiffKindBig, TiffKindStandard};
use tiff::tags::Tag;

use crate::legend::{Legend, Ramp, Stretch};
use crate::progress::Progress;

/// Writes `path` through a temporary file beside it
/// ([`terrabake_format::fsio::create_temp`]): `write` fills it, and it is
/// fsynced and renamed into place (replacing a link at `path`, never
/// writing through one); on error it is removed.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    // A missing directory is made, as the asset writers make theirs.
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        fs::create_dir_all(parent)
            .with_context(|| format!("{}: cannot create the directory", parent.display()))?;
    }
    let (file, tmp) = terrabake_format::fsio::create_temp(path).with_context(|| {
        format!(
            "{}: cannot create a temporary file beside it",
            path.display()
        )
    })?;
    let result = (|| -> Result<()> {
        let mut out = BufWriter::with_capacity(1 << 20, file);
        write(&mut out)?;
        let file = out.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        fs::rename(&tmp, path)
            .with_context(|| format!("{}: cannot rename into place", path.display()))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// The GeoTIFF tags of a grid: georeferencing (scaled to a pyramid level's
/// coarser posts) and GDAL_NODATA.
#[derive(Debug, Clone, Default)]
pub struct GeoTags {
    pub georef: Option<Georef>,
    pub nodata: Option<String>,
}

impl GeoTags {
    /// Tags for a layer at `level`: each post of level L covers 2^L posts.
    pub fn for_level(georef: Option<&Georef>, nodata: Option<String>, level: u32) -> Self {
        let georef = georef.map(|g| {
            let mut g = g.clone();
            let f = f64::from(1u32 << level.min(30));
            for i in [1, 2, 4, 5] {
                g.geotransform[i] *= f;
            }
            g
        });
        Self { georef, nodata }
    }
}

/// Writes a float32 GeoTIFF of `width x height` and `bands` samples per
/// pixel (interleaved), strip by strip: `fill` gets the first row and a
/// buffer of whole rows to fill (NaN = nodata, which is written as
/// `tags.nodata` when that is set). BigTIFF past 4 GB.
pub fn write_geotiff_f32(
    path: &Path,
    (width, height, bands): (u32, u32, u16),
    tags: &GeoTags,
    mut fill: impl FnMut(u32, &mut [f32]) -> Result<()>,
) -> Result<()> {
    let nodata_value = tags
        .nodata
        .as_deref()
        .and_then(crate::source::parse_nodata)
        .map(|v| v as f32);
    write_atomically(path, |out| {
        let big = u64::from(width) * u64::from(height) * u64::from(bands) * 4 > 3_900_000_000;
        let fill = |y0: u32, rows: &mut [f32]| -> Result<()> {
            fill(y0, rows)?;
            if let Some(nd) = nodata_value {
                rows.iter_mut().filter(|z| z.is_nan()).for_each(|z| *z = nd);
            }
            Ok(())
        };
        if big {
            write_tiff::<_, TiffKindBig>(out, (width, height, bands), tags, fill)
        } else {
            write_tiff::<_, TiffKindStandard>(out, (width, height, bands), tags, fill)
        }
    })
}

fn write_tiff<W: Write + Seek, K: TiffKind>(
    out: W,
    (width, height, bands): (u32, u32, u16),
    tags: &GeoTags,
    mut fill: impl FnMut(u32, &mut [f32]) -> Result<()>,
) -> Result<()> {
    let tiff_err = |e: tiff::TiffError| anyhow!("writing TIFF: {e}");
    let mut encoder = TiffEncoder::<W, K>::new_generic(out).map_err(tiff_err)?;
    let mut image = encoder
        .new_image::<colortype::Gray32Float>(width, height)
        .map_err(tiff_err)?;
    // Bands past the first are TIFF extra samples (GDAL reads them as bands).
    if bands > 1 {
        let extra = vec![tiff::tags::ExtraSamples::Unspecified; usize::from(bands) - 1];
        image.extra_samples(&extra).map_err(tiff_err)?;
    }
    let row_samples = width * u32::from(bands);
    // Strips of about 1 MiB: small enough to stream, large enough to be fast.
    let rows_per_strip = ((1u32 << 18) / row_samples.max(1)).clamp(1, height);
    image.rows_per_strip(rows_per_strip).map_err(tiff_err)?;
    if let Some(g) = &tags.georef {
        let t = g.geotransform;
        let dir = image.encoder();
        if t[2] == 0.0 && t[4] == 0.0 {
            dir.write_tag(Tag::ModelPixelScaleTag, &[t[1], -t[5], 0.0][..])
                .map_err(tiff_err)?;
            dir.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, t[0], t[3], 0.0][..])
                .map_err(tiff_err)?;
        } else {
            let m = [
                t[1], t[2], 0.0, t[0], t[4], t[5], 0.0, t[3], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                1.0,
            ];
            dir.write_tag(Tag::ModelTransformationTag, &m[..])
                .map_err(tiff_err)?;
        }
        if !g.geo_key_directory.is_empty() {
            dir.write_tag(Tag::GeoKeyDirectoryTag, &g.geo_key_directory[..])
                .map_err(tiff_err)?;
        }
        if !g.geo_double_params.is_empty() {
            dir.write_tag(Tag::GeoDoubleParamsTag, &g.geo_double_params[..])
                .map_err(tiff_err)?;
        }
        if !g.geo_ascii_params.is_empty() {
            dir.write_tag(Tag::GeoAsciiParamsTag, g.geo_ascii_params.as_str())
                .map_err(tiff_err)?;
        }
    }
    if let Some(nd) = &tags.nodata {
        image
            .encoder()
            .write_tag(Tag::GdalNodata, nd.as_str())
            .map_err(tiff_err)?;
    }
    let mut strip = vec![0f32; (rows_per_strip * row_samples) as usize];
    let mut y0 = 0;
    while y0 < height {
        let rows = rows_per_strip.min(height - y0);
        let buf = &mut strip[..(rows * row_samples) as usize];
        fill(y0, buf)?;
        image.write_strip(buf).map_err(tiff_err)?;
        y0 += rows;
    }
    image.finish().map_err(tiff_err)
}

/// Output kinds, by file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportKind {
    GeoTiff,
    Exr,
    Png,
}

impl ExportKind {
    pub fn from_path(path: &Path) -> Result<Self> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("tif" | "tiff") => Ok(Self::GeoTiff),
            Some("exr") => Ok(Self::Exr),
            Some("png") => Ok(Self::Png),
            _ => bail!("{}: export writes .tif, .exr or .png", path.display()),
        }
    }
}

/// How a PNG preview colours a layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PngStyle {
    /// 16-bit gray, no legend: a heightmap for engines, not a picture.
    /// Heights from min (black) to max (white); other layers from their 1st
    /// to their 99th percentile.
    Gray,
    /// Hypsometric tint (green lowlands to brown and white peaks) times a
    /// hillshade lit from the north-west at 45 degrees, with a legend;
    /// nodata is transparent. The default for heights.
    Relief,
    /// Viridis from the 1st to the 99th percentile, with a legend; nodata
    /// is transparent. The default for every other layer.
    Ramp,
}

impl PngStyle {
    /// The style for `layer` when none is asked for.
    pub fn default_for(layer: &str) -> Self {
        if is_height_like(layer) {
            PngStyle::Relief
        } else {
            PngStyle::Ramp
        }
    }
}

/// Heights and their pyramids: metres of the DEM, stretched over its range.
fn is_height_like(layer: &str) -> bool {
    layer == terrabake_format::HEIGHT_LAYER || layer.starts_with("pyramid")
}

/// What a layer's map shows, with its unit, for legends.
pub fn layer_title(layer: &str, band: u32, bands: u32) -> String {
    use terrabake_format::layers as l;
    let band = if bands > 1 {
        format!(", band {band} of {bands}")
    } else {
        String::new()
    };
    match layer {
        l::HEIGHT => "height (m)".into(),
        l::PYRAMID_MAX => "pyramid: tallest corner below (m)".into(),
        l::PYRAMID_MIN => "pyramid: lowest corner below (m)".into(),
        l::CONE_APEX => "cone apex height (m)".into(),
        l::CONE_SLOPE => "cone slope (m across per m up)".into(),
        l::HORIZON => format!("horizon angle (degrees){band}"),
        l::SVF => "sky-view factor (0-1)".into(),
        l::SVF_COSINE => "cosine sky-view factor (0-1)".into(),
        l::OPENNESS => "positive openness (degrees)".into(),
        l::HORIZON_EDGE => "bands open past the DEM's edge".into(),
        l::VIEWSHED => format!("seen from the observer (1 seen, 0 hidden){band}"),
        l::VIEWSHED_ANGLE => format!("elevation angle from the observer (degrees){band}"),
        l::TOTAL_VIEWSHED => "total viewshed: area seen (m2)".into(),
        other => format!("{other}{band}"),
    }
}

/// Exports `layer` to `out`: every band to GeoTIFF (one TIFF band each) and
/// OpenEXR (one channel each, `B0`, `B1`, ...), band `band` to a PNG.
pub fn export_layer(
    asset: &Asset<Mmap>,
    layer: &Layer<Mmap>,
    out: &Path,
    style: Option<PngStyle>,
    band: u32,
    progress: Progress,
) -> Result<()> {
    let style = style.unwrap_or_else(|| PngStyle::default_for(&layer.entry().name));
    let (w, h, bands) = (layer.width(), layer.height(), layer.bands());
    if band >= bands {
        bail!(
            "layer {} has {bands} band(s); --band {band} is past them",
            layer.entry().key()
        );
    }
    let bands16 =
        u16::try_from(bands).map_err(|_| anyhow!("{bands} bands is more than TIFF holds"))?;
    let manifest = asset.manifest();
    // All bands of rows y0.., pixel-interleaved.
    let read = |y0: u32, rows: &mut [f32]| -> Result<()> {
        if bands == 1 {
            return Ok(layer.read_rows_f32(0, y0, rows)?);
        }
        let n = rows.len() / bands as usize;
        let mut one = vec![0f32; n];
        for b in 0..bands as usize {
            layer.read_rows_f32(b as u32, y0, &mut one)?;
            for (i, v) in one.iter().enumerate() {
                rows[i * bands as usize + b] = *v;
            }
        }
        Ok(())
    };
    // The source's nodata value only for heights (a real horizon or svf
    // could equal it); NaN for the rest.
    let height_like = is_height_like(&layer.entry().name);
    match ExportKind::from_path(out)? {
        ExportKind::GeoTiff => {
            let nodata = Some(match (&manifest.nodata.source_value, height_like) {
                (Some(v), true) => v.clone(),
                _ => "nan".into(),
            });
            let tags = GeoTags::for_level(manifest.georef.as_ref(), nodata, layer.entry().level);
            let bar = progress.bar(u64::from(h), "export", "rows");
            write_geotiff_f32(out, (w, h, bands16), &tags, |y0, rows| {
                read(y0, rows)?;
                bar.set_position(u64::from(y0));
                Ok(())
            })?;
            bar.finish_and_clear();
            Ok(())
        }
        ExportKind::Exr => {
            // The exr crate encodes whole images: bound what we hold.
            if u64::from(w) * u64::from(h) * u64::from(bands) > 1 << 28 {
                bail!("layer {} is {w} x {h} x {bands}: EXR export holds the whole layer and is limited to 2^28 values; export GeoTIFF instead", layer.entry().key());
            }
            let mut channels = Vec::new();
            for b in 0..bands {
                let mut all = vec![0f32; w as usize * h as usize];
                layer.read_rows_f32(b, 0, &mut all)?;
                let name = if bands == 1 {
                    "Y".to_string()
                } else {
                    format!("B{b}")
                };
                channels.push((name, all));
            }
            write_atomically(out, |file| {
                use exr::prelude::*;
                let channels = channels
                    .into_iter()
                    .map(|(name, all)| AnyChannel::new(name.as_str(), FlatSamples::F32(all)))
                    .collect();
                let image =
                    Image::from_channels((w as usize, h as usize), AnyChannels::sort(channels));
                image
                    .write()
                    .to_buffered(file)
                    .map_err(|e| anyhow!("writing EXR: {e}"))
            })
        }
        ExportKind::Png => write_png_preview(out, layer, manifest, style, band, height_like),
    }
}

/// Largest side of a PNG preview; larger layers are subsampled.
pub const PREVIEW_MAX_SIDE: u32 = 4096;

fn write_png_preview(
    out: &Path,
    layer: &Layer<Mmap>,
    manifest: &terrabake_format::Manifest,
    style: PngStyle,
    band: u32,
    height_like: bool,
) -> Result<()> {
    let (w, h) = (layer.width(), layer.height());
    let step = w.max(h).div_ceil(PREVIEW_MAX_SIDE).max(1);
    let (pw, ph) = (w.div_ceil(step), h.div_ceil(step));
    let row_at = |y: u32| -> Result<Vec<f32>> {
        let mut full = vec![0f32; w as usize];
        layer.read_rows_f32(band, y.min(h - 1), &mut full)?;
        Ok((0..pw).map(|x| full[(x * step) as usize]).collect())
    };
    // Heights scale by the DEM's range; other layers by percentiles.
    let mut stretch = match (height_like, manifest.height_range) {
        (true, Some(r)) => Stretch::linear(r.min, r.max, "the DEM's full range"),
        _ => {
            let mut values = Vec::with_capacity(pw as usize * ph as usize);
            for py in 0..ph {
                values.extend(row_at(py * step)?);
            }
            Stretch::percentiles(values).unwrap_or_else(|| Stretch::linear(0.0, 1.0, "no values"))
        }
    };
    if style == PngStyle::Relief {
        stretch.note += "; lit from the north-west";
    }
    let legend = Legend {
        title: layer_title(&layer.entry().name, band, layer.bands()),
        ramp: match style {
            PngStyle::Relief => Ramp::Hypsometric,
            _ => Ramp::Viridis,
        },
        stretch,
    };
    // Metres per preview pixel, for the hillshade's slopes.
    let (dx, dy) = (
        manifest.cell_size.dx * f64::from(step),
        manifest.cell_size.dy * f64::from(step),
    );
    let legend_rows = match style {
        PngStyle::Gray => 0,
        _ => crate::legend::height(pw),
    };
    write_atomically(out, |file| {
        let mut enc = png::Encoder::new(file, pw, ph + legend_rows);
        match style {
            PngStyle::Gray => {
                enc.set_color(png::ColorType::Grayscale);
                enc.set_depth(png::BitDepth::Sixteen);
            }
            PngStyle::Relief | PngStyle::Ramp => {
                enc.set_color(png::ColorType::Rgba);
                enc.set_depth(png::BitDepth::Eight);
            }
        }
        let mut header = enc.write_header()?;
        let mut writer = header.stream_writer()?;
        let (mut above, mut here) = (row_at(0)?, row_at(0)?);
        for py in 0..ph {
            let below = row_at(((py + 1) * step).min(h - 1))?;
            let mut bytes = Vec::with_capacity(pw as usize * 4);
            for px in 0..pw as usize {
                let z = here[px];
                let t = legend.stretch.position(z);
                match style {
                    PngStyle::Gray => {
                        let v = if z.is_nan() {
                            0
                        } else {
                            (t * 65535.0).round() as u16
                        };
                        bytes.extend_from_slice(&v.to_be_bytes());
                    }
                    _ if z.is_nan() => bytes.extend_from_slice(&[0, 0, 0, 0]),
                    PngStyle::Ramp => {
                        let [r, g, b] = legend.ramp.colour(t);
                        bytes.extend_from_slice(&[r, g, b, 255]);
                    }
                    PngStyle::Relief => {
                        let pick = |v: f32| if v.is_nan() { z } else { v };
                        let left = pick(here[px.saturating_sub(1)]);
                        let right = pick(here[(px + 1).min(pw as usize - 1)]);
                        let (up, down) = (pick(above[px]), pick(below[px]));
                        let shade = hillshade(
                            f64::from(right - left) / (2.0 * dx),
                            f64::from(down - up) / (2.0 * dy),
                        );
                        let [r, g, b] = crate::legend::hypsometric(t);
                        let s = 0.35 + 0.65 * shade;
                        bytes.extend_from_slice(&[
                            (r * s) as u8,
                            (g * s) as u8,
                            (b * s) as u8,
                            255,
                        ]);
                    }
                }
            }
            writer.write_all(&bytes)?;
            above = std::mem::replace(&mut here, below);
        }
        if legend_rows > 0 {
            let panel: Vec<u8> = crate::legend::render(pw, &legend)
                .into_iter()
                .flat_map(|[r, g, b]| [r, g, b, 255])
                .collect();
            writer.write_all(&panel)?;
        }
        writer.finish()?;
        header.finish()?;
        Ok(())
    })
}

/// Lambert shading of a surface with slopes dz/dx (east) and dz/dy (south),
/// lit from azimuth 315 degrees (north-west) at 45 degrees elevation.
fn hillshade(dzdx: f64, dzdy: f64) -> f32 {
    let normal = [-dzdx, dzdy, 1.0];
    let len = (normal[0] * normal[0] + normal[1] * normal[1] + 1.0).sqrt();
    let (az, el) = (315f64.to_radians(), 45f64.to_radians());
    // x east, y north, z up.
    let light = [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()];
    let d = (normal[0] * light[0] + normal[1] * light[1] + normal[2] * light[2]) / len;
    d.clamp(0.0, 1.0) as f32
}
