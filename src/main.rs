//! The `terrabake` command line: argument parsing and printing only; the
//! work is in the library.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use terrabake::asset::{AssetWriter, Wait};
use terrabake::cones::{ConesStage, SliceChoice};
use terrabake::export::{export_layer, PngStyle};
use terrabake::horizon::{AngleChoice, HorizonsStage, Method as HorizonMethod};
use terrabake::ingest::{ingest_into, IngestOptions, DEFAULT_INGEST_MEMORY, DEFAULT_TILE};
use terrabake::progress::Progress;
use terrabake::pyramid::PyramidStage;
use terrabake::render::{builtin_views, render, write_png, Camera, RenderOptions, Shadows, Sun};
use terrabake::source::{ByteOrder, RawSampleType, RawSpec};
use terrabake::stage::{bake, run_stage_in, Recipe, Stage, StageOutcome};
use terrabake::synth::SynthKind;
use terrabake_format::cones::{ConeEncoding, CONE_APEX};
use terrabake_format::horizons::{AngleEncoding, HORIZON};
use terrabake_format::trace::{Method, Tracer};
use terrabake_format::{Asset, Codec};

/// Exit status when `verify` finds problems (1 is any other error, 2 a usage error).
const EXIT_VERIFY_FAILED: u8 = 3;

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
struct Cli {
    /// No progress bars and no summary lines on stderr.
    #[arg(long, short, global = true)]
    quiet: bool,
    /// When another process is writing the asset, fail at once (naming its
    /// pid) instead of waiting for it to finish.
    #[arg(long, global = true)]
    no_wait: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Read a DEM (GeoTIFF, SRTM .hgt, raw, 16-bit PNG, OpenEXR) into a new asset's height layer.
    ///
    /// The DEM is streamed one tile row at a time: memory does not grow with its area. Nodata,
    /// NaN and infinite samples become nodata (NaN in the asset) and are counted. An existing
    /// asset at the output path is replaced only once the new one is complete.
    Ingest {
        /// The DEM file.
        src: PathBuf,
        /// The asset directory to write.
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        opts: IngestArgs,
        /// Print the manifest as JSON on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Describe an asset: shape, cell size, georeferencing, layers, nodata, provenance.
    Info {
        asset: PathBuf,
        /// The manifest as JSON, for scripts.
        #[arg(long)]
        json: bool,
    },
    /// Check every checksum and structural invariant of an asset (exit status 3 if any fails).
    Verify {
        asset: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Write a layer as GeoTIFF (.tif, georeferenced, with nodata), OpenEXR (.exr) or a PNG preview (.png).
    ///
    /// GeoTIFF and EXR carry every band (a horizon layer: one band per azimuth, in degrees, in
    /// compass order); quantised layers are decoded. A PNG shows one band (--band).
    #[command(after_help = "Examples:\n  terrabake export dem.tbake -o dem.tif\n  \
terrabake export dem.tbake --layer horizon -o horizon.tif\n  \
terrabake export dem.tbake --layer svf --style gray -o svf.png")]
    Export {
        asset: PathBuf,
        /// Layer name (see `terrabake info`).
        #[arg(long, default_value = "height")]
        layer: String,
        /// Pyramid level of the layer.
        #[arg(long, default_value_t = 0)]
        level: u32,
        /// PNG style: `relief` (hypsometric tint with hillshade, nodata transparent) or
        /// `gray` (16-bit, min to max).
        #[arg(long, value_enum, default_value = "relief")]
        style: PngStyle,
        /// The band a PNG shows (GeoTIFF and EXR carry all bands).
        #[arg(long, default_value_t = 0)]
        band: u32,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Write a synthetic terrain as a float32 GeoTIFF (30 m posts), strip by strip, at any size.
    Synth {
        #[arg(value_enum)]
        kind: SynthKind,
        /// WIDTHxHEIGHT in posts.
        #[arg(long, value_parser = parse_size)]
        size: (u32, u32),
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Add the quadtree max/min pyramid layers (for hierarchical ray tracing) to an asset.
    ///
    /// Level 0 holds each cell's tallest and lowest corner; each level above the max and min of
    /// 2 x 2 blocks, up to one tile. Skipped when the asset already has them.
    Pyramid {
        asset: PathBuf,
        /// Rebuild even if the asset already has an up-to-date pyramid.
        #[arg(long)]
        force: bool,
        #[arg(long)]
        json: bool,
    },
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
    Cones {
        asset: PathBuf,
        /// A slice count K (1..=65535), auto, or exact.
        #[arg(long, default_value = "auto")]
        slices: SliceChoice,
        /// With --slices auto: how far (metres) the apex may sit above a cell's neighbourhood;
        /// default relief / 255, i.e. 256 slices unless the data has fewer height steps.
        #[arg(long, value_parser = parse_positive)]
        apex_gap: Option<f64>,
        /// How the planes are stored: f32, f16 or u16 (conservatively rounded).
        #[arg(long, default_value = "f32")]
        encoding: ConeEncoding,
        /// Working memory in MiB; a DEM that needs more is baked in windows.
        #[arg(long, default_value_t = 8192, value_parser = clap::value_parser!(u64).range(1..))]
        max_memory: u64,
        /// Rebuild even if the asset already has up-to-date planes.
        #[arg(long)]
        force: bool,
        #[arg(long)]
        json: bool,
    },
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
    /// georeferenced DEMs (docs/HORIZONS.md).
    #[command(
        after_help = "Examples:\n  terrabake horizons dem.tbake --sectors 16\n  \
terrabake horizons dem.tbake --sectors 64 --method sector\n  \
terrabake horizons dem.tbake --sectors 32 --aoi 100,100,400,400 --max-error 0.01 --json\n  \
terrabake export dem.tbake --layer horizon -o horizon.tif"
    )]
    Horizons {
        asset: PathBuf,
        /// Number of azimuths (bands), 3..=4096; band i is centred on i * 360 / S degrees.
        #[arg(long, default_value_t = 16)]
        sectors: usize,
        /// line (exact sight lines), sector (Stewart's wedges) or sampled (baseline).
        #[arg(long, value_enum, default_value = "line")]
        method: HorizonMethod,
        /// Look no farther than this many metres (default: the whole DEM, exact). Bounded
        /// line and sector horizons walk or scan each post's reach: O(M) and O(M^2 / S) per post;
        /// bounded sector runs out of core.
        #[arg(long, value_parser = parse_positive)]
        max_distance: Option<f64>,
        /// Earth curvature, drop d^2 (1 - k) / 2R: on, off (default: on for georeferenced DEMs).
        #[arg(long, value_parser = parse_on_off)]
        curvature: Option<bool>,
        /// Refraction coefficient k of the curvature drop.
        #[arg(long, default_value_t = terrabake::horizon::terrain::DEFAULT_REFRACTION)]
        refraction: f64,
        /// Only compute posts in columns X0..X1 and rows Y0..Y1 (end exclusive); every post of the
        /// DEM still occludes.
        #[arg(long, value_parser = parse_aoi)]
        aoi: Option<[u32; 4]>,
        /// Largest angular error of the stored angles, degrees: picks u8 (0.354), u16 (0.0014) or
        /// f32.
        #[arg(long, default_value_t = 0.5, conflicts_with = "encoding")]
        max_error: f64,
        /// Store angles as u8, u16 or f32 regardless of --max-error.
        #[arg(long)]
        encoding: Option<AngleEncoding>,
        /// Leave out Stewart's narrow-sector check (sec. IV-E) with --method sector.
        #[arg(long)]
        no_narrow_check: bool,
        /// How far a line direction may sit from i * 360 / S, degrees (default: spacing / 8).
        #[arg(long, value_parser = parse_positive)]
        direction_tolerance: Option<f64>,
        /// Working memory in MiB for the methods that hold the DEM in memory (sector
        /// without --max-distance, sampled, line with --max-distance); a DEM that needs more
        /// is refused with the out-of-core routes named.
        #[arg(long, default_value_t = 8192, value_parser = clap::value_parser!(u64).range(1..))]
        max_memory: u64,
        /// Recompute even if the asset already has up-to-date horizons.
        #[arg(long)]
        force: bool,
        #[arg(long)]
        json: bool,
    },
    /// Chart the horizon methods' accuracy against their time, and time them on the whole DEM.
    ///
    /// Accuracy: on a centred crop, every method and band count against a reference of 1024
    /// exact sight-line directions: RMS error of the horizon angle and of the sky-view factor
    /// (central half of the crop). Speed: all bands of the whole DEM, all cores, for the runs in
    /// --speed. Prints tables; --chart writes PREFIX_horizon.svg and PREFIX_svf.svg.
    #[command(
        after_help = "Example:\n  terrabake bench-horizons srtm.tbake --chart docs/charts/horizons"
    )]
    BenchHorizons {
        asset: PathBuf,
        /// Band counts for the accuracy study, comma-separated.
        #[arg(long, value_delimiter = ',', default_value = "8,16,32,64,128,256")]
        counts: Vec<usize>,
        /// Methods for the accuracy study, comma-separated.
        #[arg(long, value_delimiter = ',', default_value = "line,sector,sampled")]
        methods: Vec<HorizonMethod>,
        /// Directions of the reference.
        #[arg(long, default_value_t = 1024)]
        reference: usize,
        /// Side of the centred crop for the accuracy study, posts.
        #[arg(long, default_value_t = 256)]
        crop: usize,
        /// Whole-DEM speed runs METHOD:COUNT, comma-separated (none: skip).
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "line:16,line:64,sector:16,sector:64,sampled:16"
        )]
        speed: Vec<String>,
        /// Write PREFIX_horizon.svg and PREFIX_svf.svg.
        #[arg(long)]
        chart: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Chart the parametric tracer's speed against the cone planes' bake time (replaces the asset's planes).
    ///
    /// For every slice count and encoding: bake the planes (all cores), then trace the sixteen
    /// views of bench-views with the parametric tracer on one thread; the hierarchical tracer and
    /// its pyramid are the reference. Prints a table; --chart writes PREFIX_steps.svg and
    /// PREFIX_speed.svg.
    #[command(
        after_help = "Example:\n  terrabake bench-cones srtm.tbake --chart docs/charts/cones"
    )]
    BenchCones {
        asset: PathBuf,
        /// Slice counts and/or exact, comma-separated.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "4,8,16,32,64,128,256,512,1024,exact"
        )]
        slices: Vec<SliceChoice>,
        /// Encodings, comma-separated.
        #[arg(long, value_delimiter = ',', default_value = "f32")]
        encodings: Vec<ConeEncoding>,
        /// Image side in pixels.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Trace every N-th pixel.
        #[arg(long, default_value_t = 4)]
        every: u32,
        /// Write PREFIX_steps.svg and PREFIX_speed.svg.
        #[arg(long)]
        chart: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Render a shaded perspective view, traced through the asset (sun light and sun shadows).
    ///
    /// Coordinates are local metres: x east and y north from the DEM's south-west post, z the
    /// heights' metres (`terrabake info` gives the extent). Use --view 1..16 for the built-in
    /// oblique views of the tracing benchmark, or --camera and --look-at.
    Render {
        asset: PathBuf,
        /// Instead of a perspective view: an overhead map shaded from the stored horizons alone,
        /// `sky` (overcast sky, radiosity) or `sun:AZ,EL` (sun disc and Stewart's sky); needs the
        /// horizons stage.
        #[arg(long, conflicts_with_all = ["view", "camera"])]
        shade: Option<terrabake::shade::Shade>,
        /// Camera position X,Y,Z (local metres).
        #[arg(long, value_parser = parse_point, allow_hyphen_values = true, requires = "look_at", conflicts_with = "view")]
        camera: Option<[f64; 3]>,
        /// Point the camera looks at, X,Y,Z (local metres).
        #[arg(long, value_parser = parse_point, allow_hyphen_values = true, requires = "camera")]
        look_at: Option<[f64; 3]>,
        /// One of the sixteen built-in oblique views (1..=16).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=16))]
        view: Option<u32>,
        /// Horizontal field of view, degrees (built-in views use 104).
        #[arg(long)]
        fov: Option<f64>,
        /// Image size WIDTHxHEIGHT.
        #[arg(long, value_parser = parse_size, default_value = "800x600")]
        size: (u32, u32),
        /// Tracer: incremental, runs, hierarchical, parametric, brute-force (all give the same picture;
        /// hierarchical needs the pyramid stage, parametric the cones stage).
        #[arg(long, default_value = "hierarchical")]
        method: Method,
        /// Sun azimuth (clockwise from north) and elevation, degrees.
        #[arg(long, value_parser = parse_sun, default_value = "135,35")]
        sun: Sun,
        /// Trace every N-th pixel only (others copy the nearest traced one).
        #[arg(long, default_value_t = 1)]
        every: u32,
        /// No shadow rays.
        #[arg(long)]
        no_shadows: bool,
        /// Sun shadows from the stored horizons (lit_fraction, soft, no shadow rays; needs the
        /// horizons stage) instead of shadow rays.
        #[arg(long, conflicts_with = "no_shadows")]
        horizon_shadows: bool,
        /// Vertical exaggeration (camera heights are then in exaggerated metres).
        #[arg(long, default_value_t = 1.0)]
        exaggerate: f64,
        #[arg(short, long)]
        output: PathBuf,
        /// Print rays per second and mean steps per ray.
        #[arg(long)]
        stats: bool,
        /// Print the statistics as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Benchmark the tracers on the sixteen built-in views, side by side (Paglieroni's Table 1).
    BenchViews {
        /// One asset, or several (a scaling series, e.g. for --chart).
        #[arg(required = true)]
        assets: Vec<PathBuf>,
        /// With several assets: write PREFIX_steps.svg and PREFIX_time.svg, per method against DEM side.
        #[arg(long)]
        chart: Option<PathBuf>,
        /// Image side in pixels.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Trace every N-th pixel (16 as in the paper, 1 for every pixel).
        #[arg(long, default_value_t = 16)]
        every: u32,
        /// Methods, comma-separated.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "incremental,runs,hierarchical"
        )]
        methods: Vec<Method>,
        /// Instead of the views: cost per ray in N azimuths (shallow rays from a grid of origins).
        #[arg(long)]
        directions: Option<u32>,
        #[arg(long)]
        json: bool,
    },
    /// Ingest a DEM and run every stage of a recipe, skipping work already done.
    Bake {
        src: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
        /// A recipe from pipelines/ (TOML): ingest options and stages.
        #[arg(long)]
        recipe: PathBuf,
        #[arg(long)]
        json: bool,
    },
}

