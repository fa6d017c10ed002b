//! The command line: its grammar, every subcommand and flag with the help
//! text people read, and the one way a command runs. Each subcommand is a
//! variant holding its arguments, one clap `Args` type that implements
//! [`Run`]; [`Command::run`] dispatches in one line each, and the binary
//! (`src/main.rs`) prints what a run returns. The stages' own parameter
//! types are flattened into their commands' arguments (`stages.rs`); the
//! commands of other rooms keep their arguments beside their work
//! (`RenderArgs` in `present::render`, `ExportArgs` in `export`, ...).

pub mod asset;
pub mod stages;

use std::process::ExitCode;

use clap::{ArgMatches, CommandFactory, FromArgMatches, Parser, Subcommand};

use crate::stage::session::{Run, Session};
use crate::stages::pyramid::PyramidStage;
use crate::stages::sky::SkyStage;
use crate::stages::viewshed::stage::TotalViewshedStage;
use asset::{InfoArgs, SynthArgs, VerifyArgs};
use stages::{
    AssembleArgs, BakeArgs, ConesCommand, HorizonsCommand, IngestArgs, SolarCommand, StageCommand,
};

#[derive(Parser, Debug)]
#[command(
    name = "terrabake",
    version,
    about = "Bake terrain height fields (DEMs) into chunked, memory-mapped assets for renderers.",
    long_about = "Bake terrain height fields (DEMs) into chunked, memory-mapped assets for renderers.\n\n\
An asset is a directory: a manifest (manifest.tba) and one file per layer, each cut into tiles that a \
renderer maps and reads in place (docs/FORMAT.md). `ingest` makes an asset from a DEM; later stages add \
layers to it; `bake` runs a recipe of stages, skipping those already done.\n\n\
Exit status: 0 success, 1 error (the message names the file and the problem), 2 bad usage, \
3 `verify` found problems.",
    after_help = "Examples:\n  terrabake ingest dem.tif -o dem.tbake\n  terrabake info dem.tbake --json\n  \
terrabake export dem.tbake --layer height -o preview.png\n  terrabake synth fractal --size 4096x4096 -o fractal.tif\n  \
terrabake bake dem.tif -o dem.tbake --recipe pipelines/demo.toml"
)]
pub struct Cli {
    /// No progress bars and no summary lines on stderr.
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// When another process is writing the asset, fail at once (naming its
    /// pid) instead of waiting for it to finish.
    #[arg(long, global = true)]
    pub no_wait: bool,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Read a DEM (GeoTIFF, SRTM .hgt, raw, 16-bit PNG, OpenEXR) into a new asset's height layer.
    ///
    /// The DEM is streamed one tile row at a time: memory does not grow with its area. Nodata,
    /// NaN and infinite samples become nodata (NaN in the asset) and are counted. An existing
    /// asset at the output path is replaced only once the new one is complete.
    Ingest(IngestArgs),
    /// Describe an asset: shape, cell size, georeferencing, layers, nodata, provenance.
    Info(InfoArgs),
    /// Check every checksum and structural invariant of an asset (exit status 3 if any fails).
    Verify(VerifyArgs),
    /// Write a layer as a Cloud-Optimized GeoTIFF (.tif), OpenEXR (.exr), a PNG preview (.png),
    /// or one GeoTIFF per direction for GRASS (--for grass).
    ///
    /// GeoTIFF and EXR carry every band (a horizon layer: one band per azimuth, in degrees, in
    /// compass order); quantised layers are decoded. A GeoTIFF is tiled, band-interleaved, with
    /// internal overviews, and each band's description names what it holds (`horizon azimuth
    /// 21.80 deg, line`). A PNG shows one band (--band).
    #[command(after_help = "Examples:\n  terrabake export dem.tbake -o dem.tif\n  \
terrabake export dem.tbake --layer horizon -o horizon.tif\n  \
terrabake export dem.tbake --layer horizon --for grass -o horizons/\n  \
terrabake export dem.tbake --layer svf -o svf.png")]
    Export(crate::export::ExportArgs),
    /// Write a synthetic terrain as a float32 GeoTIFF (30 m posts), a tile row at a time, at any size.
    Synth(SynthArgs),
    /// Add the quadtree max/min pyramid layers (for hierarchical ray tracing) to an asset.
    ///
    /// Level 0 holds each cell's tallest and lowest corner; each level above the max and min of
    /// 2 x 2 blocks, up to one tile. Skipped when the asset already has them.
    Pyramid(StageCommand<PyramidStage>),
    /// Add the parameter planes (a cone of empty space over every cell) for parametric ray tracing.
    ///
    /// Per cell, the apex height and the slope (horizontal metres per metre of rise) of a cone that
    /// no terrain enters (Paglieroni and Petersen 1992). --slices K is the paper's method: K
    /// horizontal slices, one exact distance transform each, the apex at the first slice above the
    /// cell. --slices exact computes the limit of infinitely many slices without slicing (the
    /// lowest apex, the widest cone). --slices auto picks K from the data: no more slices than the
    /// data has height steps, and no more than --apex-gap needs. Encodings f16 and u16 halve the
    /// planes' size and stay conservative (slope rounded down, apex up). DEMs larger than
    /// --max-memory are baked in windows with halos (docs/CONES.md).
    #[command(
        after_help = "Examples:\n  terrabake cones dem.tbake\n  terrabake cones dem.tbake --slices exact\n  \
terrabake cones dem.tbake --slices 256 --encoding u16 --json"
    )]
    Cones(ConesCommand),
    /// Add horizon maps: the horizon's elevation angle at every post in S azimuths, plus sky-view
    /// factors and openness.
    ///
    /// --method line (default): the steepest sight line along the straight line from each post on
    /// the same surface the tracers use, exact; directions are grid directions within a tolerance
    /// of i * 360 / S (listed per band in the manifest). --method sector: Stewart's maximum over
    /// each closed azimuth wedge, exact (a spike anywhere in a wedge sets the whole sector).
    /// --method sampled: centre-line sampling with nearest-post heights, what GRASS r.horizon and
    /// SAGA do (a baseline). Angles are compass-ordered bands of the `horizon` layer, degrees,
    /// stored in the smallest encoding within --max-error; the stage also writes `svf` (Zakšek:
    /// 1 - mean sin h), `svf_cosine` (view factor from the tilted surface), `openness` and
    /// `horizon_edge` (bands the DEM's edge may cut). Earth curvature is on by default for
    /// georeferenced DEMs (docs/HORIZONS.md). With --max-distance, line and sector walk or scan
    /// each post's reach of M posts, O(M) and O(M^2 / S) per post; bounded sector runs out of
    /// core.
    #[command(
        after_help = "Examples:\n  terrabake horizons dem.tbake --sectors 16\n  \
terrabake horizons dem.tbake --sectors 64 --method sector\n  \
terrabake horizons dem.tbake --sectors 32 --aoi 100,100,400,400 --max-error 0.01 --json\n  \
terrabake export dem.tbake --layer horizon -o horizon.tif"
    )]
    Horizons(HorizonsCommand),
    /// Add the sky layers from the asset's horizons: sky-view factors (svf, svf_cosine),
    /// positive openness, and the count of bands the DEM's edge may cut (horizon_edge).
    ///
    /// Reads the committed horizon layer and the horizons stage's recorded parameters (area of
    /// interest, curvature); `terrabake horizons` runs it unless --no-sky.
    Sky(StageCommand<SkyStage>),
    /// Render a shaded perspective view, traced through the asset (sun light and sun shadows).
    ///
    /// Coordinates are local metres: x east and y north from the DEM's south-west post, z the
    /// heights' metres (`terrabake info` gives the extent). Use --view 1..16 for the built-in
    /// oblique views of the tracing benchmark, or --camera and --look-at.
    Render(crate::present::render::RenderArgs),
    /// Plan the horizons a budget needs: directions, encoding, predicted error, time and bytes.
    Plan(crate::plan::PlanArgs),
    /// Time this machine against the planner's time models (cached; --fresh measures again).
    Calibrate(crate::plan::CalibrateArgs),
    /// Measure the horizon and sky-view factor errors a bake achieved against exact references,
    /// and check them against a budget.
    Check(crate::plan::check::CheckArgs),
    /// Write one self-contained HTML page with an asset's summary, pictures and charts.
    Page(crate::present::page::PageArgs),
    /// One observer's viewshed as a GeoTIFF: which posts it sees, and at what elevation angle.
    Viewshed(crate::export::viewshed::ViewshedArgs),
    /// The horizon around one point at every azimuth step, from the exact sight line at each
    /// azimuth, with the distance to what sets it: CSV, JSON, or PVGIS's horizon columns.
    Profile(crate::present::profile::ProfileArgs),
    /// Add the total viewshed: at every post, the area an eye above it sees (square metres),
    /// by Timonen's azimuthal sweeps with the convex hull tree.
    TotalViewshed(StageCommand<TotalViewshedStage>),
    /// Add clear-sky irradiation and sun hours over days from the stored horizons, and write
    /// them as one GeoTIFF: r.sun's model, shadowed without a ray.
    ///
    /// Layers solar_global, solar_beam, solar_diffuse, solar_reflected (Wh/m^2 per day, the
    /// mean day of the period) and sun_hours (hours per day with the sun's centre above the
    /// horizon and in front of the surface), one band for the period or one per month with
    /// --monthly. The model is r.sun's (Suri and Hofierka 2004: ESRA clear sky with the Linke
    /// turbidity, Muneer's diffuse on slopes, ground reflection); the sun's position is Meeus's
    /// (about 0.01 degrees; NREL's SPA example within 0.02); a post is sunlit where the sun's centre is above
    /// its horizon as the loader serves it and in front of its surface. The diffuse part's
    /// isotropic sky and the reflected part are weighed by svf_cosine (the sky stage runs first
    /// when the asset lacks it). Latitude comes from the georeferencing, row by row (--lat
    /// otherwise). docs/SOLAR.md has the formulas, the comparison with r.sun and the timings.
    #[command(
        after_help = "Examples:\n  terrabake solar dem.tbake --day 172 -o june21.tif\n  \
terrabake solar dem.tbake --year --monthly -o year.tif\n  \
terrabake solar dem.tbake --days 80-100 --step 10 --linke 2.5 --albedo 0.3 --json\n  \
terrabake solar flat.tbake --lat 46.5 --lon 8 --year -o year.tif"
    )]
    Solar(SolarCommand),
    /// Ingest a DEM and run every stage of a recipe, skipping work already done.
    ///
    /// A recipe is a TOML file: an [ingest] table with ingest's options (tile, codec,
    /// cell_size, nodata, z_scale, z_offset...), then one [[stage]] table per stage, in order,
    /// with `name` (pyramid, cones, horizons, sky, viewshed, total_viewshed, solar) and its options, dashes as
    /// underscores (max_distance = 3000.0, max_error_deg = 0.1). Unknown keys are refused by
    /// name, and the whole recipe is checked before ingest starts. A stage whose recorded
    /// options match and whose layers are present is skipped, so a bake that stopped resumes
    /// (a recipe is shown below).
    ///
    /// With --parts N --part I, bake only part I of N (0-based) into OUTPUT.parts/, for a
    /// scheduler to run the N parts anywhere (Slurm array tasks, Kubernetes indexed jobs,
    /// make -j); `terrabake assemble OUTPUT` then joins them. The result is the same, bit for
    /// bit, as one bake (docs/SCALE.md says which stage splits how).
    // One of the two is required: clap's error then names both.
    #[command(group = clap::ArgGroup::new("recipe_or_budget").required(true).args(["recipe", "budget"]))]
    #[command(
        after_help = "Examples:\n  terrabake bake dem.tif -o dem.tbake --recipe pipelines/demo.toml\n  \
for i in 0 1 2 3; do terrabake bake dem.tif -o dem.tbake --recipe pipelines/demo.toml --parts 4 --part $i; done\n  \
terrabake assemble dem.tbake\n\n\
A recipe (a shorter pipelines/demo.toml):\n  \
[ingest]\n  tile = 256\n  codec = \"raw\"\n\n  \
[[stage]]\n  name = \"pyramid\"\n\n  \
[[stage]]\n  name = \"horizons\"\n  sectors = 16\n  method = \"line\"\n  max_distance = 3000.0\n\n  \
[[stage]]\n  name = \"sky\"\n  layers = [\"svf\", \"openness\"]"
    )]
    Bake(BakeArgs),
    /// Join the parts of a partitioned bake (OUTPUT.parts/) into the asset.
    ///
    /// Checks that every part is there, finished and baked with the same recipe and source,
    /// copies each part's chunks into the asset's layers (checksummed, not decoded), commits
    /// the manifest once, then runs the stages left to the join (the pyramid, cones). A
    /// missing or damaged part is named and nothing is committed.
    Assemble(AssembleArgs),
}

