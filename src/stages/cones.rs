//! The `cones` stage: parameter planes (`cone_apex@0`, `cone_slope@0`, one
//! element per cell) for parametric ray tracing. The planes, their guarantee
//! and their encodings are specified in `terrabake_format::cones`; the
//! algorithms are in [`crate::algorithms::planes`].
//!
//! **Slices.** `--slices K` is the paper's method with `K` slices; `exact`
//! is the limit of infinitely many, computed without slices; `auto` picks
//! `K` from the data: never more slices than the data has height steps
//! (slicing finer than a 1 m integer DEM buys nothing), and no more than the
//! requested apex gap needs (the apex may sit up to one slice step above a
//! cell's neighbourhood; `--apex-gap` defaults to 1/255 of the relief, i.e.
//! 256 slices).
//!
//! **Out of core.** Distance transforms are global. When the DEM's cells,
//! at [`BYTES_PER_CELL`], fit in `--max-memory`, the whole DEM is one window
//! and the planes are exact for it. Otherwise the stage cuts it into square
//! core blocks (a multiple of the tile size) and computes each over the
//! block plus a halo of half a block on every side; terrain beyond the halo
//! is at least `halo * min(dx, dy)` metres away and no taller than the DEM's
//! maximum, so every slope is capped at `halo * min(dx, dy) / (z_max -
//! apex)`. That cap is the cost: a leap never crosses more than about one
//! halo, where the in-core planes are unbounded. Peak memory is one window
//! and one row of core blocks of output, both counted against the budget.

use std::path::Path;

use anyhow::Result;
use terrabake_format::cones::{
    apex_quantization, encode_apex, encode_slope, ConeEncoding, CONE_APEX, CONE_SLOPE,
};
use terrabake_format::{Asset, Codec, Element, LayerEntry, LayerSpec, LayerWriter, Mmap};

use crate::algorithms::planes::exact::exact_planes;
use crate::error::bail;

use crate::algorithms::planes::{neighbourhood_max, sliced_planes, Cap, Planes, Slices};
use crate::plumbing::progress::Progress;
use crate::stage::Stage;
use crate::terrain::tiling::push_tile_row;

/// Working memory per cell of a window: posts, `nmax`, the apex slices (in
/// two bytes and in one), the floors, the two planes and the exact method's
/// pyramid (the column distances are a band's at a time, per thread).
pub const BYTES_PER_CELL: u64 = 32;

/// How many slices: written `K` (a count), `auto` or `exact`, on the
/// command line and in recipes (where a count may also be an integer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SliceChoice {
    Count(usize),
    /// `K` from the data and the apex gap ([`ConesStage::apex_gap`]).
    Auto,
    Exact,
}

impl std::fmt::Display for SliceChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SliceChoice::Count(k) => write!(f, "{k}"),
            SliceChoice::Auto => f.write_str("auto"),
            SliceChoice::Exact => f.write_str("exact"),
        }
    }
}

impl serde::Serialize for SliceChoice {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            SliceChoice::Count(k) => s.serialize_u64(*k as u64),
            other => s.collect_str(other),
        }
    }
}

impl<'de> serde::Deserialize<'de> for SliceChoice {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Written {
            Count(u64),
            Text(String),
        }
        match Written::deserialize(d)? {
            Written::Count(k) => k.to_string().parse(),
            Written::Text(s) => s.parse(),
        }
        .map_err(serde::de::Error::custom)
    }
}

impl std::str::FromStr for SliceChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(SliceChoice::Auto),
            "exact" => Ok(SliceChoice::Exact),
            n => match n.parse::<usize>() {
                Ok(k) if (1..=65535).contains(&k) => Ok(SliceChoice::Count(k)),
                _ => Err(format!(
                    "slices takes a count from 1 to 65535, auto or exact, not {s:?}"
                )),
            },
        }
    }
}

