//! Clear-sky irradiation over days from stored horizons: r.sun's model
//! (Šúri and Hofierka 2004, sec. 3; the ESRA clear-sky model of Rigollier,
//! Bauer and Wald 2000 with Muneer's diffuse model on inclined surfaces),
//! shadowed by the horizon map instead of by rays. docs/SOLAR.md has every
//! formula and where we depart.
//!
//! **The sums are linear in what a post is.** Every irradiance term at one
//! sun position is a fixed weight (set by the sun, the day's atmosphere and
//! the post's height) times one of a few numbers of the post: the three
//! components of its normal, its tilt term `g(slope)`, its cosine sky-view
//! factor, or 1. So a day is, per row of posts, one array of weight vectors
//! in time order ([`RowDay`]) and its running sums; a post adds the running
//! sum where its sun comes out from behind the horizon and where it goes
//! back, and multiplies by its own numbers once at the end of the period
//! ([`shadow::ShadowRow`]). The 96 steps of a day cost a compare each in
//! vector code and a few additions where a post's shadow begins or ends,
//! rather than the whole model per step and post.
//!
//! **Height** enters only through the air mass (the pressure `exp(-z /
//! 8434.5)`). The weights are computed at fixed heights every
//! [`LEVEL_SPACING`] metres over the row's range, and a post's sums are
//! the quadratic (Lagrange) interpolation of the three levels around its
//! height: within 2e-4 of the model at the post's own height (tested).
//! The levels are fixed heights, not the row's own, so that a post's
//! values depend on nothing but its own inputs: a crop of the DEM gives
//! the same bits.

pub mod shadow;

use terrabake_format::horizons::bands_around;

use crate::terrain::sun::{direction_of, julian_day, ut_of_solar_time, SolarCoordinates, Sun};

/// The solar constant r.sun takes, W/m^2.
pub const SOLAR_CONSTANT: f64 = 1367.0;

/// Muneer's `N` on a surface in shadow (r.sun's 0.252271).
pub const N_SHADOWED: f64 = 0.252_271;

/// The scale height of the pressure correction, metres (ESRA).
pub const PRESSURE_SCALE_HEIGHT: f64 = 8434.5;

/// Below this solar elevation (radians) Muneer's model takes the beam
/// fraction along the surface's azimuth instead of its incidence.
pub const LOW_SUN: f64 = 0.1;

/// The relative optical air mass at sea level for a sun `h0` radians up
/// (Kasten and Young 1989, with ESRA's refraction correction of `h0`).
pub fn relative_air_mass(h0: f64) -> f64 {
    let refraction = 0.061_359 * (0.1594 + h0 * (1.123 + 0.065_656 * h0))
        / (1.0 + h0 * (28.9344 + 277.3971 * h0));
    let h = h0 + refraction;
    1.0 / (h.sin() + 0.505_72 * (h.to_degrees() + 6.079_95).powf(-1.6364))
}

/// The Rayleigh optical thickness at air mass `m` (Kasten 1996, as ESRA).
pub fn rayleigh_thickness(m: f64) -> f64 {
    if m <= 20.0 {
        1.0 / (6.6296 + m * (1.7513 + m * (-0.1202 + m * (0.0065 - m * 0.000_13))))
    } else {
        1.0 / (10.4 + 0.718 * m)
    }
}

/// The beam's transmittance `B0c / G0` through a clear sky of Linke
/// turbidity `linke` (at air mass 2) at sea-level air mass `m0`, seen from
/// `z` metres up.
pub fn beam_transmittance(linke: f64, m0: f64, z: f64) -> f64 {
    transmittance_of_mass(linke, m0 * pressure_ratio(z))
}

/// The pressure at `z` metres over that at sea level (ESRA).
pub fn pressure_ratio(z: f64) -> f64 {
    (-z / PRESSURE_SCALE_HEIGHT).exp()
}

/// [`beam_transmittance`] of the pressure-corrected air mass `m`.
fn transmittance_of_mass(linke: f64, m: f64) -> f64 {
    (-0.8662 * linke * m * rayleigh_thickness(m)).exp()
}

/// The diffuse transmission at zenith `Tn(T_LK)`.
pub fn diffuse_transmission(linke: f64) -> f64 {
    -0.015_843 + linke * (0.030_543 + 0.000_379_7 * linke)
}

