//! The total viewshed: at every post, the area of terrain that an eye
//! `height` metres above it sees within a distance, by Timonen's (2013)
//! azimuthal sweeps with the convex hull tree.
//!
//! **Sweeps** (sec. 3). For each of `K` directions the DEM is cut into the
//! parallel lines of [`crate::algorithms::horizon::line`] (grid directions, so every
//! post is on a line and no receiver is interpolated), each walked from its
//! far end. At every post the eye's local horizons along the line come
//! from the tree of everything farther ([`HullTree::eye_horizons`]), then
//! the post joins the tree ([`HullTree::push`], with the safe zone of
//! Algorithm 3 unless turned off). Heights carry the curvature drop as the
//! line sweep has it (`w = z - c t^2`, exact for every receiver).
//!
//! **Area.** Local horizons bound the visible stretches of the line
//! exactly (sec. 4): the stretch behind horizon point `p_i` starts at the
//! point where the sight line of the next nearer horizon meets the profile
//! (found by bisection: going outwards the profile is first below that
//! sight line, then above it up to `p_i`) and ends at `p_i`; the nearest
//! stretch runs from the eye to the first horizon. The profile is linear
//! between vertices, so the stretch ends are exact. Each visible stretch at
//! distances `r1..r2` (clipped to the maximum distance, and only over the
//! surface: holes of nodata are not area) adds `w (r2^2 - r1^2) / 2`, `w`
//! the direction's share of the circle (half the gaps to its neighbours,
//! summing to `2 pi`). This is the paper's "exact angular coordinates"
//! use of horizons turned into an area, in `O(m log n)` per post for `m`
//! horizons on a line of `n` vertices, rather than per visible point.
//!
//! **Naive method.** [`Method::Naive`] walks each post's line outwards to
//! the maximum distance with the running steepest slope, the visible part
//! of every piece by the same formula: Timonen's baseline, and the
//! reference the tests hold the sweep to.
//!
//! **Departures.** Timonen accumulates lighting on a GPU and reports no
//! area; his receivers are samples along lines one unit apart (ours are
//! posts); his eye is on the surface (ours may be raised, which the tree
//! answers without being changed). Directions are grid steps within a
//! tolerance of `i 360 / K`, as for the horizons stage.

use rayon::prelude::*;

use crate::algorithms::horizon::band_bounds;
use crate::algorithms::horizon::line::{
    default_tolerance, grid_directions, line_profile, step_lengths, GridDirection, ProfileVertex,
    Stencil,
};
use crate::algorithms::viewshed::hull_tree::{steeper, HullTree};
use crate::terrain::Terrain;

/// How the visible stretches are found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The convex hull tree, with the safe zone where `true`.
    HullTree { safe_zone: bool },
    /// Every post walks its line outwards (the baseline and reference).
    Naive,
}

/// What is asked: the eye, the reach and the directions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TotalOptions {
    /// Eye above each post, metres.
    pub height: f64,
    /// Metres; `None`: the whole DEM.
    pub max_distance: Option<f64>,
    /// Number of directions `K`.
    pub directions: usize,
    pub method: Method,
}

/// Counts for Timonen's tables, summed over receivers and directions.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TotalStats {
    /// Receivers times directions.
    pub receivers: u64,
    /// Profile vertices on the surface visible from the eyes (Table 1).
    pub visible_vertices: u64,
    /// Local horizons of the eyes (`m`, Table 2).
    pub horizons: u64,
    /// Iterations of Algorithm 1 that kept the trees (`t`, Table 2), and
    /// the root's children after each push (the `m` of its bound).
    pub iterations: u64,
    pub root_children: u64,
    /// Tests run to answer the raised eyes.
    pub eye_tests: u64,
    /// Roots replaced through the safe zone, and children visited to
    /// rebuild it.
    pub replacements: u64,
    pub zone_visits: u64,
    /// Vertices a naive walk looks at (the naive method's iterations).
    pub naive_steps: u64,
    /// Profile vertices on the lines.
    pub vertices: u64,
}

impl std::ops::AddAssign for TotalStats {
    fn add_assign(&mut self, o: Self) {
        self.receivers += o.receivers;
        self.visible_vertices += o.visible_vertices;
        self.horizons += o.horizons;
        self.iterations += o.iterations;
        self.root_children += o.root_children;
        self.eye_tests += o.eye_tests;
        self.replacements += o.replacements;
        self.zone_visits += o.zone_visits;
        self.naive_steps += o.naive_steps;
        self.vertices += o.vertices;
    }
}

