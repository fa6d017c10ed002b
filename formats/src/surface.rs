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