#[derive(clap::Args, Debug)]
struct IngestArgs {
    /// Tile edge in posts: a power of two from 16 to 4096.
    #[arg(long = "tile", default_value_t = DEFAULT_TILE)]
    tile: u32,
    /// Memory the source's reader may hold at once, MiB. Ingest streams, so
    /// only a DEM stored as a few huge strips or tiles (or an OpenEXR, read
    /// whole) comes near it; such a source is refused from its header.
    #[arg(long, default_value_t = DEFAULT_INGEST_MEMORY >> 20, value_name = "MIB")]
    max_memory: u64,
    /// Nodata value of the source, overriding what the file says.
    #[arg(long, allow_hyphen_values = true)]
    nodata: Option<f64>,
    /// Post spacing in metres, DX or DX,DY (default: from the georeferencing, else 1 m).
    #[arg(long, value_parser = parse_cell_size)]
    cell_size: Option<(f64, f64)>,
    /// Heights are `sample * z_scale + z_offset` (for PNG heightmaps, say).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    z_scale: f64,
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    z_offset: f64,
    /// Tile codec: `raw` (read in place from the mapping) or `zstd` (smaller; decompressed into a cache).
    #[arg(long, value_parser = parse_codec, default_value = "raw")]
    codec: Codec,
    /// Shape of a headerless raster, WIDTHxHEIGHT.
    #[arg(long, value_parser = parse_size, requires = "raw_type")]
    raw_shape: Option<(u32, u32)>,
    /// Sample type of a headerless raster.
    #[arg(long, value_enum, requires = "raw_shape")]
    raw_type: Option<RawSampleType>,
    /// Byte order of a headerless raster.
    #[arg(long, value_enum, default_value = "le")]
    byte_order: ByteOrder,
}

