//! GeoTIFF through the `tiff` crate, one strip or tile row at a time.
//!
//! The decoder handles striped and tiled layouts, BigTIFF, the compressions
//! (none, deflate, LZW, zstd, PackBits) and predictors 1-3. We add what it
//! leaves to the caller: sparse chunks (byte count 0 means "never written",
//! which GDAL reads as nodata), the GeoTIFF tags, GDAL_NODATA, and GDAL's
//! mask band (an internal mask IFD or a `FILE.msk` beside the file), whose
//! zero posts are nodata as GDAL reads them.
//!
//! Assets are north-up: row 0 is the northern edge, column 0 the western.
//! A source written south-up (a positive pixel height: row 0 is the
//! southern edge) or east-left (a negative pixel width) is flipped as it is
//! read, and its geotransform with it, so that its posts keep their places
//! on the ground; a rotated or sheared geotransform is refused by name (a
//! grid whose rows are not parallels cannot be walked as one).

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::{anyhow, Context, Result};
use rayon::prelude::*;
use tiff::decoder::{ChunkType, Decoder, DecodingResult, Limits};
use tiff::tags::Tag;
use tiff::ColorType;

use super::{check_shape, HeightMapping, Memory, RasterSource, SourceInfo};
use crate::error::bail;
use crate::terrain::geo;

pub struct GeoTiffSource {
    path: PathBuf,
    /// One decoder per rayon thread: a `Decoder` reads one chunk at a time,
    /// so chunks are decoded in parallel by independent decoders.
    decoders: Vec<Mutex<Decoder<BufReader<File>>>>,
    info: SourceInfo,
    /// Strip or tile size; a strip spans the whole width.
    chunk_w: u32,
    chunk_h: u32,
    chunks_across: u32,
    byte_counts: Vec<u64>,
    single: bool,
    /// The last decoded chunk row, kept when the next read starts inside
    /// it: its index and heights (`width x chunk_h`, row-major, as stored).
    held: Option<(u32, Vec<f32>)>,
    /// GDAL's mask band, when the file has one: zero means nodata.
    mask: Option<Mask>,
    /// The file is south-up (rows are read bottom first) or east-left
    /// (each row is reversed).
    flip_rows: bool,
    flip_columns: bool,
}

