//! Exact ray tracing of a baked height field.
//!
//! Every method returns the same first hit on the surface model of
//! [`crate::surface`] (two triangles per cell); a method only changes the
//! speed. They share one cell test ([`crate::surface::intersect_cell`]) and
//! one notion of which cells a ray touches ([`GridRay::square`]), so they
//! agree with the brute force bit for bit on every cell they test.
//!
//! - [`Method::Incremental`]: cell by cell along the ray's ground track
//!   (Amanatides-Woo DDA, corners and grid-line rays included, see `walk`);
//!   no cell skipped. Paglieroni and Petersen's "incremental" baseline.
//! - [`Method::Runs`]: Henning and Stephenson's run-based traversal: the
//!   track is cut into runs of cells that share a row (or column, for steep
//!   tracks); each run costs one computation, and a whole run is skipped with
//!   one test of the ray's lowest point against the run's tallest post.
//!   Run ends follow the paper's intercept recurrence (eq. 6-7), kept in
//!   integers so that it cannot drift (see `runs`).
//! - [`Method::Hierarchical`]: descends the max pyramid (layers
//!   `pyramid_max@L`), stepping over nodes the ray passes above (Paglieroni
//!   and Petersen sec. 1.2), the walk at each level as exact as the
//!   incremental one.
//! - [`Method::Parametric`]: Paglieroni and Petersen's parametric tracer
//!   (sec. 2.3-2.4) over the cone planes (`crate::cones`): cell by cell like
//!   the incremental walk, but from every cell whose cone the ray is in, a
//!   leap to where the ray leaves that cone (eq. 11-13); a ray that never
//!   leaves it (the upward early exit) ends there. Departures: the leap
//!   starts where the ray leaves the cell (the cone covers the whole closed
//!   cell, so the step is never shorter than the paper's) and the walk
//!   resumes at the landing point with every touched cell's whole interval,
//!   so the hit is the brute force's to the last bit; the paper's jump start
//!   is simply the next cell of the walk.
//! - [`Method::BruteForce`]: the reference for tests: every cell the ground
//!   track touches is intersected (candidates: per row of cells, the columns
//!   the track spans there, widened by one), in no particular order, and the
//!   smallest `t` wins. No traversal logic, no skipping.
//!
//! **Coordinates.** Rays are given in local metres: `x` east and `y` north
//! from the DEM's south-west post (post `(0, H - 1)`), `z` in the heights'
//! metres. Internally a ray becomes a [`GridRay`] in posts (`u` = column,
//! `v` = row, southwards); `t` is the same in both.

mod runs;
mod walk;

use std::ops::ControlFlow;

use crate::cones::{ConePlanes, CONE_SLOPE};
use crate::error::{Error, Result};
use crate::reader::{Asset, Layer, TileCursor};
use crate::surface::{intersect_cell, Cell, GridRay};

use runs::Runs;
pub(crate) use walk::{walk, walk_from, Bounds};

pub use crate::layers::{PYRAMID_MAX, PYRAMID_MIN};

/// A ray in local metres (see the module docs): `origin + t * dir` for
/// `t` in `[t_min, t_max]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: [f64; 3],
    pub dir: [f64; 3],
    pub t_min: f64,
    pub t_max: f64,
}

/// The first point where a ray meets the terrain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f64,
    /// The cell `(column, row)` hit; cell `(c, r)` lies between posts `c..=c+1`, `r..=r+1`.
    pub cell: (u32, u32),
    /// Local metres.
    pub point: [f64; 3],
    /// Unit upward normal of the triangle hit.
    pub normal: [f32; 3],
}

/// What a trace cost.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Cells whose surface was tested against the ray.
    pub cells: u64,
    /// Traversal steps: cells visited (incremental), runs (runs), nodes of
    /// any level visited (hierarchical).
    pub steps: u64,
    /// Pyramid nodes descended into (hierarchical).
    pub nodes_pushed: u64,
    /// Leaps through empty cones (parametric): each restarts the cell walk
    /// where the leap lands.
    pub leaps: u64,
}

