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
//! horizon angle (the steepest of them) that [`super::line`] keeps.
//!
//! The tree holds the upper convex hull of every segment from its first
//! point to `R`; hulls share their points near `R`, and the root's children
//! are exactly the local horizon points. [`HullTree::push`] adds the next
//! point as the new root and restores convexity along every path
//! (Algorithm 1, iteratively); a point that starts a new convex section is
//! duplicated as a permanent leaf.
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
}

/// Whether `mid` is strictly above the chord from `far` to `near`.
fn above([d0, h0]: [f64; 2], [d1, h1]: [f64; 2], [d2, h2]: [f64; 2]) -> bool {
    (h1 - h0) * (d2 - d0) > (h2 - h0) * (d1 - d0)
}

impl HullTree {
    pub fn new() -> Self {
        Self::default()
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
        let root = self.node(n);
        let Some(old) = self.root.replace(root) else {
            return;
        };
        self.link(old, root, None);
        // Restore convexity: triplets (child -> parent -> root).
        let mut stack = Vec::new();
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
        // Did the previous point start a new convex section (eq. 1)? Then
        // it starts a segment: a permanent leaf under the root.
        let prev = n - 1;
        if prev >= 1 {
            let (a, b, c) = (self.points[prev - 1], self.points[prev], self.points[n]);
            let here = if above(a, b, c) {
                true
            } else if above([a[0], -a[1]], [b[0], -b[1]], [c[0], -c[1]]) {
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
        out.sort_unstable_by(|a, b| b.cmp(a));
        out.dedup();
        // A segment's hull may end on a point beyond which the view goes
        // on into the next segment (both visible): not a transition.
        let [dr, hr] = self.points[self.points.len() - 1];
        let slope = |i: usize| (self.points[i][1] - hr) / (dr - self.points[i][0]);
        out.retain(|&i| i == 0 || slope(i - 1) < slope(i));
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
    let [dr, hr] = profile[n];
    let slope = |i: usize| (profile[i][1] - hr) / (dr - profile[i][0]);
    let mut out = Vec::new();
    let mut steepest = f64::NEG_INFINITY;
    for i in (0..n).rev() {
        let s = slope(i);
        if s >= steepest {
            steepest = s;
            if i == 0 || slope(i - 1) < s {
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
