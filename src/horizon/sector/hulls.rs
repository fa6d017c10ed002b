//! The hulls in the nodes of Stewart's tree (sec. IV-B): each node's upper
//! convex hull, in the centre plane `(t, w)`, of the processed posts under
//! it, sorted by `t`. Two stores do the same two operations, the steepest
//! tangent from a post in front of every point and the insertion of a
//! post, with the same comparisons and so the same bits:
//!
//! * [`Heap`] keeps each hull in a vector of its own and walks it point by
//!   point, as Stewart does: a binary search for the insertion point, pops
//!   one at a time, a tangent scan that stops where the slopes turn down.
//! * [`Slab`] (AVX-512) keeps up to [`CAP`] points of every node in one
//!   array, `t`, `w` and the tags apart, and does each operation on all the
//!   points at once: every slope, or every pop test, in vectors; the
//!   tangent point and the runs of pops found as bits of the resulting
//!   masks; the kept tail moved by masked stores. A walk through the tree
//!   then has no branch that depends on the terrain but whether a hull is
//!   empty and whether the new post lands below it. The tree's cost was
//!   its fixed part per level (a node, two data-dependent branches, a
//!   pointer to a hull of six to nine points: docs/BENCHMARKS.md, "Per
//!   level of the tree"), not moving points. A hull that outgrows `CAP`
//!   points (a dome's every post is on it) moves to the heap.
//!
//! Why the masks give the scalar pops: a point left of the new post `p` is
//! popped when it lies on or below the segment from its left neighbour to
//! `p`, and the scalar loop pops from `p` leftwards while that holds. The
//! test of each point uses its original neighbour, which the loop has not
//! popped when it gets there, so the loop pops exactly the run of set bits
//! that ends next to `p`; likewise to the right.

use super::Point;
use crate::horizon::steepest::{Steepest, Tag};

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
    /// Inserts `p` into node `v`'s hull; its new count.
    fn insert(&mut self, v: usize, len: u32, p: Point<T>) -> u32;
    /// Empties node `v`'s hull (its posts are all processed).
    fn clear(&mut self, v: usize, len: u32);
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
    fn insert(&mut self, v: usize, _: u32, p: Point<T>) -> u32 {
        let hull = &mut self.hulls[v];
        hull_insert(hull, p);
        hull.len() as u32
    }

    fn clear(&mut self, v: usize, _: u32) {
        self.hulls[v] = Vec::new();
    }
}

/// Whether `(t, w)` lies on or below the segment from `l` to `r` (`l.t <
/// t < r.t`, or `t` beyond `r` for the pops' tests).
#[inline(always)]
fn below(l: (f64, f64), r: (f64, f64), (t, w): (f64, f64)) -> bool {
    (w - l.1) * (r.0 - l.0) <= (r.1 - l.1) * (t - l.0)
}

