//! The tracing layers from a tracing budget (`steps=N`, `rays=N`): whether
//! the max pyramid alone serves the rays fast enough, and else how many
//! slices the cone planes need (docs/PLANNING.md, "Tracing").
//!
//! **The workload.** Paglieroni and Petersen measure their tracers over the
//! oblique views of their Table 1; `terrabake render --view 1..=16` and the
//! tracing benchmark use sixteen such views of any DEM
//! ([`builtin_views`](crate::views::builtin_views)), and so does
//! this pilot: their primary rays, [`VIEWS`] pixels, traced on one thread.
//! Mean steps per ray count the work the tracer does, the same on any
//! machine; rays per second per thread are this machine's.
//!
//! **The scene measures itself.** The cone planes' gain depends on the
//! scene: on the bundled tile 64 slices take 3.35 steps a ray against the
//! pyramid's 10.0, while on a lidar DSM of walls and flat roofs no slice
//! count traces faster than the pyramid alone. So the pilot bakes the
//! layers as the stages would, into a temporary asset of the DEM (its
//! centre [`WINDOW_SIDE`]-post window when larger; the views then span the
//! window, not the DEM, and the plan says so), and traces the
//! views through them: the pyramid alone, then cone planes of each of
//! [`SLICE_COUNTS`] in turn, u16 (as fast as f32 in half the bytes,
//! docs/BENCHMARKS.md). It stops at the first that meets the budget: the
//! least bytes (no cone planes at all, when the need is `tracing`), then
//! the least bake time (fewer slices bake faster). The paper fixes its
//! slice count per run (sec. 2.1); here the budget picks it per scene.
//!
//! Rays per second are timed, and passes of the same layers spread by up
//! to a tenth here, so the pilot asks [`RAYS_MARGIN`] of a `rays` budget.
//! `check` traces the same views through the baked asset ([`speed`]) and
//! judges the budget on the whole DEM.

use std::io::Write;

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use terrabake_format::cones::ConeEncoding;
use terrabake_format::trace::{Method, Tracer};
use terrabake_format::{Asset, Mmap};

use crate::io::source::{ByteOrder, RawSampleType, RawSpec};
use crate::plan::budget::Budget;
use crate::plan::{round_up, Choice};
use crate::plumbing::progress::Progress;
use crate::stage::asset::Wait;
use crate::stage::run_stage;
use crate::stages::cones::{ConesStage, SliceChoice};
use crate::stages::ingest::{IngestOptions, IngestStage};
use crate::stages::pyramid::PyramidStage;
use crate::views::views_cost;

/// Cone slice counts the pilot tries, fewest first.
pub const SLICE_COUNTS: [usize; 7] = [4, 8, 16, 32, 64, 128, 256];
/// Each view's side in pixels and the pixel stride traced: 16 views of
/// 64 x 64 rays, 65,536 rays a pass.
pub const VIEWS: (u32, u32) = (256, 4);
/// Timed passes; the fastest is taken.
const PASSES: usize = 5;
/// The pilot takes a `rays` budget as met only at this multiple of it:
/// passes of the same layers spread by up to a tenth on this machine
/// (docs/BENCHMARKS.md), and `check` measures again.
pub const RAYS_MARGIN: f64 = 1.1;
/// The pilot bakes at most this many posts a side: the centre window of a
/// larger DEM. The views span what is baked, so a window's rays are
/// shorter than the whole DEM's: on a 4096² fractal a 2048² window
/// measured 4.25 steps a ray at 64 slices where the whole took 4.85
/// (docs/BENCHMARKS.md). Up to this side the prediction is exact.
pub const WINDOW_SIDE: u32 = 4096;

/// What tracing a set of layers costs over the views, on one thread.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TracingSpeed {
    /// Mean steps per ray: the walk's steps, levels and leaps.
    pub mean_steps: f64,
    /// Rays per second on one thread: the fastest of [`PASSES`] passes.
    pub rays_per_second: f64,
}

impl TracingSpeed {
    /// Whether the budget's tracing limits hold with `margin` on `rays`.
    pub fn meets(&self, budget: &Budget, margin: f64) -> bool {
        budget.steps.is_none_or(|s| self.mean_steps <= s)
            && budget
                .rays
                .is_none_or(|r| self.rays_per_second >= margin * r)
    }
}

