//! The `horizons` stage: horizon angles at every post in `S` azimuths, and
//! the sky layers derived from them. `docs/HORIZONS.md` is the long form.
//!
//! **Stage.** Two cases run out of core, bands in parallel: `line` without
//! a maximum distance sweeps each direction over tile-row bands of the DEM
//! with every line's hull carried across ([`line::BandedSweep`]); `sector`
//! with one reads each tile row with the rows within reach
//! ([`sector::sector_horizons_within`]). The other cases hold the DEM in
//! memory (4 bytes per post) and one band of output per worker, within
//! `--max-memory`. Bands are written band-major (sector-major) in compass
//! order, in an order that does not depend on thread timing
//! ([`crate::plumbing::ordered`]). The derived layers (`svf`, `svf_cosine`,
//! `openness`, `horizon_edge`) are the `sky` stage's ([`crate::stages::sky`]), from
//! the committed angles. Geographic grids take their east-west spacing row
//! by row ([`terrain::RowScale`]).
//!
//! **Parts.** In a partitioned bake ([`crate::bake::partition`]) the stage splits
//! by rows within a maximum distance and by bands without one; a share
//! skips the bands and (where rows are independent) the rows it does not
//! own, and bounded `line` holds only its rows and their reach.

mod encode;
mod memory;

pub(crate) use encode::encode_angles;

use std::path::Path;
use std::sync::Mutex;

use anyhow::{Context, Result};
use rayon::prelude::*;
use terrabake_format::features::{HorizonFeatures, MAX_FEATURES};
use terrabake_format::horizons::{AngleEncoding, HORIZON};
use terrabake_format::layers::HORIZON_DISTANCE;
use terrabake_format::{Asset, Codec, LayerEntry, LayerWriter, Mmap};

use crate::algorithms::horizon::features::spikes_in_rows;
use crate::algorithms::horizon::line;
use crate::algorithms::horizon::{
    band_horizons_into, plan_bands, sector, Band, BandKind, BandOptions, Method,
};
use crate::error::bail;
use crate::plumbing::progress::Progress;
use crate::stage::args::{check_positive, Aoi};
use crate::stage::post_layer;
use crate::stage::sight::SightLines;
use crate::stage::{Share, Split, Stage};
use crate::terrain::held::read_rows;
use crate::terrain::{self, RowScale, Terrain};

/// The `horizons` stage and its parameters: `terrabake horizons` flattens
/// it, a recipe's `[[stage]] name = "horizons"` table deserialises into it
/// (unknown keys refused), and the manifest records its serialisation.
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HorizonsStage {
    /// Number of azimuths (bands), 3..=4096; band i is centred on i * 360 / S degrees (line:
    /// on the grid step nearest it, each step baked once, so a few fewer bands where
    /// neighbouring azimuths share one).
    #[arg(long, visible_alias = "directions", default_value_t = Self::DEFAULT_SECTORS, value_parser = crate::stage::args::parse_sectors)]
    pub sectors: usize,
    /// line (exact sight lines), sector (Stewart's wedges) or sampled (baseline).
    #[arg(long, default_value = Self::DEFAULT_METHOD.name(), value_parser = crate::stage::args::named(&Method::ALL, Method::name))]
    pub method: Method,
    /// How far the sight lines go and how the Earth bends them.
    #[command(flatten)]
    #[serde(flatten)]
    pub sight: SightLines,
    /// Only compute posts in columns X0..X1 and rows Y0..Y1 (end exclusive); every post of the
    /// DEM still occludes. With --max-distance the work is the area's and its reach's.
    #[arg(long, value_parser = crate::stage::args::parse_aoi)]
    pub aoi: Option<Aoi>,
    /// Largest angular error of the stored angles, degrees: picks u8 (0.354), u16 (0.0014) or
    /// f32.
    #[arg(long, default_value_t = Self::DEFAULT_MAX_ERROR_DEG, conflicts_with = "encoding", allow_hyphen_values = true, value_parser = crate::stage::args::parse_positive)]
    #[serde(rename = "max_error_deg")]
    pub max_error: f64,
    /// Store angles as u8, u16 or f32 regardless of --max-error.
    #[arg(long)]
    pub encoding: Option<AngleEncoding>,
    /// Stewart's narrow-sector check (sec. IV-E) with --method sector;
    /// `--no-narrow-check` leaves it out.
    #[arg(long = "no-narrow-check", action = clap::ArgAction::SetFalse)]
    pub narrow_check: bool,
    /// How far a line direction may sit from i * 360 / S, degrees (default: spacing / 8; less
    /// than spacing / 2). Wider takes shorter grid steps: at 16 directions on the SRTM tile in UTM,
    /// 4.5 degrees sweeps in half the time for 5 % more horizon error
    /// (docs/BENCHMARKS.md). `terrabake bake --budget` picks it from the budget.
    #[arg(long, allow_hyphen_values = true, value_parser = crate::stage::args::parse_positive)]
    pub direction_tolerance: Option<f64>,
    /// Also write `horizon_distance`: per post and band, the horizontal distance in metres to
    /// the point that sets the horizon (line: exact; sector: the steepest post of the wedge;
    /// sampled: the steepest sample).
    #[arg(long)]
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub distance: bool,
    /// Working memory in MiB for the methods that hold the DEM in memory (sector
    /// without --max-distance, sampled, line with --max-distance); a DEM that needs more
    /// is refused with the out-of-core routes named. Out of core, line's SIMD lanes take
    /// at most a quarter of it. Results do not depend on it, so it is not recorded.
    #[arg(long = "max-memory", value_name = "MIB", default_value = crate::stage::mib::STAGE_DEFAULT, value_parser = crate::stage::mib::parse)]
    #[serde(
        rename = "max_memory_mib",
        with = "crate::stage::mib",
        skip_serializing
    )]
    pub max_memory: u64,
    /// Tiles of the layers written: raw (read in place from the mapping, what a renderer
    /// wants) or zstd (smaller: horizon angles about 3x, sky and solar layers 1.5-2x;
    /// decoded into a cache on read).
    #[arg(long, value_parser = crate::stage::args::parse_codec, default_value = "raw")]
    #[serde(
        default = "crate::stage::args::raw",
        skip_serializing_if = "crate::stage::args::is_raw"
    )]
    pub codec: Codec,
    /// Also list the N posts that rise highest above their eight neighbours (lone spikes,
    /// masts, single trees) with the angles (line method, projected grids): the loader serves
    /// their exact horizon between bands, where bands alone lose them (docs/HORIZONS.md,
    /// "Features"). 0: none.
    #[arg(long, default_value_t = 0, value_name = "N")]
    #[serde(skip_serializing_if = "crate::stage::args::is_default")]
    pub features: usize,
    /// With --features: list only posts that rise at least this many metres above all eight
    /// neighbours.
    #[arg(long, value_name = "METRES", default_value_t = 0.0, requires = "features", value_parser = crate::stage::args::parse_non_negative)]
    #[serde(
        rename = "feature_rise_m",
        skip_serializing_if = "crate::stage::args::is_default"
    )]
    pub feature_rise: f64,
}

