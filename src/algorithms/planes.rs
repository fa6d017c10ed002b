//! The parameter planes' algorithms: pure functions over row-major grids of
//! cells, called by the `cones` stage on whole DEMs or on windows of them,
//! and by the tests on tiny ones.
//!
//! **What is bounded.** The surface over cell `C'` never rises above the
//! tallest of its corners, `cellmax(C')`. A cone over cell `C` (apex `z_p`,
//! slope `m_p`, see `terrabake_format::cones`) is empty when, for every
//! cell `C'` taller than the apex, `dist(C, C') >= m_p (cellmax(C') - z_p)`,
//! `dist` being the distance between the two closed squares. That distance
//! is the distance between cell *centres* once every cell is dilated by its
//! 3 x 3 neighbourhood: `min` over the neighbours `C''` of `C'` of
//! `|centre(C) - centre(C'')|` equals `dist(C, C')` axis by axis. So both
//! algorithms below work on [`neighbourhood_max`] (`nmax`: the tallest corner
//! of any cell touching the cell) with plain centre-to-centre distances,
//! which is exact, not an approximation of the continuous surface.
//!
//! - [`sliced_planes`]: Paglieroni and Petersen (1992, sec. 2.1-2.2): `K`
//!   horizontal slices `z_k` (eq. 1-2), the Euclidean distance transform of
//!   each slice's bit plane `nmax >= z_k` (eq. 3-4; Felzenszwalb-Huttenlocher
//!   in `crate::algorithms::edt`), the apex at the first slice the cell is not part of,
//!   and the least slope over the pairs `(D_k, z_{k+1})`, slice by slice, so
//!   one distance plane exists at a time. Departures (docs/CONES.md): a
//!   slice whose bit plane equals the next one is skipped, since the next
//!   gives tighter bounds from the same distances (so `K` above the data's
//!   number of distinct heights costs nothing); the column distances are
//!   two integer sweeps (no parabolas needed for a bit plane), run band by
//!   band of rows just before the band's rows are evaluated, from where the
//!   bands meet ([`BandCarries`]), so that no plane of them is stored or
//!   streamed; the row pass leaves out parabolas too far to narrow any cone of
//!   the row (farther than its reach from the span of its open cells), and
//!   those of plane cells between near neighbours (never the lowest at a
//!   cell outside the plane: [`Span::hidden_bits`]); the top slice runs
//!   first so that every row has a finite reach;
//!   each distance found is kept, in two bytes, as a floor for the slices
//!   above (whose planes it contains), and a cell whose floor reaches its
//!   cone's width is left out of the slice (85 % of the evaluations at 2048²);
//!   the scan for the cells left in reads only the blocks of eight cells
//!   that can have opened since they were last read (their *wake*, from
//!   each closed cell's apex slice, slope and floor; see [`Scan`]).
//! - [`exact::exact_planes`]: the limit `K -> infinity`, without slices: the apex at
//!   the cell's own `nmax` (the lowest apex possible) and the least slope
//!   over every taller cell, found by branch and bound over a max pyramid of
//!   `nmax`: a node whose nearest point divided by its height above the apex
//!   cannot beat the best cone so far is not opened. The previous cell's
//!   tightest cell seeds the search.
//!
//! Both take an optional [`Cap`]: when the grid is a window of a larger DEM,
//! terrain outside the window is at least `radius` away and no taller than
//! the DEM's maximum, which bounds every slope (see the stage's docs).

use rayon::prelude::*;
use terrabake_format::cones::{round_down_f32, round_up_f32};
use terrabake_format::surface::Cell;

use crate::algorithms::edt::Envelope;
use crate::plumbing::pages;

/// Per cell of a `w x h`-post grid (`(w - 1) x (h - 1)` cells), the tallest
/// corner of any cell in its 3 x 3 neighbourhood; `-inf` where none of them
/// has a surface.
pub fn neighbourhood_max(posts: &[f32], w: usize, h: usize) -> Vec<f32> {
    assert!(w >= 2 && h >= 2 && posts.len() == w * h, "{w} x {h} posts");
    let (cw, ch) = (w - 1, h - 1);
    // Each cell's tallest corner, then the 3-wide max along rows, then along
    // columns.
    let mut across = vec![0f32; cw * ch];
    across.par_chunks_mut(cw).enumerate().for_each(|(r, out)| {
        let (north, south) = (&posts[r * w..(r + 1) * w], &posts[(r + 1) * w..(r + 2) * w]);
        let cell = |c: usize| {
            Cell {
                nw: north[c],
                ne: north[c + 1],
                sw: south[c],
                se: south[c + 1],
            }
            .max()
        };
        let mut prev = f32::NEG_INFINITY;
        let mut here = cell(0);
        for (c, o) in out.iter_mut().enumerate() {
            let next = if c + 1 < cw {
                cell(c + 1)
            } else {
                f32::NEG_INFINITY
            };
            *o = prev.max(here).max(next);
            (prev, here) = (here, next);
        }
    });
    let mut nmax = vec![0f32; cw * ch];
    nmax.par_chunks_mut(cw).enumerate().for_each(|(r, out)| {
        let row = |k: usize| &across[k * cw..(k + 1) * cw];
        out.copy_from_slice(row(r));
        for k in [r.wrapping_sub(1), r + 1] {
            if k < ch {
                for (o, &v) in out.iter_mut().zip(row(k)) {
                    *o = o.max(v);
                }
            }
        }
    });
    nmax
}

