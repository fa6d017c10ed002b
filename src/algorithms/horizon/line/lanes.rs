//! Line sweeps in SIMD lanes: the lines of one direction stepped together
//! row by row, eight neighbouring lines to an AVX-512 vector (four to an
//! AVX2 one), with masked pops (issue #17, item 1). Timonen (2013, sec. 4)
//! sweeps one line's hull at a time, as our scalar sweep does; this is the
//! same sweep turned a quarter: every line at once, one post each per row.
//!
//! The scalar sweep ([`crate::algorithms::horizon::line::BandedSweep`] without lanes) walks a line
//! through a band of rows before it starts the next, so every hull push
//! waits on a pop loop whose exit is a data-dependent branch (about 15 ns a
//! vertex). Here, on each row, every line with a post there receives it,
//! and the posts of eight neighbouring columns are eight different lines (a
//! step with `b != 0` never joins two posts of one row). Their crossings
//! load with plain vector loads (a stencil's offsets are the same for every
//! post), and a pop is one masked compare over eight hulls, repeated while
//! any lane still pops.
//!
//! **State.** A line is known by its key `col - s * (row div |b|)` (`s = a
//! sign(b)`) within its row class `row mod |b|`: the key stays the same
//! along the line and counts up along a row, so eight lanes load their
//! lines' `t` and hull lengths with one load. Keys are taken modulo
//! `width + |s|`, more than the lines alive in a class at once, so the state is
//! `O(width |b|)` whatever the height, and the sweep goes a band of rows at
//! a time out of core like the scalar one. Hulls are stacks of up to 128
//! vertices (fewer where the memory given, at most [`MAX_BYTES`] a
//! direction, would not hold that many for every line; never fewer than
//! 32, or the direction takes the scalar sweep), stored depth-major
//! (`[depth][line]`: the tops of neighbouring lines share cache lines). A
//! lane holds its top vertices in registers (four in AVX-512, three in
//! AVX2), the third gathered while its pops go on, so that a pop's next
//! compare never waits on memory. With four, a push's first pop takes the
//! fourth up instead of gathering, and a push that follows a pop has room
//! without sending one down (in AVX-512 a gather or scatter whose lanes
//! are all masked off costs about what a full one does, so each is skipped
//! where no lane needs it): 1.03x-1.06x at 36 and 64 directions, nothing
//! at 16, where the pops are few; five or six held were slower (spilled
//! registers). Between rows the held vertices wait in arrays indexed by
//! line, not in the storage, so that eight neighbouring lines load theirs
//! with plain vector loads where a row starts (six gathers before, a sixth
//! of the sweep); a push sends the lowest held vertex down to the storage
//! instead of the new top. A hull's length is kept only as its top's
//! index in the storage (`top`, which every pop and push moves anyway),
//! compared with the index a hull of one, two or three vertices would
//! have (`avx512::floors`): one vector operation fewer a pop and a push
//! (1.00-1.04x in AVX-512, 1.03-1.06x in AVX2, docs/BENCHMARKS.md), and
//! between rows the lines keep it as it is ([`Lines`]'s `top`), loaded
//! and stored with the heads, never turned into a length and back.
//!
//! **Two vectors at once.** A pop loop is a chain of dependent steps (the
//! compare, the moves, the refill gathered for the compare after next), so
//! a kernel steps [`GROUPS`] vectors of neighbouring lines together and
//! runs their pop loops as one: each round compares both, and one vector's
//! compares go on while the other's gathers are in flight. The loop runs
//! while either still pops, so lanes wait more often; on the UTM tile two
//! vectors are 1.10x faster than one (16 directions) and three or four
//! slower, their registers spilling.
//!
//! **The same bits.** Each line does the scalar sweep's arithmetic in the
//! scalar sweep's order (no fused multiply-adds; the arctangent is
//! [`crate::algorithms::horizon::line::atan_deg`] with its branches as blends), so the angles are the
//! scalar sweep's bits, which `tests/horizons.rs` checks on random and real
//! terrains in every direction, in one band and in many. Three kinds of
//! post go through the scalar sweep: each line's far post (its crossings
//! may leave the DEM), the posts near a row's ends whose far neighbour is
//! off the DEM (the same), and every post of a line whose hull could outgrow
//! the depth in its next step (the line leaves the lanes for good).
//!
//! **When.** AVX-512 F, VL and DQ (and popcnt), else AVX2 (and popcnt),
//! detected at run time ([`crate::plumbing::simd::level`]; the AVX2 kernel is the AVX-512 one in
//! four lanes, its masks vectors, its scatter one lane at a time); without
//! nodata and without distances; for steps with `b != 0` and of at most
//! [`HEADROOM`] vertices fewer than the depth. An east or west step has one line per row, so its lanes are
//! rows instead ([`Rows`]: neighbouring rows stepped column by column, the
//! same hulls and pops, a whole row's depth of storage). Anything else
//! takes the scalar sweep, which gives the same bits.

use super::{Lane, Out, Stencil, Sweep, SweepStats};
use crate::plumbing::simd::Level;

/// Hull vertices a lane keeps at most, and at least: fewer than 128 where
/// the memory given would not hold that many for every line, and no lanes
/// where it would not hold 32.
pub const MAX_DEPTH: usize = 128;
pub const MIN_DEPTH: usize = 32;

/// Hull vertices a lane keeps free beyond a step's: a step of more than
/// `depth - HEADROOM` vertices takes the scalar sweep. A line whose hull
/// could outgrow the depth in its next step leaves the lanes (for the
/// scalar sweep, the same bits), so a long step in lanes costs only those
/// lines, and steps of 20 to 120 vertices (directions within 0.1 degree of
/// nominal) stay in lanes.
pub const HEADROOM: usize = 8;

/// The most the lanes' hulls of one direction take (bytes) unless told
/// less ([`crate::algorithms::horizon::line::BandedSweep::with_lane_memory`]: the stage gives them a
/// share of `--max-memory`).
pub const MAX_BYTES: usize = 32 << 20;

/// Hull vertices a lane of `level` holds in registers, and between rows
/// in the head arrays (module docs, "State").
fn held(level: Level) -> usize {
    if level == Level::Avx512 {
        4
    } else {
        3
    }
}

/// [`Lines::top`] of a line that left the lanes: below every hull's, so
/// that no "holds at least" compare takes it.
const SPILLED: i64 = i64::MIN;

/// Vectors of lines a kernel steps together (module docs, "Two vectors at
/// once").
const GROUPS: usize = 2;

/// The state of every line of one direction, indexed as the module docs
/// say.
#[derive(Debug)]
pub(super) struct Lines {
    step: (i64, i64),
    width: usize,
    /// `|b|`: rows between a line's posts.
    q: usize,
    /// `a sign(b)`: how far a line's key moves per `|b|` rows.
    s: i64,
    /// Keys are taken modulo this.
    modulus: usize,
    /// Lines in all: `q * modulus`.
    count: usize,
    /// Hull vertices a lane keeps.
    depth: usize,
    /// What sweeps them.
    level: Level,
    /// `t` of each line's last post.
    t: Vec<f64>,
    /// Each line's hull as the index its top vertex has in the storage,
    /// `(len - 1) * count + line` for a hull of `len` vertices, as the
    /// kernels keep it in registers ([`Self::top_of`]); [`SPILLED`] for a
    /// line swept by the scalar sweep.
    top: Vec<i64>,
    /// The top three vertices of each hull, `[k * count + line]` for the
    /// vertex `k` below the top: eight neighbouring lines' load with one
    /// vector load where the kernel starts a row.
    head_t: Vec<f64>,
    head_w: Vec<f64>,
    /// The vertices below the top three, `[depth * count + line]`.
    hull_t: Vec<f64>,
    hull_w: Vec<f64>,
    /// Lines that left the lanes, carried from band to band.
    spilled: Vec<Lane>,
}

impl Lines {
    /// The lanes for lines of `stencil`'s step (`b != 0`) over a DEM
    /// `width` posts wide with hulls of at most `bytes`, swept in vector
    /// code of `level`, or `None` where the step is longer than the depth
    /// `bytes` allows, less [`HEADROOM`].
    fn new(stencil: &Stencil, width: usize, bytes: usize, level: Level) -> Option<Self> {
        let step = stencil.step;
        let (q, s, modulus, count) = Self::lines_of(step, width);
        let depth = Self::depth(stencil, count, bytes)?;
        let heads = held(level);
        Some(Self {
            step,
            width,
            q,
            s,
            modulus,
            count,
            depth,
            level,
            t: vec![0.0; count],
            // Every hull empty: `top_of(i, 0)`.
            top: (0..count as i64).map(|i| i - count as i64).collect(),
            head_t: vec![0.0; heads * count],
            head_w: vec![0.0; heads * count],
            hull_t: vec![0.0; depth * count],
            hull_w: vec![0.0; depth * count],
            spilled: Vec::new(),
        })
    }

