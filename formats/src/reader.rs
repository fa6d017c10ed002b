//! The read-only side: open an asset, validate it, and serve tiles without
//! copying.
//!
//! [`Asset::open`] maps the manifest and every layer file and checks all the
//! structure up front (magics, versions, header and index checksums, every
//! chunk's bounds and alignment), so that no later read can go out of bounds.
//! The tile bytes themselves are checksummed lazily: a tile is verified the
//! first time it is read (then remembered), and [`Asset::verify`] checks them
//! all. A raw tile is then a `&[T]` into the mapping; a zstd tile is
//! decompressed once into a bounded cache shared by all threads.
//!
//! Every type here is generic over where the bytes live (`D: AsRef<[u8]>`):
//! `memmap2::Mmap` for files, `Vec<u8>` in tests.

use std::collections::HashMap;
use std::marker::PhantomData;
use std::ops::Deref;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use memmap2::Mmap;
use zerocopy::{FromBytes, Immutable, IntoBytes, KnownLayout};

use crate::error::{Error, Location, Result};
use crate::layout::{
    tiles_for, xxh3, ChunkEntry, Codec, ElemType, LayerFooter, LayerHeader, ManifestHeader,
    CHUNK_ALIGN, ENTRY_LEN, FOOTER_LEN, FOOTER_MAGIC, FORMAT_VERSION, HEADER_LEN, LAYER_MAGIC,
    MANIFEST_FILE, MANIFEST_HEADER_LEN, MANIFEST_MAGIC,
};
use crate::manifest::{LayerEntry, Manifest, HEIGHT_LAYER};

/// Default bound of the decompressed-tile cache: 256 MiB.
pub const DEFAULT_CACHE_BYTES: u64 = 256 << 20;

/// A Rust type that a layer's elements can be read as.
pub trait Element: FromBytes + IntoBytes + Immutable + KnownLayout + Copy + Send + Sync {
    const NAME: &'static str;
    /// Whether a layer of `stored` type can be viewed as `Self`.
    fn accepts(stored: ElemType) -> bool;
}

macro_rules! element {
    ($t:ty, $name:literal, $($stored:path),+) => {
        impl Element for $t {
            const NAME: &'static str = $name;
            fn accepts(stored: ElemType) -> bool {
                matches!(stored, $($stored)|+)
            }
        }
    };
}
element!(f32, "f32", ElemType::F32);
// f16 has no std type: its bits are read as u16.
element!(u16, "u16", ElemType::U16, ElemType::F16);
element!(u8, "u8", ElemType::U8);
element!(i16, "i16", ElemType::I16);
element!(u32, "u32", ElemType::U32);

/// A decompressed tile, 8-byte aligned so any element type can view it.
#[derive(Debug)]
pub struct TileBuf {
    words: Vec<u64>,
    len: usize,
}

impl TileBuf {
    fn bytes(&self) -> &[u8] {
        &self.words.as_bytes()[..self.len]
    }
}

#[derive(Clone)]
struct ByteWeighter;
impl quick_cache::Weighter<(u32, u64), Arc<TileBuf>> for ByteWeighter {
    fn weight(&self, _key: &(u32, u64), val: &Arc<TileBuf>) -> u64 {
        val.len as u64
    }
}

type TileCache = quick_cache::sync::Cache<(u32, u64), Arc<TileBuf>, ByteWeighter>;

/// Reads elements of one band of a layer that lie near each other, as a
/// ray's walk does: the last tile read is kept, so that consecutive elements
/// in one tile pay the tile's lookup (chunk index, first-read checksum flag,
/// alignment) once, not each. One cursor per thread.
pub struct TileCursor<'a, D, T> {
    layer: &'a Layer<D>,
    band: u32,
    shift: u32,
    tile: Option<((u32, u32), Tile<'a, T>)>,
}

impl<D, T> std::fmt::Debug for TileCursor<'_, D, T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TileCursor")
            .field("layer", &self.layer.entry.key())
            .field("band", &self.band)
            .field("tile", &self.tile.as_ref().map(|t| t.0))
            .finish()
    }
}

impl<'a, D: AsRef<[u8]>, T: Element> TileCursor<'a, D, T> {
    /// The tile holding element `(x, y)` and the element's index in it
    /// (its row-major neighbours in the tile follow at `+1` and
    /// `+tile_size`, where the tile has them).
    #[inline]
    pub fn tile_of(&mut self, x: u32, y: u32) -> Result<(&[T], usize)> {
        self.layer.check_element(x, y)?;
        let (key, i) = tile_index(self.shift, x, y);
        if self.tile.as_ref().map(|t| t.0) != Some(key) {
            self.tile = Some((key, self.layer.tile::<T>(self.band, key.0, key.1)?));
        }
        Ok((&self.tile.as_ref().expect("just set").1, i))
    }

    /// Elements per tile side (a power of two).
    pub fn tile_size(&self) -> u32 {
        1 << self.shift
    }