/// Terrain outside a window: at least `radius` metres from every cell of
/// its core, and no taller than `z_max`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cap {
    pub radius: f64,
    pub z_max: f64,
}

impl Cap {
    /// The widest slope that terrain outside the window allows for `apex`.
    fn slope(cap: Option<Cap>, apex: f64) -> f64 {
        match cap {
            Some(c) if c.z_max > apex => c.radius / (c.z_max - apex),
            _ => f64::INFINITY,
        }
    }
}

/// The slice heights `z_k` (eq. 1-2): `k` heights from `z_min` to `z_max`,
/// increasing; the last is `z_max` exactly (with one slice, `z_min`).
#[derive(Debug, Clone, PartialEq)]
pub struct Slices {
    pub z: Vec<f64>,
    /// The DEM's top, `z_max`: the height bound above the last slice.
    pub top: f64,
    /// `z_k+1 - z_k` (0 for one slice or a flat DEM).
    pub step: f64,
}

impl Slices {
    pub fn uniform(z_min: f64, z_max: f64, k: usize) -> Self {
        assert!(
            k >= 1 && z_min <= z_max,
            "{k} slices over [{z_min}, {z_max}]"
        );
        let step = if k > 1 {
            (z_max - z_min) / (k - 1) as f64
        } else {
            0.0
        };
        let mut z: Vec<f64> = (0..k).map(|i| z_min + i as f64 * step).collect();
        z[k - 1] = if k > 1 { z_max } else { z_min };
        Self {
            z,
            top: z_max,
            step,
        }
    }

    pub fn len(&self) -> usize {
        self.z.len()
    }

    pub fn is_empty(&self) -> bool {
        self.z.is_empty()
    }

    /// Per apex slice `0..=len`, the rise that slice `k` bounds: from the
    /// apex to the height above slice `k` (`z_k+1`; the top above the last
    /// slice), since cells in slice `k` and not in `k + 1` are below it;
    /// `0` for the cells in slice `k`'s plane, which it does not bound.
    pub(crate) fn rise_of(&self, k: usize) -> Vec<f64> {
        let z_next = self.z.get(k + 1).copied().unwrap_or(self.top);
        (0..=self.len())
            .map(|a| if a <= k { z_next - self.z[a] } else { 0.0 })
            .collect()
    }

    /// How many slices a cell of this `nmax` belongs to: it is in the bit
    /// plane of slices `0..n` and not in the rest, so `n` is the index of its
    /// apex slice (`n == len` when it is in every slice).
    pub fn member_of(&self, nmax: f32) -> usize {
        let v = f64::from(nmax);
        let (z, n) = (&self.z, self.z.len());
        // Slices are uniform: guess from the step, then settle exactly on
        // the count of slices at or below v (a binary search costs 3x more).
        let mut i = if self.step > 0.0 && v.is_finite() {
            (((v - z[0]) / self.step).floor() + 1.0).clamp(0.0, n as f64) as usize
        } else {
            z.partition_point(|&s| s <= v)
        };
        while i > 0 && z[i - 1] > v {
            i -= 1;
        }
        while i < n && z[i] <= v {
            i += 1;
        }
        i
    }
}

/// What a bake did, for the stage's report and the benchmarks.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct PlaneStats {
    /// Distance transforms computed (sliced).
    pub transforms: usize,
    /// Slices skipped because their bit plane equals the next one.
    pub slices_skipped: usize,
    /// Pyramid nodes examined (exact).
    pub nodes: u64,
    /// Blocks of the open-cell scans (sliced; every row of every transform)
    /// and those of them read, their wake having come (see `Scan`).
    pub scan_blocks: u64,
    pub scan_blocks_read: u64,
    /// Cells the scans found open, each evaluated once in its slice.
    pub cells_open: u64,
}

/// The planes of one grid: per cell, the apex rounded up and the slope
/// rounded down to `f32` (the encodings round further from these).
#[derive(Debug, Clone, PartialEq)]
pub struct Planes {
    pub apex: Vec<f32>,
    pub slope: Vec<f32>,
    pub stats: PlaneStats,
}

/// Slopes are computed in `f64` from exact integer offsets; this margin
/// covers the rounding of the metre scaling and of the square root.
const SLOPE_MARGIN: f64 = 1.0 - 1e-12;

/// Columns per share of a row that [`keep_in_reach`] tests at once (one
/// bit each in a `u64`).
const SHARE: usize = 64;

/// Rows per band of the row pass: a band's column distances are found
/// just before its rows are evaluated, while they are in the cache (see
/// [`band_columns`]).
const BAND: usize = 32;