impl HorizonsStage {
    /// Bands (azimuths) unless told: 16.
    pub const DEFAULT_SECTORS: usize = 16;
    /// The largest angular error of the stored angles unless told: 0.5
    /// degrees (u8 angles, 0.354).
    pub const DEFAULT_MAX_ERROR_DEG: f64 = 0.5;
    /// The method unless told: exact sight lines.
    pub const DEFAULT_METHOD: Method = Method::Line;

    /// The encoding of the stored angles: `encoding`, else the smallest
    /// within `max_error`.
    pub(crate) fn angle_encoding(&self) -> AngleEncoding {
        self.encoding
            .unwrap_or_else(|| AngleEncoding::for_error(self.max_error))
    }
}

/// Memory of unbounded `sector` per post and sector in flight: the tree's
/// hulls and buckets, the posts' centre-plane coordinates, both orders and
/// the ranks (75-84 bytes measured at 1 M to 4.2 M posts, with the hulls
/// in one array, `sector::hulls`, the ranks handed on, `sector::Ranks`,
/// and a room of arrays each sector takes from the one before,
/// `sector::Scratch`; 77-87 before the room; about 5 more at 4.2 M posts
/// since each thread sweeps a sector and its opposite and holds both
/// bands' angles, [`opposite_pairs`]).
pub const SECTOR_BYTES_PER_POST: u64 = 96;

impl Default for HorizonsStage {
    fn default() -> Self {
        Self {
            sectors: Self::DEFAULT_SECTORS,
            method: Self::DEFAULT_METHOD,
            sight: SightLines::default(),
            aoi: None,
            max_error: Self::DEFAULT_MAX_ERROR_DEG,
            encoding: None,
            narrow_check: true,
            direction_tolerance: None,
            distance: false,
            max_memory: crate::stage::mib::STAGE_DEFAULT_BYTES,
            codec: Codec::Raw,
            features: 0,
            feature_rise: 0.0,
        }
    }
}

impl HorizonsStage {
    /// What [`Stage::check`] cannot know without the DEM: memory and the
    /// area of interest.
    /// `held` of the `h` rows are held in memory.
    fn check_dem(&self, w: usize, h: usize, held: usize) -> Result<()> {
        let threads = rayon::current_num_threads() as u64;
        if let Some(need) = self.in_core_bytes((w * held) as u64, threads) {
            if need > self.max_memory {
                let routes = match self.method {
                    Method::Sector => "give --max-distance M (bounded sectors run out of core), use --method line (exact sight lines, out of core)",
                    _ => "use --method line without --max-distance (out of core)",
                };
                bail!(
                    "--method {} holds this {w} x {h} DEM in memory: about {} MiB with {threads} bands in flight, over --max-memory {} MiB; {routes}, or raise --max-memory",
                    self.method.name(),
                    need >> 20,
                    self.max_memory >> 20
                );
            }
        }
        if let Some([x0, y0, x1, y1]) = self.aoi {
            if x0 >= x1 || y0 >= y1 || x1 as usize > w || y1 as usize > h {
                bail!("aoi = [{x0}, {y0}, {x1}, {y1}] (--aoi {x0},{y0},{x1},{y1}) is not a non-empty window of the {w} x {h} DEM");
            }
        }
        Ok(())
    }

