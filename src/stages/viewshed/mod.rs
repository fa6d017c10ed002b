//! The viewshed stages ([`stage`]): what observers see (the `viewshed`
//! stage, over [`crate::algorithms::viewshed::observer`]; `terrabake
//! viewshed` writes one observer's as a GeoTIFF) and how much terrain every
//! post sees (the `total_viewshed` stage, Timonen 2013's sweeps with the
//! convex hull tree, [`crate::algorithms::viewshed::total`]); and here, how
//! an observer's position and height are given. docs/VISIBILITY.md is the long form: the
//! surface model, the comparison with GRASS `r.viewshed`, and Timonen's
//! tables on our DEMs.
//!
//! Both take the earth's curvature and refraction as the horizons stage
//! does (on by default for georeferenced DEMs) and hold the DEM in memory
//! (4 bytes a post, and for the total viewshed 8 more per worker).

pub mod stage;

use anyhow::Result;
use terrabake_format::manifest::CrsKind;
use terrabake_format::Manifest;

use crate::error::bail;
use crate::terrain::held::HeldDem;

/// An observer's eye above the ground unless told, metres: a standing
/// person's.
pub const DEFAULT_EYE_HEIGHT: f64 = 1.7;

/// How an observer's `X,Y` is given.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Crs {
    /// The DEM's own coordinates (metres of its projection, or degrees of a
    /// geographic grid); grid posts for a DEM without georeferencing.
    #[default]
    Native,
    /// Longitude, latitude in degrees (WGS 84): on a geographic DEM, or one in a
    /// WGS 84 UTM zone (EPSG 326zz/327zz).
    Lonlat,
    /// Column, row of the grid (0, 0 is the north-west post).
    Grid,
}

impl Crs {
    pub fn name(self) -> &'static str {
        match self {
            Crs::Native => "native",
            Crs::Lonlat => "lonlat",
            Crs::Grid => "grid",
        }
    }
}

/// The post nearest `(x, y)` given in `crs`, checked to lie on the DEM and
/// to have a height.
pub fn observer_post(
    m: &Manifest,
    dem: &HeldDem,
    (x, y): (f64, f64),
    crs: Crs,
) -> crate::Result<(usize, usize)> {
    Ok(post_at(m, dem, "--observer", (x, y), crs)?)
}

/// The post nearest to `(x, y)` given in `crs` (as the flag `flag` gave
/// it, for the messages); refused off the DEM or on nodata.
pub(crate) fn post_at(
    m: &Manifest,
    dem: &HeldDem,
    flag: &str,
    (x, y): (f64, f64),
    crs: Crs,
) -> Result<(usize, usize)> {
    let said = format!("{flag} {x},{y} (--crs {})", crs.name());
    let georef = m.georef.as_ref();
    let (col, row) = match (crs, georef) {
        (Crs::Grid, _) | (Crs::Native, None) => (x, y),
        (Crs::Native, Some(g)) => g
            .world_to_post(x, y)
            .ok_or_else(|| anyhow::anyhow!("{said}: the DEM's geotransform is singular"))?,
        (Crs::Lonlat, Some(g)) if g.crs_kind == CrsKind::Geographic => g
            .world_to_post(x, y)
            .ok_or_else(|| anyhow::anyhow!("{said}: the DEM's geotransform is singular"))?,
        (Crs::Lonlat, Some(g)) if g.epsg.and_then(crate::terrain::geo::utm_zone).is_some() => {
            let zone = g
                .epsg
                .and_then(crate::terrain::geo::utm_zone)
                .expect("a UTM zone");
            let (e, n) = crate::terrain::geo::lonlat_to_utm(x, y, zone);
            g.world_to_post(e, n)
                .ok_or_else(|| anyhow::anyhow!("{said}: the DEM's geotransform is singular"))?
        }
        (Crs::Lonlat, _) => bail!(
            "{said}: this DEM is neither on a geographic grid nor in a WGS 84 UTM zone, and \
             terrabake projects no other CRS; give the DEM's own coordinates (--crs native, \
             e.g. from `gdaltransform -t_srs` of the DEM) or grid posts (--crs grid)"
        ),
    };
    let (c, r) = (col.round(), row.round());
    if !(c >= 0.0 && r >= 0.0 && c < dem.width as f64 && r < dem.height as f64) {
        bail!(
            "{said} is at post ({c}, {r}), outside the {} x {} DEM",
            dem.width,
            dem.height
        );
    }
    let (c, r) = (c as usize, r as usize);
    if dem.z()[r * dem.width + c].is_nan() {
        bail!("{said} stands on post ({c}, {r}), which has no height (nodata)");
    }
    Ok((c, r))
}

/// Refuses a negative or non-finite height, naming it.
pub(crate) fn check_height(flag: &str, value: f64) -> Result<()> {
    if !(value >= 0.0 && value.is_finite()) {
        bail!("{flag} {value}: a height above the ground must be 0 or more metres");
    }
    Ok(())
}