/// A distance in cells along a column; `NONE` when the column has no plane
/// cell. `u16` (whenever the grid has fewer rows than `u16::MAX`) halves
/// the bands' room and lets [`keep_in_reach`] run in vector lanes.
trait ColumnDistance: Copy + Send + Sync + Eq + Ord {
    const NONE: Self;
    const ZERO: Self;
    fn next(self) -> Self;
    fn cells(self) -> f64;
    /// `n` cells (less than the grid's rows, so never `NONE`).
    fn rows(n: u32) -> Self;
    /// The distances as `u16`, for the AVX-512 lanes of [`keep_in_reach`];
    /// `None` where they are wider.
    fn as_u16(g: &[Self]) -> Option<&[u16]> {
        let _ = g;
        None
    }
}

macro_rules! column_distance {
    ($t:ty $(, $as_u16:item)?) => {
        impl ColumnDistance for $t {
            const NONE: Self = <$t>::MAX;
            const ZERO: Self = 0;
            #[inline]
            fn next(self) -> Self {
                self.saturating_add(1)
            }
            #[inline]
            fn cells(self) -> f64 {
                f64::from(self)
            }
            #[inline]
            fn rows(n: u32) -> Self {
                <$t>::try_from(n).unwrap_or(Self::NONE)
            }
            $($as_u16)?
        }
    };
}
column_distance!(
    u16,
    fn as_u16(g: &[Self]) -> Option<&[u16]> {
        Some(g)
    }
);
column_distance!(u32);

/// Paglieroni and Petersen's planes from `slices`, over a `cw x ch` grid of
/// `nmax` values with cells `dx x dy` metres; `on_slice` is called after
/// every slice (for progress).
pub fn sliced_planes(
    nmax: &[f32],
    cells: (usize, usize),
    spacing: (f64, f64),
    slices: &Slices,
    cap: Option<Cap>,
    on_slice: &(dyn Fn() + Sync),
) -> Planes {
    // A distance of u16::MAX - 1 rows must stay representable.
    if cells.1 < usize::from(u16::MAX) {
        sliced_planes_with::<u16>(nmax, cells, spacing, slices, cap, on_slice)
    } else {
        sliced_planes_with::<u32>(nmax, cells, spacing, slices, cap, on_slice)
    }
}

