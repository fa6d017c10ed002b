//! Timonen's convex hull tree (2013, sec. 4-5): every local horizon of every
//! point of a profile, in time linear in the number of horizons.
//!
//! Along a profile walked from its far end (`p_0`) to its near end, the
//! newest point `R = p_n` sees the terrain behind it in visible segments.
//! Each segment's **local horizon** is the sight line from `R` that grazes
//! the segment's last visible point `p_i^R` (going outwards) before the
//! terrain drops out of view; the sight line to `p_0` counts when nothing
//! blocks it. They describe visibility completely: the segment starting at
//! one horizon point ends where the next horizon's sight line meets it. This
//! is what intervisibility and indirect light need, beyond the single
//! horizon angle (the steepest of them) that [`crate::algorithms::horizon::line`] keeps.
//!
//! The tree holds the upper convex hull of every segment from its first
//! point to `R`; hulls share their points near `R`, and the root's children
//! are exactly the local horizon points. [`HullTree::push`] adds the next
//! point as the new root and restores convexity along every path
//! (Algorithm 1, iteratively); a point that starts a new convex section is
//! duplicated as a permanent leaf.
//!
//! **Safe zone** (sec. 7, Algorithm 3). Most often the new point simply
//! replaces the old root: every child of the old root moves to it and no
//! grandchild changes. With the safe zone on ([`HullTree::with_safe_zone`]),
//! the tree keeps, for distances `b1..b2` just ahead, the lowest of the
//! lines from each child's first grandchild through that child (Algorithm
//! 3); a new point below it (by a margin against rounding) whose old root's
//! nearest child fails the convexity test takes the old root's place in
//! O(1), with exactly the tree Algorithm 1 would leave. The zone is
//! rebuilt, O(children), after any other change or when a point lands
//! beyond `b2`.
//!
//! **A raised eye.** [`HullTree::eye_horizons`] gives the local horizons
//! of a point above the profile's end (an observer's eye, not a profile
//! point) by running Algorithm 1's tests against the eye without changing
//! the tree: the tree then goes on with the ground.
//!
//! We depart from the paper in two details: the convex/concave test of
//! eq. 1 uses the chord between neighbours (our profile vertices are not
//! evenly spaced), and the recursion runs on an explicit stack.

/// One node: a profile point, with doubly linked children, first = farthest.
#[derive(Debug, Clone, Copy)]
struct Node {
    point: usize,
    parent: Option<usize>,
    first: Option<usize>,
    last: Option<usize>,
    prev: Option<usize>,
    next: Option<usize>,
}

/// The convex hull tree of a profile pushed point by point, far end first.
#[derive(Debug, Default)]
pub struct HullTree {
    points: Vec<[f64; 2]>,
    nodes: Vec<Node>,
    root: Option<usize>,
    /// Per point: whether it is in a convex section (eq. 1).
    convex: Vec<bool>,
    /// Calls of the convexity step (Timonen's iterations).
    pub iterations: u64,
    safe_zone: bool,
    zone: Option<Zone>,
    /// Points that replaced the root through the safe zone.
    pub replacements: u64,
    /// Children visited to rebuild the safe zone.
    pub zone_visits: u64,
    /// The root's children now, and summed after every push: the paper's
    /// `m` (its horizons; ours also hold segment-start duplicates and
    /// continuations, which [`HullTree::horizons`] drops).
    degree: u64,
    pub root_children: u64,
    /// Algorithm 1's stack, kept between pushes.
    stack: Vec<(usize, usize)>,
}

/// The safe zone: for distances `b1 < d <= b2`, a point below the chord
/// from `(b1, h1)` to `(b2, h2)` leaves every first grandchild's test
/// passing.
#[derive(Debug, Clone, Copy)]
struct Zone {
    b1: f64,
    b2: f64,
    h1: f64,
    h2: f64,
}

/// How far ahead the safe zone reaches, in spacings of the last step.
const ZONE_STEPS: f64 = 8.0;