impl IngestArgs {
    fn options(&self) -> IngestOptions {
        IngestOptions {
            tile_size: self.tile,
            nodata: self.nodata,
            cell_size: self.cell_size,
            z_scale: self.z_scale,
            z_offset: self.z_offset,
            codec: self.codec,
            raw: match (self.raw_shape, self.raw_type) {
                (Some((width, height)), Some(sample)) => Some(RawSpec {
                    width,
                    height,
                    sample,
                    order: self.byte_order,
                }),
                _ => None,
            },
            max_memory: self.max_memory << 20,
        }
    }
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or("expected WIDTHxHEIGHT, e.g. 1024x768")?;
    let parse = |v: &str| v.trim().parse::<u32>().map_err(|e| format!("{v:?}: {e}"));
    Ok((parse(w)?, parse(h)?))
}

fn parse_cell_size(s: &str) -> Result<(f64, f64), String> {
    let parse = |v: &str| match v.trim().parse::<f64>() {
        Ok(f) if f.is_finite() && f > 0.0 => Ok(f),
        _ => Err(format!("{v:?} is not a positive number of metres")),
    };
    match s.split_once(',') {
        Some((dx, dy)) => Ok((parse(dx)?, parse(dy)?)),
        None => parse(s).map(|d| (d, d)),
    }
}

