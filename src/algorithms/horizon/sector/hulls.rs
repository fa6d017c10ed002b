//! The hulls in the nodes of Stewart's tree (sec. IV-B): each node's upper
//! convex hull, in the centre plane `(t, w)`, of the processed posts under
//! it, sorted by `t`. Two stores do the same two operations, the steepest
//! tangent from a post in front of every point and the insertion of a
//! post, with the same comparisons and so the same bits:
//!
//! * [`Heap`] keeps each hull in a vector of its own and walks it point by
//!   point, as Stewart does: a binary search for the insertion point, pops
//!   one at a time, a tangent scan that stops where the slopes turn down.
//! * [`Slab`] (AVX-512, eight points to a vector, or AVX2, four) keeps up
//!   to [`CAP`] points of every node in one array, `t`, `w` and the tags
//!   apart, and does each operation on all the points at once: every
//!   slope, or every pop test, in vectors; the tangent point and the runs
//!   of pops found as bits of the resulting masks; the kept tail moved by
//!   masked stores. A walk through the tree then has no branch that
//!   depends on the terrain but whether a hull is empty and whether the
//!   new post lands below it. A hull that outgrows `CAP` points (a dome's
//!   every post is on it) moves to the heap.
//!
//! A level's cost is its fixed part (a node, two data-dependent branches,
//! a pointer to a hull of six to nine points), not moving points: that
//! fixed part is what the slab shrinks (docs/BENCHMARKS.md, "Bounded
//! sectors, and the sector tree's constant factor").
//!
//! Why the masks give the scalar pops: a point left of the new post `p` is
//! popped when it lies on or below the segment from its left neighbour to
//! `p`, and the scalar loop pops from `p` leftwards while that holds. The
//! test of each point uses its original neighbour, which the loop has not
//! popped when it gets there, so the loop pops exactly the run of set bits
//! that ends next to `p`; likewise to the right.

use crate::algorithms::horizon::sector::Point;
use crate::terrain::steepest::{Steepest, Tag};

/// Points a node's hull holds in the slab before it moves to the heap.
/// Across the 64 sectors of the UTM SRTM tile, 0.0065 % of insertions left
/// a hull longer than 32 points; 7 % one longer than 16.
pub const CAP: usize = 32;

/// A node's length with this bit set: its hull is on the heap.
const ON_HEAP: u32 = 1 << 31;

/// The hulls of a tree's nodes. `len` is the node's count as the store
/// returned it (0: empty).
pub(super) trait Hulls<T> {
    fn with_nodes(nodes: usize) -> Self;
    /// The steepest slope from `(t, w)`, in front of every point, to node
    /// `v`'s hull (not empty); `steps` counts the points the scalar scan
    /// reads.
    fn tangent(&self, v: usize, len: u32, t: f64, w: f64, steps: &mut u64) -> Steepest<T>;
    /// Inserts `p` into node `v`'s hull: its new count, and whether `p`
    /// stayed out lying more than `margin` below the hull ([`well_below`]).
    fn insert(&mut self, v: usize, len: u32, p: Point<T>, margin: f64) -> (u32, bool);
    /// Empties node `v`'s hull (its posts are all processed).
    fn clear(&mut self, v: usize, len: u32);
    /// [`steepest_shift`] in the store's vector code.
    fn steepest_shift(t: &mut [f64], w: &mut [f64], p: (f64, f64)) -> Steepest<u32>;
}

/// Each hull in a vector of its own, walked point by point.
pub(super) struct Heap<T> {
    hulls: Vec<Vec<Point<T>>>,
}

impl<T: Copy + Default> Hulls<T> for Heap<T> {
    fn with_nodes(nodes: usize) -> Self {
        Self {
            hulls: vec![Vec::new(); nodes],
        }
    }

    #[inline]
    fn tangent(&self, v: usize, _: u32, t: f64, w: f64, steps: &mut u64) -> Steepest<T> {
        hull_tangent(&self.hulls[v], t, w, steps)
    }

    #[inline]
    fn insert(&mut self, v: usize, _: u32, p: Point<T>, margin: f64) -> (u32, bool) {
        let hull = &mut self.hulls[v];
        let below = hull_insert(hull, p, margin);
        (hull.len() as u32, below)
    }

    fn clear(&mut self, v: usize, _: u32) {
        self.hulls[v] = Vec::new();
    }

    #[inline]
    fn steepest_shift(t: &mut [f64], w: &mut [f64], p: (f64, f64)) -> Steepest<u32> {
        steepest_shift(t, w, p)
    }
}

