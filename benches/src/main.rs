//! `terrabake-bench`: the benchmark harnesses' command line. Each
//! subcommand measures one thing on the assets it is given and prints
//! Markdown tables (docs/BENCHMARKS.md has the figures and the `make`
//! targets that reproduce them); `--chart PREFIX` writes SVG charts.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use terrabake::plumbing::progress::Progress;

#[derive(Parser, Debug)]
#[command(
    name = "terrabake-bench",
    version,
    about = "Measure terrabake's methods: speed, and error against exact references, beside the peers.",
    after_help = "Build it with `make build-bench`; the `make bench-*` targets run it."
)]
struct Cli {
    /// No progress bars or messages on stderr.
    #[arg(short, long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Chart the horizon methods' accuracy against their time, and time them on the whole DEM.
    ///
    /// Accuracy: on a centred crop, every method and band count against a reference of 1024
    /// exact sight-line directions: RMS error of the horizon angle and of the sky-view factor
    /// (central half of the crop). Speed: all bands of the whole DEM, all cores, for the runs in
    /// --speed. Prints tables; --chart writes PREFIX_horizon.svg and PREFIX_svf.svg.
    #[command(
        after_help = "Example:\n  terrabake-bench horizons srtm.tbake --chart docs/charts/horizons"
    )]
    Horizons(terrabake_bench::horizons::BenchHorizonsArgs),
    /// Chart the parametric tracer's speed against the cone planes' bake time (replaces the asset's planes).
    ///
    /// For every slice count and encoding: bake the planes (all cores), then trace the sixteen
    /// views of `views` with the parametric tracer on one thread; the hierarchical tracer and
    /// its pyramid are the reference. Prints a table; --chart writes PREFIX_steps.svg and
    /// PREFIX_speed.svg.
    #[command(
        after_help = "Example:\n  terrabake-bench cones srtm.tbake --chart docs/charts/cones"
    )]
    Cones(terrabake_bench::cones::BenchConesArgs),
    /// Benchmark the tracers on the sixteen built-in views, side by side (Paglieroni's Table 1).
    Views(terrabake_bench::views::BenchViewsArgs),
    /// Plan, bake and check each DEM at each budget: achieved error, time and bytes against the
    /// budget (the planner's chart).
    Plan(terrabake_bench::plan::BenchPlanArgs),
    /// Timonen's tables on our terrains: visible points, horizons and iterations per point, sweep
    /// times against the naive method, scaling with line length, error against directions.
    Visibility(terrabake_bench::visibility::BenchVisibilityArgs),
    /// Chart the solar stage beside GRASS r.sun: error of day 172's irradiation against its
    /// seconds, from the points pipelines/solar/chart_rsun.sh measures.
    #[command(
        after_help = "Example:\n  bash pipelines/solar/chart_rsun.sh target/solar-chart\n  terrabake-bench solar target/solar-chart/points.tsv --chart docs/charts/solar"
    )]
    Solar(terrabake_bench::solar::BenchSolarArgs),
    /// Chart points a script measured (series, kind, label, x, y; tab-separated): one curve per
    /// series, ours as lines, the peers' as dashed curves, each point labelled.
    #[command(after_help = "Example:
  bash pipelines/compare_grass_viewshed.sh 3   # draws docs/charts/viewshed_rviewshed.svg this way")]
    Points(terrabake_bench::points::BenchPointsArgs),
}

fn main() -> ExitCode {
    let cli: Cli = terrabake::cli::parse_finite(std::env::args_os()).unwrap_or_else(|e| e.exit());
    terrabake::plumbing::interrupt::install();
    let say = |msg: String| {
        if !cli.quiet {
            eprintln!("{msg}");
        }
    };
    let run = || -> anyhow::Result<()> {
        terrabake::plumbing::simd::cap_from_env().map_err(anyhow::Error::msg)?;
        match &cli.command {
            Command::Horizons(args) => args.run(&say),
            Command::Cones(args) => args.run(Progress::new(cli.quiet), &say),
            Command::Views(args) => args.run(&say),
            Command::Plan(args) => args.run(&say),
            Command::Visibility(args) => args.run(&say),
            Command::Solar(args) => args.run(&say),
            Command::Points(args) => args.run(&say),
        }
    };
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", terrabake::error::error_chain(&e));
            ExitCode::FAILURE
        }
    }
}