fn parse_point(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("{p:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err("expected X,Y,Z in metres".into()),
    }
}

fn parse_sun(s: &str) -> Result<Sun, String> {
    let (az, el) = s
        .split_once(',')
        .ok_or("expected AZIMUTH,ELEVATION in degrees")?;
    let parse = |v: &str| v.trim().parse::<f64>().map_err(|e| format!("{v:?}: {e}"));
    let (azimuth, elevation) = (parse(az)?, parse(el)?);
    if !(-90.0..=90.0).contains(&elevation) {
        return Err(format!(
            "sun elevation {elevation} is not between -90 and 90 degrees"
        ));
    }
    Ok(Sun { azimuth, elevation })
}

fn parse_positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("expected a positive number, not {s:?}")),
    }
}

fn parse_on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("{s:?}: expected on or off")),
    }
}

fn parse_aoi(s: &str) -> Result<[u32; 4], String> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse::<u32>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("{s:?}: expected X0,Y0,X1,Y1 in posts"))?;
    v.try_into()
        .map_err(|_| format!("{s:?}: expected four numbers X0,Y0,X1,Y1"))
}

fn parse_codec(s: &str) -> Result<Codec, String> {
    match s {
        "raw" => Ok(Codec::Raw),
        "zstd" => Ok(Codec::Zstd),
        _ => Err(format!("{s:?}: expected raw or zstd")),
    }
}

