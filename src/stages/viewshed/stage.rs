//! The `viewshed` stage (the viewsheds of a list of observers, one band
//! each) and the `total_viewshed` stage (the visible area at every post).
//! Both read `height@0` whole into memory; their algorithms are in
//! [`crate::algorithms::viewshed::observer`] and [`crate::algorithms::viewshed::total`].

use std::path::Path;

use anyhow::Result;
use terrabake_format::layers::{TOTAL_VIEWSHED, VIEWSHED, VIEWSHED_ANGLE};
use terrabake_format::{Asset, Codec, ElemType, LayerEntry, LayerWriter, Mmap};

use crate::algorithms::viewshed::observer::{observer_viewshed, Observer, OUTSIDE};
use crate::algorithms::viewshed::total::{total_viewshed, Method, TotalOptions};
use crate::error::bail;
use crate::plumbing::progress::Progress;
use crate::stage::post_layer;
use crate::stage::sight::SightLines;
use crate::stage::{Share, Stage};
use crate::stages::viewshed::{check_height, observer_post, Crs};
use crate::terrain::held::HeldDem;
use crate::terrain::tiling::push_tile_row;

/// Bytes a post costs in memory beyond the DEM: the total viewshed's sum
/// (f64) per worker.
const TOTAL_BYTES_PER_POST_AND_WORKER: u64 = 8;

/// Refuses a DEM whose in-core work needs more than `max` bytes.
fn check_memory(stage: &str, w: usize, h: usize, per_post: u64, max: u64) -> Result<()> {
    let need = (w * h) as u64 * per_post;
    if need > max {
        bail!(
            "the {stage} stage holds this {w} x {h} DEM in memory: about {} MiB, over --max-memory {} MiB; raise --max-memory or crop the DEM",
            need >> 20,
            max >> 20
        );
    }
    Ok(())
}

/// The `viewshed` stage: `terrabake viewshed` for every observer of a list,
/// kept in the asset (layers `viewshed`, u8, and `viewshed_angle`, f32; one
/// band per observer, in the order given).
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewshedStage {
    /// An observer, X,Y in --crs (repeat for more; the nearest post is used).
    #[arg(long = "observer", required = true, value_parser = crate::stage::args::parse_xy, allow_hyphen_values = true)]
    pub observers: Vec<(f64, f64)>,
    /// The coordinates of the observers: native (the DEM's CRS), lonlat, grid (column,row).
    #[arg(long, value_enum, default_value = "native")]
    #[serde(default)]
    pub crs: Crs,
    /// Every observer's eye above the ground, metres.
    #[arg(long, default_value_t = super::DEFAULT_EYE_HEIGHT, allow_hyphen_values = true)]
    #[serde(default = "default_eye")]
    pub observer_height: f64,
    /// The target above the ground at every post, metres.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    #[serde(default)]
    pub target_height: f64,
    /// How far the observers see (targets beyond are outside) and how the Earth bends sight.
    #[command(flatten)]
    #[serde(flatten)]
    pub sight: SightLines,
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

fn default_eye() -> f64 {
    super::DEFAULT_EYE_HEIGHT
}

impl Stage for ViewshedStage {
    fn name(&self) -> &'static str {
        "viewshed"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("parameters serialise")
    }

    fn check(&self) -> crate::Result<()> {
        if self.observers.is_empty() {
            bail!("observers = [] (--observer X,Y) names no observer");
        }
        check_height("observer_height (--observer-height)", self.observer_height)?;
        check_height("target_height (--target-height)", self.target_height)?;
        self.sight.check()?;
        Ok(())
    }

    fn outputs(&self, _: &terrabake_format::Manifest) -> Vec<String> {
        vec![format!("{VIEWSHED}@0"), format!("{VIEWSHED_ANGLE}@0")]
    }

    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        _: &Share,
        progress: Progress,
    ) -> crate::Result<Vec<LayerEntry>> {
        let m = asset.manifest();
        let dem = HeldDem::read(asset)?;
        let (w, h, ts) = (dem.width, dem.height, m.tile_size as usize);
        let posts = self
            .observers
            .iter()
            .map(|&xy| observer_post(m, &dem, xy, self.crs))
            .collect::<crate::Result<Vec<_>>>()?;
        let terrain = dem.terrain(self.sight.curvature_coefficient(m));
        let bands = posts.len() as u32;
        let where_ = |(c, r): (usize, usize)| format!("({c}, {r})");
        let list = posts
            .iter()
            .map(|&p| where_(p))
            .collect::<Vec<_>>()
            .join(", ");
        let mut seen = LayerWriter::create(
            dir,
            post_layer(
                (VIEWSHED, "viewshed"),
                ElemType::U8,
                bands,
                (w, h, ts),
                format!("1 where the observer sees a target {} m above the post, 0 where not, 255 beyond the distance or on nodata; band per observer at posts {list}, eye {} m", self.target_height, self.observer_height),
                self.codec,
            ),
        )?;
        let mut angle = LayerWriter::create(
            dir,
            post_layer(
                (VIEWSHED_ANGLE, "viewshed"),
                ElemType::F32,
                bands,
                (w, h, ts),
                format!("elevation angle of the post from the observer's eye, degrees; band per observer at posts {list}"),
                self.codec,
            ),
        )?;
        let bar = progress.bar(posts.len() as u64, "viewsheds", "observers");
        // Band-major: every tile row of the first observer, then the next.
        for (col, row) in posts {
            let v = observer_viewshed(
                &terrain,
                &Observer {
                    col,
                    row,
                    height: self.observer_height,
                    target_height: self.target_height,
                    max_distance: self.sight.max_distance,
                },
            );
            for y0 in (0..h).step_by(ts) {
                let rows = y0 * w..(y0 + ts).min(h) * w;
                push_tile_row(&mut seen, &v.visible[rows.clone()], w, OUTSIDE)?;
                push_tile_row(&mut angle, &v.angle[rows], w, f32::NAN)?;
            }
            bar.inc(1);
        }
        bar.finish_and_clear();
        Ok(vec![seen.finish()?, angle.finish()?])
    }
}