impl Cli {
    /// The process's arguments, parsed as [`Parser::parse`] does, with one
    /// more rule for every number flag of every command: NaN and the
    /// infinities are refused (clap's own `f64` parser takes `nan` and
    /// `inf`), with clap's message and exit status 2.
    pub fn parse_checked() -> Self {
        Self::try_parse_checked(std::env::args_os()).unwrap_or_else(|e| e.exit())
    }

    /// [`Self::parse_checked`] of `args` (the program's name first).
    pub(crate) fn try_parse_checked<I, T>(args: I) -> Result<Self, clap::Error>
    where
        I: IntoIterator<Item = T>,
        T: Into<std::ffi::OsString> + Clone,
    {
        let cli: Self = parse_finite(args)?;
        if let Command::Bake(BakeArgs {
            part: Some(i),
            parts: Some(n),
            ..
        }) = cli.command
        {
            if let Err(e) = crate::bake::partition::Part::new(i, n) {
                let mut cmd = Self::command();
                let bake = cmd.find_subcommand_mut("bake").expect("bake is a command");
                return Err(bake.error(clap::error::ErrorKind::ValueValidation, e));
            }
        }
        Ok(cli)
    }
}

impl Command {
    /// The command's arguments, to run.
    fn args(&self) -> &dyn Run {
        match self {
            Command::Ingest(a) => a,
            Command::Info(a) => a,
            Command::Verify(a) => a,
            Command::Export(a) => a,
            Command::Synth(a) => a,
            Command::Pyramid(a) => a,
            Command::Cones(a) => a,
            Command::Horizons(a) => a,
            Command::Sky(a) => a,
            Command::Render(a) => a,
            Command::Plan(a) => a,
            Command::Calibrate(a) => a,
            Command::Check(a) => a,
            Command::Page(a) => a,
            Command::Viewshed(a) => a,
            Command::Profile(a) => a,
            Command::TotalViewshed(a) => a,
            Command::Solar(a) => a,
            Command::Bake(a) => a,
            Command::Assemble(a) => a,
        }
    }