/// The steepest slope from `p` to points `..n - 1` of `t` and `w` (as long
/// as each other, `n`) and which of them, those points moved up one and
/// `p` put first: a bucket's tail as a post joins it ([`crate::algorithms::horizon::sector::Bucket`]).
/// One pass from the end moves each point as it is read, where a scan and
/// then a `memmove` per column took longer than the moves (a few dozen
/// points). In independent lanes; every store runs this same code, so
/// the same point wins a tie in each.
#[inline(always)]
pub(super) fn steepest_shift(t: &mut [f64], w: &mut [f64], (tp, wp): (f64, f64)) -> Steepest<u32> {
    const LANES: usize = 8;
    let mut best = [Steepest::<u32>::default(); LANES];
    let w = &mut w[..t.len()];
    // Points `..end` are still to read and move.
    let mut end = t.len() - 1;
    while end >= LANES {
        let i = end - LANES;
        let whole = "a chunk of LANES";
        let tc: [f64; LANES] = t[i..end].try_into().expect(whole);
        let wc: [f64; LANES] = w[i..end].try_into().expect(whole);
        for l in 0..LANES {
            best[l].take((wc[l] - wp) / (tc[l] - tp), (i + l) as u32);
        }
        t[i + 1..=end].copy_from_slice(&tc);
        w[i + 1..=end].copy_from_slice(&wc);
        end = i;
    }
    while end > 0 {
        end -= 1;
        best[0].take((w[end] - wp) / (t[end] - tp), end as u32);
        (t[end + 1], w[end + 1]) = (t[end], w[end]);
    }
    (t[0], w[0]) = (tp, wp);
    best.into_iter()
        .fold(Steepest::default(), Steepest::steeper)
}

/// Whether the point `p = (t, w)` lies on or below the segment from `l`
/// to `r` (`l.t < t < r.t`, or `t` beyond `r` for the pops' tests), with
/// `sub`, `mul` and `le` of numbers or of vectors of them: one expression,
/// evaluated in the same order by [`below`] and by the kernels lane by
/// lane, so that both decide every point alike.
macro_rules! below {
    ($sub:expr, $mul:expr, $le:expr; $l:expr, $r:expr, $p:expr) => {{
        let (l, r, p) = ($l, $r, $p);
        $le(
            $mul($sub(p.1, l.1), $sub(r.0, l.0)),
            $mul($sub(r.1, l.1), $sub(p.0, l.0)),
        )
    }};
}

/// [`below!`] of numbers.
#[inline(always)]
fn below(l: (f64, f64), r: (f64, f64), p: (f64, f64)) -> bool {
    below!(|a: f64, b| a - b, |a: f64, b| a * b, |a: f64, b| a <= b; l, r, p)
}

/// Whether `p` lies more than `margin` below the segment from `l` to `r`
/// (`l.t < p.t < r.t`, or `p.t` at a point `l == r` of the hull). The
/// hull's points are posts; a hull over a superset of them lies above
/// that segment, so `p` is below it too, with `margin` to spare for
/// rounding: far above the rounding of [`below`] (a few ulps of the `w`
/// compared), so that the other hull's test finds it below as well.
#[inline(always)]
pub(super) fn well_below(l: (f64, f64), r: (f64, f64), p: (f64, f64), margin: f64) -> bool {
    let over = if r.0 > l.0 {
        l.1 + (r.1 - l.1) * ((p.0 - l.0) / (r.0 - l.0))
    } else {
        l.1
    };
    over - p.1 > margin
}

/// Inserts `p` into an upper hull sorted by `t`; whether it stayed out,
/// lying more than `margin` below the hull ([`well_below`]).
pub(super) fn hull_insert<T: Copy>(hull: &mut Vec<Point<T>>, p: Point<T>, margin: f64) -> bool {
    let (t, w) = (p.t, p.w);
    let i = hull.partition_point(|q| q.t < t);
    if i < hull.len() && hull[i].t == t {
        if hull[i].w >= w {
            let q = (hull[i].t, hull[i].w);
            return well_below(q, q, (t, w), margin);
        }
        hull.remove(i);
    }
    let at = |i: usize| (hull[i].t, hull[i].w);
    // Below the hull edge over `t`: not on the hull.
    if i > 0 && i < hull.len() && below(at(i - 1), at(i), (t, w)) {
        return well_below(at(i - 1), at(i), (t, w), margin);
    }
    hull.insert(i, p);
    let mut i = i;
    let at = |hull: &[Point<T>], i: usize| (hull[i].t, hull[i].w);
    while i >= 2 && below(at(hull, i - 2), at(hull, i), at(hull, i - 1)) {
        hull.remove(i - 1);
        i -= 1;
    }
    while i + 2 < hull.len() && below(at(hull, i), at(hull, i + 2), at(hull, i + 1)) {
        hull.remove(i + 1);
    }
    false
}

/// Steepest slope from `(t, w)` (left of every hull point) to the hull.
pub(super) fn hull_tangent<T: Copy + Default>(
    hull: &[Point<T>],
    t: f64,
    w: f64,
    steps: &mut u64,
) -> Steepest<T> {
    let mut best = Steepest::default();
    for q in hull {
        *steps += 1;
        let s = (q.w - w) / (q.t - t);
        if s < best.slope {
            break; // slopes to an upper hull rise, then fall
        }
        best = Steepest {
            slope: s,
            tag: q.tag,
        };
    }
    best
}

