//! Sector horizons (Stewart 1998): in sector `i` of post `p`, the largest
//! elevation angle of any post that falls in the closed wedge between the
//! sector's two bounding azimuths, the angle measured in the vertical plane
//! through the sector's centre line (sec. III: `atan(dz / ((q - p) . r_i))`).
//! A narrow spike anywhere in the wedge sets the whole sector.
//!
//! **Algorithm** (sec. IV-A to IV-C). Per sector, posts are processed in
//! order along `a_perp` (the normal of the clockwise boundary), so that when
//! `p` is processed every post on the inner side of that boundary already
//! has been; a static binary tree over the posts' ranks along `b_perp`
//! holds, in each node, the upper convex hull of the processed posts
//! projected onto the centre plane `(t, w)`. The nodes on the path from the
//! root to `p`'s leaf cover exactly the processed posts on the inner side of
//! the other boundary: the wedge (the Observation of sec. IV). `p`'s horizon
//! is the steepest tangent from `p` to those hulls; `p` then joins the hulls
//! of the left siblings along its path. Nodes whose leaves are all
//! processed are dropped (sec. IV-C). Hulls are sorted arrays, as Stewart
//! found best (their mean size is small).
//!
//! **Boundaries** (sec. IV-D). Ties along `a_perp` are broken by the
//! projection on `a`, ties along `b_perp` by the projection on `b`, so that
//! a post exactly on a boundary ray is in the sector and a post on the
//! boundary line behind the apex is not. Boundaries at multiples of 45
//! degrees are snapped to exact directions and keys are computed in post
//! units when `dx == dy`, so that grid diagonals tie exactly.
//!
//! **Narrow sectors** (sec. IV-E). A narrow wedge may miss every post near
//! its apex; with the check on, the posts within `spacing / sin(2 pi / s)`
//! whose cell (the `dx x dy` rectangle around the post) touches the wedge
//! count as well ([`NarrowStencil`]).
//!
//! **Curvature.** The drop uses the distance along the centre line, `t`;
//! with `w = z - c t^2` the slope from `p` is `(w_q - w_p) / (t_q - t_p) +
//! 2 c t_p`, so the hulls hold `w` and stay exact.
//!
//! **Maximum distance.** The tree cannot bound the distance;
//! [`sector_horizons_within`] scans each post's wedge within it instead,
//! exact and out of core.
//!
//! We depart from Stewart in five ways: the posts are grid posts, so keys
//! come from `(col, row)` and the IV-E stencil is one list of offsets per
//! sector rather than a search per point; the tree's lowest seven levels
//! are buckets of 128 ranks, scanned for ranks above the query's (the same
//! set of posts: the bucket stands for the subtree). The walk up a tall
//! tree misses the caches at its foot; a bucket is contiguous (1.3x faster
//! at 1.44 M posts), and kept in rank order, so that the ranks above a
//! query's are its tail, which a query divides for alone and moves up as it
//! reads it, to put the post in its place ([`Bucket`]). The hulls of every
//! node live in one array and are searched and updated in AVX-512 or AVX2
//! code, not walked point by point ([`hulls`]). The sweep reads the posts
//! in its order from a copy gathered beforehand, leaving the stencil and
//! the angles to a pass row by row: a post's lookups in the sweep's order
//! are cache misses on its critical path. That pass takes each offset of
//! the stencil across a whole row in vector lanes ([`narrow`]), `t` and
//! `w` in arrays of their own. And the sorts are shared: a sector's
//! processing order is the previous sector's rank order, and its ranks the
//! opposite sector's reversed ([`Ranks`]), sorted by buckets
//! ([`sort_keyed`]); the walk up the tree follows the bucket index's bits,
//! without a branch a level to mispredict. A thread's sectors sort and
//! sweep in one room of arrays, each taking it from the one before
//! ([`Scratch`]), rather than glibc mapping them anew every sector. Each
//! of these keeps the bits; docs/BENCHMARKS.md has what each saves.
//! And where Stewart updates each hull on its path on its own, a post's
//! insertions stop at the first hull it lies well below: those further up
//! hold supersets of its posts ([`hulls::well_below`]: 42 % fewer
//! insertion attempts at 64 sectors).

mod bounded;
mod hulls;
mod narrow;

pub use bounded::{sector_horizon_of_post, sector_horizons_within};

use crate::terrain::steepest::{Steepest, Tag};
use crate::terrain::Terrain;
use hulls::{Heap, Hulls, Slab};
use std::sync::{Arc, Mutex, MutexGuard};
use zerocopy::{FromBytes, Immutable, IntoBytes, KnownLayout};

/// The geometry of sector `index` of `count`: its boundaries and centre.
#[derive(Debug, Clone, Copy)]
pub struct SectorFrame {
    /// Unit-ish (east, north) of the clockwise boundary `a` and the
    /// counter-clockwise one `b`, in key units ([`Terrain::key_position`]).
    lo: (f64, f64),
    hi: (f64, f64),
    /// Unit (east, north) of the centre line, metres.
    centre: (f64, f64),
    /// North metres per key unit over east metres per key unit.
    aspect: f64,
    dx: f64,
}

