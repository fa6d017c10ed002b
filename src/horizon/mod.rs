//! The `horizons` stage: horizon angles at every post in `S` azimuths, and
//! the sky layers derived from them. `docs/HORIZONS.md` is the long form.
//!
//! Three methods, each exact for its own definition (see the modules):
//!
//! - [`line`]: the steepest sight line along the straight line from the
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
//! **Stage.** The DEM is held in memory (4 bytes per post) with one band
//! of output per worker; bands are computed in parallel (rayon), written
//! band-major (sector-major) in compass order, and folded into the derived
//! layers (`svf`, `svf_cosine`, `openness`) and the edge count as they
//! arrive, so that the stage never holds more than a few bands. Out of
//! core (DEMs larger than memory) is not done yet: see docs/HORIZONS.md.

pub mod bench;
pub mod brute;
pub mod line;
pub mod sampled;
pub mod sector;
pub mod sky;
pub mod terrain;

use std::path::Path;

use anyhow::{bail, Context, Result};
use rayon::prelude::*;
use terrabake_format::horizons::{
    edge_distance, AngleEncoding, HORIZON, OPENNESS, SVF, SVF_COSINE,
};
use terrabake_format::manifest::CrsKind;
use terrabake_format::{Asset, Codec, LayerEntry, LayerSpec, LayerWriter, Mmap};

use crate::progress::Progress;
use crate::stage::Stage;
use crate::tiling::push_tile_row;
use line::GridDirection;
use terrain::Terrain;

/// Layer counting, per post, the bands whose horizon the DEM's edge may cut.
pub const HORIZON_EDGE: &str = "horizon_edge";

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

