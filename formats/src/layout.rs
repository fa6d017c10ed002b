//! The fixed-layout, little-endian records of a layer file, read in place
//! from the mapped bytes with `zerocopy` (no parsing, no allocation).
//!
//! ```text
//! offset 0            ┌──────────────────────────────┐
//!                     │ LayerHeader (64 B)           │ magic "TBLAYER\0", version, shape, type
//! 64                  ├──────────────────────────────┤
//!                     │ chunk 0 (64-byte aligned)    │ raw: tile_size² elements, row-major
//!                     │ chunk 1 ...                  │ zstd: one zstd frame of the same bytes
//!                     │                              │ shuffled zstd: of the bytes grouped by significance
//! index_offset        ├──────────────────────────────┤
//!                     │ ChunkEntry × chunk_count     │ (offset, stored_len, raw_len, codec, xxh3)
//! file_len - 64       ├──────────────────────────────┤
//!                     │ LayerFooter (64 B)           │ index offset + checksum, version, "TBLEND\0\0"
//!                     └──────────────────────────────┘
//! ```
//!
//! Chunks are ordered band-major, then tile row, then tile column:
//! `chunk = (band * tiles_y + ty) * tiles_x + tx`. A GPU uploads one band (a
//! horizon sector, say) as one contiguous run of chunks.

use zerocopy::little_endian::{U16, U32, U64};
use zerocopy::{FromBytes, Immutable, IntoBytes, KnownLayout, Unaligned};

/// The format version this crate writes and the only one it reads.
pub const FORMAT_VERSION: u32 = 1;
/// Magic at offset 0 of every layer file.
pub const LAYER_MAGIC: [u8; 8] = *b"TBLAYER\0";
/// Magic in the last 8 bytes of every layer file.
pub const FOOTER_MAGIC: [u8; 8] = *b"TBLEND\0\0";
/// Magic at offset 0 of the manifest file.
pub const MANIFEST_MAGIC: [u8; 8] = *b"TBASSET\0";
/// File name of the manifest inside an asset directory.
pub const MANIFEST_FILE: &str = "manifest.tba";
/// Every chunk starts at a multiple of this, so that a raw tile can be viewed
/// in place as `&[f32]` (and as a cache line on the GPU side).
pub const CHUNK_ALIGN: u64 = 64;

/// Element type of a layer, as stored in `LayerHeader::elem_type`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u16)]
#[non_exhaustive]
pub enum ElemType {
    F32 = 1,
    U16 = 2,
    U8 = 3,
    I16 = 4,
    /// IEEE 754 binary16, stored as its `u16` bits.
    F16 = 5,
    U32 = 6,
}

impl ElemType {
    pub fn from_code(code: u16) -> Option<Self> {
        Some(match code {
            1 => Self::F32,
            2 => Self::U16,
            3 => Self::U8,
            4 => Self::I16,
            5 => Self::F16,
            6 => Self::U32,
            _ => return None,
        })
    }
    pub fn size(self) -> usize {
        match self {
            Self::F32 | Self::U32 => 4,
            Self::U16 | Self::I16 | Self::F16 => 2,
            Self::U8 => 1,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::U16 => "u16",
            Self::U8 => "u8",
            Self::I16 => "i16",
            Self::F16 => "f16",
            Self::U32 => "u32",
        }
    }
}

/// How a chunk's bytes are stored.
///
/// A layer's manifest entry names the codec its writer was asked for (`raw`
/// or `zstd`); each chunk's index record names the codec that chunk is in.
/// Asked for `zstd`, the writer keeps for each tile the smallest of raw,
/// plain zstd and shuffled zstd ([`crate::encode_tile`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u8)]
#[non_exhaustive]
pub enum Codec {
    /// The tile's bytes as they are: a reader views them in place.
    Raw = 0,
    /// One zstd frame that decompresses to the tile's bytes.
    Zstd = 1,
    /// One zstd frame that decompresses to the tile's bytes *shuffled*:
    /// byte 0 of every element, then byte 1 of every element, and so on
    /// (HDF5's and Blosc's shuffle). Neighbouring posts share their high
    /// bytes, so grouped they compress further: the bundled tile's heights
    /// 6.1x against plain zstd's 4.7x, its sky-view factors 1.8x against
    /// 1.5x. A chunk codec only: a layer's writer is asked for `zstd`.
    #[serde(skip)]
    ShuffledZstd = 2,
}

