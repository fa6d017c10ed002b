//! What renderers and analysts derive from horizons: sky-view factor in its
//! two common definitions, positive openness, and Stewart's (1998, sec. VI)
//! direct sky irradiance under any sky radiance and his approximate
//! radiosity.
//!
//! A post's horizon is known in bands, each covering an azimuth interval
//! `[lo, hi]` with one angle (a Stewart sector covers its wedge; a line or
//! sampled direction covers half the way to its neighbours). Within a band
//! the horizon is taken as constant.
//!
//! - **`svf`** (Zakšek et al. 2011): the solid angle of visible sky over the
//!   hemisphere above the horizontal, `1 - sum w_i sin(max(h_i, 0))`.
//!   Horizons below the horizontal count as the horizontal: this is the
//!   GIS quantity (RVT, SAGA), blind to the surface's own tilt.
//! - **`svf_cosine`** (Dozier and Frew 1990; Stewart sec. VI): the view
//!   factor from the tilted surface to the visible sky, `(1/pi) integral
//!   over visible sky of N.u dOmega`, the sky limited both by the horizon
//!   and by the surface's tangent plane. 1 on flat open ground, less on any
//!   slope even with nothing around; this is what diffuse lighting needs.
//! - **`openness`** (Yokoyama et al. 2002, positive): `sum w_i (90 -
//!   h_i)` degrees, negative horizons included (so above 90 on summits).

use crate::terrain::{atan, compass};

/// What the derived layers need of one band `[lo, hi]` (degrees): its
/// share of the circle and the azimuth integrals of the tilt term.
#[derive(Debug, Clone, Copy)]
pub struct BandIntegrals {
    fraction: f64,
    width: f64,
    /// Integrals over the band of sin(phi) and cos(phi), phi in radians.
    sin: f64,
    cos: f64,
    centre: (f64, f64),
}

impl BandIntegrals {
    /// The integrals of the bands around ascending `azimuths`
    /// ([`crate::algorithms::horizon::band_bounds`]: half the way to each neighbour).
    pub fn of_azimuths(azimuths: &[f64]) -> Vec<Self> {
        crate::algorithms::horizon::band_bounds(azimuths)
            .into_iter()
            .map(|(lo, hi)| Self::new(lo, hi))
            .collect()
    }

    pub fn new(lo: f64, hi: f64) -> Self {
        let (l, h) = (lo.to_radians(), hi.to_radians());
        Self {
            fraction: (hi - lo) / 360.0,
            width: h - l,
            sin: l.cos() - h.cos(),
            cos: h.sin() - l.sin(),
            centre: compass((lo + hi) / 2.0),
        }
    }
}

/// Running sums of the three derived layers over the bands of one post.
#[derive(Debug, Clone, Copy, Default)]
pub struct SkySums {
    sin_sum: f64,
    zenith_sum: f64,
    cosine_sum: f64,
}

impl SkySums {
    /// Adds a band whose horizon is `h_deg` (with `(sh, ch)` its sine and
    /// cosine, which callers often need too), at a post with unit `normal`.
    pub fn add(
        &mut self,
        h_deg: f64,
        (sh, ch): (f64, f64),
        band: &BandIntegrals,
        normal: [f64; 3],
    ) {
        let [sin, zenith, cosine] = band_terms(h_deg, (sh, ch), band, normal);
        self.sin_sum += sin;
        self.zenith_sum += zenith;
        self.cosine_sum += cosine;
    }

    /// The sums from their three parts: `1 - svf`, openness and `pi *
    /// svf_cosine` (what a row of posts keeps in columns).
    pub(crate) fn from_parts(sin_sum: f64, zenith_sum: f64, cosine_sum: f64) -> Self {
        Self {
            sin_sum,
            zenith_sum,
            cosine_sum,
        }
    }

    pub fn svf(&self) -> f64 {
        1.0 - self.sin_sum
    }
    pub fn svf_cosine(&self) -> f64 {
        self.cosine_sum / std::f64::consts::PI
    }
    pub fn openness(&self) -> f64 {
        self.zenith_sum
    }
}

