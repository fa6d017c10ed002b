//! GeoTIFF through the `tiff` crate, one strip or tile row at a time.
//!
//! The decoder handles striped and tiled layouts, BigTIFF, the compressions
//! (none, deflate, LZW, zstd, PackBits) and predictors 1-3. We add what it
//! leaves to the caller: sparse chunks (byte count 0 means "never written",
//! which GDAL reads as nodata), the GeoTIFF tags, and GDAL_NODATA.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::{anyhow, bail, Context, Result};
use rayon::prelude::*;
use tiff::decoder::{ChunkType, Decoder, DecodingResult, Limits};
use tiff::tags::Tag;
use tiff::ColorType;

use super::{check_shape, HeightMapping, Memory, RasterSource, SourceInfo};
use crate::geo;

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
    /// The last decoded chunk row, kept when a read ends inside it: its
    /// index and heights (`width x chunk_h`, row-major).
    held: Option<(u32, Vec<f32>)>,
}

impl GeoTiffSource {
    pub fn open(path: &Path, memory: Memory) -> Result<Self> {
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
        let georef = read_georef(&mut decoder);
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
        Ok(out)
    }
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
        let (first, last) = (y0 / self.chunk_h, (y0 + rows - 1) / self.chunk_h);
        // Reuse the held chunk row if the read starts in it; decode the rest.
        let held = self.held.take().filter(|(r, _)| *r == first);
        let decode_from = if held.is_some() { first + 1 } else { first };
        let mut bands: Vec<Vec<f32>> = held.map(|(_, b)| b).into_iter().collect();
        bands.extend(self.decode_chunk_rows(decode_from..last + 1, map)?);
        for (i, row_out) in out.chunks_exact_mut(width).enumerate() {
            let y = y0 + i as u32;
            let band = &bands[(y / self.chunk_h - first) as usize];
            let r = (y % self.chunk_h) as usize;
            row_out.copy_from_slice(&band[r * width..(r + 1) * width]);
        }
        // Keep the last chunk row if the next read will start inside it.
        if !(y0 + rows).is_multiple_of(self.chunk_h) && y0 + rows < self.info.height {
            self.held = bands.pop().map(|b| (last, b));
        }
        Ok(())
    }
}