/// The diffuse angular function `Fd(h0)` of `sin h0`.
pub fn diffuse_angular(linke: f64, sin_h0: f64) -> f64 {
    let tn = diffuse_transmission(linke);
    let a1 = 0.264_63 + linke * (-0.061_581 + 0.003_140_8 * linke);
    let a1 = if a1 * tn < 0.0022 { 0.0022 / tn } else { a1 };
    let a2 = 2.040_20 + linke * (0.018_945 - 0.011_161 * linke);
    let a3 = -1.3025 + linke * (0.039_231 + 0.008_507_9 * linke);
    a1 + sin_h0 * (a2 + a3 * sin_h0)
}

/// Muneer's tilt term `sin s - s cos s - pi sin^2(s / 2)` of a slope of
/// `slope` radians (the part of the diffuse that `N` scales).
pub fn tilt_term(slope: f64) -> f64 {
    slope.sin() - slope * slope.cos() - std::f64::consts::PI * (slope / 2.0).sin().powi(2)
}

/// Muneer's `N` on a sunlit surface at beam fraction `kb`.
pub fn n_sunlit(kb: f64) -> f64 {
    0.002_63 - kb * (0.712 + 0.6883 * kb)
}

/// One step of a day: where the sun is, from the earth's centre, as the
/// sines and cosines of its declination and hour angle (0 at local
/// apparent noon), which every row's sun is two products of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DayStep {
    pub declination: (f64, f64),
    pub hour_angle: (f64, f64),
    /// Extraterrestrial irradiance normal to the beam, W/m^2.
    pub g0: f64,
}

impl DayStep {
    /// The step's middle in hours of local apparent solar time (0-24).
    pub fn solar_hours(&self) -> f64 {
        let (sin, cos) = self.hour_angle;
        (sin.atan2(cos).to_degrees() + 180.0) / 15.0
    }

    /// The unit vector towards the sun at latitude `(sin, cos)`
    /// ([`crate::terrain::sun::direction_at`] of the step).
    #[inline]
    pub fn sun(&self, latitude: (f64, f64)) -> [f64; 3] {
        direction_of(latitude, self.declination, self.hour_angle)
    }
}

/// The steps of day `day` of `year` every `step_minutes` of local apparent
/// solar time, each at its step's midpoint, at longitude `longitude`
/// (degrees east, for the instant of each step: the declination moves by up
/// to 0.4 degrees a day).
pub fn day_steps(year: i32, day: u32, step_minutes: f64, longitude: f64) -> Vec<DayStep> {
    let count = (1440.0 / step_minutes).round() as usize;
    (0..count)
        .map(|k| {
            let solar_hours = (k as f64 + 0.5) * step_minutes / 60.0;
            let ut = ut_of_solar_time(year, day, solar_hours, longitude);
            let c = SolarCoordinates::at(julian_day(year, day, ut));
            DayStep {
                declination: c.declination.sin_cos(),
                hour_angle: (solar_hours * 15.0 - 180.0).to_radians().sin_cos(),
                g0: SOLAR_CONSTANT / (c.distance * c.distance),
            }
        })
        .collect()
}

/// A sun position of one row's day, above the astronomical horizon.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowStep {
    /// Unit vector towards the sun (x east, y north, z up).
    pub sun: [f64; 3],
    /// Elevation of the sun's centre, degrees.
    pub elevation: f64,
    /// The horizon bands around the sun's azimuth and the fraction of the
    /// way between them ([`bands_around`], as the loader serves it).
    pub bands: (u32, u32),
    pub between: f64,
    /// Extraterrestrial irradiance normal to the beam, W/m^2.
    pub g0: f64,
}

/// The weights one step adds, in this order; [`Sums`] names them.
pub const COMPONENTS: usize = 10;

/// The heights a post's sums are interpolated between.
pub const LEVELS: usize = 3;

/// Metres between the heights the weights are taken at.
pub const LEVEL_SPACING: f64 = 500.0;

/// The lowest of the three levels around height `z` (as a multiple of
/// [`LEVEL_SPACING`]: `z` lies within half a spacing of the middle one)
/// and the Lagrange weights of `z` among the three.
pub fn levels_around(z: f64) -> (i64, [f64; LEVELS]) {
    let middle = (z / LEVEL_SPACING).round();
    let t = z / LEVEL_SPACING - middle + 1.0;
    (
        middle as i64 - 1,
        [
            (t - 1.0) * (t - 2.0) / 2.0,
            -t * (t - 2.0),
            t * (t - 1.0) / 2.0,
        ],
    )
}

/// The levels a row of posts between heights `lo` and `hi` needs: the
/// first (as a multiple of [`LEVEL_SPACING`]) and how many.
pub fn levels_spanning(lo: f64, hi: f64) -> (i64, usize) {
    let (first, _) = levels_around(lo);
    let (last, _) = levels_around(hi);
    (first, (last - first) as usize + LEVELS)
}

