//! Cloud-Optimized GeoTIFF, written in one streaming pass.
//!
//! A COG is an ordinary tiled GeoTIFF whose bytes are laid out for readers
//! that fetch ranges (GDAL's `/vsicurl/`, QGIS, rasterio): every image file
//! directory (IFD) first, the full resolution's then each overview's, and
//! then the tile data, smallest overview first and the full resolution
//! last, each image's tiles in TIFF's own index order (band by band, then
//! row-major). GDAL's `validate_cloud_optimized_geotiff.py` checks exactly
//! that order; `pipelines/gis/check_cog.sh` runs it in `make test`.
//!
//! ```text
//!  ┌────────┬──────────────┬──────────────┬─────┬────────────┬─────┬──────────────┐
//!  │ header │ IFD 0 + tags │ IFD 1 + tags │ ... │ tiles of n │ ... │ tiles of 0   │
//!  │ 8 / 16 │ full res.    │ overview 1   │     │ (smallest) │     │ (full res.)  │
//!  └────────┴──────────────┴──────────────┴─────┴────────────┴─────┴──────────────┘
//! ```
//!
//! The order is the opposite of the order the data come in (full
//! resolution first, row by row), so tiles are compressed as their tile
//! row completes, appended to an unnamed temporary file beside the output
//! (gone with the process, whatever happens), and copied into place once
//! every size is known; the IFDs are written then, with their final
//! offsets. Memory is bounded by a tile row per level: each band is read a
//! tile row at a time, and each overview level holds the one tile row it is
//! filling, fed by pairs of rows from the level above.
//!
//! Tiles are float32, compressed with deflate or zstd after TIFF's
//! floating-point predictor (3: bytes split into planes, most significant
//! first, then differenced), which is what GDAL writes with `PREDICTOR=3`.
//! Multi-band layers are band-interleaved (`PlanarConfiguration` 2), so a
//! reader of one azimuth fetches only that band's tiles. Whether the file
//! is BigTIFF is decided from the compressed size, so only files that need
//! it are.
//!
//! Band descriptions, units and the dataset's metadata go in GDAL's own
//! XML tag (42112), which GDAL, rasterio and QGIS show as band descriptions
//! and metadata; nodata in GDAL's tag 42113.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;

use anyhow::{Context, Result};
use rayon::prelude::*;

use terrabake_format::manifest::Georef;

use crate::error::bail;
use crate::plumbing::output::write_atomically;

/// The GeoTIFF tags of a grid: georeferencing (scaled to a pyramid level's
/// coarser posts) and GDAL_NODATA.
#[derive(Debug, Clone, Default)]
pub struct GeoTags {
    pub georef: Option<Georef>,
    pub nodata: Option<String>,
}

impl GeoTags {
    /// Tags for a layer at `level`: each post of level L covers 2^L posts.
    pub(crate) fn for_level(georef: Option<&Georef>, nodata: Option<String>, level: u32) -> Self {
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

/// Tile edge when none is asked for: GDAL's COG default.
pub const DEFAULT_TILE: u32 = 512;

/// How tiles are compressed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Compression {
    /// Deflate (zlib) with the floating-point predictor: every TIFF reader.
    #[default]
    Deflate,
    /// Zstandard with the floating-point predictor: smaller and faster;
    /// GDAL 2.3 and later.
    Zstd,
    /// Uncompressed.
    None,
}

impl Compression {
    fn tag(self) -> u16 {
        match self {
            Compression::Deflate => 8,
            Compression::Zstd => 50000,
            Compression::None => 1,
        }
    }
}

/// How overviews are made from the level above: 2 x 2 posts to one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Resampling {
    /// The north-west post of the four: angles, codes and counts, whose
    /// mean would be a value no post has.
    Nearest,
    /// The mean of the posts that are not nodata: heights and fractions.
    Average,
}

/// GDAL's metadata for the dataset and each band.
#[derive(Debug, Clone, Default)]
pub struct Metadata {
    /// Dataset items, `name = value`.
    pub dataset: Vec<(String, String)>,
    /// One per band (or none).
    pub bands: Vec<BandMetadata>,
}

