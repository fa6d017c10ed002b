//! Line horizons: in direction `theta`, the largest elevation angle of the
//! surface (`terrabake_format::surface`: two triangles per cell) along the
//! straight line from a post, found for every post at once by sweeps of
//! parallel lines that carry an upper convex hull (Timonen 2013, sec. 3-5;
//! Dozier et al. 1981 for one hull per line).
//!
//! **Grid directions.** A line from a post in direction `theta` passes
//! through other posts only when `theta` is the direction of an integer
//! step `(a, b)` of the grid; then every post on it shares one sweep and the
//! result is still exact at each post. For any other `theta` every post has
//! its own line, and sharing a sweep means interpolating the receiver, which
//! is what Timonen does (lines one unit apart, samples stepped along them).
//! So we pick, for each asked azimuth, the grid step with the fewest posts
//! per step whose azimuth is within a tolerance, and report the azimuth it
//! has ([`grid_direction`]; the manifest lists it per band). The cost per
//! post is the number of profile vertices per step, about `|a| + |b| +
//! |a + b|`.
//!
//! **Profiles.** Along a step the line crosses vertical and horizontal grid
//! lines and cell diagonals (`col + row` integer: the SW-NE diagonals); the
//! surface is linear between crossings, so the steepest sight line from a
//! post ends at a crossing ([`Stencil`]: the crossings of one step, the same
//! for every post). With curvature, each crossing at distance `d` drops by
//! `c d^2`; with `w = z - c t^2` (t along the line) the slope from post `p`
//! is `(w_q - w_p) / (t_q - t_p) + 2 c t_p`, so one hull of `w` serves every
//! post of the line, exactly.
//!
//! **Geographic grids.** A step's length uses the east-west spacing at its
//! middle row ([`step_lengths`], [`RowScale`]), and `t` along a line sums
//! the steps: the line stays straight in posts, its metric length exact to
//! the spacing's variation within a step.
//!
//! **Sweep.** Each line is walked from its far end towards the near end;
//! every vertex is pushed on a stack that is the upper hull of everything
//! farther along the line, popping what falls below (Graham's scan). When a
//! post is pushed, the hull vertex it lands next to is its horizon (the
//! tangent from the leftmost point of an upper hull is its neighbour), so a
//! line of `n` vertices costs `O(n)` in all. Timonen's convex hull tree keeps
//! the popped branches to list every local horizon ([`crate::algorithms::viewshed::hull_tree`]);
//! the horizon alone needs only the stack, which is what this sweep keeps.
//!
//! **Out of core.** [`BandedSweep`] walks the lines band of rows by band of
//! rows, each line's hull carried from band to band; one band holding the
//! whole DEM is the in-core case ([`line_horizons`]), and any banding gives
//! the same bits.
//!
//! **Nodata and edges.** A vertex exists when a segment beside it lies in a
//! cell with a surface, and a post when it is a corner of such a cell (a
//! line may graze it between two holes); nodata posts receive nothing
//! (NaN). A post with no
//! surface ahead within the DEM gets -90 degrees.
//!
//! **Maximum distance.** A bounded horizon breaks the stack's amortisation
//! (far vertices must leave it), so [`line_horizon_within`] walks each post's
//! line up to the distance instead: `O(distance)` per post.

pub mod lanes;

use crate::terrain::steepest::{Steepest, Tag};
use crate::terrain::{angle_between, RowScale, Terrain};

/// Largest `|a|`, `|b|` of a grid step considered.
pub const MAX_STEP: i64 = 64;

/// A grid direction: a step of `step.0` columns east and `step.1` rows
/// south between consecutive posts of a line.
#[derive(Debug, Clone, PartialEq)]
pub struct GridDirection {
    pub step: (i64, i64),
    /// Compass azimuth of the step, degrees clockwise from north.
    pub azimuth: f64,
    /// The azimuth that was asked for.
    pub nominal: f64,
}

/// Metres of each step of direction `step` on a DEM of `height` rows:
/// entry `r` is the step from a post on row `r` to the next post farther
/// along (row `r + step.1`), with the east-west spacing at the step's middle
/// row ([`RowScale`]; every step the same on a uniform grid).
pub fn step_lengths(
    (a, b): (i64, i64),
    height: usize,
    (dx, dy): (f64, f64),
    row_scale: RowScale,
) -> Vec<f64> {
    (0..height as i64)
        .map(|r| (a as f64 * dx * row_scale.at_half(2 * r + b)).hypot(b as f64 * dy))
        .collect()
}

/// Compass azimuth (degrees) of the grid step `(a, b)`.
pub(crate) fn step_azimuth((a, b): (i64, i64), dx: f64, dy: f64) -> f64 {
    (a as f64 * dx)
        .atan2(-(b as f64) * dy)
        .to_degrees()
        .rem_euclid(360.0)
}

fn gcd(a: i64, b: i64) -> i64 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// The grid step nearest in cost to `nominal`: the fewest posts per step
/// (`max(|a|, |b|)`) among steps within `tolerance` degrees, the closest
/// among those; the closest of all if none is within tolerance.
pub fn grid_direction(nominal: f64, dx: f64, dy: f64, tolerance: f64) -> GridDirection {
    Steps::new(dx, dy).direction(nominal, tolerance)
}

