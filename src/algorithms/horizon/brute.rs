//! Brute-force references, one post at a time, written independently of
//! the fast algorithms so that the tests compare two derivations of each
//! definition: the line horizon from the surface of
//! `terrabake_format::surface` sampled at every crossing of the line with
//! the grid, and the sector horizon from every post of the DEM, `O(n)` per
//! post.

use terrabake_format::features::SightLine;
use terrabake_format::surface::Cell;

use crate::algorithms::horizon::sector::{NarrowStencil, SectorFrame};
use crate::terrain::{MaxBlocks, Terrain};

/// Surface height at fractional post coordinates `(col, row)` (row grows
/// south), from any cell with a surface that contains the point.
fn surface_at(t: &Terrain, col: f64, row: f64) -> Option<f64> {
    // `v.floor() as i64` without a call: the baseline x86-64 target has no
    // rounding instruction, and libm's `floor` was a twelfth of a plan.
    let floor = |v: f64| {
        let t = v as i64;
        t - i64::from(v < t as f64)
    };
    // The cells whose closed square holds v: one, or two on a grid line.
    let around = |v: f64| {
        let (lo, hi) = (floor(v - 1e-9), floor(v + 1e-9));
        [lo, hi].into_iter().take(if lo == hi { 1 } else { 2 })
    };
    for c in around(col) {
        for r in around(row) {
            if t.cell_exists(c, r) {
                let (cu, ru) = (c as usize, r as usize);
                let cell = Cell {
                    nw: t.at(cu, ru),
                    ne: t.at(cu + 1, ru),
                    sw: t.at(cu, ru + 1),
                    se: t.at(cu + 1, ru + 1),
                };
                return Some(cell.height(col - c as f64, (r + 1) as f64 - row));
            }
        }
    }
    None
}

/// The line horizon of post `(col, row)` along grid step `(a, b)` from the
/// crossings no farther than `max_distance` metres, degrees (NaN for
/// nodata, -90 when no surface lies ahead).
pub fn line_horizon(
    t: &Terrain,
    post: (usize, usize),
    step: (i64, i64),
    max_distance: Option<f64>,
) -> f32 {
    if t.at(post.0, post.1).is_nan() {
        return f32::NAN;
    }
    horizon_within(&line_horizon_records(t, post, step), max_distance)
}

/// The records of a sight line no farther than `max_distance` metres
/// (all of them without one): the last is the horizon within it.
pub(crate) fn records_within(
    records: &[HorizonRecord],
    max_distance: Option<f64>,
) -> &[HorizonRecord] {
    // Records are nearest first: a binary search finds the last within.
    let within = max_distance.map_or(records.len(), |m| {
        records.partition_point(|r| r.distance <= m)
    });
    &records[..within]
}

/// The horizon of a sight line with these records from the terrain no
/// farther than `max_distance` metres: the last record within it, degrees
/// (-90 when none).
pub(crate) fn horizon_within(records: &[HorizonRecord], max_distance: Option<f64>) -> f32 {
    records_within(records, max_distance)
        .last()
        .map_or(-90.0, |r| r.angle)
}

/// A new highest elevation angle along a sight line, and how far out it
/// was met: the horizon of a sight line cut at any distance `D` is the
/// last record no farther than `D` (the planner's distance limit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HorizonRecord {
    /// Metres from the post (horizontal), as the bounded stage measures it.
    pub distance: f64,
    /// Degrees.
    pub angle: f32,
}

/// Every record of post `(col, row)`'s sight line along grid step `(a, b)`,
/// nearest first (angles strictly increasing; empty for nodata or when no
/// surface lies ahead). The last one is the exact, unbounded line horizon.
pub fn line_horizon_records(
    t: &Terrain,
    post: (usize, usize),
    step: (i64, i64),
) -> Vec<HorizonRecord> {
    let (a, b) = step;
    sight_line_records(t, post, (a as f64, b as f64), None).0
}

/// [`line_horizon_records`] with the terrain's heights bounded by
/// `heights` (of `t`): the same records, found sooner. From a post at
/// height `z_p`, nothing at distance `d` or farther rises above `(z_max -
/// z_p) / d - c d` (which falls as `d` grows), so the walk stops where that
/// bound falls below the horizon so far (by a margin of 1e-9 in slope, far
/// above the rounding of either side): no farther crossing can set a
/// record. Within a block of [`BlockMax`] the same bound with the block's
/// highest post (over the distances the line spends in it) lets the walk
/// step over the whole block. The planner's pilot and `check`'s reference
/// walk them so (docs/BENCHMARKS.md).
pub(crate) fn line_horizon_records_below(
    t: &Terrain,
    post: (usize, usize),
    (a, b): (i64, i64),
    heights: &BlockMax,
) -> Vec<HorizonRecord> {
    sight_line_records(t, post, (a as f64, b as f64), Some(heights)).0
}

