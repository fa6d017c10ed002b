//! Grayscale PNG heightmaps, as game engines export them (16-bit, often with
//! a vertical scale and offset that the user passes as --z-scale/--z-offset).
//! Read row by row; interlaced files are refused, since their rows arrive in
//! seven passes and cannot be streamed.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use anyhow::{anyhow, Context, Result};

use super::{check_shape, HeightMapping, Memory, RasterSource, SourceInfo};

use crate::error::bail;

pub struct PngSource {
    reader: png::Reader<BufReader<File>>,
    info: SourceInfo,
    next_row: u32,
    sixteen: bool,
}

impl PngSource {
    pub fn open(path: &Path, memory: Memory) -> crate::Result<Self> {
        let file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
        let mut decoder = png::Decoder::new(BufReader::new(file));
        decoder.set_transformations(png::Transformations::IDENTITY);
        let reader = decoder
            .read_info()
            .map_err(|e| anyhow!("{}: not a readable PNG: {e}", path.display()))?;
        let info = reader.info();
        let (width, height) = (info.width, info.height);
        check_shape(path, width.into(), height.into())?;
        // The decoder holds a row and the previous one (for its filters).
        let row = u64::from(width) * 2;
        memory.check(
            path,
            width.into(),
            height.into(),
            row * 2,
            "two rows of samples",
        )?;
        if info.interlaced {
            bail!(
                "{}: interlaced PNG cannot be streamed; re-save it without interlacing",
                path.display()
            );
        }
        if info.color_type != png::ColorType::Grayscale {
            bail!(
                "{}: {:?} PNG: a heightmap must be single-channel grayscale (8 or 16 bit)",
                path.display(),
                info.color_type
            );
        }
        let sixteen = match info.bit_depth {
            png::BitDepth::Sixteen => true,
            png::BitDepth::Eight => false,
            d => bail!(
                "{}: {d:?}-bit grayscale PNG: heightmaps are 8 or 16 bit",
                path.display()
            ),
        };
        Ok(Self {
            reader,
            info: SourceInfo {
                format: "png",
                width,
                height,
                georef: None,
                nodata: None,
                vertical_units: None,
                linear_unit_m: 1.0,
                sample_type: if sixteen { "uint16" } else { "uint8" }.into(),
            },
            next_row: 0,
            sixteen,
        })
    }
}

impl RasterSource for PngSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, y0: u32, out: &mut [f32], map: &HeightMapping) -> Result<()> {
        crate::error::ensure!(y0 >= self.next_row, "PNG rows are read in order");
        // Rows skipped (a part of a partitioned bake reads only its own)
        // are decoded and dropped: PNG has no index to seek with.
        while self.next_row < y0 {
            self.reader
                .next_row()
                .map_err(|e| anyhow!("PNG row {}: {e}", self.next_row))?
                .ok_or_else(|| anyhow!("PNG ended at row {}", self.next_row))?;
            self.next_row += 1;
        }
        for row_out in out.chunks_exact_mut(self.info.width as usize) {
            let row = self
                .reader
                .next_row()
                .map_err(|e| anyhow!("PNG row {}: {e}", self.next_row))?
                .ok_or_else(|| anyhow!("PNG ended at row {}", self.next_row))?;
            let data = row.data();
            if self.sixteen {
                for (o, b) in row_out.iter_mut().zip(data.chunks_exact(2)) {
                    *o = map.height(f64::from(u16::from_be_bytes([b[0], b[1]])), false);
                }
            } else {
                for (o, &b) in row_out.iter_mut().zip(data) {
                    *o = map.height(f64::from(b), false);
                }
            }
            self.next_row += 1;
        }
        Ok(())
    }
}
