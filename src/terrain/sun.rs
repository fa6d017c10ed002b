//! The sun as the stages and renderers see it: a direction, where it
//! stands at a time and place (an ephemeris), and its path over a day.
//!
//! **The ephemeris** is Meeus's low-precision solar theory (Astronomical
//! Algorithms, 2nd ed., ch. 25, "Solar coordinates", with the equation of
//! time of ch. 28, eq. 28.3, as NOAA's solar calculator uses them): the
//! apparent longitude from the mean longitude, the mean anomaly and the
//! equation of the centre, corrected for nutation and aberration: about
//! 0.01 degrees, which the tests hold against Meeus's worked examples and
//! against NREL's SPA (Reda and Andreas 2008) on its own worked example
//! (within 0.02 degrees, refraction and parallax aside). That is a hundred
//! times finer than a 15-minute step (3.75 degrees of hour angle), which is
//! all the daily integrals ask. No refraction: the sun's centre is its
//! geometric one, as in r.sun.

use serde::Serialize;

/// Sun direction: azimuth clockwise from north, elevation above the horizon, degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Sun {
    pub azimuth: f64,
    pub elevation: f64,
}

impl Sun {
    /// Unit vector towards the sun (x east, y north, z up).
    pub fn direction(&self) -> [f64; 3] {
        let (az, el) = (self.azimuth.to_radians(), self.elevation.to_radians());
        [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()]
    }

    /// The sun in direction `d` (x east, y north, z up; unit length).
    pub fn from_direction([e, n, up]: [f64; 3]) -> Self {
        Self {
            azimuth: e.atan2(n).to_degrees().rem_euclid(360.0),
            elevation: up.clamp(-1.0, 1.0).asin().to_degrees(),
        }
    }
}

/// A sun position: azimuth clockwise from north and elevation, degrees.
pub type SunPosition = [f64; 2];

/// The Julian day of hour `ut_hours` (UT) of day `day` (1 = 1 January) of
/// the Gregorian `year`.
pub fn julian_day(year: i32, day: u32, ut_hours: f64) -> f64 {
    // Meeus eq. 7.1 for 1 January 0h, then the day of the year.
    let y = f64::from(year - 1);
    let a = (y / 100.0).floor();
    let b = 2.0 - a + (a / 4.0).floor();
    let jan0 = (365.25 * (y + 4716.0)).floor() + (30.6001 * 14.0_f64).floor() + b - 1524.5;
    jan0 + f64::from(day) + ut_hours / 24.0
}

/// Where the sun stands seen from the earth's centre at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolarCoordinates {
    /// Declination, radians.
    pub declination: f64,
    /// Equation of time (apparent minus mean solar time), minutes.
    pub equation_of_time: f64,
    /// Earth-sun distance, astronomical units.
    pub distance: f64,
}

impl SolarCoordinates {
    /// At Julian day `jd` (Meeus ch. 25 and eq. 28.3).
    pub fn at(jd: f64) -> Self {
        let t = (jd - 2_451_545.0) / 36_525.0;
        let l0 = (280.466_46 + t * (36_000.769_83 + t * 0.000_303_2)).rem_euclid(360.0);
        let m = 357.529_11 + t * (35_999.050_29 - t * 0.000_153_7);
        let e = 0.016_708_634 - t * (0.000_042_037 + t * 0.000_000_126_7);
        let mr = m.to_radians();
        let centre = (1.914_602 - t * (0.004_817 + t * 0.000_014)) * mr.sin()
            + (0.019_993 - t * 0.000_101) * (2.0 * mr).sin()
            + 0.000_289 * (3.0 * mr).sin();
        let anomaly = (m + centre).to_radians();
        let distance = 1.000_001_018 * (1.0 - e * e) / (1.0 + e * anomaly.cos());
        let omega = (125.04 - 1934.136 * t).to_radians();
        let lambda = (l0 + centre - 0.005_69 - 0.004_78 * omega.sin()).to_radians();
        let seconds = 21.448 - t * (46.815 + t * (0.000_59 - t * 0.001_813));
        let eps0 = 23.0 + (26.0 + seconds / 60.0) / 60.0;
        let eps = (eps0 + 0.002_56 * omega.cos()).to_radians();
        let declination = (eps.sin() * lambda.sin()).asin();
        let y = (eps / 2.0).tan().powi(2);
        let l0r = l0.to_radians();
        let eot = y * (2.0 * l0r).sin() - 2.0 * e * mr.sin()
            + 4.0 * e * y * mr.sin() * (2.0 * l0r).cos()
            - 0.5 * y * y * (4.0 * l0r).sin()
            - 1.25 * e * e * (2.0 * mr).sin();
        Self {
            declination,
            equation_of_time: 4.0 * eot.to_degrees(),
            distance,
        }
    }
}

/// The unit vector towards the sun (x east, y north, z up) at latitude
/// `latitude` (radians) when its declination is `declination` and its hour
/// angle `hour_angle` (radians, 0 at local apparent noon, growing westwards).
#[inline]
pub fn direction_at(latitude: f64, declination: f64, hour_angle: f64) -> [f64; 3] {
    direction_of(
        latitude.sin_cos(),
        declination.sin_cos(),
        hour_angle.sin_cos(),
    )
}

