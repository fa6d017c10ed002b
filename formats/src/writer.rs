//! Writing layers and committing manifests, so that a crash at any point
//! leaves the asset as it was before or as it is after, never in between,
//! and a reader never sees anything but a whole asset.
//!
//! ```text
//!  WriteLock::acquire ──► reclaim garbage ──► LayerWriter × n ──► commit_manifest
//!  (writer.lock, flock)   (dead writers'      (unique .tmp,        (manifest.tba: the
//!                          .tmp and orphans)   fsync, rename to     commit point; old
//!                                              a fresh generation)  files retired)
//! ```
//!
//! - **One writer at a time.** A writer holds [`WriteLock`], an advisory
//!   lock (`flock`) on `writer.lock` inside the asset, for its whole run; the
//!   lock file records the holder's pid for the message a second writer
//!   gets. The kernel drops the lock when the holder dies, however it dies,
//!   so a crashed writer never blocks the next one.
//! - **Layers** are written to a uniquely named temporary file
//!   ([`crate::fsio::create_temp`]), fsynced, and renamed to a name that no
//!   earlier version used (it carries a generation number). Every
//!   `WRITEBACK_STEP` bytes the writer asks the kernel to start writing
//!   what it has written so far ([`crate::fsio::start_writeback`]): the
//!   final fsync then waits for the last stretch, not for the whole file
//!   (12 ms to 1.5 ms for the line stage's 23 MB layer). Durability rests
//!   on that fsync alone.
//! - **The commit** ([`commit_manifest`]) writes the manifest the same way;
//!   its rename is the commit point. Files the previous manifest named and
//!   this one does not are *retired*: listed in the manifest with the time,
//!   and kept for [`WriteLock::grace`] (60 s by default) so that a reader
//!   that read the previous manifest a moment ago still finds them. A reader
//!   needs them only between reading the manifest and mapping the layers
//!   (a mapped file stays readable after it is unlinked), and
//!   [`crate::Asset::open`] also retries when a layer is gone and the
//!   manifest has changed, so a renderer that opens an asset during any
//!   number of commits never fails.
//! - **Garbage** ([`WriteLock::reclaim`]): under the lock, every temporary
//!   file is a dead writer's, and every layer file that the manifest neither
//!   names nor keeps as retired is an orphan of a writer that died between
//!   its layer renames and its commit, or of a stage that failed. The next
//!   writer removes both when it takes the lock, and a writer whose stage
//!   fails removes its own before it lets go.

