//! The DEM as the horizon algorithms see it: posts in metres, nodata, and
//! the earth's curvature.

/// Mean earth radius, metres (the sphere of the curvature correction).
pub const EARTH_RADIUS: f64 = 6_371_000.0;

/// Standard refraction coefficient for visible light near the ground
/// (Gauss's 0.13; surveyors use 0.13-0.14).
pub const DEFAULT_REFRACTION: f64 = 0.13;

/// `c` in the curvature drop `c * d^2`: `(1 - k) / (2 R)` for refraction
/// coefficient `k`.
pub fn curvature_coefficient(refraction: f64) -> f64 {
    (1.0 - refraction) / (2.0 * EARTH_RADIUS)
}

/// A row-major grid of posts; row 0 is the north edge, column 0 the west.
/// Post `(col, row)` stands at `col * dx` metres east and `row * dy` metres
/// south of post `(0, 0)`. It may hold only a window of rows of the DEM
/// (out-of-core sweeps): `z` is rows `row0..` of a `width x height` grid.
#[derive(Debug, Clone, Copy)]
pub struct Terrain<'a> {
    /// Heights in metres, NaN for nodata, from row `row0` on.
    pub z: &'a [f32],
    pub width: usize,
    /// Rows of the whole DEM.
    pub height: usize,
    pub row0: usize,
    pub dx: f64,
    pub dy: f64,
    /// `c` of the curvature drop `c * d^2` over horizontal distance `d`
    /// (0: a flat earth). See [`curvature_coefficient`].
    pub curvature: f64,
}

impl<'a> Terrain<'a> {
    pub fn new(z: &'a [f32], width: usize, height: usize, dx: f64, dy: f64) -> Self {
        assert_eq!(z.len(), width * height, "{width} x {height} posts");
        Self::window(z, (width, height), 0, (dx, dy))
    }

    /// Rows `row0..row0 + z.len() / width` of a `width x height` DEM.
    pub fn window(
        z: &'a [f32],
        (width, height): (usize, usize),
        row0: usize,
        (dx, dy): (f64, f64),
    ) -> Self {
        assert!(z.len() % width == 0 && row0 + z.len() / width <= height);
        assert!(dx > 0.0 && dy > 0.0, "post spacing {dx} x {dy}");
        Self {
            z,
            width,
            height,
            row0,
            dx,
            dy,
            curvature: 0.0,
        }
    }

    pub fn with_curvature(self, curvature: f64) -> Self {
        Self { curvature, ..self }
    }

    /// Height of post `(col, row)`, NaN for nodata.
    #[inline]
    pub fn at(&self, col: usize, row: usize) -> f32 {
        self.z[(row - self.row0) * self.width + col]
    }

    pub fn contains(&self, col: i64, row: i64) -> bool {
        col >= 0 && row >= 0 && (col as usize) < self.width && (row as usize) < self.height
    }

    /// Whether cell `(c, r)` (between posts `(c, r)` and `(c + 1, r + 1)`)
    /// has a surface: inside the grid and no nodata corner.
    pub fn cell_exists(&self, c: i64, r: i64) -> bool {
        self.contains(c, r)
            && self.contains(c + 1, r + 1)
            && [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .all(|&(i, j)| !self.at((c + i) as usize, (r + j) as usize).is_nan())
    }

    pub fn has_nodata(&self) -> bool {
        self.z.iter().any(|v| v.is_nan())
    }

    /// Metres east and north of post `(col, row)` from post `(0, 0)`.
    pub fn east_north(&self, col: f64, row: f64) -> (f64, f64) {
        (col * self.dx, -row * self.dy)
    }

    /// The surface normal at a post (unit, upward), from central
    /// differences (one-sided at edges and beside nodata); `None` for nodata.
    pub fn normal(&self, col: usize, row: usize) -> Option<[f64; 3]> {
        let z0 = f64::from(self.at(col, row));
        if z0.is_nan() {
            return None;
        }
        let sample = |c: Option<usize>, r: Option<usize>| {
            let (c, r) = (c?, r?);
            (c < self.width && r < self.height)
                .then(|| f64::from(self.at(c, r)))
                .filter(|z| !z.is_nan())
        };
        // Derivative along one axis from whichever neighbours exist.
        let slope = |lo: Option<f64>, hi: Option<f64>, step: f64| match (lo, hi) {
            (Some(a), Some(b)) => (b - a) / (2.0 * step),
            (Some(a), None) => (z0 - a) / step,
            (None, Some(b)) => (b - z0) / step,
            (None, None) => 0.0,
        };
        let dz_east = slope(
            sample(col.checked_sub(1), Some(row)),
            sample(Some(col + 1), Some(row)),
            self.dx,
        );
        // Rows grow southwards: north is row - 1.
        let dz_north = slope(
            sample(Some(col), Some(row + 1)),
            sample(Some(col), row.checked_sub(1)),
            self.dy,
        );
        let n = [-dz_east, -dz_north, 1.0];
        let len = (n[0] * n[0] + n[1] * n[1] + 1.0).sqrt();
        Some(n.map(|v| v / len))
    }
}

/// Unit vector (east, north) of a compass azimuth in degrees.
pub fn compass(azimuth_deg: f64) -> (f64, f64) {
    let (s, c) = azimuth_deg.to_radians().sin_cos();
    (s, c)
}
