//! The shared terrain kernel: the DEM as the algorithms see it
//! ([`Terrain`]: posts in metres, nodata, the earth's curvature, and the
//! `atan` every horizon angle goes through), a whole DEM held in memory
//! ([`held`]), what a horizon search keeps of its steepest point
//! ([`steepest`]), geodesy ([`geo`]), tile rows ([`tiling`]), the sun
//! ([`sun`]) and the seeded random stream of every sample ([`random`]).

pub mod geo;
pub mod held;
pub mod random;
pub mod steepest;
pub mod sun;
pub mod tiling;

/// Mean earth radius, metres (the sphere of the curvature correction).
pub const EARTH_RADIUS: f64 = 6_371_000.0;

/// Standard refraction coefficient for visible light near the ground
/// (Gauss's 0.13; surveyors use 0.13-0.14).
pub const DEFAULT_REFRACTION: f64 = 0.13;

/// Posts of `spacing` metres within `metres` along one axis: the `k` with
/// `k * spacing <= metres`. The one rounding rule of every reach, halo and
/// window a distance limit sets (each adds its own margin, named where it
/// is added).
pub(crate) fn posts_within(metres: f64, spacing: f64) -> usize {
    (metres.max(0.0) / spacing).floor() as usize
}

/// `c` in the curvature drop `c * d^2`: `(1 - k) / (2 R)` for refraction
/// coefficient `k`.
pub fn curvature_coefficient(refraction: f64) -> f64 {
    (1.0 - refraction) / (2.0 * EARTH_RADIUS)
}

/// Refuses a refraction coefficient that is not a finite number (a NaN
/// made every horizon -90 and every post seen): what each stage's check
/// and the Python functions ask before anything bends a sight line.
pub(crate) fn check_refraction(refraction: f64) -> anyhow::Result<()> {
    anyhow::ensure!(
        refraction.is_finite(),
        "refraction = {refraction} (--refraction {refraction}): give a finite coefficient (0.13 is the usual, 0 none)"
    );
    Ok(())
}

/// The east-west post spacing row by row, relative to [`Terrain::dx`].
///
/// On a geographic (latitude/longitude) grid a column step is a fixed
/// fraction of a degree of longitude, whose length shrinks with the cosine
/// of latitude: 1.8 % from edge to edge of a one-degree tile at 45 N. The
/// horizon methods place post `(col, row)` at `((col - c) * dx(row), -row *
/// dy)` metres, `c` the centre column (the sinusoidal projection about the
/// DEM's central meridian, exact along every row and along the central
/// meridian), and measure a line's steps with the spacing at each step's
/// middle. Uniform (every scale 1) on projected and local grids.
#[derive(Debug, Clone, Copy, Default)]
pub struct RowScale<'a> {
    /// Entry `2 r` is row `r`, entry `2 r + 1` midway between rows `r` and
    /// `r + 1`; empty: 1 everywhere.
    half_rows: &'a [f64],
}

impl<'a> RowScale<'a> {
    /// Scales at every half row of an `h`-row DEM: `2 h - 1` entries.
    pub fn new(half_rows: &'a [f64]) -> Self {
        Self { half_rows }
    }

    pub(crate) fn is_uniform(&self) -> bool {
        self.half_rows.is_empty()
    }

    /// The scales of rows `rows` alone (a crop of the DEM).
    pub fn crop(&self, rows: std::ops::Range<usize>) -> Self {
        if self.is_uniform() || rows.is_empty() {
            return *self;
        }
        Self::new(&self.half_rows[2 * rows.start..2 * rows.end - 1])
    }

    /// The largest scale of any half row (1 when uniform).
    pub fn max(&self) -> f64 {
        match self.half_rows {
            [] => 1.0,
            rows => rows.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        }
    }

    /// The scale at half row `half` (row `half / 2`), clamped to the DEM's
    /// rows (a line's first step may reach past the edge).
    #[inline]
    pub(crate) fn at_half(&self, half: i64) -> f64 {
        match self.half_rows.len() {
            0 => 1.0,
            n => self.half_rows[half.clamp(0, n as i64 - 1) as usize],
        }
    }
}

