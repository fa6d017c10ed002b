//! Grid traversal: every node of a square grid that a ray's ground track
//! touches, in order of entry time.
//!
//! This is Amanatides and Woo's DDA with one change that makes it exact for
//! our purposes: a node is "touched" when the closed square meets the ray
//! segment, the test that the brute force uses ([`GridRay::square`]), so a
//! ray through a corner also visits the two nodes it only grazes, and a ray
//! running exactly along a grid line visits the nodes on both sides. Every
//! crossing time is computed from the ray and the boundary itself, never
//! accumulated, so the walk and the brute force agree bit for bit on which
//! nodes a ray touches and when.

use std::ops::ControlFlow;

use crate::surface::GridRay;

/// One axis of the walk: nodes `k` cover `[k * size, (k + 1) * size]`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Axis {
    o: f64,
    d: f64,
    size: f64,
    /// The node the ray is in just after the current time (for `d == 0`,
    /// the lower of the one or two nodes it runs in or along).
    forward: i64,
    /// For `d == 0`: whether the ray runs exactly along the boundary between
    /// `forward` and `forward + 1`, touching both.
    both: bool,
}

impl Axis {
    /// Boundary `k * size` is crossed at this parameter (`d != 0`).
    #[inline]
    fn boundary(&self, k: i64) -> f64 {
        (k as f64 * self.size - self.o) / self.d
    }

    /// The axis state at parameter `t`, and the nodes touched at `t`.
    /// Inlined: the parametric tracer starts a walk after every leap (two
    /// calls a leap), and folded into the walk, whose cell size is the
    /// constant 1, the start costs 280 instructions a ray less and that
    /// tracer runs 1.08x faster at 8192² (docs/BENCHMARKS.md).
    #[inline]
    fn start(o: f64, d: f64, size: f64, t: f64) -> (Self, [i64; 2], usize) {
        let mut a = Self {
            o,
            d,
            size,
            forward: 0,
            both: false,
        };
        if d == 0.0 {
            let q = o / size;
            a.forward = q.floor() as i64;
            // Exactly on a boundary: the ray runs along it, touching both sides.
            if q == q.floor() {
                a.forward -= 1;
                a.both = true;
                return (a, [a.forward, a.forward + 1], 2);
            }
            return (a, [a.forward, 0], 1);
        }
        let mut k = ((o + t * d) / size).floor() as i64;
        // `k` starts at most a node or two from the answer; the loops only
        // correct the rounding of the division. They are bounded all the
        // same: on absurd rays (an origin 1e20 cells away) boundaries round
        // together and an unbounded correction would never end.
        let mut fix = MAX_START_FIX;
        if d > 0.0 {
            // forward = max { k : boundary(k) <= t }
            while a.boundary(k) > t && fix > 0 {
                k -= 1;
                fix -= 1;
            }
            while a.boundary(k + 1) <= t && fix > 0 {
                k += 1;
                fix -= 1;
            }
            a.forward = k;
            if a.boundary(k) == t {
                return (a, [k - 1, k], 2);
            }
        } else {
            // Moving to lower k: forward = min { k : boundary(k + 1) <= t }
            while a.boundary(k + 1) > t && fix > 0 {
                k += 1;
                fix -= 1;
            }
            while a.boundary(k) <= t && fix > 0 {
                k -= 1;
                fix -= 1;
            }
            a.forward = k;
            if a.boundary(k + 1) == t {
                return (a, [k + 1, k], 2);
            }
        }
        (a, [a.forward, 0], 1)
    }

    /// When the ray next leaves `forward` (infinity for `d == 0`).
    #[inline]
    fn next_event(&self) -> f64 {
        if self.d > 0.0 {
            self.boundary(self.forward + 1)
        } else if self.d < 0.0 {
            self.boundary(self.forward)
        } else {
            f64::INFINITY
        }
    }

    #[inline]
    fn advance(&mut self) {
        self.forward += if self.d > 0.0 { 1 } else { -1 };
    }

    /// Nodes the ray is in on the open interval after the current time.
    #[inline]
    fn current(&self) -> ([i64; 2], usize) {
        if self.both {
            ([self.forward, self.forward + 1], 2)
        } else {
            ([self.forward, 0], 1)
        }
    }

    /// Whether no node at or beyond `forward` can lie in `lo..=hi`.
    #[inline]
    fn gone(&self, lo: i64, hi: i64) -> bool {
        (self.d > 0.0 && self.forward > hi) || (self.d < 0.0 && self.forward < lo)
    }
}

/// Most corrections of a start node's rounding (see [`Axis::start`]).
const MAX_START_FIX: u32 = 64;

/// Index bounds of a walk (inclusive), per axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Bounds {
    pub u: (i64, i64),
    pub v: (i64, i64),
}

impl Bounds {
    #[inline]
    fn contains(&self, a: i64, b: i64) -> bool {
        self.u.0 <= a && a <= self.u.1 && self.v.0 <= b && b <= self.v.1
    }
}

