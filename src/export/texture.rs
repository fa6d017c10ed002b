//! Textures for shaders: KTX2 files (Khronos' container, which Vulkan,
//! wgpu, Unity, Unreal and Godot load) written by hand, uncompressed, one
//! mip level.
//!
//! - **Horizons** (`--layer horizon`, `.ktx2`): a 2D array texture, one
//!   layer per band, `R8_UNORM` or `R16_UNORM` as the bake's angle encoding
//!   stored them (an `f32` bake is quantised to 16 bits, rounded to the
//!   nearest). A shader reads `v` in 0..1 and gets degrees as `offset +
//!   scale * v * max_code` (the key `terrabake.decode` says which; code 0 is
//!   nodata). The band azimuths are in `terrabake.band_azimuths`.
//! - **Cone planes** (`--layer cone_apex` or `cone_slope`, `.ktx2`): one
//!   `R32G32_SFLOAT` texture, apex in R and slope in G, one texel per cell.
//!   Made **conservative under bilinear filtering**: a filtered sample at a
//!   point `p` blends the four texels around `p`, and `p`'s own cell is one
//!   of them; each texel stores the highest apex and the least slope of the
//!   3 x 3 cells around it, so every blend is at least as high and at most
//!   as wide as the cone of the cell `p` lies in, and the cone from `p` with
//!   the blended apex and slope holds no terrain (the cell's cone covers
//!   it: `d(q, cell) <= |q - p|`). An ordinary cone map is not conservative
//!   under filtering: the blend of a wide neighbour and a narrow cell is
//!   wider than the cell's (tests/textures.rs counts such violations on the
//!   undilated planes). Unbounded slopes are stored as 1e30 (a blend with
//!   infinity would be NaN at weight 0).
//!
//! Other layers export as `R32_SFLOAT` arrays of their decoded values.

use std::io::Write;
use std::path::Path;

use anyhow::Result;
use terrabake_format::horizons::AngleEncoding;
use terrabake_format::{Asset, ElemType, Layer, Mmap};

use crate::error::bail;
use crate::plumbing::output::write_atomically;

/// Vulkan's format numbers for the formats written.
pub const VK_FORMAT_R8_UNORM: u32 = 9;
pub const VK_FORMAT_R16_UNORM: u32 = 70;
pub const VK_FORMAT_R32_SFLOAT: u32 = 100;
pub const VK_FORMAT_R32G32_SFLOAT: u32 = 103;

/// What a slope of infinity is stored as.
pub const UNBOUNDED_SLOPE: f32 = 1e30;

/// One uncompressed KTX2 texture: `layers` images of `width x height`
/// texels, each texel `channels` samples of `bits` bits (unsigned
/// normalised, or float for 32).
#[derive(Debug)]
pub struct Ktx2 {
    pub vk_format: u32,
    pub width: u32,
    pub height: u32,
    /// Array layers (0: not an array).
    pub layers: u32,
    pub channels: u32,
    pub bits: u32,
    pub float: bool,
    /// Key/value metadata.
    pub kv: Vec<(String, String)>,
    /// The level's bytes: layer after layer, rows top (north) first.
    pub data: Vec<u8>,
}

impl Ktx2 {
    /// The file's bytes (KTX 2.0 spec, sec. 3: identifier, header, index,
    /// level index, data format descriptor, key/value data, level data).
    pub(crate) fn to_bytes(&self) -> Vec<u8> {
        let type_size = (self.bits / 8).max(1);
        let texel = type_size * self.channels;
        // Data format descriptor: its total size, then one basic block of
        // 24 bytes plus 16 per sample.
        let mut dfd = Vec::new();
        let block = 24 + 16 * self.channels;
        dfd.extend((4 + block).to_le_bytes());
        dfd.extend(0u32.to_le_bytes()); // vendor 0 (Khronos), type 0 (basic)
        dfd.extend(2u16.to_le_bytes()); // version 2 (KDFD 1.3)
        dfd.extend((block as u16).to_le_bytes());
        // Colour model RGBSDA, primaries BT.709, transfer linear, no flags.
        dfd.extend([1u8, 1, 1, 0]);
        dfd.extend([0u8; 4]); // texel block 1 x 1 x 1 x 1 (stored minus one)
        let mut planes = [0u8; 8];
        planes[0] = texel as u8;
        dfd.extend(planes);
        for c in 0..self.channels {
            dfd.extend(((c * self.bits) as u16).to_le_bytes());
            dfd.push((self.bits - 1) as u8);
            // Channel id (R 0, G 1); float samples are also signed.
            dfd.push(c as u8 | if self.float { 0x80 | 0x40 } else { 0 });
            dfd.extend([0u8; 4]); // sample position
            let (lower, upper) = if self.float {
                ((-1.0f32).to_bits(), 1.0f32.to_bits())
            } else {
                (0, ((1u64 << self.bits) - 1) as u32)
            };
            dfd.extend(lower.to_le_bytes());
            dfd.extend(upper.to_le_bytes());
        }
        let mut kvd = Vec::new();
        let mut kv = self.kv.clone();
        kv.push((
            "KTXwriter".into(),
            format!("terrabake {}", env!("CARGO_PKG_VERSION")),
        ));
        kv.sort();
        for (k, v) in &kv {
            let entry = [k.as_bytes(), &[0], v.as_bytes(), &[0]].concat();
            kvd.extend((entry.len() as u32).to_le_bytes());
            kvd.extend(&entry);
            while kvd.len() % 4 != 0 {
                kvd.push(0);
            }
        }
        // 12 identifier + 36 header + 32 index + 24 level index.
        let dfd_offset = 12 + 36 + 32 + 24;
        let kvd_offset = dfd_offset + dfd.len();
        // Level data aligned to lcm(texel size, 4).
        let align = lcm(texel as usize, 4);
        let data_offset = (kvd_offset + kvd.len()).div_ceil(align) * align;
        let mut out = Vec::with_capacity(data_offset + self.data.len());
        out.extend([
            0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A,
        ]);
        for v in [
            self.vk_format,
            type_size,
            self.width,
            self.height,
            0, // depth
            self.layers,
            1, // faces
            1, // levels
            0, // no supercompression
        ] {
            out.extend(v.to_le_bytes());
        }
        out.extend((dfd_offset as u32).to_le_bytes());
        out.extend((dfd.len() as u32).to_le_bytes());
        out.extend((kvd_offset as u32).to_le_bytes());
        out.extend((kvd.len() as u32).to_le_bytes());
        out.extend(0u64.to_le_bytes()); // no supercompression global data
        out.extend(0u64.to_le_bytes());
        for v in [data_offset, self.data.len(), self.data.len()] {
            out.extend((v as u64).to_le_bytes());
        }
        out.extend(&dfd);
        out.extend(&kvd);
        out.resize(data_offset, 0);
        out.extend(&self.data);
        out
    }
}