fn snapped(az_deg: f64) -> (f64, f64) {
    let (e, n) = crate::terrain::compass(az_deg);
    let snap = |v: f64| {
        if v.abs() < 1e-12 {
            0.0
        } else {
            v
        }
    };
    let (e, n) = (snap(e), snap(n));
    if (e.abs() - n.abs()).abs() < 1e-12 {
        (e.signum(), n.signum())
    } else {
        (e, n)
    }
}

/// The opposite direction, exactly (and no `-0`).
fn opposite((e, n): (f64, f64)) -> (f64, f64) {
    (0.0 - e, 0.0 - n)
}

impl SectorFrame {
    pub fn new(index: usize, count: usize, dx: f64, dy: f64) -> Self {
        assert!(
            count >= 3,
            "sectors narrower than 180 degrees need 3 or more"
        );
        let width = 360.0 / count as f64;
        let mid = index as f64 * width;
        // Boundary `j` lies at `j * width - width / 2`, the same bits for a
        // sector's `hi` and the next one's `lo` (the last sector's `hi` is
        // sector 0's `lo`), and for an even count, boundary `j + count / 2`
        // is boundary `j` negated to the bit: each sector's ranks are then
        // the next one's processing order and the opposite one's ranks
        // reversed ([`Ranks`]).
        let at = |j: usize| snapped(j as f64 * width - width / 2.0);
        let half = count / 2;
        let boundary = |j: usize| match j % count {
            j if count.is_multiple_of(2) && j >= half => opposite(at(j - half)),
            j => at(j),
        };
        // In the key frame a post is (col, -row * dy / dx): metres / dx.
        // A world direction keeps its angle under that uniform scaling.
        Self {
            lo: boundary(index),
            hi: boundary(index + 1),
            centre: crate::terrain::compass(mid),
            aspect: dy / dx,
            dx,
        }
    }

    /// Compass azimuth of the sector's centre, degrees.
    pub(crate) fn centre_azimuth(index: usize, count: usize) -> f64 {
        index as f64 * 360.0 / count as f64
    }

    /// An offset of `(dcol, drow)` posts in key units, at the spacing of
    /// the centre row.
    fn key_offset(&self, dcol: f64, drow: f64) -> (f64, f64) {
        (dcol, -drow * self.aspect)
    }

    /// The four keys of a post at `key_position` ([`Terrain::key_position`]):
    /// along `a_perp` and `a` (order), along `b_perp` and `b` (rank).
    pub fn keys(&self, (e, n): (f64, f64)) -> [f64; 4] {
        let (a, b) = (self.lo, self.hi);
        // `+ 0.0` turns -0 into 0, so that sorting and comparing agree.
        [
            -(a.0 * n - a.1 * e),
            a.0 * e + a.1 * n,
            b.0 * n - b.1 * e,
            b.0 * e + b.1 * n,
        ]
        .map(|k| k + 0.0)
    }

    /// Metres along the centre line of the post at `key_position`.
    pub fn along(&self, (e, n): (f64, f64)) -> f64 {
        (self.centre.0 * e + self.centre.1 * n) * self.dx
    }

    /// Whether post `q` (keys `kq`) is in the closed wedge of post `p`.
    pub fn contains(kp: &[f64; 4], kq: &[f64; 4]) -> bool {
        let after = |i: usize| kq[i] > kp[i] || (kq[i] == kp[i] && kq[i + 1] > kp[i + 1]);
        after(0) && after(2)
    }