    /// Memory that gives these lanes their depth ([`Self::new`]).
    fn bytes(&self) -> usize {
        self.depth * 2 * 8 * self.count
    }

    /// `(|b|, a sign(b), modulus, count)` of `step = (a, b)`'s lines over
    /// a DEM `width` posts wide, as the fields say.
    fn lines_of(step: (i64, i64), width: usize) -> (usize, i64, usize, usize) {
        let q = step.1.unsigned_abs() as usize;
        let s = step.0 * step.1.signum();
        let modulus = width + s.unsigned_abs() as usize;
        (q, s, modulus, q * modulus)
    }

    /// Hull vertices a lane of `count` lines keeps within `bytes`, or
    /// `None` where that is too few for `stencil`'s steps.
    fn depth(stencil: &Stencil, count: usize, bytes: usize) -> Option<usize> {
        let depth = (bytes.min(MAX_BYTES) / (2 * 8 * count)).min(MAX_DEPTH);
        (depth >= MIN_DEPTH && stencil.len() + HEADROOM <= depth).then_some(depth)
    }

    /// The most bytes [`Self::new`]'s arrays take: each line's `t`, `top`
    /// and held vertices, and the hulls below them at their full depth.
    fn most_bytes(stencil: &Stencil, width: usize, bytes: usize, level: Level) -> Option<usize> {
        let count = Self::lines_of(stencil.step, width).3;
        let depth = Self::depth(stencil, count, bytes)?;
        Some(count * 8 * (2 + 2 * held(level) + 2 * depth))
    }

    /// The `top` of line `i` with a hull of `len` vertices.
    fn top_of(&self, i: usize, len: usize) -> i64 {
        (len as i64 - 1) * self.count as i64 + i as i64
    }

    /// Vertices on line `i`'s hull (a line in the lanes).
    fn hull_len(&self, i: usize) -> usize {
        ((self.top[i] - i as i64) / self.count as i64 + 1) as usize
    }

    /// Where vertex `d` of line `i`'s hull is kept: in the head (`true`) or
    /// the storage below it, and its index.
    fn slot(&self, i: usize, d: usize) -> (bool, usize) {
        match self.hull_len(i) - 1 - d {
            k if k < held(self.level) => (true, k * self.count + i),
            _ => (false, d * self.count + i),
        }
    }

    fn vertex(&self, i: usize, d: usize) -> [f64; 2] {
        match self.slot(i, d) {
            (true, j) => [self.head_t[j], self.head_w[j]],
            (false, j) => [self.hull_t[j], self.hull_w[j]],
        }
    }

    fn set_vertex(&mut self, i: usize, d: usize, [t, w]: [f64; 2]) {
        let (head, j) = self.slot(i, d);
        let (ts, ws) = if head {
            (&mut self.head_t, &mut self.head_w)
        } else {
            (&mut self.hull_t, &mut self.hull_w)
        };
        (ts[j], ws[j]) = (t, w);
    }

    /// The index of the line through post `(col, row)`.
    fn index(&self, col: usize, row: usize) -> usize {
        let (class, j) = (row % self.q, (row / self.q) as i64);
        class * self.modulus + (col as i64 - self.s * j).rem_euclid(self.modulus as i64) as usize
    }

    /// Takes line `i`, whose last post is `(col, row)`, out of the lanes and
    /// sweeps it through `band` with the scalar sweep.
    fn spill(
        &mut self,
        i: usize,
        lane: Lane,
        sweep: &Sweep,
        band: &std::ops::Range<usize>,
        out: &mut Out,
        stats: &mut SweepStats,
    ) {
        self.top[i] = SPILLED;
        stats.spilled += 1;
        let mut lane = lane;
        if sweep.run(&mut lane, band, out, stats) {
            self.spilled.push(lane);
        }
    }

    /// Sweeps output rows `band` (the next in the sweep's order) of
    /// `sweep`'s window into `out`: as the scalar sweep, the same bits.
    fn sweep(
        &mut self,
        sweep: &Sweep,
        band: std::ops::Range<usize>,
        out: &mut Out,
        stats: &mut SweepStats,
    ) {
        let mut spilled = std::mem::take(&mut self.spilled);
        spilled.retain_mut(|lane| sweep.run(lane, &band, out, stats));
        self.spilled = spilled;
        let terrain = sweep.placed.t;
        let n = sweep.placed.stencil.len();
        let kernel = Kernel::new(sweep);
        let (a, b) = self.step;
        let (w, h) = (self.width as i64, terrain.height as i64);
        // Columns whose far neighbour `col + a` is on the DEM.
        let lo = (-a).clamp(0, w);
        let cols = lo as usize..(w - a).clamp(lo, w) as usize;
        let rows: Vec<usize> = if b < 0 {
            band.clone().collect()
        } else {
            band.clone().rev().collect()
        };
        for row in rows {
            let far_row = !(0..h).contains(&(row as i64 + b));
            let edges = if far_row {
                [0..self.width, 0..0]
            } else {
                [0..cols.start, cols.end..self.width]
            };
            for col in edges.into_iter().flatten() {
                let lane = sweep.start((col as i64, row as i64), out, stats);
                let i = self.index(col, row);
                if lane.hull.len() + n > self.depth {
                    self.spill(i, lane, sweep, &band, out, stats);
                    continue;
                }
                self.t[i] = lane.t;
                self.top[i] = self.top_of(i, lane.hull.len());
                for (d, &v) in lane.hull.iter().enumerate() {
                    self.set_vertex(i, d, v);
                }
            }
            if far_row {
                continue;
            }
            // Lines whose hull could outgrow the depth in this step.
            for (col, i) in cols.clone().zip(self.indices(cols.clone(), row)) {
                if self.top[i] > self.top_of(i, self.depth - n) {
                    let hull = (0..self.hull_len(i)).map(|d| self.vertex(i, d)).collect();
                    let (col, row) = (col as i64 + a, row as i64 + b);
                    let lane = Lane::new(hull, (col, row), self.t[i]);
                    self.spill(i, lane, sweep, &band, out, stats);
                }
            }
            // Keys are consecutive along the row but wrap once at most.
            let split = cols.start + self.unwrapped(cols.clone(), row);
            for part in [cols.start..split, split..cols.end] {
                if part.is_empty() {
                    continue;
                }
                // SAFETY: `new` took a vector level the CPU runs; a step
                // from `part` stays on the DEM, whose rows the window holds.
                #[cfg(target_arch = "x86_64")]
                match self.level {
                    // SAFETY: as above, for AVX-512.
                    Level::Avx512 => unsafe {
                        kernel.row_avx512(self, terrain, row, part, out, stats)
                    },
                    // SAFETY: as above, for AVX2.
                    Level::Avx2 => unsafe { kernel.row_avx2(self, terrain, row, part, out, stats) },
                    Level::Scalar => unreachable!("`Lanes::new` makes no lanes for scalar code"),
                }
            }
        }
    }

    /// The indices of the lines through posts `cols` of `row`, in order.
    fn indices(
        &self,
        cols: std::ops::Range<usize>,
        row: usize,
    ) -> impl Iterator<Item = usize> + use<> {
        let first = self.index(cols.start, row);
        let class = first - first % self.modulus;
        let (m, mut key) = (self.modulus, first - class);
        cols.map(move |_| {
            let i = class + key;
            key = if key + 1 == m { 0 } else { key + 1 };
            i
        })
    }

    /// How many columns of `cols` on `row`, from the first, have
    /// consecutive indices (before the key wraps).
    fn unwrapped(&self, cols: std::ops::Range<usize>, row: usize) -> usize {
        let first = self.index(cols.start, row) % self.modulus;
        (self.modulus - first).min(cols.len())
    }
}

/// The SIMD lanes of one direction's sweep: its lines, or for an
/// east-west step its rows.
#[derive(Debug)]
pub(super) enum Lanes {
    Lines(Lines),
    Rows(Rows),
}

