//! Where the runs of a ray's ground track end, from Henning and Stephenson's
//! intercept sequence (2004, sec. 2) in integers.
//!
//! The track `origin + t * dir` crosses the rows of the minor axis one after
//! another; while it is in one row it touches a *run* of cells along the
//! major axis. Henning and Stephenson show that, away from the ends of the
//! ray, a run is one of two lengths, `r = floor(1 / alpha)` (short) or
//! `r + 1` (long), `alpha` the track's slope (minor over major), and that
//! which one comes next follows from the *intercept sequence*: the fraction
//! of a cell by which the track passes the corner where the run ends
//! (eq. 2-7). One addition and one comparison per run, no division.
//!
//! **Exact, where the paper's recurrence drifts.** In floating point the
//! sequence accumulates one rounding per run and sooner or later puts a run
//! end one cell off. Here it is kept in integers: every `f64` is an integer
//! times a power of two, so the track's corner test
//!
//! ```text
//! G(X, Y) = (Y - p_b) * D_a - (X - p_a) * D_b      (>= 0: boundary X is crossed no later than Y)
//! ```
//!
//! (mirrored so that both directions are positive: `p` the origin, `D` the
//! direction's magnitudes, `a` major, `b` minor) is an exact `i128` in units
//! of the smallest power of two among its terms. Between consecutive minor
//! boundaries `G` grows by `D_a`; reduced modulo `D_b` it is the paper's
//! intercept sequence scaled by `D_b`, and the quotient is the run length.
//! Only the first boundary needs products, and those are taken modulo
//! 2^128, exact because the result is known to be small.
//!
//! **The same cells as the definition.** Every tracer decides which cells a
//! ray touches by the rounded crossing times of [`GridRay::slab`], not by
//! exact geometry; the two disagree only where the track passes within
//! rounding of a lattice corner. So each run end whose `G` lies within a
//! bound on that rounding of a corner (`tol`, about 2^-49 of the terms'
//! size) is settled by the rounded times themselves, and that bound makes
//! every other exact decision the rounded one too. A ray whose numbers do
//! not fit (an origin far beyond the grid, a track so close to an axis that
//! its runs are longer than 2^16 cells) gets `None` from [`RunEnds::new`];
//! [`Runs`] then finds each run's ends from the rounded times
//! (`walk::first_touched`, `walk::last_touched`).
//!
//! **The truncated first run** (eq. 8-11) and the last run end where the
//! segment `[ta, tb]` does, not at a boundary: [`Runs`] takes those two
//! ends from the rounded times at `ta` and `tb`.

use crate::surface::GridRay;
use crate::trace::walk::{first_touched, last_touched};

/// The runs of one ray's track over `[ta, tb]`, row by row of the minor
/// axis: each run's first and last cell along the major axis, from the
/// intercept sequence at the rows' boundaries ([`RunEnds`]) and from the
/// rounded times at the segment's ends (or everywhere, where the sequence
/// cannot start).
#[derive(Debug, Clone)]
pub(crate) struct Runs {
    ends: Option<RunEnds>,
    /// The major axis' origin and direction, for the rounded times.
    o: f64,
    d: f64,
    /// Whether the minor axis runs towards higher indices.
    forward: bool,
    ta: f64,
    tb: f64,
}

impl Runs {
    pub(crate) fn new(g: &GridRay, major: usize, ta: f64, tb: f64) -> Self {
        Self {
            ends: RunEnds::new(g, major, ta, tb),
            o: g.origin[major],
            d: g.dir[major],
            forward: g.dir[1 - major] > 0.0,
            ta,
            tb,
        }
    }

    /// The run in minor row `k`, which the ray is over during `[r0, r1]`:
    /// its first and last major-axis cell in travel order (unclamped). It
    /// starts where the track entered the row, or at the segment's start
    /// (the truncated first run), and ends where the track leaves, or at
    /// the segment's end.
    #[inline]
    pub(crate) fn cells(&mut self, k: i64, r0: f64, r1: f64) -> (i64, i64) {
        let (entry, exit) = if self.forward { (k, k + 1) } else { (k + 1, k) };
        let entered = self
            .ends
            .as_mut()
            .filter(|_| r0 != self.ta)
            .and_then(|e| e.at_boundary(entry));
        let left = self
            .ends
            .as_mut()
            .filter(|_| r1 != self.tb)
            .and_then(|e| e.at_boundary(exit));
        (
            entered.map_or_else(|| first_touched(self.o, self.d, r0), |e| e.1),
            left.map_or_else(|| last_touched(self.o, self.d, r1), |e| e.0),
        )
    }
}

