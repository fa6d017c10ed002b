//! The `horizons` stage: horizon angles at every post in `S` azimuths, and
//! the sky layers derived from them. `docs/HORIZONS.md` is the long form.
//!
//! Three methods, each exact for its own definition (see the modules):
//!
//! - [`line`](mod@line): the steepest sight line along the straight line from the
//!   post, on the surface the tracers use (Timonen 2013's sweeps, along grid
//!   directions so that every post is on a line);
//! - [`sector`]: Stewart's (1998) maximum over the closed azimuth wedge,
//!   with his tree of upper convex hulls;
//! - [`sampled`]: centre-line sampling with nearest-post heights, the
//!   baseline other tools use (comparison only).
//!
//! [`brute`] has one-post-at-a-time references for `line` and `sector`,
//! which the tests hold the fast algorithms to.
//!
//! **Stage.** Two cases run out of core, bands in parallel: `line` without
//! a maximum distance sweeps each direction over tile-row bands of the DEM
//! with every line's hull carried across ([`line::BandedSweep`]); `sector`
//! with one reads each tile row with the rows within reach
//! ([`sector::sector_horizons_within`]). The other cases hold the DEM in
//! memory (4 bytes per post) and one band of output per worker, within
//! `--max-memory`. Bands are written band-major (sector-major) in compass
//! order; the derived layers (`svf`, `svf_cosine`, `openness`,
//! `horizon_edge`) are then computed tile row by tile row from the stored
//! angles (`sky_layers`). Geographic grids take their east-west spacing
//! row by row ([`terrain::RowScale`]).

pub mod bench;
pub mod brute;
pub mod hull_tree;
pub mod line;
pub mod sampled;
pub mod sector;
pub mod sky;
pub mod terrain;

use std::path::Path;
use std::sync::Mutex;

use anyhow::{bail, Context, Result};
use rayon::prelude::*;
use terrabake_format::horizons::{
    edge_distance, AngleEncoding, HORIZON, HORIZON_EDGE, OPENNESS, SVF, SVF_COSINE,
};
use terrabake_format::manifest::CrsKind;
use terrabake_format::{Asset, Codec, LayerEntry, LayerSpec, LayerWriter, Mmap};

use crate::progress::Progress;
use crate::stage::Stage;
use crate::tiling::{encode_tile_row, push_tile_row};
use line::GridDirection;
use terrain::{RowScale, Terrain};

/// Which definition of the horizon.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Steepest sight line along the line in each direction (exact, fast).
    Line,
    /// Stewart's sector maximum over each closed azimuth wedge (exact).
    Sector,
    /// Centre-line sampling, nearest post (baseline, approximate).
    Sampled,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Line => "line",
            Method::Sector => "sector",
            Method::Sampled => "sampled",
        }
    }
}

/// One output band: what it looks at and the azimuth interval it covers.
#[derive(Debug, Clone)]
pub struct Band {
    /// Compass azimuth of the band, degrees.
    pub azimuth: f64,
    /// The azimuth interval the band stands for (`lo < hi`, may wrap).
    pub lo: f64,
    pub hi: f64,
    pub kind: BandKind,
}

#[derive(Debug, Clone)]
pub enum BandKind {
    Line(GridDirection),
    Sector { index: usize, count: usize },
    Sampled,
}

/// The azimuth interval each band stands for: half way to its neighbours
/// (for sectors, exactly the sector).
pub fn band_bounds(azimuths: &[f64]) -> Vec<(f64, f64)> {
    let n = azimuths.len();
    (0..n)
        .map(|i| {
            let back = (azimuths[i] - azimuths[(i + n - 1) % n]).rem_euclid(360.0);
            let ahead = (azimuths[(i + 1) % n] - azimuths[i]).rem_euclid(360.0);
            (azimuths[i] - back / 2.0, azimuths[i] + ahead / 2.0)
        })
        .collect()
}

