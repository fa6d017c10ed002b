//! The cone planes' speed against precomputation cost (`terrabake
//! terrabake-bench cones`): for each slice count (and the exact cones) and each
//! encoding, the bake time on all cores and the parametric tracer's mean
//! steps and rays per second on one thread over the sixteen views of the
//! tracing benchmark, with the hierarchical tracer (and its pyramid's bake
//! time) and the tracers that need nothing but the heights (incremental,
//! runs) beside them. This is the chart a user reads to choose `--slices`,
//! and, against bytes, to choose the tracing layers at all.
//! With `--scan`, what the sliced bake itself did instead ([`scan_stats`]).

use std::path::Path;

use anyhow::Result;
use serde::Serialize;
use terrabake_format::cones::ConeEncoding;
use terrabake_format::trace::Method;
use terrabake_format::Asset;

use super::chart::{log_log_svg, Series};
use super::markdown_table;
use super::views::{bench_views, BenchRow};
use terrabake::algorithms::planes::{neighbourhood_max, sliced_planes, PlaneStats, Slices};
use terrabake::plumbing::progress::Progress;
use terrabake::stage::run_stage;
use terrabake::stages::cones::{summarize_heights, ConesStage, SliceChoice};
use terrabake::stages::pyramid::PyramidStage;

/// One configuration's cost and benefit.
#[derive(Debug, Clone, Serialize)]
pub struct TradeoffRow {
    /// `K` slices, `exact`, the hierarchical reference (`pyramid`), or
    /// `none` (the heights alone).
    pub planes: String,
    pub encoding: String,
    /// Bake time of the layers the tracer needs beyond the heights, all
    /// cores.
    pub bake_seconds: f64,
    /// Bytes per cell of those layers.
    pub bytes_per_cell: f64,
    pub method: String,
    pub mean_steps: f64,
    pub mean_cells: f64,
    pub rays_per_second_per_thread: f64,
}

fn row(
    planes: String,
    encoding: &str,
    bake_seconds: f64,
    bytes_per_cell: f64,
    b: &BenchRow,
) -> TradeoffRow {
    TradeoffRow {
        planes,
        encoding: encoding.into(),
        bake_seconds,
        bytes_per_cell,
        method: b.method.clone(),
        mean_steps: b.mean_steps,
        mean_cells: b.mean_cells,
        rays_per_second_per_thread: b.rays_per_second_per_thread,
    }
}

/// Bakes every configuration into the asset at `dir` (replacing its cone
/// planes) and traces the views (`size x size`, every `every`-th pixel) on
/// one thread, in `rounds` rounds over all of them; each row keeps its
/// fastest bake and its fastest trace. This machine has slow spells of
/// seconds that a configuration's back-to-back passes all fall in; rounds
/// spread each configuration over the whole run. The first rows are the
/// tracers over the heights alone, then the hierarchical reference.
pub fn cone_tradeoff(
    dir: &Path,
    slices: &[SliceChoice],
    encodings: &[ConeEncoding],
    (size, every, rounds): (u32, u32, u32),
    progress: Progress,
) -> Result<Vec<TradeoffRow>> {
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let trace = |method: Method| -> Result<BenchRow> {
        let asset = Asset::open(dir)?;
        let rows = one_thread.install(|| bench_views(&asset, size, every, &[method], 1))?;
        Ok(rows.into_iter().next().expect("one method"))
    };
    let mut rows: Vec<TradeoffRow> = Vec::new();
    for round in 0..rounds.max(1) as usize {
        let mut measured = Vec::new();
        for method in [Method::Incremental, Method::Runs] {
            measured.push(row("none".into(), "-", 0.0, 0.0, &trace(method)?));
        }
        let pyramid = run_stage(dir, &PyramidStage, true, progress)?;
        // The pyramid's levels above 0 add a third: 4 bytes x 4/3 per cell (max only is traced).
        measured.push(row(
            "pyramid".into(),
            "f32",
            pyramid.seconds,
            4.0 * 4.0 / 3.0,
            &trace(Method::Hierarchical)?,
        ));
        for &encoding in encodings {
            for &choice in slices {
                let stage = ConesStage {
                    slices: choice,
                    encoding,
                    ..Default::default()
                };
                let outcome = run_stage(dir, &stage, true, progress)?;
                let bytes = 2.0 * encoding.elem().size() as f64;
                measured.push(row(
                    choice.to_string(),
                    encoding.name(),
                    outcome.seconds,
                    bytes,
                    &trace(Method::Parametric)?,
                ));
            }
        }
        if round == 0 {
            rows = measured;
            continue;
        }
        for (best, now) in rows.iter_mut().zip(measured) {
            best.bake_seconds = best.bake_seconds.min(now.bake_seconds);
            best.rays_per_second_per_thread = best
                .rays_per_second_per_thread
                .max(now.rays_per_second_per_thread);
        }
    }
    Ok(rows)
}