impl std::ops::AddAssign for Counters {
    fn add_assign(&mut self, o: Self) {
        self.cells += o.cells;
        self.steps += o.steps;
        self.nodes_pushed += o.nodes_pushed;
        self.leaps += o.leaps;
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Method {
    Incremental,
    Runs,
    Hierarchical,
    Parametric,
    BruteForce,
}

impl Method {
    pub const ALL: [Method; 5] = [
        Method::Incremental,
        Method::Runs,
        Method::Hierarchical,
        Method::Parametric,
        Method::BruteForce,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Method::Incremental => "incremental",
            Method::Runs => "runs",
            Method::Hierarchical => "hierarchical",
            Method::Parametric => "parametric",
            Method::BruteForce => "brute-force",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                format!("unknown method {s:?} (incremental, runs, hierarchical, parametric, brute-force)")
            })
    }
}

/// `ray` (local metres) in grid space for a DEM `rows` posts tall with posts
/// `dx x dy` metres apart: u east in cells from the west edge, v south in
/// rows from the north edge, z in metres; the same `t`. Shaders take their
/// rays in this frame (terrabake-gpu).
pub fn grid_ray(ray: &Ray, (dx, dy): (f64, f64), rows: u32) -> GridRay {
    let top = f64::from(rows - 1);
    GridRay {
        origin: [ray.origin[0] / dx, top - ray.origin[1] / dy, ray.origin[2]],
        dir: [ray.dir[0] / dx, -ray.dir[1] / dy, ray.dir[2]],
    }
}

/// A tracer over an opened asset. Cheap to create; `Sync`, so one tracer
/// serves every render thread.
pub struct Tracer<'a, D> {
    /// The asset's directory, for errors.
    asset: &'a std::path::Path,
    height: &'a Layer<D>,
    /// Max pyramid, level 0 (cells) upwards: the stored levels, then
    /// levels built in memory from the stored top up to a single node.
    pyramid: Vec<Level<'a, D>>,
    /// The cone planes, when the asset has them.
    cones: Option<ConePlanes<'a, D>>,
    /// Posts per side and cells per side.
    posts: (u32, u32),
    cells: (u32, u32),
    dx: f64,
    dy: f64,
}

impl<D> std::fmt::Debug for Tracer<'_, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tracer")
            .field("posts", &self.posts)
            .field("levels", &self.pyramid.len())
            .finish()
    }
}

/// The posts of the cells a trace visits, through a [`TileCursor`]:
/// consecutive cells of a trace mostly share a tile.
struct Posts<'a, D> {
    cursor: TileCursor<'a, D, f32>,
}

impl<'a, D: AsRef<[u8]>> Posts<'a, D> {
    fn new(layer: &'a Layer<D>) -> Self {
        Self {
            cursor: layer.cursor(0),
        }
    }

    /// The corners of cell `(c, r)`.
    fn cell(&mut self, c: u32, r: u32) -> Result<Cell> {
        let ts = self.cursor.tile_size();
        if (c & (ts - 1)) + 1 < ts && (r & (ts - 1)) + 1 < ts {
            let (tile, i) = self.cursor.tile_of(c, r)?;
            let t = ts as usize;
            return Ok(Cell {
                nw: tile[i],
                ne: tile[i + 1],
                sw: tile[i + t],
                se: tile[i + t + 1],
            });
        }
        let mut get = |x, y| self.cursor.get(x, y);
        Ok(Cell {
            nw: get(c, r)?,
            ne: get(c + 1, r)?,
            sw: get(c, r + 1)?,
            se: get(c + 1, r + 1)?,
        })
    }
}

/// The max pyramid above a `width x height` grid (row-major `base`): each
/// level the max of 2 x 2 blocks of the one below (a last odd row or column
/// alone), up to a single node; `(width, height, values)` per level, the
/// base not included.
pub fn max_levels(width: usize, height: usize, base: &[f32]) -> Vec<(usize, usize, Vec<f32>)> {
    let mut levels: Vec<(usize, usize, Vec<f32>)> = Vec::new();
    let (mut w, mut h) = (width, height);
    while w > 1 || h > 1 {
        let below = levels.last().map_or(base, |l| &l.2);
        let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
        let mut up = vec![f32::NEG_INFINITY; nw * nh];
        for y in 0..h {
            for x in 0..w {
                let i = (y / 2) * nw + x / 2;
                up[i] = up[i].max(below[y * w + x]);
            }
        }
        levels.push((nw, nh, up));
        (w, h) = (nw, nh);
    }
    levels
}