impl Lanes {
    /// The lanes for `stencil`'s step over a DEM `width` posts wide with
    /// hulls of at most `bytes`, in vector code of `level`, or `None` where
    /// they do not apply (scalar code, a level the CPU does not run, or
    /// hulls that `bytes` cannot hold).
    pub(super) fn new(stencil: &Stencil, width: usize, bytes: usize, level: Level) -> Option<Self> {
        if level == Level::Scalar || level > crate::plumbing::simd::level() {
            None
        } else if stencil.step.1 == 0 {
            Rows::new(width, bytes, level).map(Self::Rows)
        } else {
            Lines::new(stencil, width, bytes, level).map(Self::Lines)
        }
    }

    /// The most bytes [`Self::new`] with the same arguments holds, or
    /// `None` where it makes no lanes; computed without making them.
    pub(super) fn most_bytes(
        stencil: &Stencil,
        width: usize,
        bytes: usize,
        level: Level,
    ) -> Option<usize> {
        if level == Level::Scalar || level > crate::plumbing::simd::level() {
            None
        } else if stencil.step.1 == 0 {
            Rows::vertices(width, bytes).map(|v| 2 * 8 * v)
        } else {
            Lines::most_bytes(stencil, width, bytes, level)
        }
    }

    /// Bytes these lanes' arrays take: what [`Self::most_bytes`] states.
    #[cfg(test)]
    pub(super) fn held_bytes(&self) -> usize {
        match self {
            Self::Lines(l) => {
                let f64s = [&l.t, &l.head_t, &l.head_w, &l.hull_t, &l.hull_w];
                8 * (l.top.len() + f64s.iter().map(|v| v.len()).sum::<usize>())
            }
            Self::Rows(r) => 8 * (r.hull_t.len() + r.hull_w.len()),
        }
    }

    /// What sweeps these lanes.
    pub(super) fn level(&self) -> Level {
        match self {
            Self::Lines(l) => l.level,
            Self::Rows(r) => r.level,
        }
    }

    /// Memory that gives these lanes their shape: [`Self::new`] with it
    /// makes the same lanes.
    pub(super) fn bytes(&self) -> usize {
        match self {
            Self::Lines(l) => l.bytes(),
            Self::Rows(r) => 8 * (r.hull_t.len() + r.hull_w.len()),
        }
    }

    /// Sweeps output rows `band` (the next in the sweep's order) of
    /// `sweep`'s window into `out`: as the scalar sweep, the same bits.
    pub(super) fn sweep(
        &mut self,
        sweep: &Sweep,
        band: std::ops::Range<usize>,
        out: &mut Out,
        stats: &mut SweepStats,
    ) {
        match self {
            Self::Lines(l) => l.sweep(sweep, band, out, stats),
            Self::Rows(r) => r.sweep(sweep, band, out, stats),
        }
    }
}

/// East-west lines (steps `(±1, 0)`): every row is one line, so the lanes
/// are rows instead, [`GROUPS`] vectors of neighbouring rows stepped
/// column by column from the far end, their posts gathered. A line never
/// leaves its row, so nothing is carried between bands, and a hull holds
/// at most a row's posts: the storage is `16 * width` bytes a lane, kept
/// from band to band (a vertex is stored before it is read).
#[derive(Debug)]
pub(super) struct Rows {
    level: Level,
    hull_t: Vec<f64>,
    hull_w: Vec<f64>,
}

impl Rows {
    /// Rows `width` posts wide in vector code of `level`, or `None` where
    /// a row's hulls would take more than `bytes`.
    fn new(width: usize, bytes: usize, level: Level) -> Option<Self> {
        Self::vertices(width, bytes).map(|vertices| Self {
            level,
            hull_t: vec![0.0; vertices],
            hull_w: vec![0.0; vertices],
        })
    }

    /// Hull vertices the rows' lanes store, or `None` where they would
    /// take more than `bytes`.
    fn vertices(width: usize, bytes: usize) -> Option<usize> {
        let vertices = GROUPS * 8 * width;
        (2 * 8 * vertices <= bytes.min(MAX_BYTES)).then_some(vertices)
    }

    fn sweep(
        &mut self,
        sweep: &Sweep,
        band: std::ops::Range<usize>,
        out: &mut Out,
        stats: &mut SweepStats,
    ) {
        let kernel = Kernel::new(sweep);
        let terrain = sweep.placed.t;
        let (hull_t, hull_w) = (&mut self.hull_t[..], &mut self.hull_w[..]);
        let east = sweep.placed.stencil.step.0 > 0;
        // SAFETY: `new` took a vector level the CPU runs; the band's rows
        // are in the window and in `out`, and the storage holds a row.
        #[cfg(target_arch = "x86_64")]
        match self.level {
            // SAFETY: as above, for AVX-512.
            Level::Avx512 => unsafe {
                kernel.rows_avx512(terrain, band, east, out, stats, hull_t, hull_w)
            },
            // SAFETY: as above, for AVX2.
            Level::Avx2 => unsafe {
                kernel.rows_avx2(terrain, band, east, out, stats, hull_t, hull_w)
            },
            Level::Scalar => unreachable!("`Lanes::new` makes no rows for scalar code"),
        }
    }
}

/// Whether this CPU runs the lanes ([`crate::plumbing::simd::level`]).
pub fn cpu_has_lanes() -> bool {
    crate::plumbing::simd::level() > Level::Scalar
}

/// A step's interior crossings as offsets into the heights, and what a row
/// needs of the sweep.
struct Kernel<'s> {
    /// Per crossing, far first: fraction of the step, the two posts'
    /// offsets from the step's near post, and the weight of the second.
    crossings: Vec<(f64, isize, isize, f64)>,
    curvature: f64,
    /// [`crate::algorithms::horizon::line::step_lengths`] of the direction.
    lengths: &'s [f64],
}