/// The directions of a `K`-direction total viewshed, with each one's share
/// of the circle in radians (half the gaps to its neighbours).
pub fn directions(terrain: &Terrain, count: usize) -> Vec<(GridDirection, f64)> {
    let dirs = grid_directions(count, terrain.dx, terrain.dy, default_tolerance(count));
    let azimuths: Vec<f64> = dirs.iter().map(|d| d.azimuth).collect();
    // The horizon bands' bounds: half-way to each neighbour.
    dirs.into_iter()
        .zip(band_bounds(&azimuths))
        .map(|(dir, (lo, hi))| (dir, (hi - lo).to_radians()))
        .collect()
}

/// The total viewshed at `posts` alone (square metres; NaN at nodata), in
/// `opts.directions` directions: each post's line walked outwards in each
/// direction, the naive method's areas, which the sweep's equal to
/// rounding. What the planner's pilot measures direction counts with, and
/// the reference `check` holds a baked layer to.
pub fn total_viewshed_at(
    terrain: &Terrain,
    opts: &TotalOptions,
    posts: &[(usize, usize)],
) -> Vec<f64> {
    // Each direction's step, stencil, step lengths and share of the circle.
    let lines: Vec<_> = directions(terrain, opts.directions)
        .into_iter()
        .map(|(dir, share)| {
            let lengths = step_lengths(
                dir.step,
                terrain.height,
                (terrain.dx, terrain.dy),
                terrain.row_scale,
            );
            (dir.step, Stencil::new(dir.step), lengths, share)
        })
        .collect();
    posts
        .par_iter()
        .map_init(Scratch::default, |scratch, &(col, row)| {
            if terrain.at(col, row).is_nan() {
                return f64::NAN;
            }
            let post = (col as i64, row as i64);
            lines
                .iter()
                .map(|(step, stencil, lengths, share)| {
                    let far = far_within(terrain, *step, lengths, post, opts.max_distance);
                    line_profile(
                        terrain,
                        stencil,
                        lengths,
                        far,
                        Some(post),
                        &mut scratch.profile,
                    );
                    share
                        * area_at_last(
                            &scratch.profile,
                            opts,
                            terrain.curvature,
                            &mut scratch.pushed,
                        )
                })
                .sum()
        })
        .collect()
}

/// The post of `post`'s line to start its profile from: the line's far
/// post, or, within `max` metres, the first post two steps past that
/// reach (the vertices a receiver can see, and the one beyond its reach
/// that clips it, are then the whole line's).
fn far_within(
    terrain: &Terrain,
    (a, b): (i64, i64),
    lengths: &[f64],
    post: (i64, i64),
    max: Option<f64>,
) -> (i64, i64) {
    let (mut far, mut reach, mut past) = (post, 0.0, 0);
    while terrain.contains(far.0 + a, far.1 + b) && past < 2 {
        reach += lengths[far.1 as usize];
        far = (far.0 + a, far.1 + b);
        if max.is_some_and(|m| reach > m) {
            past += 1;
        }
    }
    far
}

/// The area the eye above the last vertex of `profile` (a post) sees
/// along it, as [`sweep_line`] gives it with the naive method.
fn area_at_last(profile: &[ProfileVertex], opts: &TotalOptions, c: f64, p: &mut Pushed) -> f64 {
    let Some((v, farther)) = profile.split_last() else {
        return 0.0;
    };
    p.clear();
    let w_of = |v: &ProfileVertex| v.z - c * v.d * v.d;
    for u in farther.iter().filter(|u| u.surface) {
        p.push(u.d, w_of(u), u.piece);
    }
    if p.d.is_empty() {
        return 0.0;
    }
    let eye = Eye {
        d: v.d,
        w: w_of(v) + opts.height,
        tail: v.surface && v.piece,
        clip: v.d - opts.max_distance.unwrap_or(f64::INFINITY),
    };
    area_by_walking(p, &eye).0
}

/// The far posts of direction `step`'s lines: those whose `step` neighbour
/// is off the DEM.
fn line_starts<'a>(
    terrain: &'a Terrain<'a>,
    (a, b): (i64, i64),
) -> impl Iterator<Item = (i64, i64)> + 'a {
    let (w, h) = (terrain.width as i64, terrain.height as i64);
    (0..h)
        .flat_map(move |r| (0..w).map(move |c| (c, r)))
        .filter(move |&(c, r)| !terrain.contains(c + a, r + b))
}

