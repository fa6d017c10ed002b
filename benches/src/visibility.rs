//! Timonen's (2013) tables on our terrains (`terrabake-bench visibility`):
//! visible points per direction (Table 1), horizons and iterations per
//! point (Table 2), sweep times against the naive method (Table 3), the
//! scaling of iterations with line length (Fig. 8), and the total
//! viewshed's error against the number of directions (sec. 10.2).
//!
//! Terrains: the assets given (a centred crop, so that the naive method's
//! `O(n)` per post stays affordable) and synthetic terrains of the same
//! size standing in for the paper's four (fractal terrain, brick surface,
//! sine grid, blocks). Times are wall seconds on all cores, per direction.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use serde::Serialize;

use super::chart::{log_log_svg, Series};
use super::markdown_table;
use terrabake::algorithms::viewshed::observer::{observer_viewshed, Observer};
use terrabake::algorithms::viewshed::total::{total_viewshed, Method, TotalOptions, TotalStats};
use terrabake::io::synth::{fill_rows, SynthKind};
use terrabake::terrain::held::HeldDem;
use terrabake::terrain::Terrain;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example (docs/BENCHMARKS.md):\n  terrabake-bench visibility \
out/srtm.tbake --crop 512 --directions 32 --chart docs/charts/visibility"
)]
pub struct BenchVisibilityArgs {
    /// Assets whose heights to measure (a centred crop of each).
    pub assets: Vec<PathBuf>,
    /// Side of the centred crop, and of the synthetic terrains, posts.
    #[arg(long, default_value_t = 512)]
    pub crop: usize,
    /// Directions K of Tables 1-3.
    #[arg(long, default_value_t = 32)]
    pub directions: usize,
    /// The eye above each post, metres (Timonen's eye is on the surface: 0).
    #[arg(long, default_value_t = 0.0)]
    pub observer_height: f64,
    /// Also time the total viewshed of each whole asset within this many metres (naive, hull
    /// tree, hull tree with the safe zone).
    #[arg(long, value_parser = terrabake::stage::args::parse_positive)]
    pub bounded: Option<f64>,
    /// Line lengths (DEM sides) of the scaling study (Fig. 8), comma-separated; none given: skip.
    #[arg(long, value_delimiter = ',', num_args = 0.., default_value = "128,256,512,1024,2048")]
    pub scaling: Vec<usize>,
    /// Direction counts of the error study, against 1024 directions; none given: skip.
    #[arg(long, value_delimiter = ',', num_args = 0.., default_value = "4,8,16,32,64,128,256")]
    pub errors: Vec<usize>,
    /// Write PREFIX_scaling.svg and PREFIX_directions.svg.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Print the results as JSON.
    #[arg(long)]
    pub json: bool,
}

/// One terrain's Tables 1-3 row.
#[derive(Debug, Clone, Serialize)]
pub struct TableRow {
    pub terrain: String,
    pub posts: usize,
    pub directions: usize,
    /// Profile vertices behind a post in one direction (what the naive
    /// method walks).
    pub behind: f64,
    /// Table 1: visible vertices per post and direction.
    pub visible: f64,
    /// Table 2: local horizons `m_a` and iterations `t_a` of Algorithm 1
    /// per post and direction, and the eye's tests.
    pub horizons: f64,
    pub iterations: f64,
    /// The root's children per pushed vertex, and iterations per pushed
    /// vertex: Timonen's bound is `t <= 2 m + 1` per vertex.
    pub root_children_per_vertex: f64,
    pub iterations_per_vertex: f64,
    pub eye_tests: f64,
    /// Share of pushes that replaced the root through the safe zone.
    pub replaced: f64,
    /// Table 3: seconds per direction (all cores).
    pub naive_s: f64,
    pub hull_tree_s: f64,
    pub safe_zone_s: f64,
}

/// Mean iterations per line of `n` posts (Fig. 8).
#[derive(Debug, Clone, Serialize)]
pub struct ScalingRow {
    pub terrain: String,
    pub n: usize,
    pub iterations_per_line: f64,
    pub naive_per_line: f64,
}