    /// Whether the bands run out of core: `line` without a maximum
    /// distance, `sector` with one (see `row_bands`).
    pub(crate) fn out_of_core(&self) -> bool {
        matches!(
            (self.method, self.sight.max_distance),
            (Method::Line, None) | (Method::Sector, Some(_))
        )
    }

    /// How `band` is computed out of core (where [`Self::out_of_core`]):
    /// `line` without a maximum distance sweeps tile-row bands with every
    /// line's hull carried across; `sector` within a maximum distance reads
    /// each tile row with the rows within the distance.
    fn row_bands(
        &self,
        band: &Band,
        dims: (usize, usize),
        spacing: (f64, f64),
        row_scale: RowScale,
        nodata: bool,
        height_bound: f64,
    ) -> Box<dyn RowBands + Send> {
        match (&band.kind, self.sight.max_distance) {
            (BandKind::Line(dir), None) => Box::new(
                line::BandedSweep::new(dir, dims, spacing, row_scale, nodata)
                    .with_lane_memory(self.lane_bytes())
                    .with_height_bound(height_bound),
            ),
            (&BandKind::Sector { index, count }, Some(max_distance)) => Box::new(BoundedSector {
                sector: (index, count),
                narrow: self.narrow_check,
                max_distance,
                halo: terrain::posts_within(max_distance, spacing.1),
                height: dims.1,
                cols: {
                    let [x0, _, x1, _] = self.area(dims.0, dims.1);
                    x0..x1
                },
            }),
            _ => unreachable!("{:?} bands run in memory", self.method),
        }
    }

    /// The bands this stage bakes on cells of `dx x dy` metres: its
    /// directions (line grid steps within its tolerance) or sectors.
    pub fn bands(&self, dx: f64, dy: f64) -> Vec<Band> {
        plan_bands(self.method, self.sectors, dx, dy, self.direction_tolerance)
    }

    /// The area of interest, or the whole `w x h` DEM.
    pub fn area(&self, w: usize, h: usize) -> [usize; 4] {
        crate::stage::args::area_of(self.aoi, w, h)
    }

    /// The parameters the horizons stage last ran with on this asset.
    pub fn recorded(asset: &Asset<Mmap>) -> Option<Self> {
        crate::stage::recorded_params(asset.manifest(), "horizons")
    }
}