/// The bands of `count` azimuths for `method` on posts `dx x dy` apart.
/// `tolerance`: how far (degrees) a line direction may sit from its nominal
/// azimuth (default: an eighth of the spacing).
pub fn plan_bands(
    method: Method,
    count: usize,
    dx: f64,
    dy: f64,
    tolerance: Option<f64>,
) -> Vec<Band> {
    let kinds: Vec<(f64, BandKind)> = match method {
        Method::Sector => (0..count)
            .map(|i| {
                (
                    i as f64 * 360.0 / count as f64,
                    BandKind::Sector { index: i, count },
                )
            })
            .collect(),
        Method::Sampled => (0..count)
            .map(|i| (i as f64 * 360.0 / count as f64, BandKind::Sampled))
            .collect(),
        Method::Line => {
            let tol = tolerance.unwrap_or_else(|| line::default_tolerance(count));
            line::grid_directions(count, dx, dy, tol)
                .into_iter()
                .map(|d| (d.azimuth, BandKind::Line(d)))
                .collect()
        }
    };
    let azimuths: Vec<f64> = kinds.iter().map(|k| k.0).collect();
    kinds
        .into_iter()
        .zip(band_bounds(&azimuths))
        .map(|((azimuth, kind), (lo, hi))| Band {
            azimuth,
            lo,
            hi,
            kind,
        })
        .collect()
}

/// Options that change every band's values; the default is exact: the
/// whole DEM, with Stewart's narrow-sector check.
#[derive(Debug, Clone, Copy)]
pub struct BandOptions {
    /// Metres; `None`: the whole DEM (exact).
    pub max_distance: Option<f64>,
    /// Stewart's narrow-sector check (sec. IV-E), for `sector`.
    pub narrow_check: bool,
}

impl Default for BandOptions {
    fn default() -> Self {
        Self {
            max_distance: None,
            narrow_check: true,
        }
    }
}

/// The horizon angles (degrees; NaN for nodata) of one band at every post,
/// and a count of the work done (hull vertices, tree steps or samples).
pub fn band_horizons(terrain: &Terrain, band: &Band, opts: BandOptions) -> (Vec<f32>, u64) {
    let mut out = vec![0f32; terrain.z.len()];
    let work = match &band.kind {
        BandKind::Line(dir) => match opts.max_distance {
            None => line::line_horizons(terrain, dir, &mut out).vertices,
            Some(max) => {
                let stencil = line::Stencil::new(dir.step);
                let lengths = line::step_lengths(
                    dir.step,
                    terrain.height,
                    (terrain.dx, terrain.dy),
                    terrain.row_scale,
                );
                out.par_chunks_mut(terrain.width)
                    .enumerate()
                    .for_each(|(row, out)| {
                        for (col, v) in out.iter_mut().enumerate() {
                            *v = line::line_horizon_within(
                                terrain,
                                &stencil,
                                &lengths,
                                (col as i64, row as i64),
                                max,
                            );
                        }
                    });
                0
            }
        },
        BandKind::Sector { index, count } => {
            let s = match opts.max_distance {
                None => {
                    sector::sector_horizons(terrain, *index, *count, opts.narrow_check, &mut out)
                }
                Some(max) => sector::sector_horizons_within(
                    terrain,
                    (*index, *count),
                    opts.narrow_check,
                    max,
                    0..terrain.height,
                    &mut out,
                ),
            };
            s.tangent_steps + s.inserts
        }
        BandKind::Sampled => {
            sampled::sampled_horizons(
                terrain,
                band.azimuth,
                opts.max_distance.unwrap_or(f64::INFINITY),
                &mut out,
            );
            0
        }
    };
    (out, work)
}

/// How the stage stores angles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AngleChoice {
    Fixed(AngleEncoding),
    /// The smallest encoding within this many degrees.
    MaxError(f64),
}

impl AngleChoice {
    pub fn resolve(self) -> AngleEncoding {
        match self {
            AngleChoice::Fixed(e) => e,
            AngleChoice::MaxError(err) => AngleEncoding::for_error(err),
        }
    }
}

/// An area of interest in posts: columns `x0..x1`, rows `y0..y1`.
pub type Aoi = [u32; 4];

/// The `horizons` stage.
#[derive(Debug, Clone)]
pub struct HorizonsStage {
    pub sectors: usize,
    pub method: Method,
    pub max_distance: Option<f64>,
    /// `None`: on for georeferenced DEMs, off otherwise.
    pub curvature: Option<bool>,
    pub refraction: f64,
    pub aoi: Option<Aoi>,
    pub encoding: AngleChoice,
    pub narrow_check: bool,
    pub direction_tolerance: Option<f64>,
    /// Bytes the methods that hold the DEM in memory may use; more is an
    /// error that names the out-of-core routes. Results do not depend on it.
    pub max_memory: u64,
}