/// Relative error of the total viewshed with `directions` against 1024.
#[derive(Debug, Clone, Serialize)]
pub struct ErrorRow {
    pub terrain: String,
    pub directions: usize,
    pub mean_relative_error: f64,
    pub seconds: f64,
}

/// The bounded total viewshed of a whole asset, three ways.
#[derive(Debug, Clone, Serialize)]
pub struct BoundedRow {
    pub terrain: String,
    pub posts: usize,
    pub max_distance: f64,
    pub directions: usize,
    pub naive_s: f64,
    pub hull_tree_s: f64,
    pub safe_zone_s: f64,
    /// Largest relative difference of the tree's areas from the naive's.
    pub max_relative_difference: f64,
}

/// Everything the command measures.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub tables: Vec<TableRow>,
    pub scaling: Vec<ScalingRow>,
    /// The fitted exponent k of `t = O(n^k)` per terrain (n >= 512).
    pub exponents: Vec<(String, f64)>,
    pub errors: Vec<ErrorRow>,
    /// Mean relative difference between the continuous visible area and
    /// the count of visible posts times a post's area (sampling, not K).
    pub sampling: Vec<(String, f64)>,
    pub bounded: Vec<BoundedRow>,
}

/// A synthetic terrain in memory (10 m posts).
fn synthetic(kind: SynthKind, side: usize) -> HeldDem {
    let mut z = vec![0f32; side * side];
    fill_rows(kind, 0, &mut z, side as u32, side as u32, 1);
    HeldDem::in_memory(z, (side, side), (10.0, 10.0), Vec::new())
}

/// The centred `side x side` crop of `dem`.
fn crop(dem: &HeldDem, side: usize) -> HeldDem {
    let (w, h) = (side.min(dem.width), side.min(dem.height));
    let (c0, r0) = ((dem.width - w) / 2, (dem.height - h) / 2);
    let z = (r0..r0 + h)
        .flat_map(|r| {
            dem.z()[r * dem.width + c0..r * dem.width + c0 + w]
                .iter()
                .copied()
        })
        .collect();
    let row_scale = if dem.row_scale.is_empty() {
        Vec::new()
    } else {
        dem.row_scale[2 * r0..2 * (r0 + h) - 1].to_vec()
    };
    HeldDem::in_memory(z, (w, h), (dem.dx, dem.dy), row_scale)
}

fn timed(terrain: &Terrain, opts: &TotalOptions) -> (Vec<f64>, TotalStats, f64) {
    let start = Instant::now();
    let (area, stats) = total_viewshed(terrain, opts, &|| ());
    (area, stats, start.elapsed().as_secs_f64())
}

fn max_relative_difference(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .filter(|(x, _)| !x.is_nan())
        .map(|(x, y)| (x - y).abs() / x.abs().max(1.0))
        .fold(0.0, f64::max)
}

/// The slope of a least-squares line through `(ln x, ln y)`.
fn log_slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let (lx, ly): (Vec<f64>, Vec<f64>) = points.iter().map(|p| (p.0.ln(), p.1.ln())).unzip();
    let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
    let cov: f64 = lx.iter().zip(&ly).map(|(x, y)| (x - mx) * (y - my)).sum();
    let var: f64 = lx.iter().map(|x| (x - mx) * (x - mx)).sum();
    cov / var
}

impl BenchVisibilityArgs {
    fn options(&self, directions: usize, method: Method) -> TotalOptions {
        TotalOptions {
            height: self.observer_height,
            max_distance: None,
            directions,
            method,
        }
    }

    fn table_row(&self, name: &str, terrain: &Terrain) -> TableRow {
        let k = self.directions;
        let (naive, ns, naive_s) = timed(terrain, &self.options(k, Method::Naive));
        let (_, ts, tree_s) = timed(
            terrain,
            &self.options(k, Method::HullTree { safe_zone: false }),
        );
        let (zoned, zs, zone_s) = timed(
            terrain,
            &self.options(k, Method::HullTree { safe_zone: true }),
        );
        // The benchmark is only worth its numbers if the methods agree.
        let gap = max_relative_difference(&naive, &zoned);
        assert!(
            gap < 1e-9,
            "{name}: the hull tree's areas differ from the naive method's by {gap}"
        );
        let r = ns.receivers as f64;
        TableRow {
            terrain: name.into(),
            posts: terrain.z.len(),
            directions: k,
            behind: ns.naive_steps as f64 / r,
            visible: ns.visible_vertices as f64 / r,
            horizons: ts.horizons as f64 / r,
            iterations: ts.iterations as f64 / r,
            root_children_per_vertex: ts.root_children as f64 / ts.vertices as f64,
            iterations_per_vertex: ts.iterations as f64 / ts.vertices as f64,
            eye_tests: ts.eye_tests as f64 / r,
            replaced: zs.replacements as f64 / zs.vertices.max(1) as f64,
            naive_s: naive_s / k as f64,
            hull_tree_s: tree_s / k as f64,
            safe_zone_s: zone_s / k as f64,
        }
    }