/// What the clear-sky model asks of a day: its Linke turbidity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClearSky {
    pub linke: f64,
}

/// One row's day: the sun above the horizon at each step, in time order,
/// and the running sums of each step's weights at the row's heights.
#[derive(Debug, Clone)]
pub struct RowDay {
    pub steps: Vec<RowStep>,
    /// The levels: `count` heights from `first * LEVEL_SPACING` up.
    pub first: i64,
    pub count: usize,
    /// `prefix[(k * count + level) * COMPONENTS + c]`: weight `c` summed
    /// over steps `0..k` at level `level`, `k` in `0..=steps`.
    pub prefix: Vec<f64>,
    /// Over every step with the sun up (shadow or not): the diffuse
    /// horizontal irradiance, and the global horizontal at each level.
    pub diffuse_horizontal: f64,
    pub global_horizontal: Vec<f64>,
}

impl RowDay {
    /// The day of `steps` at latitude `latitude` (degrees) on a grid whose
    /// north lies `convergence` degrees clockwise from true north, for
    /// horizons in bands at `azimuths` (grid azimuths), under `sky`, at the
    /// levels `(first, count)` ([`levels_spanning`]).
    pub fn new(
        steps: &[DayStep],
        (latitude, convergence): (f64, f64),
        azimuths: &[f64],
        sky: ClearSky,
        levels: (i64, usize),
    ) -> Self {
        let phi = latitude.to_radians().sin_cos();
        let (sg, cg) = convergence.to_radians().sin_cos();
        let suns = steps.iter().filter_map(|s| {
            let [e, n, up] = s.sun(phi);
            // To the grid's axes: a true azimuth A is the grid's A - convergence.
            (up > 0.0).then_some(([e * cg - n * sg, n * cg + e * sg, up], s.g0))
        });
        Self::of_suns(suns, azimuths, sky, levels)
    }

    /// The day of the sun directions `suns` (with their extraterrestrial
    /// irradiance), all above the horizon, in time order.
    pub fn of_suns(
        suns: impl IntoIterator<Item = ([f64; 3], f64)>,
        azimuths: &[f64],
        sky: ClearSky,
        (first, count): (i64, usize),
    ) -> Self {
        let tn = diffuse_transmission(sky.linke);
        let pressure: Vec<f64> = (0..count)
            .map(|i| pressure_ratio((first + i as i64) as f64 * LEVEL_SPACING))
            .collect();
        let kept = count * COMPONENTS;
        let mut prefix = Vec::with_capacity(kept * 98);
        prefix.resize(kept, 0.0);
        let mut day = Self {
            steps: Vec::with_capacity(97),
            first,
            count,
            prefix,
            diffuse_horizontal: 0.0,
            global_horizontal: vec![0.0; count],
        };
        for (sun, g0) in suns {
            let sin_h0 = sun[2];
            let h0 = sin_h0.clamp(-1.0, 1.0).asin();
            let Sun { azimuth, .. } = Sun::from_direction(sun);
            let (i, j, f) = bands_around(azimuths, azimuth);
            day.steps.push(RowStep {
                sun,
                elevation: h0.to_degrees(),
                bands: (i as u32, j as u32),
                between: f,
                g0,
            });
            let m0 = relative_air_mass(h0);
            let dhc = g0 * tn * diffuse_angular(sky.linke, sin_h0);
            day.diffuse_horizontal += dhc;
            let last = day.prefix.len() - kept;
            for (level, &p) in pressure.iter().enumerate() {
                let w = step_weights(sun, h0, g0, dhc, transmittance_of_mass(sky.linke, m0 * p));
                day.global_horizontal[level] += g0 * w.kb * sin_h0 + dhc;
                let at = last + level * COMPONENTS;
                // Appended level by level: step k + 1's slot, in the
                // layout `prefix` promises (reads are of step k's, before it).
                for c in 0..COMPONENTS {
                    let running = day.prefix[at + c] + w.weights[c];
                    day.prefix.push(running);
                }
            }
        }
        day
    }

    /// The running sums before step `k` (`k` = the step count: the day's
    /// totals) at the three levels from level `first` (an index into this
    /// day's levels), level after level.
    #[inline]
    pub fn before(&self, k: usize, first: usize) -> &[f64; LEVELS * COMPONENTS] {
        self.prefix[(k * self.count + first) * COMPONENTS..][..LEVELS * COMPONENTS]
            .try_into()
            .expect("three levels")
    }
}