/// `count` directions for nominal azimuths `i * 360 / count`, each within
/// `tolerance` degrees where a step up to [`MAX_STEP`] allows.
pub(crate) fn grid_directions(
    count: usize,
    dx: f64,
    dy: f64,
    tolerance: f64,
) -> Vec<GridDirection> {
    let steps = Steps::new(dx, dy);
    (0..count)
        .map(|i| steps.direction(i as f64 * 360.0 / count as f64, tolerance))
        .collect()
}

/// Every primitive grid step up to [`MAX_STEP`] with its azimuth, sorted by
/// azimuth, so that a direction looks at the steps within its tolerance
/// only (a plan asks for 720: a scan of all 16,000 steps with an arctangent
/// each was a tenth of a plan).
struct Steps {
    /// Azimuth, posts per step, rank in the order `a`, then `b`,
    /// ascending (which breaks ties, as a scan in that order would), step.
    sorted: Vec<(f64, i64, usize, (i64, i64))>,
}

impl Steps {
    fn new(dx: f64, dy: f64) -> Self {
        let mut sorted: Vec<_> = (-MAX_STEP..=MAX_STEP)
            .flat_map(|a| (-MAX_STEP..=MAX_STEP).map(move |b| (a, b)))
            .filter(|&(a, b)| gcd(a.abs(), b.abs()) == 1)
            .enumerate()
            .map(|(rank, step)| {
                (
                    step_azimuth(step, dx, dy),
                    step.0.abs().max(step.1.abs()),
                    rank,
                    step,
                )
            })
            .collect();
        sorted.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.2.cmp(&y.2)));
        Self { sorted }
    }

    /// [`grid_direction`] from these steps.
    fn direction(&self, nominal: f64, tolerance: f64) -> GridDirection {
        let err = |az: f64| angle_between(az, nominal);
        // The steps whose azimuth lies within the tolerance, the circle
        // cut open at 0 (a hair wider: the test below is the exact one).
        let (at, reach) = (nominal.rem_euclid(360.0), tolerance + 1e-9);
        let (lo, hi) = (at - reach, at + reach);
        let from = |az: f64| self.sorted.partition_point(|s| s.0 < az);
        let to = |az: f64| self.sorted.partition_point(|s| s.0 <= az);
        let n = self.sorted.len();
        let ranges = [
            from(lo.max(0.0))..to(hi.min(360.0)),
            if lo < 0.0 { from(lo + 360.0)..n } else { n..n },
            if hi > 360.0 { 0..to(hi - 360.0) } else { 0..0 },
        ];
        let within = ranges
            .into_iter()
            .flat_map(|r| &self.sorted[r])
            .map(|&(az, len, rank, step)| (len, err(az), rank, (az, step)))
            .filter(|&(_, e, _, _)| e <= tolerance)
            .min_by(|x, y| {
                (x.0, x.1, x.2)
                    .partial_cmp(&(y.0, y.1, y.2))
                    .expect("no NaN")
            });
        let (azimuth, step) = match within {
            Some((.., chosen)) => chosen,
            // None within: the closest of all.
            None => {
                self.sorted
                    .iter()
                    .map(|&(az, _, rank, step)| (err(az), rank, (az, step)))
                    .min_by(|x, y| (x.0, x.1).partial_cmp(&(y.0, y.1)).expect("no NaN"))
                    .expect("steps exist")
                    .2
            }
        };
        GridDirection {
            step,
            azimuth,
            nominal,
        }
    }
}

/// The default tolerance for `count` directions: an eighth of their spacing.
pub fn default_tolerance(count: usize) -> f64 {
    360.0 / count as f64 / 8.0
}

/// What a tolerance for `count` directions must stay below: half their
/// spacing. Two nominal azimuths closer than twice the tolerance could take
/// the same grid step, and the bands would repeat a direction.
pub fn tolerance_limit(count: usize) -> f64 {
    180.0 / count as f64
}

/// One crossing of a step's line with the grid: the surface height there is
/// `(1 - wb) * z[a] + wb * z[b]` (posts given as offsets from the step's
/// first post).
#[derive(Debug, Clone)]
struct StencilVertex {
    /// Fraction of the step, in (0, 1]; 1 is the next post.
    s: f64,
    a: (i64, i64),
    b: (i64, i64),
    wb: f64,
}

/// The crossings of one step `P -> P + step`, the same for every post `P`,
/// and the cells beside each segment between them.
#[derive(Debug, Clone)]
pub struct Stencil {
    step: (i64, i64),
    /// Interior crossings by increasing `s`, then the next post (`s = 1`).
    vertices: Vec<StencilVertex>,
    /// `segments[k]`: the cells (offsets from `P`) that hold the segment
    /// ending at vertex `k`; `segments[n]` is the first segment of the next
    /// step (after the next post).
    segments: Vec<Vec<(i64, i64)>>,
}

