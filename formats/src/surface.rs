//! The continuous surface that a DEM stands for, in every part of terrabake:
//! the tracers, the pyramid, and later the cones and the line horizons.
//!
//! **Posts** are the DEM's samples. A **cell** is the square between four
//! posts: cell `(c, r)` has corners at posts `(c, r)` (north-west),
//! `(c + 1, r)` (north-east), `(c, r + 1)` (south-west) and `(c + 1, r + 1)`
//! (south-east), so a `W x H` DEM has `(W - 1) x (H - 1)` cells.
//!
//! Each cell is split along its **south-west to north-east diagonal** into two
//! triangles, each the plane through its three posts: Henning and
//! Stephenson's linear-plane reconstruction (2004, sec. 3), and what a mesh
//! renderer draws from the same posts, so a traced hit and a rasterised mesh
//! agree. We depart from Paglieroni and Petersen (1992, sec. 1.1), who use a
//! bilinear patch: along a straight line a triangle's height is linear, so
//! every ray-cell test is one linear root per triangle (exact up to rounding,
//! no quadratic), and a terrain profile along a line is piecewise linear with
//! vertices on cell edges, which is what Timonen's convex hulls need.
//!
//! A cell's **bounding heights** are its tallest and lowest corner (the
//! triangles lie between them). A cell with a **nodata** corner has no
//! surface: rays pass through it, its maximum is `-inf` and its minimum
//! `+inf`. Real terrain beside a hole is untouched (a cell exists exactly when
//! its four posts do), and no ray hits an invented height.
//!
//! A ray **hits** at the first parameter `t` where the ray is at or below the
//! surface: a ray that starts below the terrain hits where it starts, and a
//! ray that grazes a ridge (touches it exactly) hits there.

/// The four corner heights of a cell; NaN for nodata.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    pub nw: f32,
    pub ne: f32,
    pub sw: f32,
    pub se: f32,
}

impl Cell {
    /// Whether the cell has a surface (no nodata corner).
    pub fn exists(&self) -> bool {
        !(self.nw.is_nan() || self.ne.is_nan() || self.sw.is_nan() || self.se.is_nan())
    }

    /// Tallest corner, `-inf` for a cell without surface.
    pub fn max(&self) -> f32 {
        if self.exists() {
            self.nw.max(self.ne).max(self.sw).max(self.se)
        } else {
            f32::NEG_INFINITY
        }
    }

    /// Lowest corner, `+inf` for a cell without surface.
    pub fn min(&self) -> f32 {
        if self.exists() {
            self.nw.min(self.ne).min(self.sw).min(self.se)
        } else {
            f32::INFINITY
        }
    }

    /// Surface height at `(east, north)` fractions of the cell in [0, 1];
    /// clamped to the bounding heights so that rounding never lifts the
    /// surface above its tallest corner (the pyramids rely on that).
    /// Inline across crates: the tracers and the exact references call it
    /// once a step.
    #[inline]
    pub fn height(&self, east: f64, north: f64) -> f64 {
        let (e, n) = (east.clamp(0.0, 1.0), north.clamp(0.0, 1.0));
        let [nw, ne, sw, se] = [self.nw, self.ne, self.sw, self.se].map(f64::from);
        let z = if e >= n {
            // South-east triangle: SW, SE, NE.
            sw + e * (se - sw) + n * (ne - se)
        } else {
            // North-west triangle: SW, NE, NW.
            sw + n * (nw - sw) + e * (ne - nw)
        };
        z.clamp(f64::from(self.min()), f64::from(self.max()))
    }

    /// Upward normal (not normalised) of the triangle at `(east, north)`,
    /// for cells of `dx x dy` metres.
    pub fn normal(&self, east: f64, north: f64, dx: f64, dy: f64) -> [f64; 3] {
        let [nw, ne, sw, se] = [self.nw, self.ne, self.sw, self.se].map(f64::from);
        let (dzde, dzdn) = if east >= north {
            (se - sw, ne - se)
        } else {
            (ne - nw, nw - sw)
        };
        [-dzde / dx, -dzdn / dy, 1.0]
    }
}