impl Stage for HorizonsStage {
    fn name(&self) -> &'static str {
        "horizons"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("parameters serialise")
    }

    fn check(&self) -> crate::Result<()> {
        if self.sectors < 3 || self.sectors > 4096 {
            bail!(
                "sectors = {0} (--sectors {0}): give 3 to 4096 (sectors must be narrower than 180 degrees)",
                self.sectors
            );
        }
        self.sight.check()?;
        check_positive(
            ("direction_tolerance", "direction-tolerance"),
            self.direction_tolerance,
        )?;
        check_positive(("max_error_deg", "max-error"), Some(self.max_error))?;
        if self.features > 0 && self.method != Method::Line {
            bail!(
                "features = {} (--features {}) with method = {}: features are served between line directions only; use --method line",
                self.features,
                self.features,
                self.method.name()
            );
        }
        if self.features > MAX_FEATURES {
            bail!(
                "features = {0} (--features {0}): give at most {MAX_FEATURES}",
                self.features
            );
        }
        if !(self.feature_rise >= 0.0 && self.feature_rise.is_finite()) {
            bail!(
                "feature_rise_m = {0} (--feature-rise {0}): give a height in metres, 0 or more",
                self.feature_rise
            );
        }
        let half = line::tolerance_limit(self.sectors);
        match self.direction_tolerance {
            Some(t) if self.method == Method::Line && t >= half => bail!(
                "direction_tolerance = {t} (--direction-tolerance {t}): give less than half the spacing of {} directions, {half} degrees (else two directions can take the same grid step)",
                self.sectors
            ),
            _ => Ok(()),
        }
    }

    fn outputs(&self, _: &terrabake_format::Manifest) -> Vec<String> {
        let mut outputs = vec![format!("{HORIZON}@0")];
        if self.distance {
            outputs.push(format!("{HORIZON_DISTANCE}@0"));
        }
        outputs
    }

    /// Out of core, [`HorizonsStage::memory_bytes`]. In core,
    /// [`HorizonsStage::in_core_bytes`], checked with the DEM's own routes
    /// out in `check_dem`.
    fn memory(&self, m: &terrabake_format::Manifest) -> Option<u64> {
        self.out_of_core().then(|| {
            self.memory_bytes(
                (m.width as usize, m.height as usize, m.tile_size as usize),
                (m.cell_size.dx, m.cell_size.dy),
                m.nodata.count > 0,
            )
        })
    }

    fn max_memory(&self) -> Option<u64> {
        Some(self.max_memory)
    }

    /// Within `max_distance`, every post reads the terrain up to that far
    /// (the shortest post spacing, row by row on geographic grids, sets how
    /// many posts that is, plus one for the cell a sight line ends in);
    /// without it, the whole DEM.
    fn reach(&self, m: &terrabake_format::Manifest) -> crate::stage::Reach {
        let Some(d) = self.sight.max_distance else {
            return crate::stage::Reach::Whole;
        };
        let scale = crate::terrain::geo::row_scale(m.georef.as_ref(), m.height);
        let narrowest = scale.iter().copied().fold(1.0f64, f64::min);
        let spacing = (m.cell_size.dx * narrowest).min(m.cell_size.dy);
        // A post of margin: the sight line's surface between the last post
        // within the distance and the next.
        let posts = terrain::posts_within(d, spacing) + 1;
        if posts >= m.width.max(m.height) as usize {
            crate::stage::Reach::Whole
        } else {
            crate::stage::Reach::Posts(posts as u32)
        }
    }

    /// Within a maximum distance, by rows; without one, by bands: each
    /// direction (or sector) is independent of the others, and runs over
    /// the whole DEM out of core (line) or in memory (sector, sampled).
    fn split(&self, m: &terrabake_format::Manifest) -> Split {
        match self.reach(m) {
            crate::stage::Reach::Posts(halo) => Split::Rows { halo },
            crate::stage::Reach::Whole => Split::Bands,
        }
    }

    /// Bands outside the share are not computed; rows outside it are not
    /// where the rows are independent (bounded `line` and `sector`).
    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        share: &Share,
        progress: Progress,
    ) -> crate::Result<Vec<LayerEntry>> {
        let m = asset.manifest();
        let height = asset.height()?;
        let (w, h, ts) = (
            height.width() as usize,
            height.height() as usize,
            height.tile_size() as usize,
        );
        // Posts outside the area of interest are NaN, so only its rows (of
        // the share's) are computed where rows are independent, and only
        // its columns by bounded `line`.
        let aoi = self.area(w, h);
        let rows = share.rows_within(h, aoi[1]..aoi[3]);
        let cols = aoi[0]..aoi[2];
        // Bounded `line` holds only the rows it computes and those within
        // reach of them (a part of a partitioned bake: its share; an area of
        // interest); the other in-memory methods the whole DEM.
        let window = match (self.method, self.reach(m)) {
            (Method::Line, crate::stage::Reach::Posts(r)) => {
                rows.start.saturating_sub(r as usize)..(rows.end + r as usize).min(h)
            }
            _ => 0..h,
        };
        self.check_dem(w, h, window.len())?;
        let curvature = self.sight.curvature_coefficient(m);
        let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
        let row_scale = crate::terrain::geo::row_scale(m.georef.as_ref(), h as u32);
        let row_scale = RowScale::new(&row_scale);
        let bands = self.bands(dx, dy);
        let enc = self.angle_encoding();
        let method_text = match self.method {
            Method::Line => "line: steepest sight line along the grid direction of the band (exact on the two-triangle surface)",
            Method::Sector => if self.narrow_check {
                "sector: Stewart's maximum over the closed wedge, with the IV-E narrow-sector check"
            } else {
                "sector: Stewart's maximum over the closed wedge, without the IV-E check"
            },
            Method::Sampled => "sampled: centre-line sampling, nearest post, one spacing per step (baseline)",
        };
        let description = format!(
            "horizon elevation angle, degrees, band per azimuth (band_azimuths), {}; {method_text}; curvature {}",
            enc.name(),
            if curvature > 0.0 { format!("on, refraction {}", self.sight.refraction) } else { "off".into() }
        );
        // A writer of one of the stage's layers (band per azimuth), masked
        // to the area of interest.
        let band_writer =
            |name: &str, enc: AngleEncoding, description: String| -> Result<BandWriter> {
                let spec = post_layer(
                    (name, "horizons"),
                    enc.elem(),
                    bands.len() as u32,
                    (w, h, ts),
                    description,
                    self.codec,
                );
                Ok(BandWriter {
                    codec: self.codec,
                    writer: Mutex::new(LayerWriter::create(dir, spec)?),
                    enc,
                    width: w,
                    tile_size: ts,
                    tiles: (w.div_ceil(ts), h.div_ceil(ts)),
                    aoi,
                })
            };
        let out = band_writer(HORIZON, enc, description)?;
        // Distances: f32 metres, written beside the angles.
        let distances = self
            .distance
            .then(|| band_writer(
                HORIZON_DISTANCE,
                AngleEncoding::F32,
                format!("horizontal distance to the point that sets the horizon, metres, band per azimuth (band_azimuths) as {HORIZON}; NaN for nodata and where no terrain lies ahead; {method_text}"),
            ))
            .transpose()?;
        let mine = share.bands(bands.len());
        // Tile rows outside the share's rows (all of them for bands outside
        // its bands) hold the fill value.
        for b in (0..bands.len()).filter(|b| !mine.contains(b)) {
            for y0 in (0..h).step_by(ts) {
                out.push(b, y0, None)?;
                if let Some(d) = &distances {
                    d.push(b, y0, None)?;
                }
            }
        }
        let bar = progress.bar(mine.len() as u64, "horizons", "bands");
        let opts = BandOptions {
            max_distance: self.sight.max_distance,
            narrow_check: self.narrow_check,
        };
        let nodata = m.nodata.count > 0;
        // No post is higher: what lets a line's hull drop far vertices.
        let highest = m.height_range.map_or(f64::INFINITY, |r| f64::from(r.max));
        let run = Run {
            height,
            dims: (w, h, ts),
            rows,
            cols,
            window,
            spacing: (dx, dy),
            row_scale,
            curvature,
            bands: &bands,
            mine,
            out: &out,
            distances: distances.as_ref(),
            opts,
            bar: &bar,
        };
        // Before the sweeps: a grid that cannot serve them is refused first.
        let features = (self.features > 0)
            .then(|| self.find_features(&run, !row_scale.is_uniform()))
            .transpose()?;
        if self.out_of_core() {
            self.sweep_out_of_core(&run, nodata, highest)?;
        } else {
            self.sweep_in_core(&run)?;
        }
        bar.finish_and_clear();
        let azimuths: Vec<f64> = bands.iter().map(|b| b.azimuth).collect();
        let mut horizon = out.finish(&azimuths)?;
        horizon.features = features;
        let mut layers = vec![horizon];
        if let Some(d) = distances {
            layers.push(d.finish(&azimuths)?);
        }
        Ok(layers)
    }
}