impl Stencil {
    pub fn new((a, b): (i64, i64)) -> Self {
        assert!((a, b) != (0, 0));
        // Every crossing is at s = m / l for integer m.
        let lcm = |x: i64, y: i64| {
            if x == 0 {
                y
            } else if y == 0 {
                x
            } else {
                x / gcd(x, y) * y
            }
        };
        let l = lcm(lcm(a.abs(), b.abs()), (a + b).abs());
        let mut ms: Vec<i64> = Vec::new();
        for den in [a.abs(), b.abs(), (a + b).abs()] {
            if den > 1 {
                ms.extend((1..den).map(|i| i * (l / den)));
            }
        }
        ms.sort_unstable();
        ms.dedup();
        ms.push(l);
        let vertex = |m: i64| {
            let (cn, rn) = (a * m, b * m);
            let (c, r) = (cn.div_euclid(l), rn.div_euclid(l));
            let (fc, fr) = (cn.rem_euclid(l), rn.rem_euclid(l));
            let frac = |f: i64| f as f64 / l as f64;
            let (pa, pb, wb) = match (fc == 0, fr == 0) {
                (true, true) => ((c, r), (c, r), 0.0),
                (true, false) => ((c, r), (c, r + 1), frac(fr)),
                (false, true) => ((c, r), (c + 1, r), frac(fc)),
                // On the SW-NE diagonal of cell (c, r): SW post (c, r + 1)
                // to NE post (c + 1, r), `frac(fc)` of the way.
                (false, false) => ((c, r + 1), (c + 1, r), frac(fc)),
            };
            StencilVertex {
                s: m as f64 / l as f64,
                a: pa,
                b: pb,
                wb,
            }
        };
        // Cells holding the segment whose midpoint is at 2m/(2l) of the step.
        let cells = |m2: i64| {
            let side = |n: i64| {
                let (q, f) = (n.div_euclid(2 * l), n.rem_euclid(2 * l));
                if f == 0 {
                    vec![q - 1, q]
                } else {
                    vec![q]
                }
            };
            let mut out = Vec::new();
            for c in side(a * m2) {
                for r in side(b * m2) {
                    out.push((c, r));
                }
            }
            out
        };
        let mut prev = 0;
        let mut segments = Vec::new();
        for &m in &ms {
            segments.push(cells(prev + m));
            prev = m;
        }
        let first = ms[0];
        segments.push(cells(first).iter().map(|&(c, r)| (c + a, r + b)).collect());
        Self {
            step: (a, b),
            vertices: ms.into_iter().map(vertex).collect(),
            segments,
        }
    }

    /// Profile vertices per step (crossings and the next post).
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }
}

/// Counts of one sweep, for the benchmarks and the bowl test.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SweepStats {
    /// Profile vertices pushed on a hull.
    pub vertices: u64,
    /// Vertices popped off a hull (each at most once).
    pub pops: u64,
    /// Posts that received a horizon.
    pub posts: u64,
    /// Lines that left the SIMD lanes for the scalar sweep ([`lanes`]).
    pub spilled: u64,
    /// The most vertices one line's hull held in the scalar sweep, after
    /// its trims ([`BandedSweep::with_height_bound`]).
    pub longest_hull: u64,
}

impl std::ops::AddAssign for SweepStats {
    fn add_assign(&mut self, o: Self) {
        self.vertices += o.vertices;
        self.pops += o.pops;
        self.posts += o.posts;
        self.spilled += o.spilled;
        self.longest_hull = self.longest_hull.max(o.longest_hull);
    }
}

/// Where a step's vertices stand for post `(col, row)`, and whether they lie
/// on the surface.
struct Placed<'t> {
    t: &'t Terrain<'t>,
    stencil: &'t Stencil,
}

impl Placed<'_> {
    fn segment_exists(&self, (col, row): (i64, i64), k: usize) -> bool {
        self.stencil.segments[k]
            .iter()
            .any(|&(c, r)| self.t.cell_exists(col + c, row + r))
    }

    /// Height of stencil vertex `k` from post `(col, row)`, if it is on the
    /// surface.
    fn vertex(&self, (col, row): (i64, i64), k: usize) -> Option<f64> {
        let v = &self.stencil.vertices[k];
        let (a, b) = ((col + v.a.0, row + v.a.1), (col + v.b.0, row + v.b.1));
        if !(self.t.contains(a.0, a.1) && self.t.contains(b.0, b.1)) {
            return None;
        }
        let on_surface = if v.wb == 0.0 {
            // A post: on the surface when any cell it is a corner of is,
            // whether or not the line runs through that cell.
            self.t.post_on_surface(a.0, a.1)
        } else {
            self.segment_exists((col, row), k) || self.segment_exists((col, row), k + 1)
        };
        on_surface.then(|| self.height_unchecked(a, b, v.wb))
    }

    #[inline]
    fn height_unchecked(&self, a: (i64, i64), b: (i64, i64), wb: f64) -> f64 {
        let za = f64::from(self.t.at(a.0 as usize, a.1 as usize));
        if wb == 0.0 {
            return za;
        }
        let zb = f64::from(self.t.at(b.0 as usize, b.1 as usize));
        za + wb * (zb - za)
    }
}