/// Inserts `p` into an upper hull sorted by `t`.
pub(super) fn hull_insert<T: Copy>(hull: &mut Vec<Point<T>>, p: Point<T>) {
    let (t, w) = (p.t, p.w);
    let i = hull.partition_point(|q| q.t < t);
    if i < hull.len() && hull[i].t == t {
        if hull[i].w >= w {
            return;
        }
        hull.remove(i);
    }
    let at = |i: usize| (hull[i].t, hull[i].w);
    // Below the hull edge over `t`: not on the hull.
    if i > 0 && i < hull.len() && below(at(i - 1), at(i), (t, w)) {
        return;
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

/// Up to [`CAP`] points of every node in one array (`[v * CAP + i]`), the
/// longer hulls on the heap. Only where the CPU has AVX-512
/// ([`crate::simd::level`]).
pub(super) struct Slab<T> {
    t: Vec<f64>,
    w: Vec<f64>,
    /// The points' posts, where `T` keeps them (else empty).
    tags: Vec<u32>,
    heap: Heap<T>,
}

impl<T: Tag<u32>> Slab<T> {
    fn keeps_tags() -> bool {
        T::of(0).get().is_some()
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
    fn tie(&mut self, v: usize, len: usize, i: usize, p: Point<T>) -> u32 {
        if self.w[v * CAP + i] >= p.w {
            return len as u32;
        }
        let range = v * CAP + i + 1..v * CAP + len;
        self.t.copy_within(range.clone(), v * CAP + i);
        self.w.copy_within(range.clone(), v * CAP + i);
        if Self::keeps_tags() {
            self.tags.copy_within(range, v * CAP + i);
        }
        self.insert(v, len as u32 - 1, p)
    }

    /// Moves node `v`'s hull to the heap and inserts `p` there.
    #[cold]
    fn spill(&mut self, v: usize, len: usize, p: Point<T>) -> u32 {
        self.heap.hulls[v] = self.points(v, len);
        self.heap.insert(v, 0, p) | ON_HEAP
    }
}

impl<T: Tag<u32>> Hulls<T> for Slab<T> {
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
        }
    }

    #[inline(always)]
    fn tangent(&self, v: usize, len: u32, t: f64, w: f64, steps: &mut u64) -> Steepest<T> {
        if len & ON_HEAP != 0 {
            return self.heap.tangent(v, len, t, w, steps);
        }
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: a slab is built only where the CPU has AVX-512.
            let (k, read) = unsafe { avx512::tangent(self, v, len as usize, t, w) };
            *steps += read as u64;
            let i = v * CAP + k;
            Steepest {
                slope: (self.w[i] - w) / (self.t[i] - t),
                tag: self.tag(i),
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("a slab needs AVX-512")
    }

    #[inline(always)]
    fn insert(&mut self, v: usize, len: u32, p: Point<T>) -> u32 {
        if len & ON_HEAP != 0 {
            return self.heap.insert(v, len, p) | ON_HEAP;
        }
        let len = len as usize;
        let base = v * CAP;
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: a slab is built only where the CPU has AVX-512.
            let (i, kept, from) = unsafe { avx512::plan(self, v, len, (p.t, p.w)) };
            if i < len && self.t[base + i] == p.t {
                return self.tie(v, len, i, p);
            }
            let at = |i: usize| (self.t[base + i], self.w[base + i]);
            // Below the hull edge over `t`: not on the hull.
            if i > 0 && i < len && below(at(i - 1), at(i), (p.t, p.w)) {
                return len as u32;
            }
            let new_len = kept + 1 + (len - from);
            if new_len > CAP {
                return self.spill(v, len, p);
            }
            // SAFETY: as above; `kept + 1 + len - from` points fit.
            unsafe { avx512::move_tail(self, v, len, from, kept + 1) };
            self.t[base + kept] = p.t;
            self.w[base + kept] = p.w;
            if let Some(post) = p.tag.get() {
                self.tags[base + kept] = post;
            }
            new_len as u32
        }
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("a slab needs AVX-512")
    }

    fn clear(&mut self, v: usize, len: u32) {
        if len & ON_HEAP != 0 {
            self.heap.clear(v, len);
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{Slab, CAP};
    use crate::horizon::steepest::Tag;
    use std::arch::x86_64::*;

    const CHUNKS: usize = CAP / 8;

    /// The lanes of chunk `c` that hold one of `len` points.
    #[inline(always)]
    fn lanes(len: usize, c: usize) -> __mmask8 {
        let k = len.saturating_sub(8 * c).min(8);
        ((1u32 << k) - 1) as __mmask8
    }

    /// Node `v`'s `len` points, chunk by chunk (`+inf` and 0 past them),
    /// and one chunk more so that every point has a right neighbour.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    unsafe fn load<T>(
        slab: &Slab<T>,
        v: usize,
        len: usize,
    ) -> ([__m512d; CHUNKS + 1], [__m512d; CHUNKS + 1]) {
        let (pt, pw) = (slab.t[v * CAP..].as_ptr(), slab.w[v * CAP..].as_ptr());
        let mut t = [_mm512_set1_pd(f64::INFINITY); CHUNKS + 1];
        let mut w = [_mm512_setzero_pd(); CHUNKS + 1];
        for c in 0..len.div_ceil(8) {
            let m = lanes(len, c);
            // SAFETY: lanes under `m` are points of the node.
            unsafe {
                t[c] = _mm512_mask_loadu_pd(t[c], m, pt.add(8 * c));
                w[c] = _mm512_maskz_loadu_pd(m, pw.add(8 * c));
            }
        }
        (t, w)
    }

    /// The index of the point of node `v`'s hull (`len >= 1` points) where
    /// the slopes from `(tp, wp)` first turn down (the scalar scan's stop,
    /// so the steepest), and how many points that scan reads.
    ///
    /// # Safety
    /// AVX-512 F, VL and DQ; `len <= CAP`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    pub(super) unsafe fn tangent<T>(
        slab: &Slab<T>,
        v: usize,
        len: usize,
        tp: f64,
        wp: f64,
    ) -> (usize, usize) {
        // SAFETY: as the caller's.
        let (t, w) = unsafe { load(slab, v, len) };
        let (tp_v, wp_v) = (_mm512_set1_pd(tp), _mm512_set1_pd(wp));
        let mut slope = [_mm512_set1_pd(f64::NEG_INFINITY); CHUNKS + 1];
        for c in 0..len.div_ceil(8) {
            slope[c] = _mm512_mask_div_pd(
                slope[c],
                lanes(len, c),
                _mm512_sub_pd(w[c], wp_v),
                _mm512_sub_pd(t[c], tp_v),
            );
        }
        // Bit k: the slope to point k + 1 is less than to point k (past
        // the last point it is -inf, so the last point always stops).
        let mut turns = 0u64;
        for c in 0..len.div_ceil(8) {
            let next = _mm512_castsi512_pd(_mm512_alignr_epi64::<1>(
                _mm512_castpd_si512(slope[c + 1]),
                _mm512_castpd_si512(slope[c]),
            ));
            turns |= u64::from(_mm512_cmp_pd_mask::<_CMP_LT_OQ>(next, slope[c])) << (8 * c);
        }
        let k = turns.trailing_zeros() as usize;
        (k, (k + 2).min(len))
    }

    /// Where a post `(tp, wp)` goes into node `v`'s `len` points: `i`, the
    /// points with a smaller `t`; and, if it is not below the hull, the
    /// points before `kept` stay in place and the points from `from` on
    /// follow the post (those between are popped).
    ///
    /// # Safety
    /// AVX-512 F, VL and DQ; `len <= CAP`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    pub(super) unsafe fn plan<T>(
        slab: &Slab<T>,
        v: usize,
        len: usize,
        (tp, wp): (f64, f64),
    ) -> (usize, usize, usize) {
        // SAFETY: as the caller's.
        let (t, w) = unsafe { load(slab, v, len) };
        let (tp_v, wp_v) = (_mm512_set1_pd(tp), _mm512_set1_pd(wp));
        let shift = |hi: __m512d, lo: __m512d, by: i32| {
            let (hi, lo) = (_mm512_castpd_si512(hi), _mm512_castpd_si512(lo));
            _mm512_castsi512_pd(match by {
                1 => _mm512_alignr_epi64::<1>(hi, lo),
                _ => _mm512_alignr_epi64::<7>(hi, lo),
            })
        };
        // Bit j of `left`: point j lies on or below the segment from point
        // j - 1 to the post; of `right`: on or below the segment from the
        // post to point j + 1 (`below`, lane by lane).
        let (mut left, mut right, mut before) = (0u64, 0u64, 0u64);
        let zero = _mm512_setzero_pd();
        for c in 0..len.div_ceil(8) {
            before |= u64::from(_mm512_cmp_pd_mask::<_CMP_LT_OQ>(t[c], tp_v)) << (8 * c);
            let prev = |x: &[__m512d]| shift(x[c], if c == 0 { zero } else { x[c - 1] }, 7);
            let next = |x: &[__m512d]| shift(x[c + 1], x[c], 1);
            let (lt, lw) = (prev(&t), prev(&w));
            let l = _mm512_cmp_pd_mask::<_CMP_LE_OQ>(
                _mm512_mul_pd(_mm512_sub_pd(w[c], lw), _mm512_sub_pd(tp_v, lt)),
                _mm512_mul_pd(_mm512_sub_pd(wp_v, lw), _mm512_sub_pd(t[c], lt)),
            );
            let (rt, rw) = (next(&t), next(&w));
            let r = _mm512_cmp_pd_mask::<_CMP_LE_OQ>(
                _mm512_mul_pd(_mm512_sub_pd(w[c], wp_v), _mm512_sub_pd(rt, tp_v)),
                _mm512_mul_pd(_mm512_sub_pd(rw, wp_v), _mm512_sub_pd(t[c], tp_v)),
            );
            left |= u64::from(l) << (8 * c);
            right |= u64::from(r) << (8 * c);
        }
        let i = before.count_ones() as usize;
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
        (i, kept, from)
    }

    /// Moves node `v`'s points `from..len` to start at `to`.
    ///
    /// # Safety
    /// AVX-512 F, VL and DQ; `from <= len <= CAP`, `to + len - from <= CAP`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
    pub(super) unsafe fn move_tail<T: Tag<u32>>(
        slab: &mut Slab<T>,
        v: usize,
        len: usize,
        from: usize,
        to: usize,
    ) {
        if from == to || from == len {
            return;
        }
        let tail = ((1u64 << len) - 1) & !((1u64 << from) - 1);
        let by = to as isize - from as isize;
        let keeps = Slab::<T>::keeps_tags();
        // Every chunk is read before any is written.
        // SAFETY: as the caller's.
        let (t, w) = unsafe { load(slab, v, len) };
        let mut tags = [_mm256_setzero_si256(); CHUNKS];
        let base = v * CAP;
        if keeps {
            for (c, tag) in tags.iter_mut().enumerate().take(len.div_ceil(8)) {
                // SAFETY: lanes under the mask are points of the node.
                *tag = unsafe {
                    _mm256_maskz_loadu_epi32(
                        lanes(len, c),
                        slab.tags[base..].as_ptr().add(8 * c).cast(),
                    )
                };
            }
        }
        let (pt, pw) = (slab.t.as_mut_ptr(), slab.w.as_mut_ptr());
        let ptag = slab.tags.as_mut_ptr();
        for c in 0..len.div_ceil(8) {
            let m = (tail >> (8 * c)) as __mmask8;
            if m == 0 {
                continue;
            }
            let at = (base + 8 * c) as isize + by;
            // SAFETY: the lanes under `m` land on `to..to + len - from` of
            // the node; the others are not written.
            unsafe {
                _mm512_mask_storeu_pd(pt.wrapping_offset(at), m, t[c]);
                _mm512_mask_storeu_pd(pw.wrapping_offset(at), m, w[c]);
                if keeps {
                    _mm256_mask_storeu_epi32(ptag.wrapping_offset(at).cast(), m, tags[c]);
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
            hull_insert(&mut hull, Point { t, w, tag: () });
        }
        let points: Vec<[f64; 2]> = hull.iter().map(|p| [p.t, p.w]).collect();
        assert_eq!(points, vec![[1.0, 0.0], [2.0, 5.0], [5.0, 0.0]]);
    }

    /// A random walk of posts into both stores, with runs that build a
    /// dome (every post on the hull, past `CAP`) and ties in `t`: the same
    /// hulls, the same tangents, bit for bit.
    #[test]
    fn the_slab_keeps_the_heaps_hulls() {
        if crate::simd::level() < crate::simd::Level::Avx512 {
            return;
        }
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut random = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        const NODES: usize = 4;
        let mut heap = Heap::<Option<u32>>::with_nodes(NODES);
        let mut slab = Slab::<Option<u32>>::with_nodes(NODES);
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
            lens[v].0 = heap.insert(v, lens[v].0, p);
            lens[v].1 = slab.insert(v, lens[v].1, p);
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
