//! Horizon maps as stored in an asset, and what a renderer asks of them.
//!
//! The `horizon` layer has one band per azimuth: band `i` holds, for every
//! post, the elevation angle of the horizon seen from that post in direction
//! `band_azimuths[i]` (compass degrees, clockwise from north; the manifest
//! lists them). Angles are degrees in `[-90, 90]`: negative means the
//! terrain ahead stays below the horizontal, and `-90` ([`NOTHING_AHEAD`])
//! means nothing of the DEM lies ahead at all within the distance searched
//! (the post is on the DEM's edge, facing out). That is a marker, not an
//! angle: between a band holding it and a band holding a real angle the
//! reader serves the real angle, never a blend of the two (which would put
//! a horizon tens of degrees below anything on the ground). Bands
//! are chunked band-major (sector-major), so one sector is a contiguous run
//! of tiles that a GPU uploads as one texture-array slice.
//!
//! What an angle means depends on the method the `horizons` stage ran
//! (recorded in the layer description and the stage parameters): `sector`
//! is Stewart's (1998) maximum over the closed azimuth wedge centred on the
//! band azimuth, `line` the maximum along the straight line from the post
//! in that direction, `sampled` centre-line sampling (a baseline).
//!
//! **Encodings** (chosen at bake time from the angular error asked for):
//!
//! | elem | stored `q` | angle in degrees | worst error |
//! |------|-----------|------------------|-------------|
//! | `u8` | 1..=255, 0 = nodata | `-90 + (q - 1) * 180 / 254` | 0.354 deg |
//! | `u16` | 1..=65535, 0 = nodata | `-90 + (q - 1) * 180 / 65534` | 0.0014 deg |
//! | `f32` | the angle, NaN = nodata | itself | rounding |
//!
//! The layer's [`Quantization`] says the same (`offset = -90 - step`,
//! `scale = step`, `nodata = 0`), so generic readers decode it without this
//! module.

use crate::error::{Error, Result};
use crate::features::{serve, HorizonFeatures, SightLine};
use crate::manifest::Quantization;
use crate::reader::{Asset, Layer};
use crate::ElemType;

pub use crate::layers::{HORIZON, HORIZON_EDGE, OPENNESS, SVF, SVF_COSINE};

/// The angle stored where nothing of the DEM lies ahead (degrees): every
/// encoding holds it exactly (code 1 of `u8` and `u16`).
pub const NOTHING_AHEAD: f64 = -90.0;

/// A horizon as the reader serves it between two bands.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Served {
    /// Degrees: linear between the two nearest bands, or the one band
    /// holding a real angle where the other holds [`NOTHING_AHEAD`].
    pub angle: f64,
    /// One of the two bands has nothing ahead: the azimuth looks past the
    /// DEM's edge on one side, and the horizon there jumps (from a real
    /// angle to none) at an azimuth the bands do not record.
    pub at_edge: bool,
}

/// How horizon angles are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AngleEncoding {
    U8,
    U16,
    F32,
}

impl std::str::FromStr for AngleEncoding {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|e| e.name() == s)
            .ok_or_else(|| format!("unknown angle encoding {s:?} (u8, u16, f32)"))
    }
}

impl AngleEncoding {
    pub const ALL: [AngleEncoding; 3] = [Self::U8, Self::U16, Self::F32];