/// Memory of unbounded `sector` per post and sector in flight: the tree's
/// hulls and buckets, the posts' centre-plane coordinates, both orders and
/// the ranks (65-75 bytes measured at 1.44 M and 16.7 M posts).
pub const SECTOR_BYTES_PER_POST: u64 = 80;

impl Default for HorizonsStage {
    fn default() -> Self {
        Self {
            sectors: 16,
            method: Method::Line,
            max_distance: None,
            curvature: None,
            refraction: terrain::DEFAULT_REFRACTION,
            aoi: None,
            encoding: AngleChoice::MaxError(0.5),
            narrow_check: true,
            direction_tolerance: None,
            max_memory: 8 << 30,
        }
    }
}

/// Reads the whole `height` layer (NaN for nodata).
pub fn read_heights(asset: &Asset<Mmap>) -> Result<(Vec<f32>, usize, usize)> {
    let height = asset.height()?;
    let (w, h) = (height.width(), height.height());
    let mut z = vec![0f32; w as usize * h as usize];
    height.read_window(0, 0, 0, w, h, &mut z)?;
    Ok((z, w as usize, h as usize))
}

impl HorizonsStage {
    fn check(&self, w: usize, h: usize) -> Result<()> {
        if self.sectors < 3 || self.sectors > 4096 {
            bail!(
                "--sectors {}: give 3 to 4096 (sectors must be narrower than 180 degrees)",
                self.sectors
            );
        }
        if let Some(d) = self.max_distance {
            if d.is_nan() || d <= 0.0 {
                bail!("--max-distance {d}: give a positive distance in metres");
            }
        }
        let threads = rayon::current_num_threads() as u64;
        if let Some(need) = self.in_core_bytes((w * h) as u64, threads) {
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
                bail!("--aoi {x0},{y0},{x1},{y1} is not a non-empty window of the {w} x {h} DEM");
            }
        }
        Ok(())
    }

    /// Bytes held in memory for `posts` posts with `threads` bands in
    /// flight, or `None` where the method runs out of core: the DEM (4
    /// bytes per post) and per band Stewart's tree ([`SECTOR_BYTES_PER_POST`])
    /// or one band of angles.
    pub fn in_core_bytes(&self, posts: u64, threads: u64) -> Option<u64> {
        let per_band = match self.method {
            Method::Sector => SECTOR_BYTES_PER_POST,
            Method::Line | Method::Sampled => 4,
        };
        (!self.out_of_core()).then_some(posts * (4 + per_band * threads))
    }

    /// Whether the bands run out of core: `line` without a maximum
    /// distance, `sector` with one ([`Self::row_bands`]).
    pub fn out_of_core(&self) -> bool {
        matches!(
            (self.method, self.max_distance),
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
    ) -> Box<dyn RowBands + Send> {
        match (&band.kind, self.max_distance) {
            (BandKind::Line(dir), None) => Box::new(line::BandedSweep::new(
                dir, dims, spacing, row_scale, nodata,
            )),
            (&BandKind::Sector { index, count }, Some(max_distance)) => Box::new(BoundedSector {
                sector: (index, count),
                narrow: self.narrow_check,
                max_distance,
                halo: sector::rows_within(max_distance, spacing.1),
                height: dims.1,
            }),
            _ => unreachable!("{:?} bands run in memory", self.method),
        }
    }

    fn curvature_on(&self, asset: &Asset<Mmap>) -> bool {
        self.curvature.unwrap_or_else(|| {
            asset
                .manifest()
                .georef
                .as_ref()
                .is_some_and(|g| g.crs_kind != CrsKind::Unknown)
        })
    }
}