pub fn tradeoff_table_markdown(rows: &[TradeoffRow]) -> String {
    markdown_table(
        &[
            "tracer",
            "planes",
            "encoding",
            "bake (s)",
            "bytes / cell",
            "mean steps / ray",
            "mean cells tested / ray",
            "rays/s per thread",
        ],
        rows.iter().map(|r| {
            vec![
                r.method.clone(),
                r.planes.clone(),
                r.encoding.clone(),
                format!("{:.2}", r.bake_seconds),
                format!("{:.1}", r.bytes_per_cell),
                format!("{:.2}", r.mean_steps),
                format!("{:.2}", r.mean_cells),
                format!("{:.0}", r.rays_per_second_per_thread),
            ]
        }),
    )
}

/// Bytes a post of f32 heights: every tracer reads them.
const HEIGHT_BYTES: f64 = 4.0;

/// `PREFIX_steps.svg` and `PREFIX_speed.svg`: steps per ray and rays per
/// second against bake time, one line per encoding of the sliced planes,
/// the exact cones and the hierarchical reference as points;
/// `PREFIX_bytes.svg`: rays per second against the bytes a post the
/// tracer reads (the heights and its layers), every tracer, where the
/// slice counts stand in a column (their bytes are the same).
pub fn tradeoff_charts(prefix: &Path, rows: &[TradeoffRow]) -> Result<()> {
    // A line per kind of layers and encoding: the tracers over the heights
    // alone by name, the pyramid, the exact cones, and the sliced planes
    // (their points labelled with K).
    let kind = |r: &TradeoffRow| match r.planes.as_str() {
        "none" => r.method.clone(),
        "pyramid" | "exact" => r.planes.clone(),
        _ => "sliced".to_string(),
    };
    let series = |x: &dyn Fn(&TradeoffRow) -> f64, y: &dyn Fn(&TradeoffRow) -> f64| {
        let mut keys: Vec<(String, String)> = Vec::new();
        for r in rows.iter().filter(|r| x(r) > 0.0) {
            let key = (kind(r), r.encoding.clone());
            if !keys.contains(&key) {
                keys.push(key);
            }
        }
        keys.into_iter()
            .map(|(of_kind, encoding)| {
                let name = match of_kind.as_str() {
                    "pyramid" => "hierarchical (max pyramid)".to_string(),
                    "exact" => format!("parametric, exact cones, {encoding}"),
                    "sliced" => format!("parametric, K slices, {encoding}"),
                    method => format!("{method} (the heights alone)"),
                };
                let points = rows
                    .iter()
                    .filter(|r| r.encoding == encoding && kind(r) == of_kind)
                    .map(|r| {
                        let label = match of_kind.as_str() {
                            "sliced" => format!("K={}", r.planes),
                            _ => String::new(),
                        };
                        (x(r), y(r), label)
                    })
                    .collect();
                Series::through(name, points)
            })
            .collect::<Vec<_>>()
    };
    let path =
        |suffix: &str| std::path::PathBuf::from(format!("{}_{suffix}.svg", prefix.display()));
    let bake = |r: &TradeoffRow| r.bake_seconds;
    let read = |r: &TradeoffRow| HEIGHT_BYTES + r.bytes_per_cell;
    let steps = |r: &TradeoffRow| r.mean_steps;
    let speed = |r: &TradeoffRow| r.rays_per_second_per_thread;
    log_log_svg(
        &path("steps"),
        "Mean steps per ray against precomputation (K = 4 .. 1024 slices)",
        "bake time (s, 2 cores)",
        "steps per ray",
        &series(&bake, &steps),
    )?;
    log_log_svg(
        &path("speed"),
        "Rays per second (one thread) against precomputation",
        "bake time (s, 2 cores)",
        "rays per second",
        &series(&bake, &speed),
    )?;
    log_log_svg(
        &path("bytes"),
        "Rays per second (one thread) against bytes read, every tracer",
        "bytes a post: f32 heights and the tracer's layers",
        "rays per second",
        &series(&read, &speed),
    )
}