/// One level of the max pyramid.
enum Level<'a, D> {
    Stored(&'a Layer<D>),
    Memory {
        width: u32,
        height: u32,
        max: Vec<f32>,
    },
}

impl<D: AsRef<[u8]>> Level<'_, D> {
    fn width(&self) -> u32 {
        match self {
            Level::Stored(l) => l.width(),
            Level::Memory { width, .. } => *width,
        }
    }
    fn height(&self) -> u32 {
        match self {
            Level::Stored(l) => l.height(),
            Level::Memory { height, .. } => *height,
        }
    }
    #[inline]
    fn max(&self, a: u32, b: u32) -> Result<f32> {
        match self {
            Level::Stored(l) => l.get::<f32>(0, a, b),
            Level::Memory { width, max, .. } => Ok(max[(b * width + a) as usize]),
        }
    }
}

/// The best hit so far: smallest `t`; on equal `t`, the first found.
#[derive(Default)]
struct Best {
    hit: Option<(f64, u32, u32)>,
}

impl Best {
    #[inline]
    fn t(&self) -> f64 {
        self.hit.map_or(f64::INFINITY, |h| h.0)
    }
    #[inline]
    fn offer(&mut self, t: f64, c: u32, r: u32) {
        if t < self.t() {
            self.hit = Some((t, c, r));
        }
    }
}

/// The state of one trace: the ray in grid space and its clipped range,
/// the tile cursor, the best hit so far, the counters, and the first error
/// (which ends the trace).
struct Trace<'a, D> {
    g: GridRay,
    ta: f64,
    tb: f64,
    posts: Posts<'a, D>,
    best: Best,
    counters: Counters,
    err: Option<Error>,
}

impl<D> Trace<'_, D> {
    /// Continue, unless an error ended the trace.
    #[inline]
    fn stop_on_error(&self) -> ControlFlow<()> {
        if self.err.is_some() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    }

    /// The value, or: record the error and stop the walk.
    #[inline]
    fn ok<T>(&mut self, r: Result<T>) -> ControlFlow<(), T> {
        match r {
            Ok(v) => ControlFlow::Continue(v),
            Err(e) => {
                self.err = Some(e);
                ControlFlow::Break(())
            }
        }
    }
}

impl<'a, D: AsRef<[u8]>> Tracer<'a, D> {
    /// A tracer over `asset`'s height layer, and its max pyramid and cone
    /// planes when the asset has them (needed by [`Method::Hierarchical`]
    /// and [`Method::Parametric`]).
    pub fn new(asset: &'a Asset<D>) -> Result<Self> {
        let height = asset.height()?;
        let m = asset.manifest();
        let (w, h) = (height.width(), height.height());
        if w < 2 || h < 2 {
            return Err(Error::Spec(format!(
                "a {w} x {h} DEM has no cells to trace"
            )));
        }
        let mut pyramid = Vec::new();
        // The walk steps by 2^level and indexes children at 2a, 2a + 1: the
        // levels must halve from the cells up, and the stored ones stop at
        // one tile (larger tops would be built in memory). Checked here, so
        // that no asset, however crafted, makes a walk overflow or allocate.
        let mut expect = (w - 1, h - 1);
        while let Ok(level) = asset.layer(PYRAMID_MAX, pyramid.len() as u32) {
            let got = (level.width(), level.height());
            let ts = level.tile_size();
            if got != expect || level.entry().elem != crate::ElemType::F32 {
                return Err(Error::Spec(format!(
                    "{PYRAMID_MAX}@{} is {} x {}, expected {} x {} f32: not the pyramid of this DEM",
                    pyramid.len(),
                    got.0,
                    got.1,
                    expect.0,
                    expect.1
                )));
            }
            pyramid.push(Level::Stored(level));
            if expect.0 <= ts && expect.1 <= ts {
                break;
            }
            expect = (expect.0.div_ceil(2), expect.1.div_ceil(2));
        }
        // The stage stores levels up to one tile; the few above it (down to
        // one node) are small, so they are built here, in memory.
        if let Some(Level::Stored(top)) = pyramid.last() {
            let (w, h) = (top.width(), top.height());
            let mut max = vec![0f32; w as usize * h as usize];
            top.read_window(0, 0, 0, w, h, &mut max)?;
            for (width, height, max) in max_levels(w as usize, h as usize, &max) {
                pyramid.push(Level::Memory {
                    width: width as u32,
                    height: height as u32,
                    max,
                });
            }
        }
        Ok(Self {
            asset: asset.dir(),
            height,
            pyramid,
            cones: ConePlanes::open(asset)?,
            posts: (w, h),
            cells: (w - 1, h - 1),
            dx: m.cell_size.dx,
            dy: m.cell_size.dy,
        })
    }