/// What one band adds to a post's three sums ([`SkySums`]): the sine
/// term of `svf`, the zenith term of openness and the cosine integral of
/// `svf_cosine`, for a horizon of `h_deg` degrees whose sine and cosine are
/// `(sh, ch)`, at a post with unit `normal`. The cosine integral is exact
/// in elevation and in azimuth; only the clip to the tangent plane is taken
/// at the band's centre.
///
/// Branch-free (both sides of the clip computed, one kept), so that the
/// sky stage's loop over a row of posts compiles to vector code.
#[inline(always)]
pub(crate) fn band_terms(
    h_deg: f64,
    (sh, ch): (f64, f64),
    band: &BandIntegrals,
    [nx, ny, nz]: [f64; 3],
) -> [f64; 3] {
    let sin = band.fraction * sh.max(0.0);
    let zenith = band.fraction * (90.0 - h_deg);
    // The tangent plane's elevation p at the band's centre: tan p = -A / nz,
    // |p| < 90 degrees, so cos p = 1 / sqrt(1 + tan^2 p) > 0.
    let tan_plane = -(nx * band.centre.0 + ny * band.centre.1) / nz;
    let cp = 1.0 / (tan_plane * tan_plane + 1.0).sqrt();
    let below = sh < tan_plane * ch;
    let h = if below {
        atan(tan_plane)
    } else {
        h_deg.to_radians()
    };
    let (sh, ch) = if below {
        (tan_plane * cp, cp)
    } else {
        (sh, ch)
    };
    let cos_squared_integral = std::f64::consts::FRAC_PI_4 - h / 2.0 - sh * ch / 2.0;
    let sin_cos_integral = ch * ch / 2.0;
    let cosine =
        (nx * band.sin + ny * band.cos) * cos_squared_integral + nz * sin_cos_integral * band.width;
    [sin, zenith, cosine]
}

/// The sine and cosine of an angle of `deg` degrees in [-90, 90] (a
/// horizon's elevation), by their Taylor series in radians to the 21st and
/// 20th power (the next terms are below 1e-17 at 90 degrees): within 2.2e-16
/// (one unit in the last place of 1) of libm's `sin_cos` there, and with
/// neither calls nor branches, so that a loop of them compiles to vector
/// code where libm's would not.
#[inline(always)]
pub(crate) fn sin_cos_deg(deg: f64) -> (f64, f64) {
    // 1 / n! for n = 2..=21: the odd ones for the sine, the even ones for
    // the cosine, each with its alternating sign.
    const SIN: [f64; 10] = [
        -1.0 / 6.0,
        1.0 / 120.0,
        -1.0 / 5040.0,
        1.0 / 362_880.0,
        -1.0 / 39_916_800.0,
        1.0 / 6_227_020_800.0,
        -1.0 / 1_307_674_368_000.0,
        1.0 / 355_687_428_096_000.0,
        -1.0 / 121_645_100_408_832_000.0,
        1.0 / 51_090_942_171_709_440_000.0,
    ];
    const COS: [f64; 10] = [
        -1.0 / 2.0,
        1.0 / 24.0,
        -1.0 / 720.0,
        1.0 / 40_320.0,
        -1.0 / 3_628_800.0,
        1.0 / 479_001_600.0,
        -1.0 / 87_178_291_200.0,
        1.0 / 20_922_789_888_000.0,
        -1.0 / 6_402_373_705_728_000.0,
        1.0 / 2_432_902_008_176_640_000.0,
    ];
    let x = deg.to_radians();
    let z = x * x;
    let (mut s, mut c) = (0.0, 0.0);
    for i in (0..10).rev() {
        s = s * z + SIN[i];
        c = c * z + COS[i];
    }
    (x + x * z * s, 1.0 + z * c)
}

/// The sums of a post with unit `normal` whose horizon is `horizons`
/// degrees in the bands of `integrals`, in order.
pub fn sums_of_horizons(
    integrals: &[BandIntegrals],
    horizons: impl IntoIterator<Item = f64>,
    normal: [f64; 3],
) -> SkySums {
    let mut sums = SkySums::default();
    for (band, h) in integrals.iter().zip(horizons) {
        sums.add(h, sin_cos_deg(h), band, normal);
    }
    sums
}

/// The sky-view factor (Zakšek's, over the horizontal) of a post whose
/// horizon is `horizons` degrees in the bands of `integrals`, in order.
pub fn svf_of_horizons(
    integrals: &[BandIntegrals],
    horizons: impl IntoIterator<Item = f64>,
) -> f64 {
    sums_of_horizons(integrals, horizons, [0.0, 0.0, 1.0]).svf()
}