/// The run ends of one ray at the minor axis' boundaries, in travel order.
#[derive(Debug, Clone)]
struct RunEnds {
    /// The track in grid units, for the rounded crossing times.
    o_a: f64,
    d_a: f64,
    o_b: f64,
    d_b: f64,
    /// `-1` where an axis runs towards lower indices (mirrored).
    s_a: i64,
    s_b: i64,
    /// The exact quantities in units of `2^e` (the smallest power of two
    /// among G's terms): `p_a = s_a * o_a = pa_int + f_a`, likewise `p_b`,
    /// and `D_a = |d_a|`, `D_b = |d_b|`.
    pa_int: i64,
    pb_int: i64,
    /// `f_a * D_b - f_b * D_a` (the fractional parts of `p`) modulo 2^128.
    fractions: i128,
    da: i128,
    db: i128,
    /// `D_a = q * D_b + rem`: `q` is the short run's length.
    q: i64,
    rem: i128,
    /// Within `tol` of a corner (`G < tol` or `G > D_b - tol`), the rounded
    /// times decide.
    tol: i128,
    /// The recurrence's state: at mirrored minor boundary `y`, the last
    /// mirrored major boundary `x` crossed no later than it, and
    /// `G(x, y)` in `0..D_b`; `None` before the first boundary.
    state: Option<(i64, i64, i128)>,
    /// The last boundary's answer, `(k, ends)`: each boundary ends one row
    /// and starts the next, and is asked for by both.
    last: Option<(i64, (i64, i64))>,
    /// Boundaries settled by the rounded times (for the tests: that the
    /// corner cases are reached).
    settled_by_rounding: u64,
}

/// An `f64` as `(m, e)` with `value = m * 2^e`, `m` odd or zero.
fn decode(v: f64) -> (i128, i32) {
    if v == 0.0 {
        return (0, 0);
    }
    let bits = v.abs().to_bits();
    let exp = ((bits >> 52) & 0x7ff) as i32;
    let frac = bits & ((1u64 << 52) - 1);
    let (mut m, mut e) = if exp == 0 {
        (frac, -1074)
    } else {
        (frac | (1u64 << 52), exp - 1075)
    };
    let tz = m.trailing_zeros();
    m >>= tz;
    e += tz as i32;
    let m = i128::from(m);
    (if v < 0.0 { -m } else { m }, e)
}

/// `m * 2^shift` modulo 2^128 (`shift >= 0`).
#[inline]
fn shifted(m: i128, shift: i32) -> i128 {
    if shift >= 128 {
        0
    } else {
        m.wrapping_shl(shift as u32)
    }
}

/// Runs longer than this many cells (tracks within 2^-16 of an axis) are
/// left to the rounded times: their `D_a / D_b` would not leave the `i128`
/// enough room.
const MAX_RUN: f64 = 65536.0;

/// Origins and tracks farther than this many cells from the first boundary
/// are left to the rounded times: the first `G` is found from an `f64`
/// estimate that must land within a cell.
const MAX_REACH: f64 = (1u64 << 40) as f64;