    pub fn name(self) -> &'static str {
        match self {
            Self::U8 => "u8",
            Self::U16 => "u16",
            Self::F32 => "f32",
        }
    }

    pub fn elem(self) -> ElemType {
        match self {
            Self::U8 => ElemType::U8,
            Self::U16 => ElemType::U16,
            Self::F32 => ElemType::F32,
        }
    }

    #[inline]
    fn codes(self) -> Option<f64> {
        match self {
            Self::U8 => Some(254.0),
            Self::U16 => Some(65534.0),
            Self::F32 => None,
        }
    }

    /// Degrees between neighbouring codes (0 for f32).
    #[inline]
    pub fn step_deg(self) -> f64 {
        self.codes().map_or(0.0, |n| 180.0 / n)
    }

    /// How far below a band's angle the features' horizon at its azimuth
    /// may be and still be what set it (`crate::features::serve`): the
    /// encoding's error and the rounding of an `f32` angle.
    pub fn feature_tolerance(self) -> f64 {
        self.max_error_deg() + 1e-3
    }

    /// The worst error of a stored angle, in degrees: half a step, or f32
    /// rounding at 90 degrees.
    pub fn max_error_deg(self) -> f64 {
        match self {
            Self::F32 => 90.0 * f64::from(f32::EPSILON),
            _ => self.step_deg() / 2.0,
        }
    }

    /// The smallest encoding whose worst error is within `error_deg`.
    pub fn for_error(error_deg: f64) -> Self {
        [Self::U8, Self::U16]
            .into_iter()
            .filter(|_| error_deg > 0.0)
            .find(|e| e.max_error_deg() <= error_deg)
            .unwrap_or(Self::F32)
    }

    pub fn quantization(self) -> Option<Quantization> {
        let step = self.step_deg();
        self.codes().map(|_| Quantization {
            offset: -90.0 - step,
            scale: step,
            nodata: Some(0),
        })
    }

    /// The stored code of `deg` (NaN: nodata), rounded to the nearest code.
    #[inline]
    pub fn encode(self, deg: f64) -> u32 {
        match self.codes() {
            None => (deg as f32).to_bits(),
            Some(n) => quantise(deg, n, self.step_deg()),
        }
    }

    /// The codes of a row of angles (degrees, NaN: nodata) in a quantised
    /// encoding, each as [`Self::encode`] gives it, narrowed by `narrow`
    /// (to `u8` or `u16`): one loop without branches, which the compiler
    /// turns into vector code. `None` for f32, whose angles are stored as
    /// they are.
    #[inline]
    pub fn quantise_row<T>(self, degs: &[f32], narrow: impl Fn(u32) -> T) -> Option<Vec<T>> {
        let (n, step) = (self.codes()?, self.step_deg());
        Some(
            degs.iter()
                .map(|&deg| narrow(quantise(f64::from(deg), n, step)))
                .collect(),
        )
    }

    /// The angle in degrees of a stored code; `None` for nodata.
    pub fn decode(self, code: u32) -> Option<f64> {
        match self.codes() {
            None => Some(f64::from(f32::from_bits(code))).filter(|d| !d.is_nan()),
            Some(_) if code == 0 => None,
            Some(_) => Some(-90.0 + f64::from(code - 1) * self.step_deg()),
        }
    }

    fn from_elem(elem: ElemType) -> Option<Self> {
        match elem {
            ElemType::U8 => Some(Self::U8),
            ElemType::U16 => Some(Self::U16),
            ElemType::F32 => Some(Self::F32),
            _ => None,
        }
    }
}

/// The code of `deg` among `n + 1` codes `step` degrees apart from -90
/// (0 for NaN, nodata), rounded to the nearest: `round` of a quotient in
/// [0, n] inline (libm's call was a fifth of encoding), its integer part
/// plus one from a fraction of a half or more (`x - trunc(x)` is exact).
/// Branch-free: NaN's quotient is selected away, not tested first. The
/// code leaves `f64` as the low bits of its sum with 2^52, which vector
/// code does in lanes: `as u32` saturates, and went lane by lane (7 % of
/// the line stage's samples, 2.6 % this way).
#[inline]
fn quantise(deg: f64, n: f64, step: f64) -> u32 {
    // 2^52: an integer below it is the low bits of its sum with it.
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    let x = (deg.clamp(-90.0, 90.0) + 90.0) / step;
    let whole = x.trunc();
    let up = if x - whole >= 0.5 { 1.0 } else { 0.0 };
    let code = ((whole + up).min(n) + 1.0 + TWO_52).to_bits() as u32;
    if deg.is_nan() {
        0
    } else {
        code
    }
}

