//! The cone planes' speed against precomputation cost (`terrabake
//! terrabake-bench cones`): for each slice count (and the exact cones) and each
//! encoding, the bake time on all cores and the parametric tracer's mean
//! steps and rays per second on one thread over the sixteen views of the
//! tracing benchmark, with the hierarchical tracer (and its pyramid's bake
//! time) beside them. This is the chart a user reads to choose `--slices`.
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
    /// `K` slices, `exact`, or the hierarchical reference (`pyramid`).
    pub planes: String,
    pub encoding: String,
    /// Bake time of the layers the tracer needs, all cores.
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
/// one thread. The first row is the hierarchical reference.
pub fn cone_tradeoff(
    dir: &Path,
    slices: &[SliceChoice],
    encodings: &[ConeEncoding],
    size: u32,
    every: u32,
    progress: Progress,
) -> Result<Vec<TradeoffRow>> {
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let trace = |method: Method| -> Result<BenchRow> {
        let asset = Asset::open(dir)?;
        let rows = one_thread.install(|| bench_views(&asset, size, every, &[method], 1))?;
        Ok(rows.into_iter().next().expect("one method"))
    };
    let pyramid = run_stage(dir, &PyramidStage, true, progress)?;
    // The pyramid's levels above 0 add a third: 4 bytes x 4/3 per cell (max only is traced).
    let mut rows = vec![row(
        "pyramid".into(),
        "f32",
        pyramid.seconds,
        4.0 * 4.0 / 3.0,
        &trace(Method::Hierarchical)?,
    )];
    for &encoding in encodings {
        for &choice in slices {
            let stage = ConesStage {
                slices: choice,
                encoding,
                ..Default::default()
            };
            let outcome = run_stage(dir, &stage, true, progress)?;
            let planes = choice.to_string();
            let bytes = 2.0 * encoding.elem().size() as f64;
            rows.push(row(
                planes,
                encoding.name(),
                outcome.seconds,
                bytes,
                &trace(Method::Parametric)?,
            ));
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

/// `PREFIX_steps.svg` and `PREFIX_speed.svg`: steps per ray and rays per
/// second against bake time, one line per encoding of the sliced planes,
/// the exact cones and the hierarchical reference as points.
pub fn tradeoff_charts(prefix: &Path, rows: &[TradeoffRow]) -> Result<()> {
    let series = |value: &dyn Fn(&TradeoffRow) -> f64| -> Vec<Series> {
        let mut out = Vec::new();
        let mut keys: Vec<(String, String)> = Vec::new();
        for r in rows {
            let kind = match r.planes.as_str() {
                "pyramid" | "exact" => r.planes.clone(),
                _ => "sliced".into(),
            };
            if !keys.contains(&(kind.clone(), r.encoding.clone())) {
                keys.push((kind, r.encoding.clone()));
            }
        }
        for (kind, encoding) in keys {
            let name = match kind.as_str() {
                "pyramid" => "hierarchical (max pyramid)".to_string(),
                "exact" => format!("parametric, exact cones, {encoding}"),
                _ => format!("parametric, K slices, {encoding}"),
            };
            let mut of: Vec<&TradeoffRow> = rows
                .iter()
                .filter(|r| {
                    r.encoding == encoding
                        && match kind.as_str() {
                            "pyramid" | "exact" => r.planes == kind,
                            _ => r.planes.parse::<usize>().is_ok(),
                        }
                })
                .collect();
            // In order of cost: a line that reads left to right.
            of.sort_by(|p, q| p.bake_seconds.total_cmp(&q.bake_seconds));
            let points = of.iter().map(|r| (r.bake_seconds, value(r))).collect();
            let series = Series::new(name, points);
            out.push(if kind == "sliced" {
                series.labelled(of.iter().map(|r| format!("K={}", r.planes)).collect())
            } else {
                series
            });
        }
        out
    };
    let path =
        |suffix: &str| std::path::PathBuf::from(format!("{}_{suffix}.svg", prefix.display()));
    log_log_svg(
        &path("steps"),
        "Mean steps per ray against precomputation (K = 4 .. 1024 slices)",
        "bake time (s, 2 cores)",
        "steps per ray",
        &series(&|r| r.mean_steps),
    )?;
    log_log_svg(
        &path("speed"),
        "Rays per second (one thread) against precomputation",
        "bake time (s, 2 cores)",
        "rays per second",
        &series(&|r| r.rays_per_second_per_thread),
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
    /// Write PREFIX_steps.svg and PREFIX_speed.svg.
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
            self.size,
            self.every,
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
                "wrote {0}_steps.svg and {0}_speed.svg",
                prefix.display()
            ));
        }
        Ok(())
    }
}