/// One set of tracing layers the pilot measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TracingCandidate {
    /// Cone slices (`None`: the pyramid alone, hierarchical tracing).
    pub slices: Option<usize>,
    pub speed: TracingSpeed,
    /// Seconds the cone planes took to bake on the pilot's window, scaled
    /// to the whole DEM by its posts (0 for the pyramid alone, which every
    /// tracing need bakes).
    pub bake_seconds: f64,
    pub meets: bool,
}

/// What the tracing budget decided.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TracingPlan {
    /// Every candidate measured, in the order tried; the first that meets
    /// the budget is the chosen one.
    pub candidates: Vec<TracingCandidate>,
    /// The window the pilot baked, `[x, y, width, height]` posts.
    pub window: [u32; 4],
}

impl TracingPlan {
    /// The chosen candidate.
    pub fn chosen(&self) -> &TracingCandidate {
        self.candidates
            .iter()
            .find(|c| c.meets)
            .expect("a tracing plan has met its budget")
    }
}

/// Traces the views through `asset`'s layers with `method` on one thread:
/// a warm pass (pages and checksums on first touch are not the tracer's),
/// then the fastest of [`PASSES`].
pub fn speed(asset: &Asset<Mmap>, method: Method) -> Result<TracingSpeed> {
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let tracer = Tracer::new(asset)?;
    one_thread.install(|| -> Result<TracingSpeed> {
        views_cost(asset, &tracer, method, VIEWS)?;
        let mut passes = (0..PASSES)
            .map(|_| views_cost(asset, &tracer, method, VIEWS))
            .collect::<terrabake_format::Result<Vec<_>>>()?;
        // The fastest pass: another process or a busy host only ever
        // slows a pass, so the fastest is the layers' own speed.
        passes.sort_by(|a, b| a.seconds.total_cmp(&b.seconds));
        let fastest = passes[0];
        Ok(TracingSpeed {
            mean_steps: fastest.mean_steps,
            rays_per_second: fastest.rays as f64 / fastest.seconds.max(1e-9),
        })
    })
}

/// Plans the tracing layers of `asset` for `budget`'s `steps` and `rays`:
/// `fast` when the need is `fast_tracing` (cone planes whatever the
/// pyramid alone does). Refused, with the fastest measured, when no
/// candidate meets the budget.
pub fn plan(
    asset: &Asset<Mmap>,
    budget: &Budget,
    fast: bool,
    progress: Progress,
) -> Result<TracingPlan> {
    let m = asset.manifest();
    let window = centre_window(m.width, m.height);
    let scratch = tempfile::Builder::new()
        .prefix("terrabake-tracing-pilot-")
        .tempdir()
        .context("the tracing pilot's temporary asset")?;
    let dir = scratch.path().join("window.tbake");
    write_window(asset, window, scratch.path(), &dir)?;
    let posts_scale =
        f64::from(m.width) * f64::from(m.height) / (f64::from(window[2]) * f64::from(window[3]));
    run_stage(&dir, &PyramidStage, true, progress)?;
    let mut candidates = Vec::new();
    if !fast {
        let speed = speed(&Asset::open(&dir)?, Method::Hierarchical)?;
        candidates.push(TracingCandidate {
            slices: None,
            speed,
            bake_seconds: 0.0,
            meets: speed.meets(budget, RAYS_MARGIN),
        });
    }
    for k in SLICE_COUNTS {
        if candidates.last().is_some_and(|c| c.meets) {
            break;
        }
        let mut stage = ConesStage {
            slices: SliceChoice::Count(k),
            encoding: ConeEncoding::U16,
            ..Default::default()
        };
        if let Some(bytes) = budget.memory_bytes() {
            stage.max_memory = bytes;
        }
        let baked = run_stage(&dir, &stage, true, progress)?;
        let speed = speed(&Asset::open(&dir)?, Method::Parametric)?;
        candidates.push(TracingCandidate {
            slices: Some(k),
            speed,
            bake_seconds: baked.seconds * posts_scale,
            meets: speed.meets(budget, RAYS_MARGIN),
        });
    }
    if !candidates.iter().any(|c| c.meets) {
        let fastest = candidates
            .iter()
            .max_by(|a, b| a.speed.rays_per_second.total_cmp(&b.speed.rays_per_second))
            .expect("candidates");
        let fewest = candidates
            .iter()
            .min_by(|a, b| a.speed.mean_steps.total_cmp(&b.speed.mean_steps))
            .expect("candidates");
        anyhow::bail!(
            "budget {budget} cannot be met by the tracing layers on this scene: the fewest steps a ray are {:.2} ({}), the most rays per second on one thread {:.0} ({}); relax{}{}",
            fewest.speed.mean_steps,
            layers(fewest.slices),
            fastest.speed.rays_per_second,
            layers(fastest.slices),
            budget.steps.map_or(String::new(), |_| format!(" steps to at least {}", round_up(fewest.speed.mean_steps, 2))),
            budget.rays.map_or(String::new(), |_| format!(" rays to at most {}", (fastest.speed.rays_per_second / RAYS_MARGIN).floor())),
        );
    }
    Ok(TracingPlan { candidates, window })
}