/// One run of the stage: what its two routes, out of core and in memory,
/// share.
struct Run<'a> {
    height: &'a terrabake_format::Layer<Mmap>,
    /// Width, height and tile size, posts.
    dims: (usize, usize, usize),
    /// The rows and columns computed (the share's, within the area of
    /// interest), and the rows held (those and their reach).
    rows: std::ops::Range<usize>,
    cols: std::ops::Range<usize>,
    window: std::ops::Range<usize>,
    spacing: (f64, f64),
    row_scale: RowScale<'a>,
    curvature: f64,
    bands: &'a [Band],
    /// The share's bands.
    mine: std::ops::Range<usize>,
    out: &'a BandWriter,
    distances: Option<&'a BandWriter>,
    opts: BandOptions,
    bar: &'a indicatif::ProgressBar,
}

impl<'a> Run<'a> {
    /// The DEM's `rows`, whole (NaN for nodata).
    fn read_rows(&self, rows: std::ops::Range<usize>) -> Result<Vec<f32>> {
        read_rows(self.height, rows)
    }

    /// `z`, rows `row0..` of the DEM, as the algorithms see them: the
    /// grid's spacing, row scales and curvature.
    fn terrain<'z>(&self, z: &'z [f32], row0: usize) -> Terrain<'z>
    where
        'a: 'z,
    {
        let (w, h, _) = self.dims;
        Terrain::window(z, (w, h), row0, self.spacing)
            .with_row_scale(self.row_scale)
            .with_curvature(self.curvature)
    }

    /// Whether the tile row at `y0` holds rows of the share (the others
    /// hold the fill value).
    fn wanted(&self, y0: usize) -> bool {
        y0 < self.rows.end && y0 + self.dims.2 > self.rows.start
    }
}

impl HorizonsStage {
    /// The posts the loader serves exactly between bands: the whole DEM's
    /// highest-rising spikes (every part of a partitioned bake lists the
    /// same), read a tile row at a time.
    fn find_features(&self, run: &Run, geographic: bool) -> Result<HorizonFeatures> {
        if geographic {
            return Err(crate::error::mark(
                crate::ErrorKind::Parameters,
                anyhow::anyhow!(
                    "features = {0} (--features {0}): features are served on grids of uniform spacing only, and this DEM is latitude/longitude; reproject it (gdalwarp -t_srs EPSG:...) or leave --features out",
                    self.features
                ),
            ));
        }
        let (_, h, ts) = run.dims;
        let mut found = Vec::new();
        for y0 in (0..h).step_by(ts) {
            let rows = y0..(y0 + ts).min(h);
            let held = y0.saturating_sub(1)..(rows.end + 1).min(h);
            let z = run.read_rows(held.clone())?;
            let t = run.terrain(&z, held.start);
            spikes_in_rows(
                &t,
                rows,
                self.feature_rise as f32,
                self.features,
                &mut found,
            );
        }
        Ok(HorizonFeatures {
            curvature: run.curvature,
            max_distance: self.sight.max_distance,
            posts: found.into_iter().map(|s| s.post).collect(),
        })
    }