/// [`line_horizon_records_below`] and how many crossings it looked at
/// (the surface's height there), for the tests that count what the bounds
/// save.
pub fn line_horizon_records_walked(
    t: &Terrain,
    post: (usize, usize),
    (a, b): (i64, i64),
    heights: &BlockMax,
) -> (Vec<HorizonRecord>, usize) {
    sight_line_records(t, post, (a as f64, b as f64), Some(heights))
}

/// The highest post of a terrain in blocks of a few sizes ([`MaxBlocks`],
/// their edges' posts included), and the highest of all: to step a sight
/// line over the blocks it crosses too low to set a record.
#[derive(Debug, Clone)]
pub struct BlockMax {
    /// The terrain's posts across and down.
    posts: (usize, usize),
    /// Coarsest first.
    levels: Vec<MaxBlocks>,
    /// The highest post of the terrain.
    pub top: f64,
}

impl BlockMax {
    /// Blocks of each of `sizes` cells (coarsest first) over the whole of
    /// `t` (not a window).
    pub fn of(t: &Terrain, sizes: &[usize]) -> Self {
        assert!(t.row0 == 0 && t.z.len() == t.width * t.height);
        let levels = sizes
            .iter()
            .map(|&size| MaxBlocks::of(t, size, 0))
            .collect();
        let top =
            t.z.iter()
                .filter(|v| !v.is_nan())
                .fold(f64::NEG_INFINITY, |m, &v| m.max(f64::from(v)));
        Self {
            posts: (t.width, t.height),
            levels,
            top,
        }
    }

    /// Whether these are blocks of a terrain of `t`'s size.
    pub fn fits(&self, t: &Terrain) -> bool {
        self.posts == (t.width, t.height)
    }

    /// The memory the blocks hold, bytes.
    pub fn bytes(&self) -> usize {
        self.levels.iter().map(MaxBlocks::bytes).sum()
    }
}

/// The block of `blocks` the line `p + s (a, b)` is in just past `s`: its
/// highest post and the `s` at which the line leaves it (`None` where
/// rounding leaves no room to pass).
fn ahead(
    blocks: &MaxBlocks,
    (pc, pr): (f64, f64),
    (a, b): (f64, f64),
    s: f64,
) -> Option<(f64, f64)> {
    let size = blocks.size() as f64;
    // Nudged forwards, so that a point on a block's edge falls into the
    // block the line goes on through.
    let (bc, br) = blocks.block(pc + a * s + a * 1e-7, pr + b * s + b * 1e-7);
    let leave = |p: f64, d: f64, k: usize| match d.partial_cmp(&0.0) {
        Some(std::cmp::Ordering::Greater) => ((k + 1) as f64 * size - p) / d,
        Some(std::cmp::Ordering::Less) => (k as f64 * size - p) / d,
        _ => f64::INFINITY,
    };
    let exit = leave(pc, a, bc).min(leave(pr, b, br));
    (exit > s).then(|| (blocks.max((bc, br)), exit))
}

/// [`line_horizon_records`] of the sight line from post `(col, row)` at
/// compass `azimuth` (degrees), any azimuth: the line straight on the grid
/// whose direction on the ground is `azimuth` at the post (on a geographic
/// grid, with the east-west spacing of the post's row). `terrabake profile`.
pub fn ray_horizon_records(
    t: &Terrain,
    (col, row): (usize, usize),
    azimuth: f64,
) -> Vec<HorizonRecord> {
    // The ground direction at the post's row: its own east-west spacing.
    let spacing = (t.dx * t.row_scale.at_half(2 * row as i64), t.dy);
    let line = SightLine::new((col as u32, row as u32), 0.0, azimuth, spacing);
    sight_line_records(t, (col, row), line.direction(), None).0
}

/// One family of a line's crossings with the grid (`col = i`, `row = j`
/// or `col + row = k`: where `p + s d` is an integer), ascending in `s`
/// within `(0, s_max]`.
struct Crossings {
    k: i64,
    last: i64,
    by: i64,
    p: f64,
    d: f64,
    s_max: f64,
}

impl Crossings {
    fn new(p: f64, d: f64, s_max: f64) -> Self {
        let (lo, hi) = if d > 0.0 {
            (p, p + d * s_max)
        } else {
            (p + d * s_max, p)
        };
        // A margin for the exit point, which rounding may put a hair off.
        let (lo, hi) = ((lo - 1e-6).ceil() as i64, (hi + 1e-6).floor() as i64);
        let (k, last, by) = match d.partial_cmp(&0.0) {
            Some(std::cmp::Ordering::Greater) => (lo, hi, 1),
            Some(std::cmp::Ordering::Less) => (hi, lo, -1),
            // Parallel to the family's lines: none met (an empty run).
            _ => (1, 0, 1),
        };
        Self {
            k,
            last,
            by,
            p,
            d,
            s_max,
        }
    }

