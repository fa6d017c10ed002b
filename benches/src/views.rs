//! The tracing benchmark (`terrabake-bench views`): Paglieroni and
//! Petersen's Table 1 (every method over the sixteen built-in oblique views,
//! primary rays only), the cost per ray by azimuth, and the scaling charts.

use serde::Serialize;
use terrabake_format::trace::{Method, Ray, Tracer};
use terrabake_format::{Asset, Mmap};

use super::chart::{log_log_svg, Series};
use super::markdown_table;
use terrabake::views::views_cost;

/// One method's totals over the sixteen views.
#[derive(Debug, Clone, Default, Serialize)]
pub struct BenchRow {
    pub method: String,
    pub rays: u64,
    pub hits: u64,
    pub seconds: f64,
    pub threads: usize,
    pub mean_steps: f64,
    pub mean_cells: f64,
    pub mean_nodes_pushed: f64,
    pub rays_per_second_per_thread: f64,
}

/// Paglieroni and Petersen's Table 1 on `asset`: every method over the
/// sixteen built-in views (`size x size`, every `every`-th pixel, primary
/// rays only, as in the paper), in one run; `repeat` timed passes, the
/// methods taking turns within each, and the median pass reported.
pub fn bench_views(
    asset: &Asset<Mmap>,
    size: u32,
    every: u32,
    methods: &[Method],
    repeat: u32,
) -> anyhow::Result<Vec<BenchRow>> {
    let tracer = Tracer::new(asset)?;
    // Warm the page cache, the process's page tables and the tiles'
    // first-read checksums along the very rays timed below, with every
    // method (each reads its own layers: heights, pyramid, cone planes), so
    // that no method timed pays for a first touch. Warming along a sparser
    // set of rays is not enough: a parametric leap lands on a page no
    // sparser ray touched, and each such page costs a minor fault (about a
    // microsecond) that the timed run then charged to the tracer.
    for &method in methods {
        views_cost(asset, &tracer, method, (size, every))?;
    }
    median_passes(
        methods,
        repeat,
        |a: &BenchRow| a.seconds,
        |method| {
            let cost = views_cost(asset, &tracer, method, (size, every))?;
            let threads = rayon::current_num_threads();
            Ok(BenchRow {
                method: method.name().into(),
                rays: cost.rays,
                hits: cost.hits,
                seconds: cost.seconds,
                threads,
                mean_steps: cost.mean_steps,
                mean_cells: cost.mean_cells,
                mean_nodes_pushed: cost.mean_nodes_pushed,
                rays_per_second_per_thread: cost.rays as f64
                    / cost.seconds.max(1e-9)
                    / threads as f64,
            })
        },
    )
}

/// Per method, the median by `seconds` of `repeat` timed passes (at least
/// one). The methods take turns within each pass, so that a slow spell of
/// the machine falls on every method alike.
fn median_passes<T>(
    methods: &[Method],
    repeat: u32,
    seconds: impl Fn(&T) -> f64,
    mut pass: impl FnMut(Method) -> anyhow::Result<T>,
) -> anyhow::Result<Vec<T>> {
    let mut passes: Vec<Vec<T>> = methods.iter().map(|_| Vec::new()).collect();
    for _ in 0..repeat.max(1) {
        for (&method, passes) in methods.iter().zip(&mut passes) {
            passes.push(pass(method)?);
        }
    }
    Ok(passes
        .into_iter()
        .map(|mut p| {
            p.sort_by(|a, b| seconds(a).total_cmp(&seconds(b)));
            p.swap_remove(p.len() / 2)
        })
        .collect())
}

/// The benchmark as a Markdown table, with time ratios against the first row.
pub fn bench_table_markdown(rows: &[BenchRow]) -> String {
    let base = rows.first().map_or(1.0, |r| r.seconds);
    markdown_table(
        &[
            "method",
            "rays",
            "hits",
            "mean steps / ray",
            "mean cells tested / ray",
            "time (s)",
            "rays/s per thread",
            "time vs first",
        ],
        rows.iter().map(|r| {
            vec![
                r.method.clone(),
                r.rays.to_string(),
                r.hits.to_string(),
                format!("{:.2}", r.mean_steps),
                format!("{:.2}", r.mean_cells),
                format!("{:.3}", r.seconds),
                format!("{:.0}", r.rays_per_second_per_thread),
                format!("{:.2}x", base / r.seconds.max(1e-9)),
            ]
        }),
    )
}

