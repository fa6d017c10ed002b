//! Horizon features: the posts whose horizon no sampling of azimuth keeps,
//! stored as posts and served exactly between the bands.
//!
//! A lone spike (a mast, a single tree in a DSM, a needle of rock) rises
//! far above the eight posts around it. Seen from a post `d` away it is a
//! wedge of the horizon about `spacing / d` radians wide: between two bands
//! a degree apart it is lost whole a few dozen posts out, so no count of
//! line directions bounds the largest horizon error near it (a 1000 m spike
//! on 30 m posts leaves 12.9 degrees at 360 directions; docs/PLANNING.md).
//!
//! What a feature adds is exact. On the two-triangle surface
//! ([`crate::surface`]) the height of post `C` enters only the six grid
//! segments that meet at it: along its row to the west and east posts,
//! along its column to the north and south posts, and along the cell
//! diagonal to the south-west and north-east posts. A sight line's horizon
//! is the largest slope over its crossings with the grid, so it is the
//! larger of the crossings on those segments ([`HorizonFeatures::horizon`],
//! computed here from the seven heights stored with the feature) and all
//! the others, which `C` does not touch. The stored band `i` (the `line`
//! method's exact sight line at `band_azimuths[i]`) holds that larger one.
//! Where the feature's horizon at the band's azimuth equals the band's
//! angle (within the encoding's error) the feature sets the band, and the
//! terrain behind it is unknown there, though no higher than the band; the
//! reader then takes it as the nearest bands on either side that the
//! features do not set, linear across it, capped at the band, and serves
//! the larger of the bands so read and the features' exact horizon
//! ([`serve`]). At a band's
//! own azimuth the result is the band; between bands a spike is served at
//! its true height and width.
//!
//! We depart from every paper here: Stewart (1998) and Timonen (2013) store
//! a horizon per azimuth band only, and their error between bands is
//! unbounded for such features. Features are recorded for the `line` method
//! on grids of uniform spacing (projected, not latitude/longitude) only.

use serde::{Deserialize, Serialize};

use crate::horizons::{bands_around, between, Served, NOTHING_AHEAD};

/// The most features a horizon layer may list: each query looks at every
/// feature that lies near its sight line, so the list stays short.
pub const MAX_FEATURES: usize = 4096;

/// The features of a `horizon` layer (its manifest entry's `features`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HorizonFeatures {
    /// `c` of the curvature drop `c d^2` over horizontal distance `d`
    /// metres, as the bands were baked (0: a flat earth).
    pub curvature: f64,
    /// The bands' distance limit, metres (`None`: the whole DEM).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_distance: Option<f64>,
    pub posts: Vec<FeaturePost>,
}

/// One feature post and the heights (metres) of the six segments that meet
/// at it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeaturePost {
    pub x: u32,
    pub y: u32,
    /// The post itself, then west, east, north, south, south-west and
    /// north-east of it (`(x - 1, y + 1)` and `(x + 1, y - 1)`).
    pub z: [f32; 7],
}

/// Where a sight line starts and how it runs, in posts (`x` east, `y`
/// south) and metres.
#[derive(Debug, Clone, Copy)]
pub struct SightLine {
    x: f64,
    y: f64,
    z: f64,
    /// Posts east and south per unit of the line's parameter `s`.
    a: f64,
    b: f64,
    /// Metres per unit of `s`.
    metres: f64,
}

impl SightLine {
    /// The line from post `(x, y)` at height `z` towards compass `azimuth`
    /// (degrees) on a grid of `dx x dy` metres: the same straight line
    /// through the grid as the exact references and the `line` stage take.
    pub fn new((x, y): (u32, u32), z: f64, azimuth: f64, (dx, dy): (f64, f64)) -> Self {
        let (sin, cos) = azimuth.to_radians().sin_cos();
        let (a, b) = (sin / dx, -cos / dy);
        let major = a.abs().max(b.abs());
        // Exact zeros along an axis, so that no crossing is made of rounding.
        let clean = |v: f64| {
            if (v / major).abs() < 1e-12 {
                0.0
            } else {
                v / major
            }
        };
        let (a, b) = (clean(a), clean(b));
        Self {
            x: f64::from(x),
            y: f64::from(y),
            z,
            a,
            b,
            metres: (a * dx).hypot(b * dy),
        }
    }
}