impl Stage for HorizonsStage {
    fn name(&self) -> &'static str {
        "horizons"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::json!({
            "sectors": self.sectors,
            "method": self.method.name(),
            "max_distance": self.max_distance,
            "curvature": self.curvature,
            "refraction": self.refraction,
            "aoi": self.aoi,
            "encoding": match self.encoding {
                AngleChoice::Fixed(e) => serde_json::json!(e.name()),
                AngleChoice::MaxError(d) => serde_json::json!({ "max_error_deg": d }),
            },
            "narrow_check": self.narrow_check,
            "direction_tolerance": self.direction_tolerance,
        })
    }

    fn run(&self, asset: &Asset<Mmap>, dir: &Path, progress: Progress) -> Result<Vec<LayerEntry>> {
        let m = asset.manifest();
        let height = asset.height()?;
        let (w, h, ts) = (
            height.width() as usize,
            height.height() as usize,
            height.tile_size() as usize,
        );
        self.check(w, h)?;
        let curvature = if self.curvature_on(asset) {
            terrain::curvature_coefficient(self.refraction)
        } else {
            0.0
        };
        let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
        let row_scale = crate::geo::row_scale(m.georef.as_ref(), h as u32);
        let row_scale = RowScale::new(&row_scale);
        let bands = plan_bands(self.method, self.sectors, dx, dy, self.direction_tolerance);
        let enc = self.encoding.resolve();
        let aoi = self
            .aoi
            .unwrap_or([0, 0, w as u32, h as u32])
            .map(|v| v as usize);
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
            if curvature > 0.0 { format!("on, refraction {}", self.refraction) } else { "off".into() }
        );
        let spec = post_layer(
            HORIZON,
            enc.elem(),
            bands.len() as u32,
            (w, h, ts),
            description,
        );
        let out = BandWriter {
            writer: Mutex::new(LayerWriter::create(dir, spec)?),
            enc,
            width: w,
            tile_size: ts,
            tiles: (w.div_ceil(ts), h.div_ceil(ts)),
            aoi,
        };
        let bar = progress.bar(bands.len() as u64, "horizons", "bands");
        let opts = BandOptions {
            max_distance: self.max_distance,
            narrow_check: self.narrow_check,
        };
        let nodata = m.nodata.count > 0;
        if self.out_of_core() {
            // Bands in batches of a fixed size, each batch's sweeps run tile
            // row by tile row on every core and written in a fixed order
            // (crate::ordered): the layer's bytes are the same on every run
            // and any number of threads.
            let threads = rayon::current_num_threads();
            for (b, batch) in bands.chunks(OUT_OF_CORE_BATCH).enumerate() {
                let sweeps: Vec<_> = batch
                    .iter()
                    .map(|band| self.row_bands(band, (w, h), (dx, dy), row_scale, nodata))
                    .collect();
                let steps = crate::tiling::row_bands(h, ts).len();
                crate::ordered::steps_in_order(
                    sweeps,
                    steps,
                    threads,
                    |sweep, k| {
                        let rows = sweep.bands(ts)[k].clone();
                        let window = sweep.window(&rows);
                        let mut rows_buf = vec![0f32; window.len() * w];
                        height.read_window(
                            0,
                            0,
                            window.start as u32,
                            w as u32,
                            window.len() as u32,
                            &mut rows_buf,
                        )?;
                        let terrain = Terrain::window(&rows_buf, (w, h), window.start, (dx, dy))
                            .with_row_scale(row_scale)
                            .with_curvature(curvature);
                        let mut angles = vec![0f32; rows.len() * w];
                        sweep.sweep(&terrain, rows.clone(), &mut angles);
                        Ok((rows.start, out.encode(rows.start, &mut angles)))
                    },
                    |j, k, (y0, tiles)| {
                        out.push(b * OUT_OF_CORE_BATCH + j, y0, tiles)?;
                        if k + 1 == steps {
                            bar.inc(1);
                        }
                        Ok(())
                    },
                )?;
            }
        } else {
            let (z, _, _) = read_heights(asset)?;
            let terrain = Terrain::new(&z, w, h, dx, dy)
                .with_row_scale(row_scale)
                .with_curvature(curvature);
            let threads = rayon::current_num_threads().max(1);
            for (b, batch) in bands.chunks(threads).enumerate() {
                let results: Vec<(Vec<f32>, u64)> = batch
                    .par_iter()
                    .map(|band| band_horizons(&terrain, band, opts))
                    .collect();
                for (j, (mut angles, _)) in results.into_iter().enumerate() {
                    for (k, rows) in angles.chunks_mut(ts * w).enumerate() {
                        out.write(b * threads + j, k * ts, rows)?;
                    }
                    bar.inc(1);
                }
            }
        }
        bar.finish_and_clear();
        let mut horizon = out
            .writer
            .into_inner()
            .expect("no panic while writing")
            .finish()?;
        horizon.quantization = enc.quantization();
        horizon.band_azimuths = bands.iter().map(|b| b.azimuth).collect();

        // The derived layers, tile row by tile row, from the stored angles.
        let mut manifest = m.clone();
        manifest.upsert_layer(horizon.clone());
        let fresh = Asset::open_uncommitted(dir, manifest)?;
        let mut entries = vec![horizon];
        entries.extend(sky_layers(
            &fresh, dir, &bands, row_scale, aoi, curvature, progress,
        )?);
        Ok(entries)
    }
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
    /// Angles of output rows `band` from `window`, the rows [`Self::window`] named.
    fn sweep(&mut self, window: &Terrain, band: std::ops::Range<usize>, out: &mut [f32]);
}