/// The vertices on the surface of one line so far, in the frame of the
/// curvature drop, with prefix sums of their pieces over the surface.
#[derive(Debug, Default)]
struct Pushed {
    d: Vec<f64>,
    w: Vec<f64>,
    /// Whether the piece ending at vertex `j` lies on the surface.
    piece: Vec<bool>,
    /// Sums over surface pieces up to vertex `j` of their length and of
    /// `(d_j^2 - d_{j-1}^2) / 2`.
    s1: Vec<f64>,
    s2: Vec<f64>,
}

impl Pushed {
    fn clear(&mut self) {
        for v in [&mut self.d, &mut self.w, &mut self.s1, &mut self.s2] {
            v.clear();
        }
        self.piece.clear();
    }

    fn push(&mut self, d: f64, w: f64, piece: bool) {
        let (s1, s2) = match (self.d.last(), self.s1.last(), self.s2.last()) {
            (Some(&d0), Some(&a), Some(&b)) if piece => (a + (d - d0), b + 0.5 * (d * d - d0 * d0)),
            (_, Some(&a), Some(&b)) => (a, b),
            _ => (0.0, 0.0),
        };
        self.d.push(d);
        self.w.push(w);
        self.piece.push(piece && !self.s1.is_empty());
        self.s1.push(s1);
        self.s2.push(s2);
    }
}

/// A receiver: its eye, and the piece from the last pushed vertex to it.
#[derive(Debug, Clone, Copy)]
struct Eye {
    d: f64,
    w: f64,
    /// Whether the piece from the last pushed vertex to the post is surface.
    tail: bool,
    /// The nearest distance along the line that counts (`d - max`).
    clip: f64,
}

impl Eye {
    fn at(&self) -> [f64; 2] {
        [self.d, self.w]
    }

    /// Whether pushed vertex `a` looks strictly steeper than `b` (exact).
    #[inline]
    fn steeper(&self, p: &Pushed, a: usize, b: usize) -> bool {
        steeper(self.at(), [p.d[a], p.w[a]], [p.d[b], p.w[b]])
    }

    /// [`Self::steeper`] for vertices whose slopes are known: the slopes
    /// decide where they differ by more than their rounding (each within
    /// three units in the last place), the exact predicate where not.
    #[inline]
    fn steeper_known(&self, p: &Pushed, (a, sa): (usize, f64), (b, sb): (usize, f64)) -> bool {
        if (sa - sb).abs() > 8.0 * f64::EPSILON * sa.abs().max(sb.abs()) {
            sa > sb
        } else {
            self.steeper(p, a, b)
        }
    }

    /// Slope of the sight line to pushed vertex `j`.
    #[inline]
    fn slope(&self, p: &Pushed, j: usize) -> f64 {
        (p.w[j] - self.w) / (self.d - p.d[j])
    }

    /// `integral (d_eye - y) dy` over `a..b`.
    #[inline]
    fn ring(&self, a: f64, b: f64) -> f64 {
        (b - a) * (self.d - 0.5 * (a + b))
    }

    /// Where the sight line of slope `m` meets the piece from vertex `j + 1`
    /// out to vertex `j`.
    fn meet(&self, p: &Pushed, j: usize, m: f64) -> f64 {
        let (da, wa) = (p.d[j + 1], p.w[j + 1]);
        let (db, wb) = (p.d[j], p.w[j]);
        let (dd, dw) = (db - da, wb - wa);
        let lambda = ((self.w + m * (self.d - da) - wa) / (dw + m * dd)).clamp(0.0, 1.0);
        da + lambda * dd
    }

    /// `F(x)`: the integral of `(d_eye - y) dy` over the surface up to
    /// distance-along `x`, from the prefix sums; `j` is the last pushed
    /// vertex at or before `x`.
    #[inline]
    fn f_at(&self, p: &Pushed, x: f64, j: usize) -> f64 {
        let on = p.piece.get(j + 1).copied().unwrap_or(self.tail);
        self.d * p.s1[j] - p.s2[j] + if on { self.ring(p.d[j], x) } else { 0.0 }
    }