/// The vector code a [`Slab`] runs on one node's hull of `len <= CAP`
/// points (`t` and `w` the node's whole arrays; past `len` they hold
/// anything).
pub(super) trait Kernel {
    /// The first point `k` of the `len >= 1` where the slope from `(tp,
    /// wp)` to point `k + 1` is less than to point `k` (the last point
    /// where none is), and the slope to it: the lane of the vector
    /// division that found it, the bits a scalar division gives.
    ///
    /// # Safety
    /// The CPU runs the kernel's instructions.
    unsafe fn tangent(t: &[f64; CAP], w: &[f64; CAP], len: usize, p: (f64, f64)) -> (usize, f64);

    /// For a post `p`, bits of the points: `t` less than the post's;
    /// on or below the segment from the point before to the post (`left`,
    /// for `k >= 1`); on or below the segment from the post to the point
    /// after (`right`, for `k + 1 < len`); each [`below`] lane by lane.
    ///
    /// # Safety
    /// As [`Kernel::tangent`].
    unsafe fn pop_tests(t: &[f64; CAP], w: &[f64; CAP], len: usize, p: (f64, f64)) -> [u64; 3];

    /// Moves points `from..len` to start at `to` (`to + len - from <=
    /// CAP`).
    ///
    /// # Safety
    /// As [`Kernel::tangent`].
    unsafe fn move_tail(t: &mut [f64; CAP], w: &mut [f64; CAP], len: usize, from: usize, to: usize);

    /// [`steepest_shift`] compiled for the kernel's instructions (out of
    /// line, it would run in the baseline's two lanes).
    ///
    /// # Safety
    /// As [`Kernel::tangent`].
    unsafe fn steepest_shift(t: &mut [f64], w: &mut [f64], p: (f64, f64)) -> Steepest<u32>;
}

/// Up to [`CAP`] points of every node in one array (`[v * CAP + i]`), the
/// longer hulls on the heap, searched and updated by `K`'s vector code:
/// build it only where the CPU runs `K` ([`crate::plumbing::simd::level`]).
pub(super) struct Slab<T, K> {
    t: Vec<f64>,
    w: Vec<f64>,
    /// The points' posts, where `T` keeps them (else empty).
    tags: Vec<u32>,
    heap: Heap<T>,
    kernel: std::marker::PhantomData<K>,
}

impl<T: Tag<u32>, K: Kernel> Slab<T, K> {
    fn keeps_tags() -> bool {
        T::of(0).get().is_some()
    }

    /// Node `v`'s arrays.
    #[inline(always)]
    fn node(&self, v: usize) -> (&[f64; CAP], &[f64; CAP]) {
        let r = v * CAP..(v + 1) * CAP;
        let whole = "a node holds CAP points";
        (
            self.t[r.clone()].try_into().expect(whole),
            self.w[r].try_into().expect(whole),
        )
    }

    /// The hull of node `v` (`len` points in the slab) as the heap keeps it.
    fn points(&self, v: usize, len: usize) -> Vec<Point<T>> {
        let base = v * CAP;
        (base..base + len)
            .map(|i| Point {
                t: self.t[i],
                w: self.w[i],
                tag: self.tag(i),
            })
            .collect()
    }

    #[inline]
    fn tag(&self, i: usize) -> T {
        if Self::keeps_tags() {
            T::of(self.tags[i])
        } else {
            T::default()
        }
    }

    /// Inserts `p` where point `i` of node `v`'s `len` has the same `t`
    /// (two posts the same distance along the centre line): the higher
    /// stays, as in `hull_insert`.
    #[cold]
    fn tie(&mut self, v: usize, len: usize, i: usize, p: Point<T>, margin: f64) -> (u32, bool) {
        let q = (self.t[v * CAP + i], self.w[v * CAP + i]);
        if q.1 >= p.w {
            return (len as u32, well_below(q, q, (p.t, p.w), margin));
        }
        let range = v * CAP + i + 1..v * CAP + len;
        self.t.copy_within(range.clone(), v * CAP + i);
        self.w.copy_within(range.clone(), v * CAP + i);
        if Self::keeps_tags() {
            self.tags.copy_within(range, v * CAP + i);
        }
        self.insert(v, len as u32 - 1, p, margin)
    }

    /// Moves node `v`'s hull to the heap and inserts `p` there.
    #[cold]
    fn spill(&mut self, v: usize, len: usize, p: Point<T>) -> (u32, bool) {
        self.heap.hulls[v] = self.points(v, len);
        let (len, below) = self.heap.insert(v, 0, p, f64::INFINITY);
        (len | ON_HEAP, below)
    }
}

impl<T: Tag<u32>, K: Kernel> Hulls<T> for Slab<T, K> {
    fn with_nodes(nodes: usize) -> Self {
        Self {
            t: vec![0.0; nodes * CAP],
            w: vec![0.0; nodes * CAP],
            tags: if Self::keeps_tags() {
                vec![0; nodes * CAP]
            } else {
                Vec::new()
            },
            heap: Heap::with_nodes(nodes),
            kernel: std::marker::PhantomData,
        }
    }

