//! The viewshed of one observer: for every post within reach, whether the
//! sight line from the observer's eye to a target above the post clears
//! the surface, and the elevation angle of the post.
//!
//! **Surface.** The two triangles per cell of [`terrabake_format::surface`],
//! with the earth's curvature as the horizons stage has it
//! ([`crate::algorithms::horizon::line`]): a point at horizontal distance `d` from the
//! observer drops by `c d^2`, applied where the sight line crosses a grid
//! line or a cell diagonal, and the surface is linear between those
//! crossings. The sight line is straight in that frame, so it clears the
//! surface exactly when it clears every crossing; one that only grazes the
//! surface (touches, never passes below) sees the target. A crossing blocks
//! only where it lies on the surface (a corner or an edge of a cell with
//! four heights), so holes of nodata never block.
//!
//! **Geometry.** The observer stands on a post; post offsets become metres
//! with the east-west spacing of the observer's row (on a geographic grid
//! this is the local scale there: 0.1 % off at 50 km at 7 degrees of
//! latitude, far below a post's size in angle at that distance).
//!
//! **Method.** [`line_of_sight`] visits every crossing of one sight line;
//! it is the reference. [`observer_viewshed`] gives the same answer for
//! every post, faster: the sight line is cut at the borders of blocks of
//! [`BLOCK`] cells, and a block whose highest post (dropped by the
//! curvature at its nearest) lies below the sight line's lowest point over
//! the block is passed over; the others are walked crossing by crossing as
//! the reference does. A block's height bound includes one post around it,
//! so a crossing that rounding assigns to a neighbouring block is still
//! bounded. Posts are independent, computed row by row in parallel.

use rayon::prelude::*;

use crate::terrain::{MaxBlocks, Terrain};

/// Cells per side of the blocks [`observer_viewshed`] skips over.
pub const BLOCK: usize = 16;

/// `visible` value of a post outside the distance or without a height.
pub const OUTSIDE: u8 = 255;

/// Where the observer stands and what it looks at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observer {
    pub col: usize,
    pub row: usize,
    /// Eye above the ground, metres.
    pub height: f64,
    /// Target above the ground at every post, metres.
    pub target_height: f64,
    /// Posts farther than this (metres) are [`OUTSIDE`].
    pub max_distance: Option<f64>,
}

/// An observer's viewshed, one value per post, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Viewshed {
    /// 1 visible, 0 hidden, [`OUTSIDE`] beyond the distance or on nodata.
    pub visible: Vec<u8>,
    /// Elevation angle of the post's ground from the eye, degrees, with
    /// the curvature drop; NaN where `visible` is [`OUTSIDE`]. The
    /// observer's own post looks straight down (-90).
    pub angle: Vec<f32>,
}

/// The sight line from an observer's eye to one target post, in the frame
/// of the curvature drop (see the module docs).
#[derive(Debug, Clone, Copy)]
struct Sight {
    /// Observer post (u = column, v = row).
    from: (i64, i64),
    to: (i64, i64),
    eye: f64,
    /// Target height minus the curvature drop at the target.
    target: f64,
    /// Horizontal length, metres.
    length: f64,
    curvature: f64,
}

impl Sight {
    /// Height of the sight line at fraction `t` of the way.
    #[inline]
    fn at(&self, t: f64) -> f64 {
        self.eye + t * (self.target - self.eye)
    }

    /// Whether a crossing at fraction `t` with surface height `z` rises
    /// strictly above the sight line.
    #[inline]
    fn blocked_by(&self, t: f64, z: f64) -> bool {
        let d = t * self.length;
        z - self.curvature * d * d > self.at(t)
    }
}

fn sight(terrain: &Terrain, obs: &Observer, (col, row): (usize, usize)) -> Option<Sight> {
    let z0 = f64::from(terrain.at(obs.col, obs.row));
    let z1 = f64::from(terrain.at(col, row));
    if z1.is_nan() {
        return None;
    }
    // Metres per column and row at the observer (see the module docs).
    let (sx, sy) = (terrain.dx_at(obs.row), terrain.dy);
    let du = col as f64 - obs.col as f64;
    let dv = row as f64 - obs.row as f64;
    let length = (du * sx).hypot(dv * sy);
    if obs.max_distance.is_some_and(|m| length > m) {
        return None;
    }
    let c = terrain.curvature;
    Some(Sight {
        from: (obs.col as i64, obs.row as i64),
        to: (col as i64, row as i64),
        eye: z0 + obs.height,
        target: z1 + obs.target_height - c * length * length,
        length,
        curvature: c,
    })
}