    /// Bands in batches of a fixed size, each batch's sweeps run tile row
    /// by tile row on every core and written in a fixed order
    /// (`crate::plumbing::ordered`): the layer's bytes are the same on
    /// every run and any number of threads.
    fn sweep_out_of_core(&self, run: &Run, nodata: bool, highest: f64) -> Result<()> {
        let (w, h, ts) = run.dims;
        let (dx, dy) = run.spacing;
        let row_scale = run.row_scale;
        let (bands, mine, out, distances, bar) =
            (run.bands, run.mine.clone(), run.out, run.distances, run.bar);
        let wanted = |y0: usize| run.wanted(y0);
        let threads = rayon::current_num_threads();
        let first = mine.start;
        for (b, batch) in bands[mine.clone()].chunks(OUT_OF_CORE_BATCH).enumerate() {
            // Each sweep with its row bands, in the order it must take them.
            let sweeps: Vec<_> = batch
                .iter()
                .map(|band| {
                    let sweep = self.row_bands(band, (w, h), (dx, dy), row_scale, nodata, highest);
                    let rows = sweep.bands(ts);
                    (sweep, rows)
                })
                .collect();
            let steps = crate::terrain::tiling::row_bands(h, ts).len();
            crate::plumbing::ordered::steps_in_order(
                sweeps,
                steps,
                threads,
                |(sweep, bands), k| {
                    let rows = bands[k].clone();
                    if sweep.independent() && !wanted(rows.start) {
                        return Ok((rows.start, None, None));
                    }
                    let window = sweep.window(&rows);
                    let rows_buf = run.read_rows(window.clone())?;
                    let terrain = run.terrain(&rows_buf, window.start);
                    let mut angles = vec![0f32; rows.len() * w];
                    let mut metres = distances.as_ref().map(|_| vec![0f32; rows.len() * w]);
                    sweep.sweep(&terrain, rows.clone(), &mut angles, metres.as_deref_mut());
                    let metres = distances
                        .as_ref()
                        .zip(metres.as_mut())
                        .map(|(d, m)| d.encode(rows.start, m));
                    Ok((
                        rows.start,
                        Some(out.encode(rows.start, &mut angles)),
                        metres,
                    ))
                },
                |j, k, (y0, tiles, metres)| {
                    let band = first + b * OUT_OF_CORE_BATCH + j;
                    if let Some(d) = &distances {
                        d.push(band, y0, metres)?;
                    }
                    out.push(band, y0, tiles)?;
                    if k + 1 == steps {
                        bar.inc(1);
                    }
                    Ok(())
                },
            )?;
        }
        Ok(())
    }

    /// Every band of the share over the DEM (or the window of it bounded
    /// lines need) held in memory, the bands of a batch in parallel.
    fn sweep_in_core(&self, run: &Run) -> Result<()> {
        let (w, h, ts) = run.dims;
        let (bands, mine, out, distances, bar, opts) = (
            run.bands,
            run.mine.clone(),
            run.out,
            run.distances,
            run.bar,
            run.opts,
        );
        let (rows, cols, window) = (&run.rows, &run.cols, &run.window);
        let wanted = |y0: usize| run.wanted(y0);
        let z = run.read_rows(window.clone())?;
        let terrain = run.terrain(&z, window.start);
        let threads = rayon::current_num_threads().max(1);
        let mut tile_row = vec![0f32; ts * w];
        // A band's values over the window into `writer`, tile row by
        // tile row (NaN outside the window, fill outside the share).
        let mut write_band = |writer: &BandWriter, band: usize, values: &[f32]| -> Result<()> {
            for y0 in (0..h).step_by(ts) {
                if !wanted(y0) {
                    writer.push(band, y0, None)?;
                    continue;
                }
                let tile_row = &mut tile_row[..ts.min(h - y0) * w];
                for (r, row) in tile_row.chunks_mut(w).enumerate() {
                    match (y0 + r)
                        .checked_sub(window.start)
                        .filter(|&i| i < window.len())
                    {
                        Some(i) => row.copy_from_slice(&values[i * w..(i + 1) * w]),
                        None => row.fill(f32::NAN),
                    }
                }
                writer.write(band, y0, tile_row)?;
            }
            Ok(())
        };
        // Unbounded sectors hand their sorted orders on: each sweeps
        // beside its opposite (whose ranks are its own reversed), a
        // batch's pairs sort their ranks side by side, and each sector
        // takes its processing order from the sector before
        // (`sector::Ranks`).
        let sector = |band: &Band| match band.kind {
            BandKind::Sector { index, count } if opts.max_distance.is_none() => {
                Some((index, count))
            }
            _ => None,
        };
        let posts = bands[mine.clone()]
            .iter()
            .any(|b| sector(b).is_some())
            .then(|| sector::DataPosts::of(&terrain));
        // The last pair's ranks, for the first pair of the next batch.
        let mut previous: Vec<sector::Ranks> = Vec::new();
        // Each of a batch's pairs sorts and sweeps in the room the same
        // place in the batch before left (`sector::Scratch`).
        let rooms: Vec<sector::Scratch> = (0..threads).map(|_| Default::default()).collect();
        for batch in opposite_pairs(bands, mine.clone()).chunks(threads) {
            let ranks: Vec<Vec<sector::Ranks>> = batch
                .par_iter()
                .zip(&rooms)
                .map(|(pair, room)| {
                    let Some(posts) = posts.as_ref() else {
                        return Vec::new();
                    };
                    let sort = |s| sector::Ranks::of_in(&terrain, posts, s, room);
                    let first = sector(&bands[pair[0]]).map(sort);
                    // The second is the first's opposite ([`opposite_pairs`]).
                    let second = pair.get(1).and_then(|&b| sector(&bands[b])).map(|s| {
                        first
                            .as_ref()
                            .and_then(sector::Ranks::opposite)
                            .unwrap_or_else(|| sort(s))
                    });
                    first.into_iter().chain(second).collect()
                })
                .collect();
            let known: Vec<&sector::Ranks> = ranks.iter().flatten().chain(&previous).collect();
            let find = |s: Option<(usize, usize)>| {
                let s = s?;
                known.iter().copied().find(|r| r.sector() == s)
            };
            type Swept = (usize, Vec<f32>, Option<Vec<f32>>);
            let results: Vec<Vec<Swept>> = batch
                .par_iter()
                .zip(&rooms)
                .map(|(pair, room)| {
                    let sweep = |&b: &usize| {
                        let band = &bands[b];
                        let mut angles = vec![0f32; terrain.z.len()];
                        let mut metres = distances.as_ref().map(|_| vec![0f32; angles.len()]);
                        let s = sector(band);
                        let shared = sector::Shared {
                            posts: posts.as_ref(),
                            ranks: find(s),
                            previous: find(s.map(|(i, n)| ((i + n - 1) % n, n))),
                            scratch: Some(room),
                        };
                        band_horizons_into(
                            &terrain,
                            band,
                            opts,
                            [rows.clone(), cols.clone()],
                            (&mut angles, metres.as_deref_mut()),
                            shared,
                        );
                        (b, angles, metres)
                    };
                    pair.iter().map(sweep).collect()
                })
                .collect();
            drop(known);
            previous = ranks.into_iter().next_back().unwrap_or_default();
            for (band, angles, metres) in results.into_iter().flatten() {
                write_band(out, band, &angles)?;
                if let (Some(d), Some(metres)) = (&distances, metres) {
                    write_band(d, band, &metres)?;
                }
                bar.inc(1);
            }
        }
        Ok(())
    }
}