/// Pushes `(t, w)` (nearer than everything on the hull) and returns the
/// hull vertex it lands beside: the steepest sight line from it.
#[inline]
fn push(hull: &mut Vec<[f64; 2]>, t: f64, w: f64, pops: &mut u64) -> Option<[f64; 2]> {
    while let [.., [t1, w1], [t0, w0]] = hull[..] {
        // Drop the top if it is on or below the line from the new point to
        // the one behind it.
        if (w0 - w) * (t1 - t) <= (w1 - w) * (t0 - t) {
            hull.pop();
            *pops += 1;
        } else {
            break;
        }
    }
    let top = hull.last().copied();
    hull.push([t, w]);
    top
}

/// The steepest sight line from `(t, w)` to a hull, without changing it.
fn tangent(hull: &[[f64; 2]], t: f64, w: f64) -> Option<[f64; 2]> {
    let slope = |[tq, wq]: [f64; 2]| (wq - w) / (tq - t);
    let mut best = *hull.last()?;
    for &q in hull.iter().rev().skip(1) {
        if slope(q) >= slope(best) {
            best = q;
        } else {
            break;
        }
    }
    Some(best)
}

/// Elevation angle in degrees of the sight line from `(t, w)` to `q`, with
/// the curvature term; -90 when nothing lies ahead.
fn angle_deg(q: Option<[f64; 2]>, t: f64, w: f64, curvature: f64) -> f32 {
    match q {
        Some([tq, wq]) => atan_deg((wq - w) / (tq - t) + 2.0 * curvature * t),
        None => -90.0,
    }
}

/// [`atan_deg`]'s reduction points, `tan(3 pi / 8)` and `tan(pi / 8)`, and
/// its polynomial's coefficients (alternating in sign), which the lanes'
/// vector copies share.
const TAN_3PI_8: f64 = 2.414_213_562_373_095;
const TAN_PI_8: f64 = 0.414_213_562_373_095_1;
const ATAN_POLY: [f64; 4] = [
    8.053_744_495_38e-2,
    1.387_768_560_32e-1,
    1.997_771_064_78e-1,
    3.333_294_915_39e-1,
];

/// `atan(x)` in degrees, as f32: Cephes' `atanf` reduction and polynomial
/// in f64, within 2e-7 radians (about two f32 steps of an angle near 45
/// degrees, far below any stored encoding's step) and branch-light, where
/// libm's `atan` is a third of a one-crossing sweep's time.
#[inline]
pub(crate) fn atan_deg(x: f64) -> f32 {
    let (sign, x) = (x.signum(), x.abs());
    let (base, x) = if x > TAN_3PI_8 {
        (std::f64::consts::FRAC_PI_2, -1.0 / x)
    } else if x > TAN_PI_8 {
        (std::f64::consts::FRAC_PI_4, (x - 1.0) / (x + 1.0))
    } else {
        (0.0, x)
    };
    let z = x * x;
    let [p0, p1, p2, p3] = ATAN_POLY;
    let poly = (((p0 * z - p1) * z + p2) * z - p3) * z * x + x;
    (sign * (base + poly)).to_degrees() as f32
}

/// One line being swept: its hull and the post it has got to.
#[derive(Debug)]
struct Lane {
    hull: Vec<[f64; 2]>,
    col: i64,
    row: i64,
    t: f64,
    /// The hull's length at which its far end is next trimmed
    /// ([`Sweep::trim`]).
    trim_at: usize,
}

impl Lane {
    fn new(hull: Vec<[f64; 2]>, (col, row): (i64, i64), t: f64) -> Self {
        Self {
            hull,
            col,
            row,
            t,
            trim_at: TRIM_FROM,
        }
    }
}

/// Hull vertices a line holds before its far end is first trimmed; after
/// each trim, twice what is left (the trims cost `O(1)` a vertex).
const TRIM_FROM: usize = 16;

/// How far (metres of `w`) below the line through two far hull vertices
/// every post still to come must stand for the farther to be dropped,
/// over what rounding could make of it ([`trim_margin`]).
const TRIM_MARGIN: f64 = 1e-6;

/// The margin [`Sweep::trim`] asks of a post at `at` below the line
/// through `[t0, w0]` (farther) and `[t1, w1]`, when no post is higher
/// than `z`: a post that far below it pops the nearer vertex's rival in a
/// cross product of `(t0 - t1)` times that height, and the pop test's two
/// products round by some `1e-16` of `|w| |t|`; `w_P` itself rounds by
/// `1e-16 |w|`. A thousand times both, and [`TRIM_MARGIN`].
fn trim_margin([t0, w0]: [f64; 2], [t1, w1]: [f64; 2], at: f64, c: f64, z: f64) -> f64 {
    let scale_w = w0.abs() + w1.abs() + z.abs() + c * at * at;
    let scale_t = t0.abs() + at.abs();
    TRIM_MARGIN + 1e-12 * scale_w * (1.0 + scale_t / (t0 - t1))
}

