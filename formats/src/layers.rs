//! The name of every layer the pipeline writes, in one place, so that a
//! renderer can name any of them and no two files spell one differently.
//! Each module that reads a layer (`trace`, `cones`, `horizons`) re-exports
//! the names it serves. FORMAT.md "Layers" says what each holds.

/// Terrain height, f32 metres, NaN for nodata (ingest).
pub const HEIGHT: &str = "height";
/// Per cell and pyramid level, the tallest corner of every cell below
/// (`-inf` where no surface) (pyramid stage).
pub const PYRAMID_MAX: &str = "pyramid_max";
/// As [`PYRAMID_MAX`], the lowest corner (`+inf` where no surface).
pub const PYRAMID_MIN: &str = "pyramid_min";
/// Per cell, the apex height of its cone of empty space (cones stage).
pub const CONE_APEX: &str = "cone_apex";
/// Per cell, the cone's slope: horizontal metres per metre of rise.
pub const CONE_SLOPE: &str = "cone_slope";
/// Horizon elevation angle per post, one band per azimuth (horizons stage).
pub const HORIZON: &str = "horizon";
/// Per post (f32), one band per azimuth as [`HORIZON`]: the horizontal
/// distance in metres to the point that sets the horizon (horizons stage
/// with `distance`); NaN for nodata and where no terrain lies ahead.
pub const HORIZON_DISTANCE: &str = "horizon_distance";
/// Sky-view factor as the solid angle of visible sky over the hemisphere
/// above the horizontal: `1 - mean(sin(max(h, 0)))` (Zakšek et al. 2011).
pub const SVF: &str = "svf";
/// Sky-view factor as the cosine-weighted view factor of the visible sky
/// from the tilted surface: `(1/pi) * integral over visible sky of N.u`
/// (Dozier and Frew 1990; Stewart 1998 sec. VI).
pub const SVF_COSINE: &str = "svf_cosine";
/// Positive openness (Yokoyama et al. 2002): the mean zenith angle of the
/// horizon, `mean(90 - h)` in degrees; above 90 where the terrain falls away.
pub const OPENNESS: &str = "openness";
/// Per post (u16), how many bands' horizon terrain beyond the DEM's edge, no
/// higher than its highest post, could rise above.
pub const HORIZON_EDGE: &str = "horizon_edge";

/// Per post (u8), one band per observer: 1 where the observer sees a target
/// above the post, 0 where not, 255 beyond the distance or on nodata
/// (viewshed stage).
pub const VIEWSHED: &str = "viewshed";
/// Per post (f32), one band per observer: the elevation angle of the post's
/// ground from the observer's eye, degrees, curvature included; NaN where
/// [`VIEWSHED`] is 255.
pub const VIEWSHED_ANGLE: &str = "viewshed_angle";
/// Per post (f32), the area of terrain an eye above the post sees within
/// the stage's distance, square metres (total_viewshed stage).
pub const TOTAL_VIEWSHED: &str = "total_viewshed";

/// Per post (f32), one band per period (the days asked, or each month of
/// them): the mean daily global irradiation (beam + diffuse + reflected),
/// Wh/m^2, clear sky, shadowed by the horizons (solar stage).
pub const SOLAR_GLOBAL: &str = "solar_global";
/// As [`SOLAR_GLOBAL`], its beam (direct) part.
pub const SOLAR_BEAM: &str = "solar_beam";
/// As [`SOLAR_GLOBAL`], its diffuse part.
pub const SOLAR_DIFFUSE: &str = "solar_diffuse";
/// As [`SOLAR_GLOBAL`], its ground-reflected part.
pub const SOLAR_REFLECTED: &str = "solar_reflected";
/// Per post (f32), one band per period as [`SOLAR_GLOBAL`]: hours per day
/// with the sun's centre above the horizon and in front of the surface.
pub const SUN_HOURS: &str = "sun_hours";

/// Every name above, in the order stages write them.
pub const ALL: [&str; 19] = [
    HEIGHT,
    PYRAMID_MAX,
    PYRAMID_MIN,
    CONE_APEX,
    CONE_SLOPE,
    HORIZON,
    HORIZON_DISTANCE,
    SVF,
    SVF_COSINE,
    OPENNESS,
    HORIZON_EDGE,
    VIEWSHED,
    VIEWSHED_ANGLE,
    TOTAL_VIEWSHED,
    SOLAR_GLOBAL,
    SOLAR_BEAM,
    SOLAR_DIFFUSE,
    SOLAR_REFLECTED,
    SUN_HOURS,
];