/// [`direction_at`] of the sines and cosines of the three angles, which a
/// caller with many latitudes or hours takes once.
#[inline]
pub fn direction_of((sp, cp): (f64, f64), (sd, cd): (f64, f64), (sw, cw): (f64, f64)) -> [f64; 3] {
    // East: -cos d sin w; north and up: the declination's circle tilted
    // by the latitude.
    [-cd * sw, cp * sd - sp * cd * cw, sp * sd + cp * cd * cw]
}

/// The sun seen from `latitude`, `longitude` (degrees, east positive) at
/// Julian day `jd` (UT): what `check_spa.py` compares with NREL's SPA.
pub fn sun_at(latitude: f64, longitude: f64, jd: f64) -> Sun {
    let c = SolarCoordinates::at(jd);
    let ut_minutes = ((jd + 0.5).fract()) * 1440.0;
    let solar_minutes = ut_minutes + c.equation_of_time + 4.0 * longitude;
    let hour_angle = (solar_minutes / 4.0 - 180.0).to_radians();
    Sun::from_direction(direction_at(
        latitude.to_radians(),
        c.declination,
        hour_angle,
    ))
}

/// The UT hour at which local apparent solar time is `solar_hours` at
/// `longitude` (degrees east) on day `day` of `year`: solar time less the
/// longitude's offset and the equation of time (taken at the first guess,
/// which moves it by well under a second).
pub fn ut_of_solar_time(year: i32, day: u32, solar_hours: f64, longitude: f64) -> f64 {
    let guess = solar_hours - longitude / 15.0;
    let eot = SolarCoordinates::at(julian_day(year, day, guess)).equation_of_time;
    guess - eot / 60.0
}

/// The year the planner's day paths are taken in (any recent year moves a
/// day's sun by a fraction of a degree).
pub const PATH_YEAR: i32 = 2026;

/// The sun every 15 minutes of day `day` (1-366) while it is up, at
/// `latitude` degrees, as `[azimuth clockwise from north, elevation]`
/// degrees, at the midpoints of the quarter hours of local apparent solar
/// time: what a plan for "this day's shadows" needs.
pub(crate) fn sun_path(latitude: f64, day: u32) -> Vec<SunPosition> {
    let phi = latitude.to_radians();
    (0..96)
        .filter_map(|quarter| {
            let solar_hours = (f64::from(quarter) + 0.5) / 4.0;
            let ut = ut_of_solar_time(PATH_YEAR, day, solar_hours, 0.0);
            let c = SolarCoordinates::at(julian_day(PATH_YEAR, day, ut));
            let hour_angle = (solar_hours * 15.0 - 180.0).to_radians();
            let sun = Sun::from_direction(direction_at(phi, c.declination, hour_angle));
            (sun.elevation > 0.0).then_some([sun.azimuth, sun.elevation])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Meeus's worked example 25.a (1992 October 13.0 TD): apparent
    /// declination -7.78507 degrees, distance 0.99766 AU; and example 28.b
    /// (the same instant): equation of time 13m42.7s.
    #[test]
    fn meeus_worked_examples() {
        let jd = 2_448_908.5;
        assert!((julian_day(1992, 287, 0.0) - jd).abs() < 1e-9);
        let c = SolarCoordinates::at(jd);
        assert!((c.declination.to_degrees() + 7.785_07).abs() < 2e-4);
        assert!((c.distance - 0.997_66).abs() < 1e-5);
        assert!((c.equation_of_time - (13.0 + 42.7 / 60.0)).abs() < 0.05);
    }

    /// SPA's own example (Reda and Andreas 2008, table A5.1: 2003 October
    /// 17, 12:30:30 local at UT-7, 39.742476 N, 105.1786 W): topocentric
    /// zenith 50.11162, azimuth 194.34024 degrees. Without parallax and
    /// refraction the geocentric sun differs from that by under 0.01 deg
    /// in azimuth and by the refraction (about 0.012 deg at 40 deg up).
    #[test]
    fn near_spa_example() {
        let jd = julian_day(2003, 290, 19.0 + 30.0 / 60.0 + 30.0 / 3600.0);
        let sun = sun_at(39.742_476, -105.178_6, jd);
        assert!((sun.azimuth - 194.340_24).abs() < 0.02, "{sun:?}");
        assert!((90.0 - sun.elevation - 50.111_62).abs() < 0.03, "{sun:?}");
    }

    #[test]
    fn direction_round_trips() {
        let sun = Sun {
            azimuth: 250.0,
            elevation: 15.0,
        };
        let back = Sun::from_direction(sun.direction());
        assert!((back.azimuth - 250.0).abs() < 1e-9 && (back.elevation - 15.0).abs() < 1e-9);
    }

    /// At the midsummer solstice noon, 45 N: the sun due south at 68.4 deg;
    /// the path is symmetric about noon and holds 15.4 hours of day.
    #[test]
    fn a_solstice_path() {
        let path = sun_path(45.0, 172);
        let top = path.iter().map(|p| p[1]).fold(f64::MIN, f64::max);
        assert!((top - 68.4).abs() < 0.2, "{top}");
        assert!(
            (path.len() as f64 / 4.0 - 15.4).abs() < 0.3,
            "{}",
            path.len()
        );
        assert!(sun_path(80.0, 172).len() == 96 && sun_path(80.0, 355).is_empty());
    }
}