    /// Whether the closed wedge from the origin touches the rectangle of
    /// half-sizes `(hx, hy)` centred at `(cx, cy)` (key units).
    fn touches_rect(&self, (cx, cy): (f64, f64), (hx, hy): (f64, f64)) -> bool {
        let (a, b) = (self.lo, self.hi);
        let inside = |(e, n): (f64, f64)| -(a.0 * n - a.1 * e) >= 0.0 && b.0 * n - b.1 * e >= 0.0;
        let corners = [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
            .map(|(sx, sy)| (cx + sx * hx, cy + sy * hy));
        if corners.iter().any(|&c| inside(c)) {
            return true;
        }
        // A boundary ray through the rectangle (slab test, t >= 0).
        [a, b].iter().any(|&(de, dn)| {
            let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
            for (d, lo, hi) in [(de, cx - hx, cx + hx), (dn, cy - hy, cy + hy)] {
                if d.abs() < 1e-15 {
                    if lo > 0.0 || hi < 0.0 {
                        return false;
                    }
                } else {
                    let (u, v) = (lo / d, hi / d);
                    t0 = t0.max(u.min(v));
                    t1 = t1.min(u.max(v));
                }
            }
            t0 <= t1
        })
    }
}

/// The posts near a sector's apex that Stewart's narrow-sector check
/// (sec. IV-E) adds: offsets `(dcol, drow)` within `max(dx, dy) / sin(2 pi /
/// s)` whose `dx x dy` rectangle touches the closed wedge.
#[derive(Debug, Clone)]
pub struct NarrowStencil {
    pub offsets: Vec<(i64, i64)>,
}

impl NarrowStencil {
    pub fn new(frame: &SectorFrame, count: usize, dx: f64, dy: f64) -> Self {
        let radius = dx.max(dy) / (2.0 * std::f64::consts::PI / count as f64).sin().max(1e-9);
        let (rc, rr) = ((radius / dx).ceil() as i64, (radius / dy).ceil() as i64);
        let mut offsets = Vec::new();
        for dr in -rr..=rr {
            for dc in -rc..=rc {
                let (e, n) = (dc as f64 * dx, -(dr as f64) * dy);
                if (dc, dr) == (0, 0) || e.hypot(n) > radius {
                    continue;
                }
                let centre = frame.key_offset(dc as f64, dr as f64);
                if frame.touches_rect(centre, (0.5, 0.5 * frame.aspect)) {
                    offsets.push((dc, dr));
                }
            }
        }
        Self { offsets }
    }
}

/// Counts of one sector's run, for the benchmarks.
#[derive(Debug, Clone, Copy, Default)]
pub struct SectorStats {
    /// Hull points visited by tangent queries.
    pub tangent_steps: u64,
    /// Hull insertions attempted.
    pub inserts: u64,
}

/// One sector's posts (their indices among the posts with data) in order
/// along `b_perp`, ties by `b` (IV-D): the sector's ranks in Stewart's
/// tree, and the next sector's processing order, whose clockwise boundary
/// is this sector's counter-clockwise one (the same bits,
/// [`SectorFrame::new`]): its order along `a_perp` descending is this one
/// along `b_perp` ascending, but for ties, which IV-D breaks by `a`
/// descending there and by `b` ascending here, so each run of equal keys
/// is read backwards. A bake that hands each sector's ranks on sorts once
/// a sector, not twice (#17 item 2). And the opposite sector's boundaries
/// are this one's negated to the bit, so its keys are these negated and
/// its ranks these reversed ([`Ranks::opposite`]): a bake that sweeps
/// opposite sectors together sorts once for both.
#[derive(Debug, Clone)]
pub struct Ranks {
    sector: (usize, usize),
    /// The grid they were sorted on: width, height and spacing's bits.
    grid: [u64; 4],
    /// Indices into the posts with data, in order (read backwards where
    /// `reversed`: the opposite sector's ranks share the sorted posts).
    sorted: Arc<[u32]>,
    reversed: bool,
    /// The runs of more than one equal `b_perp` key: start and length (in
    /// `sorted` as stored).
    ties: Arc<[(usize, usize)]>,
    /// Whether no two posts share both keys: then, and only then, is the
    /// order reversed the order of the keys negated.
    distinct: bool,
}

impl Ranks {
    /// The ranks of sector `index` of `count` over `terrain`'s posts with
    /// data (`posts`, [`DataPosts::of`] that terrain).
    pub fn of(terrain: &Terrain, posts: &DataPosts, sector: (usize, usize)) -> Self {
        Self::sorted_in(terrain, posts, sector, None)
    }

    /// [`Ranks::of`], sorted in `scratch`'s room where it is free.
    pub fn of_in(
        terrain: &Terrain,
        posts: &DataPosts,
        sector: (usize, usize),
        scratch: &Scratch,
    ) -> Self {
        Self::sorted_in(terrain, posts, sector, Some(scratch))
    }

    fn sorted_in(
        terrain: &Terrain,
        posts: &DataPosts,
        (index, count): (usize, usize),
        scratch: Option<&Scratch>,
    ) -> Self {
        assert!(posts.fits(terrain), "the posts of another grid");
        let frame = SectorFrame::new(index, count, terrain.dx, terrain.dy);
        let mut room = Scratch::room(scratch);
        Self::new(terrain, (index, count), &posts.indices, &frame, &mut room)
    }

    fn new(
        terrain: &Terrain,
        sector: (usize, usize),
        posts: &[u32],
        frame: &SectorFrame,
        room: &mut Room,
    ) -> Self {
        let (keys, sorted) = room.take(posts.len(), posts.len());
        keyed(terrain, posts, frame, |k| (k[2], k[3]), keys);
        sort_keyed(keys, sorted);
        let mut ties = Vec::new();
        let mut distinct = true;
        let mut start = 0;
        for run in sorted.chunk_by(|a, b| a[0] == b[0]) {
            if run.len() > 1 {
                ties.push((start, run.len()));
                distinct &= run.windows(2).all(|p| p[0][1] != p[1][1]);
            }
            start += run.len();
        }
        Self {
            sector,
            grid: grid(terrain),
            sorted: sorted.iter().map(|&[_, _, j]| j as u32).collect(),
            reversed: false,
            ties: ties.into(),
            distinct,
        }
    }

    /// The sector they rank.
    pub fn sector(&self) -> (usize, usize) {
        self.sector
    }

    /// The ranks of the opposite sector (`index + count / 2`, the count
    /// even): these read backwards, with no sort and no copy; `None` where
    /// two posts share both keys, which a sort orders by post both ways.
    pub fn opposite(&self) -> Option<Self> {
        let (index, count) = self.sector;
        (count.is_multiple_of(2) && self.distinct).then(|| Self {
            sector: ((index + count / 2) % count, count),
            reversed: !self.reversed,
            ..self.clone()
        })
    }