    /// Element `(x, y)`.
    #[inline]
    pub fn get(&mut self, x: u32, y: u32) -> Result<T> {
        let (tile, i) = self.tile_of(x, y)?;
        Ok(tile[i])
    }
}

/// The tile holding element `(x, y)` of a layer whose tiles are `1 <<
/// shift` elements a side, and the element's row-major index in it. The
/// tile size is a power of two (checked at open): shifts and masks, not
/// the four integer divisions that a tracer's every step would otherwise
/// pay.
#[inline]
fn tile_index(shift: u32, x: u32, y: u32) -> ((u32, u32), usize) {
    let mask = (1 << shift) - 1;
    let i = ((y & mask) << shift) | (x & mask);
    ((x >> shift, y >> shift), i as usize)
}

/// A tile's elements: borrowed from the mapping, or shared from the cache.
pub enum Tile<'a, T> {
    Borrowed(&'a [T]),
    Cached(Arc<TileBuf>, PhantomData<T>),
}

impl<T: Element> Deref for Tile<'_, T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match self {
            Tile::Borrowed(s) => s,
            // Aligned to 8 and sized to a whole number of elements when cached.
            Tile::Cached(buf, _) => <[T]>::ref_from_bytes(buf.bytes()).expect("cached tile layout"),
        }
    }
}

impl<T> std::fmt::Debug for Tile<'_, T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Tile::Borrowed(s) => write!(f, "Tile::Borrowed({} elements)", s.len()),
            Tile::Cached(b, _) => write!(f, "Tile::Cached({} bytes)", b.len),
        }
    }
}

/// One layer file, validated.
pub struct Layer<D> {
    id: u32,
    entry: LayerEntry,
    path: PathBuf,
    bytes: D,
    header: LayerHeader,
    index_offset: usize,
    /// Per chunk: its stored bytes have been checksummed.
    checked: Box<[AtomicBool]>,
    cache: Arc<TileCache>,
}

impl<D> std::fmt::Debug for Layer<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Layer")
            .field("entry", &self.entry)
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

impl<D: AsRef<[u8]>> Layer<D> {
    fn open(
        id: u32,
        entry: LayerEntry,
        path: PathBuf,
        bytes: D,
        cache: Arc<TileCache>,
    ) -> Result<Self> {
        let at = Location::layer(&path, entry.key());
        let data = bytes.as_ref();
        let (header, footer) = header_and_footer(&at, data)?;
        let [tx, ty] = check_grid(&at, data.len(), &header, &entry)?;
        let chunks = u64::from(header.bands.get()) * u64::from(tx) * u64::from(ty);
        let index_offset = check_index(&at, data, &footer, chunks, &entry)?;
        let index_end = data.len() - FOOTER_LEN;
        let index = <[ChunkEntry]>::ref_from_bytes(&data[index_offset..index_end])
            .expect("unaligned records");
        let tile_bytes = u64::from(header.tile_size.get()).pow(2) * entry.elem.size() as u64;
        check_chunks(&at, index, index_offset as u64, tile_bytes, [tx, ty])?;
        Ok(Self {
            id,
            checked: (0..chunks).map(|_| AtomicBool::new(false)).collect(),
            index_offset,
            entry,
            path,
            bytes,
            header,
            cache,
        })
    }

    pub fn entry(&self) -> &LayerEntry {
        &self.entry
    }
    pub fn width(&self) -> u32 {
        self.entry.width
    }
    pub fn height(&self) -> u32 {
        self.entry.height
    }
    pub fn tile_size(&self) -> u32 {
        self.entry.tile_size
    }
    pub fn tiles_x(&self) -> u32 {
        self.header.tiles_x.get()
    }
    pub fn tiles_y(&self) -> u32 {
        self.header.tiles_y.get()
    }
    pub fn bands(&self) -> u32 {
        self.entry.bands
    }
    /// Bits of the value tiles are padded with past the grid's edge.
    pub fn fill_bits(&self) -> u64 {
        self.header.fill_bits.get()
    }

    fn index(&self) -> &[ChunkEntry] {
        let data = self.bytes.as_ref();
        let end = data.len() - FOOTER_LEN;
        <[ChunkEntry]>::ref_from_bytes(&data[self.index_offset..end]).expect("validated at open")
    }

    fn chunk_of(&self, band: u32, tx: u32, ty: u32) -> Result<u64> {
        let range = |what, index: u32, limit: u32| {
            if index >= limit {
                Err(Error::OutOfRange {
                    layer: self.entry.key(),
                    what,
                    index: index.into(),
                    limit: limit.into(),
                })
            } else {
                Ok(())
            }
        };
        range("band", band, self.bands())?;
        range("tile column", tx, self.tiles_x())?;
        range("tile row", ty, self.tiles_y())?;
        Ok(
            (u64::from(band) * u64::from(self.tiles_y()) + u64::from(ty))
                * u64::from(self.tiles_x())
                + u64::from(tx),
        )
    }

