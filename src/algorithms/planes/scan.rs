//! The open-cell scan of one slice: which cells of a row the slice can
//! narrow, read block by block where a block's wake has come, with each
//! cell's floor (its distance to the planes above, in two bytes).

use super::{each_awake_block, Level, Slices};

/// A cell's distance to a slice's plane, rounded down to a `u16` count of
/// quarter cells (of the shorter side), saturating: the floor of its
/// distance to every higher slice's plane, since those planes are subsets.
/// A cell whose floor already reaches its cone's width at a slice's height,
/// `slope * rise`, cannot be narrowed by that slice and is no target: no
/// evaluation, and no part in the row's reach. (The paper evaluates every
/// cell in every slice.) Two bytes a cell rather than a float's four: the
/// floor is read for every cell and slice.
#[derive(Debug, Clone, Copy)]
pub(super) struct Floor {
    /// Metres per count.
    pub(super) unit: f64,
}

impl Floor {
    pub(super) fn new(spacing: f64) -> Self {
        Self {
            unit: spacing / 4.0,
        }
    }

    /// The floor of a squared distance in metres: rounded down with a
    /// margin above the square root's rounding, so that `count * unit`
    /// never exceeds the distance.
    pub(super) fn of(self, d2: f64) -> u16 {
        (d2.sqrt() / self.unit * (1.0 - 1e-9)).min(f64::from(u16::MAX)) as u16
    }
}

/// Cells per block of the open-cell scan: a block whose [`Scan::wake`]
/// lies above the slice is not read at all.
pub(super) const BLOCK: usize = 8;

/// What the open-cell scan of one slice tests a cell against: the cell is
/// open when its cone's width at the slice above, `slope * rise_of[member]`,
/// exceeds its [`Floor`] (`floor * unit` metres).
///
/// **Blocks that cannot open.** Most of a row's cells are closed in most
/// slices (at 2048², K = 256, 7 % of the cells are open in a slice), yet
/// testing every cell's member, slope and floor was a third of the bake at
/// 8192² (about half of it the test's gather and conversions, which a
/// second scan of a row already in the cache paid again). A closed cell's
/// slope and floor change only when it is evaluated, that is, when it is open; so
/// while it stays closed, the first slice at which it can open follows from
/// its three values alone: its rise grows one `step` a slice from its apex
/// slice, and it opens once `slope * rise > floor * unit`. Each block keeps
/// a lower bound of that slice over its cells, its *wake* (`0` after a
/// block with an open cell: its targets' values change), and the scan
/// passes over a block until the slice reaches its wake, testing 32
/// blocks' wakes in one compare. A block is one vector of eight cells: at
/// 8192², K = 256, 23 % of the blocks are read; at 2048², 28 % (54 % with
/// blocks of 64 cells, which gained nothing); `terrabake-bench cones
/// --scan` counts them ([`PlaneStats`]). The targets are the same as
/// without blocks, so the planes are the same bit for bit.
#[derive(Debug, Clone, Copy)]
pub(super) struct Scan<'a> {
    /// The slice, in the bottom-up order of the passes (the top slice,
    /// run first, scans every block: wakes start at 0).
    pub(super) slice: u16,
    pub(super) unit: f64,
    pub(super) rise_of: &'a [f64],
    /// Slices per floor count, `unit / step`, rounded down by
    /// [`WAKE_MARGIN`]; `0` where the slices do not step (one slice, a
    /// flat DEM: every wake is then the apex slice).
    pub(super) slices_per_count: f64,
    /// The vector code that runs the scan (the CPU's best; the tests
    /// try each).
    pub(super) lanes: Level,
}

impl<'a> Scan<'a> {
    /// Slice `k`'s test, `rise_of` its [`Slices::rise_of`].
    pub(super) fn new(slices: &Slices, k: usize, unit: f64, rise_of: &'a [f64]) -> Self {
        Self {
            slice: k as u16,
            unit,
            rise_of,
            slices_per_count: if slices.step > 0.0 {
                unit / slices.step * WAKE_MARGIN
            } else {
                0.0
            },
            lanes: crate::plumbing::simd::level(),
        }
    }