    /// Moves on to the crossings from about `s` on (one before it may
    /// stay: walking a crossing more is always safe).
    fn skip_to(&mut self, s: f64) {
        let at = self.p + self.d * s;
        self.k = match self.by {
            1 => self.k.max(at.ceil() as i64 - 1),
            _ => self.k.min(at.floor() as i64 + 1),
        };
    }
}

impl Iterator for Crossings {
    type Item = f64;

    fn next(&mut self) -> Option<f64> {
        while (self.last - self.k) * self.by >= 0 {
            let s = (self.k as f64 - self.p) / self.d;
            self.k += self.by;
            if s > 0.0 && s <= self.s_max * (1.0 + 1e-12) {
                return Some(s.min(self.s_max));
            }
        }
        None
    }
}

/// The three families of a line's crossings merged in order of `s`.
struct Merged {
    families: [Crossings; 3],
    heads: [Option<f64>; 3],
}

impl Merged {
    fn new(mut families: [Crossings; 3]) -> Self {
        let heads = families.each_mut().map(|f| f.next());
        Self { families, heads }
    }

    /// [`Crossings::skip_to`] in every family.
    fn skip_to(&mut self, s: f64) {
        for (f, head) in self.families.iter_mut().zip(&mut self.heads) {
            if head.is_some_and(|h| h < s) {
                f.skip_to(s);
                *head = f.next();
            }
        }
    }
}

impl Iterator for Merged {
    type Item = f64;

    fn next(&mut self) -> Option<f64> {
        let heads = &self.heads;
        let i = (0..3)
            .filter(|&i| heads[i].is_some())
            .min_by(|&i, &j| heads[i].unwrap().total_cmp(&heads[j].unwrap()))?;
        let s = self.heads[i];
        self.heads[i] = self.families[i].next();
        s
    }
}

/// The records of the line `(col, row) + s (a, b)`, `s > 0` (grid units),
/// walked to the DEM's edge, or with `heights` no farther than a record
/// can be set and over no block too low for one
/// ([`line_horizon_records_below`]), and how many crossings it looked at.
fn sight_line_records(
    t: &Terrain,
    (col, row): (usize, usize),
    (a, b): (f64, f64),
    heights: Option<&BlockMax>,
) -> (Vec<HorizonRecord>, usize) {
    let zp = t.at(col, row);
    if zp.is_nan() {
        return (Vec::new(), 0);
    }
    let (pc, pr) = (col as f64, row as f64);
    // Largest s that keeps col + a s in [0, W-1] and row + b s in [0, H-1].
    let exit = |p: f64, d: f64, last: f64| {
        if d > 0.0 {
            (last - p) / d
        } else if d < 0.0 {
            p / -d
        } else {
            f64::INFINITY
        }
    };
    let s_max = exit(pc, a, (t.width - 1) as f64).min(exit(pr, b, (t.height - 1) as f64));
    // Every s where p + s (a, b) meets col = i, row = j or col + row = k:
    // three runs, merged as the walk goes (it may stop long before the
    // edge).
    let mut crossings =
        Merged::new([(pc, a), (pr, b), (pc + pr, a + b)].map(|(p, d)| Crossings::new(p, d, s_max)));
    // Metres from the post to parameter s: whole steps, each with the
    // east-west spacing at its middle row, then the fraction of the next.
    let step_len = |k: f64| {
        (a * t.dx
            * t.row_scale
                .at_half((2.0 * pr + (2.0 * k + 1.0) * b).round() as i64))
        .hypot(b * t.dy)
    };
    // Crossings in order, so that the whole steps' metres are summed once
    // along the line rather than again for every crossing.
    let (mut whole_steps, mut metres, mut this_step) = (0i64, 0.0, step_len(0.0));
    let mut distance = |s: f64| {
        while ((whole_steps + 1) as f64) <= s {
            metres += this_step;
            whole_steps += 1;
            this_step = step_len(whole_steps as f64);
        }
        metres + (s - whole_steps as f64) * this_step
    };
    let (mut best, mut records) = (f64::NEG_INFINITY, Vec::new());
    let zp64 = f64::from(zp);
    let rise = heights.map_or(f64::INFINITY, |h| h.top - zp64);
    // The longest a unit of `s` can be, metres, for the far end of a block.
    let longest = (a * t.dx * t.row_scale.max()).hypot(b * t.dy) * (1.0 + 1e-12);
    // The block the walk last looked at: crossings before its exit are
    // walked (it could hold a record).
    let (mut block_exit, mut walked) = (0.0, 0);
    while let Some(s) = crossings.next() {
        let d = distance(s);
        // (rise - c d^2) / d < best - margin, without the division.
        if rise - t.curvature * d * d < (best - 1e-9) * d {
            break;
        }
        // A block entered: over the distances `d..far` it spans, nothing
        // in it rises above its highest post's bound; below the horizon so
        // far (the same margin), the walk goes on past it. The largest
        // block first; where the finest cannot be passed, its crossings
        // are walked.
        if let Some(heights) = heights.filter(|_| s >= block_exit) {
            let passed = heights.levels.iter().find_map(|blocks| {
                let (high, exit) = ahead(blocks, (pc, pr), (a, b), s)?;
                block_exit = exit;
                let far = d + (exit - s) * longest;
                let bound = ((high - zp64) / d).max((high - zp64) / far)
                    + (-t.curvature * d).max(-t.curvature * far);
                (bound < best - 1e-9).then_some(exit)
            });
            if let Some(exit) = passed {
                crossings.skip_to(exit);
                continue;
            }
        }
        walked += 1;
        if let Some(z) = surface_at(t, pc + a * s, pr + b * s) {
            let slope = (z - t.curvature * d * d - zp64) / d;
            if slope > best {
                best = slope;
                let angle = slope.atan().to_degrees() as f32;
                // Slopes that round to one f32 angle are one record.
                match records.last_mut() {
                    Some(HorizonRecord { angle: last, .. }) if *last == angle => {}
                    _ => records.push(HorizonRecord { distance: d, angle }),
                }
            }
        }
    }
    (records, walked)
}