impl RowBands for line::BandedSweep {
    fn bands(&self, rows: usize) -> Vec<std::ops::Range<usize>> {
        line::BandedSweep::bands(self, rows)
    }

    fn window(&self, band: &std::ops::Range<usize>) -> std::ops::Range<usize> {
        line::BandedSweep::window(self, band)
    }

    fn sweep(&mut self, window: &Terrain, band: std::ops::Range<usize>, out: &mut [f32]) {
        line::BandedSweep::sweep(self, window, band, out)
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
}

impl RowBands for BoundedSector {
    fn bands(&self, rows: usize) -> Vec<std::ops::Range<usize>> {
        crate::tiling::row_bands(self.height, rows)
    }

    fn window(&self, band: &std::ops::Range<usize>) -> std::ops::Range<usize> {
        band.start.saturating_sub(self.halo)..(band.end + self.halo).min(self.height)
    }

    fn sweep(&mut self, window: &Terrain, band: std::ops::Range<usize>, out: &mut [f32]) {
        sector::sector_horizons_within(
            window,
            self.sector,
            self.narrow,
            self.max_distance,
            band,
            out,
        );
    }
}

/// A layer of the stage: one element per post, raw tiles like the heights.
fn post_layer(
    name: &str,
    elem: terrabake_format::ElemType,
    bands: u32,
    (w, h, ts): (usize, usize, usize),
    description: String,
) -> LayerSpec {
    LayerSpec {
        name: name.into(),
        level: 0,
        elem,
        bands,
        width: w as u32,
        height: h as u32,
        tile_size: ts as u32,
        codec: Codec::Raw,
        fill_bits: 0,
        stage: "horizons".into(),
        description,
    }
}

/// Writes a band's rows of angles into the horizon layer as they come (in
/// any order), masked to the area of interest.
struct BandWriter {
    writer: Mutex<LayerWriter>,
    enc: AngleEncoding,
    width: usize,
    tile_size: usize,
    tiles: (usize, usize),
    aoi: [usize; 4],
}

impl BandWriter {
    /// Rows `y0..` of band `band` (whole tile rows, `y0` on a tile edge).
    fn write(&self, band: usize, y0: usize, angles: &mut [f32]) -> Result<()> {
        let tiles = self.encode(y0, angles);
        self.push(band, y0, tiles)
    }

    /// The tiles of rows `y0..` of angles, masked to the area of interest.
    fn encode(&self, y0: usize, angles: &mut [f32]) -> Vec<terrabake_format::EncodedTile> {
        let (w, ts, [x0, ay0, x1, ay1]) = (self.width, self.tile_size, self.aoi);
        for (r, row) in angles.chunks_mut(w).enumerate() {
            let y = y0 + r;
            for (x, v) in row.iter_mut().enumerate() {
                if !(x0..x1).contains(&x) || !(ay0..ay1).contains(&y) {
                    *v = f32::NAN;
                }
            }
        }
        let enc = self.enc;
        let code = |a: &f32| enc.encode(f64::from(*a));
        match enc {
            AngleEncoding::F32 => encode_tile_row(angles, w, ts, f32::NAN, Codec::Raw),
            AngleEncoding::U16 => {
                let codes: Vec<u16> = angles.iter().map(|a| code(a) as u16).collect();
                encode_tile_row(&codes, w, ts, 0u16, Codec::Raw)
            }
            AngleEncoding::U8 => {
                let codes: Vec<u8> = angles.iter().map(|a| code(a) as u8).collect();
                encode_tile_row(&codes, w, ts, 0u8, Codec::Raw)
            }
        }
    }