    /// The reach's far end as `(x, j)` for [`Self::f_at`] (`None`: before
    /// the first vertex, where `F` is 0).
    fn clip_at(&self, p: &Pushed) -> Option<(f64, usize)> {
        let j = p.d.partition_point(|&d| d <= self.clip);
        (j > 0).then(|| (self.clip, j - 1))
    }

    /// `ring` over `lo..hi` within reach (one piece on the surface).
    fn stretch_piece(&self, lo: f64, hi: f64) -> f64 {
        let lo = lo.max(self.clip);
        if hi <= lo {
            0.0
        } else {
            self.ring(lo, hi)
        }
    }
}

/// Visible area weight and visible vertices of `eye` from its horizons
/// (pushed indices, nearest first).
fn area_from_horizons(p: &Pushed, eye: &Eye, horizons: &[usize]) -> (f64, u64) {
    let n = p.d.len();
    let (mut area, mut seen) = (0.0, 0);
    let mut nearer: Option<usize> = None;
    // The reach's far end, looked up once, when a stretch first crosses it.
    let mut clip: Option<Option<(f64, usize)>> = None;
    for &i in horizons {
        let (hi, last) = match nearer {
            None => (eye.d, n - 1),
            Some(k) => {
                let m = eye.slope(p, k);
                // Last index in i..k still at or above the sight line of k.
                let (mut lo, mut hi) = (i, k - 1);
                while lo < hi {
                    let mid = (lo + hi).div_ceil(2);
                    if !eye.steeper(p, k, mid) {
                        lo = mid;
                    } else {
                        hi = mid - 1;
                    }
                }
                (eye.meet(p, lo, m), lo)
            }
        };
        if hi <= eye.clip {
            // This stretch and every farther one lie beyond reach.
            break;
        }
        let from = if p.d[i] >= eye.clip {
            eye.f_at(p, p.d[i], i)
        } else {
            clip.get_or_insert_with(|| eye.clip_at(p))
                .map_or(0.0, |(x, j)| eye.f_at(p, x, j))
        };
        area += eye.f_at(p, hi, last) - from;
        seen += (last - i + 1) as u64;
        nearer = Some(i);
    }
    (area, seen)
}

/// The same by walking outwards from the eye (the naive method).
fn area_by_walking(p: &Pushed, eye: &Eye) -> (f64, u64, u64) {
    let n = p.d.len();
    let (mut area, mut seen, mut steps) = (0.0, 0, 0);
    // The steepest vertex so far (the farthest of equals), and the slopes
    // of it and of the vertex before this one.
    let mut best: Option<(usize, f64)> = None;
    let mut near: Option<(usize, f64)> = None;
    for j in (0..n).rev() {
        if p.d[j] < eye.clip && near.is_some_and(|(a, _)| p.d[a] <= eye.clip) {
            break;
        }
        steps += 1;
        let here = (j, eye.slope(p, j));
        let at_least = |b: Option<(usize, f64)>| b.is_none_or(|b| !eye.steeper_known(p, b, here));
        // Most vertices are hidden: one comparison with the steepest.
        if at_least(best) {
            // The piece from the nearer vertex (or the post) out to vertex
            // j: its slope is monotone, so its visible part is one end of it.
            if at_least(near) {
                let on = near.map_or(eye.tail, |(a, _)| p.piece[a]);
                let hi = match (near, best) {
                    (None, _) => eye.d,
                    (Some(a), Some(b)) if eye.steeper_known(p, b, a) => eye.meet(p, j, b.1),
                    (Some((a, _)), _) => p.d[a],
                };
                if on {
                    area += eye.stretch_piece(p.d[j], hi);
                }
            }
            seen += 1;
            best = Some(here);
        }
        near = Some(here);
    }
    (area, seen, steps)
}

/// Scratch space of one worker.
#[derive(Default)]
struct Scratch {
    profile: Vec<ProfileVertex>,
    pushed: Pushed,
    horizons: Vec<usize>,
    stack: Vec<(usize, Option<usize>)>,
}