impl<'s> Kernel<'s> {
    fn new(sweep: &'s Sweep) -> Self {
        let w = sweep.placed.t.width as i64;
        let vertices = &sweep.placed.stencil.vertices;
        let crossings = vertices[..vertices.len() - 1]
            .iter()
            .rev()
            .map(|v| {
                let off = |(c, r): (i64, i64)| (c + r * w) as isize;
                (v.s, off(v.a), off(v.b), v.wb)
            })
            .collect();
        Self {
            crossings,
            curvature: sweep.placed.t.curvature,
            lengths: sweep.lengths,
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{Kernel, Lines, Out, SweepStats, GROUPS, SPILLED};
    use crate::terrain::Terrain;
    use std::arch::x86_64::*;

    /// Eight lanes' hulls: the top four vertices of each (the third
    /// gathered while the pops go on, off their critical path, where the
    /// fourth is not held), its length, the index its top would have in the
    /// depth-major storage, and the storage (which holds every vertex but
    /// those held). At rest (between a push and the next pop) a lane holds
    /// `min(len, 4)`; during its pops, `min(len, 3)` or more.
    struct Hulls {
        top_t: __m512d,
        top_w: __m512d,
        sec_t: __m512d,
        sec_w: __m512d,
        third_t: __m512d,
        third_w: __m512d,
        fourth_t: __m512d,
        fourth_w: __m512d,
        /// Lanes whose fourth vertex is held (else the storage has it, or
        /// the hull is shorter).
        full: __mmask8,
        /// `(len - 1) * count + line`: the hull's length `len` in the
        /// storage's terms.
        top: __m512i,
        /// `top` where `len` is 1, 2 and 3: `len >= k` is one compare of
        /// `top` with `floors[k - 1]`, and a pop or push moves `top` alone.
        floors: [__m512i; 3],
        /// Lines in all: one depth further in the storage.
        count: __m512i,
        /// Lanes that take part: on the row and not outgrown.
        active: __mmask8,
        hull_t: *mut f64,
        hull_w: *mut f64,
    }

    /// Eight lines of a row: their hulls, `t` at their new post, and where
    /// their posts are in the heights and the output.
    struct Group {
        hulls: Hulls,
        t: __m512d,
        on_row: __mmask8,
        /// The first line's index.
        i0: usize,
        near: isize,
        near_out: isize,
    }

    impl Kernel<'_> {
        /// Steps every line with a post on `row` in `cols` (each with its
        /// far neighbour on the DEM) by one post, [`GROUPS`] vectors of
        /// eight lines at a time whose pop loops run as one (module docs,
        /// "Two vectors at once").
        ///
        /// # Safety
        /// AVX-512 F, VL and DQ; every crossing of the steps from `cols`
        /// in `terrain`'s rows, `row` in `out`'s, and the lines' indices
        /// consecutive over `cols`.
        #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
        pub(super) unsafe fn row_avx512(
            &self,
            lines: &mut Lines,
            terrain: &Terrain,
            row: usize,
            cols: std::ops::Range<usize>,
            out: &mut Out,
            stats: &mut SweepStats,
        ) {
            let (z, step) = (terrain.z, self.lengths[row]);
            let angles = &mut *out.angles;
            let c = _mm512_set1_pd(self.curvature);
            let twice_c = _mm512_set1_pd(2.0 * self.curvature);
            let step_v = _mm512_set1_pd(step);
            // The caller's columns have consecutive line indices.
            let first = lines.index(cols.start, row);
            for c0 in cols.clone().step_by(8 * GROUPS) {
                let mut groups = std::array::from_fn::<_, GROUPS, _>(|g| {
                    let c0 = c0 + 8 * g;
                    let c0 = c0.min(cols.end);
                    let i0 = first + (c0 - cols.start);
                    let near = ((row - terrain.row0) * lines.width + c0) as isize;
                    let near_out = ((row - out.row0) * lines.width + c0) as isize;
                    // SAFETY: lines `i0..` under the group's mask exist.
                    unsafe { open(lines, (cols.end - c0).min(8), i0, step_v, near, near_out) }
                });
                if groups.iter().all(|g| g.hulls.active == 0) {
                    continue;
                }
                // SAFETY: every load is of a crossing, which the caller
                // keeps on the DEM; lanes off the row are masked.
                let load = |g: &Group, off: isize| unsafe {
                    _mm512_cvtps_pd(_mm256_maskz_loadu_ps(
                        g.on_row,
                        z.as_ptr().wrapping_offset(g.near + off),
                    ))
                };
                // The step's crossings far first and the post, as the
                // scalar sweep takes them.
                for &(s, off_a, off_b, wb) in &self.crossings {
                    let vertex = |g: &Group| {
                        let (za, zb) = (load(g, off_a), load(g, off_b));
                        let zc = _mm512_add_pd(
                            za,
                            _mm512_mul_pd(_mm512_set1_pd(wb), _mm512_sub_pd(zb, za)),
                        );
                        let tc = _mm512_add_pd(g.t, _mm512_mul_pd(_mm512_set1_pd(s), step_v));
                        (
                            tc,
                            _mm512_sub_pd(zc, _mm512_mul_pd(_mm512_mul_pd(c, tc), tc)),
                        )
                    };
                    let v = groups.each_ref().map(vertex);
                    // SAFETY: the hulls' storage.
                    unsafe {
                        pop(groups.each_mut().map(|g| &mut g.hulls), v, stats);
                        for (g, (t, w)) in groups.iter_mut().zip(v) {
                            push(&mut g.hulls, t, w, stats);
                        }
                    }
                }
                let post = |g: &Group| {
                    let zp = load(g, 0);
                    (
                        g.t,
                        _mm512_sub_pd(zp, _mm512_mul_pd(_mm512_mul_pd(c, g.t), g.t)),
                    )
                };
                let p = groups.each_ref().map(post);
                // SAFETY: the hulls' storage.
                unsafe { pop(groups.each_mut().map(|g| &mut g.hulls), p, stats) };
                for (g, (t, wp)) in groups.iter_mut().zip(p) {
                    let hulls = &mut g.hulls;
                    let posts = hulls.active;
                    let angle = horizon(hulls, t, wp, twice_c);
                    stats.posts += u64::from(posts.count_ones());
                    let i0 = g.i0;
                    // SAFETY: the hulls' storage, and posts of the row.
                    unsafe {
                        push(hulls, t, wp, stats);
                        _mm256_mask_storeu_ps(
                            angles.as_mut_ptr().wrapping_offset(g.near_out),
                            posts,
                            _mm512_cvtpd_ps(angle),
                        );
                        _mm512_mask_storeu_epi64(lines.top.as_mut_ptr().add(i0), posts, hulls.top);
                        for (k, (vt, vw)) in [
                            (hulls.top_t, hulls.top_w),
                            (hulls.sec_t, hulls.sec_w),
                            (hulls.third_t, hulls.third_w),
                            (hulls.fourth_t, hulls.fourth_w),
                        ]
                        .into_iter()
                        .enumerate()
                        {
                            let at = k * lines.count + i0;
                            _mm512_mask_storeu_pd(lines.head_t.as_mut_ptr().add(at), posts, vt);
                            _mm512_mask_storeu_pd(lines.head_w.as_mut_ptr().add(at), posts, vw);
                        }
                        _mm512_mask_storeu_pd(lines.t.as_mut_ptr().add(i0), g.on_row, t);
                    }
                }
            }
        }
    }

    impl Kernel<'_> {
        /// East-west lines ([`super::Rows`]): rows `band`, eight to a
        /// vector, [`GROUPS`] vectors at a time, swept column by column from
        /// the far end (the east end when `east`).
        ///
        /// # Safety
        /// AVX-512 F, VL and DQ; rows `band` in `terrain`'s window and in
        /// `out`; `hull_t` and `hull_w` of `8 * GROUPS * width` each.
        #[allow(clippy::too_many_arguments)]
        #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
        pub(super) unsafe fn rows_avx512(
            &self,
            terrain: &Terrain,
            band: std::ops::Range<usize>,
            east: bool,
            out: &mut Out,
            stats: &mut SweepStats,
            hull_t: &mut [f64],
            hull_w: &mut [f64],
        ) {
            let width = terrain.width;
            let c = _mm512_set1_pd(self.curvature);
            let twice_c = _mm512_set1_pd(2.0 * self.curvature);
            let lane = _mm512_set_epi64(7, 6, 5, 4, 3, 2, 1, 0);
            let count = _mm512_set1_epi64(8 * GROUPS as i64);
            let (z, angles) = (terrain.z.as_ptr(), out.angles.as_mut_ptr());
            for r0 in band.clone().step_by(8 * GROUPS) {
                let mut groups = std::array::from_fn::<_, GROUPS, _>(|g| {
                    let first = (r0 + 8 * g).min(band.end);
                    let on_row = ((1u16 << (band.end - first).min(8)) - 1) as u8;
                    let rows = _mm512_add_epi64(_mm512_set1_epi64(first as i64), lane);
                    let line = _mm512_add_epi64(_mm512_set1_epi64(8 * g as i64), lane);
                    let hulls = Hulls {
                        top_t: _mm512_setzero_pd(),
                        top_w: _mm512_setzero_pd(),
                        sec_t: _mm512_setzero_pd(),
                        sec_w: _mm512_setzero_pd(),
                        third_t: _mm512_setzero_pd(),
                        third_w: _mm512_setzero_pd(),
                        fourth_t: _mm512_setzero_pd(),
                        fourth_w: _mm512_setzero_pd(),
                        full: 0,
                        top: _mm512_sub_epi64(line, count),
                        floors: floors(line, count),
                        count,
                        active: on_row,
                        hull_t: hull_t.as_mut_ptr(),
                        hull_w: hull_w.as_mut_ptr(),
                    };
                    let at = |row0: usize| {
                        let from = _mm512_sub_epi64(rows, _mm512_set1_epi64(row0 as i64));
                        _mm512_mullo_epi64(from, _mm512_set1_epi64(width as i64))
                    };
                    // SAFETY: the rows under `on_row` have lengths.
                    let step =
                        unsafe { _mm512_maskz_loadu_pd(on_row, self.lengths.as_ptr().add(first)) };
                    (hulls, step, at(terrain.row0), at(out.row0))
                });
                let mut t = [_mm512_setzero_pd(); GROUPS];
                for k in 0..width {
                    let col = _mm512_set1_epi64(if east { width - 1 - k } else { k } as i64);
                    let p = std::array::from_fn::<_, GROUPS, _>(|g| {
                        let (hulls, step, at_z, _) = &groups[g];
                        if k > 0 {
                            t[g] = _mm512_sub_pd(t[g], *step);
                        }
                        // SAFETY: the posts of rows under the mask.
                        let zp = unsafe {
                            _mm512_cvtps_pd(_mm512_mask_i64gather_ps::<4>(
                                _mm256_setzero_ps(),
                                hulls.active,
                                _mm512_add_epi64(*at_z, col),
                                z,
                            ))
                        };
                        (
                            t[g],
                            _mm512_sub_pd(zp, _mm512_mul_pd(_mm512_mul_pd(c, t[g]), t[g])),
                        )
                    });
                    // SAFETY: the hulls' storage.
                    unsafe { pop(groups.each_mut().map(|g| &mut g.0), p, stats) };
                    for ((hulls, _, _, at_out), (t, wp)) in groups.iter_mut().zip(p) {
                        let posts = hulls.active;
                        let angle = horizon(hulls, t, wp, twice_c);
                        stats.posts += u64::from(posts.count_ones());
                        // SAFETY: the hulls' storage, and the rows' posts.
                        unsafe {
                            _mm512_mask_i64scatter_ps::<4>(
                                angles,
                                posts,
                                _mm512_add_epi64(*at_out, col),
                                _mm512_cvtpd_ps(angle),
                            );
                            push(hulls, t, wp, stats);
                        }
                    }
                }
            }
        }
    }