/// The orientation of three profile points `(d, h)`: positive when they
/// turn counter-clockwise, zero when collinear, exactly for the floating
/// point inputs (Shewchuk's adaptive predicate, the `robust` crate). Every
/// visibility decision goes through it, so that methods that decide the
/// same question in different orders agree at exact ties (flat plateaus,
/// repeated heights, an eye level with a far ridge), as rounded cross
/// products do not.
#[inline]
pub(crate) fn orient([d0, h0]: [f64; 2], [d1, h1]: [f64; 2], [d2, h2]: [f64; 2]) -> f64 {
    robust::orient2d(
        robust::Coord { x: d0, y: h0 },
        robust::Coord { x: d1, y: h1 },
        robust::Coord { x: d2, y: h2 },
    )
}

/// Whether `mid` is strictly above the chord from `far` to `near`.
#[inline]
fn above(far: [f64; 2], mid: [f64; 2], near: [f64; 2]) -> bool {
    orient(far, mid, near) < 0.0
}

/// Whether, seen from `eye` (nearer than both), point `a` rises strictly
/// higher than point `b`: a steeper sight line.
#[inline]
pub(crate) fn steeper(eye: [f64; 2], a: [f64; 2], b: [f64; 2]) -> bool {
    orient(eye, a, b) > 0.0
}

impl HullTree {
    pub fn new() -> Self {
        Self::default()
    }

    /// A tree that replaces its root through the safe zone where it can.
    pub(crate) fn with_safe_zone() -> Self {
        Self {
            safe_zone: true,
            ..Self::default()
        }
    }

    /// Empties the tree for a new profile, keeping its memory, its safe
    /// zone setting and its counters.
    pub(crate) fn restart(&mut self) {
        self.points.clear();
        self.nodes.clear();
        self.convex.clear();
        self.root = None;
        self.zone = None;
        self.degree = 0;
    }

    /// The number of points pushed.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Rebuilds the safe zone ahead of the root (Algorithm 3).
    fn rebuild_zone(&mut self) {
        let Some(root) = self.root else { return };
        let [d, _] = self.at(root);
        let n = self.points.len();
        let step = if n >= 2 {
            d - self.points[n - 2][0]
        } else {
            0.0
        };
        let (b1, b2) = (d, d + ZONE_STEPS * step);
        let (mut h1, mut h2) = (f64::INFINITY, f64::INFINITY);
        let mut child = self.nodes[root].first;
        while let Some(c) = child {
            self.zone_visits += 1;
            if let Some(g) = self.nodes[c].first {
                let ([dg, hg], [dc, hc]) = (self.at(g), self.at(c));
                let line = |x: f64| hc + (hc - hg) / (dc - dg) * (x - dc);
                (h1, h2) = (h1.min(line(b1)), h2.min(line(b2)));
            }
            child = self.nodes[c].next;
        }
        self.zone = (b2 > b1).then_some(Zone { b1, b2, h1, h2 });
    }

    /// Puts point `n` in the root's place where the safe zone allows.
    fn replace_root(&mut self, n: usize) -> bool {
        let Some(root) = self.root.filter(|_| self.safe_zone) else {
            return false;
        };
        let [d, h] = self.points[n];
        if self.zone.is_none_or(|z| d > z.b2) {
            self.rebuild_zone();
        }
        let Some(z) = self.zone.filter(|z| d > z.b1 && d <= z.b2) else {
            return false;
        };
        let chord = if z.h1.is_finite() && z.h2.is_finite() {
            z.h1 + (z.h2 - z.h1) * (d - z.b1) / (z.b2 - z.b1)
        } else {
            f64::INFINITY
        };
        let margin = 1e-9 * (1.0 + z.h1.abs().max(z.h2.abs()).min(1e12));
        let Some(last) = self.nodes[root].last else {
            return false;
        };
        // NaN heights never replace the root.
        let below = h < chord - margin;
        if !below || above(self.at(last), self.at(root), [d, h]) {
            return false;
        }
        self.nodes[root].point = n;
        self.replacements += 1;
        true
    }