    #[inline(always)]
    fn tangent(&self, v: usize, len: u32, t: f64, w: f64, steps: &mut u64) -> Steepest<T> {
        if len & ON_HEAP != 0 {
            return self.heap.tangent(v, len, t, w, steps);
        }
        let len = len as usize;
        let (ts, ws) = self.node(v);
        // SAFETY: a slab is built only where the CPU runs its kernel.
        let (k, slope) = unsafe { K::tangent(ts, ws, len, (t, w)) };
        *steps += (k + 2).min(len) as u64;
        Steepest {
            slope,
            tag: self.tag(v * CAP + k),
        }
    }

    #[inline(always)]
    fn insert(&mut self, v: usize, len: u32, p: Point<T>, margin: f64) -> (u32, bool) {
        if len & ON_HEAP != 0 {
            let (len, below) = self.heap.insert(v, len, p, margin);
            return (len | ON_HEAP, below);
        }
        let len = len as usize;
        let (ts, ws) = self.node(v);
        // SAFETY: a slab is built only where the CPU runs its kernel.
        let [before, left, right] = unsafe { K::pop_tests(ts, ws, len, (p.t, p.w)) };
        let i = (before & ((1u64 << len) - 1)).count_ones() as usize;
        if i < len && ts[i] == p.t {
            return self.tie(v, len, i, p, margin);
        }
        // Below the hull edge over `t`: not on the hull.
        if i > 0 && i < len {
            let (l, r) = ((ts[i - 1], ws[i - 1]), (ts[i], ws[i]));
            if below(l, r, (p.t, p.w)) {
                return (len as u32, well_below(l, r, (p.t, p.w), margin));
            }
        }
        let below_i = (1u64 << i) - 1;
        // Left: the pops run down from i - 1 while the bit is set; point 0
        // has no left neighbour and always stays.
        let kept = match i {
            0 => 0,
            _ => 64 - ((!left | 1) & below_i).leading_zeros() as usize,
        };
        // Right: the pops run up from i while the bit is set; the last
        // point has no right neighbour and always stays.
        let from = if i == len {
            len
        } else {
            let last = 1u64 << (len - 1);
            (((!right & (last - 1)) | last) & !below_i).trailing_zeros() as usize
        };
        let new_len = kept + 1 + (len - from);
        if new_len > CAP {
            return self.spill(v, len, p);
        }
        let r = v * CAP..(v + 1) * CAP;
        let whole = "a node holds CAP points";
        let ts: &mut [f64; CAP] = (&mut self.t[r.clone()]).try_into().expect(whole);
        let ws: &mut [f64; CAP] = (&mut self.w[r.clone()]).try_into().expect(whole);
        // The tail moves even where it stays put (nothing popped: two
        // insertions in five that reach here), a few masked stores
        // cheaper than the branch that went either way.
        // SAFETY: as above; `kept + 1 + len - from` points fit.
        unsafe { K::move_tail(ts, ws, len, from, kept + 1) };
        if Self::keeps_tags() {
            self.tags[r.clone()].copy_within(from..len, kept + 1);
        }
        ts[kept] = p.t;
        ws[kept] = p.w;
        if let Some(post) = p.tag.get() {
            self.tags[r.start + kept] = post;
        }
        (new_len as u32, false)
    }

    fn clear(&mut self, v: usize, len: u32) {
        if len & ON_HEAP != 0 {
            self.heap.clear(v, len);
        }
    }

    #[inline(always)]
    fn steepest_shift(t: &mut [f64], w: &mut [f64], p: (f64, f64)) -> Steepest<u32> {
        // SAFETY: a slab is built only where the CPU runs its kernel.
        unsafe { K::steepest_shift(t, w, p) }
    }
}

/// Where the slopes from a post first turn down (bit `k` of `turns`: the
/// slope to point `k + 1` is less than to point `k`), the last of `len`
/// points at the latest, and the slope there, read from the vectors the
/// kernel divided: the tangent's slope is not divided again on its own,
/// a division on the critical path of every level's query.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn first_turn<V: Copy, const N: usize>(turns: u64, len: usize, slope: [V; N]) -> (usize, f64) {
    let k = (turns | 1 << (len - 1)).trailing_zeros() as usize;
    debug_assert!(k < CAP && CAP <= N * size_of::<V>() / size_of::<f64>());
    // SAFETY: `V` is a vector of `f64` lanes, so `[V; N]` is `N * lanes`
    // of them in order, and `k < len <= CAP` of which lie within.
    let at_k = unsafe { slope.as_ptr().cast::<f64>().add(k).read() };
    (k, at_k)
}

/// [`Kernel`] in AVX-512: eight points to a vector, masks as bits.
#[cfg(target_arch = "x86_64")]
#[derive(Debug, Clone, Copy)]
pub(super) struct Avx512;

