//! A whole DEM held in memory, as the in-core algorithms take it, and the
//! curvature coefficient an asset's georeferencing implies.

use anyhow::Result;
use terrabake_format::manifest::CrsKind;
use terrabake_format::{Asset, Mmap};
use zerocopy::FromBytes;

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

/// A whole DEM as the in-core algorithms take it (one slice, row by row):
/// in memory, or, where it would not fit, spilled to a file the kernel
/// pages in and out ([`HeldDem::read_within`]).
#[derive(Debug)]
pub struct HeldDem {
    heights: Heights,
    pub width: usize,
    pub height: usize,
    pub dx: f64,
    pub dy: f64,
    /// [`crate::terrain::geo::row_scale`] of the grid.
    pub row_scale: Vec<f64>,
}

/// Where a [`HeldDem`]'s heights are.
#[derive(Debug)]
enum Heights {
    Memory(Vec<f32>),
    /// Row-major f32 in an unlinked temporary file, mapped read-only: its
    /// pages are the page cache's, which the kernel drops under pressure
    /// and reads again on the next touch, so the DEM costs no anonymous
    /// memory and a memory limit smaller than it still holds.
    Spilled(Mmap),
}

/// Rows a spill reads and writes at a time: at most this many bytes.
const SPILL_BATCH_BYTES: usize = 32 << 20;

impl HeldDem {
    /// The asset's `height` layer, whole, in memory; refused before reading
    /// when the machine lacks the memory (4 bytes a post), naming the asset.
    pub fn read(asset: &Asset<Mmap>) -> crate::Result<Self> {
        let m = asset.manifest();
        crate::plumbing::resources::ensure_memory(
            4 * u64::from(m.width) * u64::from(m.height),
            &format!("{}: holding the whole DEM", asset.dir().display()),
        )?;
        let (z, _, _) = read_heights(asset)?;
        Ok(Self::new(asset, Heights::Memory(z)))
    }

    /// The asset's `height` layer, whole: in memory when its 4 bytes a post
    /// take at most half of `allowance` (bytes; by default the memory the
    /// machine has available), else spilled (see [`Heights`]), written a
    /// few rows at a time, so that a DEM larger than the memory allowed is
    /// read as a slice all the same (the planner's pilot and `check` walk
    /// sight lines anywhere in it). The spill file is unlinked as it is
    /// made: nothing is left behind on any exit.
    pub fn read_within(asset: &Asset<Mmap>, allowance: Option<u64>) -> crate::Result<Self> {
        let m = asset.manifest();
        let bytes = 4 * u64::from(m.width) * u64::from(m.height);
        let allowance = allowance
            .into_iter()
            .chain(crate::plumbing::resources::available_memory())
            .min();
        if allowance.is_none_or(|a| bytes <= a / 2) {
            return Self::read(asset);
        }
        let place = std::env::temp_dir();
        crate::plumbing::resources::ensure_disk(
            &place.join("terrabake-heights"),
            bytes,
            &format!("spilling the heights of {}", asset.dir().display()),
        )?;
        let spill = |e: std::io::Error| {
            anyhow::anyhow!(
                "{}: spilling the heights to {}: {e}",
                asset.dir().display(),
                place.display()
            )
        };
        let mut file = tempfile::tempfile_in(&place).map_err(spill)?;
        let height = asset.height()?;
        let (w, h) = (m.width as usize, m.height as usize);
        let rows = (SPILL_BATCH_BYTES / (4 * w)).max(1);
        let mut out = std::io::BufWriter::new(&mut file);
        for y0 in (0..h).step_by(rows) {
            let z = read_rows(height, y0..(y0 + rows).min(h))?;
            std::io::Write::write_all(&mut out, zerocopy::IntoBytes::as_bytes(&z[..]))
                .map_err(spill)?;
        }
        std::io::Write::flush(&mut out).map_err(spill)?;
        drop(out);
        // SAFETY: the file is this process's alone (unlinked at creation),
        // and nothing writes it once mapped.
        let map = unsafe { Mmap::map(&file) }.map_err(spill)?;
        Ok(Self::new(asset, Heights::Spilled(map)))
    }

    /// Heights already in memory (`width x height`, row by row).
    pub fn in_memory(
        z: Vec<f32>,
        (width, height): (usize, usize),
        (dx, dy): (f64, f64),
        row_scale: Vec<f64>,
    ) -> Self {
        assert_eq!(z.len(), width * height, "{width} x {height} posts");
        Self {
            heights: Heights::Memory(z),
            width,
            height,
            dx,
            dy,
            row_scale,
        }
    }

    /// The asset's grid, with its heights where `heights` says.
    fn new(asset: &Asset<Mmap>, heights: Heights) -> Self {
        let m = asset.manifest();
        Self {
            heights,
            width: m.width as usize,
            height: m.height as usize,
            dx: m.cell_size.dx,
            dy: m.cell_size.dy,
            row_scale: crate::terrain::geo::row_scale(m.georef.as_ref(), m.height),
        }
    }

    /// The heights, row by row (NaN for nodata).
    pub fn z(&self) -> &[f32] {
        match &self.heights {
            Heights::Memory(z) => z,
            Heights::Spilled(map) => {
                <[f32]>::ref_from_bytes(&map[..]).expect("a page-aligned map of whole f32s")
            }
        }
    }

    /// Whether the heights were spilled to a file rather than held.
    pub fn spilled(&self) -> bool {
        matches!(self.heights, Heights::Spilled(_))
    }

    /// Bytes the heights hold in anonymous memory (none when spilled).
    pub fn held_bytes(&self) -> u64 {
        match &self.heights {
            Heights::Memory(z) => 4 * z.len() as u64,
            Heights::Spilled(_) => 0,
        }
    }

    /// The DEM as the algorithms see it, with curvature coefficient `c`.
    pub fn terrain(&self, curvature: f64) -> Terrain<'_> {
        Terrain::new(self.z(), self.width, self.height, self.dx, self.dy)
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