    /// Whether [`Method::Hierarchical`] can run (the asset has a pyramid).
    pub fn has_pyramid(&self) -> bool {
        !self.pyramid.is_empty()
    }

    /// Whether [`Method::Parametric`] can run (the asset has cone planes).
    pub fn has_cones(&self) -> bool {
        self.cones.is_some()
    }

    /// The DEM's extent in local metres: `(x_max, y_max)`; the DEM covers
    /// `[0, x_max] x [0, y_max]`.
    pub fn extent(&self) -> (f64, f64) {
        (
            f64::from(self.cells.0) * self.dx,
            f64::from(self.cells.1) * self.dy,
        )
    }

    /// The ray in grid space ([`grid_ray`]).
    pub fn grid_ray(&self, ray: &Ray) -> GridRay {
        grid_ray(ray, (self.dx, self.dy), self.posts.1)
    }

    /// The parameter range in which the ray is over the DEM, or `None`.
    fn clip(&self, ray: &Ray, g: &GridRay) -> Option<(f64, f64)> {
        if ray.dir.iter().any(|d| !d.is_finite())
            || ray.origin.iter().any(|o| !o.is_finite())
            || ray.dir == [0.0; 3]
        {
            return None;
        }
        let (cw, ch) = (f64::from(self.cells.0), f64::from(self.cells.1));
        let (a0, a1) = g.slab(0, 0.0, cw);
        let (b0, b1) = g.slab(1, 0.0, ch);
        let (t0, t1) = (a0.max(b0).max(ray.t_min), a1.min(b1).min(ray.t_max));
        (t0 <= t1).then_some((t0, t1))
    }

    fn cell_bounds(&self) -> Bounds {
        Bounds {
            u: (0, i64::from(self.cells.0) - 1),
            v: (0, i64::from(self.cells.1) - 1),
        }
    }

    /// Traces `ray` with `method`: the first hit, or `None`, and the cost.
    pub fn trace(&self, ray: &Ray, method: Method) -> Result<(Option<Hit>, Counters)> {
        let g = self.grid_ray(ray);
        let Some((ta, tb)) = self.clip(ray, &g) else {
            return Ok((None, Counters::default()));
        };
        let mut st = Trace {
            g,
            ta,
            tb,
            posts: Posts::new(self.height),
            best: Best::default(),
            counters: Counters::default(),
            err: None,
        };
        match method {
            Method::Incremental => self.incremental(&mut st),
            Method::Runs => self.runs(&mut st),
            Method::Hierarchical => self.hierarchical(&mut st),
            Method::Parametric => self.parametric(&mut st),
            Method::BruteForce => self.brute_force(&mut st),
        }
        if let Some(e) = st.err.take() {
            return Err(e);
        }
        let hit = match st.best.hit {
            None => None,
            Some((t, c, r)) => Some(self.hit(ray, &st.g, t, c, r, &mut st.posts)?),
        };
        Ok((hit, st.counters))
    }

    fn hit(
        &self,
        ray: &Ray,
        g: &GridRay,
        t: f64,
        c: u32,
        r: u32,
        posts: &mut Posts<'a, D>,
    ) -> Result<Hit> {
        let cell = posts.cell(c, r)?;
        let p = g.at(t);
        let (east, north) = (p[0] - f64::from(c), f64::from(r) + 1.0 - p[1]);
        let n = cell.normal(east, north, self.dx, self.dy);
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        Ok(Hit {
            t,
            cell: (c, r),
            point: [
                ray.origin[0] + t * ray.dir[0],
                ray.origin[1] + t * ray.dir[1],
                ray.origin[2] + t * ray.dir[2],
            ],
            normal: [
                (n[0] / len) as f32,
                (n[1] / len) as f32,
                (n[2] / len) as f32,
            ],
        })
    }