/// A sky radiance distribution tabulated for Stewart's direct primary
/// irradiance: per azimuth sample and per elevation bin, the cumulative
/// integral from the zenith down of `L(u) u cos(el)` (three components), so
/// that a post's irradiance is three lookups per azimuth sample.
#[derive(Debug, Clone)]
pub struct SkyTable {
    /// Azimuth samples: unit (east, north) and band index.
    units: Vec<((f64, f64), usize)>,
    bins: usize,
    /// `[sample][bin]`: integral over elevations from bin's lower edge to 90.
    cumulative: Vec<[f64; 3]>,
}

impl SkyTable {
    /// Tabulates `radiance(azimuth_deg, elevation_deg)` over bands
    /// `[lo, hi]` (degrees), `per_band` azimuth samples each, elevation in
    /// `bins` bins from -90 to 90.
    pub fn new(
        bands: &[(f64, f64)],
        per_band: usize,
        bins: usize,
        radiance: impl Fn(f64, f64) -> f64,
    ) -> Self {
        let mut units = Vec::new();
        let mut cumulative = Vec::new();
        let del = 180.0 / bins as f64;
        for (band, &(lo, hi)) in bands.iter().enumerate() {
            let dphi = (hi - lo) / per_band as f64;
            for j in 0..per_band {
                let az = lo + (j as f64 + 0.5) * dphi;
                let (e, n) = compass(az);
                units.push(((e, n), band));
                let mut acc = [0.0; 3];
                let mut column = vec![[0.0; 3]; bins + 1];
                for bin in (0..bins).rev() {
                    let el = -90.0 + (bin as f64 + 0.5) * del;
                    let (se, ce) = el.to_radians().sin_cos();
                    let l = radiance(az, el) * ce * del.to_radians() * dphi.to_radians();
                    acc[0] += l * ce * e;
                    acc[1] += l * ce * n;
                    acc[2] += l * se;
                    column[bin] = acc;
                }
                cumulative.extend(column);
            }
        }
        Self {
            units,
            bins,
            cumulative,
        }
    }

    /// Direct sky irradiance `integral over visible sky of L(u) N.u dOmega`
    /// at a post with unit `normal` and band horizons `horizon_deg`.
    pub(crate) fn irradiance(&self, normal: [f64; 3], horizon_deg: &[f32]) -> f64 {
        let mut total = 0.0;
        for (j, &((e, n), band)) in self.units.iter().enumerate() {
            let tilt = normal[0] * e + normal[1] * n;
            let plane = (-tilt / normal[2]).atan().to_degrees();
            let h = f64::from(horizon_deg[band]).max(plane);
            let bin = (((h + 90.0) / 180.0 * self.bins as f64).round() as usize).min(self.bins);
            let c = self.cumulative[j * (self.bins + 1) + bin];
            total += normal[0] * c[0] + normal[1] * c[1] + normal[2] * c[2];
        }
        total.max(0.0)
    }
}

/// Stewart and Langer's radiosity (Stewart 1998, sec. VI-A): outgoing
/// radiance of a Lambertian post of albedo `rho` with direct irradiance
/// `irradiance` and cosine sky-view factor `svf_cosine`, the terrain it sees
/// assumed as bright as itself.
pub(crate) fn radiosity(irradiance: f64, svf_cosine: f64, rho: f64) -> f64 {
    rho * irradiance / std::f64::consts::PI / (1.0 - rho * (1.0 - svf_cosine))
}