/// What one slice count's bake did (`terrabake-bench cones --scan`).
#[derive(Debug, Clone, Serialize)]
pub struct ScanRow {
    pub slices: usize,
    /// The planes alone, in memory, all cores (nothing encoded or written).
    pub seconds: f64,
    #[serde(flatten)]
    pub stats: PlaneStats,
}

/// For each slice count, the sliced planes of the whole DEM as one window
/// (the stage's in-core bake, its slices from the same heights), timed and
/// with their [`PlaneStats`]: transforms, slices skipped, how many of the
/// open-cell scans' blocks were read, and how many cells were open. `exact` has no slices and is
/// left out.
pub fn scan_stats(dir: &Path, slices: &[SliceChoice]) -> Result<Vec<ScanRow>> {
    let asset = terrabake::stage::asset::open(dir)?;
    let summary = summarize_heights(&asset)?;
    let height = asset.height()?;
    let (w, h) = (height.width() as usize, height.height() as usize);
    anyhow::ensure!(w >= 2 && h >= 2, "a {w} x {h} DEM has no cells");
    let mut posts = vec![0f32; w * h];
    height.read_rows_f32(0, 0, &mut posts)?;
    let nmax = neighbourhood_max(&posts, w, h);
    drop(posts);
    let cell = &asset.manifest().cell_size;
    let mut rows = Vec::new();
    for &choice in slices {
        let Some(k) = choice.resolve(&summary, None).slices else {
            continue;
        };
        let start = std::time::Instant::now();
        let planes = sliced_planes(
            &nmax,
            (w - 1, h - 1),
            (cell.dx, cell.dy),
            &Slices::uniform(summary.z_min, summary.z_max, k),
            None,
            &|| {},
        );
        rows.push(ScanRow {
            slices: k,
            seconds: start.elapsed().as_secs_f64(),
            stats: planes.stats,
        });
    }
    Ok(rows)
}

/// The `--scan` rows as a Markdown table.
pub fn scan_table_markdown(rows: &[ScanRow]) -> String {
    markdown_table(
        &[
            "slices",
            "planes (s)",
            "transforms",
            "slices skipped",
            "scan blocks",
            "read",
            "share read",
            "cells open, per cell and transform",
        ],
        rows.iter().map(|r| {
            let s = r.stats;
            vec![
                r.slices.to_string(),
                format!("{:.2}", r.seconds),
                s.transforms.to_string(),
                s.slices_skipped.to_string(),
                s.scan_blocks.to_string(),
                s.scan_blocks_read.to_string(),
                format!(
                    "{:.1} %",
                    100.0 * s.scan_blocks_read as f64 / s.scan_blocks.max(1) as f64
                ),
                format!(
                    "{:.1} %",
                    100.0 * s.cells_open as f64 / (s.scan_blocks.max(1) * 8) as f64
                ),
            ]
        }),
    )
}