/// Fraction of a sun disc of angular radius `radius` (degrees) whose centre
/// stands at `elevation` that shows above a horizon at `horizon` (degrees):
/// the area of the disc above a chord, with the horizon taken as straight
/// across the disc. A point sun (`radius` 0) is lit or not.
pub fn disc_fraction_above(elevation: f64, horizon: f64, radius: f64) -> f64 {
    if radius <= 0.0 {
        return if elevation > horizon { 1.0 } else { 0.0 };
    }
    let d = ((elevation - horizon) / radius).clamp(-1.0, 1.0);
    1.0 - (d.acos() - d * (1.0 - d * d).sqrt()) / std::f64::consts::PI
}

/// The two bands on either side of `azimuth` (compass degrees; `azimuths`
/// ascending) and how far from the first to the second it lies, in 0..1:
/// the horizon there is `h[i] + f * (h[j] - h[i])`.
pub fn bands_around(azimuths: &[f64], azimuth: f64) -> (usize, usize, f64) {
    let n = azimuths.len();
    let az = azimuth.rem_euclid(360.0);
    let after = azimuths.partition_point(|&a| a <= az);
    let (i, j) = ((after + n - 1) % n, after % n);
    let span = (azimuths[j] - azimuths[i]).rem_euclid(360.0);
    let f = if span == 0.0 {
        0.0
    } else {
        (az - azimuths[i]).rem_euclid(360.0) / span
    };
    (i, j, f)
}

/// The horizon a fraction `f` of the way from band angle `h0` to `h1`
/// (degrees): linear, except that [`NOTHING_AHEAD`] is a marker and not an
/// angle, so between it and a real angle the real one is served. On the
/// band itself (`f` 0) the band is served, marker or not.
#[inline]
pub fn between(h0: f64, h1: f64, f: f64) -> f64 {
    if f == 0.0 {
        h0
    } else if h0 == NOTHING_AHEAD && h1 != NOTHING_AHEAD {
        h1
    } else if h1 == NOTHING_AHEAD && h0 != NOTHING_AHEAD {
        h0
    } else {
        h0 + f * (h1 - h0)
    }
}

/// Distance in metres from post `(x, y)` to the DEM's edge, going in the
/// compass direction `azimuth` on a `width x height` grid of `dx x dy`
/// metres: how far the DEM can see. A horizon whose terrain could rise past
/// it beyond that distance may be cut short by the edge.
pub fn edge_distance(
    (width, height): (u32, u32),
    (dx, dy): (f64, f64),
    (x, y): (f64, f64),
    azimuth: f64,
) -> f64 {
    edge_distance_along((width, height), (dx, dy), (x, y), heading(azimuth))
}

/// Metres east and south per metre travelled in the compass direction
/// `azimuth` (degrees), as [`edge_distance_along`] takes it.
pub fn heading(azimuth: f64) -> (f64, f64) {
    let (sin, cos) = azimuth.to_radians().sin_cos();
    (sin, -cos)
}

/// [`edge_distance`] going `(ve, vs)` metres east and south per metre
/// ([`heading`]): one direction's sine and cosine taken once for a whole
/// band of posts.
#[inline]
pub fn edge_distance_along(
    (width, height): (u32, u32),
    (dx, dy): (f64, f64),
    (x, y): (f64, f64),
    (ve, vs): (f64, f64),
) -> f64 {
    edge_reach(x, ve, width, dx).min(edge_reach(y, vs, height, dy))
}

/// Whether the DEM's edge may cut a horizon whose angle has sine and
/// cosine `(sin, cos)`, the edge `distance` metres away along it: terrain
/// beyond the edge, at most `rise` metres above the eye there (the DEM's
/// highest post less the eye and the curvature drop at `distance`), could
/// stand above it. Always at the edge itself. The `horizon_edge` layer
/// counts the bands where this holds.
#[inline]
pub fn edge_may_cut(rise: f64, distance: f64, (sin, cos): (f64, f64)) -> bool {
    // The rise's slope rise / d against tan h, both sides times d cos h.
    distance == 0.0 || rise * cos > sin * distance
}