fn main() -> ExitCode {
    // A closed pipe (`terrabake info --json | head -1`) ends the process
    // quietly, as it does `cat`, instead of a panic in println!.
    // SAFETY: restoring a signal's default disposition before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<ExitCode> {
    let progress = Progress::new(cli.quiet);
    let wait = if cli.no_wait {
        Wait::NoWait
    } else {
        Wait::Wait
    };
    let run_stage = |asset: &Path, stage: &dyn Stage, force: bool| -> Result<StageOutcome> {
        run_stage_in(&AssetWriter::open(asset, wait)?, stage, force, progress)
    };
    let say = |msg: String| {
        if !cli.quiet {
            eprintln!("{msg}");
        }
    };
    match cli.command {
        Command::Ingest {
            src,
            output,
            opts,
            json,
        } => {
            let start = std::time::Instant::now();
            let writer = AssetWriter::create(&output, wait)?;
            let manifest = ingest_into(&writer, &src, &opts.options(), progress)
                .inspect_err(|_| writer.fail())?;
            if json {
                println!("{}", serde_json::to_string_pretty(&manifest)?);
            }
            say(format!(
                "ingested {} ({} x {}, {} nodata) into {} in {:.2} s",
                src.display(),
                manifest.width,
                manifest.height,
                manifest.nodata.count,
                output.display(),
                start.elapsed().as_secs_f64()
            ));
        }
        Command::Info { asset, json } => {
            let opened = open_asset(&asset)?;
            if json {
                println!("{}", serde_json::to_string_pretty(opened.manifest())?);
            } else {
                print!("{}", describe(&asset, opened.manifest()));
            }
        }
        Command::Verify { asset, json } => {
            let opened = open_asset(&asset)?;
            let report = opened.verify();
            let problems: Vec<String> = report.problems.iter().map(|p| p.to_string()).collect();
            if json {
                let out = serde_json::json!({
                    "asset": asset.display().to_string(),
                    "layers": report.layers,
                    "chunks": report.chunks,
                    "ok": problems.is_empty(),
                    "problems": problems,
                });
                println!("{}", serde_json::to_string_pretty(&out)?);
            } else {
                for p in &problems {
                    println!("problem: {p}");
                }
                println!(
                    "{}: {} layers, {} chunks, {}",
                    asset.display(),
                    report.layers,
                    report.chunks,
                    if problems.is_empty() {
                        "all checksums and structure valid".to_string()
                    } else {
                        format!("{} problems", problems.len())
                    }
                );
            }
            if !problems.is_empty() {
                return Ok(ExitCode::from(EXIT_VERIFY_FAILED));
            }
        }
        Command::Export {
            asset,
            layer,
            level,
            style,
            band,
            output,
        } => {
            let opened = open_asset(&asset)?;
            let l = opened.layer(&layer, level)?;
            export_layer(&opened, l, &output, style, band, progress)?;
            say(format!("wrote {}", output.display()));
        }
        Command::Synth {
            kind,
            size,
            seed,
            output,
        } => {
            terrabake::synth::write_geotiff(&output, kind, size.0, size.1, seed, progress)?;
            say(format!(
                "wrote {} ({} x {} {:?}, seed {seed})",
                output.display(),
                size.0,
                size.1,
                kind
            ));
        }
        Command::Render {
            asset,
            shade: Some(shade),
            output,
            ..
        } => {
            let opened = open_asset(&asset)?;
            terrabake::shade::write_shade_png(&opened, shade, &output, 4096)?;
            say(format!("wrote {}", output.display()));
        }
        Command::Render {
            asset,
            shade: None,
            camera,
            look_at,
            view,
            fov,
            size,
            method,
            sun,
            every,
            no_shadows,
            horizon_shadows,
            exaggerate,
            output,
            stats,
            json,
        } => {
            anyhow::ensure!(
                exaggerate > 0.0 && exaggerate.is_finite(),
                "--exaggerate {exaggerate} must be a positive number"
            );
            let opened = open_asset(&asset)?;
            let tracer = Tracer::new(&opened)?;
            let mut cam = match (view, camera, look_at) {
                (Some(v), _, _) => builtin_views(&tracer, &opened)[v as usize - 1],
                (None, Some(eye), Some(look_at)) => Camera {
                    eye,
                    look_at,
                    fov: 60.0,
                },
                _ => bail!("give --view N, or --camera X,Y,Z and --look-at X,Y,Z"),
            };
            if let Some(f) = fov {
                anyhow::ensure!(
                    f > 0.0 && f < 180.0,
                    "--fov {f} is not between 0 and 180 degrees"
                );
                cam.fov = f;
            }
            let opts = RenderOptions {
                width: size.0,
                height: size.1,
                method,
                sun,
                every,
                shadows: match (no_shadows, horizon_shadows) {
                    (true, _) => Shadows::Off,
                    (false, true) => Shadows::Horizons,
                    (false, false) => Shadows::Rays,
                },
                exaggeration: exaggerate,
            };
            let (image, st) = render(&opened, &tracer, &cam, &opts)?;
            write_png(&output, &image)?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(
                        &serde_json::json!({ "camera": cam, "method": method.name(), "stats": st })
                    )?
                );
            } else if stats {
                println!(
                    "{}: {} primary + {} shadow rays in {:.3} s on {} threads: {:.0} rays/s; per primary ray {:.2} steps, {:.2} cells, {:.2} nodes pushed",
                    method.name(), st.primary_rays, st.shadow_rays, st.seconds, st.threads, st.rays_per_second, st.mean_steps, st.mean_cells, st.mean_nodes_pushed
                );
            }
            say(format!("wrote {}", output.display()));
        }
        Command::BenchViews {
            assets,
            directions: Some(n),
            methods,
            json,
            ..
        } => {
            for asset in &assets {
                let opened = open_asset(asset)?;
                let rows = terrabake::render::bench_directions(&opened, n, &methods)?;
                if json {
                    println!("{}", serde_json::to_string_pretty(&rows)?);
                } else {
                    print!("{}", terrabake::render::directions_table_markdown(&rows));
                }
            }
        }
        Command::BenchViews {
            assets,
            chart,
            size,
            every,
            methods,
            json,
            directions: None,
        } => {
            let mut results = Vec::new();
            for asset in &assets {
                let opened = open_asset(asset)?;
                let side = opened.manifest().width.max(opened.manifest().height);
                let table = terrabake::render::bench_views(&opened, size, every, &methods)?;
                if json {
                    println!(
                        "{}",
                        serde_json::to_string_pretty(
                            &serde_json::json!({ "asset": asset.display().to_string(), "side": side, "methods": table })
                        )?
                    );
                } else {
                    if assets.len() > 1 {
                        println!("\n{} ({side} posts a side)\n", asset.display());
                    }
                    print!("{}", terrabake::render::bench_table_markdown(&table));
                }
                results.push((f64::from(side), table));
            }
            if let Some(prefix) = chart {
                terrabake::render::scaling_charts(&prefix, &results)?;
                say(format!(
                    "wrote {}_steps.svg and {}_time.svg",
                    prefix.display(),
                    prefix.display()
                ));
            }
        }
        Command::Pyramid { asset, force, json } => {
            let outcome = run_stage(&asset, &PyramidStage, force)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&outcome)?);
            }
            say(describe_outcome(&outcome));
        }
        Command::Cones {
            asset,
            slices,
            apex_gap,
            encoding,
            max_memory,
            force,
            json,
        } => {
            let slices = match (slices, apex_gap) {
                (SliceChoice::Auto { .. }, gap) => SliceChoice::Auto { apex_gap: gap },
                (_, Some(_)) => bail!("--apex-gap goes with --slices auto"),
                (s, None) => s,
            };
            let stage = ConesStage {
                slices,
                encoding,
                max_memory: max_memory << 20,
            };
            let outcome = run_stage(&asset, &stage, force)?;
            let how = open_asset(&asset)?
                .manifest()
                .layer(CONE_APEX, 0)
                .map(|l| l.description.clone())
                .unwrap_or_default();
            if json {
                let mut v = serde_json::to_value(&outcome)?;
                v["planes"] = serde_json::Value::String(how.clone());
                println!("{}", serde_json::to_string_pretty(&v)?);
            }
            say(describe_outcome(&outcome));
            say(how);
        }
        Command::Horizons {
            asset,
            sectors,
            method,
            max_distance,
            curvature,
            refraction,
            aoi,
            max_error,
            encoding,
            no_narrow_check,
            direction_tolerance,
            max_memory,
            force,
            json,
        } => {
            let stage = HorizonsStage {
                sectors,
                method,
                max_distance,
                curvature,
                refraction,
                aoi,
                encoding: match encoding {
                    Some(e) => AngleChoice::Fixed(e),
                    None => AngleChoice::MaxError(max_error),
                },
                narrow_check: !no_narrow_check,
                direction_tolerance,
                max_memory: max_memory << 20,
            };
            let outcome = run_stage(&asset, &stage, force)?;
            let opened = open_asset(&asset)?;
            let entry = opened.manifest().layer(HORIZON, 0).cloned();
            if json {
                let mut v = serde_json::to_value(&outcome)?;
                if let Some(e) = &entry {
                    v["horizon"] = serde_json::json!({
                        "description": e.description,
                        "encoding": e.elem.name(),
                        "band_azimuths": e.band_azimuths,
                    });
                }
                println!("{}", serde_json::to_string_pretty(&v)?);
            }
            say(describe_outcome(&outcome));
            if let Some(e) = entry {
                say(e.description);
            }
        }
        Command::BenchHorizons {
            asset,
            counts,
            methods,
            reference,
            crop,
            speed,
            chart,
            json,
        } => {
            use terrabake::horizon::bench;
            use terrabake::horizon::terrain::{RowScale, Terrain};
            let opened = open_asset(&asset)?;
            let (z, w, h) = terrabake::horizon::read_heights(&opened)?;
            let cs = &opened.manifest().cell_size;
            let runs = speed
                .iter()
                .map(|r| {
                    let (m, k) = r.split_once(':').context("--speed takes METHOD:COUNT")?;
                    let m = <HorizonMethod as clap::ValueEnum>::from_str(m, true)
                        .map_err(|e| anyhow::anyhow!("--speed {r}: {e}"))?;
                    Ok((m, k.parse::<usize>().context("--speed METHOD:COUNT")?))
                })
                .collect::<Result<Vec<_>>>()?;
            let georef = opened.manifest().georef.as_ref();
            let row_scale = terrabake::geo::row_scale(georef, h as u32);
            let whole =
                Terrain::new(&z, w, h, cs.dx, cs.dy).with_row_scale(RowScale::new(&row_scale));
            let speed_rows = bench::speed(&whole, &runs);
            let study = bench::accuracy_study(&whole, crop, reference, &methods, &counts);
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&serde_json::json!({
                        "speed": speed_rows,
                        "crop": study.crop,
                        "reference_directions": study.reference_directions,
                        "reference_seconds": study.reference_seconds,
                        "accuracy": study.rows,
                    }))?
                );
            } else {
                print!("{}", bench::speed_table_markdown(&speed_rows));
                println!();
                println!(
                    "accuracy on a {side} x {side} crop, reference {reference} directions ({:.1} s):",
                    study.reference_seconds,
                    side = study.crop
                );
                print!("{}", bench::accuracy_table_markdown(&study.rows));
            }
            if let Some(prefix) = chart {
                bench::accuracy_charts(&prefix, &study.rows)?;
                say(format!(
                    "wrote {}_horizon.svg and {}_svf.svg",
                    prefix.display(),
                    prefix.display()
                ));
            }
        }
        Command::BenchCones {
            asset,
            slices,
            encodings,
            size,
            every,
            chart,
            json,
        } => {
            open_asset(&asset)?;
            let rows = terrabake::bench::cone_tradeoff(
                &asset, &slices, &encodings, size, every, progress,
            )?;
            if json {
                println!("{}", serde_json::to_string_pretty(&rows)?);
            } else {
                print!("{}", terrabake::bench::tradeoff_table_markdown(&rows));
            }
            if let Some(prefix) = chart {
                terrabake::bench::tradeoff_charts(&prefix, &rows)?;
                say(format!(
                    "wrote {}_steps.svg and {}_speed.svg",
                    prefix.display(),
                    prefix.display()
                ));
            }
        }
        Command::Bake {
            src,
            output,
            recipe,
            json,
        } => {
            let recipe_data = Recipe::load(&recipe)?;
            let outcomes = bake(&src, &output, &recipe_data, wait, progress)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&outcomes)?);
            }
            for o in &outcomes {
                say(describe_outcome(o));
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn describe_outcome(o: &StageOutcome) -> String {
    let what = if o.skipped {
        "up to date".to_string()
    } else {
        format!("{:.2} s", o.seconds)
    };
    format!("{:<10} {what:>12}  {}", o.stage, o.outputs.join(", "))
}

fn open_asset(path: &Path) -> Result<Asset<terrabake_format::Mmap>> {
    if !path.is_dir() {
        bail!("{}: not an asset directory", path.display());
    }
    Asset::open(path).with_context(|| format!("{}: cannot open asset", path.display()))
}

/// Human-readable summary of a manifest.
fn describe(path: &Path, m: &terrabake_format::Manifest) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let posts = u64::from(m.width) * u64::from(m.height);
    let _ = writeln!(s, "asset       {}", path.display());
    let _ = writeln!(s, "format      v{}", m.format_version);
    let _ = writeln!(
        s,
        "shape       {} x {} posts, tiles of {}",
        m.width, m.height, m.tile_size
    );
    let _ = writeln!(
        s,
        "cell size   {:.3} x {:.3} m ({})",
        m.cell_size.dx, m.cell_size.dy, m.cell_size.source
    );
    match &m.georef {
        Some(g) => {
            let epsg = g
                .epsg
                .map_or("no EPSG code".to_string(), |c| format!("EPSG:{c}"));
            let _ = writeln!(
                s,
                "georef      {:?}, {epsg}, pixel is {:?}",
                g.crs_kind, g.raster_type
            );
            let t = g.geotransform;
            let _ = writeln!(
                s,
                "            origin ({}, {}), pixel scale ({}, {})",
                t[0], t[3], t[1], t[5]
            );
        }
        None => {
            let _ = writeln!(s, "georef      none");
        }
    }
    let _ = writeln!(
        s,
        "heights     {} (x {} + {})",
        m.vertical.units, m.vertical.scale, m.vertical.offset
    );
    if let Some(r) = m.height_range {
        let _ = writeln!(s, "range       {} .. {}", r.min, r.max);
    }
    let _ = writeln!(
        s,
        "nodata      {} posts ({:.3} %), source value {}",
        m.nodata.count,
        100.0 * m.nodata.count as f64 / posts.max(1) as f64,
        m.nodata.source_value.as_deref().unwrap_or("none")
    );
    let _ = writeln!(s, "layers");
    for l in &m.layers {
        let _ = writeln!(
            s,
            "  {:<16} {:>4} x{} {:>6} x {:<6} {:?} {:>10} stored, {}/{} chunks constant  {}",
            l.key(),
            l.elem.name(),
            l.bands,
            l.width,
            l.height,
            l.codec,
            human_bytes(l.stored_bytes),
            l.constant_chunks,
            l.chunks,
            l.file
        );
        if !l.band_azimuths.is_empty() {
            let azimuths: Vec<String> = l.band_azimuths.iter().map(|a| format!("{a:.2}")).collect();
            let _ = writeln!(
                s,
                "  {:<16} band azimuths (deg): {}",
                "",
                azimuths.join(" ")
            );
        }
    }
    let _ = writeln!(
        s,
        "provenance  {} ({}, {} bytes), by {}",
        m.provenance.source, m.provenance.source_format, m.provenance.source_len, m.provenance.tool
    );
    for r in &m.provenance.stages {
        let _ = writeln!(
            s,
            "  stage {:<10} -> {}  {}",
            r.stage,
            r.outputs.join(", "),
            r.params
        );
    }
    s
}

fn human_bytes(n: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = n as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < units.len() {
        v /= 1024.0;
        u += 1;
    }
    format!("{v:.1} {}", units[u])
}
