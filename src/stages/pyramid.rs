//! The `pyramid` stage: quadtree max (and min) pyramids of the surface's
//! bounding heights, for hierarchical ray tracing (Paglieroni and Petersen
//! 1992, sec. 1.2).
//!
//! Level 0 has one element per cell: the tallest (`pyramid_max`) and lowest
//! (`pyramid_min`) of its four corners, `-inf` / `+inf` for a cell with a
//! nodata corner (no surface; see `terrabake_format::surface`). Level `l + 1`
//! holds the max / min of 2 x 2 blocks of level `l` (a last odd row or column
//! is reduced alone), up to the first level that fits in one tile.
//!
//! Out of core in one pass: rows of cells are made from two rows of posts and
//! fed up the levels as they come; each level holds at most one tile row
//! before writing it, so memory is about two output tile rows of level 0
//! whatever the DEM's area.
//!
//! Memory on disk: 2 x 4 bytes per cell at level 0, and a third more for the
//! levels above: 10.7 bytes per DEM cell for max and min together (5.3 for
//! max alone), against 32-byte quadtree nodes per node in the paper
//! (42.7 bytes per cell).

use std::path::Path;

use anyhow::Result;
use terrabake_format::surface::Cell;
use terrabake_format::trace::{PYRAMID_MAX, PYRAMID_MIN};
use terrabake_format::{Asset, Codec, ElemType, LayerEntry, LayerSpec, LayerWriter, Mmap};

use crate::plumbing::progress::Progress;
use crate::stage::Stage;
use crate::terrain::tiling::push_tile_row;

/// Level-0 bounding heights of one row of cells from its two rows of posts
/// (`north` and `south`, `n + 1` posts each): `max[i]` and `min[i]` of cell `i`.
pub(crate) fn cell_bounds_row(north: &[f32], south: &[f32], max: &mut [f32], min: &mut [f32]) {
    for i in 0..max.len() {
        let cell = Cell {
            nw: north[i],
            ne: north[i + 1],
            sw: south[i],
            se: south[i + 1],
        };
        max[i] = cell.max();
        min[i] = cell.min();
    }
}

/// The cells of each stored level of a `w x h`-post DEM: level 0 has one per
/// cell, each level above halves them, up to the first that fits a tile.
pub(crate) fn level_dims(w: u32, h: u32, ts: u32) -> Vec<(u32, u32)> {
    let mut dims = vec![(w.saturating_sub(1), h.saturating_sub(1))];
    while dims.last().is_some_and(|&(x, y)| x > ts || y > ts) {
        let &(x, y) = dims.last().expect("non-empty");
        dims.push((x.div_ceil(2), y.div_ceil(2)));
    }
    dims
}

/// One row of level `l + 1` from two rows of level `l` (`lower` is `None` for
/// a last odd row): 2 x 2 maxima into `max`, minima into `min`.
pub(crate) fn reduce_rows(
    upper: (&[f32], &[f32]),
    lower: Option<(&[f32], &[f32])>,
    max: &mut [f32],
    min: &mut [f32],
) {
    let w = upper.0.len();
    for (i, (mx, mn)) in max.iter_mut().zip(min.iter_mut()).enumerate() {
        let (a, b) = (2 * i, (2 * i + 1).min(w - 1));
        let mut hi = upper.0[a].max(upper.0[b]);
        let mut lo = upper.1[a].min(upper.1[b]);
        if let Some((lmax, lmin)) = lower {
            hi = hi.max(lmax[a]).max(lmax[b]);
            lo = lo.min(lmin[a]).min(lmin[b]);
        }
        *mx = hi;
        *mn = lo;
    }
}

/// One level being written: a tile row being filled, and a row waiting for
/// its partner to be reduced into the next level.
struct Level {
    width: usize,
    max: LayerWriter,
    min: LayerWriter,
    band_max: Vec<f32>,
    band_min: Vec<f32>,
    carry: Option<(Vec<f32>, Vec<f32>)>,
}

struct Builder {
    levels: Vec<Level>,
    tile: usize,
}

impl Builder {
    fn push(&mut self, l: usize, max: Vec<f32>, min: Vec<f32>) -> Result<()> {
        let (tile, top) = (self.tile, l + 1 == self.levels.len());
        let level = &mut self.levels[l];
        level.band_max.extend_from_slice(&max);
        level.band_min.extend_from_slice(&min);
        if level.band_max.len() == tile * level.width {
            Self::flush(level)?;
        }
        if top {
            return Ok(());
        }
        match level.carry.take() {
            None => level.carry = Some((max, min)),
            Some((umax, umin)) => {
                let w = self.levels[l + 1].width;
                let (mut nmax, mut nmin) = (vec![0f32; w], vec![0f32; w]);
                reduce_rows((&umax, &umin), Some((&max, &min)), &mut nmax, &mut nmin);
                self.push(l + 1, nmax, nmin)?;
            }
        }
        Ok(())
    }

    fn flush(level: &mut Level) -> Result<()> {
        if !level.band_max.is_empty() {
            push_tile_row(
                &mut level.max,
                &level.band_max,
                level.width,
                f32::NEG_INFINITY,
            )?;
            push_tile_row(&mut level.min, &level.band_min, level.width, f32::INFINITY)?;
            level.band_max.clear();
            level.band_min.clear();
        }
        Ok(())
    }