    pub fn run(&self, say: &dyn Fn(String)) -> Result<()> {
        let mut assets = Vec::new();
        for path in &self.assets {
            let asset = terrabake::stage::asset::open(path)?;
            let name = path
                .file_stem()
                .map_or("asset".into(), |s| s.to_string_lossy().into_owned());
            assets.push((name, HeldDem::read(&asset)?));
        }
        let kinds = [
            (SynthKind::Fractal, "fractal"),
            (SynthKind::Blocks, "blocks"),
            (SynthKind::Sine, "sine"),
            (SynthKind::Noise, "noise"),
        ];
        let mut terrains: Vec<(String, HeldDem)> = assets
            .iter()
            .map(|(n, d)| (format!("{n} (crop {})", self.crop), crop(d, self.crop)))
            .collect();
        terrains.extend(
            kinds
                .iter()
                .map(|&(k, n)| (n.to_string(), synthetic(k, self.crop))),
        );
        let mut report = Report {
            tables: Vec::new(),
            scaling: Vec::new(),
            exponents: Vec::new(),
            errors: Vec::new(),
            sampling: Vec::new(),
            bounded: Vec::new(),
        };
        for (name, dem) in &terrains {
            say(format!("tables: {name}"));
            report.tables.push(self.table_row(name, &dem.terrain(0.0)));
        }
        // Fig. 8: one direction (east), so every line has n posts.
        for &(kind, name) in kinds
            .iter()
            .filter(|k| matches!(k.0, SynthKind::Fractal | SynthKind::Noise))
        {
            let mut points = Vec::new();
            for &n in &self.scaling {
                say(format!("scaling: {name} {n}"));
                let dem = synthetic(kind, n);
                let t = dem.terrain(0.0);
                // Four directions: E, S, W, N (axis lines of n posts each).
                let lines = (4 * n) as f64;
                let (_, ts, _) = timed(&t, &self.options(4, Method::HullTree { safe_zone: false }));
                let (_, ns, _) = if n <= 1024 {
                    timed(&t, &self.options(4, Method::Naive))
                } else {
                    (Vec::new(), TotalStats::default(), 0.0)
                };
                let row = ScalingRow {
                    terrain: name.into(),
                    n,
                    iterations_per_line: ts.iterations as f64 / lines,
                    naive_per_line: ns.naive_steps as f64 / lines,
                };
                points.push((n as f64, row.iterations_per_line));
                report.scaling.push(row);
            }
            let fit: Vec<(f64, f64)> = points.iter().copied().filter(|p| p.0 >= 512.0).collect();
            if fit.len() >= 2 {
                report.exponents.push((name.into(), log_slope(&fit)));
            }
        }
        // Sec. 10.2: error against K, the reference 1024 directions.
        if !self.errors.is_empty() {
            for (name, dem) in terrains
                .iter()
                .take(assets.len().max(1))
                .chain(terrains.iter().skip(assets.len()).take(1))
            {
                let small = crop(dem, 128);
                let t = small.terrain(0.0);
                let opts = |k| TotalOptions {
                    height: 1.7,
                    max_distance: None,
                    directions: k,
                    method: Method::HullTree { safe_zone: true },
                };
                say(format!("errors: {name}"));
                let (reference, _, _) = timed(&t, &opts(1024));
                for &k in &self.errors {
                    let (area, _, seconds) = timed(&t, &opts(k));
                    let (mut sum, mut n) = (0.0, 0.0);
                    for (a, r) in area.iter().zip(&reference).filter(|(a, _)| !a.is_nan()) {
                        sum += (a - r).abs() / r.max(1.0);
                        n += 1.0;
                    }
                    report.errors.push(ErrorRow {
                        terrain: name.clone(),
                        directions: k,
                        mean_relative_error: sum / n,
                        seconds,
                    });
                }
                // Sampling: the continuous area against visible posts.
                let (mut sum, mut n) = (0.0, 0.0);
                for i in (0..small.width * small.height).step_by(331) {
                    let (col, row) = (i % small.width, i / small.width);
                    if small.z()[i].is_nan() {
                        continue;
                    }
                    let v = observer_viewshed(
                        &t,
                        &Observer {
                            col,
                            row,
                            height: 1.7,
                            target_height: 0.0,
                            max_distance: None,
                        },
                    );
                    let seen = v.visible.iter().filter(|&&s| s == 1).count() as f64 * t.dx * t.dy;
                    sum += (reference[i] - seen).abs() / seen.max(1.0);
                    n += 1.0;
                }
                report.sampling.push((name.clone(), sum / n));
            }
        }
        if let Some(d) = self.bounded {
            for (name, dem) in &assets {
                say(format!("bounded: {name} within {d} m"));
                let t = dem.terrain(terrabake::terrain::curvature_coefficient(
                    terrabake::terrain::DEFAULT_REFRACTION,
                ));
                let opts = |method| TotalOptions {
                    height: 1.7,
                    max_distance: Some(d),
                    directions: self.directions,
                    method,
                };
                let (naive, _, naive_s) = timed(&t, &opts(Method::Naive));
                let (_, _, tree_s) = timed(&t, &opts(Method::HullTree { safe_zone: false }));
                let (zoned, _, zone_s) = timed(&t, &opts(Method::HullTree { safe_zone: true }));
                report.bounded.push(BoundedRow {
                    terrain: name.clone(),
                    posts: t.z.len(),
                    max_distance: d,
                    directions: self.directions,
                    naive_s,
                    hull_tree_s: tree_s,
                    safe_zone_s: zone_s,
                    max_relative_difference: max_relative_difference(&naive, &zoned),
                });
            }
        }
        if let Some(prefix) = &self.chart {
            self.charts(prefix, &report, say)?;
        }
        if self.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print!("{}", tables(&report));
        }
        Ok(())
    }

    fn charts(
        &self,
        prefix: &std::path::Path,
        report: &Report,
        say: &dyn Fn(String),
    ) -> Result<()> {
        let with = |suffix: &str| {
            let mut p = prefix.as_os_str().to_owned();
            p.push(suffix);
            PathBuf::from(p)
        };
        let mut series = Vec::new();
        for name in ["fractal", "noise"] {
            let rows: Vec<&ScalingRow> = report
                .scaling
                .iter()
                .filter(|r| r.terrain == name)
                .collect();
            series.push(Series::new(
                format!("{name}: hull tree"),
                rows.iter()
                    .map(|r| (r.n as f64, r.iterations_per_line))
                    .collect(),
            ));
            series.push(Series::new(
                format!("{name}: naive"),
                rows.iter()
                    .filter(|r| r.naive_per_line > 0.0)
                    .map(|r| (r.n as f64, r.naive_per_line))
                    .collect(),
            ));
        }
        if !report.scaling.is_empty() {
            let path = with("_scaling.svg");
            log_log_svg(
                &path,
                "Iterations per line against its length (Timonen Fig. 8)",
                "posts per line n",
                "iterations per line",
                &series,
            )?;
            say(format!("wrote {}", path.display()));
        }
        let mut names: Vec<&str> = report.errors.iter().map(|r| r.terrain.as_str()).collect();
        names.dedup();
        let series: Vec<Series> = names
            .iter()
            .map(|n| {
                let points = report.errors.iter().filter(|r| r.terrain == *n);
                Series::new(
                    *n,
                    points
                        .map(|r| (r.directions as f64, r.mean_relative_error))
                        .collect(),
                )
            })
            .collect();
        if !series.is_empty() {
            let path = with("_directions.svg");
            log_log_svg(
                &path,
                "Total viewshed error against directions K (reference K = 1024)",
                "directions K",
                "mean relative error of the visible area",
                &series,
            )?;
            say(format!("wrote {}", path.display()));
        }
        Ok(())
    }
}