/// [`Kernel`] in AVX2: four points to a vector, masks as vectors.
#[cfg(target_arch = "x86_64")]
#[derive(Debug, Clone, Copy)]
pub(super) struct Avx2;

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{first_turn, Avx512, Kernel, CAP};
    use crate::terrain::steepest::Steepest;
    use std::arch::x86_64::*;

    const CHUNKS: usize = CAP / 8;

    /// The lanes of chunk `c` that hold one of `len` points.
    #[inline(always)]
    fn lanes(len: usize, c: usize) -> __mmask8 {
        let k = len.saturating_sub(8 * c).min(8);
        ((1u32 << k) - 1) as __mmask8
    }

    /// The node's `len` points, chunk by chunk (`+inf` and 0 past them),
    /// and one chunk more so that every point has a right neighbour.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    fn load(
        t: &[f64; CAP],
        w: &[f64; CAP],
        len: usize,
    ) -> ([__m512d; CHUNKS + 1], [__m512d; CHUNKS + 1]) {
        let mut tv = [_mm512_set1_pd(f64::INFINITY); CHUNKS + 1];
        let mut wv = [_mm512_setzero_pd(); CHUNKS + 1];
        for c in 0..len.div_ceil(8) {
            let m = lanes(len, c);
            // SAFETY: every lane is in the node's arrays.
            unsafe {
                tv[c] = _mm512_mask_loadu_pd(tv[c], m, t.as_ptr().add(8 * c));
                wv[c] = _mm512_maskz_loadu_pd(m, w.as_ptr().add(8 * c));
            }
        }
        (tv, wv)
    }

    /// Lanes `1..8` of `lo` and lane 0 of `hi` (`by` 1): each lane's next
    /// point; or lane 7 of `lo` and lanes `0..7` of `hi` (`by` 7): each
    /// lane's previous point.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    fn shift<const BY: i32>(hi: __m512d, lo: __m512d) -> __m512d {
        let (hi, lo) = (_mm512_castpd_si512(hi), _mm512_castpd_si512(lo));
        _mm512_castsi512_pd(_mm512_alignr_epi64::<BY>(hi, lo))
    }

    impl Kernel for Avx512 {
        #[inline]
        #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
        unsafe fn tangent(
            t: &[f64; CAP],
            w: &[f64; CAP],
            len: usize,
            (tp, wp): (f64, f64),
        ) -> (usize, f64) {
            let (t, w) = load(t, w, len);
            let (tp, wp) = (_mm512_set1_pd(tp), _mm512_set1_pd(wp));
            let mut slope = [_mm512_set1_pd(f64::NEG_INFINITY); CHUNKS + 1];
            for c in 0..len.div_ceil(8) {
                slope[c] = _mm512_mask_div_pd(
                    slope[c],
                    lanes(len, c),
                    _mm512_sub_pd(w[c], wp),
                    _mm512_sub_pd(t[c], tp),
                );
            }
            let mut turns = 0u64;
            for c in 0..len.div_ceil(8) {
                let next = shift::<1>(slope[c + 1], slope[c]);
                turns |= u64::from(_mm512_cmp_pd_mask::<_CMP_LT_OQ>(next, slope[c])) << (8 * c);
            }
            first_turn(turns, len, slope)
        }

        #[inline]
        #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
        unsafe fn pop_tests(
            t: &[f64; CAP],
            w: &[f64; CAP],
            len: usize,
            (tp, wp): (f64, f64),
        ) -> [u64; 3] {
            let (t, w) = load(t, w, len);
            let (tp, wp) = (_mm512_set1_pd(tp), _mm512_set1_pd(wp));
            let [mut before, mut left, mut right] = [0u64; 3];
            let zero = _mm512_setzero_pd();
            for c in 0..len.div_ceil(8) {
                let at = 8 * c;
                before |= u64::from(_mm512_cmp_pd_mask::<_CMP_LT_OQ>(t[c], tp)) << at;
                let prev = |x: &[__m512d]| shift::<7>(x[c], if c == 0 { zero } else { x[c - 1] });
                let next = |x: &[__m512d]| shift::<1>(x[c + 1], x[c]);
                let below = |l: (__m512d, __m512d), r: (__m512d, __m512d)| {
                    let le = _mm512_cmp_pd_mask::<_CMP_LE_OQ>;
                    below!(_mm512_sub_pd, _mm512_mul_pd, le; l, r, (t[c], w[c]))
                };
                let l = below((prev(&t), prev(&w)), (tp, wp));
                let r = below((tp, wp), (next(&t), next(&w)));
                left |= u64::from(l) << at;
                right |= u64::from(r) << at;
            }
            [before, left, right]
        }

        #[inline]
        #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
        unsafe fn steepest_shift(t: &mut [f64], w: &mut [f64], p: (f64, f64)) -> Steepest<u32> {
            super::steepest_shift(t, w, p)
        }

        #[inline]
        #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
        unsafe fn move_tail(
            t: &mut [f64; CAP],
            w: &mut [f64; CAP],
            len: usize,
            from: usize,
            to: usize,
        ) {
            let tail = ((1u64 << len) - 1) & !((1u64 << from) - 1);
            let by = to as isize - from as isize;
            // Every chunk is read before any is written.
            let (tv, wv) = load(t, w, len);
            for c in 0..len.div_ceil(8) {
                let m = (tail >> (8 * c)) as __mmask8;
                let at = (8 * c) as isize + by;
                // SAFETY: the lanes under `m` land on `to..to + len - from`
                // of the node; the others are not written.
                unsafe {
                    _mm512_mask_storeu_pd(t.as_mut_ptr().wrapping_offset(at), m, tv[c]);
                    _mm512_mask_storeu_pd(w.as_mut_ptr().wrapping_offset(at), m, wv[c]);
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{first_turn, Avx2, Kernel, CAP};
    use crate::terrain::steepest::Steepest;
    use std::arch::x86_64::*;

    const CHUNKS: usize = CAP / 4;

    /// The lane indices of chunk `c`.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn indices(c: usize) -> __m256i {
        let at = 4 * c as i64;
        _mm256_set_epi64x(at + 3, at + 2, at + 1, at)
    }

    /// The lanes of chunk `c` whose index is in `lo..hi`, as a vector mask.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn lanes(c: usize, lo: usize, hi: usize) -> __m256i {
        let i = indices(c);
        _mm256_and_si256(
            _mm256_cmpgt_epi64(i, _mm256_set1_epi64x(lo as i64 - 1)),
            _mm256_cmpgt_epi64(_mm256_set1_epi64x(hi as i64), i),
        )
    }

    /// The node's arrays, chunk by chunk, one chunk more (`+inf`, 0) so
    /// that every point has a right neighbour; past `len` anything.
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn load(
        t: &[f64; CAP],
        w: &[f64; CAP],
        len: usize,
    ) -> ([__m256d; CHUNKS + 1], [__m256d; CHUNKS + 1]) {
        let mut tv = [_mm256_set1_pd(f64::INFINITY); CHUNKS + 1];
        let mut wv = [_mm256_setzero_pd(); CHUNKS + 1];
        for c in 0..len.div_ceil(4) {
            // SAFETY: every lane is in the node's arrays.
            unsafe {
                tv[c] = _mm256_loadu_pd(t.as_ptr().add(4 * c));
                wv[c] = _mm256_loadu_pd(w.as_ptr().add(4 * c));
            }
        }
        (tv, wv)
    }

    /// Each lane's previous point (lane 0 from `lo`'s lane 3).
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn prev(x: __m256d, lo: __m256d) -> __m256d {
        _mm256_blend_pd::<0b0001>(
            _mm256_permute4x64_pd::<0b10_01_00_11>(x),
            _mm256_permute4x64_pd::<0b10_01_00_11>(lo),
        )
    }

    /// Each lane's next point (lane 3 from `hi`'s lane 0).
    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn next(x: __m256d, hi: __m256d) -> __m256d {
        _mm256_blend_pd::<0b1000>(
            _mm256_permute4x64_pd::<0b00_11_10_01>(x),
            _mm256_permute4x64_pd::<0b00_11_10_01>(hi),
        )
    }

    #[inline]
    #[target_feature(enable = "avx2,popcnt")]
    fn bits(mask: __m256d, c: usize) -> u64 {
        (_mm256_movemask_pd(mask) as u64) << (4 * c)
    }

    impl Kernel for Avx2 {
        #[inline]
        #[target_feature(enable = "avx2,popcnt")]
        unsafe fn tangent(
            t: &[f64; CAP],
            w: &[f64; CAP],
            len: usize,
            (tp, wp): (f64, f64),
        ) -> (usize, f64) {
            let (t, w) = load(t, w, len);
            let (tp, wp) = (_mm256_set1_pd(tp), _mm256_set1_pd(wp));
            let mut slope = [_mm256_set1_pd(f64::NEG_INFINITY); CHUNKS + 1];
            for c in 0..len.div_ceil(4) {
                slope[c] = _mm256_div_pd(_mm256_sub_pd(w[c], wp), _mm256_sub_pd(t[c], tp));
            }
            let mut turns = 0u64;
            for c in 0..len.div_ceil(4) {
                let down = _mm256_cmp_pd::<_CMP_LT_OQ>(next(slope[c], slope[c + 1]), slope[c]);
                turns |= bits(down, c);
            }
            first_turn(turns, len, slope)
        }

        #[inline]
        #[target_feature(enable = "avx2,popcnt")]
        unsafe fn pop_tests(
            t: &[f64; CAP],
            w: &[f64; CAP],
            len: usize,
            (tp, wp): (f64, f64),
        ) -> [u64; 3] {
            let (t, w) = load(t, w, len);
            let (tp, wp) = (_mm256_set1_pd(tp), _mm256_set1_pd(wp));
            let [mut before, mut left, mut right] = [0u64; 3];
            let zero = _mm256_setzero_pd();
            for c in 0..len.div_ceil(4) {
                before |= bits(_mm256_cmp_pd::<_CMP_LT_OQ>(t[c], tp), c);
                let lo = |x: &[__m256d]| if c == 0 { zero } else { x[c - 1] };
                let below = |l: (__m256d, __m256d), r: (__m256d, __m256d)| {
                    let le = _mm256_cmp_pd::<_CMP_LE_OQ>;
                    below!(_mm256_sub_pd, _mm256_mul_pd, le; l, r, (t[c], w[c]))
                };
                let l = below((prev(t[c], lo(&t)), prev(w[c], lo(&w))), (tp, wp));
                let r = below((tp, wp), (next(t[c], t[c + 1]), next(w[c], w[c + 1])));
                left |= bits(l, c);
                right |= bits(r, c);
            }
            [before, left, right]
        }

        #[inline]
        #[target_feature(enable = "avx2,popcnt")]
        unsafe fn steepest_shift(t: &mut [f64], w: &mut [f64], p: (f64, f64)) -> Steepest<u32> {
            super::steepest_shift(t, w, p)
        }

        #[inline]
        #[target_feature(enable = "avx2,popcnt")]
        unsafe fn move_tail(
            t: &mut [f64; CAP],
            w: &mut [f64; CAP],
            len: usize,
            from: usize,
            to: usize,
        ) {
            let by = to as isize - from as isize;
            // Every chunk is read before any is written.
            let (tv, wv) = load(t, w, len);
            for c in from / 4..len.div_ceil(4) {
                let m = lanes(c, from, len);
                let at = (4 * c) as isize + by;
                // SAFETY: the lanes under `m` land on `to..to + len - from`
                // of the node; the others are not written.
                unsafe {
                    _mm256_maskstore_pd(t.as_mut_ptr().wrapping_offset(at), m, tv[c]);
                    _mm256_maskstore_pd(w.as_mut_ptr().wrapping_offset(at), m, wv[c]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hull_insert_keeps_the_upper_hull() {
        let mut hull = Vec::new();
        for (t, w) in [
            (3.0, 1.0),
            (1.0, 0.0),
            (2.0, 5.0),
            (5.0, 0.0),
            (4.0, 1.0),
            (2.0, 4.0),
        ] {
            hull_insert(&mut hull, Point { t, w, tag: () }, 0.0);
        }
        let points: Vec<[f64; 2]> = hull.iter().map(|p| [p.t, p.w]).collect();
        assert_eq!(points, vec![[1.0, 0.0], [2.0, 5.0], [5.0, 0.0]]);
    }

    /// What lets a post skip the hulls further up its path: where it lies
    /// well below the hull of some points, it stays out of the hull of
    /// any superset of them, whatever order they came in. Random sets on
    /// a few `t` (ties) and many, curved like the tree's `w`, with the
    /// stage's margin.
    #[test]
    fn well_below_one_hull_is_below_every_hull_over_more_points() {
        let mut rng = crate::terrain::random::SplitMix64(5);
        let mut random = move || rng.unit();
        let (mut skipped, mut tries) = (0, 0);
        for round in 0..400 {
            let spread = if round % 2 == 0 { 8.0 } else { 3.0e4 };
            let point = |random: &mut dyn FnMut() -> f64| {
                let t = (random() * spread).floor() + 1.0;
                let w = random() * 1200.0 - 7.8e-8 * t * t;
                Point { t, w, tag: () }
            };
            let small: Vec<Point<()>> = (0..1 + round % 20).map(|_| point(&mut random)).collect();
            let mut large = small.clone();
            large.extend((0..round % 50).map(|_| point(&mut random)));
            // The superset in another order.
            large.sort_by(|a, b| (a.w * 7.0).sin().total_cmp(&(b.w * 7.0).sin()));
            let margin = 1e-9 * (1.0 + 1200.0);
            let build = |points: &[Point<()>]| {
                let mut hull = Vec::new();
                for &q in points {
                    hull_insert(&mut hull, q, margin);
                }
                hull
            };
            let (a, b) = (build(&small), build(&large));
            for _ in 0..50 {
                let p = point(&mut random);
                tries += 1;
                if hull_insert(&mut a.clone(), p, margin) {
                    skipped += 1;
                    let mut after = b.clone();
                    hull_insert(&mut after, p, margin);
                    assert_eq!(after, b, "round {round}: {p:?} changed the larger hull");
                }
            }
        }
        assert!(
            skipped > tries / 4,
            "only {skipped} of {tries} lay well below"
        );
    }

    /// A random walk of posts into both stores, with runs that build a
    /// dome (every post on the hull, past `CAP`) and ties in `t`: the same
    /// hulls, the same tangents, bit for bit, in every kernel the CPU runs.
    #[test]
    fn the_slab_keeps_the_heaps_hulls() {
        use crate::plumbing::simd::Level;
        #[cfg(target_arch = "x86_64")]
        for level in crate::plumbing::simd::available() {
            match level {
                Level::Avx512 => walk::<Avx512>(),
                Level::Avx2 => walk::<Avx2>(),
                Level::Scalar => {}
            }
        }
    }

    /// A bucket's pass, in every store's code: the steepest slope is the
    /// largest of the divisions one by one, the point named is one that
    /// gives it (the same in every store, ties included: the `t` and `w`
    /// here repeat), and the points come out moved up one after the post.
    #[test]
    fn steepest_shift_scans_and_moves_alike_in_every_store() {
        use crate::plumbing::simd::Level;
        let mut rng = crate::terrain::random::SplitMix64(5);
        let mut random = move || rng.unit();
        type Shift = fn(&mut [f64], &mut [f64], (f64, f64)) -> Steepest<u32>;
        let mut stores: Vec<(&str, Shift)> = vec![("heap", Heap::<()>::steepest_shift)];
        #[cfg(target_arch = "x86_64")]
        for level in crate::plumbing::simd::available() {
            match level {
                Level::Avx512 => stores.push(("avx512", Slab::<(), Avx512>::steepest_shift)),
                Level::Avx2 => stores.push(("avx2", Slab::<(), Avx2>::steepest_shift)),
                Level::Scalar => {}
            }
        }
        for n in 0..300 {
            let len = n % 41;
            let p = (-1.0, (random() * 4.0).floor());
            let t: Vec<f64> = (0..len).map(|_| (random() * 4.0).floor()).collect();
            let w: Vec<f64> = (0..len).map(|_| (random() * 8.0).floor()).collect();
            let slopes: Vec<f64> = (0..len).map(|i| (w[i] - p.1) / (t[i] - p.0)).collect();
            let mut first = None;
            for &(name, shift) in &stores {
                let (mut ts, mut ws) = (t.clone(), w.clone());
                ts.push(f64::NAN);
                ws.push(f64::NAN);
                let best = shift(&mut ts, &mut ws, p);
                let want = slopes.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                assert_eq!(best.slope.to_bits(), want.to_bits(), "{name}, {len} points");
                if len > 0 {
                    assert_eq!(
                        slopes[best.tag as usize].to_bits(),
                        want.to_bits(),
                        "{name}"
                    );
                }
                assert_eq!(ts, [&[p.0][..], &t].concat(), "{name}: t moved");
                assert_eq!(ws, [&[p.1][..], &w].concat(), "{name}: w moved");
                let named = *first.get_or_insert(best.tag);
                assert_eq!(best.tag, named, "{name} names another of equal slope");
            }
        }
    }

    fn walk<K: Kernel>() {
        let mut rng = crate::terrain::random::SplitMix64(17);
        let mut random = move || rng.unit();
        const NODES: usize = 4;
        let mut heap = Heap::<Option<u32>>::with_nodes(NODES);
        let mut slab = Slab::<Option<u32>, K>::with_nodes(NODES);
        let mut lens = [(0u32, 0u32); NODES];
        let (mut spilled, mut steps) = (0, (0u64, 0u64));
        for n in 0..20_000u32 {
            let v = (random() * NODES as f64) as usize;
            let dome = (n / 500) % 3 == 1;
            let t = if dome {
                f64::from(n % 500)
            } else {
                (random() * 64.0).floor()
            };
            let w = if dome {
                -(t - 250.0) * (t - 250.0) / 100.0
            } else {
                random() * 10.0 + t * 0.1
            };
            let p = Point {
                t: t + 1.0,
                w,
                tag: Some(n),
            };
            let margin = if n % 2 == 0 { 0.0 } else { 1e-3 };
            let (a, b) = (
                heap.insert(v, lens[v].0, p, margin),
                slab.insert(v, lens[v].1, p, margin),
            );
            assert_eq!(
                a.1, b.1,
                "post {n} into node {v}: whether it lies well below"
            );
            (lens[v].0, lens[v].1) = (a.0, b.0);
            spilled += usize::from(lens[v].1 & ON_HEAP != 0);
            let slab_points = if lens[v].1 & ON_HEAP != 0 {
                slab.heap.hulls[v].clone()
            } else {
                slab.points(v, lens[v].1 as usize)
            };
            assert_eq!(heap.hulls[v], slab_points, "post {n} into node {v}");
            let (tq, wq) = (random() * -5.0, random() * 20.0 - 5.0);
            if lens[v].0 > 0 {
                let a = heap.tangent(v, lens[v].0, tq, wq, &mut steps.0);
                let b = slab.tangent(v, lens[v].1, tq, wq, &mut steps.1);
                assert_eq!((a.slope.to_bits(), a.tag), (b.slope.to_bits(), b.tag));
            }
            if random() < 0.01 {
                heap.clear(v, lens[v].0);
                slab.clear(v, lens[v].1);
                lens[v] = (0, 0);
            }
        }
        assert_eq!(steps.0, steps.1, "points the scans read");
        assert!(spilled > 0, "no hull outgrew the slab");
    }
}