    /// Whether these are sector `sector`'s ranks over `terrain`'s `posts`
    /// posts with data.
    fn fits(&self, sector: (usize, usize), terrain: &Terrain, posts: usize) -> bool {
        self.sector == sector && self.grid == grid(terrain) && self.sorted.len() == posts
    }

    /// The posts in rank order.
    fn in_order(&self) -> Vec<u32> {
        match self.reversed {
            false => self.sorted.to_vec(),
            true => self.sorted.iter().rev().copied().collect(),
        }
    }

    /// The next sector's processing order: runs of equal `b_perp` keys
    /// backwards.
    fn following(&self) -> Vec<u32> {
        let mut order = self.in_order();
        let n = order.len();
        for &(start, len) in self.ties.iter() {
            let start = if self.reversed {
                n - start - len
            } else {
                start
            };
            order[start..start + len].reverse();
        }
        order
    }
}

/// What a sector's tree may take from its neighbours' ([`Ranks`]): the
/// terrain's posts with data, its own ranks, and the previous sector's
/// (sector `index - 1`, or the last for sector 0), each used only where it
/// is the right grid's (and the right sector's over the same posts and,
/// for the previous, its boundary is this sector's to the bit).
#[derive(Debug, Clone, Copy, Default)]
pub struct Shared<'a> {
    pub posts: Option<&'a DataPosts>,
    pub ranks: Option<&'a Ranks>,
    pub previous: Option<&'a Ranks>,
    /// Room for the sweep's largest arrays, left by the sector before.
    pub scratch: Option<&'a Scratch>,
}

/// Room a thread's sectors sort and sweep in, one after another: two
/// arrays of 24 bytes a post (the sorting keys and their sorted copy; in
/// the sweep, the posts gathered in processing order and each post's `t`,
/// `w` and slope). Made once a sector, the arrays of a DEM above 1.4 M
/// posts are past the 32 MiB below which glibc reuses freed memory, so
/// every sector mapped them anew and faulted their pages in (a sixth of
/// the CPU time of 64 sectors at 1.44 M posts). A room reused holds no
/// more than one sector held at once. One sector at a time holds it; a
/// sector that finds it held makes its own.
#[derive(Debug, Default)]
pub struct Scratch(Mutex<Room>);

impl Scratch {
    /// The room, unless another sector holds it.
    fn take(&self) -> Option<MutexGuard<'_, Room>> {
        self.0.try_lock().ok()
    }

    /// `scratch`'s room where it is free, else a room of the caller's own.
    fn room(scratch: Option<&Scratch>) -> Lent<'_> {
        scratch
            .and_then(Scratch::take)
            .map_or_else(|| Lent::Own(Room::default()), Lent::Shared)
    }
}

/// A room for one sector's sort or sweep ([`Scratch::room`]).
enum Lent<'a> {
    Shared(MutexGuard<'a, Room>),
    Own(Room),
}

impl std::ops::Deref for Lent<'_> {
    type Target = Room;
    fn deref(&self) -> &Room {
        match self {
            Lent::Shared(room) => room,
            Lent::Own(room) => room,
        }
    }
}

impl std::ops::DerefMut for Lent<'_> {
    fn deref_mut(&mut self) -> &mut Room {
        match self {
            Lent::Shared(room) => room,
            Lent::Own(room) => room,
        }
    }
}

#[derive(Debug, Default)]
struct Room {
    a: Vec<[u64; 3]>,
    b: Vec<[u64; 3]>,
}

impl Room {
    /// The first `a` and `b` records of the two arrays, grown where short
    /// (their contents are whatever the last sector left).
    fn take(&mut self, a: usize, b: usize) -> (&mut [[u64; 3]], &mut [[u64; 3]]) {
        for (v, len) in [(&mut self.a, a), (&mut self.b, b)] {
            if v.len() < len {
                v.resize(len, [0; 3]);
            }
        }
        (&mut self.a[..a], &mut self.b[..b])
    }
}

/// What ranks are checked against before they are used: the grid's size
/// and spacing (not its rows' scales nor its heights: the caller hands on
/// ranks sorted on the terrain it passes).
fn grid(terrain: &Terrain) -> [u64; 4] {
    [
        terrain.width as u64,
        terrain.height as u64,
        terrain.dx.to_bits(),
        terrain.dy.to_bits(),
    ]
}

/// Each post's two sorting keys, picked from its four [`SectorFrame::keys`]
/// made [`ordered`], and its index among `posts`, into `out` (as long as
/// `posts`): sorted with their keys in place, since sorting indices by
/// keys looked up elsewhere misses the cache on every comparison.
fn keyed(
    terrain: &Terrain,
    posts: &[u32],
    frame: &SectorFrame,
    pick: impl Fn([u64; 4]) -> (u64, u64),
    out: &mut [[u64; 3]],
) {
    let w = terrain.width;
    for (j, (&i, out)) in posts.iter().zip(out).enumerate() {
        let k = frame.keys(terrain.key_position(i as usize % w, i as usize / w));
        let (first, second) = pick(k.map(ordered));
        *out = [first, second, j as u64];
    }
}