/// The smooth upward normal (not normalised) at `(east, north)` fractions
/// of a cell, for shading: each corner post's normal by central
/// differences over its neighbours, bilinear between the four corners
/// (Gouraud's interpolation, applied to normals as Phong does). The flat
/// [`Cell::normal`] shows every triangle as a facet; this one is
/// continuous across cell edges and equals it on a plane.
///
/// `posts` is the 4 x 4 window of posts around the cell, row-major from
/// the north: the cell's corners are `posts[5]` (north-west), `posts[6]`,
/// `posts[9]` and `posts[10]` (south-east). A post outside the DEM or
/// nodata is NaN; a corner then takes a one-sided difference, or none
/// (a zero slope) where both sides are missing. Cells of `dx x dy` metres.
pub fn smooth_normal(posts: &[f32; 16], east: f64, north: f64, dx: f64, dy: f64) -> [f64; 3] {
    let p = |row: usize, col: usize| f64::from(posts[row * 4 + col]);
    // A slope from the posts before and after one, over the gap they span.
    let slope =
        |before: f64, here: f64, after: f64, step: f64| match (before.is_nan(), after.is_nan()) {
            (false, false) => (after - before) / (2.0 * step),
            (true, false) => (after - here) / step,
            (false, true) => (here - before) / step,
            (true, true) => 0.0,
        };
    let corner = |row: usize, col: usize| -> [f64; 2] {
        let here = p(row, col);
        if here.is_nan() {
            return [f64::NAN; 2];
        }
        [
            slope(p(row, col - 1), here, p(row, col + 1), dx),
            // North is up the window: rows decrease northwards.
            slope(p(row + 1, col), here, p(row - 1, col), dy),
        ]
    };
    let (e, n) = (east.clamp(0.0, 1.0), north.clamp(0.0, 1.0));
    let (mut slopes, mut weight) = ([0.0; 2], 0.0);
    for (row, col, w) in [
        (1, 1, (1.0 - e) * n),
        (1, 2, e * n),
        (2, 1, (1.0 - e) * (1.0 - n)),
        (2, 2, e * (1.0 - n)),
    ] {
        let s = corner(row, col);
        if w > 0.0 && !s[0].is_nan() {
            slopes = [slopes[0] + w * s[0], slopes[1] + w * s[1]];
            weight += w;
        }
    }
    if weight == 0.0 {
        return [0.0, 0.0, 1.0];
    }
    [-slopes[0] / weight, -slopes[1] / weight, 1.0]
}

/// A ray in grid space: `u` east in posts (column), `v` south in posts (row),
/// `z` in metres; `point(t) = origin + t * dir`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridRay {
    pub origin: [f64; 3],
    pub dir: [f64; 3],
}

impl GridRay {
    #[inline]
    pub fn at(&self, t: f64) -> [f64; 3] {
        [
            self.origin[0] + t * self.dir[0],
            self.origin[1] + t * self.dir[1],
            self.origin[2] + t * self.dir[2],
        ]
    }

    #[inline]
    pub fn z(&self, t: f64) -> f64 {
        self.origin[2] + t * self.dir[2]
    }

    /// Parameter interval during which the ray's ground track lies in the
    /// closed slab `lo <= coordinate <= hi` of `axis` (0: u, 1: v); empty
    /// (`lo > hi`) when it never does. Every tracer and the brute force use
    /// this one formula, so they agree bit for bit on which cells a ray
    /// touches and when.
    #[inline]
    pub fn slab(&self, axis: usize, lo: f64, hi: f64) -> (f64, f64) {
        let (o, d) = (self.origin[axis], self.dir[axis]);
        if d == 0.0 {
            if lo <= o && o <= hi {
                (f64::NEG_INFINITY, f64::INFINITY)
            } else {
                (f64::INFINITY, f64::NEG_INFINITY)
            }
        } else {
            let (a, b) = ((lo - o) / d, (hi - o) / d);
            if a <= b {
                (a, b)
            } else {
                (b, a)
            }
        }
    }

    /// The parameter interval during which the ray is over the closed square
    /// `[u0, u0 + size] x [v0, v0 + size]`, intersected with `[t_min, t_max]`.
    #[inline]
    pub fn square(&self, u0: f64, v0: f64, size: f64, t_min: f64, t_max: f64) -> (f64, f64) {
        let (a0, a1) = self.slab(0, u0, u0 + size);
        let (b0, b1) = self.slab(1, v0, v0 + size);
        (a0.max(b0).max(t_min), a1.min(b1).min(t_max))
    }
}