/// Where a sweep writes: rows from `row0` on, of angles and, when asked,
/// of distances to the horizon.
struct Out<'a> {
    angles: &'a mut [f32],
    distances: Option<&'a mut [f32]>,
    row0: usize,
}

/// A sweep of one direction's lines over a band of rows.
struct Sweep<'t> {
    placed: Placed<'t>,
    /// [`step_lengths`] of the direction.
    lengths: &'t [f64],
    nodata: bool,
    /// No post of the DEM is higher (metres; infinite: unknown, no trims).
    height_bound: f64,
}

impl Sweep<'_> {
    fn w_of(&self, t: f64, z: f64) -> f64 {
        let c = self.placed.t.curvature;
        z - c * t * t
    }

    /// Pushes the crossings of the step from the lane's post to the one
    /// before it (farther), far first. `checked`: the step may leave the
    /// DEM (a line's first step), so every crossing is checked as with
    /// nodata.
    #[inline]
    fn push_crossings(&self, lane: &mut Lane, checked: bool, stats: &mut SweepStats) {
        let n = self.placed.stencil.vertices.len();
        let (nc, nr) = (lane.col, lane.row);
        let len = self.lengths[nr as usize];
        for k in (0..n - 1).rev() {
            let v = &self.placed.stencil.vertices[k];
            let z = if self.nodata || checked {
                self.placed.vertex((nc, nr), k)
            } else {
                Some(self.placed.height_unchecked(
                    (nc + v.a.0, nr + v.a.1),
                    (nc + v.b.0, nr + v.b.1),
                    v.wb,
                ))
            };
            if let Some(z) = z {
                let t = lane.t + v.s * len;
                push(&mut lane.hull, t, self.w_of(t, z), &mut stats.pops);
                stats.vertices += 1;
            }
        }
    }

    /// The lane's post takes its horizon from the hull and joins it.
    #[inline]
    fn receive(&self, lane: &mut Lane, out: &mut Out, stats: &mut SweepStats) {
        let t = self.placed.t;
        let zp = t.at(lane.col as usize, lane.row as usize);
        let idx = (lane.row as usize - out.row0) * t.width + lane.col as usize;
        if zp.is_nan() {
            out.angles[idx] = f32::NAN;
            if let Some(d) = out.distances.as_deref_mut() {
                d[idx] = f32::NAN;
            }
            return;
        }
        stats.posts += 1;
        let wp = self.w_of(lane.t, f64::from(zp));
        let q = if !self.nodata || self.placed.t.post_on_surface(lane.col, lane.row) {
            stats.vertices += 1;
            push(&mut lane.hull, lane.t, wp, &mut stats.pops)
        } else {
            tangent(&lane.hull, lane.t, wp)
        };
        out.angles[idx] = angle_deg(q, lane.t, wp, t.curvature);
        if let Some(d) = out.distances.as_deref_mut() {
            // The hull vertex that sets the horizon, `tq - t` metres out
            // along the line (`t` falls towards the near end).
            d[idx] = q.map_or(f32::NAN, |[tq, _]| (tq - lane.t) as f32);
        }
        if lane.hull.len() >= lane.trim_at {
            self.trim(lane);
        }
        stats.longest_hull = stats.longest_hull.max(lane.hull.len() as u64);
    }

    /// Drops the far vertices of the lane's hull that no post still to
    /// come can have as its horizon. On a curved earth a flat sea is a
    /// string of hull vertices that never pop (`w = z - c t^2` is concave
    /// there), so without this a line's hull, and the sweep's memory, grow
    /// with its length. A post `P` nearer than the hull's vertices reaches
    /// past vertex `q1` to the farther `q0` only on or above the line
    /// through them (`w_P >= L(t_P)`); every post still to come has
    /// `t_P <= t` (the lane's post) and `w_P <= Z - c t_P^2` for the
    /// DEM's highest post `Z`. So `q0` goes when `L(t') + c t'^2 - Z`, a
    /// convex quadratic whose least value over `t' <= t` is at
    /// `min(-s / 2c, t)`, stays above [`trim_margin`] (and grows faster
    /// than rounding does away from there). The horizons keep their bits;
    /// only vertices that could never be one leave.
    fn trim(&self, lane: &mut Lane) {
        let (c, z) = (self.placed.t.curvature, self.height_bound);
        if !(c > 0.0 && z.is_finite()) {
            lane.trim_at = usize::MAX;
            return;
        }
        let hull = &lane.hull;
        let mut gone = 0;
        // The two nearest stay: a post's tangent needs a vertex.
        while gone + 2 < hull.len() {
            let ([t0, w0], [t1, w1]) = (hull[gone], hull[gone + 1]);
            let s = (w0 - w1) / (t0 - t1);
            let at = (-s / (2.0 * c)).min(lane.t);
            let below = w1 + s * (at - t1) + c * at * at - z;
            if below > trim_margin([t0, w0], [t1, w1], at, c, z) {
                gone += 1;
            } else {
                break;
            }
        }
        lane.hull.drain(..gone);
        lane.trim_at = (2 * lane.hull.len()).max(TRIM_FROM);
        if lane.hull.capacity() > 2 * lane.trim_at {
            lane.hull.shrink_to(lane.trim_at);
        }
    }

    /// Starts the line whose far post is `(col, row)`: the crossings beyond
    /// it that are still on the DEM, then the post.
    fn start(&self, (col, row): (i64, i64), out: &mut Out, stats: &mut SweepStats) -> Lane {
        let mut lane = Lane::new(Vec::new(), (col, row), 0.0);
        self.push_crossings(&mut lane, true, stats);
        self.receive(&mut lane, out, stats);
        lane
    }

    /// Steps the lane towards the near end while its next post is in rows
    /// `rows`; whether the line goes on past them.
    fn run(
        &self,
        lane: &mut Lane,
        rows: &std::ops::Range<usize>,
        out: &mut Out,
        stats: &mut SweepStats,
    ) -> bool {
        let (a, b) = self.placed.stencil.step;
        let t = self.placed.t;
        loop {
            let (nc, nr) = (lane.col - a, lane.row - b);
            if !t.contains(nc, nr) {
                return false;
            }
            if !rows.contains(&(nr as usize)) {
                return true;
            }
            (lane.col, lane.row, lane.t) = (nc, nr, lane.t - self.lengths[nr as usize]);
            self.push_crossings(lane, false, stats);
            self.receive(lane, out, stats);
        }
    }
}