    fn node(&mut self, point: usize) -> usize {
        self.nodes.push(Node {
            point,
            parent: None,
            first: None,
            last: None,
            prev: None,
            next: None,
        });
        self.nodes.len() - 1
    }

    fn unlink(&mut self, v: usize) {
        let Node {
            parent, prev, next, ..
        } = self.nodes[v];
        let p = parent.expect("unlink a child");
        match prev {
            Some(q) => self.nodes[q].next = next,
            None => self.nodes[p].first = next,
        }
        match next {
            Some(q) => self.nodes[q].prev = prev,
            None => self.nodes[p].last = prev,
        }
        let n = &mut self.nodes[v];
        (n.parent, n.prev, n.next) = (None, None, None);
        if Some(p) == self.root {
            self.degree -= 1;
        }
    }

    /// Makes `v` a child of `p` just before `before` (or last).
    fn link(&mut self, v: usize, p: usize, before: Option<usize>) {
        let prev = match before {
            Some(b) => self.nodes[b].prev,
            None => self.nodes[p].last,
        };
        let n = &mut self.nodes[v];
        (n.parent, n.prev, n.next) = (Some(p), prev, before);
        match prev {
            Some(q) => self.nodes[q].next = Some(v),
            None => self.nodes[p].first = Some(v),
        }
        match before {
            Some(b) => self.nodes[b].prev = Some(v),
            None => self.nodes[p].last = Some(v),
        }
        if Some(p) == self.root {
            self.degree += 1;
        }
    }

    fn at(&self, v: usize) -> [f64; 2] {
        self.points[self.nodes[v].point]
    }

    /// Adds the next point `(d, h)` (distance along the profile, growing;
    /// height) as the new receiver.
    pub fn push(&mut self, d: f64, h: f64) {
        let n = self.points.len();
        self.points.push([d, h]);
        self.convex.push(true);
        if self.replace_root(n) {
            self.segment_start(n);
            self.root_children += self.degree;
            return;
        }
        let root = self.node(n);
        let Some(old) = self.root.replace(root) else {
            return;
        };
        self.degree = 0;
        self.link(old, root, None);
        // Restore convexity: triplets (child -> parent -> root).
        let mut stack = std::mem::take(&mut self.stack);
        if let Some(c) = self.nodes[old].first {
            stack.push((c, old));
        }
        while let Some((c, par)) = stack.pop() {
            self.iterations += 1;
            if above(self.at(c), self.at(par), self.at(root)) {
                continue;
            }
            let next = self.nodes[c].next;
            self.unlink(c);
            self.link(c, root, Some(par));
            match next {
                // The next sibling is now `par`'s first child: step wider.
                Some(s) => stack.push((s, par)),
                // `par` is orphaned: no hull passes through it any more.
                None => self.unlink(par),
            }
            if let Some(g) = self.nodes[c].first {
                stack.push((g, c)); // step deeper
            }
        }
        self.stack = stack;
        self.segment_start(n);
        self.root_children += self.degree;
        if self.safe_zone {
            self.rebuild_zone();
        }
    }

    /// Did the point before `n` start a new convex section (eq. 1)? Then it
    /// starts a segment: a permanent leaf under the root.
    fn segment_start(&mut self, n: usize) {
        let root = self.root.expect("a root");
        let prev = n - 1;
        if prev >= 1 {
            let (a, b, c) = (self.points[prev - 1], self.points[prev], self.points[n]);
            let turn = orient(a, b, c);
            let here = if turn < 0.0 {
                true
            } else if turn > 0.0 {
                false
            } else {
                self.convex[prev - 1]
            };
            self.convex[prev] = here;
        }
        let starts = prev == 0 || (self.convex[prev] && !self.convex[prev - 1]);
        if starts {
            let leaf = self.node(prev);
            self.link(leaf, root, None);
        }
    }