impl GeoTiffSource {
    pub fn open(path: &Path, memory: Memory) -> crate::Result<Self> {
        let what = |m: &str| format!("{}: {m}", path.display());
        let open_decoder = || -> Result<Decoder<BufReader<File>>> {
            let file = File::open(path).with_context(|| what("cannot open"))?;
            let mut limits = Limits::default();
            // The decoder itself never allocates past the budget, whatever
            // the header claims; large DEMs have large offset arrays.
            let budget = usize::try_from(memory.budget).unwrap_or(usize::MAX);
            limits.decoding_buffer_size = budget;
            limits.intermediate_buffer_size = budget;
            limits.ifd_value_size = (256 << 20).min(budget);
            Ok(Decoder::new(BufReader::with_capacity(1 << 16, file))
                .map_err(|e| anyhow!("{}", what(&format!("not a readable TIFF: {e}"))))?
                .with_limits(limits))
        };
        let mut decoder = open_decoder()?;
        let (width, height) = decoder
            .dimensions()
            .map_err(|e| anyhow!("{}", what(&format!("bad dimensions: {e}"))))?;
        check_shape(path, width.into(), height.into())?;
        let colortype = decoder
            .colortype()
            .map_err(|e| anyhow!("{}", what(&format!("unsupported pixel layout: {e}"))))?;
        let bits = match colortype {
            ColorType::Gray(b) => b,
            other => bail!(
                "{}",
                what(&format!(
                    "{other:?} pixels: terrabake reads single-band DEMs (one sample per pixel)"
                ))
            ),
        };
        let sample_format = decoder
            .find_tag_unsigned::<u16>(Tag::SampleFormat)
            .ok()
            .flatten()
            .unwrap_or(1);
        let sample_type = match (sample_format, bits) {
            (1, 8 | 16 | 32) => format!("uint{bits}"),
            (2, 8 | 16 | 32) => format!("int{bits}"),
            (3, 32 | 64) => format!("float{bits}"),
            (f, b) => bail!(
                "{}",
                what(&format!(
                    "unsupported sample format {f} with {b} bits (supported: int8/16/32, uint8/16/32, float32/64)"
                ))
            ),
        };
        let (chunk_w, chunk_h, byte_count_tag) = match decoder.get_chunk_type() {
            ChunkType::Strip => {
                let rows = decoder
                    .find_tag_unsigned::<u32>(Tag::RowsPerStrip)
                    .ok()
                    .flatten()
                    .unwrap_or(height)
                    .clamp(1, height);
                (width, rows, Tag::StripByteCounts)
            }
            ChunkType::Tile => {
                let tw = decoder.get_tag_u32(Tag::TileWidth).ok();
                let th = decoder.get_tag_u32(Tag::TileLength).ok();
                match (tw, th) {
                    (Some(tw), Some(th)) if tw > 0 && th > 0 && tw <= 1 << 16 && th <= 1 << 16 => {
                        (tw, th, Tag::TileByteCounts)
                    }
                    _ => bail!("{}", what("tiled TIFF without valid TileWidth/TileLength")),
                }
            }
        };
        let chunks_across = width.div_ceil(chunk_w);
        let chunks_down = height.div_ceil(chunk_h);
        // Held at once: the decoded chunk rows one read spans, as f32, twice
        // (the chunks and the assembled rows), and each thread's chunk in
        // its own sample type while it is converted.
        let (w64, cw, ch) = (u64::from(width), u64::from(chunk_w), u64::from(chunk_h));
        let spans = u64::from(memory.rows.min(height)).div_ceil(ch) + 1;
        let chunk_rows = spans * (u64::from(chunks_across) * cw).max(w64) * ch * 4 * 2;
        let converting = rayon::current_num_threads() as u64 * cw * ch * (u64::from(bits) / 8 + 4);
        let unit = if chunks_across == 1 { "strip" } else { "tile" };
        memory.check(
            path,
            w64,
            u64::from(height),
            chunk_rows.saturating_add(converting),
            &format!("{unit}s of {chunk_w} x {chunk_h} {sample_type} samples"),
        )?;
        let byte_counts: Vec<u64> = decoder
            .find_tag_unsigned_vec::<u64>(byte_count_tag)
            .ok()
            .flatten()
            .unwrap_or_default();
        if byte_counts.len() as u64 != u64::from(chunks_across) * u64::from(chunks_down) {
            bail!(
                "{}",
                what(&format!(
                    "{} chunk byte counts for a {chunks_across} x {chunks_down} chunk grid",
                    byte_counts.len()
                ))
            );
        }
        let nodata = decoder
            .get_tag_ascii_string(Tag::GdalNodata)
            .ok()
            .map(|s| s.trim_end_matches('\0').trim().to_string());
        let mut georef = read_georef(&mut decoder);
        let (flip_rows, flip_columns) = match georef.as_mut() {
            Some(g) => north_up(g, width, height).map_err(|e| anyhow!("{}", what(&e)))?,
            None => (false, false),
        };
        let mask = Mask::open(path, (width, height))?;
        if georef
            .as_ref()
            .is_some_and(|g| g.geo_double_params.iter().any(|v| !v.is_finite()))
        {
            bail!(
                "{}",
                what("GeoDoubleParams holds a value that is not a finite number")
            );
        }
        let linear_unit_m = georef
            .as_ref()
            .map_or(1.0, |g| geo::linear_unit_metres(&g.geo_key_directory));
        let mut decoders = vec![Mutex::new(decoder)];
        for _ in 1..rayon::current_num_threads() {
            decoders.push(Mutex::new(open_decoder()?));
        }
        Ok(Self {
            path: path.to_path_buf(),
            decoders,
            info: SourceInfo {
                format: "geotiff",
                width,
                height,
                georef,
                nodata,
                vertical_units: None,
                linear_unit_m,
                sample_type,
            },
            chunk_w,
            chunk_h,
            chunks_across,
            byte_counts,
            single: sample_format == 3 && bits == 32,
            held: None,
            mask,
            flip_rows,
            flip_columns,
        })
    }