impl RunEnds {
    /// The run ends of `g`'s track over `[ta, tb]` with `major` the axis
    /// along which runs lie; `None` when the minor axis does not move or
    /// the numbers do not fit (see the module docs).
    fn new(g: &GridRay, major: usize, ta: f64, tb: f64) -> Option<Self> {
        let minor = 1 - major;
        let (o_a, d_a, o_b, d_b) = (g.origin[major], g.dir[major], g.origin[minor], g.dir[minor]);
        if d_b == 0.0 || d_a == 0.0 || ![o_a, d_a, o_b, d_b, ta, tb].iter().all(|v| v.is_finite()) {
            return None;
        }
        let (s_a, s_b) = (
            if d_a > 0.0 { 1 } else { -1 },
            if d_b > 0.0 { 1 } else { -1 },
        );
        let (p_a, p_b) = (o_a * s_a as f64, o_b * s_b as f64);
        let (big_a, big_b) = (d_a.abs(), d_b.abs());
        let reach = ta.abs().max(tb.abs());
        if big_a / big_b > MAX_RUN
            || p_a.abs() + reach * big_a > MAX_REACH
            || p_b.abs() + reach * big_b > MAX_REACH
        {
            return None;
        }
        let (pa_int, pb_int) = (p_a.floor(), p_b.floor());
        // Exact: both lie within a factor of two of p (Sterbenz).
        let (fa, fb) = (p_a - pa_int, p_b - pb_int);
        let (ma, ea) = decode(big_a);
        let (mb, eb) = decode(big_b);
        let (nfa, efa) = decode(fa);
        let (nfb, efb) = decode(fb);
        // The smallest power of two among the terms of G.
        let mut e = ea.min(eb);
        if nfb != 0 {
            e = e.min(efb + ea);
        }
        if nfa != 0 {
            e = e.min(efa + eb);
        }
        // D_a and D_b must leave room for G + D_a below 2^127.
        if ea - e > 60 || eb - e > 60 {
            return None;
        }
        let (da, db) = (ma << (ea - e), mb << (eb - e));
        let scale = (-f64::from(e)).exp2();
        let (da_f, db_f) = (big_a * scale, big_b * scale);
        // How far the rounded crossing times may stray, in units of G: each
        // is off by at most two roundings (2^-52 of the time), times the
        // terms of G at the farthest boundary the ray can need.
        let tol = 2f64.powi(-49) * ((reach * big_a + 1.0) * db_f + (reach * big_b + 1.0) * da_f);
        if tol.is_nan() || tol >= db_f / 8.0 {
            return None;
        }
        Some(Self {
            o_a,
            d_a,
            o_b,
            d_b,
            s_a,
            s_b,
            pa_int: pa_int as i64,
            pb_int: pb_int as i64,
            fractions: shifted(nfa.wrapping_mul(mb), efa + eb - e)
                .wrapping_sub(shifted(nfb.wrapping_mul(ma), efb + ea - e)),
            da,
            db,
            q: (da / db) as i64,
            rem: da % db,
            tol: tol.ceil() as i128 + 1,
            state: None,
            last: None,
            settled_by_rounding: 0,
        })
    }

    /// The rounded time at which the track crosses mirrored major boundary
    /// `x`: bit for bit [`GridRay::slab`]'s.
    #[inline]
    fn time_a(&self, x: i64) -> f64 {
        ((self.s_a * x) as f64 - self.o_a) / self.d_a
    }

    #[inline]
    fn time_b(&self, y: i64) -> f64 {
        ((self.s_b * y) as f64 - self.o_b) / self.d_b
    }

    /// `G(x, y)` from scratch, modulo 2^128.
    fn corner_test(&self, x: i64, y: i64) -> i128 {
        let (yr, xr) = (i128::from(y - self.pb_int), i128::from(x - self.pa_int));
        yr.wrapping_mul(self.da)
            .wrapping_sub(xr.wrapping_mul(self.db))
            .wrapping_add(self.fractions)
    }

    /// Puts the recurrence at mirrored minor boundary `y`: steps along
    /// when `y` is the next boundary, starts afresh otherwise.
    fn advance_to(&mut self, y: i64) -> Option<(i64, i128)> {
        match self.state {
            Some((sy, x, g)) if sy + 1 == y => {
                // Eq. 6-7: a short run, or a long one when the intercept
                // wraps past the corner.
                let (mut x, mut g) = (x + self.q, g + self.rem);
                if g >= self.db {
                    g -= self.db;
                    x += 1;
                }
                self.state = Some((y, x, g));
                return Some((x, g));
            }
            _ => {}
        }
        // The first boundary: estimate the last major boundary crossed, then
        // settle it exactly (the estimate is within a cell: MAX_REACH).
        let p_a = self.o_a * self.s_a as f64;
        let p_b = self.o_b * self.s_b as f64;
        let estimate = p_a + (y as f64 - p_b) * (self.d_a.abs() / self.d_b.abs());
        let mut x = estimate.floor() as i64;
        let mut g = self.corner_test(x, y);
        for _ in 0..4 {
            if g < 0 {
                x -= 1;
                g += self.db;
            } else if g >= self.db {
                x += 1;
                g -= self.db;
            } else {
                self.state = Some((y, x, g));
                return Some((x, g));
            }
        }
        None
    }