/// One step's weights and its beam fraction.
struct StepWeights {
    weights: [f64; COMPONENTS],
    kb: f64,
}

/// The weights of one step with the sun in direction `sun` (`h0` radians
/// up), extraterrestrial irradiance `g0`, diffuse horizontal `dhc` and beam
/// transmittance `tb` (docs/SOLAR.md, "The sums"):
///
/// | c | weight | a post multiplies it by |
/// |---|--------|-------------------------|
/// | 0 | `Dhc (1 - Kb)` | its cosine sky-view factor |
/// | 1 | `Dhc (1 - Kb) N(Kb)` | its tilt term |
/// | 2 | `Dhc` | (the sunlit share of the day's diffuse) |
/// | 3-5 | Muneer's beam-fraction term, a vector | its normal |
/// | 6-8 | `B0c` times the sun's direction | its normal |
/// | 9 | 1 | (its sunlit steps) |
fn step_weights(sun: [f64; 3], h0: f64, g0: f64, dhc: f64, tb: f64) -> StepWeights {
    let b0c = g0 * tb;
    // Kb = Bhc / G0h = B0c sin h0 / (G0 sin h0).
    let kb = tb;
    let diffuse_sunlit = dhc * (1.0 - kb);
    let circumsolar = if h0 >= LOW_SUN {
        // Kb sin(incidence) / sin h0: the normal against the sun.
        let k = dhc * kb / sun[2];
        [k * sun[0], k * sun[1], k * sun[2]]
    } else {
        // Kb sin(slope) cos(sun azimuth - aspect) / (0.1 - 0.008 h0): the
        // normal's horizontal part against the sun's azimuth.
        let horizontal = sun[0].hypot(sun[1]);
        let k = dhc * kb / ((LOW_SUN - 0.008 * h0) * horizontal);
        [k * sun[0], k * sun[1], 0.0]
    };
    StepWeights {
        weights: [
            diffuse_sunlit,
            diffuse_sunlit * n_sunlit(kb),
            dhc,
            circumsolar[0],
            circumsolar[1],
            circumsolar[2],
            b0c * sun[0],
            b0c * sun[1],
            b0c * sun[2],
            1.0,
        ],
        kb,
    }
}

/// A post's own numbers, which its sums are multiplied by.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// Unit normal (x east, y north, z up).
    pub normal: [f64; 3],
    /// The cosine sky-view factor (`svf_cosine`): 1 on flat open ground,
    /// `(1 + cos slope) / 2` on an open slope.
    pub svf_cosine: f64,
    /// Ground albedo.
    pub albedo: f64,
}

impl Surface {
    /// r.sun's plane: no tilt at all (Muneer's model is for slopes).
    pub fn is_flat(&self) -> bool {
        self.normal[0] == 0.0 && self.normal[1] == 0.0
    }

    /// The slope, radians.
    pub fn slope(&self) -> f64 {
        self.normal[2].clamp(-1.0, 1.0).acos()
    }
}

/// A post's sums over its sunlit steps, and the row's over every step with
/// the sun up, for a period: what becomes its irradiation.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Sums {
    /// The [`COMPONENTS`] weights summed over the post's sunlit steps.
    pub sunlit: [f64; COMPONENTS],
    /// Diffuse and global horizontal summed over every step with the sun up.
    pub diffuse_horizontal: f64,
    pub global_horizontal: f64,
}

/// Irradiation of one post over a period, in the unit its sums were
/// scaled to (Wh/m^2 when each step's weight was times its hours).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Irradiation {
    pub beam: f64,
    pub diffuse: f64,
    pub reflected: f64,
    /// Steps with the sun's centre above the horizon and in front of the
    /// surface.
    pub sunlit_steps: f64,
}

impl Irradiation {
    pub fn global(&self) -> f64 {
        self.beam + self.diffuse + self.reflected
    }
}