    /// Decodes chunk rows `rows` into heights, `width x chunk_h` each, all
    /// their chunks in parallel.
    fn decode_chunk_rows(
        &self,
        rows: std::ops::Range<u32>,
        map: &HeightMapping,
    ) -> Result<Vec<Vec<f32>>> {
        let first = rows.start;
        let jobs: Vec<(u32, u32)> = rows
            .clone()
            .flat_map(|r| (0..self.chunks_across).map(move |a| (r, a)))
            .collect();
        let decoded: Vec<(u32, u32, Vec<f32>)> = jobs
            .into_par_iter()
            .map(|(row, across)| Ok((row, across, self.decode_chunk(row, across, map)?)))
            .collect::<Result<_>>()?;
        let width = self.info.width as usize;
        let mut bands: Vec<Vec<f32>> = rows
            .map(|_| vec![f32::NAN; width * self.chunk_h as usize])
            .collect();
        for (row, across, chunk) in decoded {
            let x0 = (across * self.chunk_w) as usize;
            let data_w = (self.chunk_w as usize).min(width - x0);
            let band = &mut bands[(row - first) as usize];
            for (y, src) in chunk.chunks_exact(data_w).enumerate() {
                band[y * width + x0..y * width + x0 + data_w].copy_from_slice(src);
            }
        }
        Ok(bands)
    }

    /// Decodes one chunk into heights, `data_w x data_h` (edge chunks clipped).
    fn decode_chunk(&self, row: u32, across: u32, map: &HeightMapping) -> Result<Vec<f32>> {
        let index = row * self.chunks_across + across;
        let data_w = (self.chunk_w).min(self.info.width - across * self.chunk_w) as usize;
        let data_h = (self.chunk_h).min(self.info.height - row * self.chunk_h) as usize;
        let mut out = vec![f32::NAN; data_w * data_h];
        if self.byte_counts[index as usize] == 0 {
            // Sparse chunk: never written, nodata.
            return Ok(out);
        }
        let slot = rayon::current_thread_index().unwrap_or(0) % self.decoders.len();
        let decoded = {
            let mut decoder = self.decoders[slot]
                .lock()
                .map_err(|_| anyhow!("TIFF decoder poisoned"))?;
            decoder.read_chunk(index).map_err(|e| {
                anyhow!(
                    "{}: cannot decode {} {index}: {e}",
                    self.path.display(),
                    if self.chunks_across == 1 {
                        "strip"
                    } else {
                        "tile"
                    }
                )
            })?
        };
        // Edge chunks come back clipped to the image (tiff 0.11) or padded
        // to the full tile (other readers' habit): accept either.
        let stride = if sample_count(&decoded) >= self.chunk_w as usize * data_h {
            self.chunk_w as usize
        } else {
            data_w
        };
        if sample_count(&decoded) < stride * (data_h - 1) + data_w {
            bail!(
                "{}: chunk {index} decoded to {} samples, expected {}",
                self.path.display(),
                sample_count(&decoded),
                stride * data_h
            );
        }
        for (y, row_out) in out.chunks_exact_mut(data_w).enumerate() {
            convert(&decoded, y * stride, row_out, map, self.single);
        }
        if let Some(mask) = &self.mask {
            let origin = (across * self.chunk_w, row * self.chunk_h);
            mask.apply(origin, (data_w as u32, data_h as u32), &mut out)?;
        }
        Ok(out)
    }

    /// Source rows `y0 ..` into `out`, as stored (top row first), keeping
    /// the chunk row the next read starts in: below the rows read when
    /// reading forward, above them when reading a south-up file backward.
    fn read_stored_rows(
        &mut self,
        y0: u32,
        out: &mut [f32],
        map: &HeightMapping,
        backward: bool,
    ) -> Result<()> {
        let width = self.info.width as usize;
        let rows = (out.len() / width) as u32;
        let (first, last) = (y0 / self.chunk_h, (y0 + rows - 1) / self.chunk_h);
        // The held chunk row is the first of this read (reading forward) or
        // its last (backward); the others are decoded.
        let held = self.held.take().filter(|(r, _)| *r == first || *r == last);
        let mut bands = match held {
            Some((r, band)) if r == first => {
                let mut bands = vec![band];
                bands.extend(self.decode_chunk_rows(first + 1..last + 1, map)?);
                bands
            }
            Some((_, band)) => {
                let mut bands = self.decode_chunk_rows(first..last, map)?;
                bands.push(band);
                bands
            }
            None => self.decode_chunk_rows(first..last + 1, map)?,
        };
        for (i, row_out) in out.chunks_exact_mut(width).enumerate() {
            let y = y0 + i as u32;
            let band = &bands[(y / self.chunk_h - first) as usize];
            let r = (y % self.chunk_h) as usize;
            row_out.copy_from_slice(&band[r * width..(r + 1) * width]);
        }
        if backward {
            if !y0.is_multiple_of(self.chunk_h) {
                self.held = Some((first, bands.swap_remove(0)));
            }
        } else if !(y0 + rows).is_multiple_of(self.chunk_h) && y0 + rows < self.info.height {
            self.held = bands.pop().map(|b| (last, b));
        }
        Ok(())
    }
}