/// The report as markdown tables, in the paper's order.
pub fn tables(r: &Report) -> String {
    let f = |v: f64, d: usize| format!("{v:.d$}");
    let mut out = String::new();
    out += "Tables 1 and 2: per post and direction\n\n";
    out += &markdown_table(
        &[
            "terrain",
            "posts",
            "K",
            "vertices behind",
            "visible (Table 1)",
            "visible/behind",
            "horizons m_a",
            "iterations t_a",
            "t_a/naive",
            "eye tests",
            "safe-zone replacements",
            "per vertex: root children m, iterations t",
        ],
        r.tables.iter().map(|t| {
            vec![
                t.terrain.clone(),
                t.posts.to_string(),
                t.directions.to_string(),
                f(t.behind, 1),
                f(t.visible, 2),
                format!("{:.2} %", 100.0 * t.visible / t.behind),
                f(t.horizons, 2),
                f(t.iterations, 2),
                format!("{:.2} %", 100.0 * t.iterations / t.behind),
                f(t.eye_tests, 2),
                format!("{:.0} %", 100.0 * t.replaced),
                format!(
                    "{:.2}, {:.2}",
                    t.root_children_per_vertex, t.iterations_per_vertex
                ),
            ]
        }),
    );
    out += "\nTable 3: seconds per direction (all cores)\n\n";
    out += &markdown_table(
        &[
            "terrain",
            "naive",
            "hull tree",
            "speed-up",
            "hull tree + safe zone",
            "speed-up",
        ],
        r.tables.iter().map(|t| {
            vec![
                t.terrain.clone(),
                format!("{:.1} ms", 1e3 * t.naive_s),
                format!("{:.1} ms", 1e3 * t.hull_tree_s),
                format!("{:.1}x", t.naive_s / t.hull_tree_s),
                format!("{:.1} ms", 1e3 * t.safe_zone_s),
                format!("{:.1}x", t.naive_s / t.safe_zone_s),
            ]
        }),
    );
    if !r.scaling.is_empty() {
        out += "\nFig. 8: iterations per line of n posts\n\n";
        out += &markdown_table(
            &["terrain", "n", "hull tree", "naive"],
            r.scaling.iter().map(|s| {
                vec![
                    s.terrain.clone(),
                    s.n.to_string(),
                    f(s.iterations_per_line, 0),
                    f(s.naive_per_line, 0),
                ]
            }),
        );
        for (name, k) in &r.exponents {
            out += &format!("\n{name}: t = O(n^{k:.2}) (fit over n >= 512)\n");
        }
    }
    if !r.errors.is_empty() {
        out += "\nTotal viewshed: mean relative error against K = 1024 (128 x 128 crop, eye 1.7 m)\n\n";
        out += &markdown_table(
            &["terrain", "K", "mean relative error", "seconds"],
            r.errors.iter().map(|e| {
                vec![
                    e.terrain.clone(),
                    e.directions.to_string(),
                    format!("{:.4}", e.mean_relative_error),
                    format!("{:.3}", e.seconds),
                ]
            }),
        );
        for (name, s) in &r.sampling {
            out += &format!("\n{name}: continuous area against visible posts x post area, mean relative difference {s:.4} (sampling, S)\n");
        }
    }
    if !r.bounded.is_empty() {
        out += "\nBounded total viewshed of the whole DEM, all cores\n\n";
        out += &markdown_table(
            &[
                "terrain",
                "posts",
                "max distance",
                "K",
                "naive",
                "hull tree",
                "+ safe zone",
                "largest relative difference",
            ],
            r.bounded.iter().map(|b| {
                vec![
                    b.terrain.clone(),
                    b.posts.to_string(),
                    format!("{} m", b.max_distance),
                    b.directions.to_string(),
                    format!("{:.1} s", b.naive_s),
                    format!("{:.1} s", b.hull_tree_s),
                    format!("{:.1} s", b.safe_zone_s),
                    format!("{:.1e}", b.max_relative_difference),
                ]
            }),
        );
    }
    out
}