/// `terrabake-bench cones`: its flags.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchConesArgs {
    /// The asset to measure (an ingested DEM).
    pub asset: std::path::PathBuf,
    /// Slice counts and/or exact, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "4,8,16,32,64,128,256,512,1024,exact"
    )]
    pub slices: Vec<SliceChoice>,
    /// Encodings, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "f32")]
    pub encodings: Vec<ConeEncoding>,
    /// Image side in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Trace every N-th pixel.
    #[arg(long, default_value_t = 4)]
    pub every: u32,
    /// Rounds over every configuration, each baked and traced once a
    /// round; the fastest round of each is reported (single passes here
    /// spread by a fifth, in spells of seconds).
    #[arg(long, default_value_t = 3)]
    pub rounds: u32,
    /// Write PREFIX_steps.svg, PREFIX_speed.svg and PREFIX_bytes.svg.
    #[arg(long)]
    pub chart: Option<std::path::PathBuf>,
    /// Print the rows as JSON.
    #[arg(long)]
    pub json: bool,
    /// Instead of the trade-off: bake each slice count's planes in memory
    /// (the whole DEM as one window, nothing written, no tracing) and print
    /// what the bake did: distance transforms, slices skipped, and the
    /// open-cell scans' blocks of eight cells and how many were read.
    #[arg(long)]
    pub scan: bool,
}

impl BenchConesArgs {
    /// Runs the trade-off and prints its table (or JSON); `say` reports files.
    pub fn run(&self, progress: Progress, say: &dyn Fn(String)) -> Result<()> {
        if self.scan {
            let rows = scan_stats(&self.asset, &self.slices)?;
            if self.json {
                println!("{}", serde_json::to_string_pretty(&rows)?);
            } else {
                print!("{}", scan_table_markdown(&rows));
            }
            return Ok(());
        }
        terrabake::stage::asset::open(&self.asset)?;
        let rows = cone_tradeoff(
            &self.asset,
            &self.slices,
            &self.encodings,
            (self.size, self.every, self.rounds),
            progress,
        )?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&rows)?);
        } else {
            print!("{}", tradeoff_table_markdown(&rows));
        }
        if let Some(prefix) = &self.chart {
            tradeoff_charts(prefix, &rows)?;
            say(format!(
                "wrote {0}_steps.svg, {0}_speed.svg and {0}_bytes.svg",
                prefix.display()
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tracers over the heights alone stand on the bytes chart only:
    /// they bake nothing, which a bake-time axis (log) cannot show.
    #[test]
    fn every_tracer_is_on_the_bytes_chart_and_the_baked_ones_on_the_others() {
        let bench = |method: &str, rays: f64| BenchRow {
            method: method.into(),
            mean_steps: 1e6 / rays,
            rays_per_second_per_thread: rays,
            ..Default::default()
        };
        let rows = vec![
            row("none".into(), "-", 0.0, 0.0, &bench("incremental", 2e5)),
            row("none".into(), "-", 0.0, 0.0, &bench("runs", 4e5)),
            row(
                "pyramid".into(),
                "f32",
                0.04,
                5.3,
                &bench("hierarchical", 1e6),
            ),
            row("16".into(), "u16", 0.2, 4.0, &bench("parametric", 2e6)),
            row("64".into(), "u16", 0.3, 4.0, &bench("parametric", 2.2e6)),
        ];
        let dir = tempfile::tempdir().unwrap();
        let prefix = dir.path().join("cones");
        tradeoff_charts(&prefix, &rows).unwrap();
        let svg = |suffix: &str| {
            std::fs::read_to_string(dir.path().join(format!("cones_{suffix}.svg"))).unwrap()
        };
        let bytes = svg("bytes");
        for name in ["incremental", "runs", "hierarchical", "K=16", "K=64"] {
            assert!(bytes.contains(name), "{name} on the bytes chart");
        }
        for suffix in ["steps", "speed"] {
            let chart = svg(suffix);
            assert!(chart.contains("hierarchical") && chart.contains("K=64"));
            assert!(!chart.contains("incremental") && !chart.contains("runs"));
        }
    }
}