    fn tile_at(&self, chunk: u64) -> Location {
        Location::layer(&self.path, self.entry.key()).with_tile(chunk_tile(
            chunk,
            self.tiles_x(),
            self.tiles_y(),
        ))
    }

    /// The stored bytes of a chunk, checksummed (once per chunk per process).
    fn stored(&self, chunk: u64) -> Result<(&[u8], &ChunkEntry)> {
        let entry = &self.index()[chunk as usize];
        let (off, len) = (entry.offset.get() as usize, entry.stored_len.get() as usize);
        let stored = &self.bytes.as_ref()[off..off + len];
        let flag = &self.checked[chunk as usize];
        if !flag.load(Ordering::Acquire) {
            let got = xxh3(stored);
            if got != entry.xxh3.get() {
                return Err(Error::Checksum {
                    at: self.tile_at(chunk),
                    what: "tile",
                    expected: entry.xxh3.get(),
                    got,
                });
            }
            flag.store(true, Ordering::Release);
        }
        Ok((stored, entry))
    }

    /// Tile `(tx, ty)` of `band` as it is stored ([`Self::stored_chunk`]),
    /// with the band and tile checked against the layer: what a C caller
    /// borrows (terrabake-capi's `tb_tile`).
    pub fn stored_tile(&self, band: u32, tx: u32, ty: u32) -> Result<StoredChunk<'_>> {
        self.stored_chunk(self.chunk_of(band, tx, ty)?)
    }

    /// Chunk number `chunk` (`(band * tiles_y + ty) * tiles_x + tx`) as it
    /// is stored, checksummed but not decoded: what the join of a
    /// partitioned bake copies into the assembled layer
    /// ([`crate::LayerWriter::adopt_at`]).
    pub fn stored_chunk(&self, chunk: u64) -> Result<StoredChunk<'_>> {
        if chunk >= self.index().len() as u64 {
            return Err(Error::OutOfRange {
                layer: self.entry.key(),
                what: "chunk",
                index: chunk,
                limit: self.index().len() as u64,
            });
        }
        let (bytes, entry) = self.stored(chunk)?;
        let codec = Codec::from_code(entry.codec)
            .ok_or_else(|| Error::malformed(self.tile_at(chunk), "unknown codec"))?;
        Ok(StoredChunk {
            codec,
            raw_len: entry.raw_len.get(),
            xxh3: entry.xxh3.get(),
            bytes,
        })
    }

    /// The tile `(tx, ty)` of `band`, as elements of type `T`, row-major,
    /// `tile_size²` long (edge tiles are padded with the layer's fill value).
    pub fn tile<T: Element>(&self, band: u32, tx: u32, ty: u32) -> Result<Tile<'_, T>> {
        if !T::accepts(self.entry.elem) {
            return Err(Error::ElemType {
                layer: self.entry.key(),
                stored: self.entry.elem.name(),
                requested: T::NAME,
            });
        }
        let chunk = self.chunk_of(band, tx, ty)?;
        let (stored, entry) = self.stored(chunk)?;
        if entry.codec == Codec::Raw as u8 {
            if let Ok(slice) = <[T]>::ref_from_bytes(stored) {
                return Ok(Tile::Borrowed(slice));
            }
        }
        // Compressed, or raw bytes that are not aligned for T (bytes in memory).
        let buf = self.cache.get_or_insert_with(&(self.id, chunk), || {
            let raw_len = entry.raw_len.get() as usize;
            let mut buf = TileBuf {
                words: vec![0u64; raw_len.div_ceil(8)],
                len: raw_len,
            };
            let out = &mut buf.words.as_mut_bytes()[..raw_len];
            let codec = Codec::from_code(entry.codec)
                .ok_or_else(|| Error::malformed(self.tile_at(chunk), "unknown codec"))?;
            let n = codec
                .decode_into(stored, self.entry.elem.size(), out)
                .map_err(|source| Error::Decompress {
                    at: self.tile_at(chunk),
                    source,
                })?;
            if n != raw_len {
                return Err(Error::malformed(
                    self.tile_at(chunk),
                    format!("tile decoded to {n} bytes, expected {raw_len}"),
                ));
            }
            Ok(Arc::new(buf))
        })?;
        Ok(Tile::Cached(buf, PhantomData))
    }

    /// Element `(x, y)` of `band`.
    pub fn get<T: Element>(&self, band: u32, x: u32, y: u32) -> Result<T> {
        self.check_element(x, y)?;
        let ((tx, ty), i) = tile_index(self.tile_size().trailing_zeros(), x, y);
        Ok(self.tile::<T>(band, tx, ty)?[i])
    }

    /// A reader of `band` that keeps the last tile it read (see
    /// [`TileCursor`]).
    pub fn cursor<T: Element>(&self, band: u32) -> TileCursor<'_, D, T> {
        TileCursor {
            layer: self,
            band,
            shift: self.tile_size().trailing_zeros(),
            tile: None,
        }
    }

    fn check_element(&self, x: u32, y: u32) -> Result<()> {
        if x >= self.width() || y >= self.height() {
            let (what, index, limit) = if x >= self.width() {
                ("column", x, self.width())
            } else {
                ("row", y, self.height())
            };
            return Err(Error::OutOfRange {
                layer: self.entry.key(),
                what,
                index: index.into(),
                limit: limit.into(),
            });
        }
        Ok(())
    }

    /// Copies the window `x0..x0+w` x `y0..y0+h` of `band` into `out`
    /// (row-major, `w * h` long), tile by tile.
    pub fn read_window<T: Element>(
        &self,
        band: u32,
        x0: u32,
        y0: u32,
        w: u32,
        h: u32,
        out: &mut [T],
    ) -> Result<()> {
        let (x1, y1) = (u64::from(x0) + u64::from(w), u64::from(y0) + u64::from(h));
        if x1 > u64::from(self.width())
            || y1 > u64::from(self.height())
            || out.len() as u64 != u64::from(w) * u64::from(h)
        {
            return Err(Error::OutOfRange {
                layer: self.entry.key(),
                what: "window end",
                index: x1.max(y1),
                limit: self.width().max(self.height()).into(),
            });
        }
        let ts = self.tile_size();
        if w == 0 || h == 0 {
            return Ok(());
        }
        for ty in y0 / ts..=(y0 + h - 1) / ts {
            for tx in x0 / ts..=(x0 + w - 1) / ts {
                let tile = self.tile::<T>(band, tx, ty)?;
                let (cx0, cx1) = (x0.max(tx * ts), (x0 + w).min((tx + 1) * ts));
                let (cy0, cy1) = (y0.max(ty * ts), (y0 + h).min((ty + 1) * ts));
                for y in cy0..cy1 {
                    let src = ((y - ty * ts) * ts + (cx0 - tx * ts)) as usize;
                    let dst = ((y - y0) * w + (cx0 - x0)) as usize;
                    let n = (cx1 - cx0) as usize;
                    out[dst..dst + n].copy_from_slice(&tile[src..src + n]);
                }
            }
        }
        Ok(())
    }

    /// Height post `(x, y)` of an f32 layer; `None` for nodata (NaN).
    pub fn height_at(&self, x: u32, y: u32) -> Result<Option<f32>> {
        let z = self.get::<f32>(0, x, y)?;
        Ok((!z.is_nan()).then_some(z))
    }

    /// Bilinear interpolation of an f32 layer at grid coordinates, where post
    /// `(x, y)` sits at `(x, y)`. `None` outside the grid, or when a post
    /// with non-zero weight is nodata.
    pub fn bilinear(&self, gx: f64, gy: f64) -> Result<Option<f32>> {
        let (w, h) = (f64::from(self.width() - 1), f64::from(self.height() - 1));
        if !(0.0..=w).contains(&gx) || !(0.0..=h).contains(&gy) {
            return Ok(None);
        }
        let (x0, y0) = (
            gx.floor().min((w - 1.0).max(0.0)),
            gy.floor().min((h - 1.0).max(0.0)),
        );
        let (fx, fy) = (gx - x0, gy - y0);
        let (x0, y0) = (x0 as u32, y0 as u32);
        let ts = self.tile_size();
        // Posts (x0, y0), (x0+1, y0), (x0, y0+1), (x0+1, y0+1): one tile
        // lookup when all four share a tile (the common case), else four.
        let posts: [f32; 4] = if x0 % ts + 1 < ts && y0 % ts + 1 < ts {
            let tile = self.tile::<f32>(0, x0 / ts, y0 / ts)?;
            let i = ((y0 % ts) * ts + x0 % ts) as usize;
            let t = ts as usize;
            [tile[i], tile[i + 1], tile[i + t], tile[i + t + 1]]
        } else {
            let post = |dx: u32, dy: u32| -> Result<f32> {
                let (x, y) = (
                    (x0 + dx).min(self.width() - 1),
                    (y0 + dy).min(self.height() - 1),
                );
                self.get::<f32>(0, x, y)
            };
            [post(0, 0)?, post(1, 0)?, post(0, 1)?, post(1, 1)?]
        };
        let weights = [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ];
        let mut sum = 0.0f64;
        for (z, wt) in posts.into_iter().zip(weights) {
            if wt == 0.0 {
                continue;
            }
            if z.is_nan() {
                return Ok(None);
            }
            sum += wt * f64::from(z);
        }
        Ok(Some(sum as f32))
    }

    /// Checksums every chunk and decodes every compressed chunk.
    pub fn verify(&self) -> Vec<Error> {
        let mut problems = Vec::new();
        let mut out = Vec::new();
        for chunk in 0..self.index().len() as u64 {
            let result = self.stored_chunk(chunk).and_then(|stored| {
                if stored.codec == Codec::Raw {
                    return Ok(());
                }
                out.resize(stored.raw_len as usize, 0);
                match stored.decode_into(self.entry.elem.size(), &mut out) {
                    Ok(n) if n == out.len() => Ok(()),
                    Ok(n) => Err(Error::malformed(
                        self.tile_at(chunk),
                        format!("tile decoded to {n} bytes, expected {}", out.len()),
                    )),
                    Err(source) => Err(Error::Decompress {
                        at: self.tile_at(chunk),
                        source,
                    }),
                }
            });
            problems.extend(result.err());
        }
        problems
    }
}

