//! Centre-line sampling, the baseline that GRASS `r.horizon`, SAGA and
//! topocalc use (Stewart's "CMS" family): from each post, step along the
//! direction at a fixed distance (one post spacing), take the nearest
//! post's height, and keep the steepest. Cheap per sample, `O(distance)` per
//! post, and it misses what falls between samples (a narrow spike off the
//! line). Kept for comparison only.

use crate::terrain::steepest::{metres, Steepest, Tag};
use crate::terrain::{compass, Terrain};

/// Sampled horizons in direction `azimuth` (compass degrees) at every post,
/// degrees (NaN for nodata), looking at most `max_distance` metres; where
/// `distances` is given, the distance (metres) of the steepest sample, NaN
/// where none was taken.
pub(crate) fn sampled_horizons(
    terrain: &Terrain,
    azimuth: f64,
    max_distance: f64,
    out: &mut [f32],
    distances: Option<&mut [f32]>,
) {
    assert!(distances.as_ref().is_none_or(|d| d.len() == out.len()));
    match distances {
        None => sample::<()>(terrain, azimuth, max_distance, out, None),
        Some(d) => sample::<Option<f64>>(terrain, azimuth, max_distance, out, Some(d)),
    }
}

/// [`sampled_horizons`], keeping `T` of each post's steepest sample (its
/// distance, or nothing).
fn sample<T: Tag<f64>>(
    terrain: &Terrain,
    azimuth: f64,
    max_distance: f64,
    out: &mut [f32],
    mut distances: Option<&mut [f32]>,
) {
    let (w, h) = (terrain.width, terrain.height);
    assert_eq!(out.len(), w * h);
    let (e, n) = compass(azimuth);
    let step = terrain.dx.min(terrain.dy);
    // Per sample: rows south, and east in units of the centre row's `dx`
    // ([`Terrain::key_position`]: each row has its own spacing).
    let (se, sr) = (e * step / terrain.dx, -n * step / terrain.dy);
    let centre = terrain.centre_column();
    // Columns per key unit, row by row (1 on a uniform grid): a multiply
    // per sample instead of a division.
    let columns_per_unit: Vec<f64> = (0..h)
        .map(|r| 1.0 / terrain.row_scale.at_half(2 * r as i64))
        .collect();
    let c = terrain.curvature;
    for row in 0..h {
        for col in 0..w {
            let zp = terrain.at(col, row);
            if zp.is_nan() {
                out[row * w + col] = f32::NAN;
                if let Some(d) = distances.as_deref_mut() {
                    d[row * w + col] = f32::NAN;
                }
                continue;
            }
            let east = terrain.key_position(col, row).0;
            let mut best = Steepest::<T>::default();
            let mut k = 1.0;
            loop {
                let d = k * step;
                let qr = (row as f64 + k * sr).round();
                if d > max_distance || !(0.0..h as f64).contains(&qr) {
                    break;
                }
                let qc = (centre + (east + k * se) * columns_per_unit[qr as usize]).round();
                if !(0.0..w as f64).contains(&qc) {
                    break;
                }
                let zq = terrain.at(qc as usize, qr as usize);
                // A nodata sample's slope is NaN, which `take` passes over.
                best.take((f64::from(zq) - c * d * d - f64::from(zp)) / d, T::of(d));
                k += 1.0;
            }
            out[row * w + col] = if best.found() {
                best.slope.atan().to_degrees() as f32
            } else {
                -90.0
            };
            if let Some(d) = distances.as_deref_mut() {
                d[row * w + col] = metres(best.tag);
            }
        }
    }
}