    /// Tests cell `(c, r)` over its interval `[t0, t1]`; breaks once cells
    /// start after the best hit (they are visited in order of `t0`).
    #[inline]
    fn test_cell(
        &self,
        st: &mut Trace<'a, D>,
        c: u32,
        r: u32,
        (t0, t1): (f64, f64),
    ) -> ControlFlow<()> {
        if t0 > st.best.t() {
            return ControlFlow::Break(());
        }
        st.counters.cells += 1;
        let cell = st.posts.cell(c, r);
        let cell = st.ok(cell)?;
        // The ray is above this cell's tallest corner on all of [t0, t1].
        if st.g.z(t0).min(st.g.z(t1)) > f64::from(cell.max()) {
            return ControlFlow::Continue(());
        }
        if let Some(t) = intersect_cell(&cell, c, r, &st.g, t0, t1) {
            st.best.offer(t, c, r);
        }
        ControlFlow::Continue(())
    }

    fn incremental(&self, st: &mut Trace<'a, D>) {
        let (g, ta, tb) = (st.g, st.ta, st.tb);
        let _ = walk(&g, 1.0, self.cell_bounds(), ta, tb, |c, r, t0, t1| {
            st.counters.steps += 1;
            self.test_cell(st, c as u32, r as u32, (t0, t1))
        });
    }

    fn parametric(&self, st: &mut Trace<'a, D>) {
        let Some(cones) = &self.cones else {
            st.err = Some(Error::NoLayer {
                asset: self.asset.to_path_buf(),
                name: CONE_SLOPE.into(),
                level: 0,
                available: Vec::new(),
            });
            return;
        };
        let (g, ta, tb) = (st.g, st.ta, st.tb);
        // Horizontal metres per unit of t, and metres of rise per unit of t.
        let run = (g.dir[0] * self.dx).hypot(g.dir[1] * self.dy);
        let rise = g.dir[2];
        // A walk visits at most about cells.0 + cells.1 cells; leaps only
        // ever save steps. Past this budget (absurd planes: slopes of 1e-30
        // leap a hair at a time) the rest of the ray is walked cell by cell
        // without leaps, which is exact and bounded.
        let budget = 4 * (u64::from(self.cells.0) + u64::from(self.cells.1)) + 64;
        let mut leaping = true;
        let mut t_start = ta;
        let mut planes = cones.cursor();
        loop {
            // A stretch `[from, to)` of the ray known to be above the
            // terrain: the union of the cones the ray has been in. The walk
            // leaps once it reaches a cell entered at or after `from`: every
            // cell entered before (a neighbour along a grid line, a corner
            // grazed) has been tested by then.
            let mut empty: Option<(f64, f64)> = None;
            let mut leap = None;
            let _ = walk_from(
                &g,
                1.0,
                self.cell_bounds(),
                t_start,
                (ta, tb),
                |c, r, t0, t1| {
                    if let Some((from, to)) = empty {
                        // Only a leap forward: a stretch that ends before
                        // where this walk began would start it over again.
                        if leaping && t0 >= from && to > t_start {
                            leap = Some(to);
                            return ControlFlow::Break(());
                        }
                    }
                    st.counters.steps += 1;
                    if t0 > st.best.t() {
                        return ControlFlow::Break(());
                    }
                    let cone = st.ok(planes.cone(c as u32, r as u32))?;
                    // A cone of positive slope holds no surface above its
                    // apex over its own cell (the guarantee at distance 0):
                    // a ray above the apex all across the cell cannot hit
                    // it, and the cell's posts, a cache miss of their own
                    // on a large DEM, are not read. Most steps of a walk
                    // are such cells.
                    let (z0, z1) = (g.z(t0), g.z(t1));
                    let margin =
                        (g.origin[2].abs() + z0.abs() + z1.abs() + cone.apex.abs()) * 1e-12;
                    if !(cone.slope > 0.0 && z0.min(z1) - margin > cone.apex) {
                        self.test_cell(st, c as u32, r as u32, (t0, t1))?;
                    }
                    // After a hit only the cells entered before it remain.
                    if st.best.hit.is_some() {
                        empty = None;
                        return ControlFlow::Continue(());
                    }
                    // Where the ray leaves the cell it is still over the closed
                    // cell; from there, `tau` later, it is at most `run * tau`
                    // from the cell and `room + slope * rise * tau` is the cone's
                    // radius at its height (eq. 11-12 with the cell for a point).
                    // Heights are rounded (the ray's, and the landing's `above /
                    // closing`, which cancels on grazing rays): both are shaded
                    // towards a shorter leap by far more than their rounding.
                    let slack = (g.origin[2].abs() + (t1 * rise).abs() + cone.apex.abs()) * 1e-12;
                    let above = z1 - cone.apex - slack;
                    if !(above > 0.0 && cone.slope > 0.0) {
                        return ControlFlow::Continue(());
                    }
                    let tau = if cone.slope == f64::INFINITY {
                        // Nothing in the DEM rises above the apex: the "cone" is
                        // the half-space above it.
                        if rise < 0.0 {
                            above / -rise
                        } else {
                            f64::INFINITY
                        }
                    } else {
                        let closing =
                            run - cone.slope * rise + (run + (cone.slope * rise).abs()) * 1e-12;
                        if closing <= 0.0 {
                            // Upward and never leaving the cone: no hit (sec. 2.3).
                            f64::INFINITY
                        } else {
                            cone.slope * above / closing
                        }
                    };
                    // A hair short of the cone's edge, so that rounding never
                    // carries the landing past it.
                    let to = t1 + tau * (1.0 - 1e-9);
                    empty = match empty {
                        // Overlapping stretches make one.
                        Some((from, end)) if t1 <= end && from <= to => {
                            Some((from.min(t1), end.max(to)))
                        }
                        Some((from, end)) if end >= to => Some((from, end)),
                        _ => Some((t1, to)),
                    };
                    ControlFlow::Continue(())
                },
            );
            match leap {
                Some(t) if t <= tb && st.err.is_none() => {
                    st.counters.leaps += 1;
                    t_start = t;
                    leaping = st.counters.steps <= budget;
                }
                _ => return,
            }
        }
    }