/// The bands of `mine` in the order an in-core bake sweeps them: each
/// sector of an even count followed by the opposite one where that is in
/// `mine` too (its ranks are the first's reversed, `sector::Ranks`), else
/// alone. Fixed by the bands alone, not the thread count, so that the
/// file is the same on every machine.
fn opposite_pairs(bands: &[Band], mine: std::ops::Range<usize>) -> Vec<Vec<usize>> {
    // Band `i` of sectors is sector `i` ([`plan_bands`]).
    let opposite = |b: usize| match bands[b].kind {
        BandKind::Sector { index, count } if count.is_multiple_of(2) && index == b => {
            Some((index + count / 2) % count).filter(|o| mine.contains(o))
        }
        _ => None,
    };
    let mut placed = vec![false; bands.len()];
    let mut pairs = Vec::new();
    for b in mine.clone() {
        if placed[b] {
            continue;
        }
        placed[b] = true;
        let mut pair = vec![b];
        if let Some(o) = opposite(b).filter(|&o| !placed[o]) {
            placed[o] = true;
            pair.push(o);
        }
        pairs.push(pair);
    }
    pairs
}

/// Bands swept together out of core (their sweeps are alive at once). Fixed,
/// not the thread count, so that the file is the same on every machine;
/// eight keep two to eight cores busy.
const OUT_OF_CORE_BATCH: usize = 8;

/// One band computed out of core: output rows in bands, each from a window
/// of the DEM's rows, in the order the bands must go.
trait RowBands {
    /// The bands of at most `rows` output rows, in order.
    fn bands(&self, rows: usize) -> Vec<std::ops::Range<usize>>;
    /// The DEM rows that output rows `band` need.
    fn window(&self, band: &std::ops::Range<usize>) -> std::ops::Range<usize>;
    /// Angles of output rows `band` from `window`, the rows [`Self::window`]
    /// named, and their distances to the horizon where asked.
    fn sweep(
        &mut self,
        window: &Terrain,
        band: std::ops::Range<usize>,
        out: &mut [f32],
        distances: Option<&mut [f32]>,
    );
    /// Whether a band of rows can be computed without the bands before it
    /// (a partitioned bake skips the rows another part computes).
    fn independent(&self) -> bool;
}

impl RowBands for line::BandedSweep {
    fn bands(&self, rows: usize) -> Vec<std::ops::Range<usize>> {
        line::BandedSweep::bands(self, rows)
    }

    fn window(&self, band: &std::ops::Range<usize>) -> std::ops::Range<usize> {
        line::BandedSweep::window(self, band)
    }

    fn sweep(
        &mut self,
        window: &Terrain,
        band: std::ops::Range<usize>,
        out: &mut [f32],
        distances: Option<&mut [f32]>,
    ) {
        line::BandedSweep::sweep_with_distances(self, window, band, out, distances)
    }

    /// Every line's hull is carried from band to band.
    fn independent(&self) -> bool {
        false
    }
}

/// `sector` within a maximum distance: every post depends only on the rows
/// within the distance, so bands go north to south, each reading `halo`
/// rows either side.
struct BoundedSector {
    sector: (usize, usize),
    narrow: bool,
    max_distance: f64,
    halo: usize,
    height: usize,
    /// The area of interest's columns (the others are NaN).
    cols: std::ops::Range<usize>,
}