fn sliced_planes_with<G: ColumnDistance>(
    nmax: &[f32],
    (cw, ch): (usize, usize),
    (dx, dy): (f64, f64),
    slices: &Slices,
    cap: Option<Cap>,
    on_slice: &(dyn Fn() + Sync),
) -> Planes {
    assert_eq!(nmax.len(), cw * ch);
    let k_count = slices.len();
    assert!(
        k_count >= 1 && k_count <= usize::from(u16::MAX),
        "{k_count} slices"
    );
    // The apex slice of every cell; slice k's bit plane is `member > k`.
    // The per-cell arrays the slices sweep, on huge pages: the open-cell
    // scan reads scattered blocks of them (see `crate::plumbing::pages`).
    let mut member = pages::with_capacity(cw * ch);
    member.par_extend(nmax.par_iter().map(|&v| slices.member_of(v) as u16));
    let mut apex_of_slice = vec![0usize; k_count + 1];
    for &m in &member {
        apex_of_slice[usize::from(m)] += 1;
    }
    // The apex slices again in one byte, 255 standing for 255 and above:
    // `m > k` reads the same for every slice below 255, and the column
    // sweeps, which stream them from memory once a slice, are bound by it.
    let mut member_u8 = pages::with_capacity(cw * ch);
    member_u8.par_extend(member.par_iter().map(|&m| m.min(u16::from(u8::MAX)) as u8));
    let mut slope = pages::filled(cw * ch, f32::INFINITY);
    // Distances in units of dx: a column distance of g cells is g * dy / dx.
    let aspect = dy / dx;
    let hidden = Span::hidden(aspect);
    // Per cell, a lower bound on its distance to the plane of the slices
    // still to come (see [`Floor`]).
    let floor = Floor::new(dx.min(dy));
    let mut floors = pages::filled(cw * ch, 0u16);
    // Per block of a row, the first slice at which a cell of it can open
    // (see [`Scan`]); every block is read in the first slice.
    let blocks = cw.div_ceil(BLOCK);
    let mut wakes = vec![0u16; blocks * ch];
    let mut stats = PlaneStats::default();
    // The slices in the order they run. The top slice first: it bounds
    // every cell below the top at once, so that from then on every row has
    // a finite reach and the row pass can leave out far parabolas. Then
    // bottom-up, where a cell's tightest bound tends to come from its first
    // slices: fewer slope updates than top-down, and each distance found is
    // a floor for the slices above (their planes are subsets of this
    // one's). And those of them that add to the planes (`transforms`):
    // slice k's plane equals slice k + 1's when no cell has its apex at
    // k + 1; then (D_k+1, z_k+2) = (D_k, z_k+2) bounds every cell more
    // tightly than (D_k, z_k+1), and slice k adds nothing. Nor does a slice
    // with no cell outside its plane (`outside`, by slice): nothing to
    // bound.
    let order = || std::iter::once(k_count - 1).chain(0..k_count - 1);
    let equals_next = |k: usize| k + 1 < k_count && apex_of_slice[k + 1] == 0;
    let outside: Vec<usize> = apex_of_slice
        .iter()
        .scan(0, |sum, &n| {
            *sum += n;
            Some(*sum)
        })
        .collect();
    let transforms: Vec<usize> = order()
        .filter(|&k| !equals_next(k) && outside[k] > 0)
        .collect();
    stats.transforms = transforms.len();
    // Where each band of rows meets the column distances of the rows
    // outside it ([`BandEnds`], [`BandCarries`]): the first slice's ends
    // here, each later one's by the row pass before it, from the apex
    // slices it has in the cache.
    let plane_of = |k: usize| Plane::new(&member, &member_u8, k);
    let mut ends: BandEnds = PerBand::new((cw, ch), NO_ROW);
    let mut carries: BandCarries<G> = PerBand::new((cw, ch), G::NONE);
    if let Some(&k) = transforms.first() {
        ends.find(plane_of(k));
    }
    // The slice after each one that adds to the planes.
    let mut after = transforms.iter().skip(1);
    for k in order() {
        let keeps_floor = k + 1 < k_count;
        if equals_next(k) {
            stats.slices_skipped += 1;
            on_slice();
            continue;
        }
        if outside[k] == 0 {
            on_slice();
            continue;
        }
        let (plane, next) = (plane_of(k), after.next().map(|&k| plane_of(k)));
        carries.walk(&ends);
        let carries = &carries;
        // Row pass: the lower envelope of the columns' parabolas, then the
        // slope update of every cell outside the plane; band by band.
        let rise_of = &slices.rise_of(k);
        let member = &member;
        let scan = Scan::new(slices, k, floor.unit, rise_of);
        let pass = RowPass {
            scan,
            rise_of,
            floor,
            keeps_floor,
            dx,
            aspect,
            hidden,
        };
        stats.scan_blocks += (blocks * ch) as u64;
        let (read, open) = slope
            .par_chunks_mut(cw * BAND)
            .zip(floors.par_chunks_mut(cw * BAND))
            .zip(wakes.par_chunks_mut(blocks * BAND))
            .zip(ends.bands_mut())
            .enumerate()
            .map_init(
                || {
                    let room = (Envelope::default(), Vec::<u32>::new(), Kept::default());
                    (room, Vec::<G>::new(), Vec::<G>::new())
                },
                |(room_of, down, column), (b, (((slopes, floors), wakes), band_ends))| {
                    plane.band_columns(b, (cw, ch), carries.of(b), down, column);
                    if let Some(next) = next {
                        next.band_ends(b, (cw, ch), band_ends);
                    }
                    let mut counts = (0, 0);
                    let rows = slopes
                        .chunks_mut(cw)
                        .zip(floors.chunks_mut(cw))
                        .zip(wakes.chunks_mut(blocks))
                        .zip(column.chunks(cw));
                    for (i, (((row, row_floor), row_wakes), column)) in rows.enumerate() {
                        let r = b * BAND + i;
                        let m = &member[r * cw..(r + 1) * cw];
                        let (read, open) =
                            pass.row(m, (row, row_floor, row_wakes), column, room_of);
                        counts.0 += read;
                        counts.1 += open;
                    }
                    counts
                },
            )
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        stats.scan_blocks_read += read;
        stats.cells_open += open;
        on_slice();
    }
    let apex = apexes(&member, slices);
    cap_slopes(&mut slope, &apex, cap);
    Planes { apex, slope, stats }
}

/// Each cell's apex: the height of its apex slice, conservatively rounded
/// to f32; a cell in every slice has nothing above the top.
fn apexes(member: &[u16], slices: &Slices) -> Vec<f32> {
    member
        .par_iter()
        .map(|&m| round_up_f32(slices.z.get(usize::from(m)).copied().unwrap_or(slices.top)))
        .collect()
}

/// The slopes no wider than `cap` allows at each cell's apex.
fn cap_slopes(slope: &mut [f32], apex: &[f32], cap: Option<Cap>) {
    slope
        .par_iter_mut()
        .zip(apex)
        .for_each(|(s, &a)| *s = s.min(round_down_f32(Cap::slope(cap, f64::from(a)))));
}