/// Sweeps one line, adding each receiver's area weight times `share` to
/// `out` (one value per post).
fn sweep_line(
    terrain: &Terrain,
    (stencil, lengths): (&Stencil, &[f64]),
    far: (i64, i64),
    (opts, share): (&TotalOptions, f64),
    scratch: &mut Scratch,
    out: &mut [f64],
) -> TotalStats {
    let mut stats = TotalStats::default();
    line_profile(terrain, stencil, lengths, far, None, &mut scratch.profile);
    let c = terrain.curvature;
    let max = opts.max_distance.unwrap_or(f64::INFINITY);
    let mut tree = match opts.method {
        Method::HullTree { safe_zone: true } => HullTree::with_safe_zone(),
        _ => HullTree::new(),
    };
    let p = &mut scratch.pushed;
    p.clear();
    stats.vertices = scratch.profile.len() as u64;
    let profile = &scratch.profile;
    let w_of = |v: &ProfileVertex| v.z - c * v.d * v.d;
    // Within a maximum distance the tree is restarted, once it holds twice
    // that, from the last vertex beyond the distance: far horizons cannot
    // matter, and this keeps each eye's horizons within reach.
    let mut start = profile.first().map_or(0.0, |v| v.d);
    for (i, v) in profile.iter().enumerate() {
        let w = w_of(v);
        if v.post.is_some() && v.d - start > 2.0 * max {
            let from = profile[..i]
                .partition_point(|u| u.d < v.d - max)
                .saturating_sub(1);
            start = profile[from].d;
            tree.restart();
            p.clear();
            for u in profile[from..i].iter().filter(|u| u.surface) {
                p.push(u.d, w_of(u), u.piece);
                if opts.method != Method::Naive {
                    tree.push(u.d, w_of(u));
                }
            }
        }
        if let (Some((col, row)), false) = (v.post, v.z.is_nan()) {
            let eye = Eye {
                d: v.d,
                w: w + opts.height,
                tail: v.surface && v.piece,
                clip: v.d - max,
            };
            stats.receivers += 1;
            let (area, seen) = if p.d.is_empty() {
                (0.0, 0)
            } else {
                match opts.method {
                    Method::Naive => {
                        let (a, s, steps) = area_by_walking(p, &eye);
                        stats.naive_steps += steps;
                        (a, s)
                    }
                    Method::HullTree { .. } => {
                        stats.eye_tests += tree.eye_horizons(
                            [eye.d, eye.w],
                            &mut scratch.horizons,
                            &mut scratch.stack,
                        );
                        stats.horizons += scratch.horizons.len() as u64;
                        area_from_horizons(p, &eye, &scratch.horizons)
                    }
                }
            };
            stats.visible_vertices += seen;
            out[row * terrain.width + col] += share * area;
        }
        if v.surface {
            p.push(v.d, w, v.piece);
            if opts.method != Method::Naive {
                tree.push(v.d, w);
            }
        }
    }
    stats.iterations = tree.iterations;
    stats.root_children = tree.root_children;
    stats.replacements = tree.replacements;
    stats.zone_visits = tree.zone_visits;
    stats
}

/// The total viewshed of `terrain`: visible area in square metres at every
/// post (NaN for nodata), and the counts; `done` is called after each
/// direction.
pub fn total_viewshed(
    terrain: &Terrain,
    opts: &TotalOptions,
    done: &(dyn Fn() + Sync),
) -> (Vec<f64>, TotalStats) {
    let dirs = directions(terrain, opts.directions);
    let size = terrain.width * terrain.height;
    let per_worker = dirs.len().div_ceil(rayon::current_num_threads()).max(1);
    let (mut area, stats) = dirs
        .par_iter()
        .with_min_len(per_worker)
        .fold(
            || (vec![0.0; size], TotalStats::default(), Scratch::default()),
            |(mut out, mut stats, mut scratch), (dir, share)| {
                let stencil = Stencil::new(dir.step);
                let lengths = step_lengths(
                    dir.step,
                    terrain.height,
                    (terrain.dx, terrain.dy),
                    terrain.row_scale,
                );
                for far in line_starts(terrain, dir.step) {
                    stats += sweep_line(
                        terrain,
                        (&stencil, &lengths),
                        far,
                        (opts, *share),
                        &mut scratch,
                        &mut out,
                    );
                }
                done();
                (out, stats, scratch)
            },
        )
        .map(|(out, stats, _)| (out, stats))
        .reduce(
            || (vec![0.0; size], TotalStats::default()),
            |(mut a, mut sa), (b, sb)| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                sa += sb;
                (a, sa)
            },
        );
    for (v, z) in area.iter_mut().zip(terrain.z) {
        if z.is_nan() {
            *v = f64::NAN;
        }
    }
    (area, stats)
}
