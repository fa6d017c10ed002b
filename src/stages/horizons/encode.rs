//! The horizon layer's tiles: angles quantised to the stored codes
//! (`terrabake_format::horizons::AngleEncoding`) in the CPU's vectors, and
//! cut into tiles.

use terrabake_format::horizons::AngleEncoding;
use terrabake_format::Codec;

use crate::terrain::tiling::encode_tile_row;

/// The tiles of a tile row of angles (degrees, rows `w` wide) in `enc`,
/// as the horizon layer stores them; what the planner's zstd prediction
/// encodes too.
pub(crate) fn encode_angles(
    enc: AngleEncoding,
    angles: &[f32],
    w: usize,
    ts: usize,
    codec: Codec,
) -> Vec<terrabake_format::EncodedTile> {
    match enc {
        AngleEncoding::U16 => {
            let codes = quantise_row(enc, angles, |c| c as u16);
            encode_tile_row(&codes.expect("u16 codes"), w, ts, 0u16, codec)
        }
        AngleEncoding::U8 => {
            let codes = quantise_row(enc, angles, |c| c as u8);
            encode_tile_row(&codes.expect("u8 codes"), w, ts, 0u8, codec)
        }
        AngleEncoding::F32 => encode_tile_row(angles, w, ts, f32::NAN, codec),
    }
}

/// [`AngleEncoding::quantise_row`] in the CPU's vectors ([`crate::plumbing::simd`]):
/// the format crate's loop, compiled here for AVX-512 or AVX2 (the same
/// codes), where the baseline build converts two values at a time.
fn quantise_row<T, F: Fn(u32) -> T>(enc: AngleEncoding, degs: &[f32], narrow: F) -> Option<Vec<T>> {
    quantise_row_at(crate::plumbing::simd::level(), enc, degs, narrow)
}

/// [`quantise_row`] at `level` (one the CPU runs, [`crate::plumbing::simd::available`]).
fn quantise_row_at<T, F: Fn(u32) -> T>(
    level: crate::plumbing::simd::Level,
    enc: AngleEncoding,
    degs: &[f32],
    narrow: F,
) -> Option<Vec<T>> {
    use crate::plumbing::simd::Level;
    assert!(
        level <= crate::plumbing::simd::level(),
        "{level:?} is not run by this CPU"
    );
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq")]
    fn avx512<T, F: Fn(u32) -> T>(enc: AngleEncoding, degs: &[f32], narrow: F) -> Option<Vec<T>> {
        enc.quantise_row(degs, narrow)
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn avx2<T, F: Fn(u32) -> T>(enc: AngleEncoding, degs: &[f32], narrow: F) -> Option<Vec<T>> {
        enc.quantise_row(degs, narrow)
    }
    match level {
        // SAFETY: the CPU runs `level`.
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 => unsafe { avx512(enc, degs, narrow) },
        // SAFETY: the CPU runs `level`.
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 => unsafe { avx2(enc, degs, narrow) },
        _ => enc.quantise_row(degs, narrow),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vector builds of the angle codes give the format crate's codes:
    /// every code's centre and half-steps a hair either side, the ends,
    /// NaN and infinities, and a spread of angles.
    #[test]
    fn quantised_rows_are_the_format_crates_codes_at_every_level() {
        for enc in [AngleEncoding::U8, AngleEncoding::U16] {
            let step = enc.step_deg();
            let mut degs = vec![
                f32::NAN,
                f32::INFINITY,
                f32::NEG_INFINITY,
                -1e9,
                1e9,
                -90.0,
                90.0,
            ];
            let mut k = -90.0;
            while k <= 90.0 {
                for d in [0.0, 0.5 * step, -0.5 * step] {
                    let x = (k + d) as f32;
                    degs.extend([
                        x,
                        f32::from_bits(x.to_bits() + 1),
                        f32::from_bits(x.to_bits().wrapping_sub(1)),
                    ]);
                }
                k += step;
            }
            degs.extend((0..10_000).map(|i| -95.0 + 190.0 * (i as f32 / 10_000.0)));
            for level in crate::plumbing::simd::available() {
                assert_eq!(
                    quantise_row_at(level, enc, &degs, |c| c),
                    enc.quantise_row(&degs, |c| c),
                    "{enc:?} at {level:?}"
                );
            }
        }
    }
}