use std::collections::{HashMap, HashSet};
use std::fs::{self, File, OpenOptions};
use std::io::{BufWriter, Read, Seek, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use zerocopy::IntoBytes;

use crate::error::{Error, Location, Result};
use crate::fsio::{crash_point, create_temp, start_writeback, sync_dir};
use crate::layout::{
    self as layout, align_up, tiles_for, xxh3, ChunkEntry, Codec, ElemType, LayerFooter,
    LayerHeader, ManifestHeader, FOOTER_MAGIC, FORMAT_VERSION, HEADER_LEN, LAYER_MAGIC,
    MANIFEST_FILE, MANIFEST_MAGIC,
};
use crate::manifest::{LayerEntry, Manifest, Retired};
use crate::reader::StoredChunk;

/// Bytes a layer file is written between two hand-overs to the disk's
/// writeback ([`start_writeback`]): the pages stream out while the stage
/// runs, and its final fsync waits for at most this much.
const WRITEBACK_STEP: u64 = 8 << 20;

/// What a layer holds; the writer derives the tiling from it.
#[derive(Debug, Clone)]
pub struct LayerSpec {
    pub name: String,
    pub level: u32,
    pub elem: ElemType,
    pub bands: u32,
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    pub codec: Codec,
    /// Bits of the padding value past the grid's edge (NaN's bits for f32).
    pub fill_bits: u64,
    pub stage: String,
    pub description: String,
}

impl LayerSpec {
    pub fn tiles_x(&self) -> u32 {
        tiles_for(self.width, self.tile_size)
    }
    pub fn tiles_y(&self) -> u32 {
        tiles_for(self.height, self.tile_size)
    }
    pub fn chunk_count(&self) -> u64 {
        u64::from(self.bands) * u64::from(self.tiles_x()) * u64::from(self.tiles_y())
    }
    pub fn tile_bytes(&self) -> usize {
        self.tile_size as usize * self.tile_size as usize * self.elem.size()
    }
    fn validate(&self) -> Result<()> {
        let bad = |what: String| Err(Error::Spec(format!("layer {}: {what}", self.name)));
        if !self.tile_size.is_power_of_two() || !(16..=4096).contains(&self.tile_size) {
            return bad(format!(
                "tile size {} is not a power of two in 16..=4096",
                self.tile_size
            ));
        }
        if self.width == 0 || self.height == 0 || self.bands == 0 {
            return bad(format!(
                "empty grid {} x {} x {} bands",
                self.width, self.height, self.bands
            ));
        }
        if self.name.is_empty()
            || !self
                .name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
        {
            return bad("names use only letters, digits, '_' and '-'".into());
        }
        Ok(())
    }
}

/// A tile ready to append: checksummed and possibly compressed. Made by
/// [`encode_tile`], which is pure, so callers can encode tiles in parallel.
#[derive(Debug, Clone)]
pub struct EncodedTile {
    pub codec: Codec,
    pub bytes: Vec<u8>,
    pub raw_len: u32,
    pub xxh3: u64,
    /// `Some(bits)` when every element has these bits: stored once per value.
    pub constant: Option<u64>,
}

/// The zstd level tiles are written with: zstd's default, fast to write
/// and to read.
pub const ZSTD_LEVEL: i32 = 3;

/// Encodes one tile's bytes (`tile_size²` elements of `elem_size` bytes).
/// Asked for zstd, it keeps the smaller of plain and, for elements wider
/// than a byte, shuffled zstd ([`Codec::ShuffledZstd`]: heights and sky
/// layers compress further shuffled, cone slopes of few distinct values
/// less), and stores the tile raw when neither is smaller.
pub fn encode_tile(raw: &[u8], elem_size: usize, codec: Codec, zstd_level: i32) -> EncodedTile {
    let constant = constant_bits(raw, elem_size);
    let compress = |codec: Codec, bytes: &[u8]| {
        zstd::bulk::compress(bytes, zstd_level)
            .ok()
            .map(|c| (codec, c))
    };
    let smallest = match codec {
        Codec::Raw => None,
        Codec::Zstd | Codec::ShuffledZstd => {
            let plain = compress(Codec::Zstd, raw);
            let shuffled = (elem_size > 1)
                .then(|| compress(Codec::ShuffledZstd, &layout::shuffle(raw, elem_size)))
                .flatten();
            [plain, shuffled]
                .into_iter()
                .flatten()
                .min_by_key(|(_, c)| c.len())
        }
    };
    let (codec, bytes) = match smallest.filter(|(_, c)| c.len() < raw.len()) {
        Some(chosen) => chosen,
        None => (Codec::Raw, raw.to_vec()),
    };
    EncodedTile {
        codec,
        xxh3: xxh3(&bytes),
        bytes,
        raw_len: raw.len() as u32,
        constant,
    }
}

fn constant_bits(raw: &[u8], elem_size: usize) -> Option<u64> {
    let first = raw.get(..elem_size)?;
    raw.chunks_exact(elem_size).all(|e| e == first).then(|| {
        let mut bits = [0u8; 8];
        bits[..elem_size].copy_from_slice(first);
        u64::from_le_bytes(bits)
    })
}

/// Appends tiles to a new layer file; [`LayerWriter::finish`] makes it durable.
/// Dropping an unfinished writer removes its temporary file.
#[derive(Debug)]
pub struct LayerWriter {
    spec: LayerSpec,
    dir: PathBuf,
    file_name: String,
    tmp_path: PathBuf,
    out: Option<BufWriter<File>>,
    pos: u64,
    /// Bytes before this offset were handed to the disk's writeback
    /// ([`WRITEBACK_STEP`]).
    written_back: u64,
    /// Per chunk, its entry once pushed (chunks may come in any order).
    index: Vec<Option<ChunkEntry>>,
    /// Chunks pushed so far.
    pushed: u64,
    /// (constant bits, codec) -> the entry that already stores it.
    constants: HashMap<u64, ChunkEntry>,
    constant_chunks: u64,
    stored_bytes: u64,
    header: LayerHeader,
}

impl LayerWriter {
    /// Starts `spec` in the asset directory `dir` (which must exist).
    pub fn create(dir: &Path, spec: LayerSpec) -> Result<Self> {
        spec.validate()?;
        let file_name = fresh_layer_file_name(dir, &spec.name, spec.level);
        let final_path = dir.join(&file_name);
        let (file, tmp_path) = create_temp(&final_path).map_err(|source| Error::Io {
            at: Location::layer(&final_path, format!("{}@{}", spec.name, spec.level)),
            source,
        })?;
        let io_err = |source| Error::Io {
            at: Location::layer(&final_path, format!("{}@{}", spec.name, spec.level)),
            source,
        };
        let mut header = LayerHeader {
            magic: LAYER_MAGIC,
            version: FORMAT_VERSION.into(),
            elem_type: (spec.elem as u16).into(),
            reserved0: 0.into(),
            width: spec.width.into(),
            height: spec.height.into(),
            tile_size: spec.tile_size.into(),
            bands: spec.bands.into(),
            level: spec.level.into(),
            tiles_x: spec.tiles_x().into(),
            tiles_y: spec.tiles_y().into(),
            reserved1: 0.into(),
            fill_bits: spec.fill_bits.into(),
            header_xxh3: 0.into(),
        };
        header.header_xxh3 = header.compute_xxh3().into();
        let mut out = BufWriter::with_capacity(1 << 20, file);
        out.write_all(header.as_bytes()).map_err(io_err)?;
        Ok(Self {
            dir: dir.to_path_buf(),
            file_name,
            out: Some(out),
            pos: HEADER_LEN as u64,
            written_back: 0,
            index: vec![None; spec.chunk_count() as usize],
            pushed: 0,
            constants: HashMap::new(),
            constant_chunks: 0,
            stored_bytes: 0,
            header,
            tmp_path,
            spec,
        })
    }

    pub fn spec(&self) -> &LayerSpec {
        &self.spec
    }

    /// Chunks pushed so far; [`Self::push`] gives the next one this index.
    pub fn chunks_written(&self) -> u64 {
        self.pushed
    }

    /// Where errors say the layer is: the file it is being written as (its
    /// temporary's name means nothing to a user).
    fn at(&self) -> Location {
        Location::layer(
            self.dir.join(&self.file_name),
            format!("{}@{}", self.spec.name, self.spec.level),
        )
    }

    /// Appends the next chunk in index order (band, tile row, tile column).
    pub fn push(&mut self, tile: EncodedTile) -> Result<()> {
        self.push_at(self.pushed, tile)
    }

    /// Writes chunk number `chunk` (`(band * tiles_y + ty) * tiles_x + tx`),
    /// in any order: a stage that produces a band's tile rows bottom-up, or
    /// several bands at once, still writes as it goes. Each chunk once.
    pub fn push_at(&mut self, chunk: u64, tile: EncodedTile) -> Result<()> {
        let stored = StoredChunk {
            codec: tile.codec,
            raw_len: tile.raw_len,
            xxh3: tile.xxh3,
            bytes: &tile.bytes,
        };
        self.write_chunk(chunk, stored, tile.constant)
    }

    /// Writes chunk `chunk` as another file of the same layer stored it (a
    /// part of a partitioned bake), without decoding it: the bytes are
    /// copied once. A constant tile is still stored once per value: raw
    /// tiles are scanned, and compressed frames short enough to be one (a
    /// compressed tile of any size that repeats one value is a few dozen
    /// bytes) are decoded to check.
    pub fn adopt_at(&mut self, chunk: u64, stored: StoredChunk<'_>) -> Result<()> {
        let elem = self.spec.elem.size();
        let constant = match stored.codec {
            Codec::Raw => constant_bits(stored.bytes, elem),
            _ if stored.bytes.len() <= 256 => {
                let mut raw = vec![0u8; stored.raw_len as usize];
                stored
                    .decode_into(elem, &mut raw)
                    .ok()
                    .filter(|&n| n == raw.len())
                    .and_then(|_| constant_bits(&raw, elem))
            }
            _ => None,
        };
        self.write_chunk(chunk, stored, constant)
    }

    /// Writes chunk `chunk` as a tile of the layer's fill value (what a part
    /// of a partitioned bake writes where another part computes).
    pub fn push_fill_at(&mut self, chunk: u64) -> Result<()> {
        let bits = self.spec.fill_bits;
        if self.constants.contains_key(&bits) {
            let stored = StoredChunk {
                codec: Codec::Raw,
                raw_len: self.spec.tile_bytes() as u32,
                xxh3: 0,
                bytes: &[],
            };
            return self.write_chunk(chunk, stored, Some(bits));
        }
        let elem = self.spec.elem.size();
        let raw: Vec<u8> =
            std::iter::repeat_n(&bits.to_le_bytes()[..elem], self.spec.tile_bytes() / elem)
                .flatten()
                .copied()
                .collect();
        let tile = encode_tile(&raw, elem, self.spec.codec, ZSTD_LEVEL);
        self.push_at(chunk, tile)
    }

    fn write_chunk(
        &mut self,
        chunk: u64,
        tile: StoredChunk<'_>,
        constant: Option<u64>,
    ) -> Result<()> {
        if chunk >= self.spec.chunk_count() || self.index[chunk as usize].is_some() {
            return Err(Error::Spec(format!(
                "layer {}: chunk {chunk} pushed twice or past its {} chunks",
                self.spec.name,
                self.spec.chunk_count()
            )));
        }
        if tile.raw_len as usize != self.spec.tile_bytes() {
            return Err(Error::Spec(format!(
                "layer {}: tile of {} bytes, expected {}",
                self.spec.name,
                tile.raw_len,
                self.spec.tile_bytes()
            )));
        }
        self.pushed += 1;
        if let Some(entry) = constant.and_then(|bits| self.constants.get(&bits)) {
            self.index[chunk as usize] = Some(*entry);
            self.constant_chunks += 1;
            return Ok(());
        }
        crash_point();
        let offset = align_up(self.pos);
        let pad = (offset - self.pos) as usize;
        let out = self.out.as_mut().expect("writer used after finish");
        let result = out
            .write_all(&[0u8; 64][..pad])
            .and_then(|()| out.write_all(tile.bytes));
        result.map_err(|source| Error::Io {
            at: self.at(),
            source,
        })?;
        let entry = ChunkEntry {
            offset: offset.into(),
            stored_len: (tile.bytes.len() as u64).into(),
            raw_len: tile.raw_len.into(),
            codec: tile.codec as u8,
            reserved: [0; 3],
            xxh3: tile.xxh3.into(),
        };
        self.pos = offset + tile.bytes.len() as u64;
        self.stored_bytes += tile.bytes.len() as u64;
        if let Some(bits) = constant {
            self.constants.insert(bits, entry);
            self.constant_chunks += 1;
        }
        self.index[chunk as usize] = Some(entry);
        if self.pos - self.written_back >= WRITEBACK_STEP {
            let (from, len) = (self.written_back, self.pos - self.written_back);
            let out = self.out.as_mut().expect("writer used after finish");
            let flushed = out
                .flush()
                .map(|()| start_writeback(out.get_ref(), from, len));
            flushed.map_err(|source| Error::Io {
                at: self.at(),
                source,
            })?;
            self.written_back = self.pos;
        }
        Ok(())
    }

    /// Writes the index and footer, fsyncs and renames the file into place.
    /// The returned entry is not yet visible: commit it with a manifest.
    pub fn finish(mut self) -> Result<LayerEntry> {
        if self.pushed != self.spec.chunk_count() {
            return Err(Error::Spec(format!(
                "layer {}: {} of {} chunks pushed",
                self.spec.name,
                self.pushed,
                self.spec.chunk_count()
            )));
        }
        let index: Vec<ChunkEntry> = self
            .index
            .iter()
            .map(|e| e.expect("every chunk pushed"))
            .collect();
        let index_offset = align_up(self.pos);
        let index_bytes = index.as_bytes();
        let index_xxh3 = xxh3(index_bytes);
        let footer = LayerFooter {
            index_offset: index_offset.into(),
            chunk_count: (index.len() as u64).into(),
            index_xxh3: index_xxh3.into(),
            header_xxh3: self.header.header_xxh3,
            version: FORMAT_VERSION.into(),
            reserved: [0; 20],
            magic: FOOTER_MAGIC,
        };
        let at = self.at();
        let mut out = self.out.take().expect("writer used after finish");
        let pad = (index_offset - self.pos) as usize;
        let write = || -> std::io::Result<File> {
            out.write_all(&[0u8; 64][..pad])?;
            out.write_all(index_bytes)?;
            out.write_all(footer.as_bytes())?;
            let file = out.into_inner().map_err(|e| e.into_error())?;
            crash_point();
            file.sync_all()?;
            Ok(file)
        };
        let file = write().map_err(|source| Error::Io {
            at: at.clone(),
            source,
        })?;
        let file_len = file.metadata().map(|m| m.len()).unwrap_or(0);
        drop(file);
        let final_path = self.dir.join(&self.file_name);
        crash_point();
        fs::rename(&self.tmp_path, &final_path).map_err(|source| Error::Io { at, source })?;
        Ok(LayerEntry {
            name: self.spec.name.clone(),
            level: self.spec.level,
            elem: self.spec.elem,
            bands: self.spec.bands,
            width: self.spec.width,
            height: self.spec.height,
            tile_size: self.spec.tile_size,
            codec: self.spec.codec,
            file: self.file_name.clone(),
            file_len,
            index_xxh3: format!("{index_xxh3:016x}"),
            chunks: self.index.len() as u64,
            constant_chunks: self.constant_chunks,
            stored_bytes: self.stored_bytes,
            stage: self.spec.stage.clone(),
            description: self.spec.description.clone(),
            quantization: None,
            band_azimuths: Vec::new(),
            features: None,
        })
    }
}

impl Drop for LayerWriter {
    fn drop(&mut self) {
        if self.out.is_some() {
            // Unfinished: the temporary file is garbage.
            self.out = None;
            let _ = fs::remove_file(&self.tmp_path);
        }
    }
}

/// `name.L<level>.g<generation>.tbl`, with a generation no file in `dir` has.
fn fresh_layer_file_name(dir: &Path, name: &str, level: u32) -> String {
    let prefix = format!("{name}.L{level}.g");
    let highest = fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let file = e.file_name().into_string().ok()?;
            let rest = file.strip_prefix(&prefix)?;
            rest.split('.').next()?.parse::<u64>().ok()
        })
        .max();
    format!("{prefix}{}.tbl", highest.map_or(0, |g| g + 1))
}