    /// Appends the tiles of the tile row at `y0` of band `band`.
    fn push(
        &self,
        band: usize,
        y0: usize,
        tiles: Vec<terrabake_format::EncodedTile>,
    ) -> Result<()> {
        let ty = y0 / self.tile_size;
        let mut writer = self.writer.lock().expect("no panic while writing");
        for (tx, tile) in tiles.into_iter().enumerate() {
            let chunk = (band * self.tiles.1 + ty) * self.tiles.0 + tx;
            writer.push_at(chunk as u64, tile)?;
        }
        Ok(())
    }
}

/// `svf`, `svf_cosine`, `openness` and `horizon_edge` from the stored
/// horizons of `asset`, one tile row at a time (heights with a row above
/// and below for the normals, every band's angles for the row).
fn sky_layers(
    asset: &Asset<Mmap>,
    dir: &Path,
    bands: &[Band],
    row_scale: RowScale,
    [ax0, ay0, ax1, ay1]: [usize; 4],
    curvature: f64,
    progress: Progress,
) -> Result<Vec<LayerEntry>> {
    use terrabake_format::ElemType;
    let m = asset.manifest();
    let height = asset.height()?;
    let horizon = asset.layer(HORIZON, 0)?;
    let (w, h, ts) = (
        height.width() as usize,
        height.height() as usize,
        height.tile_size() as usize,
    );
    let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
    let z_max = m.height_range.map_or(f64::INFINITY, |r| f64::from(r.max));
    let create = |name: &str, elem, description: &str| {
        LayerWriter::create(
            dir,
            post_layer(name, elem, 1, (w, h, ts), description.into()),
        )
    };
    let mut svf = create(SVF, ElemType::F32, "sky-view factor, solid angle of visible sky over the hemisphere above the horizontal: 1 - mean sin(max(h, 0)) (Zakšek 2011)")?;
    let mut svf_cosine = create(SVF_COSINE, ElemType::F32, "sky-view factor, cosine-weighted from the tilted surface: (1/pi) integral of N.u over the visible sky (Dozier-Frew 1990, Stewart 1998 sec. VI)")?;
    let mut openness = create(
        OPENNESS,
        ElemType::F32,
        "positive openness, degrees: mean zenith angle of the horizon (Yokoyama 2002)",
    )?;
    let mut edge = create(HORIZON_EDGE, ElemType::U16, "bands in which terrain beyond the DEM's edge, no higher than the DEM's highest post, could rise above the horizon")?;
    let integrals: Vec<sky::BandIntegrals> = bands
        .iter()
        .map(|b| sky::BandIntegrals::new(b.lo, b.hi))
        .collect();
    let bar = progress.bar(h.div_ceil(ts) as u64, "sky layers", "tile rows");
    for y0 in (0..h).step_by(ts) {
        let rows = ts.min(h - y0);
        let (r0, r1) = (y0.saturating_sub(1), (y0 + rows + 1).min(h));
        let mut z = vec![0f32; (r1 - r0) * w];
        height.read_window(0, 0, r0 as u32, w as u32, (r1 - r0) as u32, &mut z)?;
        let terrain = Terrain::window(&z, (w, h), r0, (dx, dy)).with_row_scale(row_scale);
        // Per post of the row: its normal (once, not once per band) and how
        // far the terrain could rise past the DEM's edge per metre of reach.
        let normals: Vec<Option<[f64; 3]>> = (0..rows * w)
            .into_par_iter()
            .map(|i| terrain.normal(i % w, y0 + i / w))
            .collect();
        let mut sums = vec![sky::SkySums::default(); rows * w];
        let mut edges = vec![0u16; rows * w];
        let mut angles = vec![0f32; rows * w];
        for (b, band) in bands.iter().enumerate() {
            horizon.read_rows_f32(b as u32, y0 as u32, &mut angles)?;
            sums.par_chunks_mut(w)
                .zip(edges.par_chunks_mut(w))
                .zip(angles.par_chunks(w))
                .enumerate()
                .for_each(|(r, ((sums, edges), angles))| {
                    let row = y0 + r;
                    for col in 0..w {
                        let hz = f64::from(angles[col]);
                        let Some(normal) = normals[r * w + col].filter(|_| !hz.is_nan()) else {
                            continue;
                        };
                        let (sh, ch) = hz.to_radians().sin_cos();
                        sums[col].add(hz, (sh, ch), &integrals[b], normal);
                        // Could terrain no higher than the DEM's top, just
                        // past the edge, rise above this horizon?
                        let d = edge_distance(
                            (w as u32, h as u32),
                            (terrain.dx_at(row), dy),
                            (col as f64, row as f64),
                            band.azimuth,
                        );
                        let rise =
                            (z_max - f64::from(terrain.at(col, row)) - curvature * d * d) / d;
                        if d == 0.0 || rise * ch > sh {
                            edges[col] += 1;
                        }
                    }
                });
        }
        let inside = |i: usize| {
            let (x, y) = (i % w, y0 + i / w);
            (ax0..ax1).contains(&x) && (ay0..ay1).contains(&y) && !terrain.at(x, y).is_nan()
        };
        let layer = |value: &dyn Fn(&sky::SkySums) -> f64| -> Vec<f32> {
            (0..rows * w)
                .map(|i| {
                    if inside(i) {
                        value(&sums[i]) as f32
                    } else {
                        f32::NAN
                    }
                })
                .collect()
        };
        push_tile_row(&mut svf, &layer(&|s| s.svf()), w, f32::NAN, Codec::Raw)?;
        push_tile_row(
            &mut svf_cosine,
            &layer(&|s| s.svf_cosine()),
            w,
            f32::NAN,
            Codec::Raw,
        )?;
        push_tile_row(
            &mut openness,
            &layer(&|s| s.openness()),
            w,
            f32::NAN,
            Codec::Raw,
        )?;
        push_tile_row(&mut edge, &edges, w, 0u16, Codec::Raw)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(vec![
        svf.finish()?,
        svf_cosine.finish()?,
        openness.finish()?,
        edge.finish()?,
    ])
}

/// `[[stage]] name = "horizons"` with optional `sectors`, `method`,
/// `max_distance`, `curvature` (bool), `refraction`, `aoi` ([x0, y0, x1,
/// y1]), `encoding` ("u8", "u16", "f32"), `max_error_deg`, `narrow_check`,
/// `direction_tolerance`, `max_memory_mib`.
pub fn from_recipe(params: &toml::Table) -> Result<HorizonsStage> {
    let mut stage = HorizonsStage::default();
    for (key, value) in params {
        let bad = || anyhow::anyhow!("stage 'horizons': invalid {key} = {value}");
        let float = || {
            value
                .as_float()
                .or(value.as_integer().map(|i| i as f64))
                .ok_or_else(bad)
        };
        match key.as_str() {
            "sectors" => stage.sectors = value.as_integer().filter(|s| *s > 0).ok_or_else(bad)? as usize,
            "method" => {
                stage.method = match value.as_str().ok_or_else(bad)? {
                    "line" => Method::Line,
                    "sector" => Method::Sector,
                    "sampled" => Method::Sampled,
                    _ => return Err(bad()),
                }
            }
            "max_distance" => stage.max_distance = Some(float()?),
            "curvature" => stage.curvature = Some(value.as_bool().ok_or_else(bad)?),
            "refraction" => stage.refraction = float()?,
            "aoi" => {
                let v: Vec<u32> = value
                    .as_array()
                    .ok_or_else(bad)?
                    .iter()
                    .map(|x| x.as_integer().and_then(|i| u32::try_from(i).ok()))
                    .collect::<Option<_>>()
                    .ok_or_else(bad)?;
                stage.aoi = Some(v.try_into().map_err(|_| bad())?);
            }
            "encoding" => {
                stage.encoding = AngleChoice::Fixed(match value.as_str().ok_or_else(bad)? {
                    "u8" => AngleEncoding::U8,
                    "u16" => AngleEncoding::U16,
                    "f32" => AngleEncoding::F32,
                    _ => return Err(bad()),
                })
            }
            "max_error_deg" => stage.encoding = AngleChoice::MaxError(float()?),
            "narrow_check" => stage.narrow_check = value.as_bool().ok_or_else(bad)?,
            "direction_tolerance" => stage.direction_tolerance = Some(float()?),
            "max_memory_mib" => {
                stage.max_memory = value.as_integer().filter(|m| *m > 0).ok_or_else(bad)? as u64 * (1 << 20);
            }
            other => bail!("stage 'horizons' takes no parameter '{other}' (sectors, method, max_distance, curvature, refraction, aoi, encoding, max_error_deg, narrow_check, direction_tolerance, max_memory_mib)"),
        }
    }
    Ok(stage)
}

/// All bands of the `horizon` layer decoded to degrees, band-major.
pub fn read_horizons(asset: &Asset<Mmap>) -> Result<(Vec<Vec<f32>>, Vec<f64>)> {
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