impl Codec {
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Self::Raw),
            1 => Some(Self::Zstd),
            2 => Some(Self::ShuffledZstd),
            _ => None,
        }
    }

    /// Decodes a chunk stored in this codec into `out` (the tile's
    /// `raw_len` bytes, elements of `elem_size` bytes); the decoded length,
    /// which a caller checks against `out`'s.
    pub fn decode_into(
        self,
        stored: &[u8],
        elem_size: usize,
        out: &mut [u8],
    ) -> std::io::Result<usize> {
        match self {
            Self::Raw => {
                let n = stored.len().min(out.len());
                out[..n].copy_from_slice(&stored[..n]);
                Ok(stored.len())
            }
            Self::Zstd => zstd::bulk::decompress_to_buffer(stored, out),
            Self::ShuffledZstd => {
                let shuffled = zstd::bulk::decompress(stored, out.len())?;
                if shuffled.len() == out.len() {
                    unshuffle(&shuffled, elem_size, out);
                }
                Ok(shuffled.len())
            }
        }
    }
}

/// Groups the bytes of `elem_size`-byte elements by significance: `out[j *
/// n + i] = raw[i * elem_size + j]` for `n` elements.
pub fn shuffle(raw: &[u8], elem_size: usize) -> Vec<u8> {
    let n = raw.len() / elem_size;
    let mut out = vec![0u8; raw.len()];
    for (i, element) in raw.chunks_exact(elem_size).enumerate() {
        for (j, &b) in element.iter().enumerate() {
            out[j * n + i] = b;
        }
    }
    out
}

/// The inverse of [`shuffle`], into `out` (as long as `shuffled`).
pub fn unshuffle(shuffled: &[u8], elem_size: usize, out: &mut [u8]) {
    let n = shuffled.len() / elem_size;
    for (i, element) in out.chunks_exact_mut(elem_size).enumerate() {
        for (j, b) in element.iter_mut().enumerate() {
            *b = shuffled[j * n + i];
        }
    }
}

/// First 64 bytes of a layer file.
#[derive(Debug, Clone, Copy, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned)]
#[repr(C)]
pub struct LayerHeader {
    pub magic: [u8; 8],
    pub version: U32,
    pub elem_type: U16,
    pub reserved0: U16,
    /// Layer grid, in elements (cells of this layer's level).
    pub width: U32,
    pub height: U32,
    pub tile_size: U32,
    pub bands: U32,
    pub level: U32,
    pub tiles_x: U32,
    pub tiles_y: U32,
    pub reserved1: U32,
    /// Bits of the value that pads edge tiles past the grid (NaN for f32),
    /// zero-extended to 64 bits.
    pub fill_bits: U64,
    /// xxh3-64 of bytes 0..56 of this header.
    pub header_xxh3: U64,
}

/// One entry of the chunk index.
#[derive(Debug, Clone, Copy, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned)]
#[repr(C)]
pub struct ChunkEntry {
    pub offset: U64,
    pub stored_len: U64,
    pub raw_len: U32,
    pub codec: u8,
    pub reserved: [u8; 3],
    /// xxh3-64 of the stored bytes.
    pub xxh3: U64,
}

/// Last 64 bytes of a layer file.
#[derive(Debug, Clone, Copy, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned)]
#[repr(C)]
pub struct LayerFooter {
    pub index_offset: U64,
    pub chunk_count: U64,
    /// xxh3-64 of the whole chunk index.
    pub index_xxh3: U64,
    /// Repeats `LayerHeader::header_xxh3`, binding head and tail.
    pub header_xxh3: U64,
    pub version: U32,
    pub reserved: [u8; 20],
    pub magic: [u8; 8],
}

/// First 32 bytes of the manifest file; the JSON manifest follows.
#[derive(Debug, Clone, Copy, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned)]
#[repr(C)]
pub struct ManifestHeader {
    pub magic: [u8; 8],
    pub version: U32,
    pub reserved: U32,
    pub json_len: U64,
    /// xxh3-64 of the JSON bytes.
    pub json_xxh3: U64,
}

pub const HEADER_LEN: usize = size_of::<LayerHeader>();
pub const FOOTER_LEN: usize = size_of::<LayerFooter>();
pub const ENTRY_LEN: usize = size_of::<ChunkEntry>();
pub const MANIFEST_HEADER_LEN: usize = size_of::<ManifestHeader>();

const _: () = assert!(HEADER_LEN == 64 && FOOTER_LEN == 64 && ENTRY_LEN == 32);
const _: () = assert!(MANIFEST_HEADER_LEN == 32);

/// The checksum used everywhere in the format.
pub fn xxh3(bytes: &[u8]) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytes)
}

impl LayerHeader {
    /// The checksum that `header_xxh3` must hold.
    pub fn compute_xxh3(&self) -> u64 {
        xxh3(&self.as_bytes()[..56])
    }
}

/// Tiles needed to cover `cells` with tiles of `tile_size`.
pub fn tiles_for(cells: u32, tile_size: u32) -> u32 {
    cells.div_ceil(tile_size)
}

/// Rounds `pos` up to the next chunk boundary.
pub fn align_up(pos: u64) -> u64 {
    pos.div_ceil(CHUNK_ALIGN) * CHUNK_ALIGN
}