/// A terrain's posts with data, row-major: every sector's tree starts from
/// them, so a bake of many sectors finds them once ([`Shared`]).
#[derive(Debug)]
pub struct DataPosts {
    /// The grid they were found on ([`grid`]).
    grid: [u64; 4],
    indices: Vec<u32>,
}

impl DataPosts {
    pub fn of(terrain: &Terrain) -> Self {
        Self {
            grid: grid(terrain),
            indices: (0..terrain.width * terrain.height)
                .filter(|&i| !terrain.z[i].is_nan())
                .map(|i| i as u32)
                .collect(),
        }
    }

    /// Whether these are `terrain`'s (by its grid, as for [`Ranks`]).
    fn fits(&self, terrain: &Terrain) -> bool {
        self.grid == grid(terrain)
    }
}

/// Ranks per bucket at the foot of the tree.
const BUCKET: usize = 128;

/// A point of a hull: centre-plane `(t, w)` and its tag.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Point<T> {
    t: f64,
    w: f64,
    tag: T,
}

/// A post in the sweep's order: its index in the grid, its rank, and its
/// centre-plane `(t, w)` (24 bytes, a record of a [`Scratch`] array).
#[derive(Debug, Clone, Copy, FromBytes, IntoBytes, KnownLayout, Immutable)]
#[repr(C)]
struct Gathered {
    post: u32,
    rank: u32,
    t: f64,
    w: f64,
}

/// The processed posts of one bucket, sorted by rank: which ranks it
/// holds, and the posts' centre-plane `(t, w)` and tags, column by column
/// so that a scan runs in SIMD lanes. The posts ranked above a query's
/// are then the run at the end, and the query divides for those alone,
/// where an unsorted bucket divided for every post and masked half out.
#[derive(Debug, Clone, Default)]
struct Bucket<T> {
    /// Bit `r` set where the bucket holds its `r`-th rank.
    held: u128,
    t: Vec<f64>,
    w: Vec<f64>,
    tag: Vec<T>,
}

impl<T: Copy + Default> Bucket<T> {
    fn with_capacity(n: usize) -> Self {
        Self {
            held: 0,
            t: Vec::with_capacity(n),
            w: Vec::with_capacity(n),
            tag: Vec::with_capacity(n),
        }
    }

    fn clear(&mut self) {
        self.held = 0;
        self.t.clear();
        self.w.clear();
        self.tag.clear();
    }

    /// Where the posts ranked above `rank` begin: the count of those below.
    #[inline(always)]
    fn above(&self, rank: u32) -> usize {
        let below = (1u128 << (rank as usize % BUCKET)) - 1;
        (self.held & below).count_ones() as usize
    }

    /// The steepest slope from `p` to the posts from `at` on
    /// ([`Self::above`]), and `p` (of rank `rank`) put at `at`, in `H`'s
    /// vector code ([`hulls::steepest_shift`]).
    #[inline(always)]
    fn steepest_then_insert<H: Hulls<T>>(
        &mut self,
        at: usize,
        rank: u32,
        p: Point<T>,
    ) -> Steepest<T> {
        self.held |= 1 << (rank as usize % BUCKET);
        self.t.push(p.t);
        self.w.push(p.w);
        let best = H::steepest_shift(&mut self.t[at..], &mut self.w[at..], (p.t, p.w));
        let tag = match best.found() {
            true => self.tag[at + best.tag as usize],
            false => T::default(),
        };
        self.tag.insert(at, p.tag);
        Steepest {
            slope: best.slope,
            tag,
        }
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct Node {
    /// A bucket's ranks still to be processed; a node's children not yet
    /// finished (0: every rank under it is processed).
    remaining: u32,
    len: u32,
}

/// Order-preserving `u64` of an `f64` (for radix-friendly sorting keys).
fn ordered(v: f64) -> u64 {
    let bits = v.to_bits();
    if bits >> 63 == 1 {
        !bits
    } else {
        bits | (1 << 63)
    }
}

/// The `f64` whose [`ordered`] is `bits`.
fn unordered(bits: u64) -> f64 {
    f64::from_bits(if bits >> 63 == 1 {
        bits & !(1 << 63)
    } else {
        !bits
    })
}

/// `keyed` (first key, second key, post) into `sorted` (as long), sorted
/// as `sort_unstable` sorts it, in linear time on grids: a bucket sort by
/// the first key's value ([`unordered`], which never decreases as the key
/// grows), as many buckets as posts, then each bucket by the whole
/// triple. A grid's posts are spread evenly along any direction, so most
/// buckets hold a post or two; where they do not (a diagonal, along which
/// hundreds of posts share a key), the bucket's sort is the comparison
/// sort there was. Out of place: the second array of a [`Scratch`].
fn sort_keyed(keyed: &[[u64; 3]], sorted: &mut [[u64; 3]]) {
    let n = keyed.len();
    assert_eq!(sorted.len(), n);
    let (lo, hi) = keyed
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), k| {
            let v = unordered(k[0]);
            (lo.min(v), hi.max(v))
        });
    // One key for all (or none): nothing to spread.
    if hi <= lo {
        sorted.copy_from_slice(keyed);
        sorted.sort_unstable();
        return;
    }
    // Rounding keeps `(v - lo) * scale` from decreasing as `v` grows, so
    // every key of a bucket lies at or below every key of the next.
    let scale = (n - 1) as f64 / (hi - lo);
    let bucket = |k: &[u64; 3]| (((unordered(k[0]) - lo) * scale) as usize).min(n - 1);
    // Counts, then each bucket's end, then (filled from the back) its start.
    let mut at = vec![0u32; n + 1];
    for k in keyed {
        at[bucket(k)] += 1;
    }
    let mut end = 0;
    for a in at.iter_mut() {
        end += *a;
        *a = end;
    }
    for k in keyed.iter().rev() {
        let a = &mut at[bucket(k)];
        *a -= 1;
        sorted[*a as usize] = *k;
    }
    for b in at.windows(2) {
        let run = &mut sorted[b[0] as usize..b[1] as usize];
        if run.len() > 1 {
            run.sort_unstable();
        }
    }
}