    /// At the minor boundary with coordinate `k` (the track crosses
    /// `minor = k`): the major-axis cell where the row being left ends and
    /// the one where the row being entered starts, as cell indices. They
    /// differ only where the track passes through the corner (both rows
    /// then touch both cells beside it). `None` when the recurrence could
    /// not start (the caller then uses the rounded times).
    #[inline]
    fn at_boundary(&mut self, k: i64) -> Option<(i64, i64)> {
        if let Some((lk, ends)) = self.last {
            if lk == k {
                return Some(ends);
            }
        }
        let y = self.s_b * k;
        let (mut x, g) = self.advance_to(y)?;
        let mut corner = false;
        if g < self.tol || g > self.db - self.tol {
            // Within rounding of a corner: the rounded times decide.
            self.settled_by_rounding += 1;
            let t = self.time_b(y);
            for _ in 0..4 {
                if self.time_a(x) > t {
                    x -= 1;
                } else if self.time_a(x + 1) <= t {
                    x += 1;
                } else {
                    break;
                }
            }
            corner = self.time_a(x) == t;
        }
        // Mirrored major cell `x` lies between boundaries `x` and `x + 1`.
        let cell = |x: i64| if self.s_a > 0 { x } else { -x - 1 };
        let ends = (cell(x), cell(x - i64::from(corner)));
        self.last = Some((k, ends));
        Some(ends)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::walk::{walk, Bounds};
    use std::ops::ControlFlow;

    /// The cells the definition says a track touches, by row of the minor
    /// axis, from the cell walk (which the brute force agrees with).
    fn cells_by_walk(g: &GridRay, major: usize, ta: f64, tb: f64) -> Vec<(i64, i64)> {
        let big = Bounds {
            u: (-1 << 40, 1 << 40),
            v: (-1 << 40, 1 << 40),
        };
        let mut out = Vec::new();
        let _ = walk(g, 1.0, big, ta, tb, |a, b, _, _| {
            out.push(if major == 0 { (b, a) } else { (a, b) });
            ControlFlow::Continue(())
        });
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The same cells from the runs: each row's cells from its first to
    /// its last; with the boundaries settled by the rounded times, or
    /// `None` where the intercept sequence could not start (the runs then
    /// come from the rounded times alone).
    fn cells_by_runs(
        g: &GridRay,
        major: usize,
        ta: f64,
        tb: f64,
    ) -> (Vec<(i64, i64)>, Option<u64>) {
        let minor = 1 - major;
        let mut runs = Runs::new(g, major, ta, tb);
        let mut line = *g;
        line.dir[major] = 0.0;
        line.origin[major] = 0.5;
        let all = (-1 << 40, 1 << 40);
        let rows = Bounds {
            u: if minor == 0 { all } else { (0, 0) },
            v: if minor == 1 { all } else { (0, 0) },
        };
        let mut out = Vec::new();
        let _ = walk(&line, 1.0, rows, ta, tb, |a, b, r0, r1| {
            let k = if minor == 0 { a } else { b };
            let (first, last) = runs.cells(k, r0, r1);
            for m in first.min(last)..=first.max(last) {
                out.push((k, m));
            }
            ControlFlow::Continue(())
        });
        out.sort_unstable();
        out.dedup();
        (out, runs.ends.map(|e| e.settled_by_rounding))
    }

    struct Rng(u64);
    impl Rng {
        fn unit(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
        fn range(&mut self, a: f64, b: f64) -> f64 {
            a + (b - a) * self.unit()
        }
    }

    /// Compares the runs' cells with the walk's; returns the boundaries
    /// settled by the rounded times, `None` where the intercept sequence
    /// did not run.
    fn check(g: GridRay, ta: f64, tb: f64) -> Option<u64> {
        let major = if g.dir[0].abs() >= g.dir[1].abs() {
            0
        } else {
            1
        };
        let (got, settled) = cells_by_runs(&g, major, ta, tb);
        let want = cells_by_walk(&g, major, ta, tb);
        assert_eq!(got, want, "ray {g:?} over [{ta}, {tb}]");
        settled
    }

    #[test]
    fn decode_is_exact() {
        for v in [
            1.0,
            0.75,
            -3.5e-300,
            123456.789,
            1e300,
            f64::MIN_POSITIVE / 8.0,
        ] {
            let (m, e) = decode(v);
            assert_eq!(m as f64 * 2f64.powi(e), v, "{v}");
            assert!(m % 2 != 0);
        }
    }

    #[test]
    fn run_ends_match_the_definition_on_random_tracks() {
        let mut rng = Rng(7);
        let mut checked = 0;
        for _ in 0..20_000 {
            let phi = rng.range(0.0, std::f64::consts::TAU);
            let len = rng.range(0.01, 50.0);
            let g = GridRay {
                origin: [rng.range(-50.0, 300.0), rng.range(-50.0, 300.0), 0.0],
                dir: [phi.cos() * len, phi.sin() * len, 0.0],
            };
            let ta = rng.range(0.0, 3.0);
            let tb = ta + rng.range(0.0, 400.0 / len);
            checked += usize::from(check(g, ta, tb).is_some());
        }
        assert!(checked > 19_000, "only {checked} rays had exact run ends");
    }

    /// Tracks through lattice corners, and tracks a hair off them: where the
    /// rounded times and exact geometry part, the rounded times must win.
    #[test]
    fn run_ends_match_the_definition_through_and_beside_corners() {
        let mut rng = Rng(11);
        let mut settled = 0;
        for _ in 0..20_000 {
            // A rational slope p / q through a post: corners every q cells.
            let (p, q) = (
                (rng.unit() * 9.0) as i64 + 1,
                (rng.unit() * 40.0) as i64 + 1,
            );
            let (p, q) = if p > q { (q, p) } else { (p, q) };
            let (sa, sb) = (
                if rng.unit() < 0.5 { -1.0 } else { 1.0 },
                if rng.unit() < 0.5 { -1.0 } else { 1.0 },
            );
            let scale = rng.range(0.1, 30.0);
            let mut dir = [sa * q as f64 * scale, sb * p as f64 * scale, 0.0];
            let mut origin = [
                (rng.unit() * 200.0).floor(),
                (rng.unit() * 200.0).floor(),
                0.0,
            ];
            if rng.unit() < 0.5 {
                dir.swap(0, 1);
            }
            // Off the corners by a few ulps, or by nothing.
            let nudge = match (rng.unit() * 4.0) as u32 {
                0 => 0.0,
                1 => 1e-15,
                2 => -1e-13,
                _ => 4e-12,
            };
            origin[(rng.unit() * 2.0) as usize] += nudge;
            let g = GridRay { origin, dir };
            let tb = 200.0 / scale / q as f64;
            if let Some(s) = check(g, 0.0, tb) {
                settled += s;
            }
        }
        assert!(settled > 0, "no corner was settled by the rounded times");
    }

    #[test]
    fn far_or_axis_hugging_tracks_are_left_to_the_rounded_times() {
        let g = GridRay {
            origin: [1e15, 3.5, 0.0],
            dir: [1.0, 0.1, 0.0],
        };
        assert!(RunEnds::new(&g, 0, 0.0, 10.0).is_none());
        let g = GridRay {
            origin: [1.5, 3.5, 0.0],
            dir: [1.0, 1e-9, 0.0],
        };
        assert!(RunEnds::new(&g, 0, 0.0, 10.0).is_none());
        let g = GridRay {
            origin: [1.5, 3.5, 0.0],
            dir: [1.0, 0.0, 0.0],
        };
        assert!(RunEnds::new(&g, 0, 0.0, 10.0).is_none());
    }
}