/// The DEM's heights: its range and its vertical quantisation.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HeightSummary {
    pub z_min: f64,
    pub z_max: f64,
    /// The smallest difference between distinct heights in an even sample
    /// of up to 2^20 posts: the data's vertical quantisation.
    pub step: f64,
}

/// What `--slices` resolved to, and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SlicePlan {
    /// `None` for exact.
    pub slices: Option<usize>,
    pub reason: String,
}

impl SliceChoice {
    /// The slice count for heights `h`; `apex_gap` (metres, `None`: relief
    /// / 255) bounds `auto`.
    pub fn resolve(self, h: &HeightSummary, apex_gap: Option<f64>) -> SlicePlan {
        let relief = h.z_max - h.z_min;
        match self {
            SliceChoice::Count(k) => SlicePlan {
                slices: Some(k),
                reason: format!("{k} slices as asked"),
            },
            SliceChoice::Exact => SlicePlan {
                slices: None,
                reason: "exact cones (no slices)".into(),
            },
            SliceChoice::Auto => {
                if relief <= 0.0 {
                    return SlicePlan {
                        slices: Some(1),
                        reason: "1 slice: the DEM is flat".into(),
                    };
                }
                let gap = apex_gap.unwrap_or(relief / 255.0);
                let by_gap = (relief / gap).ceil() + 1.0;
                let by_data = if h.step > 0.0 {
                    (relief / h.step).floor() + 1.0
                } else {
                    f64::INFINITY
                };
                let k = by_gap.min(by_data).clamp(1.0, 65535.0) as usize;
                // Metres to the millimetre, without trailing zeros.
                let m = |v: f64| {
                    let t = format!("{v:.3}");
                    t.trim_end_matches('0').trim_end_matches('.').to_string()
                };
                let reason = if by_data <= by_gap {
                    format!(
                        "{k} slices: relief {} m in steps of {} m; more slices than height steps buy nothing",
                        m(relief),
                        m(h.step)
                    )
                } else {
                    format!(
                        "{k} slices: relief {} m with the apex at most {} m above a cell's neighbourhood (the data has {by_data} height steps)",
                        m(relief),
                        m(gap)
                    )
                };
                SlicePlan {
                    slices: Some(k),
                    reason,
                }
            }
        }
    }
}

/// The cones stage and its parameters: `terrabake cones` flattens it, a
/// recipe's `[[stage]] name = "cones"` table deserialises into it (unknown
/// keys refused), and the manifest records its serialisation.
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConesStage {
    /// A slice count K (1..=65535), auto, or exact.
    #[arg(long, default_value_t = Self::DEFAULT_SLICES)]
    pub slices: SliceChoice,
    /// With slices auto: how far (metres) the apex may sit above a cell's
    /// neighbourhood; default relief / 255, i.e. 256 slices unless the data
    /// has fewer height steps.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub apex_gap: Option<f64>,
    /// How the planes are stored: f32, f16 or u16 (conservatively rounded).
    #[arg(long, default_value = "f32")]
    pub encoding: ConeEncoding,
    /// Working memory in MiB; a DEM that needs more is baked in windows
    /// (whose halos cap the slopes, so it is recorded).
    #[arg(long = "max-memory", value_name = "MIB", default_value = crate::stage::mib::STAGE_DEFAULT, value_parser = crate::stage::mib::parse)]
    #[serde(rename = "max_memory_mib", with = "crate::stage::mib")]
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
}

impl ConesStage {
    /// Slices unless told: chosen from the DEM's relief and height step.
    pub const DEFAULT_SLICES: SliceChoice = SliceChoice::Auto;
}

impl Default for ConesStage {
    fn default() -> Self {
        Self {
            slices: Self::DEFAULT_SLICES,
            apex_gap: None,
            encoding: ConeEncoding::F32,
            max_memory: crate::stage::mib::STAGE_DEFAULT_BYTES,
            codec: Codec::Raw,
        }
    }
}