/// What GDAL shows for one band.
#[derive(Debug, Clone, Default)]
pub struct BandMetadata {
    /// `GDALRasterBand::GetDescription`.
    pub description: String,
    /// `GetUnitType` (e.g. `deg`, `m`); empty for none.
    pub unit: String,
    /// Further band items, `name = value`.
    pub items: Vec<(String, String)>,
}

/// An image to write: its shape, tiling and tags.
#[derive(Debug, Clone)]
pub struct Cog {
    pub width: u32,
    pub height: u32,
    pub bands: u16,
    /// Tile edge: a multiple of 16 (TIFF's rule); 256 or 512 in practice.
    pub tile: u32,
    pub compression: Compression,
    pub resampling: Resampling,
    pub tags: GeoTags,
    pub metadata: Metadata,
    /// Internal overviews (a COG's); `false` for DEMs written as inputs,
    /// which only their full resolution is read of.
    pub overviews: bool,
}

impl Cog {
    /// The size of every level, full resolution first: halved (rounding
    /// up) until one tile holds the whole image, as GDAL's COG driver does.
    pub fn levels(&self) -> Vec<(u32, u32)> {
        let mut levels = vec![(self.width, self.height)];
        let (mut w, mut h) = (self.width, self.height);
        while self.overviews && (w > self.tile || h > self.tile) {
            (w, h) = (w.div_ceil(2), h.div_ceil(2));
            levels.push((w, h));
        }
        levels
    }

    /// Writes the COG to `path` (atomically: see
    /// [`write_atomically`]). `read(band, y0, rows)` fills whole rows of one
    /// band from row `y0`, NaN for nodata; `advance(rows)` is told as rows
    /// are done, for a progress bar.
    pub fn write(
        &self,
        path: &Path,
        mut read: impl FnMut(u32, u32, &mut [f32]) -> Result<()>,
        mut advance: impl FnMut(u64),
    ) -> crate::Result<()> {
        if self.width == 0 || self.height == 0 || self.bands == 0 {
            bail!("{}: cannot write an empty image", path.display());
        }
        if self.tile == 0 || !self.tile.is_multiple_of(16) {
            bail!("tile edge {} is not a multiple of 16", self.tile);
        }
        let nodata = self
            .tags
            .nodata
            .as_deref()
            .and_then(crate::io::source::parse_nodata)
            .map(|v| v as f32);
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create the directory", dir.display()))?;
        let scratch = tempfile::tempfile_in(dir)
            .with_context(|| format!("{}: cannot create a scratch file", dir.display()))?;
        crate::plumbing::resources::ensure_memory(
            self.memory(),
            &format!(
                "{}: a {} x {} GeoTIFF in tiles of {} (a tile row per overview level)",
                path.display(),
                self.width,
                self.height,
                self.tile
            ),
        )?;
        let mut tiles = TileSink {
            file: BufWriter::with_capacity(1 << 20, scratch),
            at: 0,
            chunks: self
                .levels()
                .iter()
                .map(|&(w, h)| {
                    vec![(0, 0); self.tiles_across(w) * self.tiles_across(h) * self.bands as usize]
                })
                .collect(),
            tile: self.tile,
            compression: self.compression,
            nodata,
        };
        let mut pyramid = Pyramid::new(self);
        for band in 0..u32::from(self.bands) {
            pyramid.start(band);
            let mut y0 = 0;
            while y0 < self.height {
                let n = self.tile.min(self.height - y0);
                // Read straight into the full resolution's tile row.
                read(band, y0, pyramid.top_rows(n))?;
                pyramid.flush(0, &mut tiles)?;
                advance(u64::from(n));
                y0 += n;
            }
        }
        let chunks = std::mem::take(&mut tiles.chunks);
        let mut scratch = tiles
            .file
            .into_inner()
            .map_err(|e| e.into_error())
            .context("writing the scratch file")?;
        let mut layout = self.layout(&chunks, false);
        if layout.total > u64::from(u32::MAX) - (1 << 20) {
            layout = self.layout(&chunks, true);
        }
        write_atomically(path, |out| {
            out.write_all(&layout.head)?;
            // Data: smallest overview first, each level's tiles in order.
            let mut buf = Vec::new();
            for level in chunks.iter().rev() {
                for &(offset, len) in level {
                    buf.resize(len as usize, 0);
                    scratch.seek(SeekFrom::Start(offset))?;
                    scratch.read_exact(&mut buf)?;
                    out.write_all(&buf)?;
                }
            }
            Ok(())
        })
    }