fn lcm(a: usize, b: usize) -> usize {
    let gcd = |mut a: usize, mut b: usize| {
        while b != 0 {
            (a, b) = (b, a % b);
        }
        a
    };
    a / gcd(a, b) * b
}

/// The texture for `layer` of `asset` (see the module docs).
pub fn texture_for_layer(asset: &Asset<Mmap>, layer: &Layer<Mmap>) -> crate::Result<Ktx2> {
    let e = layer.entry();
    let (w, h, bands) = (e.width, e.height, e.bands);
    if u64::from(w) * u64::from(h) * u64::from(bands) > 1 << 28 {
        bail!(
            "layer {} is {w} x {h} x {bands}: a KTX2 export holds the whole texture and is limited to 2^28 texels",
            e.key()
        );
    }
    let posts = w as usize * h as usize;
    let mut values = vec![0f32; posts];
    let name = e.name.as_str();
    if name == terrabake_format::layers::CONE_APEX || name == terrabake_format::layers::CONE_SLOPE {
        let read = |layer: &Layer<Mmap>| -> Result<Vec<f32>> {
            let mut v = vec![0f32; posts];
            layer.read_rows_f32(0, 0, &mut v)?;
            Ok(v)
        };
        let apex = read(asset.layer(terrabake_format::layers::CONE_APEX, 0)?)?;
        let slope = read(asset.layer(terrabake_format::layers::CONE_SLOPE, 0)?)?;
        let (apex, slope) = conservative_cones(&apex, &slope, (w as usize, h as usize));
        let mut data = Vec::with_capacity(posts * 8);
        for (a, m) in apex.iter().zip(&slope) {
            data.extend(a.to_le_bytes());
            data.extend(m.to_le_bytes());
        }
        return Ok(Ktx2 {
            vk_format: VK_FORMAT_R32G32_SFLOAT,
            width: w,
            height: h,
            layers: 0,
            channels: 2,
            bits: 32,
            float: true,
            kv: vec![(
                "terrabake.cones".into(),
                "R: cone apex (m), G: cone slope (horizontal m per m of rise; 1e30 unbounded); one texel per cell, north row first; each texel the highest apex and least slope of its 3 x 3 cells, so a bilinear sample at p bounds an empty cone from p".into(),
            )],
            data,
        });
    }
    if name == terrabake_format::layers::HORIZON {
        // The stored codes when the bake quantised; an f32 bake at 16 bits.
        let enc = match e.elem {
            ElemType::U8 => AngleEncoding::U8,
            _ => AngleEncoding::U16,
        };
        let q = enc.quantization().expect("u8 and u16 are quantised");
        let (bits, max_code) = if enc == AngleEncoding::U8 {
            (8, 255)
        } else {
            (16, 65535)
        };
        let mut data = Vec::with_capacity(posts * bands as usize * (bits / 8) as usize);
        for b in 0..bands {
            layer.read_rows_f32(b, 0, &mut values)?;
            for &deg in &values {
                let code = enc.encode(f64::from(deg));
                if bits == 8 {
                    data.push(code as u8);
                } else {
                    data.extend((code as u16).to_le_bytes());
                }
            }
        }
        let azimuths: Vec<String> = e.band_azimuths.iter().map(|a| format!("{a}")).collect();
        return Ok(Ktx2 {
            vk_format: if bits == 8 { VK_FORMAT_R8_UNORM } else { VK_FORMAT_R16_UNORM },
            width: w,
            height: h,
            layers: bands,
            channels: 1,
            bits,
            float: false,
            kv: vec![
                (
                    "terrabake.decode".into(),
                    format!(
                        "{{\"degrees\": \"offset + scale * v * max_code\", \"offset\": {}, \"scale\": {}, \"max_code\": {max_code}, \"nodata_code\": 0}}",
                        q.offset, q.scale
                    ),
                ),
                ("terrabake.band_azimuths".into(), format!("[{}]", azimuths.join(", "))),
            ],
            data,
        });
    }
    let mut data = Vec::with_capacity(posts * bands as usize * 4);
    for b in 0..bands {
        layer.read_rows_f32(b, 0, &mut values)?;
        for v in &values {
            data.extend(v.to_le_bytes());
        }
    }
    Ok(Ktx2 {
        vk_format: VK_FORMAT_R32_SFLOAT,
        width: w,
        height: h,
        layers: if bands > 1 { bands } else { 0 },
        channels: 1,
        bits: 32,
        float: true,
        kv: vec![("terrabake.layer".into(), e.key())],
        data,
    })
}