/// The DEM's range (recorded at ingest) and its height step, from an even
/// sample of up to 2^20 posts read in place.
pub fn summarize_heights(asset: &Asset<Mmap>) -> crate::Result<HeightSummary> {
    let Some(range) = asset.manifest().height_range else {
        bail!("the DEM has no valid height");
    };
    let height = asset.height()?;
    let (w, h) = (u64::from(height.width()), u64::from(height.height()));
    let stride = ((w * h) >> 20).max(1);
    let mut sample = Vec::new();
    for i in (0..w * h).step_by(stride as usize) {
        let z = height.get::<f32>(0, (i % w) as u32, (i / w) as u32)?;
        if !z.is_nan() {
            sample.push(z);
        }
    }
    sample.sort_by(f32::total_cmp);
    sample.dedup();
    let step = sample
        .windows(2)
        .map(|p| f64::from(p[1]) - f64::from(p[0]))
        .fold(f64::INFINITY, f64::min);
    Ok(HeightSummary {
        z_min: f64::from(range.min),
        z_max: f64::from(range.max),
        step: if step.is_finite() { step } else { 0.0 },
    })
}

/// The windows of a bake: core blocks and the halo around each.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Blocking {
    /// Core block side in cells (the whole DEM when one window).
    core: usize,
    halo: usize,
    whole: bool,
}

fn blocking(cells: (usize, usize), tile: usize, max_memory: u64) -> Blocking {
    let area = cells.0 as u64 * cells.1 as u64;
    if area * BYTES_PER_CELL <= max_memory {
        return Blocking {
            core: cells.0.max(cells.1),
            halo: 0,
            whole: true,
        };
    }
    // A window is (core + 2 * halo)^2 = (2 core)^2 cells at BYTES_PER_CELL,
    // and a row of core blocks of output is core x width x 8 bytes (apex and
    // slope in f32): the largest core for which both fit.
    let (b, w, m) = (BYTES_PER_CELL as f64, cells.0 as f64, max_memory as f64);
    let side = ((64.0 * w * w + 16.0 * b * m).sqrt() - 8.0 * w) / (8.0 * b);
    let core = (side as usize / tile).max(1) * tile;
    Blocking {
        core,
        halo: core / 2,
        whole: false,
    }
}

impl ConesStage {
    /// Planes of one window of cells `[x0, x1) x [y0, y1)`, whose core is
    /// returned: the whole window when `cap` is `None`.
    #[allow(clippy::too_many_arguments)]
    fn window(
        &self,
        asset: &Asset<Mmap>,
        window: (usize, usize, usize, usize),
        core: (usize, usize, usize, usize),
        plan: &SlicePlan,
        summary: &HeightSummary,
        cap: Option<Cap>,
        tick: &(dyn Fn() + Sync),
    ) -> Result<Planes> {
        let height = asset.height()?;
        let m = asset.manifest();
        let (x0, y0, x1, y1) = window;
        // One more cell around the window, so that every window cell's
        // neighbourhood is complete; posts are one more than cells.
        let (cw_dem, ch_dem) = (height.width() as usize - 1, height.height() as usize - 1);
        let (ex0, ey0) = (x0.saturating_sub(1), y0.saturating_sub(1));
        let (ex1, ey1) = ((x1 + 1).min(cw_dem), (y1 + 1).min(ch_dem));
        let (pw, ph) = (ex1 - ex0 + 1, ey1 - ey0 + 1);
        let mut posts = vec![0f32; pw * ph];
        height.read_window(0, ex0 as u32, ey0 as u32, pw as u32, ph as u32, &mut posts)?;
        let extended = neighbourhood_max(&posts, pw, ph);
        drop(posts);
        let (ww, wh) = (x1 - x0, y1 - y0);
        let inner = (x0 - ex0, y0 - ey0, x1 - ex0, y1 - ey0);
        let nmax = crop(extended, pw - 1, inner);
        let cell = (m.cell_size.dx, m.cell_size.dy);
        let planes = match plan.slices {
            Some(k) => sliced_planes(
                &nmax,
                (ww, wh),
                cell,
                &Slices::uniform(summary.z_min, summary.z_max, k),
                cap,
                tick,
            ),
            None => exact_planes(&nmax, (ww, wh), cell, summary.z_min, cap, tick),
        };
        let (cx0, cy0, cx1, cy1) = core;
        let core = (cx0 - x0, cy0 - y0, cx1 - x0, cy1 - y0);
        Ok(Planes {
            apex: crop(planes.apex, ww, core),
            slope: crop(planes.slope, ww, core),
            stats: planes.stats,
        })
    }
}

