//! Single-channel OpenEXR heightmaps. The `exr` crate decodes whole images,
//! so this one source is read into memory at open: fine for the EXR sizes
//! that engines export, and the only source that is not streamed.

use std::path::Path;

use anyhow::{anyhow, Result};
use exr::prelude::{read_first_flat_layer_from_file, FlatSamples};

use super::{check_shape, HeightMapping, Memory, RasterSource, SourceInfo};

use crate::error::bail;

pub struct ExrSource {
    samples: Vec<f32>,
    info: SourceInfo,
}

impl ExrSource {
    pub fn open(path: &Path, memory: Memory) -> crate::Result<Self> {
        // The size from the header, before the whole image is decoded.
        let meta = exr::meta::MetaData::read_from_file(path, false)
            .map_err(|e| anyhow!("{}: not a readable OpenEXR file: {e}", path.display()))?;
        let size = meta
            .headers
            .first()
            .map(|h| h.layer_size)
            .ok_or_else(|| anyhow!("{}: OpenEXR file without a layer", path.display()))?;
        let (w, h) = (size.0 as u64, size.1 as u64);
        check_shape(path, w, h)?;
        // The decoded image (up to 4 bytes a sample) and our f32 copy.
        memory.check(
            path,
            w,
            h,
            w * h * 8,
            "the whole image, which OpenEXR decodes at once",
        )?;
        let image = read_first_flat_layer_from_file(path)
            .map_err(|e| anyhow!("{}: not a readable OpenEXR file: {e}", path.display()))?;
        let layer = image.layer_data;
        let (width, height) = (layer.size.0 as u64, layer.size.1 as u64);
        check_shape(path, width, height)?;
        let channels = &layer.channel_data.list;
        if channels.len() != 1 {
            let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
            bail!(
                "{}: {} channels ({}): a heightmap has exactly one",
                path.display(),
                names.len(),
                names.join(", ")
            );
        }
        let samples: Vec<f32> = match &channels[0].sample_data {
            FlatSamples::F16(v) => v.iter().map(|h| h.to_f32()).collect(),
            FlatSamples::F32(v) => v.clone(),
            FlatSamples::U32(v) => v.iter().map(|&u| u as f32).collect(),
        };
        Ok(Self {
            info: SourceInfo {
                format: "exr",
                width: width as u32,
                height: height as u32,
                georef: None,
                nodata: None,
                vertical_units: None,
                linear_unit_m: 1.0,
                sample_type: match &channels[0].sample_data {
                    FlatSamples::F16(_) => "float16",
                    FlatSamples::F32(_) => "float32",
                    FlatSamples::U32(_) => "uint32",
                }
                .into(),
            },
            samples,
        })
    }
}

impl RasterSource for ExrSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, y0: u32, out: &mut [f32], map: &HeightMapping) -> Result<()> {
        let start = y0 as usize * self.info.width as usize;
        for (o, &s) in out.iter_mut().zip(&self.samples[start..]) {
            *o = map.height(f64::from(s), true);
        }
        Ok(())
    }
}