/// Per-azimuth cost of the tracers: shallow rays (2 degrees down) from a
/// grid of points over the DEM, all in one direction; for checking that
/// runs are never slower than incremental, whatever the direction.
#[derive(Debug, Clone, Serialize)]
pub struct DirectionRow {
    pub azimuth: f64,
    /// The mean run length of the ground track, `major / minor` (cells per
    /// row crossed), as Henning and Stephenson tabulate their speed-ups.
    pub run_length: f64,
    pub rays: usize,
    /// Per method: (name, mean steps per ray, microseconds per ray).
    pub methods: Vec<(String, f64, f64)>,
}

/// Azimuths (degrees clockwise from north) whose ground tracks have mean
/// run length `l` cells along the east-west axis: `tan(azimuth) = l`.
pub fn run_length_azimuths(lengths: &[f64]) -> Vec<f64> {
    lengths.iter().map(|&l| l.atan().to_degrees()).collect()
}

/// `n` azimuths evenly around the circle, from north.
pub fn even_azimuths(n: u32) -> Vec<f64> {
    (0..n)
        .map(|k| 360.0 * f64::from(k) / f64::from(n))
        .collect()
}

pub fn bench_directions(
    asset: &Asset<Mmap>,
    azimuths: &[f64],
    methods: &[Method],
    repeat: u32,
) -> anyhow::Result<Vec<DirectionRow>> {
    let tracer = Tracer::new(asset)?;
    let (xm, ym) = tracer.extent();
    let r = asset
        .manifest()
        .height_range
        .map_or((0.0, 1.0), |r| (f64::from(r.min), f64::from(r.max)));
    let z = r.1 + 0.05 * (r.1 - r.0).max(1.0);
    let mut rows = Vec::new();
    for &az in azimuths {
        let (s, c) = (az.to_radians().sin(), az.to_radians().cos());
        let dir = [
            s * 2f64.to_radians().cos(),
            c * 2f64.to_radians().cos(),
            -(2f64.to_radians().sin()),
        ];
        const N: u32 = 60;
        let rays: Vec<Ray> = (0..N)
            .flat_map(|i| {
                (0..N).map(move |j| {
                    [
                        xm * (f64::from(i) + 0.5) / f64::from(N),
                        ym * (f64::from(j) + 0.5) / f64::from(N),
                        z,
                    ]
                })
            })
            .map(|origin| Ray {
                origin,
                dir,
                t_min: 0.0,
                t_max: f64::INFINITY,
            })
            .collect();
        let mut row = DirectionRow {
            azimuth: az,
            run_length: s.abs().max(c.abs()) / s.abs().min(c.abs()),
            rays: rays.len(),
            methods: Vec::new(),
        };
        // Per method: (mean steps, microseconds) per ray, its median pass.
        let medians = median_passes(
            methods,
            repeat,
            |&(_, us): &(f64, f64)| us,
            |method| {
                let start = std::time::Instant::now();
                let mut steps = 0u64;
                for ray in &rays {
                    steps += tracer.trace(ray, method)?.1.steps;
                }
                let us = start.elapsed().as_secs_f64() * 1e6 / rays.len() as f64;
                Ok((steps as f64 / rays.len() as f64, us))
            },
        )?;
        for (&m, (steps, us)) in methods.iter().zip(medians) {
            row.methods.push((m.name().into(), steps, us));
        }
        rows.push(row);
    }
    Ok(rows)
}

/// The per-azimuth benchmark as a Markdown table.
pub fn directions_table_markdown(rows: &[DirectionRow]) -> String {
    let Some(first) = rows.first() else {
        return String::new();
    };
    let header: Vec<String> = ["azimuth".to_string(), "run length".to_string()]
        .into_iter()
        .chain(
            first
                .methods
                .iter()
                .flat_map(|(name, ..)| [format!("{name} steps"), format!("{name} us/ray")]),
        )
        .collect();
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    markdown_table(
        &header,
        rows.iter().map(|r| {
            [format!("{:.2}", r.azimuth), format!("{:.1}", r.run_length)]
                .into_iter()
                .chain(
                    r.methods
                        .iter()
                        .flat_map(|(_, steps, us)| [format!("{steps:.1}"), format!("{us:.2}")]),
                )
                .collect()
        }),
    )
}