    /// The local horizon points, as profile indices, nearest first, of an
    /// eye at `(d, h)` beyond the newest point (`d` greater than its
    /// distance): Algorithm 1's tests against the eye, on a stack, without
    /// changing the tree. `stack` is scratch space; returns the tests run.
    pub(crate) fn eye_horizons(
        &self,
        [d, h]: [f64; 2],
        out: &mut Vec<usize>,
        stack: &mut Vec<(usize, Option<usize>)>,
    ) -> u64 {
        out.clear();
        let Some(root) = self.root else { return 0 };
        let eye = [d, h];
        let mut tests = 0;
        stack.clear();
        stack.push((root, self.nodes[root].first));
        while let Some((par, next)) = stack.last_mut() {
            let par = *par;
            match *next {
                // Every child of `par` went to the eye: `par` is off every
                // hull, unless it never had a child (a segment's start).
                None => {
                    if self.nodes[par].first.is_none() {
                        out.push(self.nodes[par].point);
                    }
                    stack.pop();
                }
                Some(c) => {
                    tests += 1;
                    if above(self.at(c), self.at(par), eye) {
                        out.push(self.nodes[par].point);
                        stack.pop();
                    } else {
                        *next = self.nodes[c].next;
                        stack.push((c, self.nodes[c].first));
                    }
                }
            }
        }
        // The newest point is always seen; whether it starts a segment for
        // the eye is the filter's to say.
        out.push(self.points.len() - 1);
        self.keep_transitions(eye, out);
        tests
    }

    /// Sorts candidate horizon points nearest first and keeps those beyond
    /// which the view from `eye` does not simply go on (see `horizons`).
    fn keep_transitions(&self, eye: [f64; 2], out: &mut Vec<usize>) {
        out.sort_unstable_by(|a, b| b.cmp(a));
        out.dedup();
        out.retain(|&i| i == 0 || steeper(eye, self.points[i], self.points[i - 1]));
    }

    /// The local horizon points of the newest point, as profile indices,
    /// nearest first (the order their sight lines rise in).
    pub fn horizons(&self) -> Vec<usize> {
        let mut out: Vec<usize> = Vec::new();
        let Some(root) = self.root else { return out };
        let mut child = self.nodes[root].last;
        while let Some(c) = child {
            let p = self.nodes[c].point;
            if out.last() != Some(&p) {
                out.push(p);
            }
            child = self.nodes[c].prev;
        }
        // A segment's hull may end on a point beyond which the view goes
        // on into the next segment (both visible): not a transition.
        self.keep_transitions(self.points[self.points.len() - 1], &mut out);
        out
    }
}