    /// The group of the `on` (at most eight) lines from `i0`, their hulls'
    /// tops loaded and `t` stepped to their new posts.
    ///
    /// # Safety
    /// AVX-512 F, VL and DQ; lines `i0..i0 + on` exist.
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    unsafe fn open(
        lines: &mut Lines,
        on: usize,
        i0: usize,
        step_v: __m512d,
        near: isize,
        near_out: isize,
    ) -> Group {
        let on_row: __mmask8 = ((1u16 << on) - 1) as u8;
        let lane = _mm512_set_epi64(7, 6, 5, 4, 3, 2, 1, 0);
        let count = _mm512_set1_epi64(lines.count as i64);
        debug_assert!(i0 + on <= lines.count);
        // SAFETY: lines `i0..` under `on_row` exist.
        let (top, t) = unsafe {
            (
                _mm512_maskz_loadu_epi64(on_row, lines.top.as_ptr().add(i0)),
                _mm512_maskz_loadu_pd(on_row, lines.t.as_ptr().add(i0)),
            )
        };
        let active = _mm512_mask_cmpgt_epi64_mask(on_row, top, _mm512_set1_epi64(SPILLED));
        let line = _mm512_add_epi64(_mm512_set1_epi64(i0 as i64), lane);
        let floors = floors(line, count);
        let holds = |floor| _mm512_mask_cmpge_epi64_mask(active, top, floor);
        let has1 = holds(floors[0]);
        let has2 = holds(floors[1]);
        let has3 = holds(floors[2]);
        let has4 = holds(_mm512_add_epi64(floors[2], count));
        let head = |k: usize, has: __mmask8| {
            let at = k * lines.count + i0;
            // SAFETY: lines `i0..` under `on_row` exist.
            unsafe {
                (
                    _mm512_maskz_loadu_pd(has, lines.head_t.as_ptr().add(at)),
                    _mm512_maskz_loadu_pd(has, lines.head_w.as_ptr().add(at)),
                )
            }
        };
        let ((top_t, top_w), (sec_t, sec_w), (third_t, third_w), (fourth_t, fourth_w)) =
            (head(0, has1), head(1, has2), head(2, has3), head(3, has4));
        Group {
            hulls: Hulls {
                top_t,
                top_w,
                sec_t,
                sec_w,
                third_t,
                third_w,
                fourth_t,
                fourth_w,
                full: has4,
                top,
                floors,
                count,
                active,
                hull_t: lines.hull_t.as_mut_ptr(),
                hull_w: lines.hull_w.as_mut_ptr(),
            },
            // The step to this row's post.
            t: _mm512_sub_pd(t, step_v),
            on_row,
            i0,
            near,
            near_out,
        }
    }

    /// `top` where a hull holds 1, 2 and 3 vertices, for lines `line`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    fn floors(line: __m512i, count: __m512i) -> [__m512i; 3] {
        let second = _mm512_add_epi64(line, count);
        [line, second, _mm512_add_epi64(second, count)]
    }

    /// Pops, in every active lane of both groups, the top while it lies on
    /// or below the line from the group's `(t, w)` to the vertex behind it:
    /// the scalar `push`'s loop, repeated while any lane still pops.
    ///
    /// # Safety
    /// AVX-512 F; `hulls` over live storage.
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    unsafe fn pop(
        mut hulls: [&mut Hulls; GROUPS],
        v: [(__m512d, __m512d); GROUPS],
        stats: &mut SweepStats,
    ) {
        loop {
            let mut popped = [0; GROUPS];
            for ((p, h), (t, w)) in popped.iter_mut().zip(hulls.iter()).zip(v) {
                *p = pops(h, t, w);
            }
            if popped.iter().all(|&p| p == 0) {
                return;
            }
            for (h, p) in hulls.iter_mut().zip(popped) {
                stats.pops += u64::from(p.count_ones());
                // SAFETY: as the caller's.
                unsafe { drop_top(h, p) };
            }
        }
    }

    /// The lanes whose top lies on or below the line from `(t, w)` to the
    /// vertex behind it.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    fn pops(hulls: &Hulls, t: __m512d, w: __m512d) -> __mmask8 {
        let has2 = _mm512_mask_cmpge_epi64_mask(hulls.active, hulls.top, hulls.floors[1]);
        let lhs = _mm512_mul_pd(_mm512_sub_pd(hulls.top_w, w), _mm512_sub_pd(hulls.sec_t, t));
        let rhs = _mm512_mul_pd(_mm512_sub_pd(hulls.sec_w, w), _mm512_sub_pd(hulls.top_t, t));
        _mm512_mask_cmp_pd_mask::<_CMP_LE_OQ>(has2, lhs, rhs)
    }

    /// Drops the top of the `popped` lanes' hulls, the new third vertex
    /// the fourth where held, else gathered from the storage.
    ///
    /// # Safety
    /// AVX-512 F; `hulls` over live storage.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    unsafe fn drop_top(hulls: &mut Hulls, popped: __mmask8) {
        hulls.top = _mm512_mask_sub_epi64(hulls.top, popped, hulls.top, hulls.count);
        hulls.top_t = _mm512_mask_mov_pd(hulls.top_t, popped, hulls.sec_t);
        hulls.top_w = _mm512_mask_mov_pd(hulls.top_w, popped, hulls.sec_w);
        hulls.sec_t = _mm512_mask_mov_pd(hulls.sec_t, popped, hulls.third_t);
        hulls.sec_w = _mm512_mask_mov_pd(hulls.sec_w, popped, hulls.third_w);
        hulls.third_t = _mm512_mask_mov_pd(hulls.third_t, popped, hulls.fourth_t);
        hulls.third_w = _mm512_mask_mov_pd(hulls.third_w, popped, hulls.fourth_w);
        let refill = _mm512_mask_cmpge_epi64_mask(popped & !hulls.full, hulls.top, hulls.floors[2]);
        hulls.full &= !popped;
        if refill != 0 {
            let third = _mm512_sub_epi64(hulls.top, _mm512_add_epi64(hulls.count, hulls.count));
            // SAFETY: the vertex two below each refilled top is on its hull.
            unsafe {
                hulls.third_t =
                    _mm512_mask_i64gather_pd::<8>(hulls.third_t, refill, third, hulls.hull_t);
                hulls.third_w =
                    _mm512_mask_i64gather_pd::<8>(hulls.third_w, refill, third, hulls.hull_w);
            }
        }
    }

    /// Pushes `(t, w)` on every active lane's hull (after [`pop`]); the
    /// caller spilled every line that could outgrow the depth.
    ///
    /// # Safety
    /// AVX-512 F; `hulls` over live storage.
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    unsafe fn push(hulls: &mut Hulls, t: __m512d, w: __m512d, stats: &mut SweepStats) {
        let pushed = hulls.active;
        // The fourth vertex leaves the head for the storage, at its depth
        // `len - 4`.
        let evicted = pushed & hulls.full;
        if evicted != 0 {
            let fourth = _mm512_sub_epi64(
                hulls.top,
                _mm512_add_epi64(hulls.count, _mm512_add_epi64(hulls.count, hulls.count)),
            );
            // SAFETY: below the depth in each pushed lane's line.
            unsafe {
                _mm512_mask_i64scatter_pd::<8>(hulls.hull_t, evicted, fourth, hulls.fourth_t);
                _mm512_mask_i64scatter_pd::<8>(hulls.hull_w, evicted, fourth, hulls.fourth_w);
            }
        }
        hulls.full = (hulls.full & !pushed)
            | _mm512_mask_cmpge_epi64_mask(pushed, hulls.top, hulls.floors[2]);
        hulls.top = _mm512_mask_add_epi64(hulls.top, pushed, hulls.top, hulls.count);
        hulls.fourth_t = _mm512_mask_mov_pd(hulls.fourth_t, pushed, hulls.third_t);
        hulls.fourth_w = _mm512_mask_mov_pd(hulls.fourth_w, pushed, hulls.third_w);
        hulls.third_t = _mm512_mask_mov_pd(hulls.third_t, pushed, hulls.sec_t);
        hulls.third_w = _mm512_mask_mov_pd(hulls.third_w, pushed, hulls.sec_w);
        hulls.sec_t = _mm512_mask_mov_pd(hulls.sec_t, pushed, hulls.top_t);
        hulls.sec_w = _mm512_mask_mov_pd(hulls.sec_w, pushed, hulls.top_w);
        hulls.top_t = _mm512_mask_mov_pd(hulls.top_t, pushed, t);
        hulls.top_w = _mm512_mask_mov_pd(hulls.top_w, pushed, w);
        stats.vertices += u64::from(pushed.count_ones());
    }

    /// The horizon angle (degrees) of each lane's post `(t, w)` from its
    /// hull's top after the pops, -90 where the hull is empty: the scalar
    /// `angle_deg`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    fn horizon(hulls: &Hulls, t: __m512d, w: __m512d, twice_c: __m512d) -> __m512d {
        let has = _mm512_mask_cmpge_epi64_mask(hulls.active, hulls.top, hulls.floors[0]);
        let slope = _mm512_add_pd(
            _mm512_div_pd(_mm512_sub_pd(hulls.top_w, w), _mm512_sub_pd(hulls.top_t, t)),
            _mm512_mul_pd(twice_c, t),
        );
        _mm512_mask_blend_pd(has, _mm512_set1_pd(-90.0), atan_deg(slope))
    }

    /// [`crate::algorithms::horizon::line::atan_deg`] in eight lanes, its branches as blends:
    /// the same operations in the same order, so the same bits.
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    fn atan_deg(x: __m512d) -> __m512d {
        use crate::algorithms::horizon::line::{ATAN_POLY, TAN_3PI_8, TAN_PI_8};
        let set = _mm512_set1_pd;
        let sign_bit = set(-0.0);
        // `signum` of a number: 1 with its sign.
        let sign = _mm512_or_pd(_mm512_and_pd(x, sign_bit), set(1.0));
        let ax = _mm512_andnot_pd(sign_bit, x);
        let high = _mm512_cmp_pd_mask::<_CMP_GT_OQ>(ax, set(TAN_3PI_8));
        let mid = _mm512_cmp_pd_mask::<_CMP_GT_OQ>(ax, set(TAN_PI_8)) & !high;
        let base = _mm512_mask_blend_pd(
            high,
            _mm512_mask_blend_pd(mid, set(0.0), set(std::f64::consts::FRAC_PI_4)),
            set(std::f64::consts::FRAC_PI_2),
        );
        let r = _mm512_mask_blend_pd(
            mid,
            ax,
            _mm512_div_pd(_mm512_sub_pd(ax, set(1.0)), _mm512_add_pd(ax, set(1.0))),
        );
        let r = _mm512_mask_blend_pd(high, r, _mm512_div_pd(set(-1.0), ax));
        let zz = _mm512_mul_pd(r, r);
        let [p0, p1, p2, p3] = ATAN_POLY.map(|p| set(p));
        let mut p = _mm512_sub_pd(_mm512_mul_pd(p0, zz), p1);
        p = _mm512_add_pd(_mm512_mul_pd(p, zz), p2);
        p = _mm512_sub_pd(_mm512_mul_pd(p, zz), p3);
        let poly = _mm512_add_pd(_mm512_mul_pd(_mm512_mul_pd(p, zz), r), r);
        let radians = _mm512_mul_pd(sign, _mm512_add_pd(base, poly));
        _mm512_mul_pd(radians, set(1f64.to_degrees()))
    }
}

