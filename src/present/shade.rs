//! Overhead shaded maps from stored horizons alone, as Stewart's (1998)
//! Figs. 9-10: no ray is traced, so a day's worth of sun positions costs one
//! horizon bake.
//!
//! - `sky`: Stewart and Langer's radiosity (sec. VI-A) of every post under a
//!   uniform overcast sky, albedo 0.5: valleys darken by what they cannot
//!   see of the sky and by what they see of each other.
//! - `sun:AZ,EL`: the sun's disc (radius 0.27 degrees) through
//!   `lit_fraction` times `N.s`, plus Stewart's sky of Fig. 9 (`cos^20` of
//!   the angle to the sun, and a faint uniform part), through the same
//!   radiosity model.

use std::path::Path;

use anyhow::Result;
use rayon::prelude::*;
use terrabake_format::horizons::{disc_fraction_above, HorizonMap};
use terrabake_format::{Asset, Mmap};

use crate::algorithms::horizon::band_bounds;
use crate::algorithms::horizon::sky::{radiosity, sun_glow, SkyTable};
use crate::present::image::Image;
use crate::present::legend::{Legend, Ramp, Stretch};
use crate::stages::horizons::read_horizons;
use crate::terrain::held::read_heights;
use crate::terrain::sun::Sun;
use crate::terrain::{RowScale, Terrain};

/// What lights the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shade {
    Sky,
    Sun(Sun),
}

impl std::str::FromStr for Shade {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "sky" {
            return Ok(Shade::Sky);
        }
        let rest = s
            .strip_prefix("sun:")
            .ok_or_else(|| format!("{s:?}: expected sky or sun:AZIMUTH,ELEVATION"))?;
        crate::stage::args::parse_sun(rest).map(Shade::Sun)
    }
}

const ALBEDO: f64 = 0.5;
const SUN_RADIUS: f64 = 0.27;

/// The light on every post as a share of what a flat, open plain receives
/// under the same sky and sun (NaN for nodata or no horizon), row-major.
pub(crate) fn shade_posts(asset: &Asset<Mmap>, shade: Shade) -> Result<(Vec<f32>, usize, usize)> {
    use std::f64::consts::PI;
    // The stage's cosine sky-view factor is the uniform sky's irradiance / pi.
    let svf_layer = asset
        .layer(terrabake_format::horizons::SVF_COSINE, 0)
        .map_err(|e| {
            anyhow::anyhow!(
                "{e}: shaded maps need the horizons stage (terrabake horizons {})",
                asset.dir().display()
            )
        })?;
    let (w, h) = (svf_layer.width() as usize, svf_layer.height() as usize);
    let mut svf_cosine = vec![0f32; w * h];
    svf_layer.read_rows_f32(0, 0, &mut svf_cosine)?;
    let mut out: Vec<f32> = svf_cosine
        .iter()
        .map(|&f| radiosity(PI * f64::from(f), f64::from(f), ALBEDO) as f32)
        .collect();
    let mut plain = radiosity(PI, 1.0, ALBEDO);
    if let Shade::Sun(sun) = shade {
        let (z, _, _) = read_heights(asset)?;
        let (bands, azimuths) = read_horizons(asset)?;
        let cs = &asset.manifest().cell_size;
        let row_scale = crate::terrain::geo::row_scale(asset.manifest().georef.as_ref(), h as u32);
        let terrain =
            Terrain::new(&z, w, h, cs.dx, cs.dy).with_row_scale(RowScale::new(&row_scale));
        let per_band = (64 / azimuths.len()).clamp(1, 8);
        let table = SkyTable::new(
            &band_bounds(&azimuths),
            per_band,
            256,
            sun_glow(sun.azimuth, sun.elevation, 20, 0.05),
        );
        let s = sun.direction();
        // The horizon towards the sun, as `lit_fraction` serves it.
        let mut towards_sun = vec![0f32; w * h];
        HorizonMap::open(asset)?.served_rows(sun.azimuth, 0, &mut towards_sun)?;
        // The light on a surface with unit `normal`, horizon `horizon`,
        // `hz` towards the sun, and cosine sky-view factor `svf_cosine`.
        let light = |normal: [f64; 3], horizon: &[f32], hz: f64, svf_cosine: f64| {
            let lit = disc_fraction_above(sun.elevation, hz, SUN_RADIUS);
            let direct = lit * (normal[0] * s[0] + normal[1] * s[1] + normal[2] * s[2]).max(0.0);
            radiosity(
                PI * direct + table.irradiance(normal, horizon),
                svf_cosine,
                ALBEDO,
            )
        };
        plain = light([0.0, 0.0, 1.0], &vec![0f32; bands.len()], 0.0, 1.0);
        out.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
            let mut horizon = vec![0f32; bands.len()];
            for (col, o) in out.iter_mut().enumerate() {
                let i = row * w + col;
                for (b, band) in bands.iter().enumerate() {
                    horizon[b] = band[i];
                }
                let Some(normal) = terrain.normal(col, row) else {
                    continue;
                };
                if o.is_nan() || horizon.iter().any(|v| v.is_nan()) {
                    continue;
                }
                let hz = f64::from(towards_sun[i]);
                *o = light(normal, &horizon, hz, f64::from(svf_cosine[i])) as f32;
            }
        });
    }
    if plain > 0.0 {
        out.iter_mut().for_each(|v| *v /= plain as f32);
    }
    Ok((out, w, h))
}

/// Writes the shaded map as a PNG, subsampled to at most `max_side` pixels
/// across, with a legend: gray, equalised between the 1st and the 99th
/// percentile (the map shows relative light, as Stewart's figures do, and
/// most posts of a real DEM crowd near an open plain's light; nodata
/// black).
pub(crate) fn write_shade_png(
    asset: &Asset<Mmap>,
    shade: Shade,
    out: &Path,
    max_side: u32,
) -> Result<()> {
    let (values, w, h) = shade_posts(asset, shade)?;
    let step = (w.max(h) as u32).div_ceil(max_side).max(1) as usize;
    let (pw, ph) = (w.div_ceil(step), h.div_ceil(step));
    let shown: Vec<f32> = (0..h)
        .step_by(step)
        .flat_map(|y| (0..w).step_by(step).map(move |x| (y, x)))
        .map(|(y, x)| values[y * w + x])
        .collect();
    let stretch =
        Stretch::equalised(shown.clone()).unwrap_or_else(|| Stretch::linear(0.0, 1.0, "no values"));
    let title = match shade {
        Shade::Sky => "overcast sky light (albedo 0.5), share of an open plain's".to_string(),
        Shade::Sun(sun) => format!(
            "sun at {}, {} deg and its sky (albedo 0.5), share of an open plain's",
            sun.azimuth, sun.elevation
        ),
    };
    let legend = Legend {
        title,
        ramp: Ramp::Gray,
        stretch,
    };
    let mut rgb: Vec<u8> = shown
        .iter()
        .flat_map(|&v| if v.is_nan() { [0; 3] } else { legend.colour(v) })
        .collect();
    let legend_rows = crate::present::legend::append(&mut rgb, pw as u32, &legend);
    let map = Image {
        width: pw as u32,
        height: ph as u32 + legend_rows,
        rgb,
    };
    crate::present::image::write_png(out, &map)
}
