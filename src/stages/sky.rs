//! The `sky` stage: sky-view factors, openness and the edge count from the
//! committed `horizon` layer, read through the format crate's reader like
//! any renderer would (no read-back of uncommitted files). The integrals
//! are in [`crate::algorithms::horizon::sky`] (Stewart 1998 sec. VI; Zakšek 2011;
//! Yokoyama 2002; docs/HORIZONS.md).
//!
//! Inputs: `height@0` (normals, the edge test) and `horizon@0` (every band,
//! its `band_azimuths`), with the horizons stage's recorded parameters for
//! the area of interest and the curvature. Outputs: any subset of `svf`,
//! `svf_cosine`, `openness`, `horizon_edge` (all by default), one element per
//! post, NaN (0 for the edge count) outside the area or on nodata. Reach:
//! one post (the normals), computed tile row by tile row.

use std::path::Path;

use anyhow::{Context, Result};
use rayon::prelude::*;
use terrabake_format::horizons::{
    edge_may_cut, edge_reach, heading, HORIZON, HORIZON_EDGE, OPENNESS, SVF, SVF_COSINE,
};
use terrabake_format::{Asset, Codec, ElemType, LayerEntry, LayerWriter, Mmap, HEIGHT_LAYER};

use crate::algorithms::horizon::sky::{band_terms, sin_cos_deg, BandIntegrals, SkySums};
use crate::plumbing::progress::Progress;
use crate::stage::post_layer;
use crate::stage::sight::SightLines;
use crate::stage::{Share, Stage};
use crate::terrain::tiling::{push_fill_row, push_tile_row, release_tile_row};
use crate::terrain::{RowScale, Terrain};

/// One of the layers the stage can write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SkyLayer {
    Svf,
    SvfCosine,
    Openness,
    HorizonEdge,
}

impl SkyLayer {
    pub const ALL: [SkyLayer; 4] = [
        SkyLayer::Svf,
        SkyLayer::SvfCosine,
        SkyLayer::Openness,
        SkyLayer::HorizonEdge,
    ];

    /// The layer's name in the asset (and on the command line).
    pub fn name(self) -> &'static str {
        match self {
            SkyLayer::Svf => SVF,
            SkyLayer::SvfCosine => SVF_COSINE,
            SkyLayer::Openness => OPENNESS,
            SkyLayer::HorizonEdge => HORIZON_EDGE,
        }
    }

    fn parser() -> impl clap::builder::TypedValueParser<Value = SkyLayer> {
        crate::stage::args::named(&Self::ALL, Self::name)
    }

    fn elem(self) -> ElemType {
        match self {
            SkyLayer::HorizonEdge => ElemType::U16,
            _ => ElemType::F32,
        }
    }

    fn description(self) -> &'static str {
        match self {
            SkyLayer::Svf => "sky-view factor, solid angle of visible sky over the hemisphere above the horizontal: 1 - mean sin(max(h, 0)) (Zakšek 2011)",
            SkyLayer::SvfCosine => "sky-view factor, cosine-weighted from the tilted surface: (1/pi) integral of N.u over the visible sky (Dozier-Frew 1990, Stewart 1998 sec. VI)",
            SkyLayer::Openness => "positive openness, degrees: mean zenith angle of the horizon (Yokoyama 2002)",
            SkyLayer::HorizonEdge => "bands in which terrain beyond the DEM's edge, no higher than the DEM's highest post, could rise above the horizon",
        }
    }

    /// The layer's value at a post from the sums over its bands.
    fn value(self, sums: &SkySums, edges: u16) -> f64 {
        match self {
            SkyLayer::Svf => sums.svf(),
            SkyLayer::SvfCosine => sums.svf_cosine(),
            SkyLayer::Openness => sums.openness(),
            SkyLayer::HorizonEdge => f64::from(edges),
        }
    }
}