/// The lanes in AVX2: four lines to a vector, masks as vectors of whole
/// lanes, the scatter of evicted vertices one lane at a time (AVX2 has
/// none), and three vertices held, not four (sixteen registers hold no
/// more). The same arithmetic in the same order as [`avx512`], so the
/// same bits.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{Kernel, Lines, Out, SweepStats, GROUPS, SPILLED};
    use crate::terrain::Terrain;
    use std::arch::x86_64::*;

    /// Four lanes' hulls, as `avx512::Hulls`; `active` has every bit of a
    /// lane set where the lane takes part.
    struct Hulls {
        top_t: __m256d,
        top_w: __m256d,
        sec_t: __m256d,
        sec_w: __m256d,
        third_t: __m256d,
        third_w: __m256d,
        top: __m256i,
        floors: [__m256i; 3],
        count: __m256i,
        active: __m256i,
        hull_t: *mut f64,
        hull_w: *mut f64,
    }

    /// Lanes of `mask` whose `top` is not below `floor`.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn at_least(mask: __m256i, top: __m256i, floor: __m256i) -> __m256i {
        _mm256_andnot_si256(_mm256_cmpgt_epi64(floor, top), mask)
    }

    /// Lanes of `mask` whose hull holds at least `k` vertices (1 to 3):
    /// `top` not below `floors[k - 1]`.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn holds(mask: __m256i, hulls: &Hulls, k: usize) -> __m256i {
        at_least(mask, hulls.top, hulls.floors[k - 1])
    }

    /// `avx512::floors` in four lanes.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn floors(line: __m256i, count: __m256i) -> [__m256i; 3] {
        let second = _mm256_add_epi64(line, count);
        [line, second, _mm256_add_epi64(second, count)]
    }

    /// One bit per lane of a lane mask.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn bits(mask: __m256i) -> u32 {
        _mm256_movemask_pd(_mm256_castsi256_pd(mask)) as u32
    }

    /// A mask of four 64-bit lanes as four 32-bit lanes.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn narrow(mask: __m256i) -> __m128i {
        _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(
            mask,
            _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6),
        ))
    }

    /// `on` where `mask`, else `off`.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn select(mask: __m256i, on: __m256d, off: __m256d) -> __m256d {
        _mm256_blendv_pd(off, on, _mm256_castsi256_pd(mask))
    }

    /// Four lines of a row, as `avx512::Group`.
    struct Group {
        hulls: Hulls,
        t: __m256d,
        on_row: __m256i,
        on_row_32: __m128i,
        i0: usize,
        near: isize,
        near_out: isize,
    }

    impl Kernel<'_> {
        /// [`Kernel::row_avx512`] in groups of four lines.
        ///
        /// # Safety
        /// AVX2; every crossing of the steps from `cols` in `terrain`'s
        /// rows, `row` in `out`'s, and the lines' indices consecutive over
        /// `cols`.
        #[target_feature(enable = "avx2,popcnt")]
        pub(super) unsafe fn row_avx2(
            &self,
            lines: &mut Lines,
            terrain: &Terrain,
            row: usize,
            cols: std::ops::Range<usize>,
            out: &mut Out,
            stats: &mut SweepStats,
        ) {
            let (z, step) = (terrain.z, self.lengths[row]);
            let angles = &mut *out.angles;
            let c = _mm256_set1_pd(self.curvature);
            let twice_c = _mm256_set1_pd(2.0 * self.curvature);
            let step_v = _mm256_set1_pd(step);
            let first = lines.index(cols.start, row);
            for c0 in cols.clone().step_by(4 * GROUPS) {
                let mut groups = std::array::from_fn::<_, GROUPS, _>(|g| {
                    let c0 = (c0 + 4 * g).min(cols.end);
                    let i0 = first + (c0 - cols.start);
                    let near = ((row - terrain.row0) * lines.width + c0) as isize;
                    let near_out = ((row - out.row0) * lines.width + c0) as isize;
                    // SAFETY: lines `i0..` under the group's mask exist.
                    unsafe { open(lines, (cols.end - c0).min(4), i0, step_v, near, near_out) }
                });
                if groups.iter().all(|g| bits(g.hulls.active) == 0) {
                    continue;
                }
                // SAFETY: every load is of a crossing, which the caller
                // keeps on the DEM; lanes off the row are masked (and do not
                // fault).
                let load = |g: &Group, off: isize| unsafe {
                    _mm256_cvtps_pd(_mm_maskload_ps(
                        z.as_ptr().wrapping_offset(g.near + off),
                        g.on_row_32,
                    ))
                };
                for &(s, off_a, off_b, wb) in &self.crossings {
                    let vertex = |g: &Group| {
                        let (za, zb) = (load(g, off_a), load(g, off_b));
                        let zc = _mm256_add_pd(
                            za,
                            _mm256_mul_pd(_mm256_set1_pd(wb), _mm256_sub_pd(zb, za)),
                        );
                        let tc = _mm256_add_pd(g.t, _mm256_mul_pd(_mm256_set1_pd(s), step_v));
                        (
                            tc,
                            _mm256_sub_pd(zc, _mm256_mul_pd(_mm256_mul_pd(c, tc), tc)),
                        )
                    };
                    let v = groups.each_ref().map(vertex);
                    // SAFETY: the hulls' storage.
                    unsafe {
                        pop(groups.each_mut().map(|g| &mut g.hulls), v, stats);
                        for (g, (t, w)) in groups.iter_mut().zip(v) {
                            push(&mut g.hulls, t, w, stats);
                        }
                    }
                }
                let post = |g: &Group| {
                    let zp = load(g, 0);
                    (
                        g.t,
                        _mm256_sub_pd(zp, _mm256_mul_pd(_mm256_mul_pd(c, g.t), g.t)),
                    )
                };
                let p = groups.each_ref().map(post);
                // SAFETY: the hulls' storage.
                unsafe { pop(groups.each_mut().map(|g| &mut g.hulls), p, stats) };
                for (g, (t, wp)) in groups.iter_mut().zip(p) {
                    let hulls = &mut g.hulls;
                    let posts = hulls.active;
                    let angle = horizon(hulls, t, wp, twice_c);
                    stats.posts += u64::from(bits(posts).count_ones());
                    let i0 = g.i0;
                    // SAFETY: the hulls' storage, and posts of the row.
                    unsafe {
                        push(hulls, t, wp, stats);
                        _mm_maskstore_ps(
                            angles.as_mut_ptr().wrapping_offset(g.near_out),
                            narrow(posts),
                            _mm256_cvtpd_ps(angle),
                        );
                        _mm256_maskstore_epi64(lines.top.as_mut_ptr().add(i0), posts, hulls.top);
                        for (k, (vt, vw)) in [
                            (hulls.top_t, hulls.top_w),
                            (hulls.sec_t, hulls.sec_w),
                            (hulls.third_t, hulls.third_w),
                        ]
                        .into_iter()
                        .enumerate()
                        {
                            let at = k * lines.count + i0;
                            _mm256_maskstore_pd(lines.head_t.as_mut_ptr().add(at), posts, vt);
                            _mm256_maskstore_pd(lines.head_w.as_mut_ptr().add(at), posts, vw);
                        }
                        _mm256_maskstore_pd(lines.t.as_mut_ptr().add(i0), g.on_row, t);
                    }
                }
            }
        }
    }

    impl Kernel<'_> {
        /// [`Kernel::rows_avx512`] four rows to a vector.
        ///
        /// # Safety
        /// AVX2; rows `band` in `terrain`'s window and in `out`; `hull_t`
        /// and `hull_w` of `4 * GROUPS * width` each (or more).
        #[allow(clippy::too_many_arguments)]
        #[target_feature(enable = "avx2,popcnt")]
        pub(super) unsafe fn rows_avx2(
            &self,
            terrain: &Terrain,
            band: std::ops::Range<usize>,
            east: bool,
            out: &mut Out,
            stats: &mut SweepStats,
            hull_t: &mut [f64],
            hull_w: &mut [f64],
        ) {
            let width = terrain.width;
            let c = _mm256_set1_pd(self.curvature);
            let twice_c = _mm256_set1_pd(2.0 * self.curvature);
            let lane = _mm256_setr_epi64x(0, 1, 2, 3);
            let count = _mm256_set1_epi64x(4 * GROUPS as i64);
            let (z, angles) = (terrain.z.as_ptr(), out.angles.as_mut_ptr());
            for r0 in band.clone().step_by(4 * GROUPS) {
                let mut groups = std::array::from_fn::<_, GROUPS, _>(|g| {
                    let first = (r0 + 4 * g).min(band.end);
                    let on = (band.end - first).min(4) as i64;
                    let on_row = _mm256_cmpgt_epi64(_mm256_set1_epi64x(on), lane);
                    let line = _mm256_add_epi64(_mm256_set1_epi64x(4 * g as i64), lane);
                    let hulls = Hulls {
                        top_t: _mm256_setzero_pd(),
                        top_w: _mm256_setzero_pd(),
                        sec_t: _mm256_setzero_pd(),
                        sec_w: _mm256_setzero_pd(),
                        third_t: _mm256_setzero_pd(),
                        third_w: _mm256_setzero_pd(),
                        top: _mm256_sub_epi64(line, count),
                        floors: floors(line, count),
                        count,
                        active: on_row,
                        hull_t: hull_t.as_mut_ptr(),
                        hull_w: hull_w.as_mut_ptr(),
                    };
                    // Where each lane's row starts (rows past the band's
                    // end are masked).
                    let at = |row0: usize| {
                        let r = |l: usize| ((first + l).saturating_sub(row0) * width) as i64;
                        [r(0), r(1), r(2), r(3)]
                    };
                    // SAFETY: the rows under `on_row` have lengths.
                    let step =
                        unsafe { _mm256_maskload_pd(self.lengths.as_ptr().add(first), on_row) };
                    (hulls, step, at(terrain.row0), at(out.row0))
                });
                let mut t = [_mm256_setzero_pd(); GROUPS];
                for k in 0..width {
                    let col = if east { width - 1 - k } else { k } as i64;
                    let p = std::array::from_fn::<_, GROUPS, _>(|g| {
                        let (hulls, step, at_z, _) = &groups[g];
                        if k > 0 {
                            t[g] = _mm256_sub_pd(t[g], *step);
                        }
                        let posts = at_z.map(|a| a + col);
                        // SAFETY: the posts of rows under the mask.
                        let zp = unsafe {
                            _mm256_cvtps_pd(_mm256_mask_i64gather_ps::<4>(
                                _mm_setzero_ps(),
                                z,
                                _mm256_setr_epi64x(posts[0], posts[1], posts[2], posts[3]),
                                _mm_castsi128_ps(narrow(hulls.active)),
                            ))
                        };
                        (
                            t[g],
                            _mm256_sub_pd(zp, _mm256_mul_pd(_mm256_mul_pd(c, t[g]), t[g])),
                        )
                    });
                    // SAFETY: the hulls' storage.
                    unsafe { pop(groups.each_mut().map(|g| &mut g.0), p, stats) };
                    for ((hulls, _, _, at_out), (t, wp)) in groups.iter_mut().zip(p) {
                        let posts = hulls.active;
                        let angle = horizon(hulls, t, wp, twice_c);
                        let on = bits(posts);
                        stats.posts += u64::from(on.count_ones());
                        // SAFETY: four lanes as four.
                        let angle = unsafe {
                            std::mem::transmute::<__m128, [f32; 4]>(_mm256_cvtpd_ps(angle))
                        };
                        for l in (0..4).filter(|l| on >> l & 1 == 1) {
                            // SAFETY: a post of the band's rows.
                            unsafe { *angles.offset((at_out[l] + col) as isize) = angle[l] };
                        }
                        // SAFETY: the hulls' storage.
                        unsafe { push(hulls, t, wp, stats) };
                    }
                }
            }
        }
    }

    /// `avx512::open` for four lines.
    ///
    /// # Safety
    /// AVX2; lines `i0..i0 + on` exist.
    #[target_feature(enable = "avx2,popcnt")]
    unsafe fn open(
        lines: &mut Lines,
        on: usize,
        i0: usize,
        step_v: __m256d,
        near: isize,
        near_out: isize,
    ) -> Group {
        let lane = _mm256_setr_epi64x(0, 1, 2, 3);
        let count = _mm256_set1_epi64x(lines.count as i64);
        let on_row = _mm256_cmpgt_epi64(_mm256_set1_epi64x(on as i64), lane);
        debug_assert!(i0 + on <= lines.count);
        // SAFETY: lines `i0..` under `on_row` exist.
        let (top, t) = unsafe {
            (
                _mm256_maskload_epi64(lines.top.as_ptr().add(i0), on_row),
                _mm256_maskload_pd(lines.t.as_ptr().add(i0), on_row),
            )
        };
        let active = _mm256_and_si256(on_row, _mm256_cmpgt_epi64(top, _mm256_set1_epi64x(SPILLED)));
        let line = _mm256_add_epi64(_mm256_set1_epi64x(i0 as i64), lane);
        let floors = floors(line, count);
        let head = |k: usize, has: __m256i| {
            let at = k * lines.count + i0;
            // SAFETY: lines `i0..` under `on_row` exist.
            unsafe {
                (
                    _mm256_maskload_pd(lines.head_t.as_ptr().add(at), has),
                    _mm256_maskload_pd(lines.head_w.as_ptr().add(at), has),
                )
            }
        };
        let ((top_t, top_w), (sec_t, sec_w), (third_t, third_w)) = (
            head(0, at_least(active, top, floors[0])),
            head(1, at_least(active, top, floors[1])),
            head(2, at_least(active, top, floors[2])),
        );
        Group {
            hulls: Hulls {
                top_t,
                top_w,
                sec_t,
                sec_w,
                third_t,
                third_w,
                top,
                floors,
                count,
                active,
                hull_t: lines.hull_t.as_mut_ptr(),
                hull_w: lines.hull_w.as_mut_ptr(),
            },
            t: _mm256_sub_pd(t, step_v),
            on_row,
            on_row_32: narrow(on_row),
            i0,
            near,
            near_out,
        }
    }

    /// `avx512::pop` in groups of four lanes.
    ///
    /// # Safety
    /// AVX2; `hulls` over live storage.
    #[target_feature(enable = "avx2,popcnt")]
    unsafe fn pop(
        mut hulls: [&mut Hulls; GROUPS],
        v: [(__m256d, __m256d); GROUPS],
        stats: &mut SweepStats,
    ) {
        loop {
            let mut popped = [_mm256_setzero_si256(); GROUPS];
            for ((p, h), (t, w)) in popped.iter_mut().zip(hulls.iter()).zip(v) {
                *p = pops(h, t, w);
            }
            if popped.iter().all(|&p| bits(p) == 0) {
                return;
            }
            for (h, p) in hulls.iter_mut().zip(popped) {
                stats.pops += u64::from(bits(p).count_ones());
                // SAFETY: as the caller's.
                unsafe { drop_top(h, p) };
            }
        }
    }

    /// `avx512::pops` in four lanes.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn pops(hulls: &Hulls, t: __m256d, w: __m256d) -> __m256i {
        let has2 = holds(hulls.active, hulls, 2);
        let lhs = _mm256_mul_pd(_mm256_sub_pd(hulls.top_w, w), _mm256_sub_pd(hulls.sec_t, t));
        let rhs = _mm256_mul_pd(_mm256_sub_pd(hulls.sec_w, w), _mm256_sub_pd(hulls.top_t, t));
        _mm256_and_si256(
            has2,
            _mm256_castpd_si256(_mm256_cmp_pd::<_CMP_LE_OQ>(lhs, rhs)),
        )
    }

    /// `avx512::drop_top` in four lanes.
    ///
    /// # Safety
    /// AVX2; `hulls` over live storage.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    unsafe fn drop_top(hulls: &mut Hulls, popped: __m256i) {
        hulls.top = _mm256_sub_epi64(hulls.top, _mm256_and_si256(popped, hulls.count));
        hulls.top_t = select(popped, hulls.sec_t, hulls.top_t);
        hulls.top_w = select(popped, hulls.sec_w, hulls.top_w);
        hulls.sec_t = select(popped, hulls.third_t, hulls.sec_t);
        hulls.sec_w = select(popped, hulls.third_w, hulls.sec_w);
        let refill = _mm256_castsi256_pd(holds(popped, hulls, 3));
        let third = _mm256_sub_epi64(hulls.top, _mm256_add_epi64(hulls.count, hulls.count));
        // SAFETY: the vertex two below each refilled top is on its hull.
        unsafe {
            hulls.third_t =
                _mm256_mask_i64gather_pd::<8>(hulls.third_t, hulls.hull_t, third, refill);
            hulls.third_w =
                _mm256_mask_i64gather_pd::<8>(hulls.third_w, hulls.hull_w, third, refill);
        }
    }

    /// `avx512::push` in four lanes.
    ///
    /// # Safety
    /// AVX2; `hulls` over live storage.
    #[target_feature(enable = "avx2,popcnt")]
    unsafe fn push(hulls: &mut Hulls, t: __m256d, w: __m256d, stats: &mut SweepStats) {
        let pushed = hulls.active;
        let evicted = bits(holds(pushed, hulls, 3));
        if evicted != 0 {
            let third = _mm256_sub_epi64(hulls.top, _mm256_add_epi64(hulls.count, hulls.count));
            // By `transmute`: stores into arrays instead took the whole
            // process from 0.68 to 0.80 s. SAFETY: four lanes as four.
            let (at, vt, vw) = unsafe {
                (
                    std::mem::transmute::<__m256i, [i64; 4]>(third),
                    std::mem::transmute::<__m256d, [f64; 4]>(hulls.third_t),
                    std::mem::transmute::<__m256d, [f64; 4]>(hulls.third_w),
                )
            };
            for l in (0..4).filter(|l| evicted >> l & 1 == 1) {
                // SAFETY: below the depth in each pushed lane's line.
                unsafe {
                    *hulls.hull_t.offset(at[l] as isize) = vt[l];
                    *hulls.hull_w.offset(at[l] as isize) = vw[l];
                }
            }
        }
        hulls.top = _mm256_add_epi64(hulls.top, _mm256_and_si256(pushed, hulls.count));
        hulls.third_t = select(pushed, hulls.sec_t, hulls.third_t);
        hulls.third_w = select(pushed, hulls.sec_w, hulls.third_w);
        hulls.sec_t = select(pushed, hulls.top_t, hulls.sec_t);
        hulls.sec_w = select(pushed, hulls.top_w, hulls.sec_w);
        hulls.top_t = select(pushed, t, hulls.top_t);
        hulls.top_w = select(pushed, w, hulls.top_w);
        stats.vertices += u64::from(bits(pushed).count_ones());
    }

    /// `avx512::horizon` in four lanes.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn horizon(hulls: &Hulls, t: __m256d, w: __m256d, twice_c: __m256d) -> __m256d {
        let has = holds(hulls.active, hulls, 1);
        let slope = _mm256_add_pd(
            _mm256_div_pd(_mm256_sub_pd(hulls.top_w, w), _mm256_sub_pd(hulls.top_t, t)),
            _mm256_mul_pd(twice_c, t),
        );
        select(has, atan_deg(slope), _mm256_set1_pd(-90.0))
    }

    /// `avx512::atan_deg` in four lanes: the same operations in the same
    /// order, so the same bits.
    #[target_feature(enable = "avx2,popcnt")]
    fn atan_deg(x: __m256d) -> __m256d {
        use crate::algorithms::horizon::line::{ATAN_POLY, TAN_3PI_8, TAN_PI_8};
        let set = _mm256_set1_pd;
        let sign_bit = set(-0.0);
        let sign = _mm256_or_pd(_mm256_and_pd(x, sign_bit), set(1.0));
        let ax = _mm256_andnot_pd(sign_bit, x);
        let high = _mm256_cmp_pd::<_CMP_GT_OQ>(ax, set(TAN_3PI_8));
        let mid = _mm256_andnot_pd(high, _mm256_cmp_pd::<_CMP_GT_OQ>(ax, set(TAN_PI_8)));
        let base = _mm256_blendv_pd(
            _mm256_blendv_pd(set(0.0), set(std::f64::consts::FRAC_PI_4), mid),
            set(std::f64::consts::FRAC_PI_2),
            high,
        );
        let r = _mm256_blendv_pd(
            ax,
            _mm256_div_pd(_mm256_sub_pd(ax, set(1.0)), _mm256_add_pd(ax, set(1.0))),
            mid,
        );
        let r = _mm256_blendv_pd(r, _mm256_div_pd(set(-1.0), ax), high);
        let zz = _mm256_mul_pd(r, r);
        let [p0, p1, p2, p3] = ATAN_POLY.map(|p| set(p));
        let mut p = _mm256_sub_pd(_mm256_mul_pd(p0, zz), p1);
        p = _mm256_add_pd(_mm256_mul_pd(p, zz), p2);
        p = _mm256_sub_pd(_mm256_mul_pd(p, zz), p3);
        let poly = _mm256_add_pd(_mm256_mul_pd(_mm256_mul_pd(p, zz), r), r);
        let radians = _mm256_mul_pd(sign, _mm256_add_pd(base, poly));
        _mm256_mul_pd(radians, set(1f64.to_degrees()))
    }
}