    fn brute_force(&self, st: &mut Trace<'a, D>) {
        // Candidates row by row: the columns the ground track spans in the
        // row, widened by one on each side; the exact test of which cells the
        // ray touches is `square`, cell by cell, and every touched cell is
        // intersected. No traversal order, no skipping.
        let (g, ta, tb) = (st.g, st.ta, st.tb);
        let (p, q) = (g.at(ta), g.at(tb));
        let widen = |a: f64, b: f64, n: u32| {
            let lo = (a.min(b).floor() as i64 - 1).max(0);
            let hi = (a.max(b).floor() as i64 + 1).min(i64::from(n) - 1);
            (lo, hi)
        };
        let rows = widen(p[1], q[1], self.cells.1);
        for r in rows.0..=rows.1 {
            let (s0, s1) = g.slab(1, r as f64, r as f64 + 1.0);
            let (s0, s1) = (s0.max(ta), s1.min(tb));
            if s0 > s1 {
                continue;
            }
            let cols = widen(
                g.origin[0] + s0 * g.dir[0],
                g.origin[0] + s1 * g.dir[0],
                self.cells.0,
            );
            for c in cols.0..=cols.1 {
                st.counters.steps += 1;
                let (t0, t1) = g.square(c as f64, r as f64, 1.0, ta, tb);
                if t0 > t1 {
                    continue;
                }
                st.counters.cells += 1;
                let Some(cell) = st
                    .posts
                    .cell(c as u32, r as u32)
                    .map_err(|e| st.err = Some(e))
                    .ok()
                else {
                    return;
                };
                if let Some(t) = intersect_cell(&cell, c as u32, r as u32, &g, t0, t1) {
                    st.best.offer(t, c as u32, r as u32);
                }
            }
        }
    }

    fn hierarchical(&self, st: &mut Trace<'a, D>) {
        let Some(top_level) = self.pyramid.last() else {
            st.err = Some(Error::NoLayer {
                asset: self.asset.to_path_buf(),
                name: PYRAMID_MAX.into(),
                level: 0,
                available: Vec::new(),
            });
            return;
        };
        let top = self.pyramid.len() - 1;
        let bounds = Bounds {
            u: (0, i64::from(top_level.width()) - 1),
            v: (0, i64::from(top_level.height()) - 1),
        };
        let (g, ta, tb) = (st.g, st.ta, st.tb);
        let _ = walk(
            &g,
            f64::from(1u32 << top),
            bounds,
            ta,
            tb,
            |a, b, t0, t1| self.node(st, top, a, b, (t0, t1)),
        );
    }