/// File name of the writer lock inside an asset directory.
pub const LOCK_FILE: &str = "writer.lock";

/// How long a retired layer file is kept after the commit that retired it.
pub const DEFAULT_RETIRE_GRACE: Duration = Duration::from_secs(60);

/// The asset's writer lock: while one is held, no other process writes the
/// asset. Dropping it (or the holder dying) releases it.
#[derive(Debug)]
pub struct WriteLock {
    dir: PathBuf,
    /// The lock belongs to this open file: it lasts as long as the file is open.
    _file: File,
    grace: Duration,
}

impl WriteLock {
    /// Takes the lock of the asset directory `dir` (which must exist). With
    /// `wait`, blocks until the holder lets go, calling `on_wait(pid)` first
    /// with the holder's pid; without, fails at once with [`Error::Locked`].
    pub fn acquire(dir: &Path, wait: bool, on_wait: impl FnOnce(Option<u32>)) -> Result<Self> {
        let path = dir.join(LOCK_FILE);
        let io = |source| Error::Io {
            at: Location::file(&path),
            source,
        };
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .mode(0o644)
            .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
            .open(&path)
            .map_err(io)?;
        if !file.metadata().map_err(io)?.file_type().is_file() {
            return Err(Error::malformed(
                Location::file(&path),
                "is not a regular file",
            ));
        }
        match file.try_lock() {
            Ok(()) => {}
            Err(fs::TryLockError::WouldBlock) => {
                let pid = holder_pid(&mut file);
                if !wait {
                    return Err(Error::Locked {
                        dir: dir.to_path_buf(),
                        pid,
                    });
                }
                on_wait(pid);
                file.lock().map_err(io)?;
            }
            Err(fs::TryLockError::Error(e)) => return Err(io(e)),
        }
        // Ours now: say who holds it, for the next writer's message.
        // One fixed-width record written in place: a writer waiting on the
        // lock reads the old holder's pid or ours, never an empty file.
        let record = || -> std::io::Result<()> {
            use std::os::unix::fs::FileExt;
            let line = format!("{:<10}\n", std::process::id());
            file.write_all_at(line.as_bytes(), 0)?;
            file.set_len(line.len() as u64)
        };
        record().map_err(io)?;
        Ok(Self {
            dir: dir.to_path_buf(),
            _file: file,
            grace: DEFAULT_RETIRE_GRACE,
        })
    }