/// The layers a candidate traces through, in words.
fn layers(slices: Option<usize>) -> String {
    slices.map_or("the pyramid alone".into(), |k| {
        format!("{k}-slice cone planes")
    })
}

/// Why the tracing layers are what they are, and what the next cheaper
/// candidate would have given.
pub(super) fn choice(plan: &TracingPlan, budget: &Budget) -> Choice {
    let chosen = plan.chosen();
    let said = |c: &TracingCandidate| {
        format!(
            "{:.2} steps a ray, {:.0} rays/s on one thread",
            c.speed.mean_steps, c.speed.rays_per_second
        )
    };
    let [x, y, w, h] = plan.window;
    let measured = if [x, y] == [0, 0] {
        format!("a bake of the whole {w} x {h} DEM")
    } else {
        format!("a bake of the DEM's centre {w} x {h} window (its views are shorter than the whole DEM's: check judges the whole)")
    };
    Choice {
        what: "tracing layers".into(),
        chosen: layers(chosen.slices),
        why: format!(
            "the fewest bytes and bake seconds that meet {}: {} over the built-in views, measured on {measured}",
            [
                budget.steps.map(|s| format!("steps={s}")),
                budget.rays.map(|r| format!("rays={r}")),
            ]
            .into_iter()
            .flatten()
            .collect::<Vec<_>>()
            .join(","),
            said(chosen)
        ),
        rejected: plan
            .candidates
            .iter()
            .rev()
            .find(|c| !c.meets)
            .map(|c| format!("{}: {}", layers(c.slices), said(c))),
    }
}

/// The centre window of at most [`WINDOW_SIDE`] posts a side,
/// `[x, y, width, height]`.
fn centre_window(width: u32, height: u32) -> [u32; 4] {
    let (w, h) = (width.min(WINDOW_SIDE), height.min(WINDOW_SIDE));
    [(width - w) / 2, (height - h) / 2, w, h]
}

/// Ingests `asset`'s heights in `window` into a new asset at `dir`,
/// through a headerless f32 file in `scratch`, with the same post spacing
/// and tiles.
fn write_window(
    asset: &Asset<Mmap>,
    window: [u32; 4],
    scratch: &std::path::Path,
    dir: &std::path::Path,
) -> Result<()> {
    let [x, y, w, h] = window;
    let heights = asset.height()?;
    let raw = scratch.join("window.f32");
    let mut out = std::io::BufWriter::new(std::fs::File::create(&raw)?);
    // A tile row at a time: the window is never held whole.
    let rows = heights.tile_size().min(h);
    let mut z = vec![0f32; w as usize * rows as usize];
    for y0 in (0..h).step_by(rows as usize) {
        let n = rows.min(h - y0);
        let part = &mut z[..w as usize * n as usize];
        heights.read_window(0, x, y + y0, w, n, part)?;
        for v in part.iter() {
            out.write_all(&v.to_le_bytes())?;
        }
    }
    out.flush()?;
    drop(out);
    let m = asset.manifest();
    let stage = IngestStage {
        src: raw,
        options: IngestOptions {
            tile_size: heights.tile_size(),
            cell_size: Some((m.cell_size.dx, m.cell_size.dy)),
            ..IngestOptions::for_raw(RawSpec {
                width: w,
                height: h,
                sample: RawSampleType::F32,
                order: ByteOrder::Le,
            })
        },
    };
    stage.create_asset(dir, Wait::NoWait, Progress::hidden())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_window_is_the_dem_or_its_centre() {
        assert_eq!(centre_window(1201, 900), [0, 0, 1201, 900]);
        assert_eq!(centre_window(5000, 2048), [452, 0, 4096, 2048]);
    }
}