/// Slice `k`'s plane, the cells with `member > k`, as the column
/// distances read it: from the apex slices in one byte below slice 255
/// (where 255, standing for 255 and above, reads the same), else in two:
/// the column sweeps read them from memory once a slice, and are bound by
/// it.
#[derive(Debug, Clone, Copy)]
enum Plane<'a> {
    Narrow(&'a [u8], u8),
    Wide(&'a [u16], u16),
}

impl<'a> Plane<'a> {
    fn new(member: &'a [u16], member_u8: &'a [u8], k: usize) -> Self {
        match u8::try_from(k) {
            Ok(k8) if k8 < u8::MAX => Plane::Narrow(member_u8, k8),
            _ => Plane::Wide(member, u16::try_from(k).expect("at most u16::MAX slices")),
        }
    }

    /// [`band_ends`] of this plane.
    fn band_ends(self, b: usize, cells: (usize, usize), ends: &mut [u8]) {
        match self {
            Plane::Narrow(member, k) => band_ends(member, k, cells, b, ends),
            Plane::Wide(member, k) => band_ends(member, k, cells, b, ends),
        }
    }

    /// [`band_columns`] of this plane.
    fn band_columns<G: ColumnDistance>(
        self,
        b: usize,
        cells: (usize, usize),
        carries: (&[G], &[G]),
        down: &mut Vec<G>,
        column: &mut Vec<G>,
    ) {
        match self {
            Plane::Narrow(member, k) => band_columns(member, k, cells, b, carries, down, column),
            Plane::Wide(member, k) => band_columns(member, k, cells, b, carries, down, column),
        }
    }
}

/// Two values per band of rows and column, `2 cw` a band: the first
/// `cw`, then the second (`BandEnds`, `BandCarries`).
#[derive(Debug)]
struct PerBand<T> {
    cells: (usize, usize),
    rows: Vec<T>,
}

impl<T: Clone + Send> PerBand<T> {
    fn new(cells: (usize, usize), fill: T) -> Self {
        Self {
            cells,
            rows: vec![fill; cells.1.div_ceil(BAND) * 2 * cells.0],
        }
    }

    /// Each band's values, in parallel.
    fn bands_mut(&mut self) -> rayon::slice::ChunksMut<'_, T> {
        self.rows.par_chunks_mut(2 * self.cells.0)
    }

    /// Band `b`'s first values and second.
    fn of(&self, b: usize) -> (&[T], &[T]) {
        let cw = self.cells.0;
        self.rows[b * 2 * cw..(b + 1) * 2 * cw].split_at(cw)
    }
}

/// Per band of rows and column, the first and the last row of the band
/// whose cell is in a slice's plane ([`band_ends`]).
type BandEnds = PerBand<u8>;

impl BandEnds {
    /// The plane's ends, the bands in parallel.
    fn find(&mut self, plane: Plane) {
        let cells = self.cells;
        self.bands_mut()
            .enumerate()
            .for_each(|(b, ends)| plane.band_ends(b, cells, ends));
    }
}

/// Per column of band `b` (rows `b * BAND..`), the first and last rows
/// whose cell is in the plane (`member > k`), counted from the band's
/// first row, into `ends` (the first rows, then the last; `NO_ROW` where
/// none). One byte each, so that the plain loop runs sixteen columns to a
/// vector.
fn band_ends<M: Copy + Ord>(
    member: &[M],
    k: M,
    (cw, ch): (usize, usize),
    b: usize,
    ends: &mut [u8],
) {
    ends.fill(NO_ROW);
    let (first, last) = ends.split_at_mut(cw);
    for (i, r) in (b * BAND..((b + 1) * BAND).min(ch)).enumerate() {
        let m = &member[r * cw..(r + 1) * cw];
        let i = i as u8;
        for ((f, l), &m) in first.iter_mut().zip(last.iter_mut()).zip(m) {
            *f = (*f).min(if m > k { i } else { NO_ROW });
            *l = if m > k { i } else { *l };
        }
    }
}

/// No row of a band ([`band_ends`]).
const NO_ROW: u8 = u8::MAX;
const _: () = assert!(BAND < NO_ROW as usize);

/// Where each band of rows meets the column distances outside it, per
/// band and column: `down`, the distance from the row above the band up to
/// the nearest plane cell at or above it, and `up`, from the row below the
/// band down to the nearest at or below it (`NONE` where there is none,
/// and above the first band and below the last). With them a band finds
/// its rows' distances from its own rows alone ([`band_columns`]). `2 cw`
/// a band, `down` then `up`.
type BandCarries<G> = PerBand<G>;

impl<G: ColumnDistance> BandCarries<G> {
    /// The carries of a plane from its bands' ends: one walk down the
    /// bands, one up.
    fn walk(&mut self, ends: &BandEnds) {
        let (cw, ch) = self.cells;
        // The last plane row above the band, then the first below it.
        let mut seen = vec![u32::MAX; cw];
        for (b, carries) in self.rows.chunks_mut(2 * cw).enumerate() {
            let (top, (_, last)) = ((b * BAND) as u32, ends.of(b));
            for ((d, s), &l) in carries[..cw].iter_mut().zip(&mut seen).zip(last) {
                *d = if *s == u32::MAX {
                    G::NONE
                } else {
                    G::rows(top - 1 - *s)
                };
                *s = if l == NO_ROW { *s } else { top + u32::from(l) };
            }
        }
        seen.fill(u32::MAX);
        for (b, carries) in self.rows.chunks_mut(2 * cw).enumerate().rev() {
            let (top, below) = ((b * BAND) as u32, ((b + 1) * BAND).min(ch) as u32);
            let (first, _) = ends.of(b);
            for ((u, s), &f) in carries[cw..].iter_mut().zip(&mut seen).zip(first) {
                *u = if *s == u32::MAX {
                    G::NONE
                } else {
                    G::rows(*s - below)
                };
                *s = if f == NO_ROW { *s } else { top + u32::from(f) };
            }
        }
    }
}