    /// The same lock with another grace period for retired files (tests).
    pub fn with_grace(mut self, grace: Duration) -> Self {
        self.grace = grace;
        self
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// How long a layer file stays after the commit that retired it.
    pub fn grace(&self) -> Duration {
        self.grace
    }

    /// [`Self::reclaim`] against the committed manifest: everything unnamed
    /// goes when there is no manifest yet (a first ingest that died); when
    /// the manifest exists but cannot be parsed, nothing is touched, since
    /// nothing can then tell garbage from the asset.
    pub fn reclaim_garbage(&self) -> Result<Vec<String>> {
        match crate::reader::committed_manifest(&self.dir) {
            Ok(manifest) => self.reclaim(manifest.as_ref()),
            Err(_) => Ok(Vec::new()),
        }
    }

    /// Removes what no writer will finish and no reader can be using:
    /// every temporary file, and every layer file that `manifest` (the
    /// committed one, `None` when there is none yet) neither names nor
    /// retired less than [`Self::grace`] ago. Returns the names removed.
    pub fn reclaim(&self, manifest: Option<&Manifest>) -> Result<Vec<String>> {
        let keep: HashSet<&str> = manifest
            .map(|m| {
                let now = unix_now();
                let layers = m.layers.iter().map(|l| l.file.as_str());
                let retired = m
                    .retired
                    .iter()
                    .filter(|r| in_grace(r, now, self.grace))
                    .map(|r| r.file.as_str());
                layers.chain(retired).collect()
            })
            .unwrap_or_default();
        let entries = fs::read_dir(&self.dir).map_err(|source| Error::Io {
            at: Location::file(&self.dir),
            source,
        })?;
        let mut removed = Vec::new();
        for entry in entries.flatten() {
            let Ok(name) = entry.file_name().into_string() else {
                continue;
            };
            // Only names this writer makes: a user's `lineitem.tbl` or
            // `notes.tmp` is never taken for garbage.
            let ours = crate::fsio::is_reclaimable_name(&name);
            // Never a directory, whatever its name (remove_file refuses one).
            let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
            if ours && !is_dir && !keep.contains(name.as_str()) {
                crash_point();
                match fs::remove_file(entry.path()) {
                    Ok(()) => removed.push(name),
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(source) => {
                        return Err(Error::Io {
                            at: Location::file(entry.path()),
                            source,
                        })
                    }
                }
            }
        }
        if !removed.is_empty() {
            sync_dir(&self.dir).map_err(|source| Error::Io {
                at: Location::file(&self.dir),
                source,
            })?;
        }
        removed.sort();
        Ok(removed)
    }
}

/// The pid written in a held lock file, if it is readable.
fn holder_pid(file: &mut File) -> Option<u32> {
    let mut text = String::new();
    file.rewind().ok()?;
    file.take(32).read_to_string(&mut text).ok()?;
    text.trim().parse().ok()
}

/// Whether a retired file is still within its grace at `now` (seconds).
fn in_grace(r: &Retired, now: u64, grace: Duration) -> bool {
    now < r.since_unix.saturating_add(grace.as_secs())
}

fn unix_now() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// Commits `manifest` atomically (temporary file, fsync, rename, fsync of
/// the directory: the commit point of every change to an asset), retires
/// the files the previous manifest named and this one does not, and
/// reclaims what is past its grace. Returns the manifest as committed (with
/// its `retired` list).
pub fn commit_manifest(lock: &WriteLock, manifest: &Manifest) -> Result<Manifest> {
    let dir = lock.dir();
    let path = dir.join(MANIFEST_FILE);
    let at = || Location::file(&path);
    // A writer never commits what a reader would refuse.
    manifest.validate().map_err(|what| {
        Error::Spec(format!(
            "{}: manifest not committed: {what}",
            path.display()
        ))
    })?;
    let mut manifest = manifest.clone();
    manifest.retired = retire(dir, &manifest, lock.grace);
    let json = serde_json::to_vec_pretty(&manifest)
        .map_err(|source| Error::Manifest { at: at(), source })?;
    let header = ManifestHeader {
        magic: MANIFEST_MAGIC,
        version: FORMAT_VERSION.into(),
        reserved: 0.into(),
        json_len: (json.len() as u64).into(),
        json_xxh3: xxh3(&json).into(),
    };
    let mut tmp = None;
    let mut write = || -> std::io::Result<()> {
        let (mut file, tmp_path) = create_temp(&path)?;
        tmp = Some(tmp_path.clone());
        crash_point();
        file.write_all(header.as_bytes())?;
        file.write_all(&json)?;
        crash_point();
        file.sync_all()?;
        drop(file);
        crash_point();
        fs::rename(&tmp_path, &path)?;
        tmp = None;
        // The rename itself must reach the disk before we report success.
        sync_dir(dir)
    };
    write().map_err(|source| {
        if let Some(tmp) = &tmp {
            let _ = fs::remove_file(tmp);
        }
        Error::Io { at: at(), source }
    })?;
    lock.reclaim(Some(&manifest))?;
    Ok(manifest)
}

/// The `retired` list of the manifest about to replace the committed one:
/// the committed one's files that `next` no longer names (retired now), and
/// its retired files still within their grace.
fn retire(dir: &Path, next: &Manifest, grace: Duration) -> Vec<Retired> {
    let Ok(Some(current)) = crate::reader::committed_manifest(dir) else {
        return Vec::new();
    };
    let named: HashSet<&str> = next.layers.iter().map(|l| l.file.as_str()).collect();
    let now = unix_now();
    let mut retired: Vec<Retired> = current
        .retired
        .into_iter()
        .chain(current.layers.into_iter().map(|l| Retired {
            file: l.file,
            since_unix: now,
        }))
        .filter(|r| in_grace(r, now, grace) && !named.contains(r.file.as_str()))
        .collect();
    retired.sort_by(|a, b| a.file.cmp(&b.file));
    retired.dedup_by(|a, b| a.file == b.file);
    retired
}
