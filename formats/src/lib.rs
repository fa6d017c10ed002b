//! # terrabake-format
//!
//! The on-disk asset format of terrabake, its writer, and its read-only,
//! memory-mapped, zero-copy reader. Renderers depend on this crate alone; it
//! knows nothing of the pipeline that bakes assets.
//!
//! An *asset* is a directory: one manifest file (`manifest.tba`: a 32-byte
//! header with magic, version and checksum, then JSON) and one file per
//! *layer* (`NAME.L<level>.g<generation>.tbl`). A layer is a grid of
//! elements (heights, pyramid maxima, cone slopes, horizon angles), cut into
//! square tiles of a power-of-two size, one chunk per tile and band, each raw
//! (viewable in place as `&[f32]`) or zstd-compressed, listed in a chunk
//! index of `(offset, stored length, raw length, codec, xxh3)` that ends the
//! file before a footer. `docs/FORMAT.md` in the repository is the full spec,
//! enough to write a reader in another language.
//!
//! Why fixed records and JSON rather than a serialisation crate: the header
//! and the index must be readable in place from a mapping, by any language,
//! without a decoder (zerocopy records, little-endian, documented offsets);
//! the manifest must be readable by people and extensible without a version
//! bump (JSON). bincode is unmaintained (RUSTSEC-2025-0141) and its layout is
//! defined by Rust code, not by a spec.
//!
//! ```no_run
//! use terrabake_format::Asset;
//! let asset = Asset::open("dem.tbake")?;
//! let height = asset.height()?;
//! let tile = height.tile::<f32>(0, 0, 0)?; // &[f32], borrowed from the mmap
//! let z = height.bilinear(10.5, 20.25)?; // None for nodata or outside
//! # Ok::<(), terrabake_format::Error>(())
//! ```

pub mod cones;
mod decode;
pub mod error;
pub mod features;
pub mod fsio;
pub mod horizons;
pub mod layers;
pub mod layout;
pub mod manifest;
pub mod reader;
pub mod surface;
pub mod trace;
pub mod writer;

pub use error::{Error, Location, Result};
pub use layout::{Codec, ElemType, FORMAT_VERSION, MANIFEST_FILE};
pub use manifest::{LayerEntry, Manifest, Quantization, HEIGHT_LAYER};
pub use memmap2::Mmap;
pub use reader::{Asset, Element, Layer, StoredChunk, Tile, TileCursor, VerifyReport};
pub use writer::{
    commit_manifest, encode_tile, EncodedTile, LayerSpec, LayerWriter, WriteLock, LOCK_FILE,
};