/// The planes dilated for bilinear filtering: per cell the highest apex
/// and the least slope of the 3 x 3 cells around it (edges clamped), NaN
/// apexes left out, infinite values made finite (1e30).
pub(crate) fn conservative_cones(
    apex: &[f32],
    slope: &[f32],
    (w, h): (usize, usize),
) -> (Vec<f32>, Vec<f32>) {
    let mut a = vec![f32::NEG_INFINITY; w * h];
    let mut m = vec![f32::INFINITY; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            for ny in y.saturating_sub(1)..(y + 2).min(h) {
                for nx in x.saturating_sub(1)..(x + 2).min(w) {
                    let j = ny * w + nx;
                    if !apex[j].is_nan() {
                        a[i] = a[i].max(apex[j]);
                    }
                    if !slope[j].is_nan() {
                        m[i] = m[i].min(slope[j]);
                    }
                }
            }
            // No surface around: an apex no ray reaches (no leap), finite
            // so that a blend never meets 0 * inf.
            if !a[i].is_finite() {
                a[i] = UNBOUNDED_SLOPE;
            }
            m[i] = m[i].min(UNBOUNDED_SLOPE);
        }
    }
    (a, m)
}

/// The horizon layer of `asset` as `2K + 1` Fourier coefficients per post
/// ([`crate::algorithms::horizon::fourier`]): an `R32_SFLOAT` array texture, layer `j`
/// coefficient `j` (`c_0`, then `cos` and `sin` of each harmonic), NaN for
/// nodata.
pub(crate) fn fourier_texture(asset: &Asset<Mmap>, harmonics: usize) -> Result<Ktx2> {
    let layer = asset.layer(terrabake_format::layers::HORIZON, 0)?;
    let e = layer.entry();
    let held = u64::from(e.bands).max(2 * harmonics as u64 + 1);
    if u64::from(e.width) * u64::from(e.height) * held > 1 << 28 {
        bail!(
            "layer {} is {} x {} x {}: a Fourier export holds the bands and the coefficients and is limited to 2^28 values",
            e.key(),
            e.width,
            e.height,
            held
        );
    }
    let (bands, azimuths) = crate::stages::horizons::read_horizons(asset)?;
    let fit = crate::algorithms::horizon::fourier::FourierBasis::new(&azimuths, harmonics)?;
    let (w, h) = (layer.width(), layer.height());
    let posts = w as usize * h as usize;
    let mut coefficients = vec![0f32; fit.len() * posts];
    let (mut post, mut c) = (vec![0f32; bands.len()], vec![0f32; fit.len()]);
    for i in 0..posts {
        post.iter_mut().zip(&bands).for_each(|(p, b)| *p = b[i]);
        fit.fit(&post, &mut c);
        for (j, &v) in c.iter().enumerate() {
            coefficients[j * posts + i] = v;
        }
    }
    Ok(Ktx2 {
        vk_format: VK_FORMAT_R32_SFLOAT,
        width: w,
        height: h,
        layers: fit.len() as u32,
        channels: 1,
        bits: 32,
        float: true,
        kv: vec![(
            "terrabake.fourier".into(),
            format!(
                "horizon (degrees) at compass azimuth a (radians) = L0 + sum over k = 1..{harmonics} of L(2k-1) cos(k a) + L(2k) sin(k a), least squares through the {} stored bands",
                bands.len()
            ),
        )],
        data: coefficients.iter().flat_map(|v| v.to_le_bytes()).collect(),
    })
}

/// Writes `texture` to `path` (atomically).
pub(crate) fn write_ktx2(path: &Path, texture: &Ktx2) -> Result<()> {
    let bytes = texture.to_bytes();
    Ok(write_atomically(path, |f| Ok(f.write_all(&bytes)?))?)
}
