//! SRTM `.hgt`: big-endian int16 posts, square, no header; the side follows
//! from the file length (1201 for 3", 3601 for 1"); -32768 is a void. The
//! file name (`N07W006.hgt`) gives the south-west post's latitude and
//! longitude, which are exact integers: the posts lie on the degree lines, so
//! the grid is PixelIsPoint.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use anyhow::{Context, Result};
use terrabake_format::manifest::RasterType;

use super::{HeightMapping, Memory, RasterSource, SourceInfo};
use crate::error::bail;
use crate::terrain::geo;

pub struct HgtSource {
    reader: BufReader<File>,
    info: SourceInfo,
    row_bytes: Vec<u8>,
}

impl HgtSource {
    pub fn open(path: &Path, memory: Memory) -> crate::Result<Self> {
        let file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
        let len = file.metadata()?.len();
        let side = (len / 2).isqrt();
        if len == 0 || len % 2 != 0 || side * side * 2 != len || side < 2 {
            bail!(
                "{}: {len} bytes is not a square grid of int16 posts (SRTM .hgt is 1201 x 1201 or 3601 x 3601)",
                path.display()
            );
        }
        memory.check(path, side, side, side * 2, "one row of samples")?;
        let side_u32 = side as u32;
        let georef = parse_hgt_name(path).map(|(lat, lon)| {
            let step = 1.0 / (side as f64 - 1.0);
            // EPSG:4326, geographic, PixelIsPoint.
            let keys = vec![
                1,
                1,
                0,
                3, //
                geo::GT_MODEL_TYPE,
                0,
                1,
                2, //
                geo::GT_RASTER_TYPE,
                0,
                1,
                2, //
                geo::GEOGRAPHIC_TYPE,
                0,
                1,
                4326,
            ];
            let mut g = geo::georef_from_keys(
                keys,
                vec![],
                String::new(),
                [lon, step, 0.0, lat + 1.0, 0.0, -step],
            );
            g.raster_type = RasterType::Point;
            g
        });
        Ok(Self {
            reader: BufReader::with_capacity(1 << 20, file),
            info: SourceInfo {
                format: "hgt",
                width: side_u32,
                height: side_u32,
                georef,
                nodata: Some("-32768".into()),
                vertical_units: Some("metre".into()),
                linear_unit_m: 1.0,
                sample_type: "int16 (big-endian)".into(),
            },
            row_bytes: vec![0; side as usize * 2],
        })
    }
}

/// `N07W006` -> (7.0, -6.0).
fn parse_hgt_name(path: &Path) -> Option<(f64, f64)> {
    let stem = path.file_stem()?.to_str()?.to_ascii_uppercase();
    let b = stem.as_bytes();
    if b.len() < 7 {
        return None;
    }
    let lat: f64 = stem.get(1..3)?.parse().ok()?;
    let lon: f64 = stem.get(4..7)?.parse().ok()?;
    let lat = match b[0] {
        b'N' => lat,
        b'S' => -lat,
        _ => return None,
    };
    let lon = match b[3] {
        b'E' => lon,
        b'W' => -lon,
        _ => return None,
    };
    Some((lat, lon))
}

impl RasterSource for HgtSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn read_rows(&mut self, y0: u32, out: &mut [f32], map: &HeightMapping) -> Result<()> {
        let width = self.info.width as u64;
        self.reader
            .seek(SeekFrom::Start(u64::from(y0) * width * 2))?;
        for row in out.chunks_exact_mut(width as usize) {
            self.reader.read_exact(&mut self.row_bytes)?;
            for (o, b) in row.iter_mut().zip(self.row_bytes.chunks_exact(2)) {
                *o = map.height(f64::from(i16::from_be_bytes([b[0], b[1]])), false);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn names() {
        use std::path::Path;
        assert_eq!(
            super::parse_hgt_name(Path::new("N07W006.hgt")),
            Some((7.0, -6.0))
        );
        assert_eq!(
            super::parse_hgt_name(Path::new("s33e151.HGT")),
            Some((-33.0, 151.0))
        );
        assert_eq!(super::parse_hgt_name(Path::new("dem.hgt")), None);
    }
}
