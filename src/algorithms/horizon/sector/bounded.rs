//! Sector horizons within a maximum distance: a scan of the posts within
//! reach, for the stage's out-of-core bands (the tree of [`super`] needs
//! the whole DEM).

use super::{elevation_deg, NarrowStencil, SectorFrame, SectorStats};
use crate::terrain::steepest::{Steepest, Tag};
use crate::terrain::{angle_between, posts_within, Terrain};

/// Sector horizons looking no farther than `max_distance` metres (the
/// horizontal distance from the post), for the posts of output rows `rows`
/// into `out` (`rows.len()` rows). `terrain` may be a window of rows: it
/// must hold every row within `max_distance` of `rows` that the DEM has.
///
/// Stewart's tree cannot bound the distance (its hulls hold every processed
/// post of the wedge), so each post scans its wedge within the distance row
/// by row: on each row the wedge and the disc are an interval of columns,
/// found from the keys' linear form and widened by a hair for rounding;
/// every candidate is then tested with the same keys and tie rules as the
/// tree. `O(M^2 / S)` per post for a distance of `M` posts; exact; and
/// independent of everything beyond the distance, so the stage runs it
/// band by band out of core. `distances`, where given (the shape of
/// `out`), receives each post's horizontal distance to the post that sets
/// its horizon, as [`super::sector_horizons_with_distances`].
pub fn sector_horizons_within(
    terrain: &Terrain,
    sector: (usize, usize),
    narrow: bool,
    max_distance: f64,
    area: [std::ops::Range<usize>; 2],
    out: &mut [f32],
    distances: Option<&mut [f32]>,
) -> SectorStats {
    assert_eq!(out.len(), area[0].len() * terrain.width);
    match distances {
        None => scan::<()>(terrain, sector, narrow, max_distance, area, out, None),
        Some(d) => {
            assert_eq!(d.len(), out.len());
            scan::<Option<f64>>(terrain, sector, narrow, max_distance, area, out, Some(d))
        }
    }
}

/// [`sector_horizons_within`], keeping `T` of each post's steepest
/// candidate (its distance, or nothing).
fn scan<T: Tag<f64>>(
    terrain: &Terrain,
    (index, count): (usize, usize),
    narrow: bool,
    max_distance: f64,
    [rows, cols]: [std::ops::Range<usize>; 2],
    out: &mut [f32],
    mut distances: Option<&mut [f32]>,
) -> SectorStats {
    let w = terrain.width;
    let frame = SectorFrame::new(index, count, terrain.dx, terrain.dy);
    let stencil = narrow.then(|| NarrowStencil::new(&frame, count, terrain.dx, terrain.dy));
    let window = terrain.row0..terrain.row0 + terrain.z.len() / w;
    let (c, aspect) = (terrain.curvature, terrain.dy / terrain.dx);
    // The distance in key units (`dx` metres).
    let reach = max_distance / terrain.dx;
    // Rows the wedge can reach: from the north components of its directions
    // (its two boundaries, and due north or south if inside), a row of
    // margin each way.
    let (mid, width) = (
        SectorFrame::centre_azimuth(index, count),
        360.0 / count as f64,
    );
    let inside = |az: f64| angle_between(az, mid) <= width / 2.0;
    let norths = [frame.lo.1, frame.hi.1];
    let north_max = if inside(0.0) {
        1.0
    } else {
        norths[0].max(norths[1])
    };
    let north_min = if inside(180.0) {
        -1.0
    } else {
        norths[0].min(norths[1])
    };
    let halo = posts_within(max_distance, terrain.dy);
    // A row of margin for the rounding of the wedge's north components.
    let reach_rows = |north: f64| (posts_within(max_distance * north, terrain.dy) + 1).min(halo);
    let (rows_north, rows_south) = (reach_rows(north_max), reach_rows(-north_min));
    let (a, b) = (frame.lo, frame.hi);
    let centre = terrain.centre_column();
    let mut stats = SectorStats::default();
    for (i, v) in out.iter_mut().enumerate() {
        let (col, row) = (i % w, rows.start + i / w);
        let zp = terrain.at(col, row);
        let distance = distances.as_deref_mut().map(|d| &mut d[i]);
        if zp.is_nan() || !cols.contains(&col) {
            *v = f32::NAN;
            if let Some(d) = distance {
                *d = f32::NAN;
            }
            continue;
        }
        let pp = terrain.key_position(col, row);
        let kp = frame.keys(pp);
        let tp = frame.along(pp);
        let wp = f64::from(zp) - c * tp * tp;
        let mut best = Steepest::<T>::default();
        let consider = |qc: usize, qr: usize, best: &mut Steepest<T>| {
            let zq = terrain.at(qc, qr);
            let pq = terrain.key_position(qc, qr);
            let d = terrain.key_distance(pp, pq);
            if zq.is_nan() || d > max_distance {
                return;
            }
            let tq = frame.along(pq);
            best.take((f64::from(zq) - c * tq * tq - wp) / (tq - tp), T::of(d));
        };
        let (r0, r1) = (
            row.saturating_sub(rows_north),
            (row + rows_south).min(terrain.height - 1),
        );
        for qr in r0.max(window.start)..=r1.min(window.end - 1) {
            // The wedge and the disc on this row, as an interval of `e`.
            let n = -(qr as f64) * aspect;
            let dn = n - pp.1;
            let half = (reach * reach - dn * dn).max(0.0).sqrt();
            let (mut lo, mut hi) = (pp.0 - half, pp.0 + half);
            // a_perp key `a.1 e - a.0 n` at least p's; b_perp key
            // `b.0 n - b.1 e` at least p's (ties settled by the exact test).
            for (coef, bound) in [(a.1, kp[0] + a.0 * n), (-b.1, kp[2] - b.0 * n)] {
                if coef > 0.0 {
                    lo = lo.max(bound / coef);
                } else if coef < 0.0 {
                    hi = hi.min(bound / coef);
                } else if bound > 0.0 {
                    hi = f64::NEG_INFINITY;
                }
            }
            if lo > hi {
                continue;
            }
            // Widened by far more than the rounding of the bounds (1e-12
            // of a column), far less than a column.
            let scale = terrain.row_scale.at_half(2 * qr as i64);
            let to_col = |e: f64| centre + e / scale;
            let c0 = (to_col(lo) - 1e-6).ceil().max(0.0) as usize;
            let c1 = (to_col(hi) + 1e-6).floor().min((w - 1) as f64);
            if c1 < 0.0 {
                continue;
            }
            for qc in c0..=c1 as usize {
                stats.tangent_steps += 1;
                let kq = frame.keys(terrain.key_position(qc, qr));
                if SectorFrame::contains(&kp, &kq) {
                    consider(qc, qr, &mut best);
                }
            }
        }
        for &(dc, dr) in stencil.as_ref().map_or(&[][..], |s| &s.offsets[..]) {
            let (qc, qr) = (col as i64 + dc, row as i64 + dr);
            if terrain.contains(qc, qr)
                && window.contains(&(qr as usize))
                && frame.along(terrain.key_position(qc as usize, qr as usize)) > tp
            {
                consider(qc as usize, qr as usize, &mut best);
            }
        }
        *v = elevation_deg(best.slope, c, tp);
        if let Some(d) = distance {
            *d = crate::terrain::steepest::metres(best.tag);
        }
    }
    stats
}