/// A row-major grid of posts; row 0 is the north edge, column 0 the west.
/// Post `(col, row)` stands `row * dy` metres south of row 0 and
/// `(col - c) * dx * scale(row)` metres east of the centre column `c`
/// ([`RowScale`]).
/// It may hold only a window of rows of the DEM (out-of-core sweeps): `z` is
/// rows `row0..` of a `width x height` grid.
#[derive(Debug, Clone, Copy)]
pub struct Terrain<'a> {
    /// Heights in metres, NaN for nodata, from row `row0` on.
    pub z: &'a [f32],
    pub width: usize,
    /// Rows of the whole DEM.
    pub height: usize,
    pub row0: usize,
    /// Metres between columns (on the centre row of a geographic grid).
    pub dx: f64,
    pub dy: f64,
    /// East-west spacing per row relative to `dx` (geographic grids).
    pub row_scale: RowScale<'a>,
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
        assert!(z.len().is_multiple_of(width) && row0 + z.len() / width <= height);
        assert!(dx > 0.0 && dy > 0.0, "post spacing {dx} x {dy}");
        Self {
            z,
            width,
            height,
            row0,
            dx,
            dy,
            row_scale: RowScale::default(),
            curvature: 0.0,
        }
    }

    pub fn with_row_scale(self, row_scale: RowScale<'a>) -> Self {
        let n = row_scale.half_rows.len();
        assert!(n == 0 || n == 2 * self.height - 1, "{n} half rows");
        Self { row_scale, ..self }
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
    pub(crate) fn cell_exists(&self, c: i64, r: i64) -> bool {
        self.contains(c, r)
            && self.contains(c + 1, r + 1)
            && [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .all(|&(i, j)| !self.at((c + i) as usize, (r + j) as usize).is_nan())
    }

    /// Whether post `(col, row)` lies on the surface: a corner of a cell
    /// with a surface (its own height is then not nodata). A line that only
    /// grazes such a corner between two holes still meets the terrain there.
    pub(crate) fn post_on_surface(&self, col: i64, row: i64) -> bool {
        [(-1, -1), (0, -1), (-1, 0), (0, 0)]
            .iter()
            .any(|&(c, r)| self.cell_exists(col + c, row + r))
    }

    pub fn has_nodata(&self) -> bool {
        self.z.iter().any(|v| v.is_nan())
    }

    /// The column that key positions measure east from (an integer, so
    /// that uniform grids keep integer keys).
    pub(crate) fn centre_column(&self) -> f64 {
        (self.width / 2) as f64
    }

    /// Horizontal metres between two posts at key positions `p` and `q`
    /// ([`Self::key_position`]).
    pub(crate) fn key_distance(&self, p: (f64, f64), q: (f64, f64)) -> f64 {
        // Not `hypot`: its care for overflow (which key offsets of a DEM
        // cannot reach) cost a third of a bounded sector scan.
        let (de, dn) = (q.0 - p.0, q.1 - p.1);
        (de * de + dn * dn).sqrt() * self.dx
    }

    /// Metres between columns on row `row`.
    pub fn dx_at(&self, row: usize) -> f64 {
        self.dx * self.row_scale.at_half(2 * row as i64)
    }

    /// Where post `(col, row)` stands, in units of `dx`: east of the centre
    /// column and north of row 0. On a uniform grid both are integers times
    /// exact factors (east exactly `col - c`), so that posts on a grid
    /// diagonal tie exactly.
    pub(crate) fn key_position(&self, col: usize, row: usize) -> (f64, f64) {
        let east = (col as f64 - self.centre_column()) * self.row_scale.at_half(2 * row as i64);
        (east, -(row as f64) * (self.dy / self.dx))
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
            self.dx_at(row),
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

/// The angle (degrees, 0..=180) between two compass azimuths.
pub(crate) fn angle_between(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d)
}

/// Unit vector (east, north) of a compass azimuth in degrees.
pub fn compass(azimuth_deg: f64) -> (f64, f64) {
    let (s, c) = azimuth_deg.to_radians().sin_cos();
    (s, c)
}

/// The highest post of each square block of `size` cells (a power of
/// two) of a whole terrain: one level of a max pyramid, as the
/// hierarchical tracers use (Paglieroni and Petersen, sec. 3), for walks
/// that step over the blocks a line passes too high (a viewshed's sight
/// line) or too low (a horizon's record) to meet. A block's posts are
/// those on its edges (a cell's surface lies within its four posts) and
/// `halo` posts around them, for a walk that may put a point a rounding's
/// width into the wrong block.
/// NEG_INFINITY for a block without heights.
#[derive(Debug, Clone)]
pub struct MaxBlocks {
    /// `log2` of the cells a side.
    shift: u32,
    /// Blocks across and down.
    cols: usize,
    rows: usize,
    /// Row-major.
    max: Vec<f64>,
}

impl MaxBlocks {
    pub fn of(t: &Terrain, size: usize, halo: usize) -> Self {
        use rayon::prelude::*;
        assert!(size.is_power_of_two(), "blocks of {size} cells");
        assert!(
            t.row0 == 0 && t.z.len() == t.width * t.height,
            "a whole terrain"
        );
        let (w, h) = (t.width, t.height);
        let cells = |n: usize| n.saturating_sub(1).max(1);
        let (cols, rows) = (cells(w).div_ceil(size), cells(h).div_ceil(size));
        // Block `k`'s posts along one axis of `n`.
        let span = |k: usize, n: usize| {
            (k * size).saturating_sub(halo)..((k + 1) * size + halo + 1).min(n)
        };
        let max = (0..cols * rows)
            .into_par_iter()
            .map(|i| {
                let (cs, rs) = (span(i % cols, w), span(i / cols, h));
                rs.flat_map(|r| t.z[r * w..][cs.clone()].iter())
                    .filter(|z| !z.is_nan())
                    .fold(f64::NEG_INFINITY, |m, &z| m.max(f64::from(z)))
            })
            .collect();
        Self {
            shift: size.trailing_zeros(),
            cols,
            rows,
            max,
        }
    }

    /// Cells a side of a block.
    pub fn size(&self) -> usize {
        1 << self.shift
    }

    /// The block of the point `(col, row)` (post units; outside the grid,
    /// the nearest block).
    #[inline]
    pub fn block(&self, col: f64, row: f64) -> (usize, usize) {
        // `as` floors a non-negative number and takes a negative one to 0.
        let at = |p: f64, n: usize| ((p as usize) >> self.shift).min(n - 1);
        (at(col, self.cols), at(row, self.rows))
    }

    /// The highest post of block `(bc, br)`.
    #[inline]
    pub fn max(&self, (bc, br): (usize, usize)) -> f64 {
        self.max[br * self.cols + bc]
    }

    /// The memory the blocks hold, bytes.
    pub fn bytes(&self) -> usize {
        8 * self.max.len()
    }
}

/// `atan(x)` in radians: Cephes' double-precision `atan` (Moshier), its
/// reduction to `|x| <= 0.66` and rational approximation, within a few
/// units in the last place of libm's, with its three ranges as selects
/// instead of branches (the sky stage's loop vectorises).
#[inline(always)]
pub fn atan(x: f64) -> f64 {
    const P: [f64; 5] = [
        -8.750_608_600_031_904e-1,
        -1.615_753_718_733_365e1,
        -7.500_855_792_314_705e1,
        -1.228_866_684_490_136_2e2,
        -6.485_021_904_942_025e1,
    ];
    const Q: [f64; 5] = [
        2.485_846_490_142_306_3e1,
        1.650_270_098_316_988_6e2,
        4.328_810_604_912_902_5e2,
        4.853_903_996_359_137e2,
        1.945_506_571_482_614e2,
    ];
    const TAN_3PI_8: f64 = 2.414_213_562_373_095;
    const MORE_BITS: f64 = 6.123_233_995_736_766e-17;
    let a = x.abs();
    let (far, mid) = (a > TAN_3PI_8, a > 0.66);
    // One division for the three ranges (`a / 1` is `a`): a division is
    // the dearest vector operation here.
    let (num, den) = if far {
        (-1.0, a)
    } else if mid {
        (a - 1.0, a + 1.0)
    } else {
        (a, 1.0)
    };
    let r = num / den;
    let (base, more) = if far {
        (std::f64::consts::FRAC_PI_2, MORE_BITS)
    } else if mid {
        (std::f64::consts::FRAC_PI_4, 0.5 * MORE_BITS)
    } else {
        (0.0, 0.0)
    };
    let z = r * r;
    let p = (((P[0] * z + P[1]) * z + P[2]) * z + P[3]) * z + P[4];
    let q = ((((z + Q[0]) * z + Q[1]) * z + Q[2]) * z + Q[3]) * z + Q[4];
    (base + (r * (z * p / q) + r + more)).copysign(x)
}