/// Makes `g` north-up: says whether the rows (a positive pixel height) and
/// the columns (a negative pixel width) are to be read reversed, and moves
/// the origin to the north-west post or corner. A rotation is refused.
fn north_up(
    g: &mut terrabake_format::manifest::Georef,
    width: u32,
    height: u32,
) -> std::result::Result<(bool, bool), String> {
    let t = &mut g.geotransform;
    if t[2] != 0.0 || t[4] != 0.0 {
        return Err(format!(
            "a rotated or sheared geotransform (row rotation {}, column rotation {}): \
             terrabake reads grids whose rows run east-west; resample it north-up first \
             (gdalwarp -t_srs with the file's own CRS)",
            t[2], t[4]
        ));
    }
    if t[1] == 0.0 || t[5] == 0.0 {
        return Err(format!(
            "a geotransform with a zero pixel size ({} x {})",
            t[1], t[5]
        ));
    }
    // The origin is the corner of an area pixel, the post of a point one.
    let posts = |n: u32| match g.raster_type {
        terrabake_format::manifest::RasterType::Point => f64::from(n - 1),
        terrabake_format::manifest::RasterType::Area => f64::from(n),
    };
    let (flip_rows, flip_columns) = (t[5] > 0.0, t[1] < 0.0);
    if flip_rows {
        t[3] += posts(height) * t[5];
        t[5] = -t[5];
    }
    if flip_columns {
        t[0] += posts(width) * t[1];
        t[1] = -t[1];
    }
    Ok((flip_rows, flip_columns))
}

fn sample_count(d: &DecodingResult) -> usize {
    match d {
        DecodingResult::U8(v) => v.len(),
        DecodingResult::U16(v) => v.len(),
        DecodingResult::U32(v) => v.len(),
        DecodingResult::U64(v) => v.len(),
        DecodingResult::F16(v) => v.len(),
        DecodingResult::F32(v) => v.len(),
        DecodingResult::F64(v) => v.len(),
        DecodingResult::I8(v) => v.len(),
        DecodingResult::I16(v) => v.len(),
        DecodingResult::I32(v) => v.len(),
        DecodingResult::I64(v) => v.len(),
    }
}

/// Converts `out.len()` samples starting at `start` into heights.
fn convert(d: &DecodingResult, start: usize, out: &mut [f32], map: &HeightMapping, single: bool) {
    macro_rules! run {
        ($v:expr) => {
            for (o, &s) in out.iter_mut().zip(&$v[start..]) {
                *o = map.height(s as f64, single);
            }
        };
    }
    match d {
        DecodingResult::U8(v) => run!(v),
        DecodingResult::U16(v) => run!(v),
        DecodingResult::U32(v) => run!(v),
        DecodingResult::U64(v) => run!(v),
        DecodingResult::F16(v) => {
            for (o, s) in out.iter_mut().zip(&v[start..]) {
                *o = map.height(f64::from(s.to_f32()), true);
            }
        }
        DecodingResult::F32(v) => run!(v),
        DecodingResult::F64(v) => run!(v),
        DecodingResult::I8(v) => run!(v),
        DecodingResult::I16(v) => run!(v),
        DecodingResult::I32(v) => run!(v),
        DecodingResult::I64(v) => run!(v),
    }
}

