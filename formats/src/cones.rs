//! Parameter planes: a cone of empty space over every cell (Paglieroni and
//! Petersen 1992, sec. 2.2), as stored in an asset and read back for the
//! parametric tracer.
//!
//! Two layers of one element per cell, laid out like `pyramid_max@0`:
//!
//! - `cone_apex` (`z_p`, metres): the height of the cone's apex over the cell;
//! - `cone_slope` (`m_p`): the cone's width per unit of rise, in horizontal
//!   metres per metre (the paper's "slope of the linear HDDT profile").
//!
//! **Guarantee.** For cell `C`, the open cone
//! `{ (q, z) : d(q, C) < m_p * (z - z_p) }`, with `d` the horizontal distance
//! in metres from point `q` to the closed square `C`, holds no point of the
//! surface (`terrabake_format::surface`). A ray that is inside the cone is
//! strictly above the terrain; the parametric tracer leaps to where it
//! leaves.
//!
//! **Encodings.** `f32`, `f16` or `u16`, chosen at bake time, always rounded
//! so that the decoded cone lies inside the computed one: the slope rounded
//! down, the apex rounded up. (Cone maps stored with ordinary rounding are
//! not conservative: Bán, Valasek et al., "Robust Cone Step Mapping", EGSR
//! 2024.) The apex in `f16` and `u16` is `offset + scale * stored`, the
//! layer's [`Quantization`]; the slope in `f16` is the value itself, and in
//! `u16` the cone's half-angle from the vertical: `m_p = tan(q * pi / (2 *
//! 65535))` for `q < 65535`, and `65535` is an unbounded cone.

use std::f64::consts::FRAC_PI_2;

use half::f16;

use crate::error::{Error, Result};
use crate::manifest::Quantization;
use crate::reader::{Asset, Element, Layer, TileCursor};
use crate::ElemType;

pub use crate::layers::{CONE_APEX, CONE_SLOPE};

/// How the planes are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ConeEncoding {
    F32,
    F16,
    U16,
}

impl ConeEncoding {
    pub const ALL: [ConeEncoding; 3] = [ConeEncoding::F32, ConeEncoding::F16, ConeEncoding::U16];

    pub fn name(self) -> &'static str {
        match self {
            ConeEncoding::F32 => "f32",
            ConeEncoding::F16 => "f16",
            ConeEncoding::U16 => "u16",
        }
    }

    pub fn elem(self) -> ElemType {
        match self {
            ConeEncoding::F32 => ElemType::F32,
            ConeEncoding::F16 => ElemType::F16,
            ConeEncoding::U16 => ElemType::U16,
        }
    }
}

impl std::str::FromStr for ConeEncoding {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        ConeEncoding::ALL
            .into_iter()
            .find(|e| e.name() == s)
            .ok_or_else(|| format!("unknown cone encoding {s:?} (f32, f16, u16)"))
    }
}

/// The `u16` code of an unbounded cone.
const U16_UNBOUNDED: u16 = u16::MAX;

fn slope_from_angle_code(q: u16) -> f64 {
    if q == U16_UNBOUNDED {
        f64::INFINITY
    } else {
        (f64::from(q) * FRAC_PI_2 / 65535.0).tan()
    }
}

/// `v` rounded up to an `f32` (never below `v`).
pub fn round_up_f32(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) < v {
        f.next_up()
    } else {
        f
    }
}

/// `v` rounded down to an `f32` (never above `v`).
pub fn round_down_f32(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) > v {
        f.next_down()
    } else {
        f
    }
}

/// The stored slope, rounded down: `f32` bits, or the `f16` / `u16` code.
pub fn encode_slope(m: f64, enc: ConeEncoding) -> u32 {
    debug_assert!(m >= 0.0, "cone slope {m}");
    match enc {
        ConeEncoding::F32 => round_down_f32(m).to_bits(),
        ConeEncoding::F16 => {
            let mut v = f16::from_f64(m);
            if v.to_f64() > m {
                v = f16::from_bits(v.to_bits() - 1);
            }
            u32::from(v.to_bits())
        }
        ConeEncoding::U16 => {
            if m == f64::INFINITY {
                return u32::from(U16_UNBOUNDED);
            }
            let mut q = (m.atan() / FRAC_PI_2 * 65535.0).floor().min(65534.0) as u16;
            while q > 0 && slope_from_angle_code(q) > m {
                q -= 1;
            }
            u32::from(q)
        }
    }
}