/// One family of crossings of a sight line: the lines `k = a u + b v` for
/// integer `k` strictly between the ends, in order from the observer. A
/// crossing's position is computed in integers (a cell and a fraction's
/// numerator), so that one on a post is recognised exactly.
#[derive(Debug, Clone, Copy)]
enum Family {
    /// `u = k`: vertical grid lines.
    Columns,
    /// `v = k`: horizontal grid lines.
    Rows,
    /// `u + v = k`: the SW-NE cell diagonals.
    Diagonals,
}

impl Family {
    const ALL: [Family; 3] = [Family::Columns, Family::Rows, Family::Diagonals];

    fn coord(self, (u, v): (i64, i64)) -> i64 {
        match self {
            Family::Columns => u,
            Family::Rows => v,
            Family::Diagonals => u + v,
        }
    }

    /// The crossing with line `k`: `t` and the surface height there, if it
    /// lies on the surface.
    #[inline]
    fn crossing(self, terrain: &Terrain, s: &Sight, k: i64) -> (f64, Option<f64>) {
        let (u0, v0) = s.from;
        let (du, dv) = (s.to.0 - u0, s.to.1 - v0);
        let den = self.coord((du, dv));
        let num = k - self.coord(s.from);
        let t = self.t(s, k);
        // The other coordinate exactly: along a column line v = v0 + num dv / den.
        let z = |c: i64, r: i64| f64::from(terrain.at(c as usize, r as usize));
        let lerp = |a: f64, b: f64, f: f64| a + f * (b - a);
        let split = |x: i64| (x.div_euclid(den.abs()), x.rem_euclid(den.abs()));
        let sign = den.signum();
        let z = match self {
            Family::Columns | Family::Rows => {
                let (along, other0) = match self {
                    Family::Columns => (dv, v0),
                    _ => (du, u0),
                };
                let (q, r) = split(other0 * den.abs() + num * along * sign);
                let (cell_lo, frac) = (q, r as f64 / den.abs() as f64);
                let at = |j: i64| match self {
                    Family::Columns => (k, j),
                    _ => (j, k),
                };
                let (a, b) = (at(cell_lo), at(cell_lo + 1));
                if r == 0 {
                    terrain.post_on_surface(a.0, a.1).then(|| z(a.0, a.1))
                } else {
                    // The cells either side of the edge from a to b.
                    let side = |o: i64| match self {
                        Family::Columns => (k + o, cell_lo),
                        _ => (cell_lo, k + o),
                    };
                    let on = terrain.cell_exists(side(-1).0, side(-1).1)
                        || terrain.cell_exists(side(0).0, side(0).1);
                    on.then(|| lerp(z(a.0, a.1), z(b.0, b.1), frac))
                }
            }
            Family::Diagonals => {
                let (c, r) = split(u0 * den.abs() + num * du * sign);
                if r == 0 {
                    // A post: a column or row crossing too, counted there.
                    None
                } else {
                    let f = r as f64 / den.abs() as f64;
                    let row = k - c - 1;
                    terrain
                        .cell_exists(c, row)
                        .then(|| lerp(z(c, row + 1), z(c + 1, row), f))
                }
            }
        };
        (t, z)
    }

    /// Fraction of the way at which the sight line meets line `k`.
    #[inline]
    fn t(self, s: &Sight, k: i64) -> f64 {
        let den = self.coord((s.to.0 - s.from.0, s.to.1 - s.from.1));
        (k - self.coord(s.from)) as f64 / den as f64
    }

    /// The first line after `k` (going from `a` towards `end` by `step`)
    /// met beyond fraction `tb`, without computing heights.
    fn skip_to(self, s: &Sight, (k, end, step): (i64, i64, i64), tb: f64) -> i64 {
        let a = self.coord(s.from);
        let span = (end - a).abs();
        let mut n = ((tb * span as f64).floor() as i64 + 1).clamp((k - a).abs(), span);
        while n > (k - a).abs() && self.t(s, a + (n - 1) * step) > tb {
            n -= 1;
        }
        while n < span && self.t(s, a + n * step) <= tb {
            n += 1;
        }
        a + n * step
    }

    /// The lines `k` strictly between the ends.
    fn range(self, s: &Sight) -> (i64, i64, i64) {
        let (a, b) = (self.coord(s.from), self.coord(s.to));
        (a, b, (b - a).signum())
    }
}