/// One direction's lines swept over the DEM band by band, each line's hull
/// carried from band to band, so that a DEM larger than memory is swept
/// with a band of rows and the hulls in memory, and gives the same bits as
/// one band holding the whole DEM (each line does the same arithmetic in
/// the same order either way).
///
/// Bands go in sweep order: north to south when the lines' far ends are in
/// the north (`step.1 < 0`), south to north otherwise. For output rows
/// `r0..r1` the sweep reads the rows [`BandedSweep::window`] names: `|b|`
/// rows behind the band for the crossings of steps that enter it, and one
/// more row each side for the cells beside them.
#[derive(Debug)]
pub struct BandedSweep {
    stencil: Stencil,
    lengths: Vec<f64>,
    width: usize,
    height: usize,
    nodata: bool,
    /// Lines that go on into the next band.
    lanes: Vec<Lane>,
    /// The lines in SIMD lanes instead, where they apply ([`lanes`]).
    simd: Option<lanes::Lanes>,
    /// Bands swept so far.
    swept: usize,
    /// No post of the DEM is higher ([`Self::with_height_bound`]).
    height_bound: f64,
    pub stats: SweepStats,
}

impl BandedSweep {
    /// `nodata`: whether the DEM has any nodata post (then crossings are
    /// checked against the cells beside them).
    pub fn new(
        dir: &GridDirection,
        (width, height): (usize, usize),
        spacing: (f64, f64),
        row_scale: RowScale,
        nodata: bool,
    ) -> Self {
        let stencil = Stencil::new(dir.step);
        Self {
            simd: if nodata {
                None
            } else {
                lanes::Lanes::new(
                    &stencil,
                    width,
                    lanes::MAX_BYTES,
                    crate::plumbing::simd::level(),
                )
            },
            stencil,
            lengths: step_lengths(dir.step, height, spacing, row_scale),
            width,
            height,
            nodata,
            lanes: Vec::new(),
            swept: 0,
            height_bound: f64::INFINITY,
            stats: SweepStats::default(),
        }
    }

    /// The same sweep told that no post of the DEM is higher than `z`
    /// metres: with curvature, each line's hull then drops the far vertices
    /// that no post to come can see ([`Sweep::trim`]), which bounds its
    /// memory on a curved sea. The same bits.
    pub fn with_height_bound(self, z: f64) -> Self {
        Self {
            height_bound: z,
            ..self
        }
    }

    /// The same sweep without SIMD lanes (the scalar sweep they are
    /// checked against; the same bits).
    pub fn without_lanes(self) -> Self {
        Self { simd: None, ..self }
    }

    /// The same sweep with the lanes' hulls held to `bytes` (fewer
    /// vertices a hull, or no lanes where even 32 would not fit): the same
    /// bits, within a memory budget.
    pub fn with_lane_memory(self, bytes: usize) -> Self {
        let simd = self
            .simd
            .as_ref()
            .and_then(|s| lanes::Lanes::new(&self.stencil, self.width, bytes, s.level()));
        Self { simd, ..self }
    }

    /// The same sweep with its lanes in vector code of `level` (one the CPU
    /// runs, [`crate::plumbing::simd::available`]; none for scalar code), where it has
    /// lanes: the same bits.
    pub fn with_lanes(self, level: crate::plumbing::simd::Level) -> Self {
        let simd = self
            .simd
            .as_ref()
            .and_then(|s| lanes::Lanes::new(&self.stencil, self.width, s.bytes(), level));
        Self { simd, ..self }
    }