    /// Visits node `(a, b)` of `level`: skipped when the ray passes above
    /// its maximum, else its children are walked (cells tested at level 0).
    fn node(
        &self,
        st: &mut Trace<'a, D>,
        level: usize,
        a: i64,
        b: i64,
        (t0, t1): (f64, f64),
    ) -> ControlFlow<()> {
        // Nodes come in order of entry: one that starts after the best hit
        // ends this level's walk unvisited.
        if t0 > st.best.t() {
            return ControlFlow::Break(());
        }
        st.counters.steps += 1;
        if level == 0 {
            return self.test_cell(st, a as u32, b as u32, (t0, t1));
        }
        let z_max = f64::from(st.ok(self.pyramid[level].max(a as u32, b as u32))?);
        if st.g.z(t0).min(st.g.z(t1)) > z_max {
            return ControlFlow::Continue(());
        }
        st.counters.nodes_pushed += 1;
        let child = &self.pyramid[level - 1];
        let bounds = Bounds {
            u: (2 * a, (2 * a + 1).min(i64::from(child.width()) - 1)),
            v: (2 * b, (2 * b + 1).min(i64::from(child.height()) - 1)),
        };
        // A child breaks its walk once children start after the best hit;
        // that ends this subtree only. A node beside this one (a ray along a
        // grid line touches two at once) is still this level's to visit.
        let g = st.g;
        let _ = walk(
            &g,
            f64::from(1u32 << (level - 1)),
            bounds,
            t0,
            t1,
            |ca, cb, s0, s1| self.node(st, level - 1, ca, cb, (s0, s1)),
        );
        st.stop_on_error()
    }