/// Options that change every band's values.
#[derive(Debug, Clone, Copy)]
pub struct BandOptions {
    /// Metres; `None`: the whole DEM (exact).
    pub max_distance: Option<f64>,
    /// Stewart's narrow-sector check (sec. IV-E), for `sector`.
    pub narrow_check: bool,
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
                let len = dir.step_length(terrain.dx, terrain.dy);
                out.par_chunks_mut(terrain.width)
                    .enumerate()
                    .for_each(|(row, out)| {
                        for (col, v) in out.iter_mut().enumerate() {
                            *v = line::line_horizon_within(
                                terrain,
                                &stencil,
                                len,
                                (col as i64, row as i64),
                                max,
                            );
                        }
                    });
                0
            }
        },
        BandKind::Sector { index, count } => {
            let s = sector::sector_horizons(terrain, *index, *count, opts.narrow_check, &mut out);
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
}

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
        if self.method == Method::Sector && self.max_distance.is_some() {
            bail!("--max-distance applies to the line and sampled methods; Stewart's sector tree covers the whole DEM");
        }
        if let Some(d) = self.max_distance {
            if d.is_nan() || d <= 0.0 {
                bail!("--max-distance {d}: give a positive distance in metres");
            }
        }
        if let Some([x0, y0, x1, y1]) = self.aoi {
            if x0 >= x1 || y0 >= y1 || x1 as usize > w || y1 as usize > h {
                bail!("--aoi {x0},{y0},{x1},{y1} is not a non-empty window of the {w} x {h} DEM");
            }
        }
        Ok(())
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
        let (z, w, h) = read_heights(asset)?;
        self.check(w, h)?;
        let curvature = if self.curvature_on(asset) {
            terrain::curvature_coefficient(self.refraction)
        } else {
            0.0
        };
        let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
        let terrain = Terrain::new(&z, w, h, dx, dy).with_curvature(curvature);
        let bands = plan_bands(self.method, self.sectors, dx, dy, self.direction_tolerance);
        let enc = self.encoding.resolve();
        let opts = BandOptions {
            max_distance: self.max_distance,
            narrow_check: self.narrow_check,
        };
        let [ax0, ay0, ax1, ay1] = self
            .aoi
            .unwrap_or([0, 0, w as u32, h as u32])
            .map(|v| v as usize);
        let in_aoi = |i: usize| (ax0..ax1).contains(&(i % w)) && (ay0..ay1).contains(&(i / w));
        let z_max = m.height_range.map_or(f64::INFINITY, |r| f64::from(r.max));
        let ts = m.tile_size;

        let spec = |name: &str, elem, bands: u32, description: String| LayerSpec {
            name: name.into(),
            level: 0,
            elem,
            bands,
            width: w as u32,
            height: h as u32,
            tile_size: ts,
            codec: Codec::Raw,
            fill_bits: 0,
            stage: "horizons".into(),
            description,
        };
        let method_text = match self.method {
            Method::Line => "line: steepest sight line along the grid direction of the band (exact on the two-triangle surface)",
            Method::Sector => if self.narrow_check {
                "sector: Stewart's maximum over the closed wedge, with the IV-E narrow-sector check"
            } else {
                "sector: Stewart's maximum over the closed wedge, without the IV-E check"
            },
            Method::Sampled => "sampled: centre-line sampling, nearest post, one spacing per step (baseline)",
        };
        let mut horizon_writer = LayerWriter::create(
            dir,
            spec(
                HORIZON,
                enc.elem(),
                bands.len() as u32,
                format!(
                    "horizon elevation angle, degrees, band per azimuth (band_azimuths), {}; {method_text}; curvature {}",
                    enc.name(),
                    if curvature > 0.0 { format!("on, refraction {}", self.refraction) } else { "off".into() }
                ),
            ),
        )?;

        let bar = progress.bar(bands.len() as u64, "horizons", "bands");
        let mut sums = vec![sky::SkySums::default(); w * h];
        let mut edge_count = vec![0u16; w * h];
        let per_batch = rayon::current_num_threads().max(1);
        for batch in bands.chunks(per_batch) {
            let results: Vec<(Vec<f32>, u64)> = batch
                .par_iter()
                .map(|band| band_horizons(&terrain, band, opts))
                .collect();
            for (band, (mut angles, _work)) in batch.iter().zip(results) {
                let integrals = sky::BandIntegrals::new(band.lo, band.hi);
                sums.par_chunks_mut(w)
                    .zip(edge_count.par_chunks_mut(w))
                    .zip(angles.par_chunks_mut(w))
                    .enumerate()
                    .for_each(|(row, ((sums, edges), angles))| {
                        for col in 0..w {
                            if !in_aoi(row * w + col) {
                                angles[col] = f32::NAN;
                                continue;
                            }
                            let hz = f64::from(angles[col]);
                            if hz.is_nan() {
                                continue;
                            }
                            let normal = terrain.normal(col, row).expect("valid post");
                            sums[col].add(hz, &integrals, normal);
                            // Could terrain no higher than the DEM's top,
                            // just past the edge, rise above this horizon?
                            let d = edge_distance(
                                (w as u32, h as u32),
                                (dx, dy),
                                (col as f64, row as f64),
                                band.azimuth,
                            );
                            let rise =
                                (z_max - f64::from(terrain.at(col, row)) - curvature * d * d) / d;
                            let (sh, ch) = hz.to_radians().sin_cos();
                            if d == 0.0 || rise * ch > sh {
                                edges[col] += 1;
                            }
                        }
                    });
                write_band(&mut horizon_writer, &angles, w, enc)?;
                bar.inc(1);
            }
        }
        bar.finish_and_clear();
        let mut horizon = horizon_writer.finish()?;
        horizon.quantization = enc.quantization();
        horizon.band_azimuths = bands.iter().map(|b| b.azimuth).collect();

        let derived = |name: &str,
                       description: &str,
                       value: &dyn Fn(&sky::SkySums) -> f64|
         -> Result<LayerEntry> {
            let mut writer = LayerWriter::create(
                dir,
                spec(name, terrabake_format::ElemType::F32, 1, description.into()),
            )?;
            let values: Vec<f32> = (0..w * h)
                .map(|i| {
                    if in_aoi(i) && !z[i].is_nan() {
                        value(&sums[i]) as f32
                    } else {
                        f32::NAN
                    }
                })
                .collect();
            for rows in values.chunks(ts as usize * w) {
                push_tile_row(&mut writer, rows, w, f32::NAN, Codec::Raw)?;
            }
            Ok(writer.finish()?)
        };
        let svf = derived(SVF, "sky-view factor, solid angle of visible sky over the hemisphere above the horizontal: 1 - mean sin(max(h, 0)) (Zakšek 2011)", &|s| s.svf())?;
        let svf_cosine = derived(SVF_COSINE, "sky-view factor, cosine-weighted from the tilted surface: (1/pi) integral of N.u over the visible sky (Dozier-Frew 1990, Stewart 1998 sec. VI)", &|s| s.svf_cosine())?;
        let openness = derived(
            OPENNESS,
            "positive openness, degrees: mean zenith angle of the horizon (Yokoyama 2002)",
            &|s| s.openness(),
        )?;
        let mut edge_writer = LayerWriter::create(
            dir,
            spec(
                HORIZON_EDGE,
                terrabake_format::ElemType::U16,
                1,
                "bands in which terrain beyond the DEM's edge, no higher than the DEM's highest post, could rise above the horizon".into(),
            ),
        )?;
        for rows in edge_count.chunks(ts as usize * w) {
            push_tile_row(&mut edge_writer, rows, w, 0u16, Codec::Raw)?;
        }
        Ok(vec![
            horizon,
            svf,
            svf_cosine,
            openness,
            edge_writer.finish()?,
        ])
    }
}