/// The local horizon points of the last point of `profile` (distance
/// growing, height), by brute force: walking outwards, a vertex is visible
/// when its slope from the receiver reaches the steepest so far, and it is a
/// horizon point when it is visible and the next vertex out is not (or it
/// is the first point of the profile). Nearest first.
pub fn local_horizons_brute(profile: &[[f64; 2]]) -> Vec<usize> {
    let n = profile.len() - 1;
    let eye = profile[n];
    let mut out = Vec::new();
    let mut steepest: Option<usize> = None;
    for i in (0..n).rev() {
        if steepest.is_none_or(|s| !steeper(eye, profile[s], profile[i])) {
            steepest = Some(i);
            if i == 0 || steeper(eye, profile[i], profile[i - 1]) {
                out.push(i);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_valley_behind_a_ridge() {
        // Far hill, valley, near ridge, receiver: two visible segments.
        let profile = [
            [0.0, 50.0],
            [1.0, 60.0],
            [2.0, 0.0],
            [3.0, 20.0],
            [4.0, 10.0],
            [5.0, 0.0],
        ];
        let mut tree = HullTree::new();
        for p in profile {
            tree.push(p[0], p[1]);
        }
        assert_eq!(local_horizons_brute(&profile), vec![3, 1]);
        assert_eq!(tree.horizons(), vec![3, 1]);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(500))]
        /// Every receiver of random profiles (small integer heights, so
        /// that collinear points and ties are common).
        #[test]
        fn equals_brute_force_at_every_receiver(
            steps in proptest::collection::vec((1u8..4, 0u8..12), 1..60)
        ) {
            let mut profile = Vec::new();
            let mut d = 0.0;
            let mut tree = HullTree::new();
            for (step, h) in steps {
                d += f64::from(step);
                profile.push([d, f64::from(h)]);
                tree.push(d, f64::from(h));
                if profile.len() >= 2 {
                    proptest::prop_assert_eq!(tree.horizons(), local_horizons_brute(&profile), "{:?}", profile);
                }
            }
        }

        /// An eye above the newest point sees what the brute force from
        /// the eye sees, and the safe zone changes nothing but the work.
        #[test]
        fn eye_and_safe_zone_equal_brute_force(
            steps in proptest::collection::vec((1u8..4, 0u8..12), 1..60),
            eye in 0u8..6,
        ) {
            let mut profile: Vec<[f64; 2]> = Vec::new();
            let mut d = 0.0;
            let (mut plain, mut zoned) = (HullTree::new(), HullTree::with_safe_zone());
            let (mut out, mut stack) = (Vec::new(), Vec::new());
            for (step, h) in steps {
                d += f64::from(step);
                if !profile.is_empty() {
                    let e = [d, f64::from(h) + f64::from(eye)];
                    let mut seen = profile.clone();
                    seen.push(e);
                    zoned.eye_horizons(e, &mut out, &mut stack);
                    proptest::prop_assert_eq!(&out, &local_horizons_brute(&seen), "{:?}", seen);
                }
                profile.push([d, f64::from(h)]);
                plain.push(d, f64::from(h));
                zoned.push(d, f64::from(h));
                proptest::prop_assert_eq!(zoned.horizons(), plain.horizons());
            }
        }

        /// Timonen's bound (sec. 6): a line of n points costs at most
        /// 2m + n iterations of Algorithm 1, m the root's children summed
        /// over the pushes (his horizons; our filtered horizons are fewer,
        /// and the bound need not hold for them).
        #[test]
        fn iterations_within_two_m_plus_n(
            steps in proptest::collection::vec((0.01f64..3.0, -50f64..50.0), 1..200),
            ties in proptest::collection::vec(0u8..4, 1..200),
        ) {
            for integer in [false, true] {
                let mut tree = HullTree::new();
                let (mut d, mut filtered) = (0.0, 0);
                let heights: Vec<f64> = if integer {
                    ties.iter().map(|&h| f64::from(h)).collect()
                } else {
                    steps.iter().map(|s| s.1).collect()
                };
                for (i, h) in heights.iter().enumerate() {
                    d += if integer { 1.0 } else { steps[i % steps.len()].0 };
                    tree.push(d, *h);
                    filtered += tree.horizons().len() as u64;
                }
                let (m, n) = (tree.root_children, heights.len() as u64);
                proptest::prop_assert!(tree.iterations <= 2 * m + n, "{} > 2 {m} + {n}", tree.iterations);
                proptest::prop_assert!(filtered <= m);
            }
        }

        /// The same with real-valued spacing and heights.
        #[test]
        fn equals_brute_force_on_real_profiles(
            steps in proptest::collection::vec((0.01f64..3.0, -50f64..50.0), 1..80)
        ) {
            let mut profile = Vec::new();
            let mut d = 0.0;
            let mut tree = HullTree::new();
            for (step, h) in steps {
                d += step;
                profile.push([d, h]);
                tree.push(d, h);
                if profile.len() >= 2 {
                    proptest::prop_assert_eq!(tree.horizons(), local_horizons_brute(&profile));
                }
            }
        }
    }
}