/// The column distances of band `b`'s rows into `column` (row-major, `cw`
/// a row): up the band from its `up` carry, then down it from its `down`
/// carry, keeping the nearer; what two sweeps down and up the whole grid
/// give, without their three passes over a plane of distances (about a
/// fifth of the bake at 8192², bound by memory). `down` is room for a row.
fn band_columns<G: ColumnDistance, M: Copy + Ord>(
    member: &[M],
    k: M,
    (cw, ch): (usize, usize),
    b: usize,
    (down_in, up_in): (&[G], &[G]),
    down: &mut Vec<G>,
    column: &mut Vec<G>,
) {
    let first = b * BAND;
    let n = ((b + 1) * BAND).min(ch) - first;
    column.resize(n * cw, G::NONE);
    for i in (0..n).rev() {
        let m = &member[(first + i) * cw..(first + i + 1) * cw];
        let (here, below) = column.split_at_mut((i + 1) * cw);
        let below = if i + 1 < n { &below[..cw] } else { up_in };
        for ((g, &m), &p) in here[i * cw..].iter_mut().zip(m).zip(below) {
            *g = if m > k { G::ZERO } else { p.next() };
        }
    }
    down.clear();
    down.extend_from_slice(down_in);
    for (i, row) in column.chunks_mut(cw).enumerate() {
        let m = &member[(first + i) * cw..(first + i + 1) * cw];
        for ((g, d), &m) in row.iter_mut().zip(down.iter_mut()).zip(m) {
            *d = if m > k { G::ZERO } else { d.next() };
            *g = (*g).min(*d);
        }
    }
}

pub mod exact;
mod lanes;
mod scan;

use crate::plumbing::simd::Level;
use scan::{open_cells_scalar, Floor, Open, RowCells, Scan, BLOCK};

/// Asks for `values` in the cache ahead of their use, where the hardware
/// prefetchers cannot: the open-cell scan reads the scattered blocks that
/// are awake.
#[inline]
fn prefetch<T>(values: &[T]) {
    #[cfg(not(target_arch = "x86_64"))]
    let _ = values;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let bytes = std::mem::size_of_val(values);
        let start = values.as_ptr().cast::<i8>();
        for offset in (0..bytes).step_by(64) {
            // SAFETY: a prefetch never faults, and the address is within
            // `values`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(start.add(offset)) };
        }
    }
}

/// The open-cell scan's walk over a row's blocks: `read(b)` for every
/// block `b` whose wake has come (`wakes[b] <= slice`), its result the
/// block's new wake; returns how many were read. 32 blocks' wakes are
/// tested at a time, and the next 32's awake cells are asked for while
/// these are read: the blocks awake are scattered, too sparse for the
/// hardware prefetchers.
#[inline(always)]
fn each_awake_block(
    wakes: &mut [u16],
    slice: u16,
    RowCells {
        member,
        slope,
        floor,
    }: RowCells,
    mut read: impl FnMut(usize) -> u16,
) -> u64 {
    let awake_in = |wakes: &[u16], b0: usize| {
        wakes[b0.min(wakes.len())..]
            .iter()
            .take(32)
            .enumerate()
            .fold(0u32, |mask, (i, &w)| mask | u32::from(w <= slice) << i)
    };
    let mut ahead = awake_in(wakes, 0);
    let mut blocks_read = 0;
    for b0 in (0..wakes.len()).step_by(32) {
        let mut awake = ahead;
        blocks_read += u64::from(awake.count_ones());
        ahead = awake_in(wakes, b0 + 32);
        let mut wanted = ahead;
        while wanted != 0 {
            let c = (b0 + 32 + wanted.trailing_zeros() as usize) * BLOCK;
            wanted &= wanted - 1;
            prefetch(&member[c..c + 1]);
            prefetch(&slope[c..c + 1]);
            prefetch(&floor[c..c + 1]);
        }
        while awake != 0 {
            let b = b0 + awake.trailing_zeros() as usize;
            awake &= awake - 1;
            wakes[b] = read(b);
        }
    }
    blocks_read
}

/// The columns of row `r` whose parabola can narrow a target's cone, with
/// their parabolas' offsets (squared, in columns), into `kept` in order;
/// returns their count. A plane cell narrows a cone only within the cone's
/// width, the row's reach at most (`reach` columns; `aspect` turns column
/// distances into columns; `hidden` is [`Span::hidden`] of it), so a
/// column is needed
/// only where `g^2 + a^2 < reach^2`, `g` its column distance and `a` its
/// distance along the row to the targets' span (zero inside it). Columns
/// farther along than the reach are not read. Parabolas left out come no
/// nearer to any target than the reach, so a cell's floor may still be
/// capped at it. Beside the row's reach alone (`g < reach`), the span
/// leaves out a third of the pushes (2048², K = 256: 246 M kept of 385 M):
/// a row's targets are often bunched, and the columns beyond them come in
/// only where their own distance is short.
fn columns_in_reach<G: ColumnDistance>(
    column: &[G],
    (first, last): (u32, u32),
    (reach, aspect, hidden): (f64, f64, u16),
    lanes: Level,
    kept: &mut Kept,
) -> usize {
    let cw = column.len();
    let within = reach.min(cw as f64) as usize;
    let lo = (first as usize).saturating_sub(within);
    let hi = (last as usize + within + 1).min(cw);
    kept.columns.resize(cw + 8, 0);
    kept.offsets.resize(cw + 8, 0.0);
    let test = Span {
        first,
        last,
        aspect,
        // (The slack keeps a column that rounding would drop.)
        reach2: reach * reach * (1.0 + 1e-12),
        hidden,
        lanes,
    };
    let mut n = 0;
    for s in lo / SHARE..hi.div_ceil(SHARE) {
        let c0 = s * SHARE;
        let (a, b) = (lo.max(c0), hi.min(c0 + SHARE));
        n = keep_in_reach(&column[a..b], a as u32, test, kept, n);
    }
    n
}