/// One axis of [`edge_distance_along`]: metres from position `pos` (in
/// posts) to the last or the first of `posts` posts `step` metres apart,
/// going `v` metres along the axis per metre travelled (infinite when the
/// axis does not move). Its own function so that a caller with many posts
/// on one row takes the row's axis once.
#[inline]
pub fn edge_reach(pos: f64, v: f64, posts: u32, step: f64) -> f64 {
    if v > 1e-12 {
        (f64::from(posts - 1) - pos) * step / v
    } else if v < -1e-12 {
        pos * step / -v
    } else {
        f64::INFINITY
    }
}

/// The `horizon` layer of an asset, decoded.
pub struct HorizonMap<'a, D> {
    layer: &'a Layer<D>,
    encoding: AngleEncoding,
    azimuths: Vec<f64>,
    /// The layer's features and what serving them needs: the heights (the
    /// eye of each sight line) and the post spacing, metres.
    features: Option<(&'a HorizonFeatures, &'a Layer<D>, (f64, f64))>,
}

impl<D> std::fmt::Debug for HorizonMap<'_, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HorizonMap")
            .field("encoding", &self.encoding)
            .field("azimuths", &self.azimuths)
            .finish_non_exhaustive()
    }
}

impl<'a, D: AsRef<[u8]>> HorizonMap<'a, D> {
    pub fn open(asset: &'a Asset<D>) -> Result<Self> {
        let layer = asset.layer(HORIZON, 0)?;
        let entry = layer.entry();
        let bad =
            |why: String| Error::malformed(crate::Location::layer(asset.dir(), entry.key()), why);
        let encoding = AngleEncoding::from_elem(entry.elem)
            .ok_or_else(|| bad(format!("horizon angles stored as {}", entry.elem.name())))?;
        if entry.band_azimuths.len() != entry.bands as usize {
            return Err(bad(format!(
                "{} bands but {} band azimuths",
                entry.bands,
                entry.band_azimuths.len()
            )));
        }
        let features = match &entry.features {
            Some(f) if !f.posts.is_empty() => {
                let m = asset.manifest();
                Some((f, asset.height()?, (m.cell_size.dx, m.cell_size.dy)))
            }
            _ => None,
        };
        Ok(Self {
            layer,
            encoding,
            azimuths: entry.band_azimuths.clone(),
            features,
        })
    }

    /// The posts served exactly between bands (`crate::features`), if any.
    pub fn features(&self) -> Option<&HorizonFeatures> {
        self.features.map(|(f, _, _)| f)
    }

    pub fn encoding(&self) -> AngleEncoding {
        self.encoding
    }