fn read_georef(
    decoder: &mut Decoder<BufReader<File>>,
) -> Option<terrabake_format::manifest::Georef> {
    let scale = decoder.get_tag_f64_vec(Tag::ModelPixelScaleTag).ok();
    let tie = decoder.get_tag_f64_vec(Tag::ModelTiepointTag).ok();
    let matrix = decoder.get_tag_f64_vec(Tag::ModelTransformationTag).ok();
    let transform = match (scale, tie, matrix) {
        (Some(s), Some(t), _) if s.len() >= 2 && t.len() >= 6 => {
            // Raster point (I, J) maps to model (X, Y); y grows southwards.
            let (i, j, x, y) = (t[0], t[1], t[3], t[4]);
            [x - i * s[0], s[0], 0.0, y + j * s[1], 0.0, -s[1]]
        }
        (_, _, Some(m)) if m.len() >= 16 => [m[3], m[0], m[1], m[7], m[4], m[5]],
        _ => return None,
    };
    if transform.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let dir = decoder
        .get_tag_u16_vec(Tag::GeoKeyDirectoryTag)
        .unwrap_or_default();
    let doubles = decoder
        .get_tag_f64_vec(Tag::GeoDoubleParamsTag)
        .unwrap_or_default();
    let ascii = decoder
        .get_tag_ascii_string(Tag::GeoAsciiParamsTag)
        .unwrap_or_default();
    Some(geo::georef_from_keys(dir, doubles, ascii, transform))
}

impl RasterSource for GeoTiffSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, y0: u32, out: &mut [f32], map: &HeightMapping) -> Result<()> {
        let width = self.info.width as usize;
        let rows = (out.len() / width) as u32;
        if rows == 0 {
            return Ok(());
        }
        if self.flip_rows {
            // Asset rows y0.. are stored rows height - y0 - rows .. height - y0,
            // read in one go and put back in north-first order.
            let stored = self.info.height - y0 - rows;
            self.read_stored_rows(stored, out, map, true)?;
            let n = rows as usize;
            for i in 0..n / 2 {
                let (top, bottom) = out.split_at_mut((n - 1 - i) * width);
                top[i * width..(i + 1) * width].swap_with_slice(&mut bottom[..width]);
            }
        } else {
            self.read_stored_rows(y0, out, map, false)?;
        }
        if self.flip_columns {
            for row in out.chunks_exact_mut(width) {
                row.reverse();
            }
        }
        Ok(())
    }
}

/// GDAL's per-dataset mask band: the IFD of the file with NewSubfileType 4
/// (a transparency mask) at the image's size, else the first image of
/// `FILE.msk`. The `tiff` crate decodes no transparency-mask IFD, so its
/// chunks are read and inflated here (none, deflate, LZW, PackBits, zstd:
/// what GDAL writes); its chunk grid may differ from the image's.
struct Mask {
    file: File,
    path: PathBuf,
    offsets: Vec<u64>,
    counts: Vec<u64>,
    compression: u16,
    /// Chunk width and height, chunks across, and 1 or 8 bits a sample.
    chunk: (u32, u32),
    across: u32,
    bits: u8,
}

