//! The `sky` stage: sky-view factors, openness and the edge count from the
//! committed `horizon` layer, read through the format crate's reader like
//! any renderer would (no read-back of uncommitted files). The integrals
//! are in [`crate::horizon::sky`] (Stewart 1998 sec. VI; Zakšek 2011;
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
    edge_distance_along, heading, HORIZON, HORIZON_EDGE, OPENNESS, SVF, SVF_COSINE,
};
use terrabake_format::{Asset, Codec, ElemType, LayerEntry, LayerWriter, Mmap, HEIGHT_LAYER};

use crate::horizon::sky::{BandIntegrals, SinCosMemo, SkySums};
use crate::horizon::terrain::{RowScale, Terrain};
use crate::horizon::{post_layer, HorizonsStage};
use crate::progress::Progress;
use crate::stage::{Share, Stage};
use crate::tiling::{push_fill_row, push_tile_row};

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
        crate::args::named(&Self::ALL, Self::name)
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
}

impl Default for SkyStage {
    fn default() -> Self {
        Self {
            layers: SkyLayer::ALL.to_vec(),
        }
    }
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

    fn check(&self) -> Result<()> {
        anyhow::ensure!(
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
    ) -> Result<Vec<LayerEntry>> {
        let horizons = HorizonsStage::recorded(asset)
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
        let [ax0, ay0, ax1, ay1] = horizons.area(w, h);
        let curvature = horizons.curvature_coefficient(asset);
        let row_scale = crate::geo::row_scale(m.georef.as_ref(), h as u32);
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
                );
                Ok((l, LayerWriter::create(dir, spec)?))
            })
            .collect::<Result<Vec<_>>>()?;
        let bar = progress.bar(h.div_ceil(ts) as u64, "sky layers", "tile rows");
        // Outside the area of interest every layer holds its fill value
        // (NaN, or no edge for the edge count): only its rows are computed.
        let wanted = share.rows_within(h, ay0..ay1);
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
            let mut z = vec![0f32; (r1 - r0) * w];
            height.read_window(0, 0, r0 as u32, w as u32, (r1 - r0) as u32, &mut z)?;
            let terrain = Terrain::window(&z, (w, h), r0, (dx, dy)).with_row_scale(row_scale);
            // Per post of the row: its normal (once, not once per band).
            let normals: Vec<Option<[f64; 3]>> = (0..rows * w)
                .into_par_iter()
                .map(|i| terrain.normal(i % w, y0 + i / w))
                .collect();
            let mut sums = vec![SkySums::default(); rows * w];
            let mut edges = vec![0u16; rows * w];
            let mut angles = vec![0f32; rows * w];
            for (b, &azimuth) in azimuths.iter().enumerate() {
                horizon.read_rows_f32(b as u32, y0 as u32, &mut angles)?;
                let towards = heading(azimuth);
                sums.par_chunks_mut(w)
                    .zip(edges.par_chunks_mut(w))
                    .zip(angles.par_chunks(w))
                    .enumerate()
                    .for_each_init(SinCosMemo::default, |memo, (r, ((sums, edges), angles))| {
                        let row = y0 + r;
                        for col in 0..w {
                            let hz = f64::from(angles[col]);
                            let Some(normal) = normals[r * w + col].filter(|_| !hz.is_nan()) else {
                                continue;
                            };
                            let (sh, ch) = memo.get(angles[col]);
                            sums[col].add(hz, (sh, ch), &integrals[b], normal);
                            // Could terrain no higher than the DEM's top, just
                            // past the edge, rise above this horizon?
                            let d = edge_distance_along(
                                (w as u32, h as u32),
                                (terrain.dx_at(row), dy),
                                (col as f64, row as f64),
                                towards,
                            );
                            // The rise's slope (z_max - z - c d^2) / d against
                            // tan h, both sides times d cos h (d, cos h >= 0).
                            let rise = z_max - f64::from(terrain.at(col, row)) - curvature * d * d;
                            if d == 0.0 || rise * ch > sh * d {
                                edges[col] += 1;
                            }
                        }
                    });
            }
            let inside = |i: usize| {
                let (x, y) = (i % w, y0 + i / w);
                (ax0..ax1).contains(&x) && (ay0..ay1).contains(&y) && !terrain.at(x, y).is_nan()
            };
            for (layer, writer) in &mut writers {
                if *layer == SkyLayer::HorizonEdge {
                    push_tile_row(writer, &edges, w, 0u16, Codec::Raw)?;
                    continue;
                }
                let values: Vec<f32> = (0..rows * w)
                    .map(|i| {
                        if inside(i) {
                            layer.value(&sums[i], edges[i]) as f32
                        } else {
                            f32::NAN
                        }
                    })
                    .collect();
                push_tile_row(writer, &values, w, f32::NAN, Codec::Raw)?;
            }
            bar.inc(1);
        }
        bar.finish_and_clear();
        writers.into_iter().map(|(_, w)| Ok(w.finish()?)).collect()
    }
}