    /// The most bytes a sweep of `dir` over a DEM `width` posts wide
    /// carries from band to band, its lanes held to `lane_bytes` as
    /// [`Self::with_lane_memory`] holds them (`nodata`: as
    /// [`Self::new`]'s), worked out without making it: its lanes' arrays
    /// at their full depth, or where it has none, each line's scalar state
    /// with a hull of twice [`TRIM_FROM`] vertices, what it holds before
    /// its first trim. What a planner adds up for the sweeps in flight.
    pub fn most_carried_bytes(
        dir: &GridDirection,
        width: usize,
        nodata: bool,
        lane_bytes: usize,
    ) -> usize {
        let stencil = Stencil::new(dir.step);
        let level = crate::plumbing::simd::level();
        let lanes = (!nodata)
            .then(|| lanes::Lanes::most_bytes(&stencil, width, lane_bytes, level))
            .flatten();
        lanes.unwrap_or_else(|| {
            // A line goes on into the next band unless it runs east-west.
            let (a, b) = dir.step;
            let lines = b.unsigned_abs() as usize * (width + a.unsigned_abs() as usize);
            lines * (std::mem::size_of::<Lane>() + 2 * TRIM_FROM * std::mem::size_of::<[f64; 2]>())
        })
    }

    /// Whether the lines go in SIMD lanes ([`lanes`]).
    pub fn in_lanes(&self) -> bool {
        self.simd.is_some()
    }

    /// Whether bands go from the south edge up.
    pub(crate) fn goes_north(&self) -> bool {
        self.stencil.step.1 > 0
    }

    /// The output row bands of `rows` rows each, in sweep order.
    pub fn bands(&self, rows: usize) -> Vec<std::ops::Range<usize>> {
        let mut bands = crate::terrain::tiling::row_bands(self.height, rows);
        if self.goes_north() {
            bands.reverse();
        }
        bands
    }

    /// The rows the sweep reads for output rows `band`.
    pub fn window(&self, band: &std::ops::Range<usize>) -> std::ops::Range<usize> {
        let b = self.stencil.step.1;
        let behind = b.unsigned_abs() as usize;
        let (lo, hi) = if b < 0 {
            (band.start.saturating_sub(behind + 1), band.end + 1)
        } else {
            (band.start.saturating_sub(1), band.end + behind + 1)
        };
        lo..hi.min(self.height)
    }

    /// Sweeps output rows `band` (the next in [`Self::bands`] order), with
    /// `window` the terrain of rows [`Self::window`] (and the DEM's full
    /// size), into `out` (`band.len()` rows of angles in degrees).
    pub fn sweep(&mut self, window: &Terrain, band: std::ops::Range<usize>, out: &mut [f32]) {
        self.sweep_with_distances(window, band, out, None);
    }

    /// [`Self::sweep`], also writing each post's distance to the point
    /// that sets its horizon (horizontal metres; NaN for nodata and where
    /// no terrain lies ahead) into `distances` (the shape of `out`).
    pub fn sweep_with_distances(
        &mut self,
        window: &Terrain,
        band: std::ops::Range<usize>,
        out: &mut [f32],
        distances: Option<&mut [f32]>,
    ) {
        assert_eq!(out.len(), band.len() * self.width);
        assert!(distances.as_ref().is_none_or(|d| d.len() == out.len()));
        let mut out = Out {
            angles: out,
            distances,
            row0: band.start,
        };
        let sweep = Sweep {
            placed: Placed {
                t: window,
                stencil: &self.stencil,
            },
            lengths: &self.lengths,
            nodata: self.nodata,
            height_bound: self.height_bound,
        };
        let stats = &mut self.stats;
        if out.distances.is_some() && self.simd.is_some() {
            // The lanes keep no distances: the scalar sweep from the start.
            assert_eq!(self.swept, 0, "distances asked after a band without");
            self.simd = None;
        }
        self.swept += 1;
        if let Some(simd) = &mut self.simd {
            simd.sweep(&sweep, band, &mut out, stats);
            return;
        }
        // Lines from earlier bands first, then the lines whose far posts
        // are in this band; each in its own order of steps, as in one band.
        let mut going_on = Vec::with_capacity(self.lanes.len());
        for mut lane in self.lanes.drain(..) {
            if sweep.run(&mut lane, &band, &mut out, stats) {
                going_on.push(lane);
            }
        }
        let (a, b) = self.stencil.step;
        for row in band.clone() {
            for col in 0..self.width as i64 {
                if window.contains(col + a, row as i64 + b) {
                    continue;
                }
                let mut lane = sweep.start((col, row as i64), &mut out, stats);
                if sweep.run(&mut lane, &band, &mut out, stats) {
                    going_on.push(lane);
                }
            }
        }
        self.lanes = going_on;
    }
}

/// One vertex of a line's profile ([`line_profile`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfileVertex {
    /// Metres along the line from its far post, growing towards the near
    /// end (the crossings beyond the far post are negative).
    pub d: f64,
    /// Height, NaN for a nodata post.
    pub z: f64,
    /// The post, where the vertex is one.
    pub post: Option<(usize, usize)>,
    /// Whether the vertex lies on the surface (crossings are only listed
    /// where they do; a post with a height may stand between holes).
    pub surface: bool,
    /// Whether the line from the previous vertex on the surface to this one
    /// runs over the surface all the way.
    pub piece: bool,
}