impl SightLine {
    /// Posts east and south per unit of the line's parameter, the larger
    /// of the two 1 in magnitude: the grid direction of its azimuth.
    pub fn direction(&self) -> (f64, f64) {
        (self.a, self.b)
    }
}

impl HorizonFeatures {
    /// The features' exact horizon along `line`, degrees: the steepest of
    /// its crossings with the segments that meet at a feature post, with
    /// the curvature and distance limit of the bands; `None` where the line
    /// crosses none.
    pub fn horizon(&self, line: &SightLine) -> Option<f64> {
        self.horizon_within(line, self.max_distance)
    }

    /// [`Self::horizon`] with the sight line cut at `max_distance` metres
    /// instead (what a bake with that distance limit would serve).
    pub fn horizon_within(&self, line: &SightLine, max_distance: Option<f64>) -> Option<f64> {
        let mut best = f64::NEG_INFINITY;
        self.crossings(line, |d, slope| {
            if max_distance.is_none_or(|m| d <= m) {
                best = best.max(slope);
            }
        });
        best.is_finite().then(|| best.atan().to_degrees())
    }

    /// Every crossing of `line` with a segment that meets at a feature
    /// post, uncut, as `(metres, degrees)`: the features' horizon cut at
    /// any distance `D` is the steepest of those no farther than `D`.
    pub fn crossings_deg(&self, line: &SightLine) -> Vec<(f64, f64)> {
        let mut all = Vec::new();
        self.crossings(line, |d, slope| all.push((d, slope.atan().to_degrees())));
        all
    }

    /// Calls `visit(metres, slope)` at each crossing of `line` ahead of its
    /// eye with a segment that meets at a feature post.
    fn crossings(&self, line: &SightLine, mut visit: impl FnMut(f64, f64)) {
        let mut slope_at = |s: f64, z: f64| {
            if s > 1e-9 {
                let d = s * line.metres;
                visit(d, (z - self.curvature * d * d - line.z) / d);
            }
        };
        // Along a segment from the post (height `c`) to a neighbour (`n`),
        // `t` of the way.
        let on = |c: f64, n: f64, t: f64| c + t.abs() * (n - c);
        let reach = 2.0 * line.a.hypot(line.b);
        for f in &self.posts {
            let (fx, fy) = (f64::from(f.x), f64::from(f.y));
            // Distance of the post from the line, in posts along the line's
            // normal: a line farther than two posts meets none of its
            // segments (each at most one post and a diagonal from it).
            let across = (fx - line.x) * line.b - (fy - line.y) * line.a;
            if across.abs() > reach {
                continue;
            }
            let [c, w, e, n, s, sw, ne] = f.z.map(f64::from);
            // Its row, `y = fy`, between the west and east posts.
            if line.b != 0.0 {
                let t = (fy - line.y) / line.b;
                let u = line.x + line.a * t - fx;
                if u.abs() <= 1.0 + 1e-9 {
                    slope_at(t, on(c, if u < 0.0 { w } else { e }, u.clamp(-1.0, 1.0)));
                }
            }
            // Its column, `x = fx`, between the north and south posts.
            if line.a != 0.0 {
                let t = (fx - line.x) / line.a;
                let v = line.y + line.b * t - fy;
                if v.abs() <= 1.0 + 1e-9 {
                    slope_at(t, on(c, if v < 0.0 { n } else { s }, v.clamp(-1.0, 1.0)));
                }
            }
            // Its diagonal, `x + y = fx + fy`, south-west to north-east.
            if line.a + line.b != 0.0 {
                let t = (fx + fy - line.x - line.y) / (line.a + line.b);
                let u = line.x + line.a * t - fx;
                if u.abs() <= 1.0 + 1e-9 {
                    slope_at(t, on(c, if u < 0.0 { sw } else { ne }, u.clamp(-1.0, 1.0)));
                }
            }
        }
    }

