//! The one decoder of stored layers: whatever a layer's element type and
//! encoding, [`Layer::read_rows_f32`] gives its real values as `f32`, with
//! NaN for nodata. Stages, export, shading and renderers all read through
//! it, so a new encoding is taught here once.
//!
//! | stored | real value |
//! | --- | --- |
//! | `f32` | as stored (NaN is nodata) |
//! | `f16` | its value, through `quantization` when the layer has one |
//! | `u8`, `u16`, `i16`, `u32` | the integer, through `quantization` when the layer has one (its `nodata` code is NaN) |
//! | `u16` `cone_slope` | the cone module's half-angle code table ([`crate::cones::decode_slope`]) |

use half::f16;

use crate::error::Result;
use crate::layout::ElemType;

use crate::reader::{Element, Layer};

impl<D: AsRef<[u8]>> Layer<D> {
    /// Rows `y0 .. y0 + out.len() / width` of `band`, whole rows, decoded to
    /// real values (see the module docs).
    pub fn read_rows_f32(&self, band: u32, y0: u32, out: &mut [f32]) -> Result<()> {
        let w = self.width();
        let rows = (out.len() / w as usize) as u32;
        self.read_window_f32(band, [0, y0, w, rows], out)
    }

    /// The window `[x0, y0, w, h]` (columns `x0..x0 + w`, rows `y0..y0 + h`)
    /// of `band`, row-major into `out` (`w * h` long), decoded to real values.
    pub fn read_window_f32(&self, band: u32, window: [u32; 4], out: &mut [f32]) -> Result<()> {
        let [x0, y0, w, rows] = window;
        let entry = self.entry();
        let q = entry.quantization;
        let number = move |code: f64, integer: Option<u64>| -> f32 {
            match (q, integer) {
                (Some(q), Some(code)) => q.value(code).map_or(f32::NAN, |v| v as f32),
                (Some(q), None) => (q.offset + q.scale * code) as f32,
                (None, _) => code as f32,
            }
        };
        match entry.elem {
            ElemType::F32 => self.read_window(band, x0, y0, w, rows, out),
            ElemType::F16 => self.decode_window::<u16>(band, window, out, |bits| {
                number(f16::from_bits(bits).to_f64(), None)
            }),
            ElemType::U16 if entry.name == crate::layers::CONE_SLOPE => {
                self.decode_window::<u16>(band, window, out, |code| {
                    crate::cones::decode_slope(u32::from(code), crate::cones::ConeEncoding::U16)
                        as f32
                })
            }
            ElemType::U16 => self.decode_window::<u16>(band, window, out, |c| {
                number(f64::from(c), Some(u64::from(c)))
            }),
            ElemType::U8 => self.decode_window::<u8>(band, window, out, |c| {
                number(f64::from(c), Some(u64::from(c)))
            }),
            ElemType::I16 => self.decode_window::<i16>(band, window, out, |c| {
                // A negative code is never quantised nodata (codes are >= 0).
                number(f64::from(c), u64::try_from(c).ok())
            }),
            ElemType::U32 => self.decode_window::<u32>(band, window, out, |c| {
                number(f64::from(c), Some(u64::from(c)))
            }),
        }
    }

    /// Reads the window as `T` and maps each element through `value`, a
    /// tile row at a time (no intermediate array of the whole window).
    fn decode_window<T: Element>(
        &self,
        band: u32,
        [x0, y0, w, rows]: [u32; 4],
        out: &mut [f32],
        value: impl Fn(T) -> f32,
    ) -> Result<()> {
        let (w, rows) = (w as usize, rows as usize);
        if out.len() != w * rows {
            return Err(crate::Error::OutOfRange {
                layer: self.entry().key(),
                what: "output length (window width x height)",
                index: out.len() as u64,
                limit: (w * rows) as u64,
            });
        }
        let ts = self.tile_size();
        // One tile row of codes at a time bounds the scratch to a tile row.
        let mut y = 0;
        let mut codes = Vec::new();
        while y < rows {
            let gy = y0 + y as u32;
            let n = (ts - gy % ts).min((rows - y) as u32) as usize;
            codes.resize(n * w, T::new_zeroed());
            self.read_window(band, x0, gy, w as u32, n as u32, &mut codes)?;
            for (o, &c) in out[y * w..(y + n) * w].iter_mut().zip(&codes) {
                *o = value(c);
            }
            y += n;
        }
        Ok(())
    }
}