/// The `sky` stage and its parameters (`terrabake sky`, recipe step `sky`).
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SkyStage {
    /// The layers to write, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "svf,svf_cosine,openness,horizon_edge",
        value_parser = SkyLayer::parser()
    )]
    pub layers: Vec<SkyLayer>,
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

impl Default for SkyStage {
    fn default() -> Self {
        Self {
            layers: SkyLayer::ALL.to_vec(),
            codec: Codec::Raw,
        }
    }
}

/// What the sky stage reads of the horizons stage's record: the area of
/// interest and the sight lines the angles were computed with, for their
/// curvature (the record's other parameters are the horizons stage's own).
#[derive(serde::Deserialize)]
struct HorizonsRecord {
    aoi: Option<crate::stage::args::Aoi>,
    #[serde(flatten)]
    sight: SightLines,
}

impl Stage for SkyStage {
    fn name(&self) -> &'static str {
        "sky"
    }

    fn params(&self) -> serde_json::Value {
        serde_json::to_value(self).expect("parameters serialise")
    }

    fn inputs(&self) -> Vec<String> {
        vec![format!("{HEIGHT_LAYER}@0"), format!("{HORIZON}@0")]
    }

    fn check(&self) -> crate::Result<()> {
        crate::error::ensure!(
            !self.layers.is_empty(),
            "layers = [] (--layers) names no layer"
        );
        Ok(())
    }

    fn outputs(&self, _: &terrabake_format::Manifest) -> Vec<String> {
        self.layers
            .iter()
            .map(|l| format!("{}@0", l.name()))
            .collect()
    }

    /// The normals need the posts around each post; `horizon_edge` asks how
    /// far the DEM's edge is, which only the whole DEM knows.
    fn reach(&self, _: &terrabake_format::Manifest) -> crate::stage::Reach {
        if self.layers.contains(&SkyLayer::HorizonEdge) {
            crate::stage::Reach::Whole
        } else {
            crate::stage::Reach::Posts(1)
        }
    }

    /// Tile rows outside the share's rows are not computed.
    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        share: &Share,
        progress: Progress,
    ) -> crate::Result<Vec<LayerEntry>> {
        let horizons: HorizonsRecord = crate::stage::recorded_params(asset.manifest(), "horizons")
            .context("the asset has no horizons record; run `terrabake horizons` first")?;
        let m = asset.manifest();
        let height = asset.height()?;
        let horizon = asset
            .layer(HORIZON, 0)
            .context("the asset has no horizon layer; run `terrabake horizons` first")?;
        let (w, h, ts) = (
            height.width() as usize,
            height.height() as usize,
            height.tile_size() as usize,
        );
        let azimuths = &horizon.entry().band_azimuths;
        let integrals = BandIntegrals::of_azimuths(azimuths);
        let [ax0, ay0, ax1, ay1] = crate::stage::args::area_of(horizons.aoi, w, h);
        let curvature = horizons.sight.curvature_coefficient(m);
        let row_scale = crate::terrain::geo::row_scale(m.georef.as_ref(), h as u32);
        let row_scale = RowScale::new(&row_scale);
        let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
        let z_max = m.height_range.map_or(f64::INFINITY, |r| f64::from(r.max));
        let mut writers = self
            .layers
            .iter()
            .map(|&l| {
                let spec = post_layer(
                    (l.name(), "sky"),
                    l.elem(),
                    1,
                    (w, h, ts),
                    l.description().into(),
                    self.codec,
                );
                Ok((l, LayerWriter::create(dir, spec)?))
            })
            .collect::<Result<Vec<_>>>()?;
        let bar = progress.bar(h.div_ceil(ts) as u64, "sky layers", "tile rows");
        // Outside the area of interest every layer holds its fill value
        // (NaN, or no edge for the edge count): only its rows are computed.
        let wanted = share.rows_within(h, ay0..ay1);
        // Buffers kept from tile row to tile row: fresh ones cost a page
        // fault a page (a third of the stage's time went to the kernel).
        let mut z = Vec::new();
        let mut post_rows: Vec<PostRow> = Vec::new();
        let mut values = Vec::new();
        let towards: Vec<_> = azimuths.iter().map(|&a| heading(a)).collect();
        for y0 in (0..h).step_by(ts) {
            let rows = ts.min(h - y0);
            if y0 >= wanted.end || y0 + rows <= wanted.start {
                for (_, writer) in &mut writers {
                    push_fill_row(writer)?;
                }
                bar.inc(1);
                continue;
            }
            let (r0, r1) = (y0.saturating_sub(1), (y0 + rows + 1).min(h));
            z.resize((r1 - r0) * w, 0.0);
            height.read_window(0, 0, r0 as u32, w as u32, (r1 - r0) as u32, &mut z)?;
            let terrain = Terrain::window(&z, (w, h), r0, (dx, dy)).with_row_scale(row_scale);
            // Row by row in parallel: its posts' normals (once, not once
            // per band), then its bands in order, each decoded by the
            // thread that sums it (one fork a tile row, not one a band,
            // and no band decoded while the other core waits).
            post_rows.resize_with(rows, || PostRow::with_width(w));
            post_rows.par_iter_mut().enumerate().try_for_each_init(
                || vec![0f32; w],
                |angles, (r, post_row)| -> terrabake_format::Result<()> {
                    let row = y0 + r;
                    post_row.start(&terrain, row);
                    for (b, &towards) in towards.iter().enumerate() {
                        horizon.read_rows_f32(b as u32, row as u32, angles)?;
                        let edge = EdgeTest {
                            z: &terrain.z[(row - r0) * w..][..w],
                            size: (w as u32, h as u32),
                            spacing: (terrain.dx_at(row), dy),
                            row: row as f64,
                            towards,
                            z_max,
                            curvature,
                        };
                        post_row.add_band(&integrals[b], angles, &edge);
                    }
                    Ok(())
                },
            )?;
            for (layer, writer) in &mut writers {
                if *layer == SkyLayer::HorizonEdge {
                    let edges: Vec<u16> = post_rows
                        .iter()
                        .flat_map(|p| p.edges.iter().copied())
                        .collect();
                    push_tile_row(writer, &edges, w, 0u16)?;
                    continue;
                }
                // Values inside the area of interest, row by row.
                values.clear();
                values.resize(rows * w, f32::NAN);
                values
                    .par_chunks_mut(w)
                    .zip(post_rows.par_iter())
                    .enumerate()
                    .filter(|(r, _)| (ay0..ay1).contains(&(y0 + r)))
                    .for_each(|(r, (values, post_row))| {
                        let x0 = ax0.min(w);
                        let columns = x0..ax1.clamp(x0, w);
                        for (x, v) in columns.clone().zip(&mut values[columns]) {
                            if !terrain.at(x, y0 + r).is_nan() {
                                *v = layer.value(&post_row.sums(x), post_row.edges[x]) as f32;
                            }
                        }
                    });
                push_tile_row(writer, &values, w, f32::NAN)?;
            }
            release_tile_row(horizon, (y0 / ts) as u32)?;
            bar.inc(1);
        }
        bar.finish_and_clear();
        writers.into_iter().map(|(_, w)| Ok(w.finish()?)).collect()
    }
}