    fn runs(&self, st: &mut Trace<'a, D>) {
        // Runs lie along the major axis of the ground track, one per row
        // (or column) of the minor axis.
        let (g, ta, tb) = (st.g, st.ta, st.tb);
        let major = if g.dir[0].abs() >= g.dir[1].abs() {
            0
        } else {
            1
        };
        let minor = 1 - major;
        // Runs shorter than three cells on average (slopes between 1/3 and
        // 3) buy nothing over the cell walk: Henning and Stephenson measured
        // no gain at run length one. There the cell walk is used; it visits
        // the same cells.
        // Vertical rays (no major motion) touch a cell or four: also walked.
        if g.dir[minor].abs() * 3.0 > g.dir[major].abs() || g.dir[major] == 0.0 {
            return self.incremental(st);
        }
        let cells = [i64::from(self.cells.0), i64::from(self.cells.1)];
        let (n_major, n_minor) = (cells[major], cells[minor]);
        let line_bounds = if minor == 0 {
            Bounds {
                u: (0, n_minor - 1),
                v: (0, 0),
            }
        } else {
            Bounds {
                u: (0, 0),
                v: (0, n_minor - 1),
            }
        };
        // Where each run starts and ends (`runs`).
        let mut runs = Runs::new(&g, major, ta, tb);
        let (o, d) = (g.origin[major], g.dir[major]);
        // A 1-D walk over the minor axis: the major axis collapses to one
        // slab that the ray never leaves.
        let mut line = g;
        line.dir[major] = 0.0;
        line.origin[major] = 0.5;
        let _ = walk(&line, 1.0, line_bounds, ta, tb, |a, b, r0, r1| {
            let k = if minor == 0 { a } else { b };
            st.counters.steps += 1;
            if r0 > st.best.t() {
                return ControlFlow::Break(());
            }
            // The run: every cell along the major axis touched while the
            // ray is in this row, `[r0, r1]`.
            let (first, last) = runs.cells(k, r0, r1);
            let (lo, hi) = (first.min(last).max(0), first.max(last).min(n_major - 1));
            if lo > hi {
                return ControlFlow::Continue(());
            }
            // A run of MIN_TESTED cells or more is skipped whole when the
            // ray's lowest point over it is above its tallest post; runs
            // longer than PIECE cells (tracks within 1/32 of an axis), in
            // pieces, so that a hit near a long run's start does not pay for
            // its far end. (Shorter runs, as near diagonals, go straight to
            // the per-cell test, which rejects as cheaply.)
            const PIECE: i64 = 32;
            const MIN_TESTED: i64 = 4;
            let step: i64 = if first <= last { 1 } else { -1 };
            let (first, last) = if step > 0 { (lo, hi) } else { (hi, lo) };
            let cell_at = |m: i64| {
                if major == 0 {
                    (m as u32, k as u32)
                } else {
                    (k as u32, m as u32)
                }
            };
            // A cell's interval is its major-axis slab within the row's
            // interval: the same numbers `GridRay::square` gives, with
            // one division per cell (each boundary is shared by two).
            let boundary = |k: i64| (k as f64 - o) / d;
            // The boundaries where the track enters and leaves cell `m`.
            let entry = |m: i64| if step > 0 { m } else { m + 1 };
            let exit = |m: i64| if step > 0 { m + 1 } else { m };
            let mut start = first;
            loop {
                let end = if step > 0 {
                    (start + PIECE - 1).min(last)
                } else {
                    (start - PIECE + 1).max(last)
                };
                if (end - start).abs() + 1 >= MIN_TESTED {
                    // The piece's interval: the row's, cut at the piece's
                    // own ends within a long run.
                    let t_start = if start == first {
                        r0
                    } else {
                        boundary(entry(start)).max(r0)
                    };
                    let t_end = if end == last {
                        r1
                    } else {
                        boundary(exit(end)).min(r1)
                    };
                    if t_start > st.best.t() {
                        // The rest of this run starts after the best hit; a
                        // parallel run (ray along a grid line) may not.
                        return ControlFlow::Continue(());
                    }
                    let z_max = st.ok(self.run_max(
                        major,
                        k as u32,
                        start.min(end) as u32,
                        start.max(end) as u32,
                    ))?;
                    if g.z(t_start).min(g.z(t_end)) > z_max {
                        if end == last {
                            return ControlFlow::Continue(());
                        }
                        start = end + step;
                        continue;
                    }
                }
                let mut m = start;
                let (mut b_lo, mut b_hi) = (boundary(m), boundary(m + 1));
                loop {
                    let (c, r) = cell_at(m);
                    let interval = (b_lo.min(b_hi).max(r0), b_lo.max(b_hi).min(r1));
                    // Past the best hit (or an error): this run is done.
                    if interval.0 <= interval.1 && self.test_cell(st, c, r, interval).is_break() {
                        return st.stop_on_error();
                    }
                    if m == end {
                        break;
                    }
                    m += step;
                    if step > 0 {
                        (b_lo, b_hi) = (b_hi, boundary(m + 1));
                    } else {
                        (b_lo, b_hi) = (boundary(m), b_lo);
                    }
                }
                if end == last {
                    return ControlFlow::Continue(());
                }
                start = end + step;
            }
        });
    }

    /// Tallest valid post under cells `lo..=hi` along `major` in minor row
    /// `k`: posts `lo..=hi + 1` along the run, `k..=k + 1` across (two rows
    /// of contiguous memory for row runs), scanned tile by tile in place.
    /// Nodata posts are left out: their cells have no surface, and every
    /// cell that has one is bounded by its own corners.
    fn run_max(&self, major: usize, k: u32, lo: u32, hi: u32) -> Result<f64> {
        let (c0, c1, r0, r1) = if major == 0 {
            (lo, hi + 1, k, k + 1)
        } else {
            (k, k + 1, lo, hi + 1)
        };
        let ts = self.height.tile_size();
        let mut z = f32::NEG_INFINITY;
        for ty in r0 / ts..=r1 / ts {
            for tx in c0 / ts..=c1 / ts {
                let tile = self.height.tile::<f32>(0, tx, ty)?;
                let (x0, x1) = (
                    c0.max(tx * ts) - tx * ts,
                    c1.min(tx * ts + ts - 1) - tx * ts,
                );
                let (y0, y1) = (
                    r0.max(ty * ts) - ty * ts,
                    r1.min(ty * ts + ts - 1) - ty * ts,
                );
                for y in y0..=y1 {
                    let row = &tile[(y * ts + x0) as usize..=(y * ts + x1) as usize];
                    // NaN is never greater: nodata posts drop out.
                    z = row.iter().fold(z, |m, &v| if v > m { v } else { m });
                }
            }
        }
        Ok(f64::from(z))
    }
}