/// Appends one band of angles (degrees) in the layer's encoding.
fn write_band(
    writer: &mut LayerWriter,
    angles: &[f32],
    w: usize,
    enc: AngleEncoding,
) -> Result<()> {
    let ts = writer.spec().tile_size as usize;
    for rows in angles.chunks(ts * w) {
        match enc {
            AngleEncoding::F32 => push_tile_row(writer, rows, w, f32::NAN, Codec::Raw)?,
            AngleEncoding::U16 => {
                let codes: Vec<u16> = rows
                    .iter()
                    .map(|&a| enc.encode(f64::from(a)) as u16)
                    .collect();
                push_tile_row(writer, &codes, w, 0u16, Codec::Raw)?
            }
            AngleEncoding::U8 => {
                let codes: Vec<u8> = rows
                    .iter()
                    .map(|&a| enc.encode(f64::from(a)) as u8)
                    .collect();
                push_tile_row(writer, &codes, w, 0u8, Codec::Raw)?
            }
        }
    }
    Ok(())
}

/// `[[stage]] name = "horizons"` with optional `sectors`, `method`,
/// `max_distance`, `curvature` (bool), `refraction`, `aoi` ([x0, y0, x1,
/// y1]), `encoding` ("u8", "u16", "f32"), `max_error_deg`, `narrow_check`,
/// `direction_tolerance`.
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
            other => bail!("stage 'horizons' takes no parameter '{other}' (sectors, method, max_distance, curvature, refraction, aoi, encoding, max_error_deg, narrow_check, direction_tolerance)"),
        }
    }
    Ok(stage)
}

/// All bands of the `horizon` layer decoded to degrees, band-major.
pub fn read_horizons(asset: &Asset<Mmap>) -> Result<(Vec<Vec<f32>>, Vec<f64>)> {
    let map = terrabake_format::horizons::HorizonMap::open(asset)
        .context("the asset has no usable horizon layer; run `terrabake horizons` first")?;
    let layer = asset.layer(HORIZON, 0)?;
    let (w, h) = (layer.width(), layer.height());
    let enc = map.encoding();
    let mut bands = Vec::new();
    for b in 0..layer.bands() {
        let decoded: Vec<f32> = match enc {
            AngleEncoding::F32 => {
                let mut v = vec![0f32; (w * h) as usize];
                layer.read_window(b, 0, 0, w, h, &mut v)?;
                v
            }
            AngleEncoding::U16 => {
                let mut v = vec![0u16; (w * h) as usize];
                layer.read_window(b, 0, 0, w, h, &mut v)?;
                v.iter()
                    .map(|&c| enc.decode(u32::from(c)).map_or(f32::NAN, |d| d as f32))
                    .collect()
            }
            AngleEncoding::U8 => {
                let mut v = vec![0u8; (w * h) as usize];
                layer.read_window(b, 0, 0, w, h, &mut v)?;
                v.iter()
                    .map(|&c| enc.decode(u32::from(c)).map_or(f32::NAN, |d| d as f32))
                    .collect()
            }
        };
        bands.push(decoded);
    }
    Ok((bands, map.azimuths().to_vec()))
}
