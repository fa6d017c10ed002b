//! HORAYZON's terrain correction factor for direct shortwave at given sun
//! positions, from the stored horizons and heights
//! (`terrabake solar ASSET --sun AZ,EL ... -o OUT.tif`, and
//! `terrabake.direct_correction` in Python): one band per sun, the factor
//! [`crate::algorithms::solar::direct_correction`] at every post.
//!
//! Climate, snow and glacier models (COSIPY, ICON's subgrid radiation)
//! take the factor from a lookup by the sun's azimuth and elevation and
//! multiply their flat-plane direct irradiance by it each time step; a
//! band per position of such a table is this file. Where HORAYZON traces
//! a ray per post and sun, a post here reads its horizon as the loader serves it
//! at the sun's azimuth (between the two bands around it, and any listed
//! features), the same shadow test as the solar
//! stage. Rows stream through the GeoTIFF writer a tile row at a time, so
//! memory is bounded as every export's is.

use std::path::Path;

use anyhow::{Context, Result};
use terrabake_format::horizons::{HorizonMap, HORIZON};
use terrabake_format::{Asset, Layer, Mmap};

use super::{cog_for_layer, TiffOptions};
use crate::algorithms::solar::direct_correction;
use crate::io::cog::{BandMetadata, Cog, Metadata};
use crate::plumbing::progress::Progress;
use crate::terrain::sun::Sun;
use crate::terrain::{RowScale, Terrain};

/// What every row of the factor reads: the heights, the horizon layer, and
/// the grid's geometry.
#[derive(Debug)]
pub struct Correction<'a> {
    height: &'a Layer<Mmap>,
    horizon: HorizonMap<'a, Mmap>,
    row_scale: Vec<f64>,
    cell: (f64, f64),
    /// Degrees from true north to grid north, clockwise.
    convergence: f64,
    /// Times HORAYZON's surface enlargement factor `1 / n_z`: the flux per
    /// unit of horizontal area rather than of the surface's own.
    pub per_horizontal_area: bool,
}

impl<'a> Correction<'a> {
    pub fn new(asset: &'a Asset<Mmap>) -> crate::Result<Self> {
        let m = asset.manifest();
        asset
            .layer(HORIZON, 0)
            .context("the asset has no horizon layer; run `terrabake horizons` first")?;
        let horizon = HorizonMap::open(asset)?;
        let (w, h) = (m.width, m.height);
        let georef = m.georef.as_ref();
        Ok(Self {
            height: asset.height()?,
            horizon,
            row_scale: crate::terrain::geo::row_scale(georef, h),
            cell: (m.cell_size.dx, m.cell_size.dy),
            convergence: georef.map_or(0.0, |g| crate::terrain::geo::grid_convergence(g, w, h)),
            per_horizontal_area: false,
        })
    }

    /// The factor for `sun` (true azimuth, elevation) at every post of the
    /// rows from `y0` that `out` holds (whole rows), NaN for nodata.
    pub fn rows(&self, sun: Sun, y0: u32, out: &mut [f32]) -> crate::Result<()> {
        let (w, h) = (self.height.width() as usize, self.height.height() as usize);
        let (y0, rows) = (y0 as usize, out.len() / w);
        let grid = Sun {
            azimuth: sun.azimuth - self.convergence,
            ..sun
        };
        let s = grid.direction();
        // The normals need the rows either side.
        let (r0, r1) = (y0.saturating_sub(1), (y0 + rows + 1).min(h));
        let mut z = vec![0f32; (r1 - r0) * w];
        self.height
            .read_window(0, 0, r0 as u32, w as u32, (r1 - r0) as u32, &mut z)?;
        let terrain = Terrain::window(&z, (w, h), r0, self.cell)
            .with_row_scale(RowScale::new(&self.row_scale));
        // The horizon towards the sun, as `lit_fraction` serves it.
        let mut towards_sun = vec![0f32; out.len()];
        (self.horizon).served_rows(grid.azimuth.rem_euclid(360.0), y0 as u32, &mut towards_sun)?;
        for (k, o) in out.iter_mut().enumerate() {
            let (x, row) = (k % w, y0 + k / w);
            let horizon = f64::from(towards_sun[k]);
            *o = match terrain.normal(x, row) {
                Some(n) if !horizon.is_nan() => {
                    let f = direct_correction(n, horizon, s);
                    (if self.per_horizontal_area {
                        f / n[2]
                    } else {
                        f
                    }) as f32
                }
                _ => f32::NAN,
            };
        }
        Ok(())
    }
}

/// Writes the factor for each of `suns` as one band of a GeoTIFF at
/// `out`, georeferenced as the asset, each band named by its sun.
pub fn write_direct_correction(
    asset: &Asset<Mmap>,
    suns: &[Sun],
    per_horizontal_area: bool,
    out: &Path,
    progress: Progress,
) -> Result<()> {
    let mut correction = Correction::new(asset)?;
    correction.per_horizontal_area = per_horizontal_area;
    let bands = u16::try_from(suns.len()).context("more suns than a GeoTIFF has bands")?;
    // The horizon layer's frame: its georeferencing, and NaN for nodata.
    let base = cog_for_layer(asset, correction.horizon.layer(), &TiffOptions::default())?;
    let per = if per_horizontal_area {
        "per unit of horizontal area"
    } else {
        "per unit of surface area"
    };
    let mut dataset = base.metadata.dataset.clone();
    dataset.retain(|(k, _)| k == "TERRABAKE_VERSION" || k == "TERRABAKE_SOURCE");
    dataset.push((
        "TERRABAKE_DESCRIPTION".into(),
        format!(
            "terrain correction factor for direct shortwave (HORAYZON's sw_dir_cor), {per}: \
             the direct irradiance on the surface over that on a flat open plane"
        ),
    ));
    let cog = Cog {
        bands,
        metadata: Metadata {
            dataset,
            bands: suns
                .iter()
                .map(|s| BandMetadata {
                    description: format!(
                        "direct shortwave correction factor, sun at azimuth {} deg, elevation {} deg",
                        s.azimuth, s.elevation
                    ),
                    unit: "1".into(),
                    items: vec![
                        ("SUN_AZIMUTH".into(), s.azimuth.to_string()),
                        ("SUN_ELEVATION".into(), s.elevation.to_string()),
                    ],
                })
                .collect(),
        },
        ..base
    };
    let bar = progress.bar(
        u64::from(correction.height.height()) * suns.len() as u64,
        "correction",
        "rows",
    );
    cog.write(
        out,
        |band, y0, rows| Ok(correction.rows(suns[band as usize], y0, rows)?),
        |n| bar.inc(n),
    )?;
    bar.finish_and_clear();
    Ok(())
}