    /// The `horizon` layer itself.
    pub fn layer(&self) -> &'a Layer<D> {
        self.layer
    }

    /// Compass azimuth of each band, degrees.
    pub fn azimuths(&self) -> &[f64] {
        &self.azimuths
    }

    /// Horizon angle (degrees) at post `(x, y)` in band `band`; `None` for
    /// nodata and posts outside the area the stage computed.
    pub fn angle(&self, x: u32, y: u32, band: u32) -> Result<Option<f64>> {
        let code = match self.encoding {
            AngleEncoding::U8 => u32::from(self.layer.get::<u8>(band, x, y)?),
            AngleEncoding::U16 => u32::from(self.layer.get::<u16>(band, x, y)?),
            AngleEncoding::F32 => self.layer.get::<f32>(band, x, y)?.to_bits(),
        };
        Ok(self.encoding.decode(code))
    }

    /// The horizon at `azimuth` (compass degrees), linear between the two
    /// nearest band azimuths (cyclically), or the one real angle where the
    /// other band has nothing ahead; `None` for nodata.
    pub fn horizon_at(&self, x: u32, y: u32, azimuth: f64) -> Result<Option<f64>> {
        Ok(self.served_at(x, y, azimuth)?.map(|s| s.angle))
    }

    /// [`Self::horizon_at`], saying whether one band had nothing ahead.
    /// With features, their exact horizon where it is higher, and the
    /// terrain behind a band they set taken from the bands beside it
    /// ([`crate::features::serve`]).
    pub fn served_at(&self, x: u32, y: u32, azimuth: f64) -> Result<Option<Served>> {
        let angle = |k: usize| self.angle(x, y, k as u32);
        let Some((features, heights, spacing)) = self.features else {
            return serve(&self.azimuths, azimuth, angle, (|_| None, None), 0.0);
        };
        let Some(eye) = heights.height_at(x, y)? else {
            return Ok(None);
        };
        let feature = |az: f64| features.horizon(&SightLine::new((x, y), eye.into(), az, spacing));
        serve(
            &self.azimuths,
            azimuth,
            angle,
            (|k: usize| feature(self.azimuths[k]), feature(azimuth)),
            self.encoding.feature_tolerance(),
        )
    }

    /// [`Self::horizon_at`] at every post of rows `y0..` (whole rows, as
    /// many as `out` holds), degrees, NaN for nodata: a map of the horizon
    /// in one direction (sun shadows, `r.horizon`'s files).
    pub fn served_rows(&self, azimuth: f64, y0: u32, out: &mut [f32]) -> Result<()> {
        if self.features.is_some() {
            let w = self.layer.width() as usize;
            for (k, a) in out.iter_mut().enumerate() {
                let (x, y) = ((k % w) as u32, y0 + (k / w) as u32);
                *a = self
                    .horizon_at(x, y, azimuth)?
                    .map_or(f32::NAN, |v| v as f32);
            }
            return Ok(());
        }
        let (i, j, f) = bands_around(&self.azimuths, azimuth);
        let mut other = vec![0f32; out.len()];
        self.layer.read_rows_f32(i as u32, y0, out)?;
        self.layer.read_rows_f32(j as u32, y0, &mut other)?;
        for (a, &b) in out.iter_mut().zip(&other) {
            *a = between(f64::from(*a), f64::from(b), f) as f32;
        }
        Ok(())
    }

    /// Fraction of the sun's disc (centre at `sun_azimuth`, `sun_elevation`,
    /// angular radius `sun_radius`, all degrees; the sun is about 0.27)
    /// visible above the horizon of post `(x, y)`: sun shadows at any hour
    /// without tracing a ray. `None` for nodata.
    pub fn lit_fraction(
        &self,
        x: u32,
        y: u32,
        sun_azimuth: f64,
        sun_elevation: f64,
        sun_radius: f64,
    ) -> Result<Option<f64>> {
        Ok(self
            .horizon_at(x, y, sun_azimuth)?
            .map(|h| disc_fraction_above(sun_elevation, h, sun_radius)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The inline rounding is `f64::round`: on every code's centre and
    /// edges (the halves, where the two could part), a hair either side,
    /// and the ends.
    #[test]
    fn codes_round_as_round_does() {
        for enc in [AngleEncoding::U8, AngleEncoding::U16] {
            let (n, step) = (enc.codes().unwrap(), enc.step_deg());
            let round =
                |deg: f64| 1 + ((deg.clamp(-90.0, 90.0) + 90.0) / step).round().min(n) as u32;
            for k in 0..=(2 * n as u32 + 2) {
                let deg = -90.0 + f64::from(k) * step / 2.0;
                for d in [deg, deg.next_up(), deg.next_down(), -95.0, 95.0] {
                    assert_eq!(enc.encode(d), round(d), "{enc:?} {d}");
                }
            }
        }
    }

    #[test]
    fn codes_round_trip_within_half_a_step() {
        for enc in [AngleEncoding::U8, AngleEncoding::U16, AngleEncoding::F32] {
            assert_eq!(enc.decode(enc.encode(f64::NAN)), None);
            for i in 0..=3600 {
                let deg = -90.0 + i as f64 * 0.05;
                let back = enc.decode(enc.encode(deg)).unwrap();
                assert!(
                    (back - deg).abs() <= enc.max_error_deg() + 1e-9,
                    "{enc:?} {deg} {back}"
                );
                if let Some(q) = enc.quantization() {
                    let value = q.value(u64::from(enc.encode(deg))).unwrap();
                    assert!((value - back).abs() < 1e-9);
                    assert_eq!(q.value(u64::from(enc.encode(f64::NAN))), None);
                }
            }
        }
        assert_eq!(AngleEncoding::for_error(0.5), AngleEncoding::U8);
        assert_eq!(AngleEncoding::for_error(0.01), AngleEncoding::U16);
        assert_eq!(AngleEncoding::for_error(0.001), AngleEncoding::F32);
        assert_eq!(AngleEncoding::for_error(0.0), AngleEncoding::F32);
    }

    #[test]
    fn disc_fraction() {
        assert_eq!(disc_fraction_above(10.0, 5.0, 0.0), 1.0);
        assert_eq!(disc_fraction_above(5.0, 10.0, 0.0), 0.0);
        assert!((disc_fraction_above(10.0, 10.0, 0.27) - 0.5).abs() < 1e-12);
        assert_eq!(disc_fraction_above(11.0, 10.0, 0.27), 1.0);
        assert_eq!(disc_fraction_above(9.0, 10.0, 0.27), 0.0);
        // Monotone in elevation.
        let f: Vec<f64> = (0..=20)
            .map(|i| disc_fraction_above(9.73 + i as f64 * 0.027, 10.0, 0.27))
            .collect();
        assert!(f.windows(2).all(|w| w[0] <= w[1]));
    }

    /// "Nothing ahead" is never blended with a real angle.
    #[test]
    fn the_edge_marker_is_not_an_angle() {
        assert_eq!(between(10.0, 20.0, 0.25), 12.5);
        assert_eq!(between(NOTHING_AHEAD, 20.0, 0.25), 20.0);
        assert_eq!(between(20.0, NOTHING_AHEAD, 0.75), 20.0);
        assert_eq!(between(NOTHING_AHEAD, NOTHING_AHEAD, 0.5), NOTHING_AHEAD);
        // On a band, the band: facing out over the edge there is no angle.
        assert_eq!(between(NOTHING_AHEAD, 20.0, 0.0), NOTHING_AHEAD);
        assert_eq!(between(20.0, NOTHING_AHEAD, 0.0), 20.0);
        for enc in [AngleEncoding::U8, AngleEncoding::U16, AngleEncoding::F32] {
            assert_eq!(enc.decode(enc.encode(NOTHING_AHEAD)), Some(NOTHING_AHEAD));
        }
    }

    #[test]
    fn bands_around_wraps() {
        let az = [0.0, 90.0, 180.0, 270.0];
        assert_eq!(bands_around(&az, 45.0), (0, 1, 0.5));
        assert_eq!(bands_around(&az, 315.0), (3, 0, 0.5));
        assert_eq!(bands_around(&az, -45.0), (3, 0, 0.5));
        assert_eq!(bands_around(&az, 90.0), (1, 2, 0.0));
    }

    #[test]
    fn edge_distances() {
        let g = ((11, 21), (2.0, 3.0));
        assert!((edge_distance(g.0, g.1, (5.0, 5.0), 0.0) - 15.0).abs() < 1e-9); // north: 5 rows
        assert!((edge_distance(g.0, g.1, (5.0, 5.0), 180.0) - 45.0).abs() < 1e-9);
        assert!((edge_distance(g.0, g.1, (5.0, 5.0), 90.0) - 10.0).abs() < 1e-9);
        assert!((edge_distance(g.0, g.1, (5.0, 5.0), 270.0) - 10.0).abs() < 1e-9);
        assert_eq!(edge_distance(g.0, g.1, (0.0, 3.0), 270.0), 0.0);
    }
}
