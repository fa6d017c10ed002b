//! The exact parameter planes: the limit of infinitely many slices, each
//! cell's cone slope from every higher cell at once (the reference the
//! sliced planes converge to), and the brute-force slopes that check both.

use rayon::prelude::*;

use terrabake_format::cones::{round_down_f32, round_up_f32};
use terrabake_format::trace::max_levels;

use super::{Cap, PlaneStats, Planes, SLOPE_MARGIN};

/// The exact planes (the limit of infinitely many slices) over a `cw x ch`
/// grid of `nmax` values; `z_floor` is the apex of cells with no surface
/// around them (the DEM's lowest height). `on_row` is called after every row.
pub(crate) fn exact_planes(
    nmax: &[f32],
    (cw, ch): (usize, usize),
    (dx, dy): (f64, f64),
    z_floor: f64,
    cap: Option<Cap>,
    on_row: &(dyn Fn() + Sync),
) -> Planes {
    assert_eq!(nmax.len(), cw * ch);
    // The max pyramid of `nmax` for the branch and bound; level 0 is `nmax`.
    let above = max_levels(cw, ch, nmax);
    let level = |l: usize| -> (usize, usize, &[f32]) {
        match l {
            0 => (cw, ch, nmax),
            _ => (above[l - 1].0, above[l - 1].1, &above[l - 1].2),
        }
    };
    let top = above.len();
    let (dx2, dy2) = (dx * dx, dy * dy);
    let mut apex = vec![0f32; cw * ch];
    let mut slope = vec![0f32; cw * ch];
    let nodes: u64 = apex
        .par_chunks_mut(cw)
        .zip(slope.par_chunks_mut(cw))
        .enumerate()
        .map_init(Vec::new, |stack, (y, (apex_row, slope_row))| {
            let mut nodes = 0u64;
            // The previous cell's tightest cell: usually this cell's too.
            let mut seed: Option<(usize, usize)> = None;
            for x in 0..cw {
                let a = f64::from(nmax[y * cw + x]).max(z_floor);
                // Squared offsets in metres from cell (x, y) to the nearest
                // cell of the index ranges.
                let gap2 = |x0: usize, x1: usize, y0: usize, y1: usize| {
                    let ex = x0.saturating_sub(x).max(x.saturating_sub(x1)) as f64;
                    let ey = y0.saturating_sub(y).max(y.saturating_sub(y1)) as f64;
                    ex * ex * dx2 + ey * ey * dy2
                };
                // The best squared slope so far: distance^2 / rise^2.
                let cap_slope = Cap::slope(cap, a);
                let mut best = cap_slope * cap_slope;
                let mut best_at = None;
                if let Some((sx, sy)) = seed {
                    let rise = f64::from(nmax[sy * cw + sx]) - a;
                    if rise > 0.0 {
                        let s = gap2(sx, sx, sy, sy) / (rise * rise);
                        if s < best {
                            (best, best_at) = (s, Some((sx, sy)));
                        }
                    }
                }
                stack.clear();
                let root_rise = f64::from(level(top).2[0]) - a;
                if root_rise > 0.0 {
                    stack.push((
                        top,
                        0usize,
                        0usize,
                        gap2(0, cw - 1, 0, ch - 1) / (root_rise * root_rise),
                    ));
                }
                while let Some((node_level, nx, ny, bound)) = stack.pop() {
                    if bound >= best {
                        continue;
                    }
                    nodes += 1;
                    if node_level == 0 {
                        (best, best_at) = (bound, Some((nx, ny)));
                        continue;
                    }
                    let (w, h, max) = level(node_level - 1);
                    let size = 1usize << (node_level - 1);
                    let first = stack.len();
                    for cy in 2 * ny..(2 * ny + 2).min(h) {
                        for cx in 2 * nx..(2 * nx + 2).min(w) {
                            let rise = f64::from(max[cy * w + cx]) - a;
                            if rise <= 0.0 {
                                continue;
                            }
                            let (x0, y0) = (cx * size, cy * size);
                            let (x1, y1) = ((x0 + size).min(cw) - 1, (y0 + size).min(ch) - 1);
                            let s = gap2(x0, x1, y0, y1) / (rise * rise);
                            if s < best {
                                stack.push((node_level - 1, cx, cy, s));
                            }
                        }
                    }
                    // Nearest-looking child on top of the stack.
                    stack[first..].sort_unstable_by(|p, q| q.3.total_cmp(&p.3));
                }
                seed = best_at;
                apex_row[x] = round_up_f32(a);
                slope_row[x] = round_down_f32(best.sqrt() * SLOPE_MARGIN);
            }
            on_row();
            nodes
        })
        .sum();
    Planes {
        apex,
        slope,
        stats: PlaneStats {
            nodes,
            ..PlaneStats::default()
        },
    }
}

/// The definition, O(n^2): for tests. Every cell's cone as the least slope
/// over every taller cell for the given apexes (`apex[i]` must be at least
/// the cell's `nmax`).
pub fn brute_force_slopes(
    nmax: &[f32],
    (cw, ch): (usize, usize),
    (dx, dy): (f64, f64),
    apex: &[f32],
) -> Vec<f64> {
    (0..cw * ch)
        .map(|i| {
            let (x, y) = ((i % cw) as f64, (i / cw) as f64);
            let a = f64::from(apex[i]);
            (0..cw * ch)
                .filter(|&j| f64::from(nmax[j]) > a)
                .map(|j| {
                    let (ex, ey) = ((x - (j % cw) as f64) * dx, (y - (j / cw) as f64) * dy);
                    (ex * ex + ey * ey).sqrt() / (f64::from(nmax[j]) - a)
                })
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
}