/// The rectangle `[x0, x1) x [y0, y1)` of a row-major grid `width` wide;
/// the grid itself when the rectangle is all of it.
fn crop(
    values: Vec<f32>,
    width: usize,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
) -> Vec<f32> {
    if (x0, y0, x1) == (0, 0, width) && y1 * width == values.len() {
        return values;
    }
    (y0..y1)
        .flat_map(|y| values[y * width + x0..y * width + x1].iter().copied())
        .collect()
}

fn encode_rows<T: Element>(
    writer: &mut LayerWriter,
    values: &[f32],
    width: usize,
    encode: impl Fn(f64) -> T + Sync,
    fill: T,
) -> Result<()> {
    // One tile row at a time, so that the encoded copy stays small.
    let ts = writer.spec().tile_size as usize;
    let mut encoded = Vec::with_capacity(ts * width);
    for band in values.chunks(ts * width) {
        encoded.clear();
        encoded.extend(band.iter().map(|&v| encode(f64::from(v))));
        push_tile_row(writer, &encoded, width, fill)?;
    }
    Ok(())
}

impl Stage for ConesStage {
    fn name(&self) -> &'static str {
        "cones"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("parameters serialise")
    }

    fn outputs(&self, _: &terrabake_format::Manifest) -> Vec<String> {
        vec![format!("{CONE_APEX}@0"), format!("{CONE_SLOPE}@0")]
    }

    fn check(&self) -> crate::Result<()> {
        if let Some(gap) = self.apex_gap {
            crate::error::ensure!(
                self.slices == SliceChoice::Auto,
                "apex_gap = {gap} (--apex-gap {gap}) goes with slices = \"auto\", not {}",
                self.slices
            );
            crate::error::ensure!(
                gap > 0.0 && gap.is_finite(),
                "apex_gap = {gap} (--apex-gap {gap}) is not a positive number of metres"
            );
        }
        Ok(())
    }

    /// Never split (it runs at the join): every chunk, whatever the share.
    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        _: &crate::stage::Share,
        progress: Progress,
    ) -> crate::Result<Vec<LayerEntry>> {
        let height = asset.height()?;
        let (w, h, ts) = (height.width(), height.height(), height.tile_size());
        crate::error::ensure!(w >= 2 && h >= 2, "a {w} x {h} DEM has no cells");
        let (cw, ch) = ((w - 1) as usize, (h - 1) as usize);
        let summary = summarize_heights(asset)?;
        let plan = self.slices.resolve(&summary, self.apex_gap);
        let blocks = blocking((cw, ch), ts as usize, self.max_memory);
        let m = asset.manifest();
        let cap = (!blocks.whole).then(|| Cap {
            radius: blocks.halo as f64 * m.cell_size.dx.min(m.cell_size.dy),
            z_max: summary.z_max,
        });
        let (bx, by) = (cw.div_ceil(blocks.core), ch.div_ceil(blocks.core));
        let units_per_window = match plan.slices {
            Some(k) => k,
            None => blocks.core.min(ch) + 2 * blocks.halo,
        };
        let bar = progress.bar(
            (bx * by * units_per_window) as u64,
            "cones",
            if plan.slices.is_some() {
                "slices"
            } else {
                "rows"
            },
        );
        let tick = || bar.inc(1);

        let enc = self.encoding;
        let apex_q = apex_quantization(summary.z_min, summary.z_max, enc);
        let how = match plan.slices {
            Some(k) => format!("{k} slices"),
            None => "exact".into(),
        };
        let spec = |name: &str, description: String| LayerSpec {
            name: name.into(),
            level: 0,
            elem: enc.elem(),
            bands: 1,
            width: cw as u32,
            height: ch as u32,
            tile_size: ts,
            codec: self.codec,
            fill_bits: 0,
            stage: "cones".into(),
            description,
        };
        let mut apex_writer = LayerWriter::create(
            dir,
            spec(
                CONE_APEX,
                // The reason names the slice count (or "exact") itself.
                format!(
                    "cone apex z_p over each cell, metres, {} rounded up ({})",
                    enc.name(),
                    plan.reason
                ),
            ),
        )?;
        let mut slope_writer = LayerWriter::create(
            dir,
            spec(
                CONE_SLOPE,
                format!(
                    "cone slope m_p, horizontal metres per metre of rise, {} rounded down ({how}{})",
                    enc.name(),
                    match cap {
                        Some(c) => format!("; windowed, capped at {:.0} m / (z_max - apex)", c.radius),
                        None => String::new(),
                    }
                ),
            ),
        )?;
        for byi in 0..by {
            let (cy0, cy1) = (byi * blocks.core, ((byi + 1) * blocks.core).min(ch));
            let (mut band_apex, mut band_slope) = (Vec::new(), Vec::new());
            for bxi in 0..bx {
                let (cx0, cx1) = (bxi * blocks.core, ((bxi + 1) * blocks.core).min(cw));
                let window = (
                    cx0.saturating_sub(blocks.halo),
                    cy0.saturating_sub(blocks.halo),
                    (cx1 + blocks.halo).min(cw),
                    (cy1 + blocks.halo).min(ch),
                );
                let planes = self.window(
                    asset,
                    window,
                    (cx0, cy0, cx1, cy1),
                    &plan,
                    &summary,
                    cap,
                    &tick,
                )?;
                // One block across: its planes are the band.
                if bx == 1 {
                    (band_apex, band_slope) = (planes.apex, planes.slope);
                    continue;
                }
                band_apex.resize(cw * (cy1 - cy0), 0.0);
                band_slope.resize(cw * (cy1 - cy0), 0.0);
                let core_w = cx1 - cx0;
                for (y, (a, s)) in planes
                    .apex
                    .chunks(core_w)
                    .zip(planes.slope.chunks(core_w))
                    .enumerate()
                {
                    band_apex[y * cw + cx0..y * cw + cx1].copy_from_slice(a);
                    band_slope[y * cw + cx0..y * cw + cx1].copy_from_slice(s);
                }
            }
            match enc {
                ConeEncoding::F32 => {
                    encode_rows(&mut apex_writer, &band_apex, cw, |v| v as f32, 0f32)?;
                    encode_rows(&mut slope_writer, &band_slope, cw, |v| v as f32, 0f32)?;
                }
                ConeEncoding::F16 | ConeEncoding::U16 => {
                    let code = |v: u32| v as u16;
                    encode_rows(
                        &mut apex_writer,
                        &band_apex,
                        cw,
                        |v| code(encode_apex(v, enc, apex_q)),
                        0u16,
                    )?;
                    encode_rows(
                        &mut slope_writer,
                        &band_slope,
                        cw,
                        |v| code(encode_slope(v, enc)),
                        0u16,
                    )?;
                }
            }
        }
        bar.finish_and_clear();
        let mut apex_entry = apex_writer.finish()?;
        apex_entry.quantization = apex_q;
        Ok(vec![apex_entry, slope_writer.finish()?])
    }
}