/// The apex quantisation for heights in `[z_lo, z_hi]`: `None` for `f32`.
pub fn apex_quantization(z_lo: f64, z_hi: f64, enc: ConeEncoding) -> Option<Quantization> {
    let relief = (z_hi - z_lo).max(0.0);
    match enc {
        ConeEncoding::F32 => None,
        ConeEncoding::F16 => Some(Quantization {
            offset: z_lo,
            scale: 1.0,
            nodata: None,
        }),
        // Code 65534 already reaches the top, so that rounding up never
        // runs out of codes.
        ConeEncoding::U16 => Some(Quantization {
            offset: z_lo,
            scale: if relief > 0.0 {
                relief / 65534.0 * (1.0 + 1e-12)
            } else {
                1.0
            },
            nodata: None,
        }),
    }
}

/// Decodes a stored apex (the inverse of [`encode_apex`]): `f32` bits or
/// the `f16` / `u16` code, through the layer's quantisation.
#[inline]
pub fn decode_apex(code: u32, enc: ConeEncoding, q: Option<Quantization>) -> f64 {
    let stored = match enc {
        ConeEncoding::F32 => return f64::from(f32::from_bits(code)),
        ConeEncoding::F16 => f16::from_bits(code as u16).to_f64(),
        ConeEncoding::U16 => f64::from(code as u16),
    };
    let q = q.expect("f16 and u16 apexes are quantised");
    q.offset + q.scale * stored
}

/// The stored apex, rounded up: `f32` bits, or the `f16` / `u16` code.
/// `q` is [`apex_quantization`] of the layer; `z` must lie in its range.
pub fn encode_apex(z: f64, enc: ConeEncoding, q: Option<Quantization>) -> u32 {
    match enc {
        ConeEncoding::F32 => round_up_f32(z).to_bits(),
        ConeEncoding::F16 => {
            let qz = q.expect("f16 apexes are quantised");
            let mut code = f16::from_f64((z - qz.offset).max(0.0)).to_bits();
            while decode_apex(u32::from(code), enc, q) < z {
                code += 1;
            }
            u32::from(code)
        }
        ConeEncoding::U16 => {
            let qz = q.expect("u16 apexes are quantised");
            let mut code = ((z - qz.offset) / qz.scale).ceil().clamp(0.0, 65535.0) as u32;
            while code < 65535 && decode_apex(code, enc, q) < z {
                code += 1;
            }
            code
        }
    }
}

/// The 65,536 `u16` slope codes decoded, each rounded down to `f32`: built
/// once per process (about a millisecond), shared by every reader.
fn u16_slope_table() -> &'static [f32] {
    static TABLE: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        (0..=u16::MAX)
            .map(|q| round_down_f32(slope_from_angle_code(q)))
            .collect()
    })
}

/// One cell's cone, decoded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cone {
    /// `z_p`, metres.
    pub apex: f64,
    /// `m_p`, horizontal metres per metre of rise; `inf` for a cone that
    /// nothing in the DEM reaches.
    pub slope: f64,
}

/// The parameter planes of an asset, decoded on the fly.
pub struct ConePlanes<'a, D> {
    apex: &'a Layer<D>,
    slope: &'a Layer<D>,
    enc: ConeEncoding,
    apex_q: Option<Quantization>,
}

impl<D> std::fmt::Debug for ConePlanes<'_, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ConePlanes")
            .field("encoding", &self.enc)
            .field("apex_quantization", &self.apex_q)
            .finish()
    }
}

impl<'a, D: AsRef<[u8]>> ConePlanes<'a, D> {
    /// The asset's planes, or `None` when it has none.
    pub fn open(asset: &'a Asset<D>) -> Result<Option<Self>> {
        let (Ok(apex), Ok(slope)) = (asset.layer(CONE_APEX, 0), asset.layer(CONE_SLOPE, 0)) else {
            return Ok(None);
        };
        let enc = match slope.entry().elem {
            ElemType::F32 => ConeEncoding::F32,
            ElemType::F16 => ConeEncoding::F16,
            ElemType::U16 => ConeEncoding::U16,
            other => {
                return Err(Error::Spec(format!(
                    "{CONE_SLOPE} has elements of type {other:?}; expected f32, f16 or u16"
                )))
            }
        };
        if apex.entry().elem != enc.elem() {
            return Err(Error::Spec(format!(
                "{CONE_APEX} and {CONE_SLOPE} are stored in different encodings"
            )));
        }
        let apex_q = apex.entry().quantization;
        if enc != ConeEncoding::F32 && apex_q.is_none() {
            return Err(Error::Spec(format!(
                "{CONE_APEX} is {} but has no quantization",
                enc.name()
            )));
        }
        Ok(Some(Self {
            apex,
            slope,
            enc,
            apex_q,
        }))
    }

    pub fn encoding(&self) -> ConeEncoding {
        self.enc
    }