/// Whether the observer sees the target above post `target`, by every
/// crossing of the sight line (the reference); `None` outside the distance
/// or on nodata.
pub fn line_of_sight(terrain: &Terrain, obs: &Observer, target: (usize, usize)) -> Option<bool> {
    let s = sight(terrain, obs, target)?;
    for family in Family::ALL {
        let (a, b, step) = family.range(&s);
        let mut k = a + step;
        while step != 0 && k != b {
            if let (t, Some(z)) = family.crossing(terrain, &s, k) {
                if s.blocked_by(t, z) {
                    return Some(false);
                }
            }
            k += step;
        }
    }
    Some(true)
}

/// The elevation angle (degrees) of a post's ground from the eye.
fn ground_angle(terrain: &Terrain, s: &Sight, target: (usize, usize)) -> f32 {
    if s.length == 0.0 {
        return -90.0;
    }
    let c = terrain.curvature;
    let ground = f64::from(terrain.at(target.0, target.1)) - c * s.length * s.length;
    (ground - s.eye).atan2(s.length).to_degrees() as f32
}

/// Whether the sight line clears the surface, skipping the blocks it passes
/// high above (see the module docs); `boundaries` is scratch space.
fn clears(terrain: &Terrain, blocks: &MaxBlocks, s: &Sight, boundaries: &mut Vec<f64>) -> bool {
    let (u0, v0) = (s.from.0 as f64, s.from.1 as f64);
    let (du, dv) = ((s.to.0 - s.from.0) as f64, (s.to.1 - s.from.1) as f64);
    boundaries.clear();
    for (p0, d) in [(s.from.0, s.to.0 - s.from.0), (s.from.1, s.to.1 - s.from.1)] {
        let (lo, hi) = (p0.min(p0 + d), p0.max(p0 + d));
        let first = lo.div_euclid(BLOCK as i64) + 1;
        let mut m = first * BLOCK as i64;
        while m < hi {
            boundaries.push((m - p0) as f64 / d as f64);
            m += BLOCK as i64;
        }
    }
    boundaries.push(1.0);
    boundaries.sort_unstable_by(f64::total_cmp);
    // The next line of each family, walked in order of t.
    let mut next = Family::ALL.map(|f| {
        let (a, b, step) = f.range(s);
        (a + step, b, step)
    });
    let margin = 1e-6 * (1.0 + s.eye.abs() + s.target.abs());
    let mut ta = 0.0;
    for &tb in boundaries.iter() {
        let tm = 0.5 * (ta + tb);
        let top = blocks.max(blocks.block(u0 + tm * du, v0 + tm * dv));
        let near = (ta - 1e-9).max(0.0) * s.length;
        let skip = top - s.curvature * near * near + margin < s.at(ta).min(s.at(tb));
        for (family, (k, end, step)) in Family::ALL.into_iter().zip(next.iter_mut()) {
            if skip {
                if *step != 0 {
                    *k = family.skip_to(s, (*k, *end, *step), tb);
                }
                continue;
            }
            while *step != 0 && *k != *end {
                let (t, z) = family.crossing(terrain, s, *k);
                if t > tb {
                    break;
                }
                if z.is_some_and(|z| s.blocked_by(t, z)) {
                    return false;
                }
                *k += *step;
            }
        }
        ta = tb;
    }
    true
}

/// The viewshed of `obs` over the whole of `terrain` (see the module docs).
pub fn observer_viewshed(terrain: &Terrain, obs: &Observer) -> Viewshed {
    let (w, h) = (terrain.width, terrain.height);
    // One post around each block: a crossing that rounding puts in the
    // neighbouring block is still bounded (module docs).
    let blocks = MaxBlocks::of(terrain, BLOCK, 1);
    let mut visible = vec![OUTSIDE; w * h];
    let mut angle = vec![f32::NAN; w * h];
    visible
        .par_chunks_mut(w)
        .zip(angle.par_chunks_mut(w))
        .enumerate()
        .for_each_init(Vec::new, |scratch, (row, (vis, ang))| {
            for col in 0..w {
                let Some(s) = sight(terrain, obs, (col, row)) else {
                    continue;
                };
                ang[col] = ground_angle(terrain, &s, (col, row));
                vis[col] = u8::from(clears(terrain, &blocks, &s, scratch));
            }
        });
    Viewshed { visible, angle }
}