    /// Bytes [`Self::write`] holds at once: a tile row of f32 per level
    /// (the levels' widths add up to under twice the image's), and the
    /// offset and length of every tile of every level and band.
    pub fn memory(&self) -> u64 {
        let levels = self.levels();
        let rows: u64 = levels
            .iter()
            .map(|&(w, _)| u64::from(w) * u64::from(self.tile) * 4)
            .sum();
        let tiles: u64 = levels
            .iter()
            .map(|&(w, h)| (self.tiles_across(w) * self.tiles_across(h)) as u64)
            .sum();
        rows + tiles * u64::from(self.bands) * 16
    }

    fn tiles_across(&self, len: u32) -> usize {
        len.div_ceil(self.tile) as usize
    }

    /// The header and every IFD, with the data offsets that follow them.
    fn layout(&self, chunks: &[Vec<(u64, u32)>], big: bool) -> Layout {
        let levels = self.levels();
        let ifds: Vec<Vec<Entry>> = levels
            .iter()
            .enumerate()
            .map(|(k, &dims)| self.entries(k, dims, &chunks[k], big))
            .collect();
        let head_len = if big { 16 } else { 8 };
        let ifd_lens: Vec<u64> = ifds.iter().map(|e| ifd_len(e, big)).collect();
        let data_start = head_len + ifd_lens.iter().sum::<u64>();
        // Where each tile lands: levels from the smallest, in order.
        let mut offsets: Vec<Vec<u64>> = vec![Vec::new(); chunks.len()];
        let mut at = data_start;
        for (k, level) in chunks.iter().enumerate().rev() {
            for &(_, len) in level {
                offsets[k].push(at);
                at += u64::from(len);
            }
        }
        let mut head = Vec::with_capacity(data_start as usize);
        if big {
            head.extend_from_slice(b"II");
            head.extend_from_slice(&43u16.to_le_bytes());
            head.extend_from_slice(&8u16.to_le_bytes());
            head.extend_from_slice(&0u16.to_le_bytes());
            head.extend_from_slice(&16u64.to_le_bytes());
        } else {
            head.extend_from_slice(b"II");
            head.extend_from_slice(&42u16.to_le_bytes());
            head.extend_from_slice(&8u32.to_le_bytes());
        }
        let mut ifd_at = head_len;
        for (k, mut entries) in ifds.into_iter().enumerate() {
            for e in &mut entries {
                if e.tag == TAG_TILE_OFFSETS {
                    e.value = if big {
                        Value::Long8(offsets[k].clone())
                    } else {
                        Value::Long(offsets[k].iter().map(|&o| o as u32).collect())
                    };
                }
            }
            let next = if k + 1 < levels.len() {
                ifd_at + ifd_lens[k]
            } else {
                0
            };
            encode_ifd(&mut head, &entries, ifd_at, next, big);
            ifd_at += ifd_lens[k];
        }
        debug_assert_eq!(head.len() as u64, data_start);
        Layout { head, total: at }
    }