    fn finish(mut self) -> Result<Vec<LayerEntry>> {
        for l in 0..self.levels.len() {
            if let Some((umax, umin)) = self.levels[l].carry.take() {
                let w = self.levels[l + 1].width;
                let (mut nmax, mut nmin) = (vec![0f32; w], vec![0f32; w]);
                reduce_rows((&umax, &umin), None, &mut nmax, &mut nmin);
                self.push(l + 1, nmax, nmin)?;
            }
            Self::flush(&mut self.levels[l])?;
        }
        let mut entries = Vec::new();
        for level in self.levels {
            entries.push(level.max.finish()?);
            entries.push(level.min.finish()?);
        }
        Ok(entries)
    }
}

/// The pyramid stage (`terrabake pyramid`, recipe step `pyramid`).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct PyramidStage;

impl Stage for PyramidStage {
    fn name(&self) -> &'static str {
        "pyramid"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::json!({ "surface": "two triangles per cell, south-west to north-east diagonal" })
    }

    /// `pyramid_max@L` and `pyramid_min@L` for every level up to the first
    /// that fits one tile, level by level.
    fn outputs(&self, m: &terrabake_format::Manifest) -> Vec<String> {
        level_dims(m.width, m.height, m.tile_size)
            .iter()
            .enumerate()
            .flat_map(|(l, _)| [format!("{PYRAMID_MAX}@{l}"), format!("{PYRAMID_MIN}@{l}")])
            .collect()
    }

    /// Level 0 of a region's cells (cell `(x, y)` lies south-east of post
    /// `(x, y)`) needs the posts at their corners: one post past the
    /// region. (Level `L` reduces aligned blocks of `2^L` cells: a region
    /// aligned to them needs nothing more.)
    fn reach(&self, _: &terrabake_format::Manifest) -> crate::stage::Reach {
        crate::stage::Reach::Posts(1)
    }

    /// Level 0 could split by rows, but every level above it is a reduction
    /// of the one below across part boundaries, and the whole pyramid costs
    /// about what copying its chunks from the parts would (one read of the
    /// heights, one write of the levels): the join builds it.
    fn split(&self, _: &terrabake_format::Manifest) -> crate::stage::Split {
        crate::stage::Split::Join
    }

    /// A band of post rows one tile high (plus one row), and per level a
    /// tile row of maxima and minima being filled (the levels' widths add
    /// up to under twice the cells').
    fn memory(&self, m: &terrabake_format::Manifest) -> Option<u64> {
        let (w, ts) = (u64::from(m.width), u64::from(m.tile_size));
        Some(4 * w * (ts + 1) + 2 * 4 * ts * 2 * w)
    }

    /// Never split (it runs at the join): every chunk, whatever the share.
    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        _: &crate::stage::Share,
        progress: Progress,
    ) -> crate::Result<Vec<LayerEntry>> {
        let height = asset.height()?;
        let (w, h, ts) = (height.width(), height.height(), height.tile_size());
        crate::error::ensure!(w >= 2 && h >= 2, "a {w} x {h} DEM has no cells");
        let (cw, ch) = (w - 1, h - 1);
        let dims = level_dims(w, h, ts);
        let spec = |name: &str, level: usize, (lw, lh): (u32, u32), fill: f32| {
            LayerSpec {
            name: name.into(),
            level: level as u32,
            elem: ElemType::F32,
            bands: 1,
            width: lw,
            height: lh,
            tile_size: ts,
            codec: Codec::Raw,
            fill_bits: u64::from(fill.to_bits()),
            stage: "pyramid".into(),
            description: format!(
                "{} corner height of the cells under each element (2^{level} x 2^{level} cells), metres; {} where no surface",
                if fill < 0.0 { "tallest" } else { "lowest" },
                if fill < 0.0 { "-inf" } else { "+inf" }
            ),
        }
        };
        let mut levels = Vec::new();
        for (l, &d) in dims.iter().enumerate() {
            levels.push(Level {
                width: d.0 as usize,
                max: LayerWriter::create(dir, spec(PYRAMID_MAX, l, d, f32::NEG_INFINITY))?,
                min: LayerWriter::create(dir, spec(PYRAMID_MIN, l, d, f32::INFINITY))?,
                band_max: Vec::with_capacity(ts as usize * d.0 as usize),
                band_min: Vec::with_capacity(ts as usize * d.0 as usize),
                carry: None,
            });
        }
        let mut builder = Builder {
            levels,
            tile: ts as usize,
        };
        let bar = progress.bar(u64::from(ch), "pyramid", "rows");
        // Post rows in bands of one tile, plus the row below it.
        let mut posts = vec![0f32; (w * (ts + 1)) as usize];
        for r0 in (0..ch).step_by(ts as usize) {
            let rows = ts.min(ch - r0);
            let band = &mut posts[..(w * (rows + 1)) as usize];
            height.read_window(0, 0, r0, w, rows + 1, band)?;
            for r in 0..rows as usize {
                let (mut max, mut min) = (vec![0f32; cw as usize], vec![0f32; cw as usize]);
                let north = &band[r * w as usize..(r + 1) * w as usize];
                let south = &band[(r + 1) * w as usize..(r + 2) * w as usize];
                cell_bounds_row(north, south, &mut max, &mut min);
                builder.push(0, max, min)?;
            }
            bar.inc(u64::from(rows));
        }
        bar.finish_and_clear();
        Ok(builder.finish()?)
    }
}
