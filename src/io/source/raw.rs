//! Headerless rasters (`.f32`, `.i16`, `.r16`): the caller gives the shape,
//! the sample type and the byte order; the file length must match exactly.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use anyhow::{Context, Result};

use super::{check_shape, HeightMapping, Memory, RasterSource, SourceInfo};

use crate::error::bail;

#[derive(
    Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum RawSampleType {
    I16,
    U16,
    F32,
}

#[derive(
    Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum ByteOrder {
    Le,
    Be,
}

#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct RawSpec {
    pub width: u32,
    pub height: u32,
    pub sample: RawSampleType,
    pub order: ByteOrder,
}

pub struct RawSource {
    reader: BufReader<File>,
    info: SourceInfo,
    spec: RawSpec,
    row_bytes: Vec<u8>,
}

impl RawSource {
    pub fn open(path: &Path, spec: &RawSpec, memory: Memory) -> crate::Result<Self> {
        check_shape(path, spec.width.into(), spec.height.into())?;
        let size = match spec.sample {
            RawSampleType::I16 | RawSampleType::U16 => 2u64,
            RawSampleType::F32 => 4,
        };
        let (w, h) = (u64::from(spec.width), u64::from(spec.height));
        memory.check(path, w, h, w * size, "one row of samples")?;
        let file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
        let len = file.metadata()?.len();
        let expected = u64::from(spec.width) * u64::from(spec.height) * size;
        if len != expected {
            bail!(
                "{}: {len} bytes, but {} x {} samples of {size} bytes need {expected}",
                path.display(),
                spec.width,
                spec.height
            );
        }
        Ok(Self {
            reader: BufReader::with_capacity(1 << 20, file),
            info: SourceInfo {
                format: "raw",
                width: spec.width,
                height: spec.height,
                georef: None,
                nodata: None,
                vertical_units: None,
                linear_unit_m: 1.0,
                sample_type: format!("{:?} ({:?})", spec.sample, spec.order).to_lowercase(),
            },
            row_bytes: vec![0; (u64::from(spec.width) * size) as usize],
            spec: *spec,
        })
    }
}

impl RasterSource for RawSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, y0: u32, out: &mut [f32], map: &HeightMapping) -> Result<()> {
        let row_len = self.row_bytes.len() as u64;
        self.reader.seek(SeekFrom::Start(u64::from(y0) * row_len))?;
        let be = self.spec.order == ByteOrder::Be;
        for row in out.chunks_exact_mut(self.spec.width as usize) {
            self.reader.read_exact(&mut self.row_bytes)?;
            match self.spec.sample {
                RawSampleType::I16 | RawSampleType::U16 => {
                    for (o, b) in row.iter_mut().zip(self.row_bytes.chunks_exact(2)) {
                        let bits = if be {
                            u16::from_be_bytes([b[0], b[1]])
                        } else {
                            u16::from_le_bytes([b[0], b[1]])
                        };
                        let v = if self.spec.sample == RawSampleType::I16 {
                            f64::from(bits as i16)
                        } else {
                            f64::from(bits)
                        };
                        *o = map.height(v, false);
                    }
                }
                RawSampleType::F32 => {
                    for (o, b) in row.iter_mut().zip(self.row_bytes.chunks_exact(4)) {
                        let b = [b[0], b[1], b[2], b[3]];
                        let v = if be {
                            f32::from_be_bytes(b)
                        } else {
                            f32::from_le_bytes(b)
                        };
                        *o = map.height(f64::from(v), true);
                    }
                }
            }
        }
        Ok(())
    }
}