/// The `total_viewshed` stage: at every post, the area an eye above it sees
/// within a distance (layer `total_viewshed`, f32 square metres, NaN on
/// nodata), by Timonen's sweeps with the convex hull tree.
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TotalViewshedStage {
    /// Number of azimuthal directions K (each a grid direction within 1/8 of the spacing).
    #[arg(long, default_value_t = Self::DEFAULT_DIRECTIONS, value_parser = crate::stage::args::parse_sectors)]
    pub directions: usize,
    /// The eye above every post, metres.
    #[arg(long, default_value_t = super::DEFAULT_EYE_HEIGHT, allow_hyphen_values = true)]
    pub observer_height: f64,
    /// How far each eye sees (terrain beyond is not counted) and how the Earth bends sight.
    #[command(flatten)]
    #[serde(flatten)]
    pub sight: SightLines,
    /// auto (the faster for the reach: naive below 500 posts of reach, else hull-tree),
    /// hull-tree (Timonen's convex hull tree) or naive (each post walks its lines). The same
    /// areas either way; not recorded.
    #[arg(long, value_enum, default_value = "auto")]
    #[serde(skip)]
    pub method: TotalMethod,
    /// Leave out the safe zone (Algorithm 3). Not recorded: it changes only the time.
    #[arg(long = "no-safe-zone", action = clap::ArgAction::SetFalse)]
    #[serde(skip, default = "yes")]
    pub safe_zone: bool,
    /// Working memory in MiB: the DEM and one sum per post and worker.
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
}

fn yes() -> bool {
    true
}

impl TotalViewshedStage {
    /// Directions unless told: 32.
    pub const DEFAULT_DIRECTIONS: usize = 32;
}

impl Default for TotalViewshedStage {
    fn default() -> Self {
        Self {
            directions: Self::DEFAULT_DIRECTIONS,
            observer_height: super::DEFAULT_EYE_HEIGHT,
            sight: SightLines::default(),
            method: TotalMethod::Auto,
            safe_zone: true,
            max_memory: crate::stage::mib::STAGE_DEFAULT_BYTES,
            codec: Codec::Raw,
        }
    }
}