    /// A reader of cones near each other, as along a ray (see
    /// [`ConeCursor`]).
    pub fn cursor(&self) -> ConeCursor<'a, D> {
        ConeCursor {
            codes: match self.enc {
                ConeEncoding::F32 => Codes::F32(self.apex.cursor(0), self.slope.cursor(0)),
                ConeEncoding::F16 | ConeEncoding::U16 => {
                    Codes::U16(self.apex.cursor(0), self.slope.cursor(0))
                }
            },
            enc: self.enc,
            apex_q: self.apex_q,
        }
    }

    /// The cone over cell `(c, r)`. Many reads near each other go faster
    /// through one [`cursor`](Self::cursor).
    pub fn cone(&self, c: u32, r: u32) -> Result<Cone> {
        self.cursor().cone(c, r)
    }
}

/// The cones of one walk through the planes ([`ConePlanes::cursor`]): the
/// last tile of each plane is kept, as for the heights, so that a tracer's
/// step costs the two codes' loads and not two tile lookups. One per
/// thread.
pub struct ConeCursor<'a, D> {
    codes: Codes<'a, D>,
    enc: ConeEncoding,
    apex_q: Option<Quantization>,
}

enum Codes<'a, D> {
    F32(TileCursor<'a, D, f32>, TileCursor<'a, D, f32>),
    U16(TileCursor<'a, D, u16>, TileCursor<'a, D, u16>),
}

impl<D> std::fmt::Debug for ConeCursor<'_, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ConeCursor")
            .field("encoding", &self.enc)
            .finish()
    }
}

impl<D: AsRef<[u8]>> ConeCursor<'_, D> {
    /// The cone over cell `(c, r)`, as [`ConePlanes::cone`].
    #[inline]
    pub fn cone(&mut self, c: u32, r: u32) -> Result<Cone> {
        // Both tiles first, then both loads back to back: on a large DEM
        // each load is a cache miss, and so the two misses overlap.
        fn codes<D: AsRef<[u8]>, T: Element>(
            apex: &mut TileCursor<'_, D, T>,
            slope: &mut TileCursor<'_, D, T>,
            (c, r): (u32, u32),
            code: fn(T) -> u32,
        ) -> Result<(u32, u32)> {
            let ((a, i), (s, j)) = (apex.tile_of(c, r)?, slope.tile_of(c, r)?);
            Ok((code(a[i]), code(s[j])))
        }
        let (apex, slope) = match &mut self.codes {
            Codes::F32(apex, slope) => codes(apex, slope, (c, r), f32::to_bits)?,
            Codes::U16(apex, slope) => codes(apex, slope, (c, r), u32::from)?,
        };
        Ok(Cone {
            apex: decode_apex(apex, self.enc, self.apex_q),
            slope: decode_slope(slope, self.enc),
        })
    }
}

/// Decodes a stored slope (the inverse of [`encode_slope`]): `f32` bits or
/// the `f16` / `u16` code.
#[inline]
pub fn decode_slope(code: u32, enc: ConeEncoding) -> f64 {
    match enc {
        ConeEncoding::F32 => f64::from(f32::from_bits(code)),
        ConeEncoding::F16 => f16::from_bits(code as u16).to_f64(),
        ConeEncoding::U16 => f64::from(u16_slope_table()[code as usize]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn rounding_is_conservative(m in prop_oneof![0.0f64..2.0, 0.0f64..1e6, Just(f64::INFINITY), Just(0.0)], z in -500.0f64..9000.0) {
            for enc in ConeEncoding::ALL {
                let got = decode_slope(encode_slope(m, enc), enc);
                prop_assert!(got <= m, "{enc:?}: slope {m} -> {got}");
                let q = apex_quantization(-500.0, 9000.0, enc);
                let a = decode_apex(encode_apex(z, enc, q), enc, q);
                prop_assert!(a >= z, "{enc:?}: apex {z} -> {a}");
            }
        }
    }

    #[test]
    fn encodings_are_close() {
        let q = apex_quantization(0.0, 4000.0, ConeEncoding::U16);
        let a = decode_apex(
            encode_apex(1234.5, ConeEncoding::U16, q),
            ConeEncoding::U16,
            q,
        );
        assert!(a - 1234.5 < 0.07, "{a}");
        let m = decode_slope(encode_slope(3.0, ConeEncoding::U16), ConeEncoding::U16);
        assert!(3.0 - m < 3e-4 * 3.0 * 4.0, "{m}");
        assert_eq!(
            decode_slope(
                encode_slope(f64::INFINITY, ConeEncoding::F16),
                ConeEncoding::F16
            ),
            f64::INFINITY
        );
        // Beyond f16's range a finite slope becomes its largest finite value.
        assert_eq!(
            decode_slope(encode_slope(1e9, ConeEncoding::F16), ConeEncoding::F16),
            65504.0
        );
    }
}