/// Stewart's sky for Fig. 9: `L = cos^exponent(angle to the sun)` over the
/// sky, plus a uniform `ambient`.
pub(crate) fn sun_glow(
    sun_azimuth: f64,
    sun_elevation: f64,
    exponent: i32,
    ambient: f64,
) -> impl Fn(f64, f64) -> f64 {
    let unit = |az: f64, el: f64| {
        let (e, n) = compass(az);
        let (s, c) = el.to_radians().sin_cos();
        [e * c, n * c, s]
    };
    let sun = unit(sun_azimuth, sun_elevation);
    move |az, el| {
        if el < 0.0 {
            return 0.0;
        }
        let u = unit(az, el);
        let cos = (u[0] * sun[0] + u[1] * sun[1] + u[2] * sun[2]).max(0.0);
        cos.powi(exponent) + ambient
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uniform_bands(k: usize) -> Vec<(f64, f64)> {
        let w = 360.0 / k as f64;
        (0..k)
            .map(|i| (i as f64 * w - w / 2.0, i as f64 * w + w / 2.0))
            .collect()
    }

    #[test]
    fn flat_open_ground_sees_the_whole_sky() {
        let bands = uniform_bands(16);
        let mut sums = SkySums::default();
        for &(lo, hi) in &bands {
            sums.add(
                0.0,
                0.0f64.to_radians().sin_cos(),
                &BandIntegrals::new(lo, hi),
                [0.0, 0.0, 1.0],
            );
        }
        assert!((sums.svf() - 1.0).abs() < 1e-12);
        assert!((sums.svf_cosine() - 1.0).abs() < 1e-9);
        assert!((sums.openness() - 90.0).abs() < 1e-12);
        let table = SkyTable::new(&bands, 4, 512, |_, el| if el >= 0.0 { 1.0 } else { 0.0 });
        let e = table.irradiance([0.0, 0.0, 1.0], &[0.0; 16]);
        assert!((e - std::f64::consts::PI).abs() < 1e-3, "{e}");
    }

    #[test]
    fn a_uniform_horizon_leaves_cos_squared() {
        // Horizon at 30 degrees all round: svf = 1 - sin 30, cosine svf = cos^2 30.
        let bands = uniform_bands(64);
        let mut sums = SkySums::default();
        for &(lo, hi) in &bands {
            sums.add(
                30.0,
                30.0f64.to_radians().sin_cos(),
                &BandIntegrals::new(lo, hi),
                [0.0, 0.0, 1.0],
            );
        }
        assert!((sums.svf() - 0.5).abs() < 1e-12);
        assert!((sums.svf_cosine() - 0.75).abs() < 1e-9);
    }

    #[test]
    fn a_tilted_plane_alone_has_cosine_svf_of_its_tilt() {
        // A surface tilted by 30 degrees on open flat ground (horizon at the
        // horizontal): (1 + cos 30) / 2; with no ground at all (horizon
        // -90) the whole hemisphere over the surface: 1.
        let tilt = 30f64.to_radians();
        let normal = [tilt.sin(), 0.0, tilt.cos()];
        let bands = uniform_bands(64);
        let mut sums = SkySums::default();
        for &(lo, hi) in &bands {
            sums.add(
                0.0,
                0.0f64.to_radians().sin_cos(),
                &BandIntegrals::new(lo, hi),
                normal,
            );
        }
        let expected = (1.0 + tilt.cos()) / 2.0;
        assert!(
            (sums.svf_cosine() - expected).abs() < 1e-3,
            "{}",
            sums.svf_cosine()
        );
        let mut open = SkySums::default();
        for &(lo, hi) in &bands {
            open.add(
                -90.0,
                (-90.0f64).to_radians().sin_cos(),
                &BandIntegrals::new(lo, hi),
                normal,
            );
        }
        assert!(
            (open.svf_cosine() - 1.0).abs() < 1e-3,
            "{}",
            open.svf_cosine()
        );
    }

    #[test]
    fn sines_cosines_and_arctangents_agree_with_libm() {
        // Every hundredth of a degree over the horizon's range, and
        // arctangents over twelve decades either side of zero (all three
        // of Cephes' ranges).
        for i in -9000..=9000 {
            let deg = f64::from(i) / 100.0;
            let (s, c) = sin_cos_deg(deg);
            let (ws, wc) = deg.to_radians().sin_cos();
            // One unit in the last place of 1 at most.
            let close = |a: f64, b: f64| (a - b).abs() <= f64::EPSILON;
            assert!(close(s, ws) && close(c, wc), "{deg}: {s} {c}");
        }
        for i in -1200..=1200 {
            for x in [f64::from(i) / 100.0, 10f64.powf(f64::from(i) / 100.0)] {
                for x in [x, -x] {
                    let want = x.atan();
                    assert!(
                        (atan(x) - want).abs() <= 4.0 * f64::EPSILON * want.abs().max(1e-300),
                        "{x}: {} against {want}",
                        atan(x)
                    );
                }
            }
        }
        assert_eq!(atan(0.0), 0.0);
    }
}