/// Sector horizons of sector `index` of `count` at every post, in degrees
/// (NaN for nodata), into `out`. `narrow`: Stewart's IV-E check.
pub fn sector_horizons(
    terrain: &Terrain,
    index: usize,
    count: usize,
    narrow: bool,
    out: &mut [f32],
) -> SectorStats {
    let with = (crate::plumbing::simd::level(), Shared::default());
    sector_horizons_at(terrain, (index, count), narrow, with, out, None)
}

/// [`sector_horizons`], also writing each post's distance to the post
/// that sets its horizon (the arg-max; horizontal metres, NaN for nodata
/// and where the wedge holds no post) into `distances`. Of posts exactly
/// as steep, any one may be named. The tree's points carry their posts.
pub fn sector_horizons_with_distances(
    terrain: &Terrain,
    (index, count): (usize, usize),
    narrow: bool,
    out: &mut [f32],
    distances: &mut [f32],
) -> SectorStats {
    let with = (crate::plumbing::simd::level(), Shared::default());
    sector_horizons_at(terrain, (index, count), narrow, with, out, Some(distances))
}

/// [`sector_horizons`] (or, with `distances`,
/// [`sector_horizons_with_distances`]) with the tree's hulls where vector
/// code of `level` keeps them (a level the CPU runs,
/// [`crate::plumbing::simd::available`]): in one array in AVX-512 or AVX2, each in a
/// vector of its own in scalar code; and the sorted orders taken from
/// `shared` where they fit. The same bits at every level, shared or not.
pub fn sector_horizons_at(
    terrain: &Terrain,
    sector: (usize, usize),
    narrow: bool,
    (level, shared): (crate::plumbing::simd::Level, Shared),
    out: &mut [f32],
    distances: Option<&mut [f32]>,
) -> SectorStats {
    assert!(
        level <= crate::plumbing::simd::level(),
        "{level:?} is past this CPU's"
    );
    match distances {
        None => tree::<()>(terrain, sector, narrow, level, shared, out, None),
        Some(d) => tree::<Option<u32>>(terrain, sector, narrow, level, shared, out, Some(d)),
    }
}