/// The first `t` in `[t0, t1]` (the interval during which the ray is over
/// cell `(c, r)`) at which the ray is at or below the cell's surface.
pub fn intersect_cell(cell: &Cell, c: u32, r: u32, ray: &GridRay, t0: f64, t1: f64) -> Option<f64> {
    if !cell.exists() || t0 > t1 {
        return None;
    }
    let (cu, rv) = (f64::from(c), f64::from(r));
    // Cell fractions: east = u - c, north = (r + 1) - v.
    let frac = |t: f64| {
        let p = ray.at(t);
        (p[0] - cu, rv + 1.0 - p[1])
    };
    // The ground track crosses the diagonal (east == north) at most once,
    // splitting [t0, t1] into parts that each lie in one triangle, where the
    // height difference is linear in t.
    let g = |t: f64| {
        let (e, n) = frac(t);
        e - n
    };
    let (g0, g1) = (g(t0), g(t1));
    let split = (g0 < 0.0 && g1 > 0.0) || (g0 > 0.0 && g1 < 0.0);
    let tm = if split {
        (t0 + (t1 - t0) * (g0 / (g0 - g1))).clamp(t0, t1)
    } else {
        t1
    };
    let parts = [(t0, tm), (tm, t1)];
    for &(a, b) in &parts[..if split { 2 } else { 1 }] {
        let height = |t: f64| {
            let (e, n) = frac(t);
            cell.height(e, n)
        };
        let (fa, fb) = (ray.z(a) - height(a), ray.z(b) - height(b));
        if fa <= 0.0 {
            return Some(a);
        }
        if fb <= 0.0 {
            return Some((a + (b - a) * (fa / (fa - fb))).clamp(a, b));
        }
    }
    None
}

#[cfg(test)]
mod smooth_normal_tests {
    use super::{smooth_normal, Cell};

    /// The 4 x 4 window around cell `(c, r)` of the heights `z(column, row)`.
    fn window(z: impl Fn(i32, i32) -> f32, c: i32, r: i32) -> [f32; 16] {
        std::array::from_fn(|i| z(c - 1 + (i % 4) as i32, r - 1 + (i / 4) as i32))
    }

    #[test]
    fn on_a_plane_it_is_the_triangles_normal() {
        // 3 m per column east, 2 m per row south; cells of 10 x 20 m.
        let z = |c: i32, r: i32| (3 * c + 2 * r) as f32;
        let posts = window(z, 5, 7);
        let cell = Cell {
            nw: posts[5],
            ne: posts[6],
            sw: posts[9],
            se: posts[10],
        };
        for (e, n) in [(0.1, 0.8), (0.5, 0.5), (0.9, 0.2)] {
            let flat = cell.normal(e, n, 10.0, 20.0);
            let smooth = smooth_normal(&posts, e, n, 10.0, 20.0);
            for k in 0..3 {
                assert!((flat[k] - smooth[k]).abs() < 1e-12, "{flat:?} {smooth:?}");
            }
        }
    }

    #[test]
    fn it_is_continuous_across_cell_edges_where_facets_are_not() {
        let z = |c: i32, r: i32| ((c * c) as f32) * 0.5 + (r * r) as f32;
        let (west, east) = (window(z, 4, 4), window(z, 5, 4));
        let a = smooth_normal(&west, 1.0, 0.3, 1.0, 1.0);
        let b = smooth_normal(&east, 0.0, 0.3, 1.0, 1.0);
        assert_eq!(a, b);
        // The triangles either side of the edge tilt differently.
        let cell = |p: &[f32; 16]| Cell {
            nw: p[5],
            ne: p[6],
            sw: p[9],
            se: p[10],
        };
        assert_ne!(
            cell(&west).normal(1.0, 0.3, 1.0, 1.0),
            cell(&east).normal(0.0, 0.3, 1.0, 1.0)
        );
        // At a post, the central difference of the quadratic is exact:
        // at post (5, 4), dz/dx = 5 and z falls northwards by 2r = 8 per row.
        let at_post = smooth_normal(&east, 0.0, 1.0, 1.0, 1.0);
        assert_eq!(at_post, [-5.0, 8.0, 1.0]);
    }

    #[test]
    fn missing_posts_take_one_sided_differences_or_none() {
        let z = |c: i32, _r: i32| (2 * c) as f32;
        let mut posts = window(z, 0, 0);
        // West of the DEM: the west column is outside.
        for row in 0..4 {
            posts[row * 4] = f32::NAN;
        }
        assert_eq!(smooth_normal(&posts, 0.0, 0.0, 1.0, 1.0), [-2.0, -0.0, 1.0]);
        let lonely = {
            let mut p = [f32::NAN; 16];
            p[9] = 7.0;
            p
        };
        assert_eq!(
            smooth_normal(&lonely, 0.0, 0.0, 1.0, 1.0),
            [-0.0, -0.0, 1.0]
        );
        assert_eq!(
            smooth_normal(&[f32::NAN; 16], 0.5, 0.5, 1.0, 1.0),
            [0.0, 0.0, 1.0]
        );
    }
}
