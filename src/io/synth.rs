//! Synthetic terrains for tests and benchmarks, each a pure function of the
//! post (x, y), the size and a seed, so that any row band can be made
//! without the rest: `terrabake synth` writes them a tile row at a time, at any
//! size, in bounded memory.
//!
//! The kinds cover the cases where terrain algorithms fail: a single spike
//! (Stewart 1998, Fig. 8: sampling misses it), a bowl (Timonen 2013's worst
//! case for hull sizes), cliffs, white noise (no coherence), flat ground
//! (degenerate slices and horizons), an 8-bit quantised fractal (terraces and
//! contour artefacts), and fractal terrain with nodata holes.

use rayon::prelude::*;

use crate::terrain::random::{mix, unit_interval};

/// Post spacing of synthetic terrains, metres.
pub const SYNTH_CELL: f64 = 30.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SynthKind {
    /// fBm value noise, about 0..1200 m.
    Fractal,
    /// 100 m everywhere.
    Flat,
    /// Flat 0 m with one post of 1000 m at the centre.
    Spike,
    /// Paraboloid, 0 m at the centre rising to 1000 m at the corners.
    Bowl,
    /// sin x + sin y egg crate, period 64 posts, 0..400 m.
    Sine,
    /// 32 x 32-post blocks of random heights in 50 m steps: cliffs.
    Blocks,
    /// Independent uniform heights, 0..100 m.
    Noise,
    /// The fractal quantised to 256 levels (an 8-bit DEM).
    Quantised,
    /// The fractal with round nodata holes.
    Holes,
}

impl SynthKind {
    pub const ALL: [SynthKind; 9] = [
        SynthKind::Fractal,
        SynthKind::Flat,
        SynthKind::Spike,
        SynthKind::Bowl,
        SynthKind::Sine,
        SynthKind::Blocks,
        SynthKind::Noise,
        SynthKind::Quantised,
        SynthKind::Holes,
    ];
}

/// A uniform value in [0, 1) for lattice point (i, j) of `octave`.
fn lattice(seed: u64, octave: u32, i: i64, j: i64) -> f64 {
    unit_interval(mix(
        seed ^ mix(u64::from(octave) ^ mix(i as u64 ^ mix(j as u64)))
    ))
}