/// Charts of a scaling series (DEM side, per-method rows): mean steps per
/// ray and microseconds per ray per thread, log-log, written to
/// `PREFIX_steps.svg` and `PREFIX_time.svg`.
pub fn scaling_charts(
    prefix: &std::path::Path,
    results: &[(f64, Vec<BenchRow>)],
) -> anyhow::Result<()> {
    let methods: Vec<String> = results
        .first()
        .map(|r| r.1.iter().map(|m| m.method.clone()).collect())
        .unwrap_or_default();
    let series = |value: &dyn Fn(&BenchRow) -> f64| -> Vec<Series> {
        methods
            .iter()
            .map(|name| {
                let points = results.iter().filter_map(|(side, rows)| {
                    rows.iter()
                        .find(|r| &r.method == name)
                        .map(|r| (*side, value(r)))
                });
                Series::new(name.clone(), points.collect())
            })
            .collect()
    };
    let path =
        |suffix: &str| std::path::PathBuf::from(format!("{}_{suffix}.svg", prefix.display()));
    log_log_svg(
        &path("steps"),
        "Mean traversal steps per ray, 16 oblique views",
        "DEM side (posts)",
        "steps per ray",
        &series(&|r| r.mean_steps),
    )?;
    log_log_svg(
        &path("time"),
        "Time per ray, one thread, 16 oblique views",
        "DEM side (posts)",
        "microseconds per ray",
        &series(&|r| 1e6 / r.rays_per_second_per_thread),
    )?;
    Ok(())
}

/// `terrabake-bench views`: its flags.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchViewsArgs {
    /// One asset, or several (a scaling series, e.g. for --chart).
    #[arg(required = true)]
    pub assets: Vec<std::path::PathBuf>,
    /// With several assets: write PREFIX_steps.svg and PREFIX_time.svg, per method against DEM side.
    #[arg(long)]
    pub chart: Option<std::path::PathBuf>,
    /// Image side in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Trace every N-th pixel (16 as in the paper, 1 for every pixel).
    #[arg(long, default_value_t = 16)]
    pub every: u32,
    /// Methods, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "incremental,runs,hierarchical"
    )]
    pub methods: Vec<Method>,
    /// Instead of the views: cost per ray in N azimuths (shallow rays from a grid of origins).
    #[arg(long, conflicts_with = "run_lengths")]
    pub directions: Option<u32>,
    /// Instead of the views: cost per ray along ground tracks of these mean
    /// run lengths (cells per row crossed; 1 is the diagonal), as Henning
    /// and Stephenson report their speed-ups, e.g. `--run-lengths 2,3,5,25`.
    #[arg(long, value_delimiter = ',')]
    pub run_lengths: Vec<f64>,
    /// Timed passes over the views (or the directions), the methods taking turns; each row
    /// reports its median pass (one pass of 16,384 rays takes hundredths
    /// of a second, within a busy machine's noise).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub repeat: u32,
    /// Print the rows as JSON.
    #[arg(long)]
    pub json: bool,
}

impl BenchViewsArgs {
    /// Runs the views (or the azimuths) on every asset and prints the
    /// tables (or JSON); `say` reports files.
    pub fn run(&self, say: &dyn Fn(String)) -> anyhow::Result<()> {
        let mut results = Vec::new();
        for asset in &self.assets {
            let opened = terrabake::stage::asset::open(asset)?;
            let azimuths = match self.directions {
                Some(n) => even_azimuths(n),
                None => run_length_azimuths(&self.run_lengths),
            };
            if !azimuths.is_empty() {
                let rows = bench_directions(&opened, &azimuths, &self.methods, self.repeat)?;
                if self.json {
                    println!("{}", serde_json::to_string_pretty(&rows)?);
                } else {
                    print!("{}", directions_table_markdown(&rows));
                }
                continue;
            }
            let side = opened.manifest().width.max(opened.manifest().height);
            let table = bench_views(&opened, self.size, self.every, &self.methods, self.repeat)?;
            if self.json {
                let record = serde_json::json!({ "asset": asset.display().to_string(), "side": side, "methods": table });
                println!("{}", serde_json::to_string_pretty(&record)?);
            } else {
                if self.assets.len() > 1 {
                    println!("\n{} ({side} posts a side)\n", asset.display());
                }
                print!("{}", bench_table_markdown(&table));
            }
            results.push((f64::from(side), table));
        }
        if let (Some(prefix), true) = (
            &self.chart,
            self.directions.is_none() && self.run_lengths.is_empty(),
        ) {
            scaling_charts(prefix, &results)?;
            say(format!(
                "wrote {0}_steps.svg and {0}_time.svg",
                prefix.display()
            ));
        }
        Ok(())
    }
}
