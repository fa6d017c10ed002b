//! The sun as the stages and renderers see it: a direction, and its path
//! over a day.

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
}

/// A sun position: azimuth clockwise from north and elevation, degrees.
pub type SunPosition = [f64; 2];

/// The sun every 15 minutes of day `day` (1-366) while it is up, at
/// `latitude` degrees, as `[azimuth clockwise from north, elevation]`
/// degrees: Cooper's declination and the hour angle of local solar time
/// (no equation of time, no refraction): within about a degree of an
/// ephemeris, which is what a plan for "this day's shadows" needs.
pub(crate) fn sun_path(latitude: f64, day: u32) -> Vec<SunPosition> {
    let phi = latitude.to_radians();
    let declination =
        23.44f64.to_radians() * (std::f64::consts::TAU * (284.0 + f64::from(day)) / 365.0).sin();
    (0..96)
        .filter_map(|quarter| {
            let hour_angle = (f64::from(quarter) * 3.75 - 180.0 + 1.875).to_radians();
            let sin_el =
                phi.sin() * declination.sin() + phi.cos() * declination.cos() * hour_angle.cos();
            let el = sin_el.clamp(-1.0, 1.0).asin();
            // Azimuth from north, clockwise: morning east, evening west.
            let az = hour_angle
                .sin()
                .atan2(hour_angle.cos() * phi.sin() - declination.tan() * phi.cos())
                + std::f64::consts::PI;
            (el > 0.0).then(|| [az.to_degrees().rem_euclid(360.0), el.to_degrees()])
        })
        .collect()
}