/// One row of posts as the stage sums it, in columns (structure of
/// arrays): the unit normals (NaN where a post has none) and the running
/// sums and edge counts over the bands so far. A band over a
/// whole row is then one loop without branches or calls, which the
/// compiler turns into vector code ([`PostRow::add_band`]).
#[derive(Debug)]
struct PostRow {
    normal: [Vec<f64>; 3],
    sin: Vec<f64>,
    zenith: Vec<f64>,
    cosine: Vec<f64>,
    edges: Vec<u16>,
}

/// What the edge count asks of one band on one row: could terrain no
/// higher than the DEM's top, just past the edge, rise above a horizon?
#[derive(Debug, Clone, Copy)]
struct EdgeTest<'a> {
    /// The row's heights.
    z: &'a [f32],
    size: (u32, u32),
    spacing: (f64, f64),
    row: f64,
    towards: (f64, f64),
    z_max: f64,
    curvature: f64,
}

impl PostRow {
    /// A row `w` posts wide, to be [`Self::start`]ed.
    fn with_width(w: usize) -> Self {
        Self {
            normal: [vec![0.0; w], vec![0.0; w], vec![0.0; w]],
            sin: vec![0.0; w],
            zenith: vec![0.0; w],
            cosine: vec![0.0; w],
            edges: vec![0; w],
        }
    }