fn dot(a: [f64; 3], b: &[f64]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl Sums {
    /// What the sums give on `surface` (docs/SOLAR.md, "The sums").
    pub fn irradiation(&self, surface: &Surface) -> Irradiation {
        let s = &self.sunlit;
        let shadowed_diffuse = self.diffuse_horizontal - s[2];
        let diffuse = if surface.is_flat() {
            // r.sun's plane (no Muneer terms), its isotropic part limited
            // by the horizon as on a slope.
            surface.svf_cosine * (s[0] + shadowed_diffuse) + (s[2] - s[0])
        } else {
            let g = tilt_term(surface.slope());
            surface.svf_cosine * (s[0] + shadowed_diffuse)
                + g * (s[1] + N_SHADOWED * shadowed_diffuse)
                + dot(surface.normal, &s[3..6])
        };
        Irradiation {
            beam: dot(surface.normal, &s[6..9]),
            diffuse,
            reflected: surface.albedo * (1.0 - surface.svf_cosine) * self.global_horizontal,
            sunlit_steps: s[9],
        }
    }
}

/// The reference the sums are checked against: one post, every step
/// evaluated by the model at the post's own height, lit where `lit(step)`
/// says (a ray, or the horizon as served): r.sun's per-step formulas in
/// its own order (`brad`, `drad`), with our two departures (docs/SOLAR.md).
pub fn direct_irradiation(
    day: &RowDay,
    sky: ClearSky,
    z: f64,
    surface: &Surface,
    mut lit: impl FnMut(&RowStep) -> bool,
) -> Irradiation {
    let mut out = Irradiation::default();
    let (flat, slope) = (surface.is_flat(), surface.slope());
    let n = surface.normal;
    for step in &day.steps {
        let g0 = step.g0;
        let sin_h0 = step.sun[2];
        let h0 = sin_h0.asin();
        let bhc = g0 * beam_transmittance(sky.linke, relative_air_mass(h0), z) * sin_h0;
        let dhc = g0 * diffuse_transmission(sky.linke) * diffuse_angular(sky.linke, sin_h0);
        let incidence = dot(n, &step.sun);
        let sunlit = incidence > 0.0 && lit(step);
        let kb = bhc / (g0 * sin_h0);
        let rsky = surface.svf_cosine;
        let diffuse = if flat {
            // r.sun's plane, its sky limited by the terrain's horizon.
            if sunlit {
                dhc * (rsky * (1.0 - kb) + kb)
            } else {
                dhc * rsky
            }
        } else {
            let g = tilt_term(slope);
            let fx = if !sunlit {
                rsky + g * N_SHADOWED
            } else if h0 >= LOW_SUN {
                (n_sunlit(kb) * g + rsky) * (1.0 - kb) + kb * incidence / sin_h0
            } else {
                let horizontal = step.sun[0].hypot(step.sun[1]);
                let towards = (n[0] * step.sun[0] + n[1] * step.sun[1]) / horizontal;
                (n_sunlit(kb) * g + rsky) * (1.0 - kb) + kb * towards / (LOW_SUN - 0.008 * h0)
            };
            dhc * fx
        };
        if sunlit {
            out.beam += bhc / sin_h0 * incidence;
            out.sunlit_steps += 1.0;
        }
        out.diffuse += diffuse;
        out.reflected += surface.albedo * (bhc + dhc) * (1.0 - surface.svf_cosine);
    }
    out
}

/// The sun's lowest elevation in [`direct_correction`]'s denominator,
/// degrees: HORAYZON's `ang_max` of 89.5 (zenith) degrees.
pub const CORRECTION_MIN_ELEVATION: f64 = 0.5;

/// The largest [`direct_correction`] returns: HORAYZON's `sw_dir_cor_max`
/// (its examples take 20 or 25).
pub const CORRECTION_MAX: f64 = 25.0;

/// HORAYZON's terrain correction factor for direct shortwave (Steger et
/// al. 2022, sec. 2.5): what multiplies the direct irradiance on a flat,
/// open plane to give it on a surface of unit upward `normal` whose horizon
/// in the sun's azimuth is `horizon` degrees, for the unit `sun` direction
/// (x east, y north, z up). 0 where the sun's centre is below the horizon
/// or behind the surface, else `n . s / sin(elevation)`, the sine held at
/// [`CORRECTION_MIN_ELEVATION`] and the factor at [`CORRECTION_MAX`] as
/// HORAYZON holds them. We read the horizon where HORAYZON traces a ray
/// (the solar stage's shadow test); its surface enlargement factor
/// (`1 / n_z`, flux per unit of horizontal area) is the caller's to apply.
pub fn direct_correction(normal: [f64; 3], horizon: f64, sun: [f64; 3]) -> f64 {
    let sin_elevation = sun[2];
    if sin_elevation <= 0.0 || sin_elevation.asin().to_degrees() <= horizon {
        return 0.0;
    }
    let facing = dot(normal, &sun);
    if facing <= 0.0 {
        return 0.0;
    }
    let floor = CORRECTION_MIN_ELEVATION.to_radians().sin();
    (facing / sin_elevation.max(floor)).min(CORRECTION_MAX)
}