/// Stewart's tree over one sector, its points tagged with `T`, its hulls
/// in the slab in vector code of `level` ([`hulls`]), on the heap in
/// scalar code.
fn tree<T: Tag<u32>>(
    terrain: &Terrain,
    sector: (usize, usize),
    narrow: bool,
    level: crate::plumbing::simd::Level,
    shared: Shared,
    out: &mut [f32],
    distances: Option<&mut [f32]>,
) -> SectorStats {
    #[cfg(target_arch = "x86_64")]
    {
        use crate::plumbing::simd::Level;
        /// `sweep` with the hulls in a slab of `$kernel`, compiled for its
        /// instructions.
        macro_rules! in_slab {
            ($features:literal, $kernel:ty) => {{
                #[target_feature(enable = $features)]
                unsafe fn run<T: Tag<u32>>(
                    terrain: &Terrain,
                    sector: (usize, usize),
                    narrow: bool,
                    shared: Shared,
                    out: &mut [f32],
                    distances: Option<&mut [f32]>,
                ) -> SectorStats {
                    sweep::<T, Slab<T, $kernel>>(terrain, sector, narrow, shared, out, distances)
                }
                run::<T> as unsafe fn(_, _, _, _, _, _) -> _
            }};
        }
        let run = match level {
            Level::Avx512 => in_slab!("avx512f,avx512vl,avx512dq,popcnt", hulls::Avx512),
            Level::Avx2 => in_slab!("avx2,popcnt", hulls::Avx2),
            Level::Scalar => {
                return sweep::<T, Heap<T>>(terrain, sector, narrow, shared, out, distances)
            }
        };
        // SAFETY: the CPU runs `level` (the callers ask `simd`).
        unsafe { run(terrain, sector, narrow, shared, out, distances) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    sweep::<T, Heap<T>>(terrain, sector, narrow, shared, out, distances)
}

/// [`tree`] with the hulls in `H`.
#[inline(always)]
fn sweep<T: Tag<u32>, H: Hulls<T>>(
    terrain: &Terrain,
    (index, count): (usize, usize),
    narrow: bool,
    shared: Shared,
    out: &mut [f32],
    mut distances: Option<&mut [f32]>,
) -> SectorStats {
    let (w, h) = (terrain.width, terrain.height);
    assert_eq!(out.len(), w * h);
    assert!(distances.as_ref().is_none_or(|d| d.len() == out.len()));
    let frame = SectorFrame::new(index, count, terrain.dx, terrain.dy);
    let c = terrain.curvature;
    let own_posts;
    let posts = match shared.posts {
        Some(p) if p.fits(terrain) => &p.indices,
        _ => {
            own_posts = DataPosts::of(terrain);
            &own_posts.indices
        }
    };
    let n = posts.len();
    let position = |i: u32| terrain.key_position(i as usize % w, i as usize / w);
    // The sector before left its room, where the caller hands it on
    // ([`Scratch`]).
    let mut room = Scratch::room(shared.scratch);
    // The ranks along `b_perp`, and the processing order: the previous
    // sector's ranks where the caller has them ([`Ranks`]), else sorted
    // here, with their keys in place (sorting indices by keys looked up
    // elsewhere misses the cache on every comparison).
    let own;
    let ranked = match shared.ranks {
        Some(r) if r.fits((index, count), terrain, n) => r,
        _ => {
            own = Ranks::new(terrain, (index, count), posts, &frame, &mut room);
            &own
        }
    };
    let mut rank = vec![0u32; n];
    for (r, &j) in ranked.sorted.iter().enumerate() {
        rank[j as usize] = if ranked.reversed { n - 1 - r } else { r } as u32;
    }
    // The previous sector's counter-clockwise boundary is this one's
    // clockwise boundary to the bit ([`SectorFrame::new`]).
    let previous = (index + count - 1) % count;
    let processing: Vec<u32> = match shared.previous {
        Some(p) if p.fits((previous, count), terrain, n) => p.following(),
        _ => {
            // a_perp descending, ties by a descending (IV-D); `!` reverses
            // an order-preserving key.
            let (by_a, _) = room.take(n, 0);
            keyed(terrain, posts, &frame, |k| (!k[0], !k[1]), by_a);
            by_a.sort_unstable();
            by_a.iter().map(|&[_, _, j]| j as u32).collect()
        }
    };
    let (gathered, planes) = room.take(n, w * h);
    // Centre-plane coordinates (t, w) per post (NaN where nodata), each
    // row-major, so that a row of either is lanes of the IV-E pass
    // ([`narrow`]); and the steepest slope the tree finds from each.
    let planes = <[f64]>::mut_from_bytes(planes.as_mut_bytes()).expect("24-byte records");
    let (ts, planes) = planes.split_at_mut(w * h);
    let (ws, slopes) = planes.split_at_mut(w * h);
    ts.fill(f64::NAN);
    ws.fill(f64::NAN);
    slopes.fill(f64::NEG_INFINITY);
    let mut highest = 0f64;
    for &i in posts {
        let t = frame.along(position(i));
        let w = f64::from(terrain.z[i as usize]) - c * t * t;
        (ts[i as usize], ws[i as usize]) = (t, w);
        highest = highest.max(w.abs());
    }
    // How far below a hull a post must lie to be below every hull over
    // more posts, whatever the rounding: a billionth of the largest `w`,
    // millions of times the rounding of a test of it.
    let margin = 1e-9 * (1.0 + highest);
    let mut tags = vec![T::default(); w * h];
    // Each post's rank and (t, w) in processing order: the lookups are out
    // of order here, where they are independent of each other, not in the
    // sweep, where each would stall a post's dependent work.
    let order = <[Gathered]>::mut_from_bytes(gathered.as_mut_bytes()).expect("24-byte records");
    for (g, j) in order.iter_mut().zip(processing) {
        let post = posts[j as usize];
        *g = Gathered {
            post,
            rank: rank[j as usize],
            t: ts[post as usize],
            w: ws[post as usize],
        };
    }
    drop(rank);

    let stencil = narrow.then(|| NarrowStencil::new(&frame, count, terrain.dx, terrain.dy));
    let stats = climb_tree::<T, H>(order, margin, slopes, &mut tags);
    if let Some(d) = distances.as_deref_mut() {
        d.fill(f32::NAN);
    }
    let planes = (&*ts, &*ws, &mut *slopes, &mut tags[..]);
    narrow::narrow_and_angles(terrain, stencil.as_ref(), planes, out, distances);
    stats
}

/// Stewart's tree over the posts in processing order (`order`, with their
/// ranks and centre-plane coordinates): each post's steepest slope and its
/// tag, from its own bucket and the hulls of its path's left siblings, and
/// then its place in the hulls of the right ones.
#[inline(always)]
fn climb_tree<T: Tag<u32>, H: Hulls<T>>(
    order: &[Gathered],
    margin: f64,
    slopes: &mut [f64],
    tags: &mut [T],
) -> SectorStats {
    let n = order.len();
    let mut stats = SectorStats::default();
    // The tree: per node, what is left of it to process ([`Node`]) and
    // how many points its hull holds, packed so that a query's walk up
    // the tree touches one small array (the hulls themselves are read only
    // where non-empty). The lowest seven levels are replaced by buckets of
    // 128 ranks, each a run in rank order ([`Bucket`]): those levels are
    // where a query's walk misses the caches, and a bucket is contiguous.
    let buckets = n.div_ceil(BUCKET).max(1);
    let leaves = buckets.next_power_of_two();
    let mut hulls = H::with_nodes(2 * leaves);
    let mut nodes = vec![Node::default(); 2 * leaves];
    let mut bucket_points: Vec<Bucket<T>> = vec![Bucket::default(); buckets];
    // The columns of the buckets emptied so far, for the next to open:
    // no bucket then grows by doubling but the first ones.
    let mut spare: Vec<Bucket<T>> = Vec::new();
    for b in 0..buckets {
        nodes[leaves + b].remaining = BUCKET.min(n - b * BUCKET) as u32;
    }
    for v in (1..leaves).rev() {
        nodes[v].remaining = nodes[2 * v..2 * v + 2]
            .iter()
            .filter(|c| c.remaining > 0)
            .count() as u32;
    }
    for &Gathered {
        post,
        rank: k,
        t: tp,
        w: wp,
    } in order
    {
        let post = post as usize;
        let me = Point {
            t: tp,
            w: wp,
            tag: T::of(post as u32),
        };
        let bucket = k as usize / BUCKET;
        // A bucket opens with the columns of one emptied before, where
        // there is one: no bucket then grows by doubling but the first.
        let points = &mut bucket_points[bucket];
        if points.t.capacity() == 0 {
            *points = spare.pop().unwrap_or_else(|| Bucket::with_capacity(BUCKET));
        }
        // The ranks below k in its own bucket, scanned as p joins them.
        let at = points.above(k);
        stats.tangent_steps += (points.t.len() - at) as u64;
        let mut best = points.steepest_then_insert::<H>(at, k, me);
        // The path from the leaf to the root, level `l` at `leaf >> l`: a
        // left child where bit `l` of the bucket is clear, and only left
        // children hold hulls (a post joins its path's left siblings).
        // Walking the set and clear bits (not testing each level's, a
        // branch that goes either way at random) leaves one mispredicted
        // branch to a loop, not one to a level.
        let leaf = leaves + bucket;
        let mut lefts = !bucket & (leaves - 1);
        while lefts != 0 {
            let v = leaf >> lefts.trailing_zeros();
            lefts &= lefts - 1;
            let len = nodes[v].len;
            if len > 0 {
                best = best.steeper(hulls.tangent(v, len, tp, wp, &mut stats.tangent_steps));
            }
        }
        // A bucket finished finishes its parent if the sibling is, and so
        // on up: each node finishes once, not a count down at every level
        // for every post.
        nodes[leaf].remaining -= 1;
        let mut v = leaf;
        while nodes[v].remaining == 0 {
            let node = &mut nodes[v];
            if node.len > 0 {
                hulls.clear(v, node.len);
                node.len = 0;
            }
            if v == 1 {
                break;
            }
            v >>= 1;
            nodes[v].remaining -= 1;
        }
        slopes[post] = best.slope;
        tags[post] = best.tag;
        // A bucket all processed leaves its columns for the next to open.
        if nodes[leaf].remaining == 0 {
            let mut done = std::mem::take(&mut bucket_points[bucket]);
            done.clear();
            spare.push(done);
        }
        // p joins the ranks below k: in its own bucket above, beyond it
        // by the hulls of the left siblings along the path (they cover
        // ranks below the bucket, whose posts have p on their b side).
        // Those hulls, from the foot up, hold the processed posts of ever
        // larger subtrees around p's (each the last one's and its
        // sibling's), so each lies above the last: a post that lies well
        // below one lies below every hull further up, and stays out of
        // them all ([`hulls::well_below`]; three attempts in five used to
        // change nothing).
        let mut rights = bucket;
        while rights != 0 {
            let v = (leaf >> rights.trailing_zeros()) - 1;
            rights &= rights - 1;
            let node = &mut nodes[v];
            if node.remaining > 0 {
                let (len, below) = hulls.insert(v, node.len, me, margin);
                node.len = len;
                stats.inserts += 1;
                if below {
                    break;
                }
            }
        }
    }
    stats
}

/// The horizon angle (degrees) of the steepest slope `best` of `w = z - c
/// t^2` from a post at `t = tp`; -90 when nothing lies in the wedge.
/// Cephes' `atan`, whose branches are selects, so that a row of them is
/// vector code (libm's was 4 % of the tree's time).
#[inline(always)]
fn elevation_deg(best: f64, c: f64, tp: f64) -> f32 {
    let angle = crate::terrain::atan(best + 2.0 * c * tp).to_degrees() as f32;
    if best == f64::NEG_INFINITY {
        -90.0
    } else {
        angle
    }
}

#[cfg(test)]
mod tests;