    /// The tags of level `k` (0: full resolution; it alone carries the
    /// georeferencing and metadata, as GDAL's own COGs do).
    fn entries(
        &self,
        k: usize,
        (w, h): (u32, u32),
        chunks: &[(u64, u32)],
        big: bool,
    ) -> Vec<Entry> {
        let bands = usize::from(self.bands);
        let short = |tag, v: Vec<u16>| Entry {
            tag,
            value: Value::Short(v),
        };
        let long = |tag, v: u32| Entry {
            tag,
            value: Value::Long(vec![v]),
        };
        let mut e = Vec::new();
        if k > 0 {
            // NewSubfileType: a reduced-resolution copy.
            e.push(long(254, 1));
        }
        e.push(long(256, w));
        e.push(long(257, h));
        e.push(short(258, vec![32; bands]));
        e.push(short(259, vec![self.compression.tag()]));
        // Photometric: min-is-black.
        e.push(short(262, vec![1]));
        e.push(short(277, vec![self.bands]));
        // Planar configuration: 2 (band-interleaved) for several bands.
        e.push(short(284, vec![if bands > 1 { 2 } else { 1 }]));
        if self.compression != Compression::None {
            // Predictor 3: floating point.
            e.push(short(317, vec![3]));
        }
        e.push(long(322, self.tile));
        e.push(long(323, self.tile));
        // Placeholder of the right length; `layout` fills it in.
        e.push(Entry {
            tag: TAG_TILE_OFFSETS,
            value: if big {
                Value::Long8(vec![0; chunks.len()])
            } else {
                Value::Long(vec![0; chunks.len()])
            },
        });
        e.push(Entry {
            tag: 325,
            value: Value::Long(chunks.iter().map(|&(_, len)| len).collect()),
        });
        if bands > 1 {
            // Extra samples: unspecified (GDAL reads them as bands).
            e.push(short(338, vec![0; bands - 1]));
        }
        // Sample format: IEEE float.
        e.push(short(339, vec![3; bands]));
        if k == 0 {
            if let Some(g) = &self.tags.georef {
                let t = g.geotransform;
                if t[2] == 0.0 && t[4] == 0.0 {
                    e.push(Entry {
                        tag: 33550,
                        value: Value::Double(vec![t[1], -t[5], 0.0]),
                    });
                    e.push(Entry {
                        tag: 33922,
                        value: Value::Double(vec![0.0, 0.0, 0.0, t[0], t[3], 0.0]),
                    });
                } else {
                    e.push(Entry {
                        tag: 34264,
                        value: Value::Double(vec![
                            t[1], t[2], 0.0, t[0], t[4], t[5], 0.0, t[3], 0.0, 0.0, 0.0, 0.0, 0.0,
                            0.0, 0.0, 1.0,
                        ]),
                    });
                }
                if !g.geo_key_directory.is_empty() {
                    e.push(short(34735, g.geo_key_directory.clone()));
                }
                if !g.geo_double_params.is_empty() {
                    e.push(Entry {
                        tag: 34736,
                        value: Value::Double(g.geo_double_params.clone()),
                    });
                }
                if !g.geo_ascii_params.is_empty() {
                    e.push(Entry {
                        tag: 34737,
                        value: Value::Ascii(g.geo_ascii_params.clone()),
                    });
                }
            }
            let xml = self.metadata.xml();
            if !xml.is_empty() {
                e.push(Entry {
                    tag: 42112,
                    value: Value::Ascii(xml),
                });
            }
        }
        if let Some(nd) = &self.tags.nodata {
            e.push(Entry {
                tag: 42113,
                value: Value::Ascii(nd.clone()),
            });
        }
        e
    }
}

/// A single-band float32 GeoTIFF, uncompressed and without overviews,
/// written a tile row at a time: `fill(y0, rows)` fills whole rows from `y0`, NaN for nodata (written
/// as `tags.nodata` when that is set). DEMs for tests and benchmarks.
pub fn write_f32(
    path: &Path,
    (width, height): (u32, u32),
    tags: &GeoTags,
    mut fill: impl FnMut(u32, &mut [f32]) -> Result<()>,
) -> crate::Result<()> {
    let cog = Cog {
        width,
        height,
        bands: 1,
        tile: DEFAULT_TILE,
        compression: Compression::None,
        resampling: Resampling::Average,
        tags: tags.clone(),
        metadata: Metadata::default(),
        overviews: false,
    };
    cog.write(path, |_, y0, rows| fill(y0, rows), |_| {})
}