    /// A lower bound of the first slice, from the apex slice `member` on,
    /// at which a cell can open: `member + floor(x) - 1` with `x = floor *
    /// unit / (slope * step)` rounded down a little (the slices between the
    /// apex slice and the one where the rise passes `floor * unit /
    /// slope`); the `- 1` takes up the rounding of the slice heights. `u16::MAX`
    /// where it never opens (a zero slope).
    pub(super) fn wake(&self, member: u16, slope: f32, floor: u16) -> u16 {
        let x = f64::from(floor) * self.slices_per_count / f64::from(slope);
        // (0 / 0: never open. A NaN compares false and takes the maximum.)
        let x = if x < f64::from(u16::MAX) {
            x
        } else {
            f64::from(u16::MAX)
        };
        (u32::from(member) + (x as u32).saturating_sub(1)).min(u32::from(u16::MAX)) as u16
    }
}

/// Below the relative error of the vector reciprocal (2^-14), so that the
/// scalar and vector wakes both stay below the true slice.
pub(super) const WAKE_MARGIN: f64 = 1.0 - 1.0 / 4096.0;

/// What [`super::open_cells`] found in a row: the cells a slice can narrow, in
/// order, the widest of their cones (the row's reach), and how many blocks
/// it read.
#[derive(Debug)]
pub(super) struct Open<'t> {
    pub(super) targets: &'t [u32],
    pub(super) reach: f64,
    pub(super) blocks_read: u64,
}

/// A row's cells as the open-cell scan reads them: each cell's member of
/// the span, its slope and its floor, as long as each other.
#[derive(Debug, Clone, Copy)]
pub(super) struct RowCells<'r> {
    pub(super) member: &'r [u16],
    pub(super) slope: &'r [f32],
    pub(super) floor: &'r [u16],
}

impl<'r> RowCells<'r> {
    pub(super) fn new(member: &'r [u16], slope: &'r [f32], floor: &'r [u16]) -> Self {
        assert!(member.len() == slope.len() && member.len() == floor.len());
        Self {
            member,
            slope,
            floor,
        }
    }

    pub(super) fn len(&self) -> usize {
        self.member.len()
    }
}

/// [`open_cells`] one cell at a time, `targets` as long as the row or
/// longer; returns the count, the reach and the blocks read.
pub(super) fn open_cells_scalar(
    cells: RowCells,
    scan: Scan,
    wakes: &mut [u16],
    targets: &mut [u32],
) -> (usize, f64, u64) {
    let (mut n, mut widest) = (0, [0.0f64; 8]);
    let blocks_read = each_awake_block(wakes, scan.slice, cells, |b| {
        open_block(b, cells, scan, targets, &mut n, &mut widest)
    });
    (n, widest.into_iter().fold(0.0, f64::max), blocks_read)
}

/// Block `b` of [`open_cells`], one cell at a time: its open cells onto
/// `targets` from `n`, their cones' widths into the running maxima
/// `widest` (eight, so that each cell need not wait on the last); returns
/// the block's new wake. Branch-free within the block.
#[inline(always)]
pub(super) fn open_block(
    b: usize,
    RowCells {
        member,
        slope,
        floor,
    }: RowCells,
    scan: Scan,
    targets: &mut [u32],
    n: &mut usize,
    widest: &mut [f64; 8],
) -> u16 {
    let (c0, c1) = (b * BLOCK, ((b + 1) * BLOCK).min(member.len()));
    let mut any_open = false;
    for c in c0..c1 {
        let v = f64::from(slope[c]) * scan.rise_of[usize::from(member[c])];
        // (inf * 0 is NaN, which is never greater.)
        let open = v > f64::from(floor[c]) * scan.unit;
        targets[*n] = c as u32;
        *n += usize::from(open);
        let lane = &mut widest[c % 8];
        *lane = if open && v > *lane { v } else { *lane };
        any_open |= open;
    }
    // (A block with an open cell is read again: its targets change.)
    if any_open {
        0
    } else {
        (c0..c1)
            .map(|c| scan.wake(member[c], slope[c], floor[c]))
            .min()
            .unwrap_or(u16::MAX)
    }
}