/// What [`keep_in_reach`] tests a column against: the targets' span
/// `first..=last`, the column distances' scale to columns, and the reach
/// squared (in columns).
#[derive(Debug, Clone, Copy)]
struct Span {
    first: u32,
    last: u32,
    aspect: f64,
    reach2: f64,
    /// The largest column distance whose parabola's offset is at most 1
    /// ([`Span::hidden_bits`]).
    hidden: u16,
    lanes: Level,
}

/// Per-thread room for [`columns_in_reach`]: the columns kept and their
/// parabolas' offsets, with a vector's room past every column of a row.
#[derive(Debug, Default)]
struct Kept {
    columns: Vec<u32>,
    offsets: Vec<f64>,
}

/// Appends to `kept` from `n` on the columns `c0..` of a row's share,
/// `g`, whose parabolas come within the reach of the targets' span
/// (`test`), with their offsets; returns the new count. `kept` has room
/// for every column and a vector more. Eight columns at a time in the
/// test's [`Level`] where the distances are `u16`.
fn keep_in_reach<G: ColumnDistance>(
    g: &[G],
    c0: u32,
    test: Span,
    kept: &mut Kept,
    n: usize,
) -> usize {
    match (test.lanes, G::as_u16(g)) {
        // SAFETY: the CPU has AVX-512 (`crate::plumbing::simd::level`);
        // `kept` has a vector's room past every column.
        #[cfg(target_arch = "x86_64")]
        (Level::Avx512, Some(g)) => unsafe { lanes::keep_in_reach_avx512(g, c0, test, kept, n) },
        // SAFETY: the same, for AVX2.
        #[cfg(target_arch = "x86_64")]
        (Level::Avx2, Some(g)) => unsafe { lanes::keep_in_reach_avx2(g, c0, test, kept, n) },
        _ => {
            let (plane, near) = test.plane_and_near(g, 0);
            test.keep_scalar(g, 0, Span::hidden_bits(plane, near), c0, kept, n)
        }
    }
}

impl Span {
    /// The largest column distance `g` with `(g aspect)^2 <= 1` as the
    /// offsets round it (`aspect` columns a row): [`Self::hidden`], once
    /// a bake. Below the distance that stands for none.
    fn hidden(aspect: f64) -> u16 {
        (1..u16::MAX)
            .take_while(|&g| {
                let d = f64::from(g) * aspect;
                d * d <= 1.0
            })
            .last()
            .unwrap_or(0)
    }

    /// Bit `j` for column `j` of a row's share (at most [`SHARE`]
    /// columns): whether it is a plane cell (`plane`, distance 0)
    /// between two columns within [`Self::hidden`] (`near`). Its parabola
    /// is then never the lowest at a target (a cell outside the plane, so
    /// not `j`): on either side the neighbour's lies at or below it (`(x -
    /// j -+ 1)^2 + o <= (x - j)^2` for `o <= 1` and `x` past the
    /// neighbour), or is itself hidden, or comes no nearer than the reach.
    /// So it is not pushed: in the low slices, whose rows are mostly plane,
    /// that is most of the pushes. (The ends of a share, whose neighbours
    /// lie in other shares, are kept.)
    fn hidden_bits(plane: u64, near: u64) -> u64 {
        plane & (near << 1) & (near >> 1)
    }

    /// The `plane` and `near` bits of [`Self::hidden_bits`] of columns
    /// `from..` of `g`, one column at a time.
    fn plane_and_near<G: ColumnDistance>(self, g: &[G], from: usize) -> (u64, u64) {
        debug_assert!(g.len() <= SHARE);
        (from..g.len()).fold((0, 0), |(plane, near), j| {
            (
                plane | u64::from(g[j] == G::ZERO) << j,
                near | u64::from(g[j].cells() <= f64::from(self.hidden)) << j,
            )
        })
    }

    /// [`keep_in_reach`] one column at a time, from column `from` of `g`
    /// (whose first is column `c0`), with `g`'s [`Self::hidden_bits`].
    fn keep_scalar<G: ColumnDistance>(
        self,
        g: &[G],
        from: usize,
        hidden: u64,
        c0: u32,
        kept: &mut Kept,
        mut n: usize,
    ) -> usize {
        for (j, &g) in g.iter().enumerate().skip(from) {
            let c = c0 + j as u32;
            let along = self
                .first
                .saturating_sub(c)
                .max(c.saturating_sub(self.last));
            let (gd, along) = (g.cells() * self.aspect, f64::from(along));
            kept.columns[n] = c;
            kept.offsets[n] = gd * gd;
            n += usize::from(
                g != G::NONE && gd * gd + along * along < self.reach2 && hidden >> j & 1 == 0,
            );
        }
        n
    }
}