impl RowBands for BoundedSector {
    fn bands(&self, rows: usize) -> Vec<std::ops::Range<usize>> {
        crate::terrain::tiling::row_bands(self.height, rows)
    }

    fn window(&self, band: &std::ops::Range<usize>) -> std::ops::Range<usize> {
        band.start.saturating_sub(self.halo)..(band.end + self.halo).min(self.height)
    }

    fn sweep(
        &mut self,
        window: &Terrain,
        band: std::ops::Range<usize>,
        out: &mut [f32],
        distances: Option<&mut [f32]>,
    ) {
        sector::sector_horizons_within(
            window,
            self.sector,
            self.narrow,
            self.max_distance,
            [band, self.cols.clone()],
            out,
            distances,
        );
    }

    fn independent(&self) -> bool {
        true
    }
}

/// Writes a band's rows of angles into the horizon layer as they come (in
/// any order), masked to the area of interest.
struct BandWriter {
    writer: Mutex<LayerWriter>,
    enc: AngleEncoding,
    codec: Codec,
    width: usize,
    tile_size: usize,
    tiles: (usize, usize),
    aoi: [usize; 4],
}

impl BandWriter {
    /// The layer's entry, with its quantisation and band azimuths.
    fn finish(self, azimuths: &[f64]) -> Result<LayerEntry> {
        let mut entry = self
            .writer
            .into_inner()
            .expect("no panic while writing")
            .finish()?;
        entry.quantization = self.enc.quantization();
        entry.band_azimuths = azimuths.to_vec();
        Ok(entry)
    }

    /// Rows `y0..` of band `band` (whole tile rows, `y0` on a tile edge).
    fn write(&self, band: usize, y0: usize, angles: &mut [f32]) -> Result<()> {
        let tiles = self.encode(y0, angles);
        self.push(band, y0, Some(tiles))
    }

    /// The tiles of rows `y0..` of angles, masked to the area of interest.
    fn encode(&self, y0: usize, angles: &mut [f32]) -> Vec<terrabake_format::EncodedTile> {
        let (w, ts, [x0, ay0, x1, ay1]) = (self.width, self.tile_size, self.aoi);
        for (r, row) in angles.chunks_mut(w).enumerate() {
            if (ay0..ay1).contains(&(y0 + r)) {
                row[..x0.min(w)].fill(f32::NAN);
                row[x1.min(w)..].fill(f32::NAN);
            } else {
                row.fill(f32::NAN);
            }
        }
        encode_angles(self.enc, angles, w, ts, self.codec)
    }

    /// Appends the tiles of the tile row at `y0` of band `band` (`None`:
    /// fill, a row another part of a partitioned bake computes).
    fn push(
        &self,
        band: usize,
        y0: usize,
        tiles: Option<Vec<terrabake_format::EncodedTile>>,
    ) -> Result<()> {
        let ty = y0 / self.tile_size;
        let chunk = |tx: usize| ((band * self.tiles.1 + ty) * self.tiles.0 + tx) as u64;
        let mut writer = self.writer.lock().expect("no panic while writing");
        match tiles {
            Some(tiles) => {
                for (tx, tile) in tiles.into_iter().enumerate() {
                    writer.push_at(chunk(tx), tile)?;
                }
            }
            None => {
                for tx in 0..self.tiles.0 {
                    writer.push_fill_at(chunk(tx))?;
                }
            }
        }
        Ok(())
    }
}

/// All bands of the `horizon` layer decoded to degrees, band-major.
pub fn read_horizons(asset: &Asset<Mmap>) -> crate::Result<(Vec<Vec<f32>>, Vec<f64>)> {
    let map = terrabake_format::horizons::HorizonMap::open(asset)
        .context("the asset has no usable horizon layer; run `terrabake horizons` first")?;
    let layer = asset.layer(HORIZON, 0)?;
    let bands = (0..layer.bands())
        .map(|b| {
            let mut v = vec![0f32; layer.width() as usize * layer.height() as usize];
            layer.read_rows_f32(b, 0, &mut v)?;
            Ok(v)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok((bands, map.azimuths().to_vec()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each sector is swept beside its opposite where the share holds
    /// both, else alone; other methods' bands and odd counts alone.
    #[test]
    fn opposite_sectors_pair_within_a_share() {
        let pairs = |method, count, mine| {
            opposite_pairs(&plan_bands(method, count, 30.0, 30.0, None), mine)
        };
        assert_eq!(
            pairs(Method::Sector, 8, 0..8),
            [[0, 4], [1, 5], [2, 6], [3, 7]]
        );
        assert_eq!(
            pairs(Method::Sector, 8, 2..7),
            [vec![2, 6], vec![3], vec![4], vec![5]]
        );
        assert_eq!(pairs(Method::Sector, 8, 5..8), [[5], [6], [7]]);
        assert_eq!(
            pairs(Method::Sector, 7, 0..7),
            (0..7).map(|b| vec![b]).collect::<Vec<_>>()
        );
        assert_eq!(
            pairs(Method::Line, 8, 0..8),
            (0..8).map(|b| vec![b]).collect::<Vec<_>>()
        );
    }
}
