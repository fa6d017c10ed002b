//! What the planner knows of a scene before it chooses: the DEM's grid,
//! relief and nodata from the manifest, the slopes and features the pilot
//! measured, and the sun positions a request names at its latitude.

use anyhow::Result;
use serde::{Deserialize, Serialize};
use terrabake_format::{Asset, Mmap};

use crate::error::bail;
use crate::plan::budget::Request;
use crate::plan::reference::{quantile_unsorted, Pilot};
use crate::terrain::sun::SunPosition;

/// What the planner measured of the scene.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Scene {
    pub width: u32,
    pub height: u32,
    pub cell_size: (f64, f64),
    pub relief_m: f64,
    pub nodata_share: f64,
    pub curvature: bool,
    /// The farthest two posts lie apart, metres.
    #[serde(default)]
    pub extent_m: f64,
    /// The scene's central latitude, degrees, when it is known.
    #[serde(default)]
    pub latitude_deg: Option<f64>,
    /// The east-west post spacing on the first and the last row, metres
    /// (they differ with latitude on geographic grids).
    #[serde(default)]
    pub dx_range_m: Option<(f64, f64)>,
    /// The slope at the pilot's posts (random ones and those of the
    /// highest relief): median and 90th percentile, degrees.
    #[serde(default)]
    pub slope_p50_deg: Option<f64>,
    #[serde(default)]
    pub slope_p90_deg: Option<f64>,
    pub pilot_posts: usize,
    /// Of those, the posts around the scene's most prominent features
    /// (where the largest errors are), and the features' prominence
    /// (metres above their surroundings), most prominent first.
    #[serde(default)]
    pub pilot_feature_posts: usize,
    #[serde(default)]
    pub feature_prominence_m: Vec<f32>,
    /// Directions the pilot measured: the reference's and those the
    /// candidate bakes would store.
    #[serde(default)]
    pub pilot_directions: usize,
    /// The reference's distinct directions (fewer than the 720 asked for
    /// where non-square cells put two on one grid step; 0 in plans
    /// recorded before this was).
    #[serde(default)]
    pub pilot_reference_directions: usize,
    pub pilot_seconds: f64,
}

/// The scene as the plan reports it: the DEM's grid, relief and nodata,
/// and what the pilot measured of its slopes.
pub(super) fn describe_scene(
    asset: &Asset<Mmap>,
    pilot: Option<&Pilot>,
    curvature: f64,
    pilot_seconds: f64,
) -> Scene {
    let m = asset.manifest();
    let (w, h) = (m.width as usize, m.height as usize);
    let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
    let posts = (w * h) as u64;
    let relief_m = m
        .height_range
        .map_or(0.0, |r| f64::from(r.max) - f64::from(r.min));
    Scene {
        width: m.width,
        height: m.height,
        cell_size: (dx, dy),
        relief_m,
        nodata_share: m.nodata.count as f64 / posts.max(1) as f64,
        curvature: curvature > 0.0,
        extent_m: ((w.saturating_sub(1)) as f64 * dx).hypot((h.saturating_sub(1)) as f64 * dy),
        latitude_deg: m
            .georef
            .as_ref()
            .and_then(|g| crate::terrain::geo::central_latitude(g, m.width, m.height)),
        dx_range_m: pilot.map(|p| p.dx_range),
        slope_p50_deg: pilot
            .as_ref()
            .map(|p| quantile_unsorted(&mut p.slope_deg.clone(), 0.5)),
        slope_p90_deg: pilot
            .as_ref()
            .map(|p| quantile_unsorted(&mut p.slope_deg.clone(), 0.9)),
        pilot_posts: pilot.map_or(0, |p| p.posts.len()),
        pilot_feature_posts: pilot.map_or(0, |p| p.feature_posts),
        feature_prominence_m: pilot
            .map_or(Vec::new(), |p| p.features.iter().map(|f| f.1).collect()),
        pilot_directions: pilot.map_or(0, Pilot::directions_measured),
        pilot_reference_directions: pilot.map_or(0, |p| p.reference.len()),
        pilot_seconds,
    }
}

/// The sun positions a request names: its own, and those of its day's path
/// at the scene's latitude.
pub(super) fn sun_positions(
    asset: &Asset<Mmap>,
    request: &Request,
    scene: &Scene,
) -> Result<Vec<SunPosition>> {
    let mut sun = request.sun.clone();
    if let Some(day) = request.sun_day {
        let Some(latitude) = scene.latitude_deg else {
            bail!(
                "{}: --sun-day needs the scene's latitude, and this DEM is neither geographic nor WGS 84 UTM; give the sun positions with --sun AZ,EL;AZ,EL...",
                asset.dir().display()
            );
        };
        sun.extend(crate::terrain::sun::sun_path(latitude, day));
    }
    Ok(sun)
}
