//! After the tree: Stewart's IV-E narrow-sector check (sec. IV-E) over
//! each post's stencil, row by row in vector lanes, and the angles.

use super::{elevation_deg, NarrowStencil};
use crate::terrain::steepest::Tag;
use crate::terrain::Terrain;

/// Stewart's IV-E stencil, then the angles: row by row, in the order of
/// memory (in the sweep's order each of the stencil's posts was a cache
/// miss), each a loop without calls (vector code). `planes` holds each
/// post's centre-plane `t` and `w` and the tree's steepest slope and tag.
pub(super) fn narrow_and_angles<T: Tag<u32>>(
    terrain: &Terrain,
    stencil: Option<&NarrowStencil>,
    (ts, ws, slopes, tags): (&[f64], &[f64], &mut [f64], &mut [T]),
    out: &mut [f32],
    mut distances: Option<&mut [f32]>,
) {
    let (w, c) = (terrain.width, terrain.curvature);
    let position = |i: u32| terrain.key_position(i as usize % w, i as usize / w);
    let rows = ts.chunks(w).zip(ws.chunks(w));
    let outputs = slopes
        .chunks_mut(w)
        .zip(tags.chunks_mut(w))
        .zip(out.chunks_mut(w));
    for (row, ((tp, wp), ((best, tag), out_row))) in rows.zip(outputs).enumerate() {
        for &(dc, dr) in stencil.map_or(&[][..], |s| &s.offsets[..]) {
            // The columns whose post `(col + dc, qr)` is in the grid.
            let qr = row as i64 + dr;
            let (c0, c1) = ((-dc).max(0), (w as i64 - dc).min(w as i64));
            if !terrain.contains(0, qr) || c0 >= c1 {
                continue;
            }
            let cols = c0 as usize..c1 as usize;
            let first = qr as usize * w + (cols.start as i64 + dc) as usize;
            let q = first..first + cols.len();
            let lanes = Lanes {
                p: (&tp[cols.clone()], &wp[cols.clone()]),
                q: (&ts[q.clone()], &ws[q]),
                first: first as u32,
            };
            narrow_row(lanes, &mut best[cols.clone()], &mut tag[cols]);
        }
        for (col, ((v, &slope), &tp)) in out_row.iter_mut().zip(&*best).zip(tp).enumerate() {
            *v = if tp.is_nan() {
                f32::NAN
            } else {
                elevation_deg(slope, c, tp)
            };
            if let (Some(d), Some(q)) = (distances.as_deref_mut(), tag[col].get()) {
                let post = row * w + col;
                d[post] = terrain.key_distance(position(post as u32), position(q)) as f32;
            }
        }
    }
}

/// A row of posts `p` (`t` and `w`) and, for one offset of the IV-E
/// stencil, the posts `q` at that offset from each, the first of them post
/// `first` of the grid.
struct Lanes<'a> {
    p: (&'a [f64], &'a [f64]),
    q: (&'a [f64], &'a [f64]),
    first: u32,
}

/// Each post's steepest slope `best` (and its `tag`) raised to the slope to
/// its post `q` where `q` lies in front (`t` beyond it): lane by lane, so
/// that the loop is vector code; each post meets the stencil's offsets in
/// the same order as a post-by-post loop, and so keeps the same tag.
#[inline(always)]
fn narrow_row<T: Tag<u32>>(lanes: Lanes, best: &mut [f64], tag: &mut [T]) {
    let Lanes {
        p: (tp, wp),
        q: (tq, wq),
        first,
    } = lanes;
    let n = best.len();
    let (tp, wp, tq, wq, tag) = (&tp[..n], &wp[..n], &tq[..n], &wq[..n], &mut tag[..n]);
    for i in 0..n {
        let slope = (wq[i] - wp[i]) / (tq[i] - tp[i]);
        // A post behind, nodata (NaN) on either side, or no steeper: kept.
        let steeper = tq[i] > tp[i] && slope > best[i];
        best[i] = if steeper { slope } else { best[i] };
        tag[i] = if steeper {
            T::of(first + i as u32)
        } else {
            tag[i]
        };
    }
}