/// Stewart's sector horizon of post `(col, row)` in the sector of `frame`,
/// from every post of the DEM (plus the IV-E posts of `narrow`) no farther
/// than `max_distance` metres, degrees.
pub fn sector_horizon(
    t: &Terrain,
    (col, row): (usize, usize),
    frame: &SectorFrame,
    narrow: Option<&NarrowStencil>,
    max_distance: Option<f64>,
) -> f32 {
    if t.at(col, row).is_nan() {
        return f32::NAN;
    }
    sector_horizon_record(t, (col, row), frame, narrow, max_distance).map_or(-90.0, |r| r.angle)
}

/// [`sector_horizon`] and the horizontal distance to the post that sets
/// it (the first of equally steep posts, row by row); `None` for nodata
/// and where no post lies in the wedge.
pub fn sector_horizon_record(
    t: &Terrain,
    (col, row): (usize, usize),
    frame: &SectorFrame,
    narrow: Option<&NarrowStencil>,
    max_distance: Option<f64>,
) -> Option<HorizonRecord> {
    let zp = t.at(col, row);
    if zp.is_nan() {
        return None;
    }
    let pp = t.key_position(col, row);
    let kp = frame.keys(pp);
    let tp = frame.along(pp);
    let c = t.curvature;
    let distance = |qc: usize, qr: usize| t.key_distance(pp, t.key_position(qc, qr));
    let near = |qc: usize, qr: usize| max_distance.is_none_or(|m| distance(qc, qr) <= m);
    let slope = |qc: usize, qr: usize| {
        let tq = frame.along(t.key_position(qc, qr));
        let dz = f64::from(t.at(qc, qr)) - c * (tq - tp) * (tq - tp) - f64::from(zp);
        dz / (tq - tp)
    };
    // The steepest slope and the post it goes to.
    let mut best: Option<(f64, (usize, usize))> = None;
    let mut consider = |qc: usize, qr: usize| {
        let s = slope(qc, qr);
        if best.is_none_or(|(b, _)| s > b) {
            best = Some((s, (qc, qr)));
        }
    };
    for qr in 0..t.height {
        for qc in 0..t.width {
            if !t.at(qc, qr).is_nan()
                && SectorFrame::contains(&kp, &frame.keys(t.key_position(qc, qr)))
                && near(qc, qr)
            {
                consider(qc, qr);
            }
        }
    }
    for &(dc, dr) in narrow.map_or(&[][..], |n| &n.offsets[..]) {
        let (qc, qr) = (col as i64 + dc, row as i64 + dr);
        if t.contains(qc, qr)
            && !t.at(qc as usize, qr as usize).is_nan()
            && frame.along(t.key_position(qc as usize, qr as usize)) > tp
            && near(qc as usize, qr as usize)
        {
            consider(qc as usize, qr as usize);
        }
    }
    best.map(|(s, (qc, qr))| HorizonRecord {
        distance: distance(qc, qr),
        angle: s.atan().to_degrees() as f32,
    })
}