impl Mask {
    fn open(path: &Path, dims: (u32, u32)) -> Result<Option<Self>> {
        let open = |p: &Path| -> Result<Decoder<BufReader<File>>> {
            let file = File::open(p).with_context(|| format!("{}: cannot open", p.display()))?;
            Decoder::new(BufReader::new(file))
                .map_err(|e| anyhow!("{}: not a readable TIFF: {e}", p.display()))
        };
        let mut decoder = open(path)?;
        let mut found = false;
        for _ in 0..64 {
            if !decoder.more_images() || decoder.next_image().is_err() {
                break;
            }
            let kind = decoder
                .find_tag_unsigned::<u32>(Tag::NewSubfileType)
                .ok()
                .flatten()
                .unwrap_or(0);
            if kind & 4 != 0 && decoder.dimensions().ok() == Some(dims) {
                found = true;
                break;
            }
        }
        let mask_path = if found {
            path.to_path_buf()
        } else {
            let mut p = path.as_os_str().to_owned();
            p.push(".msk");
            let p = PathBuf::from(p);
            if !p.is_file() {
                return Ok(None);
            }
            decoder = open(&p)?;
            p
        };
        let what = |m: String| anyhow!("{}: GDAL mask band: {m}", mask_path.display());
        if decoder.dimensions().ok() != Some(dims) {
            return Err(what(format!(
                "{:?} posts where the DEM has {dims:?}",
                decoder.dimensions().ok()
            )));
        }
        let tag =
            |d: &mut Decoder<BufReader<File>>, t: Tag| d.find_tag_unsigned::<u32>(t).ok().flatten();
        let bits = tag(&mut decoder, Tag::BitsPerSample).unwrap_or(1);
        let samples = tag(&mut decoder, Tag::SamplesPerPixel).unwrap_or(1);
        let predictor = tag(&mut decoder, Tag::Predictor).unwrap_or(1);
        let fill_order = tag(&mut decoder, Tag::FillOrder).unwrap_or(1);
        if !matches!(bits, 1 | 8) || samples != 1 || predictor != 1 || fill_order != 1 {
            return Err(what(format!(
                "{bits}-bit samples, {samples} a pixel, predictor {predictor}, fill order \
                 {fill_order} (GDAL writes one 1- or 8-bit sample, no predictor)"
            )));
        }
        let compression = tag(&mut decoder, Tag::Compression).unwrap_or(1) as u16;
        if !matches!(compression, 1 | 5 | 8 | 32946 | 32773 | 50000) {
            return Err(what(format!(
                "compression {compression} (read: none, LZW, deflate, PackBits, zstd)"
            )));
        }
        let (w, h) = dims;
        let (chunk, offsets_tag, counts_tag) = match decoder.get_chunk_type() {
            ChunkType::Strip => {
                let rows = tag(&mut decoder, Tag::RowsPerStrip)
                    .unwrap_or(h)
                    .clamp(1, h);
                ((w, rows), Tag::StripOffsets, Tag::StripByteCounts)
            }
            ChunkType::Tile => {
                let tw = tag(&mut decoder, Tag::TileWidth).unwrap_or(0);
                let th = tag(&mut decoder, Tag::TileLength).unwrap_or(0);
                if tw == 0 || th == 0 || tw > 1 << 16 || th > 1 << 16 {
                    return Err(what(format!("tiles of {tw} x {th}")));
                }
                ((tw, th), Tag::TileOffsets, Tag::TileByteCounts)
            }
        };
        let vec = |d: &mut Decoder<BufReader<File>>, t: Tag| {
            d.find_tag_unsigned_vec::<u64>(t)
                .ok()
                .flatten()
                .unwrap_or_default()
        };
        let offsets = vec(&mut decoder, offsets_tag);
        let counts = vec(&mut decoder, counts_tag);
        let across = w.div_ceil(chunk.0);
        let chunks = u64::from(across) * u64::from(h.div_ceil(chunk.1));
        if offsets.len() as u64 != chunks || counts.len() as u64 != chunks {
            return Err(what(format!(
                "{} offsets and {} byte counts for {chunks} chunks",
                offsets.len(),
                counts.len()
            )));
        }
        let file = File::open(&mask_path)
            .with_context(|| format!("{}: cannot open", mask_path.display()))?;
        Ok(Some(Self {
            file,
            path: mask_path,
            offsets,
            counts,
            compression,
            chunk,
            across,
            bits: bits as u8,
        }))
    }

    /// Bytes of one row of `w` mask samples (1-bit rows end on a byte).
    fn row_bytes(&self, w: u32) -> usize {
        if self.bits == 1 {
            w.div_ceil(8) as usize
        } else {
            w as usize
        }
    }