impl Metadata {
    /// GDAL's `<GDALMetadata>` document; empty when there is nothing to say.
    pub(crate) fn xml(&self) -> String {
        let mut items = String::new();
        let mut item = |name: &str, sample: Option<usize>, role: Option<&str>, value: &str| {
            items += &format!("  <Item name=\"{}\"", escape(name));
            if let Some(s) = sample {
                items += &format!(" sample=\"{s}\"");
            }
            if let Some(r) = role {
                items += &format!(" role=\"{r}\"");
            }
            items += &format!(">{}</Item>\n", escape(value));
        };
        for (name, value) in &self.dataset {
            item(name, None, None, value);
        }
        for (b, band) in self.bands.iter().enumerate() {
            if !band.description.is_empty() {
                item(
                    "DESCRIPTION",
                    Some(b),
                    Some("description"),
                    &band.description,
                );
            }
            if !band.unit.is_empty() {
                item("UNITTYPE", Some(b), Some("unittype"), &band.unit);
            }
            for (name, value) in &band.items {
                item(name, Some(b), None, value);
            }
        }
        if items.is_empty() {
            String::new()
        } else {
            format!("<GDALMetadata>\n{items}</GDALMetadata>\n")
        }
    }
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

const TAG_TILE_OFFSETS: u16 = 324;

struct Layout {
    /// The header and every IFD with its out-of-line values.
    head: Vec<u8>,
    /// The file's length.
    total: u64,
}

#[derive(Debug, Clone)]
enum Value {
    Short(Vec<u16>),
    Long(Vec<u32>),
    Long8(Vec<u64>),
    Double(Vec<f64>),
    /// NUL-terminated on disk.
    Ascii(String),
}

impl Value {
    /// TIFF's field type and count.
    fn kind(&self) -> (u16, u64) {
        match self {
            Value::Short(v) => (3, v.len() as u64),
            Value::Long(v) => (4, v.len() as u64),
            Value::Long8(v) => (16, v.len() as u64),
            Value::Double(v) => (12, v.len() as u64),
            Value::Ascii(s) => (2, s.len() as u64 + 1),
        }
    }