    /// Runs the command in `session`: its exit status, or what failed.
    pub fn run(&self, session: &Session) -> crate::Result<ExitCode> {
        self.args().run(session)
    }
}

/// `args` parsed as `C`, refusing NaN and the infinities in every number
/// flag with clap's message (the rule of [`Cli::parse_checked`], for any
/// command line: `terrabake-bench` takes it too).
pub fn parse_finite<C, I, T>(args: I) -> Result<C, clap::Error>
where
    C: CommandFactory + FromArgMatches,
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let mut cmd = C::command();
    let matches = cmd.try_get_matches_from_mut(args)?;
    refuse_non_finite(&mut cmd, &matches)?;
    C::from_arg_matches(&matches).map_err(|e| e.format(&mut cmd))
}

/// The first flag of `matches` (or of its subcommands) holding a number
/// that is not finite, as clap's validation error of that command.
fn refuse_non_finite(cmd: &mut clap::Command, matches: &ArgMatches) -> Result<(), clap::Error> {
    for id in matches.ids() {
        let id = id.as_str();
        let mut numbers: Vec<f64> = Vec::new();
        if let Ok(Some(v)) = matches.try_get_many::<f64>(id) {
            numbers.extend(v.copied());
        } else if let Ok(Some(v)) = matches.try_get_many::<f32>(id) {
            numbers.extend(v.map(|&x| f64::from(x)));
        } else if let Ok(Some(v)) = matches.try_get_many::<(f64, f64)>(id) {
            numbers.extend(v.flat_map(|&(a, b)| [a, b]));
        } else if let Ok(Some(v)) = matches.try_get_many::<[f64; 3]>(id) {
            numbers.extend(v.flatten().copied());
        }
        if numbers.iter().any(|v| !v.is_finite())
            && !crate::stage::args::NAN_MEANS_SOMETHING.contains(&id)
        {
            let flag = cmd
                .get_arguments()
                .find(|a| a.get_id() == id)
                .and_then(|a| a.get_long().map(|l| format!("--{l}")))
                .unwrap_or_else(|| id.to_string());
            let given = matches
                .get_raw(id)
                .and_then(|mut raw| raw.next())
                .map(|v| v.to_string_lossy().into_owned())
                .unwrap_or_default();
            return Err(cmd.error(
                clap::error::ErrorKind::ValueValidation,
                format!("invalid value '{given}' for '{flag}': not a finite number"),
            ));
        }
    }
    if let Some((name, sub)) = matches.subcommand() {
        if let Some(sub_cmd) = cmd.find_subcommand_mut(name) {
            return refuse_non_finite(sub_cmd, sub);
        }
    }
    Ok(())
}