/// A chunk's bytes as a layer file stores them ([`Layer::stored_chunk`]).
#[derive(Debug, Clone, Copy)]
pub struct StoredChunk<'a> {
    pub codec: Codec,
    /// Bytes once decoded (the tile's).
    pub raw_len: u32,
    /// Checksum of `bytes`, already verified.
    pub xxh3: u64,
    pub bytes: &'a [u8],
}

impl StoredChunk<'_> {
    /// Decodes the chunk into `out` ([`Codec::decode_into`]).
    pub fn decode_into(&self, elem_size: usize, out: &mut [u8]) -> std::io::Result<usize> {
        self.codec.decode_into(self.bytes, elem_size, out)
    }
}

fn chunk_tile(chunk: u64, tiles_x: u32, tiles_y: u32) -> (u32, u32, u32) {
    let per_band = u64::from(tiles_x) * u64::from(tiles_y);
    let band = chunk / per_band;
    let rest = chunk % per_band;
    (
        band as u32,
        (rest % u64::from(tiles_x)) as u32,
        (rest / u64::from(tiles_x)) as u32,
    )
}

/// An opened asset: its manifest and every layer it names. `Send + Sync`.
pub struct Asset<D> {
    dir: PathBuf,
    manifest: Manifest,
    layers: Vec<Layer<D>>,
}