/// The cells of a row that a slice can narrow, into `targets` in order:
/// those whose cone is still open over the rise from their apex slice
/// (`member`) to the slice above, `slope * rise`, beyond their [`Floor`]
/// (`floor` counts of `unit` metres; 0 where none is known), read block by
/// block where the block's wake (`wakes`, one per [`BLOCK`] cells) has come
/// (see [`Scan`]); the wakes of the blocks read are renewed. Returns the
/// widest such `slope * rise`, the row's reach. Eight cells at a time in
/// the scan's [`Level`] (compressed indices, a masked maximum; the same
/// targets and the same reach, a maximum being exact in any order).
fn open_cells<'t>(
    member: &[u16],
    slope: &[f32],
    floor: &[u16],
    scan: Scan,
    wakes: &mut [u16],
    room: &'t mut Vec<u32>,
) -> Open<'t> {
    let cells = RowCells::new(member, slope, floor);
    assert_eq!(wakes.len(), cells.len().div_ceil(BLOCK));
    // Room for every cell and a vector more, kept between rows: only the
    // first `n` are the row's, so nothing needs clearing.
    if room.len() < cells.len() + 8 {
        room.resize(cells.len() + 8, 0);
    }
    let (n, reach, blocks_read) = match scan.lanes {
        // SAFETY: the CPU has AVX-512 (`crate::plumbing::simd::level`);
        // `room` has room for every cell and a vector more; the slices agree
        // in length, and every member indexes `rise_of`.
        #[cfg(target_arch = "x86_64")]
        Level::Avx512 => unsafe { lanes::open_cells_avx512(cells, scan, wakes, room) },
        // SAFETY: the same, for AVX2.
        #[cfg(target_arch = "x86_64")]
        Level::Avx2 => unsafe { lanes::open_cells_avx2(cells, scan, wakes, room) },
        _ => open_cells_scalar(cells, scan, wakes, room),
    };
    Open {
        targets: &room[..n],
        reach,
        blocks_read,
    }
}

/// One slice's row pass, the same for every row: the open-cell scan, and
/// what narrowing a cell's cone needs.
#[derive(Clone, Copy)]
struct RowPass<'a> {
    scan: Scan<'a>,
    rise_of: &'a [f64],
    floor: Floor,
    /// Whether slices above this one remain to read the floors.
    keeps_floor: bool,
    dx: f64,
    aspect: f64,
    hidden: u16,
}

impl RowPass<'_> {
    /// The slope update of one row's cells outside the slice's plane (`m`,
    /// their apex slices; `column`, each column's distance to the plane):
    /// the blocks the scan read and the cells it found open.
    #[inline]
    fn row<G: ColumnDistance>(
        &self,
        m: &[u16],
        (row, row_floor, row_wakes): (&mut [f32], &mut [u16], &mut [u16]),
        column: &[G],
        (envelope, room, kept): &mut (Envelope, Vec<u32>, Kept),
    ) -> (u64, u64) {
        let (scan, rise_of, dx) = (self.scan, self.rise_of, self.dx);
        // The cells this slice can narrow (outside the plane, with a cone
        // still open), and the reach: the widest of them, the farthest that
        // a plane cell can be and still narrow a cone of this row.
        let Open {
            targets,
            reach,
            blocks_read,
        } = open_cells(m, row, row_floor, scan, row_wakes, room);
        let open = targets.len() as u64;
        if targets.is_empty() {
            return (blocks_read, open);
        }
        // Only the parabolas that come within the reach of the targets: at
        // high slices, where plane cells are few and far, that leaves out
        // most of them.
        let span = (targets[0], targets[targets.len() - 1]);
        let scale = (reach / dx, self.aspect, self.hidden);
        let n = columns_in_reach(column, span, scale, scan.lanes, kept);
        envelope.clear();
        for (&c, &offset) in kept.columns[..n].iter().zip(&kept.offsets[..n]) {
            envelope.push(f64::from(c), offset);
        }
        // (No plane cell in reach: nothing to update.)
        if envelope.is_empty() {
            return (blocks_read, open);
        }
        let dx2 = dx * dx;
        envelope.evaluate_at(targets.iter().map(|&c| c as usize), |c, d2| {
            let rise = rise_of[usize::from(m[c])];
            // Compare squares; one root only where the slope drops.
            let d2 = d2 * dx2;
            let bound = f64::from(row[c]) * rise;
            if d2 < bound * bound {
                row[c] = round_down_f32(d2.sqrt() / rise * SLOPE_MARGIN);
            }
            // Parabolas left out are `reach` or farther, so the envelope is
            // the distance only below it.
            if self.keeps_floor {
                row_floor[c] = self.floor.of(d2.min(reach * reach));
            }
        });
        (blocks_read, open)
    }
}

#[cfg(test)]
mod tests;
