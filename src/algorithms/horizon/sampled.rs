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
    let walk = SampledWalk::new(terrain, azimuth);
    for row in 0..h {
        for col in 0..w {
            let (angle, best) = walk.steepest::<T>((col, row), max_distance);
            out[row * w + col] = angle;
            if let Some(d) = distances.as_deref_mut() {
                d[row * w + col] = best.map_or(f32::NAN, |b| metres(b.tag));
            }
        }
    }
}

/// The walk of one direction's samples over a terrain: what every post's
/// sampled horizon in that direction shares (the planner's pilot measures
/// single posts with it, the stage every post).
pub(crate) struct SampledWalk<'t> {
    terrain: &'t Terrain<'t>,
    /// Metres per sample.
    step: f64,
    /// Per sample: rows south, and east in units of the centre row's `dx`
    /// ([`Terrain::key_position`]: each row has its own spacing).
    east: f64,
    south: f64,
    /// Columns per key unit, row by row (1 on a uniform grid): a multiply
    /// per sample instead of a division.
    columns_per_unit: Vec<f64>,
}

impl<'t> SampledWalk<'t> {
    /// The walk in direction `azimuth` (compass degrees).
    pub(crate) fn new(terrain: &'t Terrain<'t>, azimuth: f64) -> Self {
        let (e, n) = compass(azimuth);
        let step = terrain.dx.min(terrain.dy);
        Self {
            terrain,
            step,
            east: e * step / terrain.dx,
            south: -n * step / terrain.dy,
            columns_per_unit: (0..terrain.height)
                .map(|r| 1.0 / terrain.row_scale.at_half(2 * r as i64))
                .collect(),
        }
    }

    /// The sampled horizon of post `(col, row)`, degrees (NaN for nodata,
    /// -90 where no sample was taken), looking at most `max_distance`
    /// metres, and its steepest sample (`None` for nodata).
    pub(crate) fn steepest<T: Tag<f64>>(
        &self,
        (col, row): (usize, usize),
        max_distance: f64,
    ) -> (f32, Option<Steepest<T>>) {
        let t = self.terrain;
        let (w, h) = (t.width, t.height);
        let zp = t.at(col, row);
        if zp.is_nan() {
            return (f32::NAN, None);
        }
        let (centre, c) = (t.centre_column(), t.curvature);
        let east = t.key_position(col, row).0;
        let mut best = Steepest::<T>::default();
        let mut k = 1.0;
        loop {
            let d = k * self.step;
            let qr = (row as f64 + k * self.south).round();
            if d > max_distance || !(0.0..h as f64).contains(&qr) {
                break;
            }
            let qc = (centre + (east + k * self.east) * self.columns_per_unit[qr as usize]).round();
            if !(0.0..w as f64).contains(&qc) {
                break;
            }
            let zq = t.at(qc as usize, qr as usize);
            // A nodata sample's slope is NaN, which `take` passes over.
            best.take((f64::from(zq) - c * d * d - f64::from(zp)) / d, T::of(d));
            k += 1.0;
        }
        let angle = if best.found() {
            best.slope.atan().to_degrees() as f32
        } else {
            -90.0
        };
        (angle, Some(best))
    }
}