/// Calls `visit(a, b, t0, t1)` for every node `(a, b)` in `bounds` whose
/// closed square `[a, a + 1] x [b, b + 1] * size` meets the ray on
/// `[ta, tb]`, in order of `t0` (nodes entered at the same instant, as at a
/// corner, in any order), where `[t0, t1]` is the node's interval from
/// [`GridRay::square`]. Stops when `visit` breaks.
pub(crate) fn walk(
    ray: &GridRay,
    size: f64,
    bounds: Bounds,
    ta: f64,
    tb: f64,
    visit: impl FnMut(i64, i64, f64, f64) -> ControlFlow<()>,
) -> ControlFlow<()> {
    walk_from(ray, size, bounds, ta, (ta, tb), visit)
}

/// [`walk`] over `[ta, tb]` that starts at `t_start` instead of `ta`: the
/// nodes touched at or after `t_start`, each with its whole interval within
/// `[ta, tb]` (a node entered before `t_start` keeps its earlier `t0`), so
/// that a tracer resuming after a leap tests cells exactly as a walk from
/// the start would.
pub(crate) fn walk_from(
    ray: &GridRay,
    size: f64,
    bounds: Bounds,
    t_start: f64,
    (ta, tb): (f64, f64),
    mut visit: impl FnMut(i64, i64, f64, f64) -> ControlFlow<()>,
) -> ControlFlow<()> {
    if ta.is_nan() || tb.is_nan() || t_start.is_nan() || ta > tb || t_start > tb {
        return ControlFlow::Continue(());
    }
    let mut node = |a: i64, b: i64| -> ControlFlow<()> {
        if !bounds.contains(a, b) {
            return ControlFlow::Continue(());
        }
        let (t0, t1) = ray.square(a as f64 * size, b as f64 * size, size, ta, tb);
        if t0 > t1 {
            return ControlFlow::Continue(());
        }
        visit(a, b, t0, t1)
    };
    let t_start = t_start.max(ta);
    let (mut u, tu, nu) = Axis::start(ray.origin[0], ray.dir[0], size, t_start);
    let (mut v, tv, nv) = Axis::start(ray.origin[1], ray.dir[1], size, t_start);
    for &a in &tu[..nu] {
        for &b in &tv[..nv] {
            node(a, b)?;
        }
    }
    // Each step advances an axis by one node towards its far bound, so a
    // walk takes at most the bounds' spans plus the distance from its start
    // node to them; the cap makes that a guarantee whatever the rounding.
    let span = |a: &Axis, (lo, hi): (i64, i64)| {
        let outside = (lo - a.forward).max(a.forward - hi).max(0);
        (hi - lo).unsigned_abs() + outside.unsigned_abs() + 2
    };
    let mut steps_left = span(&u, bounds.u) + span(&v, bounds.v);
    loop {
        if u.gone(bounds.u.0, bounds.u.1) || v.gone(bounds.v.0, bounds.v.1) || steps_left == 0 {
            return ControlFlow::Continue(());
        }
        steps_left -= 1;
        let (eu, ev) = (u.next_event(), v.next_event());
        let te = eu.min(ev);
        // No further boundary (a vertical ray), or past the segment's end.
        if te == f64::INFINITY || te > tb {
            return ControlFlow::Continue(());
        }
        let (old_u, old_v) = (u.current(), v.current());
        if eu == te {
            u.advance();
        }
        if ev == te {
            v.advance();
        }
        let (new_u, new_v) = (u.current(), v.current());
        match (eu == te, ev == te) {
            (true, true) => {
                // A corner: the two nodes beside it are touched at one point.
                for &a in &new_u.0[..new_u.1] {
                    for &b in &old_v.0[..old_v.1] {
                        node(a, b)?;
                    }
                }
                for &a in &old_u.0[..old_u.1] {
                    for &b in &new_v.0[..new_v.1] {
                        node(a, b)?;
                    }
                }
                for &a in &new_u.0[..new_u.1] {
                    for &b in &new_v.0[..new_v.1] {
                        node(a, b)?;
                    }
                }
            }
            // One axis advanced: the new nodes are its new node(s) along the
            // other axis' current node(s).
            _ => {
                for &a in &new_u.0[..new_u.1] {
                    for &b in &new_v.0[..new_v.1] {
                        node(a, b)?;
                    }
                }
            }
        }
    }
}

/// The first node of one axis touched at `t` in travel order (the one
/// behind, where `t` is on a boundary): where a run starts when it starts
/// at the segment's start rather than at a boundary.
pub(crate) fn first_touched(o: f64, d: f64, t: f64) -> i64 {
    Axis::start(o, d, 1.0, t).1[0]
}

/// The last node of one axis touched at `t` in travel order (the one
/// ahead, where `t` is on a boundary): where a run ends when it ends at the
/// segment's end rather than at a boundary.
pub(crate) fn last_touched(o: f64, d: f64, t: f64) -> i64 {
    let (_, at, n) = Axis::start(o, d, 1.0, t);
    at[n - 1]
}