    /// Mask chunk `index`, inflated: `row_bytes(chunk width)` a row, as
    /// many rows as were stored (a last strip may be short).
    fn chunk(&self, index: usize) -> Result<Vec<u8>> {
        use std::io::Read;
        use std::os::unix::fs::FileExt;
        let what =
            |m: String| anyhow!("{}: GDAL mask band chunk {index}: {m}", self.path.display());
        let full = self.row_bytes(self.chunk.0) * self.chunk.1 as usize;
        let stored = self.counts[index];
        if stored == 0 {
            // Never written: GDAL reads an unwritten mask chunk as valid.
            return Ok(vec![0xff; full]);
        }
        if stored > 2 * full as u64 + 4096 {
            return Err(what(format!(
                "{stored} stored bytes for {full} bytes of mask"
            )));
        }
        let mut raw = vec![0u8; stored as usize];
        self.file
            .read_exact_at(&mut raw, self.offsets[index])
            .map_err(|e| what(format!("cannot read: {e}")))?;
        let mut out = Vec::with_capacity(full);
        match self.compression {
            1 => out = raw,
            8 | 32946 => {
                flate2::read::ZlibDecoder::new(&raw[..])
                    .take(full as u64)
                    .read_to_end(&mut out)
                    .map_err(|e| what(format!("deflate: {e}")))?;
            }
            50000 => {
                zstd::stream::read::Decoder::new(&raw[..])
                    .map_err(|e| what(format!("zstd: {e}")))?
                    .take(full as u64)
                    .read_to_end(&mut out)
                    .map_err(|e| what(format!("zstd: {e}")))?;
            }
            5 => {
                let mut lzw =
                    weezl::decode::Decoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8);
                let got = lzw.into_vec(&mut out).decode(&raw);
                got.status.map_err(|e| what(format!("LZW: {e}")))?;
                out.truncate(full);
            }
            _ => {
                // PackBits: a count n, then n + 1 literal bytes (n >= 0) or
                // one byte repeated 1 - n times (n in -127..=-1).
                let mut i = 0;
                while i < raw.len() && out.len() < full {
                    let n = raw[i] as i8;
                    i += 1;
                    if n >= 0 {
                        let end = (i + n as usize + 1).min(raw.len());
                        out.extend_from_slice(&raw[i..end]);
                        i = end;
                    } else if n != -128 && i < raw.len() {
                        out.extend(std::iter::repeat_n(raw[i], (1 - i32::from(n)) as usize));
                        i += 1;
                    }
                }
                out.truncate(full);
            }
        }
        Ok(out)
    }

    /// Sets to NaN the posts of the block at `(x0, y0)`, `w x h` in `out`,
    /// whose mask sample is zero.
    fn apply(&self, (x0, y0): (u32, u32), (w, h): (u32, u32), out: &mut [f32]) -> Result<()> {
        let (cw, ch) = self.chunk;
        for my in y0 / ch..=(y0 + h - 1) / ch {
            for mx in x0 / cw..=(x0 + w - 1) / cw {
                let bytes = self.chunk((my * self.across + mx) as usize)?;
                let stride = self.row_bytes(cw);
                let (ys, ye) = (y0.max(my * ch), (y0 + h).min((my + 1) * ch));
                let (xs, xe) = (x0.max(mx * cw), (x0 + w).min((mx + 1) * cw));
                for y in ys..ye {
                    let line = ((y - my * ch) as usize) * stride;
                    let Some(line) = bytes.get(line..line + stride) else {
                        return Err(anyhow!(
                            "{}: GDAL mask band chunk {}: too short",
                            self.path.display(),
                            my * self.across + mx
                        ));
                    };
                    let row = &mut out[((y - y0) * w) as usize..][..w as usize];
                    for x in xs..xe {
                        let i = (x - mx * cw) as usize;
                        let valid = if self.bits == 1 {
                            line[i / 8] >> (7 - i % 8) & 1 != 0
                        } else {
                            line[i] != 0
                        };
                        if !valid {
                            row[(x - x0) as usize] = f32::NAN;
                        }
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrabake_format::manifest::{CrsKind, Georef, RasterType};

    fn georef(t: [f64; 6], raster_type: RasterType) -> Georef {
        Georef {
            crs_kind: CrsKind::Geographic,
            epsg: Some(4326),
            geotransform: t,
            raster_type,
            geo_key_directory: Vec::new(),
            geo_double_params: Vec::new(),
            geo_ascii_params: String::new(),
        }
    }

    /// A south-up grid's origin moves to its northern edge (a pixel's
    /// corner, or a point raster's post), an east-left one's to its west.
    #[test]
    fn grids_are_made_north_up_and_rotations_refused() {
        let mut area = georef([10.0, 0.5, 0.0, 50.0, 0.0, 0.25], RasterType::Area);
        assert_eq!(north_up(&mut area, 4, 8), Ok((true, false)));
        assert_eq!(area.geotransform, [10.0, 0.5, 0.0, 52.0, 0.0, -0.25]);
        let mut point = georef([10.0, -0.5, 0.0, 50.0, 0.0, 0.25], RasterType::Point);
        assert_eq!(north_up(&mut point, 4, 8), Ok((true, true)));
        assert_eq!(point.geotransform, [8.5, 0.5, 0.0, 51.75, 0.0, -0.25]);
        let mut plain = georef([10.0, 0.5, 0.0, 50.0, 0.0, -0.25], RasterType::Area);
        assert_eq!(north_up(&mut plain, 4, 8), Ok((false, false)));
        assert_eq!(plain.geotransform, [10.0, 0.5, 0.0, 50.0, 0.0, -0.25]);
        let mut rotated = georef([10.0, 0.5, 0.1, 50.0, 0.0, -0.25], RasterType::Area);
        assert!(north_up(&mut rotated, 4, 8)
            .unwrap_err()
            .contains("rotated or sheared"));
    }
}
