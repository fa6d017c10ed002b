//! What the `horizons` stage holds at once: the figure the stage checks
//! against `--max-memory` before it allocates ([`crate::stage::Stage::memory`])
//! and the planner predicts a bake's peak from (docs/PLANNING.md, "What a
//! line bake holds").

use crate::algorithms::horizon::{line, BandKind, Method};
use crate::terrain;

use super::{HorizonsStage, OUT_OF_CORE_BATCH, SECTOR_BYTES_PER_POST};

/// The out-of-core line sweeps' lanes take at most `1 / LANE_SHARE` of
/// `--max-memory`, split evenly between the sweeps of a batch. A lane too
/// shallow for its step's vertices sends the step to the scalar sweep (the
/// same bits, 2.2x the time on the bundled tile at 48 directions under 100
/// MiB with a sixteenth); a quarter keeps the steps of a planned bake
/// under such a limit in lanes.
const LANE_SHARE: usize = 4;

impl HorizonsStage {
    /// Bytes held in memory for `posts` posts with `threads` bands in
    /// flight, or `None` where the method runs out of core: the DEM (4
    /// bytes per post) and per band Stewart's tree ([`SECTOR_BYTES_PER_POST`])
    /// or one band of angles; with distances, a band of them and the
    /// tree's tags (the post of every hull point and bucket entry: 12
    /// bytes per post measured, 30-46 MiB more at 1.44 M posts and two
    /// sectors in flight).
    pub(crate) fn in_core_bytes(&self, posts: u64, threads: u64) -> Option<u64> {
        let per_band = match (self.method, self.distance) {
            (Method::Sector, false) => SECTOR_BYTES_PER_POST,
            (Method::Sector, true) => SECTOR_BYTES_PER_POST + 16,
            (Method::Line | Method::Sampled, false) => 4,
            (Method::Line | Method::Sampled, true) => 8,
        };
        (!self.out_of_core()).then_some(posts * (4 + per_band * threads))
    }

    /// Bytes the stage holds at once on a `w x h` DEM in tiles of `ts`
    /// posts, cells `dx x dy` metres (`nodata`: whether it has nodata
    /// posts). In core, [`Self::in_core_bytes`]. Out of core, the steps in
    /// flight (one per thread), each holding its window of heights (a tile
    /// row, with the rows within the maximum distance for bounded sectors)
    /// and a tile row of angles (and of distances), plus what the line
    /// sweeps of a batch carry between bands ([`Self::carried_bytes`]).
    pub(crate) fn memory_bytes(
        &self,
        (w, h, ts): (usize, usize, usize),
        (dx, dy): (f64, f64),
        nodata: bool,
    ) -> u64 {
        let threads = rayon::current_num_threads() as u64;
        if let Some(held) = self.in_core_bytes((w * h) as u64, threads) {
            return held;
        }
        let halo = self
            .sight
            .max_distance
            .map_or(0, |d| terrain::posts_within(d, dy));
        let window = (ts + 2 * halo).min(h) as u64;
        let outputs = if self.distance { 2 } else { 1 };
        let (w, ts) = (w as u64, ts as u64);
        threads * 4 * w * (window + outputs * ts) + self.carried_bytes(w as usize, (dx, dy), nodata)
    }

    /// The most bytes the line sweeps to the edge of one batch carry from
    /// band to band together (`line::BandedSweep::most_carried_bytes`, the
    /// lanes' share of `--max-memory` as [`Self::row_bands`] gives it):
    /// the largest sum over any [`OUT_OF_CORE_BATCH`] neighbouring bands,
    /// so that a part's share of the bands, batched from its own first,
    /// stays within it too. Nothing for the other methods.
    fn carried_bytes(&self, width: usize, (dx, dy): (f64, f64), nodata: bool) -> u64 {
        if self.method != Method::Line || self.sight.max_distance.is_some() {
            return 0;
        }
        let lane_bytes = self.lane_bytes();
        let each: Vec<usize> = self
            .bands(dx, dy)
            .iter()
            .map(|band| match &band.kind {
                BandKind::Line(dir) => {
                    line::BandedSweep::most_carried_bytes(dir, width, nodata, lane_bytes)
                }
                _ => 0,
            })
            .collect();
        let batch = OUT_OF_CORE_BATCH.min(each.len()).max(1);
        each.windows(batch)
            .map(|w| w.iter().sum::<usize>())
            .max()
            .unwrap_or(0) as u64
    }

    /// What each out-of-core line sweep's lanes may take
    /// ([`LANE_SHARE`], split over a batch).
    pub(super) fn lane_bytes(&self) -> usize {
        self.max_memory as usize / LANE_SHARE / OUT_OF_CORE_BATCH
    }
}
