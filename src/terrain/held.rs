//! A whole DEM held in memory, as the in-core algorithms take it, and the
//! curvature coefficient an asset's georeferencing implies.

use anyhow::Result;
use terrabake_format::manifest::CrsKind;
use terrabake_format::{Asset, Mmap};

use crate::terrain::{self as terrain, RowScale, Terrain};

/// The curvature coefficient `c` of the drop `c d^2` on an asset: with
/// refraction coefficient `refraction` where `on` (by default, where the
/// DEM is georeferenced), else 0.
pub fn curvature_for(m: &terrabake_format::Manifest, on: Option<bool>, refraction: f64) -> f64 {
    let on = on.unwrap_or_else(|| {
        m.georef
            .as_ref()
            .is_some_and(|g| g.crs_kind != CrsKind::Unknown)
    });
    if on {
        terrain::curvature_coefficient(refraction)
    } else {
        0.0
    }
}

/// A whole DEM held in memory, as the in-core algorithms take it.
#[derive(Debug, Clone)]
pub struct HeldDem {
    pub z: Vec<f32>,
    pub width: usize,
    pub height: usize,
    pub dx: f64,
    pub dy: f64,
    /// [`crate::terrain::geo::row_scale`] of the grid.
    pub row_scale: Vec<f64>,
}

impl HeldDem {
    /// The asset's `height` layer, whole; refused before reading when the
    /// machine lacks the memory (4 bytes a post), naming the asset.
    pub fn read(asset: &Asset<Mmap>) -> crate::Result<Self> {
        let m = asset.manifest();
        crate::plumbing::resources::ensure_memory(
            4 * u64::from(m.width) * u64::from(m.height),
            &format!("{}: holding the whole DEM", asset.dir().display()),
        )?;
        let (z, width, height) = read_heights(asset)?;
        Ok(Self {
            z,
            width,
            height,
            dx: m.cell_size.dx,
            dy: m.cell_size.dy,
            row_scale: crate::terrain::geo::row_scale(m.georef.as_ref(), height as u32),
        })
    }

    /// The DEM as the algorithms see it, with curvature coefficient `c`.
    pub fn terrain(&self, curvature: f64) -> Terrain<'_> {
        Terrain::new(&self.z, self.width, self.height, self.dx, self.dy)
            .with_row_scale(RowScale::new(&self.row_scale))
            .with_curvature(curvature)
    }
}

/// Reads the whole `height` layer (NaN for nodata).
pub fn read_heights(asset: &Asset<Mmap>) -> crate::Result<(Vec<f32>, usize, usize)> {
    let height = asset.height()?;
    let (w, h) = (height.width() as usize, height.height() as usize);
    Ok((read_rows(height, 0..h)?, w, h))
}

/// Rows `rows` of the `height` layer, whole (NaN for nodata).
pub(crate) fn read_rows(
    height: &terrabake_format::Layer<Mmap>,
    rows: std::ops::Range<usize>,
) -> Result<Vec<f32>> {
    let w = height.width();
    let mut z = vec![0f32; w as usize * rows.len()];
    height.read_window(0, 0, rows.start as u32, w, rows.len() as u32, &mut z)?;
    Ok(z)
}