    fn bytes(&self) -> Vec<u8> {
        match self {
            Value::Short(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Value::Long(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Value::Long8(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Value::Double(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Value::Ascii(s) => s.bytes().chain([0]).collect(),
        }
    }
}

#[derive(Debug, Clone)]
struct Entry {
    tag: u16,
    value: Value,
}

/// Bytes of an IFD and its out-of-line values (each padded to even).
fn ifd_len(entries: &[Entry], big: bool) -> u64 {
    let (count, entry, next, inline) = if big { (8, 20, 8, 8) } else { (2, 12, 4, 4) };
    let values: u64 = entries
        .iter()
        .map(|e| e.value.bytes().len() as u64)
        .filter(|&n| n > inline)
        .map(|n| n + n % 2)
        .sum();
    count + entry * entries.len() as u64 + next + values
}

/// Appends the IFD that starts at file offset `at` (its values right
/// after it), pointing at the IFD at `next` (0: the last).
fn encode_ifd(out: &mut Vec<u8>, entries: &[Entry], at: u64, next: u64, big: bool) {
    let mut entries = entries.to_vec();
    entries.sort_by_key(|e| e.tag);
    let (inline, entry_len) = if big { (8usize, 20u64) } else { (4, 12) };
    let head = if big { 8 } else { 2 } + entry_len * entries.len() as u64 + if big { 8 } else { 4 };
    let mut values = Vec::new();
    let mut fields = Vec::new();
    for e in &entries {
        let (kind, count) = e.value.kind();
        let mut bytes = e.value.bytes();
        fields.extend_from_slice(&e.tag.to_le_bytes());
        fields.extend_from_slice(&kind.to_le_bytes());
        if big {
            fields.extend_from_slice(&count.to_le_bytes());
        } else {
            fields.extend_from_slice(&(count as u32).to_le_bytes());
        }
        if bytes.len() <= inline {
            bytes.resize(inline, 0);
            fields.extend_from_slice(&bytes);
        } else {
            let offset = at + head + values.len() as u64;
            if big {
                fields.extend_from_slice(&offset.to_le_bytes());
            } else {
                fields.extend_from_slice(&(offset as u32).to_le_bytes());
            }
            values.extend_from_slice(&bytes);
            if values.len() % 2 == 1 {
                values.push(0);
            }
        }
    }
    if big {
        out.extend_from_slice(&(entries.len() as u64).to_le_bytes());
    } else {
        out.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    }
    out.extend_from_slice(&fields);
    if big {
        out.extend_from_slice(&next.to_le_bytes());
    } else {
        out.extend_from_slice(&(next as u32).to_le_bytes());
    }
    out.extend_from_slice(&values);
}

/// Compressed tiles, appended to the scratch file as they are made.
struct TileSink {
    file: BufWriter<File>,
    at: u64,
    /// Per level, per tile in TIFF's index order: offset in the scratch
    /// file and length.
    chunks: Vec<Vec<(u64, u32)>>,
    tile: u32,
    compression: Compression,
    nodata: Option<f32>,
}

impl TileSink {
    /// Cuts the rows `row0 ..` of band `band` of level `k` (a tile row,
    /// `width` wide) into tiles, compresses them (in parallel) and appends
    /// them.
    fn tile_row(
        &mut self,
        (k, band): (usize, u32),
        (width, height): (u32, u32),
        row0: u32,
        rows: &[f32],
    ) -> Result<()> {
        let t = self.tile as usize;
        let w = width as usize;
        let n_rows = rows.len() / w;
        let across = width.div_ceil(self.tile) as usize;
        let (compression, nodata) = (self.compression, self.nodata);
        let tiles: Vec<Vec<u8>> = (0..across)
            .into_par_iter()
            .map(|tx| {
                // Past the image's edge: nodata (GDAL pads likewise).
                let mut samples = vec![nodata.unwrap_or(f32::NAN); t * t];
                let x0 = tx * t;
                let cols = t.min(w - x0);
                for r in 0..n_rows {
                    samples[r * t..][..cols].copy_from_slice(&rows[r * w + x0..][..cols]);
                }
                if let Some(nd) = nodata {
                    samples
                        .iter_mut()
                        .filter(|z| z.is_nan())
                        .for_each(|z| *z = nd);
                }
                Ok(encode_tile(&samples, t, compression)?)
            })
            .collect::<Result<_>>()?;
        let down = height.div_ceil(self.tile) as usize;
        let ty = (row0 / self.tile) as usize;
        for (tx, bytes) in tiles.into_iter().enumerate() {
            let len = u32::try_from(bytes.len()).context("a tile past 4 GiB")?;
            self.chunks[k][band as usize * down * across + ty * across + tx] = (self.at, len);
            self.file.write_all(&bytes)?;
            self.at += bytes.len() as u64;
        }
        Ok(())
    }
}

/// One tile (`t x t` samples, row-major) as stored: the floating-point
/// predictor, then the codec.
pub fn encode_tile(samples: &[f32], t: usize, compression: Compression) -> crate::Result<Vec<u8>> {
    if compression == Compression::None {
        return Ok(samples.iter().flat_map(|v| v.to_le_bytes()).collect());
    }
    let mut planes = vec![0u8; samples.len() * 4];
    for (row, out) in samples.chunks_exact(t).zip(planes.chunks_exact_mut(4 * t)) {
        // Byte planes, most significant first ...
        for (i, v) in row.iter().enumerate() {
            for (p, b) in v.to_be_bytes().into_iter().enumerate() {
                out[p * t + i] = b;
            }
        }
        // ... then each byte less the one before it.
        for i in (1..out.len()).rev() {
            out[i] = out[i].wrapping_sub(out[i - 1]);
        }
    }
    Ok(match compression {
        Compression::Deflate => {
            let mut z = flate2::write::ZlibEncoder::new(
                Vec::with_capacity(planes.len() / 2),
                flate2::Compression::new(6),
            );
            z.write_all(&planes)?;
            z.finish()?
        }
        Compression::Zstd => zstd::bulk::compress(&planes, 9)?,
        Compression::None => unreachable!("returned above"),
    })
}

/// The tile row each level is filling, for one band at a time. A level
/// hands its tile row down when it is written: each pair of its rows (the
/// last alone, where the level's height is odd) becomes one row of the
/// next level. A tile row holds an even number of rows, so pairs never
/// straddle two, and half a tile row of the next level comes of each.
struct Pyramid {
    band: u32,
    resampling: Resampling,
    tile: u32,
    levels: Vec<Level>,
}

struct Level {
    width: u32,
    height: u32,
    /// The tile row being filled: `filled` rows from row `row0`.
    rows: Vec<f32>,
    row0: u32,
    filled: u32,
}

impl Pyramid {
    fn new(cog: &Cog) -> Self {
        let levels = cog
            .levels()
            .into_iter()
            .map(|(width, height)| Level {
                width,
                height,
                rows: vec![0.0; cog.tile as usize * width as usize],
                row0: 0,
                filled: 0,
            })
            .collect();
        Self {
            band: 0,
            resampling: cog.resampling,
            tile: cog.tile,
            levels,
        }
    }

    /// Starts band `band` at the first row of every level.
    fn start(&mut self, band: u32) {
        self.band = band;
        for level in &mut self.levels {
            (level.row0, level.filled) = (0, 0);
        }
    }

    /// The full resolution's next tile row, `n` rows, for the caller to fill.
    fn top_rows(&mut self, n: u32) -> &mut [f32] {
        let top = &mut self.levels[0];
        top.filled = n;
        &mut top.rows[..n as usize * top.width as usize]
    }

    /// Writes level `k`'s tile row and hands its pairs of rows down,
    /// writing the next level's tile row in turn when that is complete.
    fn flush(&mut self, k: usize, sink: &mut TileSink) -> Result<()> {
        let (above, below) = self.levels.split_at_mut(k + 1);
        let level = &mut above[k];
        let w = level.width as usize;
        let rows = &level.rows[..level.filled as usize * w];
        sink.tile_row(
            (k, self.band),
            (level.width, level.height),
            level.row0,
            rows,
        )?;
        level.row0 += level.filled;
        level.filled = 0;
        let Some(next) = below.first_mut() else {
            return Ok(());
        };
        let nw = next.width as usize;
        for pair in rows.chunks(2 * w) {
            let (a, b) = pair.split_at(w);
            let out = &mut next.rows[next.filled as usize * nw..][..nw];
            downsample(a, (!b.is_empty()).then_some(b), out, self.resampling);
            next.filled += 1;
        }
        if next.filled == self.tile || next.row0 + next.filled == next.height {
            self.flush(k + 1, sink)?;
        }
        Ok(())
    }
}

/// One row of the next level (`out`) from two rows (or the last, alone).
fn downsample(a: &[f32], b: Option<&[f32]>, out: &mut [f32], how: Resampling) {
    for (x, v) in out.iter_mut().enumerate() {
        let (x0, x1) = (2 * x, (2 * x + 1).min(a.len() - 1));
        *v = match how {
            Resampling::Nearest => a[x0],
            Resampling::Average => {
                let below = b.map_or([f32::NAN; 2], |b| [b[x0], b[x1]]);
                let (sum, n) = [a[x0], a[x1], below[0], below[1]]
                    .into_iter()
                    .filter(|v| !v.is_nan())
                    .fold((0f64, 0u32), |(s, n), v| (s + f64::from(v), n + 1));
                if n == 0 {
                    f32::NAN
                } else {
                    (sum / f64::from(n)) as f32
                }
            }
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_halve_until_one_tile_holds_the_image() {
        let cog = |w, h| Cog {
            width: w,
            height: h,
            bands: 1,
            tile: 256,
            compression: Compression::Deflate,
            resampling: Resampling::Nearest,
            tags: GeoTags::default(),
            metadata: Metadata::default(),
            overviews: true,
        };
        assert_eq!(cog(256, 10).levels(), vec![(256, 10)]);
        assert_eq!(
            cog(1201, 1201).levels(),
            vec![(1201, 1201), (601, 601), (301, 301), (151, 151)]
        );
    }

    #[test]
    fn average_skips_nodata_and_nearest_takes_the_north_west_post() {
        let a = [1.0, 3.0, f32::NAN];
        let b = [5.0, f32::NAN, f32::NAN];
        let down = |how| {
            let mut out = [0f32; 2];
            downsample(&a, Some(&b), &mut out, how);
            out
        };
        assert_eq!(down(Resampling::Average)[0], 3.0);
        assert!(down(Resampling::Average)[1].is_nan());
        let nearest = down(Resampling::Nearest);
        assert_eq!(nearest[0], 1.0);
        assert!(nearest[1].is_nan());
    }

    #[test]
    fn metadata_is_escaped_xml_with_band_roles() {
        let m = Metadata {
            dataset: vec![("SOURCE".into(), "a<b>&\"c\"".into())],
            bands: vec![BandMetadata {
                description: "horizon azimuth 21.80 deg, line".into(),
                unit: "deg".into(),
                items: vec![],
            }],
        };
        let xml = m.xml();
        assert!(xml.contains("<Item name=\"SOURCE\">a&lt;b&gt;&amp;&quot;c&quot;</Item>"));
        assert!(xml.contains(
            "<Item name=\"DESCRIPTION\" sample=\"0\" role=\"description\">horizon azimuth 21.80 deg, line</Item>"
        ));
    }
}