fn smooth(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Fractal Brownian motion of value noise, in [0, 1) (roughly).
fn fbm(x: f64, y: f64, size: u32, seed: u64) -> f64 {
    let mut wavelength = f64::from((size / 2).clamp(16, 2048));
    let (mut sum, mut amp, mut norm) = (0.0, 1.0, 0.0);
    let mut octave = 0;
    while wavelength >= 2.0 {
        let (u, v) = (x / wavelength, y / wavelength);
        let (i, j) = (u.floor(), v.floor());
        let (fu, fv) = (smooth(u - i), smooth(v - j));
        let (i, j) = (i as i64, j as i64);
        let a = lattice(seed, octave, i, j);
        let b = lattice(seed, octave, i + 1, j);
        let c = lattice(seed, octave, i, j + 1);
        let d = lattice(seed, octave, i + 1, j + 1);
        sum += amp * (a + fu * (b - a) + fv * (c - a) + fu * fv * (a - b - c + d));
        norm += amp;
        amp *= 0.5;
        wavelength /= 2.0;
        octave += 1;
    }
    sum / norm
}

/// Height of post (x, y) of a `width x height` terrain; NaN is nodata.
pub fn height(kind: SynthKind, x: u32, y: u32, width: u32, height: u32, seed: u64) -> f32 {
    let (fx, fy) = (f64::from(x), f64::from(y));
    let (cx, cy) = (f64::from(width - 1) / 2.0, f64::from(height - 1) / 2.0);
    let size = width.max(height);
    let fractal = || 1200.0 * (fbm(fx, fy, size, seed) - 0.2) / 0.6;
    let z = match kind {
        SynthKind::Fractal => fractal(),
        SynthKind::Flat => 100.0,
        SynthKind::Spike => {
            if x == width / 2 && y == height / 2 {
                1000.0
            } else {
                0.0
            }
        }
        SynthKind::Bowl => {
            1000.0 * ((fx - cx).powi(2) + (fy - cy).powi(2)) / (cx * cx + cy * cy).max(1.0)
        }
        SynthKind::Sine => {
            let k = std::f64::consts::TAU / 64.0;
            100.0 * ((k * fx).sin() + (k * fy).sin() + 2.0)
        }
        SynthKind::Blocks => {
            50.0 * (lattice(seed, 99, i64::from(x / 32), i64::from(y / 32)) * 11.0).floor()
        }
        SynthKind::Noise => 100.0 * lattice(seed, 98, i64::from(x), i64::from(y)),
        SynthKind::Quantised => {
            let step = 1200.0 / 255.0;
            (fractal().clamp(0.0, 1200.0) / step).round() * step
        }
        SynthKind::Holes => {
            // Holes of radius 2..10 posts centred in 64-post cells, one in three cells.
            let (ci, cj) = (i64::from(x / 64), i64::from(y / 64));
            let h = lattice(seed, 97, ci, cj);
            let (hx, hy) = (ci as f64 * 64.0 + 32.0, cj as f64 * 64.0 + 32.0);
            let r = 2.0 + 8.0 * lattice(seed, 96, ci, cj);
            if h < 0.33 && (fx - hx).hypot(fy - hy) <= r {
                return f32::NAN;
            }
            fractal()
        }
    };
    z as f32
}

/// Fills `rows` (whole rows from `y0`) of a terrain, in parallel over rows.
pub fn fill_rows(kind: SynthKind, y0: u32, rows: &mut [f32], width: u32, height_: u32, seed: u64) {
    rows.par_chunks_mut(width as usize)
        .enumerate()
        .for_each(|(i, row)| {
            let y = y0 + i as u32;
            for (x, z) in row.iter_mut().enumerate() {
                *z = height(kind, x as u32, y, width, height_, seed);
            }
        });
}

/// Writes a synthetic terrain as a float32 GeoTIFF on a local metric grid of
/// [`SYNTH_CELL`] posts (no named CRS), a tile row at a time. Holes are written as
/// GDAL nodata -9999.
pub fn write_geotiff(
    path: &std::path::Path,
    kind: SynthKind,
    width: u32,
    height_: u32,
    seed: u64,
    progress: crate::plumbing::progress::Progress,
) -> crate::Result<()> {
    use terrabake_format::manifest::RasterType;
    crate::io::source::check_shape(path, width.into(), height_.into())?;
    crate::plumbing::resources::ensure_disk(
        path,
        u64::from(width) * u64::from(height_) * 4,
        &format!("a {width} x {height_} float32 GeoTIFF"),
    )?;
    let georef = crate::terrain::geo::georef_from_keys(
        crate::terrain::geo::local_metric_keys(RasterType::Area),
        vec![],
        String::new(),
        [
            0.0,
            SYNTH_CELL,
            0.0,
            f64::from(height_) * SYNTH_CELL,
            0.0,
            -SYNTH_CELL,
        ],
    );
    let tags = crate::io::cog::GeoTags {
        georef: Some(georef),
        nodata: Some("-9999".into()),
    };
    let bar = progress.bar(u64::from(height_), "synth", "rows");
    crate::io::cog::write_f32(path, (width, height_), &tags, |y0, rows| {
        fill_rows(kind, y0, rows, width, height_, seed);
        bar.inc((rows.len() / width as usize) as u64);
        Ok(())
    })?;
    bar.finish_and_clear();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds_are_deterministic_and_in_range() {
        for kind in [
            SynthKind::Fractal,
            SynthKind::Bowl,
            SynthKind::Sine,
            SynthKind::Blocks,
            SynthKind::Noise,
            SynthKind::Quantised,
        ] {
            for (x, y) in [(0, 0), (17, 93), (127, 127)] {
                let z = height(kind, x, y, 128, 128, 7);
                assert_eq!(z, height(kind, x, y, 128, 128, 7));
                assert!(
                    z.is_finite() && (-600.0..=1800.0).contains(&z),
                    "{kind:?} {z}"
                );
            }
        }
        assert_eq!(height(SynthKind::Spike, 64, 64, 128, 128, 0), 1000.0);
        assert_eq!(height(SynthKind::Spike, 63, 64, 128, 128, 0), 0.0);
    }

    #[test]
    fn quantised_has_at_most_256_levels() {
        let mut levels: Vec<u32> = (0..64 * 64)
            .map(|i| height(SynthKind::Quantised, i % 64, i / 64, 64, 64, 3).to_bits())
            .collect();
        levels.sort_unstable();
        levels.dedup();
        assert!(levels.len() <= 256 && levels.len() > 8, "{}", levels.len());
    }

    #[test]
    fn holes_have_nodata() {
        let n = (0..256 * 256)
            .filter(|i| height(SynthKind::Holes, i % 256, i / 256, 256, 256, 1).is_nan())
            .count();
        assert!(n > 0 && n < 256 * 256 / 4, "{n}");
    }
}