    /// Row `row` of `terrain` (as wide as this), no band summed yet.
    fn start(&mut self, terrain: &Terrain, row: usize) {
        for col in 0..terrain.width {
            let n = terrain.normal(col, row).unwrap_or([f64::NAN; 3]);
            for (axis, v) in self.normal.iter_mut().zip(n) {
                axis[col] = v;
            }
        }
        for sums in [&mut self.sin, &mut self.zenith, &mut self.cosine] {
            sums.fill(0.0);
        }
        self.edges.fill(0);
    }

    fn sums(&self, col: usize) -> SkySums {
        SkySums::from_parts(self.sin[col], self.zenith[col], self.cosine[col])
    }

    /// Adds band `band`, whose angles on this row are `angles` (degrees,
    /// NaN for none), to every post of the row: the widest vectors this
    /// machine has, the same bits on every machine (no fused multiply-adds).
    fn add_band(&mut self, band: &BandIntegrals, angles: &[f32], edge: &EdgeTest) {
        use crate::plumbing::simd::Level;
        match crate::plumbing::simd::level() {
            // SAFETY: `simd::level` found AVX-512, which the function is
            // compiled for.
            #[cfg(target_arch = "x86_64")]
            Level::Avx512 => unsafe { self.add_band_avx512(band, angles, edge) },
            // SAFETY: the same, for AVX2.
            #[cfg(target_arch = "x86_64")]
            Level::Avx2 => unsafe { self.add_band_avx2(band, angles, edge) },
            _ => self.add_band_portable(band, angles, edge),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn add_band_avx512(&mut self, band: &BandIntegrals, angles: &[f32], edge: &EdgeTest) {
        self.add_band_portable(band, angles, edge);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn add_band_avx2(&mut self, band: &BandIntegrals, angles: &[f32], edge: &EdgeTest) {
        self.add_band_portable(band, angles, edge);
    }

    #[inline(always)]
    fn add_band_portable(&mut self, band: &BandIntegrals, angles: &[f32], edge: &EdgeTest) {
        let w = self.sin.len();
        let (angles, [nx, ny, nz]) = (&angles[..w], &self.normal);
        let (nx, ny, nz) = (&nx[..w], &ny[..w], &nz[..w]);
        let (sin, zenith, cosine) = (
            &mut self.sin[..w],
            &mut self.zenith[..w],
            &mut self.cosine[..w],
        );
        let (z, edges) = (&edge.z[..w], &mut self.edges[..w]);
        let reach_down = edge_reach(edge.row, edge.towards.1, edge.size.1, edge.spacing.1);
        for col in 0..w {
            let h = f64::from(angles[col]);
            let (sh, ch) = sin_cos_deg(h);
            let [s, o, c] = band_terms(h, (sh, ch), band, [nx[col], ny[col], nz[col]]);
            // A post without a normal or an angle keeps its sums (adding 0
            // to them changes no bits: they start at +0).
            let valid = !(h.is_nan() || nz[col].is_nan());
            sin[col] += if valid { s } else { 0.0 };
            zenith[col] += if valid { o } else { 0.0 };
            cosine[col] += if valid { c } else { 0.0 };
            // `edge_distance_along`, its row's part taken once.
            let d =
                edge_reach(col as f64, edge.towards.0, edge.size.0, edge.spacing.0).min(reach_down);
            let rise = edge.z_max - f64::from(z[col]) - edge.curvature * d * d;
            edges[col] += u16::from(valid && edge_may_cut(rise, d, (sh, ch)));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrabake_format::horizons::edge_distance_along;

    /// The row kernel, on every path this CPU has, against the scalar
    /// definition (libm's sine and cosine, [`SkySums::add`], the loader's
    /// edge distance) on random terrain with nodata and random horizons
    /// with gaps: the same sums to rounding and the same edge counts.
    #[test]
    fn a_row_of_posts_sums_as_post_by_post() {
        let (w, h) = (203, 5);
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut random = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let z: Vec<f32> = (0..w * h)
            .map(|_| {
                let v = random();
                if v < 0.05 {
                    f32::NAN
                } else {
                    (v * 900.0) as f32
                }
            })
            .collect();
        let terrain = Terrain::window(&z, (w, h), 0, (30.0, 25.0));
        let azimuths: Vec<f64> = (0..8).map(|i| f64::from(i) * 45.0 + 3.0).collect();
        let integrals = BandIntegrals::of_azimuths(&azimuths);
        let angles: Vec<Vec<f32>> = (0..azimuths.len())
            .map(|_| {
                (0..w)
                    .map(|_| match random() {
                        v if v < 0.05 => f32::NAN,
                        v => (v * 180.0 - 90.0) as f32,
                    })
                    .collect()
            })
            .collect();
        let row = 2;
        let edge_of = |b: usize| EdgeTest {
            z: &z[row * w..][..w],
            size: (w as u32, h as u32),
            spacing: (30.0, 25.0),
            row: row as f64,
            towards: heading(azimuths[b]),
            z_max: 950.0,
            curvature: 6.8e-8,
        };
        type Path = fn(&mut PostRow, &BandIntegrals, &[f32], &EdgeTest);
        let mut paths: Vec<(&str, Path)> = vec![
            ("dispatched", PostRow::add_band),
            ("portable", PostRow::add_band_portable),
        ];
        #[cfg(target_arch = "x86_64")]
        if crate::plumbing::simd::level() >= crate::plumbing::simd::Level::Avx2 {
            // SAFETY: the CPU has AVX2.
            paths.push(("avx2", |p, b, a, e| unsafe { p.add_band_avx2(b, a, e) }));
        }
        for (name, add_band) in paths {
            let mut post_row = PostRow::with_width(terrain.width);
            post_row.start(&terrain, row);
            for (b, angles) in angles.iter().enumerate() {
                add_band(&mut post_row, &integrals[b], angles, &edge_of(b));
            }
            let mut tested = 0;
            for col in 0..w {
                let mut want = SkySums::default();
                let mut edges = 0;
                for (b, angles) in angles.iter().enumerate() {
                    let hz = f64::from(angles[col]);
                    let Some(normal) = terrain.normal(col, row).filter(|_| !hz.is_nan()) else {
                        continue;
                    };
                    let (sh, ch) = hz.to_radians().sin_cos();
                    want.add(hz, (sh, ch), &integrals[b], normal);
                    let e = edge_of(b);
                    let d = edge_distance_along(e.size, e.spacing, (col as f64, e.row), e.towards);
                    let rise = e.z_max - f64::from(terrain.at(col, row)) - e.curvature * d * d;
                    edges += u16::from(edge_may_cut(rise, d, (sh, ch)));
                    tested += 1;
                }
                let got = post_row.sums(col);
                for (g, w) in [
                    (got.svf(), want.svf()),
                    (got.svf_cosine(), want.svf_cosine()),
                    (got.openness(), want.openness()),
                ] {
                    assert!(
                        (g - w).abs() <= 1e-12 * w.abs().max(1.0),
                        "{name} col {col}: {g} against {w}"
                    );
                }
                assert_eq!(post_row.edges[col], edges, "{name} col {col}");
            }
            assert!(tested > 1000, "{name}: {tested} post-bands");
        }
    }
}