    /// What [`crate::Manifest::validate`] checks of a layer's features:
    /// posts inside the `width x height` grid with all their neighbours,
    /// finite heights, a finite curvature, a positive distance limit.
    pub(crate) fn validate(&self, (width, height): (u32, u32)) -> Result<(), String> {
        if self.posts.len() > MAX_FEATURES {
            return Err(format!(
                "{} features, more than {MAX_FEATURES}",
                self.posts.len()
            ));
        }
        if !self.curvature.is_finite() || self.max_distance.is_some_and(|d| d.is_nan() || d <= 0.0)
        {
            return Err("features: curvature must be finite, max_distance positive".into());
        }
        for f in &self.posts {
            let inside = f.x >= 1 && f.y >= 1 && f.x + 1 < width && f.y + 1 < height;
            if !inside || f.z.iter().any(|z| !z.is_finite()) {
                return Err(format!(
                    "feature post ({}, {}) is not an inner post of the {width} x {height} grid with finite heights",
                    f.x, f.y
                ));
            }
        }
        Ok(())
    }
}

/// The horizon at `azimuth` from bands at `azimuths` (ascending compass
/// degrees; `angle(k)` band `k`'s angle at the post, `None` for nodata)
/// and the features (module docs): the two nearest bands linear, a band
/// the features set (`at_band(k)`, their horizon at band `k`'s azimuth,
/// is not below its angle by more than `tolerance` degrees, the
/// encoding's error) standing for the smaller of itself and the nearest
/// bands beyond that they do not set, linear across it; and the features'
/// horizon at the azimuth itself, `here`, where it is higher. Without features
/// (`at_band` and `here` always `None`) this is the plain linear reading
/// of [`crate::horizons::HorizonMap`].
pub fn serve<E>(
    azimuths: &[f64],
    azimuth: f64,
    mut angle: impl FnMut(usize) -> Result<Option<f64>, E>,
    (at_band, here): (impl Fn(usize) -> Option<f64>, Option<f64>),
    tolerance: f64,
) -> Result<Option<Served>, E> {
    let n = azimuths.len();
    let (i, j, f) = bands_around(azimuths, azimuth);
    let (Some(hi), Some(hj)) = (angle(i)?, angle(j)?) else {
        return Ok(None);
    };
    let set_by_feature =
        |k: usize, h: f64| h != NOTHING_AHEAD && at_band(k).is_some_and(|v| v >= h - tolerance);
    let (mut k0, mut h0, mut k1, mut h1) = (i, hi, j, hj);
    // Walk away from the azimuth, each side, to a band the terrain sets.
    let mut steps = 0;
    while set_by_feature(k0, h0) && steps < n {
        k0 = (k0 + n - 1) % n;
        h0 = angle(k0)?.unwrap_or(NOTHING_AHEAD);
        steps += 1;
    }
    steps = 0;
    while set_by_feature(k1, h1) && steps < n {
        k1 = (k1 + 1) % n;
        h1 = angle(k1)?.unwrap_or(NOTHING_AHEAD);
        steps += 1;
    }
    let terrain = if (k0, k1) == (i, j) {
        between(hi, hj, f)
    } else if set_by_feature(k0, h0) {
        // Every band is the features': nothing says what lies behind them.
        NOTHING_AHEAD
    } else {
        // The terrain behind a band the features set is at most the band:
        // the bands beyond, linear across it, and no higher than it.
        let across = |k: usize| {
            let span = (azimuths[k1] - azimuths[k0]).rem_euclid(360.0);
            let g = if span == 0.0 {
                0.0
            } else {
                (azimuths[k] - azimuths[k0]).rem_euclid(360.0) / span
            };
            between(h0, h1, g)
        };
        let behind = |k: usize, h: f64| {
            if set_by_feature(k, h) {
                across(k).min(h)
            } else {
                h
            }
        };
        between(behind(i, hi), behind(j, hj), f)
    };
    Ok(Some(Served {
        angle: here.map_or(terrain, |v| v.max(terrain)),
        at_edge: h0 == NOTHING_AHEAD || h1 == NOTHING_AHEAD,
    }))
}