/// The sector horizon of the one post `(col, row)` from the whole DEM
/// (what the tree gives it), degrees, by [`sector_horizons_within`] over a
/// reach that grows until no post beyond it could rise above the horizon
/// found: from `top` (the DEM's highest post), a post at horizontal
/// distance `d` in the wedge lies at `t >= d cos(180 / count)` along its
/// centre line, so its slope is at most `(top - z) / t - c t`. The
/// planner's pilot measures single posts with it, in the time of their
/// own reach rather than the tree's whole DEM.
pub fn sector_horizon_of_post(
    terrain: &Terrain,
    (col, row): (usize, usize),
    sector: (usize, usize),
    narrow: bool,
    top: f64,
) -> f32 {
    let z = f64::from(terrain.at(col, row));
    if z.is_nan() {
        return f32::NAN;
    }
    // The farthest any post lies: beyond it the scan is the whole DEM.
    let p = terrain.key_position(col, row);
    let farthest = [(0, 0), (terrain.width - 1, 0), (0, terrain.height - 1)]
        .into_iter()
        .chain([(terrain.width - 1, terrain.height - 1)])
        .map(|(c, r)| terrain.key_distance(p, terrain.key_position(c, r)))
        .fold(0.0, f64::max)
        + terrain.dx.max(terrain.dy);
    let cos_half = (std::f64::consts::PI / sector.1 as f64).cos();
    let c = terrain.curvature;
    let mut out = vec![0f32; terrain.width];
    let mut reach = (64.0 * terrain.dx.max(terrain.dy)).min(farthest);
    loop {
        sector_horizons_within(
            terrain,
            sector,
            narrow,
            reach,
            [row..row + 1, col..col + 1],
            &mut out,
            None,
        );
        let angle = out[col];
        if reach >= farthest {
            return angle;
        }
        // The steepest slope any post beyond the reach could have; a
        // relative margin over the f32 rounding of the angle found.
        let t = reach * cos_half;
        let beyond = (top - z) / t - c * t;
        let found = f64::from(angle).to_radians().tan();
        if angle > -90.0 && beyond < found - 1e-5 * (1.0 + found.abs()) {
            return angle;
        }
        // Far enough for the horizon found to stand (where it is above
        // the bound's floor), and at least twice as far.
        let needed = if angle > -90.0 && c > 0.0 {
            let s = found;
            (-s + (s * s + 4.0 * c * (top - z).max(0.0)).sqrt()) / (2.0 * c) / cos_half
        } else if angle > -90.0 && found > 0.0 {
            (top - z) / found / cos_half
        } else {
            farthest
        };
        reach = needed.max(2.0 * reach).min(farthest);
    }
}