/// How the total viewshed is computed (`--method`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum TotalMethod {
    #[default]
    Auto,
    HullTree,
    Naive,
}

/// Reach in posts below which `auto` walks each post's lines: measured on
/// the bundled SRTM tile with 32 directions (docs/BENCHMARKS.md), the naive
/// walk costs in proportion to the reach and the hull tree hardly depends
/// on it; the walk is 3.5x faster at 5 km (54 posts), 1.2x at 40 km, and
/// the tree 1.25x faster at 60 km (650 posts).
pub const NAIVE_BELOW_POSTS: f64 = 500.0;

impl TotalViewshedStage {
    /// The algorithm's options on a grid of spacing `spacing` (the smaller
    /// of dx and dy, metres).
    pub fn options(&self, spacing: f64) -> TotalOptions {
        let tree = Method::HullTree {
            safe_zone: self.safe_zone,
        };
        let method = match self.method {
            TotalMethod::HullTree => tree,
            TotalMethod::Naive => Method::Naive,
            TotalMethod::Auto => match self.sight.max_distance {
                Some(d) if d / spacing < NAIVE_BELOW_POSTS => Method::Naive,
                _ => tree,
            },
        };
        TotalOptions {
            height: self.observer_height,
            max_distance: self.sight.max_distance,
            directions: self.directions,
            method,
        }
    }

    /// Bytes the stage holds per post: the DEM and, for each worker thread
    /// and the sum, an area.
    pub(crate) fn bytes_per_post() -> u64 {
        let workers = rayon::current_num_threads() as u64;
        4 + TOTAL_BYTES_PER_POST_AND_WORKER * (workers + 1)
    }
}

impl Stage for TotalViewshedStage {
    fn name(&self) -> &'static str {
        "total_viewshed"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("parameters serialise")
    }

    fn check(&self) -> crate::Result<()> {
        check_height("observer_height (--observer-height)", self.observer_height)?;
        self.sight.check()?;
        crate::stage::args::parse_sectors(&self.directions.to_string())
            .map_err(|e| anyhow::anyhow!("directions = {} (--directions): {e}", self.directions))?;
        Ok(())
    }

    fn outputs(&self, _: &terrabake_format::Manifest) -> Vec<String> {
        vec![format!("{TOTAL_VIEWSHED}@0")]
    }

    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        _: &Share,
        progress: Progress,
    ) -> crate::Result<Vec<LayerEntry>> {
        let m = asset.manifest();
        let (w, h, ts) = (m.width as usize, m.height as usize, m.tile_size as usize);
        check_memory(
            "total_viewshed",
            w,
            h,
            Self::bytes_per_post(),
            self.max_memory,
        )?;
        let dem = HeldDem::read(asset)?;
        let terrain = dem.terrain(self.sight.curvature_coefficient(m));
        let bar = progress.bar(self.directions as u64, "total viewshed", "directions");
        let opts = self.options(m.cell_size.dx.min(m.cell_size.dy));
        let (area, _) = total_viewshed(&terrain, &opts, &|| bar.inc(1));
        bar.finish_and_clear();
        let area: Vec<f32> = area.iter().map(|&a| a as f32).collect();
        let mut writer = LayerWriter::create(
            dir,
            post_layer(
                (TOTAL_VIEWSHED, "total_viewshed"),
                ElemType::F32,
                1,
                (w, h, ts),
                format!(
                    "area seen from {} m above the post{}, square metres, {} directions ({})",
                    self.observer_height,
                    self.sight
                        .max_distance
                        .map_or(String::new(), |d| format!(" within {d} m")),
                    self.directions,
                    match opts.method {
                        Method::Naive => "each post's lines walked outwards",
                        Method::HullTree { .. } => "Timonen's sweeps with the convex hull tree",
                    }
                ),
                self.codec,
            ),
        )?;
        for y0 in (0..h).step_by(ts) {
            let rows = y0 * w..(y0 + ts).min(h) * w;
            push_tile_row(&mut writer, &area[rows], w, f32::NAN)?;
        }
        Ok(vec![writer.finish()?])
    }
}