impl<D> std::fmt::Debug for Asset<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Asset")
            .field("dir", &self.dir)
            .field("layers", &self.layers.len())
            .finish()
    }
}

/// What [`Asset::verify`] found.
#[derive(Debug)]
pub struct VerifyReport {
    pub layers: usize,
    pub chunks: u64,
    pub problems: Vec<Error>,
}

impl Asset<Mmap> {
    /// Maps the asset directory `dir` read-only and validates it.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        Self::open_with_cache(dir, DEFAULT_CACHE_BYTES)
    }

    /// As [`Asset::open`], with the decompressed-tile cache bounded to `cache_bytes`.
    ///
    /// A writer may commit while this runs. Files the previous manifest named
    /// are kept for a grace period after the commit (see
    /// [`crate::writer`]), and when a layer cannot be opened although the
    /// manifest has changed since it was read, the open starts again with
    /// the new manifest (up to [`OPEN_ATTEMPTS`] times): a reader sees one
    /// whole generation of the asset or the other, never an error of the race.
    pub fn open_with_cache(dir: impl AsRef<Path>, cache_bytes: u64) -> Result<Self> {
        let dir = dir.as_ref();
        let manifest_path = dir.join(MANIFEST_FILE);
        let mut attempt = 1;
        loop {
            let manifest_bytes = read_file(&manifest_path)?;
            let manifest = parse_manifest(&manifest_path, &manifest_bytes)?;
            match Self::map_layers(dir, manifest, cache_bytes) {
                Ok(asset) => return Ok(asset),
                Err(e) if attempt < OPEN_ATTEMPTS => {
                    // Only a commit in between excuses a failure: retry then.
                    if read_file(&manifest_path).ok().as_deref() == Some(&manifest_bytes[..]) {
                        return Err(e);
                    }
                    attempt += 1;
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// The asset as `manifest` describes it before it is committed: the
    /// view a writer gives the next stage of one run, whose layers are
    /// renamed into place but which readers do not see yet. Validated as a
    /// committed manifest is.
    pub fn open_uncommitted(dir: impl AsRef<Path>, manifest: Manifest) -> Result<Self> {
        let dir = dir.as_ref();
        manifest
            .validate()
            .map_err(|what| Error::malformed(Location::file(dir.join(MANIFEST_FILE)), what))?;
        Self::map_layers(dir, manifest, DEFAULT_CACHE_BYTES)
    }

    /// Maps the layers of `manifest`, which [`parse_manifest`] has
    /// validated: every name was checked before the first file is opened.
    fn map_layers(dir: &Path, manifest: Manifest, cache_bytes: u64) -> Result<Self> {
        let mut files = HashMap::new();
        for layer in &manifest.layers {
            files.insert(layer.file.clone(), map_file(&dir.join(&layer.file))?);
        }
        Self::assemble(dir.to_path_buf(), manifest, files, cache_bytes)
    }
}

/// How many times [`Asset::open`] starts again when commits race it.
pub const OPEN_ATTEMPTS: u32 = 16;

/// The manifest committed in `dir`, parsed but not validated (a writer
/// learning which files an older manifest named); `None` when there is no
/// manifest yet.
pub(crate) fn committed_manifest(dir: &Path) -> Result<Option<Manifest>> {
    let path = dir.join(MANIFEST_FILE);
    match read_file(&path) {
        Err(Error::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e),
        Ok(bytes) => parse_manifest_unchecked(&path, &bytes).map(Some),
    }
}

/// The manifest file's bytes (small: read, not mapped, so that a writer's
/// rename can never change them under us).
fn read_file(path: &Path) -> Result<Vec<u8>> {
    crate::fsio::read_regular(path, u64::MAX)
}

fn map_file(path: &Path) -> Result<Mmap> {
    let file = crate::fsio::open_regular(path)?;
    // SAFETY: terrabake never modifies a file in place: writers create new
    // files and rename them over old names, so a mapping never changes under
    // the reader. Another program truncating the file would break that; we
    // document it and accept it, as every mmap-based reader does.
    unsafe { Mmap::map(&file) }.map_err(|source| Error::Io {
        at: Location::file(path),
        source,
    })
}

/// Parses the manifest file's bytes (header, checksum, JSON) and checks
/// every field readers rely on ([`Manifest::validate`]).
pub fn parse_manifest(path: &Path, bytes: &[u8]) -> Result<Manifest> {
    let manifest = parse_manifest_unchecked(path, bytes)?;
    manifest
        .validate()
        .map_err(|what| Error::malformed(Location::file(path), what))?;
    Ok(manifest)
}

/// [`parse_manifest`] without [`Manifest::validate`]: what a writer needs
/// to learn which files an older manifest named.
fn parse_manifest_unchecked(path: &Path, bytes: &[u8]) -> Result<Manifest> {
    let at = || Location::file(path);
    if bytes.len() < MANIFEST_HEADER_LEN {
        return Err(Error::malformed(
            at(),
            format!("{} bytes is shorter than the manifest header", bytes.len()),
        ));
    }
    let header = ManifestHeader::read_from_bytes(&bytes[..MANIFEST_HEADER_LEN]).expect("sized");
    if header.magic != MANIFEST_MAGIC {
        return Err(Error::Magic {
            at: at(),
            expected: MANIFEST_MAGIC,
            got: header.magic,
        });
    }
    if header.version.get() != FORMAT_VERSION {
        return Err(Error::Version {
            at: at(),
            expected: FORMAT_VERSION,
            got: header.version.get(),
        });
    }
    if header.reserved.get() != 0 {
        return Err(Error::malformed(at(), "reserved header bytes are not zero"));
    }
    let json = &bytes[MANIFEST_HEADER_LEN..];
    if json.len() as u64 != header.json_len.get() {
        return Err(Error::malformed(
            at(),
            format!(
                "manifest JSON is {} bytes, header says {}",
                json.len(),
                header.json_len.get()
            ),
        ));
    }
    let got = xxh3(json);
    if got != header.json_xxh3.get() {
        return Err(Error::Checksum {
            at: at(),
            what: "manifest",
            expected: header.json_xxh3.get(),
            got,
        });
    }
    let manifest: Manifest =
        serde_json::from_slice(json).map_err(|source| Error::Manifest { at: at(), source })?;
    if manifest.format_version != FORMAT_VERSION {
        return Err(Error::Version {
            at: at(),
            expected: FORMAT_VERSION,
            got: manifest.format_version,
        });
    }
    Ok(manifest)
}

impl<D: AsRef<[u8]>> Asset<D> {
    /// Builds an asset from bytes in memory: `files` maps file names (as the
    /// manifest names them, plus [`MANIFEST_FILE`]) to their bytes. `dir` only
    /// labels errors.
    pub fn from_files(dir: impl Into<PathBuf>, mut files: HashMap<String, D>) -> Result<Self> {
        let dir = dir.into();
        let manifest_path = dir.join(MANIFEST_FILE);
        let manifest_bytes = files.remove(MANIFEST_FILE).ok_or_else(|| Error::Io {
            at: Location::file(&manifest_path),
            source: std::io::ErrorKind::NotFound.into(),
        })?;
        let manifest = parse_manifest(&manifest_path, manifest_bytes.as_ref())?;
        Self::assemble(dir, manifest, files, DEFAULT_CACHE_BYTES)
    }

    fn assemble(
        dir: PathBuf,
        manifest: Manifest,
        mut files: HashMap<String, D>,
        cache_bytes: u64,
    ) -> Result<Self> {
        let cache = Arc::new(TileCache::with_weighter(
            (cache_bytes / (256 * 1024)).max(16) as usize,
            cache_bytes,
            ByteWeighter,
        ));
        let mut layers = Vec::with_capacity(manifest.layers.len());
        for (id, entry) in manifest.layers.iter().enumerate() {
            let path = dir.join(&entry.file);
            let bytes = files.remove(&entry.file).ok_or_else(|| Error::Io {
                at: Location::layer(&path, entry.key()),
                source: std::io::ErrorKind::NotFound.into(),
            })?;
            layers.push(Layer::open(
                id as u32,
                entry.clone(),
                path,
                bytes,
                cache.clone(),
            )?);
        }
        Ok(Self {
            dir,
            manifest,
            layers,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }
    pub fn layers(&self) -> &[Layer<D>] {
        &self.layers
    }

    pub fn layer(&self, name: &str, level: u32) -> Result<&Layer<D>> {
        self.layers
            .iter()
            .find(|l| l.entry.name == name && l.entry.level == level)
            .ok_or_else(|| Error::NoLayer {
                asset: self.dir.clone(),
                name: name.to_string(),
                level,
                available: self.layers.iter().map(|l| l.entry.key()).collect(),
            })
    }

    /// The height layer (f32, metres, NaN for nodata).
    pub fn height(&self) -> Result<&Layer<D>> {
        self.layer(HEIGHT_LAYER, 0)
    }

    /// Bilinear height at CRS coordinates `(x, y)` (the asset's georeferencing);
    /// `None` outside the DEM, over nodata, or when the asset has no georeferencing.
    pub fn height_at_world(&self, x: f64, y: f64) -> Result<Option<f32>> {
        match self
            .manifest
            .georef
            .as_ref()
            .and_then(|g| g.world_to_post(x, y))
        {
            Some((gx, gy)) => self.height()?.bilinear(gx, gy),
            None => Ok(None),
        }
    }

    /// Checksums every tile of every layer, and checks the manifest's
    /// statements about the heights (nodata count, height range) against
    /// the heights themselves. (Everything else the manifest states was
    /// checked when the asset was opened.)
    pub fn verify(&self) -> VerifyReport {
        let mut report = VerifyReport {
            layers: self.layers.len(),
            chunks: 0,
            problems: Vec::new(),
        };
        for layer in &self.layers {
            report.chunks += layer.entry.chunks;
            report.problems.extend(layer.verify());
        }
        if report.problems.is_empty() {
            report.problems.extend(self.verify_heights().err());
        }
        report
    }

    /// The manifest's nodata count and height range against the heights.
    fn verify_heights(&self) -> Result<()> {
        let height = self.height()?;
        let (w, h, ts) = (height.width(), height.height(), height.tile_size());
        let (mut nodata, mut min, mut max) = (0u64, f32::INFINITY, f32::NEG_INFINITY);
        for ty in 0..height.tiles_y() {
            for tx in 0..height.tiles_x() {
                let tile = height.tile::<f32>(0, tx, ty)?;
                let cols = (ts.min(w - tx * ts)) as usize;
                for row in tile
                    .chunks_exact(ts as usize)
                    .take(ts.min(h - ty * ts) as usize)
                {
                    for &z in &row[..cols] {
                        if z.is_nan() {
                            nodata += 1;
                        } else {
                            min = min.min(z);
                            max = max.max(z);
                        }
                    }
                }
            }
        }
        let m = &self.manifest;
        let at = || Location::file(self.dir.join(MANIFEST_FILE));
        if nodata != m.nodata.count {
            return Err(Error::malformed(
                at(),
                format!(
                    "nodata.count is {}, the height layer has {nodata} nodata posts",
                    m.nodata.count
                ),
            ));
        }
        let range = m.height_range.map(|r| (r.min, r.max));
        let actual = (min <= max).then_some((min, max));
        if range != actual {
            return Err(Error::malformed(
                at(),
                format!("height_range is {range:?}, the heights span {actual:?}"),
            ));
        }
        Ok(())
    }
}

// Many render threads read one asset: these must stay Send + Sync.
const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    send_sync::<Asset<Mmap>>();
    send_sync::<Asset<Vec<u8>>>();
    send_sync::<Tile<'static, f32>>();
};

/// A layer file's header and footer, each checked: magic, version,
/// checksum, the footer belonging to the header, reserved bytes zero.
fn header_and_footer(at: &Location, data: &[u8]) -> Result<(LayerHeader, LayerFooter)> {
    let bad = |what: String| Err(Error::malformed(at.clone(), what));
    if data.len() < HEADER_LEN + FOOTER_LEN {
        return bad(format!(
            "{} bytes is shorter than header and footer",
            data.len()
        ));
    }
    let header = LayerHeader::read_from_bytes(&data[..HEADER_LEN]).expect("sized");
    if header.magic != LAYER_MAGIC {
        return Err(Error::Magic {
            at: at.clone(),
            expected: LAYER_MAGIC,
            got: header.magic,
        });
    }
    if header.version.get() != FORMAT_VERSION {
        return Err(Error::Version {
            at: at.clone(),
            expected: FORMAT_VERSION,
            got: header.version.get(),
        });
    }
    let computed = header.compute_xxh3();
    if computed != header.header_xxh3.get() {
        return Err(Error::Checksum {
            at: at.clone(),
            what: "layer header",
            expected: header.header_xxh3.get(),
            got: computed,
        });
    }
    let footer = LayerFooter::read_from_bytes(&data[data.len() - FOOTER_LEN..]).expect("sized");
    if footer.magic != FOOTER_MAGIC {
        return bad("footer magic missing (file truncated or overwritten)".into());
    }
    if footer.version.get() != FORMAT_VERSION {
        return Err(Error::Version {
            at: at.clone(),
            expected: FORMAT_VERSION,
            got: footer.version.get(),
        });
    }
    if footer.header_xxh3 != header.header_xxh3 {
        return bad("footer does not belong to this header".into());
    }
    if header.reserved0.get() != 0 || header.reserved1.get() != 0 || footer.reserved != [0; 20] {
        return bad("reserved header or footer bytes are not zero".into());
    }
    Ok((header, footer))
}

/// The file's length and the header's grid against the manifest's entry;
/// the tile grid's size.
fn check_grid(
    at: &Location,
    data_len: usize,
    header: &LayerHeader,
    entry: &LayerEntry,
) -> Result<[u32; 2]> {
    let bad = |what: String| Err(Error::malformed(at.clone(), what));
    if data_len as u64 != entry.file_len {
        return bad(format!(
            "file is {} bytes, manifest says {}",
            data_len, entry.file_len
        ));
    }
    let elem = ElemType::from_code(header.elem_type.get());
    let (w, h, ts, bands) = (
        header.width.get(),
        header.height.get(),
        header.tile_size.get(),
        header.bands.get(),
    );
    if elem != Some(entry.elem)
        || w != entry.width
        || h != entry.height
        || ts != entry.tile_size
        || bands != entry.bands
        || header.level.get() != entry.level
    {
        return bad("header disagrees with the manifest's layer entry".into());
    }
    if !ts.is_power_of_two() || w == 0 || h == 0 || bands == 0 {
        return bad(format!("invalid grid {w} x {h} x {bands}, tile {ts}"));
    }
    let (tx, ty) = (header.tiles_x.get(), header.tiles_y.get());
    if tx != tiles_for(w, ts) || ty != tiles_for(h, ts) {
        return bad(format!(
            "tile grid {tx} x {ty} does not cover {w} x {h} with {ts}"
        ));
    }
    Ok([tx, ty])
}

/// Where the chunk index of `chunks` entries starts, checked to fill the
/// file up to the footer and to match its checksums (the footer's and the
/// manifest's).
fn check_index(
    at: &Location,
    data: &[u8],
    footer: &LayerFooter,
    chunks: u64,
    entry: &LayerEntry,
) -> Result<usize> {
    let bad = |what: String| Err(Error::malformed(at.clone(), what));
    let index_offset = footer.index_offset.get();
    let index_end = data.len() as u64 - FOOTER_LEN as u64;
    if footer.chunk_count.get() != chunks
        || index_offset < HEADER_LEN as u64
        || index_offset.checked_add(chunks * ENTRY_LEN as u64) != Some(index_end)
    {
        return bad(format!(
            "chunk index ({} chunks at {index_offset}) does not fit the file",
            footer.chunk_count.get()
        ));
    }
    let index_bytes = &data[index_offset as usize..index_end as usize];
    let index_xxh3 = xxh3(index_bytes);
    if index_xxh3 != footer.index_xxh3.get() {
        return Err(Error::Checksum {
            at: at.clone(),
            what: "chunk index",
            expected: footer.index_xxh3.get(),
            got: index_xxh3,
        });
    }
    if format!("{index_xxh3:016x}") != entry.index_xxh3 {
        return bad(format!(
            "chunk index checksum {index_xxh3:016x} is not the manifest's {}",
            entry.index_xxh3
        ));
    }
    Ok(index_offset as usize)
}

/// Every chunk entry in bounds: a known codec, whole tiles, aligned,
/// before the index.
fn check_chunks(
    at: &Location,
    index: &[ChunkEntry],
    index_offset: u64,
    tile_bytes: u64,
    [tx, ty]: [u32; 2],
) -> Result<()> {
    for (i, c) in index.iter().enumerate() {
        let (off, len) = (c.offset.get(), c.stored_len.get());
        let codec = Codec::from_code(c.codec);
        let ok = codec.is_some()
            && c.reserved == [0; 3]
            && u64::from(c.raw_len.get()) == tile_bytes
            && off >= HEADER_LEN as u64
            && off % CHUNK_ALIGN == 0
            && off.checked_add(len).is_some_and(|end| end <= index_offset)
            && match codec {
                Some(Codec::Raw) => len == tile_bytes,
                _ => len > 0,
            };
        if !ok {
            let tile = chunk_tile(i as u64, tx, ty);
            return Err(Error::malformed(
                at.clone().with_tile(tile),
                format!(
                    "chunk entry {i} is invalid (offset {off}, length {len}, codec {})",
                    c.codec
                ),
            ));
        }
    }
    Ok(())
}