/// The profile of the line of direction `stencil` whose far post is `far`
/// (its `step` neighbour off the DEM), far end first: the crossings still
/// on the DEM beyond the far post, then post by post towards the near end,
/// each post after the crossings of the step behind it. `lengths` are the
/// direction's [`step_lengths`]. The same vertices and heights the sweep
/// of [`line_horizons`] pushes. With `until`, the profile ends at that
/// post (on the line, nearer than `far`).
pub(crate) fn line_profile(
    terrain: &Terrain,
    stencil: &Stencil,
    lengths: &[f64],
    far: (i64, i64),
    until: Option<(i64, i64)>,
    out: &mut Vec<ProfileVertex>,
) {
    out.clear();
    let placed = Placed {
        t: terrain,
        stencil,
    };
    let n = stencil.vertices.len();
    let (a, b) = stencil.step;
    let (mut post, mut t) = (far, 0.0);
    // Whether every raw piece since the last vertex on the surface is.
    let mut piece = false;
    loop {
        let len = lengths[post.1 as usize];
        for k in (0..n - 1).rev() {
            piece &= placed.segment_exists(post, k + 1);
            if let Some(z) = placed.vertex(post, k) {
                let d = -(t + stencil.vertices[k].s * len);
                out.push(ProfileVertex {
                    d,
                    z,
                    post: None,
                    surface: true,
                    piece,
                });
                piece = true;
            }
        }
        piece &= placed.segment_exists(post, 0);
        let z = f64::from(terrain.at(post.0 as usize, post.1 as usize));
        let surface = terrain.post_on_surface(post.0, post.1);
        out.push(ProfileVertex {
            d: -t,
            z,
            post: Some((post.0 as usize, post.1 as usize)),
            surface,
            piece,
        });
        if surface {
            piece = true;
        }
        let next = (post.0 - a, post.1 - b);
        if until == Some(post) || !terrain.contains(next.0, next.1) {
            return;
        }
        t -= lengths[next.1 as usize];
        post = next;
    }
}

/// Line horizons in direction `dir` at every post of `terrain`, in degrees
/// (NaN for nodata posts), into `out` (one value per post): one band.
pub fn line_horizons(terrain: &Terrain, dir: &GridDirection, out: &mut [f32]) -> SweepStats {
    line_horizons_with_distances(terrain, dir, out, None)
}

/// [`line_horizons`], and where `distances` is given (one value per post),
/// each post's distance to the point that sets its horizon
/// ([`BandedSweep::sweep_with_distances`]).
pub fn line_horizons_with_distances(
    terrain: &Terrain,
    dir: &GridDirection,
    out: &mut [f32],
    distances: Option<&mut [f32]>,
) -> SweepStats {
    assert_eq!(out.len(), terrain.z.len());
    let highest = terrain.z.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut sweep = BandedSweep::new(
        dir,
        (terrain.width, terrain.height),
        (terrain.dx, terrain.dy),
        terrain.row_scale,
        terrain.has_nodata(),
    )
    .with_height_bound(f64::from(highest));
    sweep.sweep_with_distances(terrain, 0..terrain.height, out, distances);
    sweep.stats
}

/// The line horizon (degrees) of one post, looking no farther than
/// `max_distance` metres, and `T` of the point that sets it (`Option<f64>`:
/// its horizontal distance in metres; `()`: nothing): a walk along the
/// post's line ([`step_lengths`] of its direction in `lengths`). NaN for
/// nodata; -90 and an empty tag where no terrain lies within the distance.
/// Of points exactly as steep, the farther, as the sweep keeps it.
pub fn line_horizon_within<T: Tag<f64>>(
    terrain: &Terrain,
    stencil: &Stencil,
    lengths: &[f64],
    (col, row): (i64, i64),
    max_distance: f64,
) -> (f32, T) {
    let zp = terrain.at(col as usize, row as usize);
    if zp.is_nan() {
        return (f32::NAN, T::default());
    }
    let placed = Placed {
        t: terrain,
        stencil,
    };
    let (a, b) = stencil.step;
    let c = terrain.curvature;
    let mut best = Steepest::<T>::default();
    let mut base = (col, row);
    let mut t0 = 0.0;
    'walk: loop {
        let len = lengths[base.1 as usize];
        for (k, v) in stencil.vertices.iter().enumerate() {
            let d = t0 + v.s * len;
            if d > max_distance {
                break 'walk;
            }
            if let Some(z) = placed.vertex(base, k) {
                best.take_last((z - c * d * d - f64::from(zp)) / d, T::of(d));
            }
        }
        base = (base.0 + a, base.1 + b);
        t0 += len;
        if !terrain.contains(base.0, base.1) {
            break;
        }
    }
    if best.found() {
        (best.slope.atan().to_degrees() as f32, best.tag)
    } else {
        (-90.0, best.tag)
    }
}

#[cfg(test)]
mod tests;
