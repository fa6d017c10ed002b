//! The part of HDF5 a NetCDF-4 file is made of, written from the HDF5 File
//! Format Specification (version 3.0) with no C library: the NetCDF export
//! ([`super::netcdf`]) stays in the one binary and the wheel.
//!
//! ```text
//! ┌────────────┬────────────────────┬────────────┬─────────┬───────────┬──────────────────┐
//! │ superblock │ chunks, coordinate │ chunk      │ global  │ dataset   │ root group       │
//! │ v2 (48 B)  │ data (streamed)    │ B-trees v1 │ heap    │ headers   │ header: links    │
//! └────────────┴────────────────────┴────────────┴─────────┴───────────┴──────────────────┘
//! ```
//!
//! Everything is written once, front to back; the superblock, which names
//! the root group and the end of the file, is written last over the zeros
//! the file starts with. Object headers (version 2, checksummed with
//! Jenkins' lookup3 as the format requires) point at each other (a
//! variable's `DIMENSION_LIST` at its dimension scales, each scale's
//! `REFERENCE_LIST` back at the variables), so they are encoded twice: once
//! to learn their sizes and so their addresses, once for real.
//!
//! What is used, and why these versions:
//! - chunk indexes are version 1 B-trees (layout message version 3), the
//!   index every HDF5 reader since 1.0 follows and netCDF-C writes by
//!   default;
//! - groups and attributes are compact (links and attributes in the object
//!   header), with creation order tracked, so netCDF-C lists variables and
//!   attributes in the order written;
//! - variable-length data (the references of `DIMENSION_LIST`, arrays of
//!   strings) live in one global heap collection.
//!
//! Not written: dense (fractal heap) storage, so an attribute is at most
//! 64 KiB; shared messages; anything a writer after this one could append
//! to (the file is read-only by design).

use std::io::{self, Seek, SeekFrom, Write};

/// HDF5's undefined address.
pub const UNDEF: u64 = u64::MAX;

/// Size of offsets and of lengths: 8 bytes, as every modern file has them.
const SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

/// The most bytes one object header message holds (its size is a u16):
/// with compact storage only, the bound on an attribute.
pub const MAX_MESSAGE_LEN: usize = u16::MAX as usize;

/// The superblock's size (version 2).
pub const SUPERBLOCK_LEN: u64 = 48;

/// Jenkins' lookup3 `hashlittle` with initial value 0: the checksum of
/// HDF5's version 2 metadata. `mix` and `final` are written as their
/// tables of steps over `[a, b, c]`.
pub fn checksum(data: &[u8]) -> u32 {
    let word = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    let start = 0xdead_beef_u32.wrapping_add(data.len() as u32);
    let mut v = [start; 3];
    let add = |v: &mut [u32; 3], k: &[u8]| {
        for (x, w) in v.iter_mut().zip(k.chunks_exact(4)) {
            *x = x.wrapping_add(word(w));
        }
    };
    let mut k = data;
    while k.len() > 12 {
        add(&mut v, &k[..12]);
        // mix: x -= z; x ^= z <<< r; z += y, for (x, y, z) turning.
        for (x, r) in [(0, 4), (1, 6), (2, 8), (0, 16), (1, 19), (2, 4)] {
            let (y, z) = ((x + 1) % 3, (x + 2) % 3);
            v[x] = v[x].wrapping_sub(v[z]) ^ v[z].rotate_left(r);
            v[z] = v[z].wrapping_add(v[y]);
        }
        k = &k[12..];
    }
    if k.is_empty() {
        return v[2];
    }
    let mut tail = [0u8; 12];
    tail[..k.len()].copy_from_slice(k);
    add(&mut v, &tail);
    // final: x ^= y; x -= y <<< r, for (x, y) = (c, b), (a, c), (b, a), ...
    for (i, r) in [14, 11, 25, 16, 4, 14, 24].into_iter().enumerate() {
        let (x, y) = [(2, 1), (0, 2), (1, 0)][i % 3];
        v[x] = (v[x] ^ v[y]).wrapping_sub(v[y].rotate_left(r));
    }
    v[2]
}

/// A datatype (the datatype message, IV.A.2.d), little-endian throughout.
#[derive(Debug, Clone, PartialEq)]
pub enum Dtype {
    Int {
        size: u8,
        signed: bool,
    },
    /// IEEE 754 binary32 (4) or binary64 (8).
    Float {
        size: u8,
    },
    /// A fixed-length string, NUL-terminated where shorter than `len`.
    FixedString {
        len: u32,
        utf8: bool,
    },
    VlenString {
        utf8: bool,
    },
    ObjectRef,
    Vlen(Box<Dtype>),
    /// Members: name, byte offset, type.
    Compound(Vec<(String, u32, Dtype)>),
}

impl Dtype {
    /// Bytes of one element in the file.
    pub fn size(&self) -> u32 {
        match self {
            Dtype::Int { size, .. } | Dtype::Float { size } => u32::from(*size),
            Dtype::FixedString { len, .. } => *len,
            // Sequence length, then the global heap ID (collection, index).
            Dtype::VlenString { .. } | Dtype::Vlen(_) => 4 + 8 + 4,
            Dtype::ObjectRef => 8,
            Dtype::Compound(members) => members
                .iter()
                .map(|(_, offset, t)| offset + t.size())
                .max()
                .unwrap_or(0),
        }
    }

    fn encode(&self, b: &mut Vec<u8>) {
        let head = |b: &mut Vec<u8>, class: u8, version: u8, bits: [u8; 3], size: u32| {
            b.push(version << 4 | class);
            b.extend_from_slice(&bits);
            b.extend_from_slice(&size.to_le_bytes());
        };
        match self {
            Dtype::Int { size, signed } => {
                head(b, 0, 1, [if *signed { 0x08 } else { 0 }, 0, 0], self.size());
                b.extend_from_slice(&0u16.to_le_bytes());
                b.extend_from_slice(&(u16::from(*size) * 8).to_le_bytes());
            }
            Dtype::Float { size } => {
                let (sign, exp_loc, exp_size, mant, bias) = if *size == 4 {
                    (31, 23, 8, 23, 127u32)
                } else {
                    (63, 52, 11, 52, 1023)
                };
                // Mantissa normalisation 2: the leading 1 is implied.
                head(b, 1, 1, [0x20, sign, 0], self.size());
                b.extend_from_slice(&0u16.to_le_bytes());
                b.extend_from_slice(&(u16::from(*size) * 8).to_le_bytes());
                b.extend_from_slice(&[exp_loc, exp_size, 0, mant]);
                b.extend_from_slice(&bias.to_le_bytes());
            }
            Dtype::FixedString { utf8, .. } => {
                head(b, 3, 1, [u8::from(*utf8) << 4, 0, 0], self.size());
            }
            Dtype::ObjectRef => head(b, 7, 1, [0, 0, 0], 8),
            Dtype::Vlen(base) => {
                head(b, 9, 1, [0, 0, 0], self.size());
                base.encode(b);
            }
            Dtype::VlenString { utf8 } => {
                head(b, 9, 1, [1, u8::from(*utf8), 0], self.size());
                Dtype::Int {
                    size: 1,
                    signed: false,
                }
                .encode(b);
            }
            Dtype::Compound(members) => {
                let n = members.len() as u16;
                let size = self.size();
                let [lo, hi] = n.to_le_bytes();
                head(b, 6, 3, [lo, hi, 0], size);
                // Version 3: offsets in as few bytes as the size needs.
                let width = match size {
                    0..=0xff => 1,
                    0x100..=0xffff => 2,
                    0x1_0000..=0xff_ffff => 3,
                    _ => 4,
                };
                for (name, offset, t) in members {
                    b.extend_from_slice(name.as_bytes());
                    b.push(0);
                    b.extend_from_slice(&offset.to_le_bytes()[..width]);
                    t.encode(b);
                }
            }
        }
    }
}

/// A dataspace (IV.A.2.b): a scalar, or the sizes of a simple one.
#[derive(Debug, Clone, PartialEq)]
pub enum Dataspace {
    Scalar,
    Simple(Vec<u64>),
}

impl Dataspace {
    fn encode(&self, b: &mut Vec<u8>) {
        match self {
            Dataspace::Scalar => b.extend_from_slice(&[2, 0, 0, 0]),
            Dataspace::Simple(dims) => {
                b.extend_from_slice(&[2, dims.len() as u8, 0, 1]);
                for d in dims {
                    b.extend_from_slice(&d.to_le_bytes());
                }
            }
        }
    }
}

/// One object of a file: a group's or a dataset's header and attributes.
/// Objects are numbered by their place in [`File::objects`]; the first
/// is the root group.
#[derive(Debug, Clone)]
pub struct Object {
    pub kind: ObjectKind,
    pub attrs: Vec<Attribute>,
}

#[derive(Debug, Clone)]
pub enum ObjectKind {
    /// Hard links, by name, to other objects.
    Group { links: Vec<(String, usize)> },
    Dataset {
        dtype: Dtype,
        space: Dataspace,
        layout: Layout,
        /// The fill value's bytes, where one is defined.
        fill: Option<Vec<u8>>,
        filters: Vec<Filter>,
    },
}

/// Where a dataset's elements are.
#[derive(Debug, Clone)]
pub enum Layout {
    /// In the header itself (small datasets).
    Compact(Vec<u8>),
    Contiguous {
        address: u64,
        size: u64,
    },
    /// Chunks of `chunk` elements, found through the B-tree at `btree`.
    Chunked {
        btree: u64,
        chunk: Vec<u64>,
    },
}

/// A filter of the pipeline chunks pass through on the way to the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Filter {
    /// Bytes of each element gathered by significance (filter 2).
    Shuffle { elem_size: u32 },
    /// zlib's deflate (filter 1).
    Deflate { level: u32 },
}

/// An attribute's value.
#[derive(Debug, Clone)]
pub enum Value {
    /// Bytes of the given type and shape.
    Data(Dtype, Dataspace, Vec<u8>),
    /// A one-dimensional array of variable-length strings.
    Strings(Vec<String>),
    /// A one-dimensional array of variable-length sequences of object
    /// references: one sequence per entry (HDF5's `DIMENSION_LIST`).
    ObjectRefLists(Vec<Vec<usize>>),
    /// Compound `(dataset reference, u32)` records (`REFERENCE_LIST`).
    RefIndexPairs(Vec<(usize, u32)>),
}

#[derive(Debug, Clone)]
pub struct Attribute {
    pub name: String,
    pub value: Value,
}

impl Attribute {
    /// A text attribute: a scalar fixed-length string.
    pub fn text(name: &str, text: &str) -> Self {
        let len = text.len().max(1) as u32;
        let mut data = text.as_bytes().to_vec();
        data.resize(len as usize, 0);
        Attribute {
            name: name.into(),
            value: Value::Data(
                Dtype::FixedString {
                    len,
                    utf8: !text.is_ascii(),
                },
                Dataspace::Scalar,
                data,
            ),
        }
    }

    /// A scalar NUL-terminated string, as HDF5's dimension scale API
    /// writes `CLASS` and `NAME` (and reads them back one byte short
    /// without the NUL).
    pub fn c_string(name: &str, text: &str) -> Self {
        let mut data = text.as_bytes().to_vec();
        data.push(0);
        Attribute {
            name: name.into(),
            value: Value::Data(
                Dtype::FixedString {
                    len: data.len() as u32,
                    utf8: !text.is_ascii(),
                },
                Dataspace::Scalar,
                data,
            ),
        }
    }

    /// Bytes of its attribute message, which must be at most
    /// [`MAX_MESSAGE_LEN`] (checked again when the file is finished).
    pub fn message_len(&self) -> usize {
        let last = match &self.value {
            Value::ObjectRefLists(lists) => lists.iter().flatten().max().copied(),
            Value::RefIndexPairs(pairs) => pairs.iter().map(|p| p.0).max(),
            _ => None,
        };
        let addresses = vec![0; last.map_or(0, |l| l + 1)];
        encode_attribute(self, &addresses, 0, &mut Heap::default()).len()
    }

    /// A one-dimensional numeric attribute.
    pub fn numbers(name: &str, dtype: Dtype, bytes: Vec<u8>) -> Self {
        let n = bytes.len() as u64 / u64::from(dtype.size().max(1));
        Attribute {
            name: name.into(),
            value: Value::Data(dtype, Dataspace::Simple(vec![n]), bytes),
        }
    }
}

/// A chunk of a chunked dataset as written: its first element's indices,
/// and its place and length in the file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChunkRef {
    pub offsets: Vec<u64>,
    pub address: u64,
    pub size: u32,
}

/// A file being written front to back through `out`, which starts at
/// offset 0.
#[derive(Debug)]
pub struct File<W: Write + Seek> {
    out: W,
    pos: u64,
    pub objects: Vec<Object>,
}

impl<W: Write + Seek> File<W> {
    /// Starts a file: the superblock's place, to be written by [`Self::finish`].
    pub fn new(mut out: W) -> io::Result<Self> {
        out.write_all(&[0; SUPERBLOCK_LEN as usize])?;
        Ok(File {
            out,
            pos: SUPERBLOCK_LEN,
            objects: Vec::new(),
        })
    }

    /// Writes raw bytes (chunks, contiguous data); returns their address.
    pub fn write_raw(&mut self, bytes: &[u8]) -> io::Result<u64> {
        let at = self.pos;
        self.out.write_all(bytes)?;
        self.pos += bytes.len() as u64;
        Ok(at)
    }

    /// Writes the version 1 B-tree (node type 1, raw data chunks) that
    /// indexes `chunks` (sorted by offsets, as written) of a dataset with
    /// chunks of `chunk` elements of `elem_size` bytes; returns its root's
    /// address.
    pub fn write_chunk_btree(
        &mut self,
        chunks: &[ChunkRef],
        chunk: &[u64],
        elem_size: u32,
    ) -> io::Result<u64> {
        // Keys hold the rank's offsets and one more (0) for the element.
        #[derive(Clone)]
        struct Key {
            size: u32,
            offsets: Vec<u64>,
        }
        let key_of = |c: &ChunkRef| {
            let mut offsets = c.offsets.clone();
            offsets.push(0);
            Key {
                size: c.size,
                offsets,
            }
        };
        let last = chunks.last().expect("a chunked dataset has chunks");
        // The key past the last chunk: one chunk further in every
        // dimension, as the library writes it.
        let mut end = key_of(last);
        for (o, c) in end.offsets.iter_mut().zip(chunk) {
            *o += c;
        }
        *end.offsets.last_mut().expect("rank + 1 offsets") = u64::from(elem_size);
        let key_len = 8 + 8 * (chunk.len() + 1);
        // 2K children a node, K = 32 (the default of files without a
        // B-tree K message); readers read whole nodes, so each is padded.
        const TWO_K: usize = 64;
        let node_len = 24 + TWO_K * 8 + (TWO_K + 1) * key_len;
        let encode_key = |b: &mut Vec<u8>, k: &Key| {
            b.extend_from_slice(&k.size.to_le_bytes());
            b.extend_from_slice(&0u32.to_le_bytes()); // every filter applied
            for o in &k.offsets {
                b.extend_from_slice(&o.to_le_bytes());
            }
        };
        // (first key, address) of each node of the level below, starting
        // from the chunks themselves.
        let mut below: Vec<(Key, u64)> = chunks.iter().map(|c| (key_of(c), c.address)).collect();
        let mut level = 0u8;
        loop {
            let groups: Vec<&[(Key, u64)]> = below.chunks(TWO_K).collect();
            let first = self.pos;
            let mut above = Vec::with_capacity(groups.len());
            for (g, entries) in groups.iter().enumerate() {
                let at = first + (g * node_len) as u64;
                let sibling = |i: usize| {
                    if i < groups.len() {
                        first + (i * node_len) as u64
                    } else {
                        UNDEF
                    }
                };
                let mut b = Vec::with_capacity(node_len);
                b.extend_from_slice(b"TREE");
                b.push(1);
                b.push(level);
                b.extend_from_slice(&(entries.len() as u16).to_le_bytes());
                let left = if g == 0 { UNDEF } else { sibling(g - 1) };
                b.extend_from_slice(&left.to_le_bytes());
                b.extend_from_slice(&sibling(g + 1).to_le_bytes());
                for (key, child) in entries.iter() {
                    encode_key(&mut b, key);
                    b.extend_from_slice(&child.to_le_bytes());
                }
                let next = groups
                    .get(g + 1)
                    .map(|n| n[0].0.clone())
                    .unwrap_or_else(|| end.clone());
                encode_key(&mut b, &next);
                b.resize(node_len, 0);
                self.write_raw(&b)?;
                above.push((entries[0].0.clone(), at));
            }
            if above.len() == 1 {
                return Ok(above[0].1);
            }
            below = above;
            level += 1;
        }
    }

    /// Writes the global heap and every object's header, then the
    /// superblock; returns the file's length.
    pub fn finish(mut self) -> io::Result<(W, u64)> {
        // Pass 1 with placeholder addresses: the sizes.
        let zero = vec![0u64; self.objects.len()];
        let mut heap = Heap::default();
        let sizes: Vec<u64> = (0..self.objects.len())
            .map(|i| Ok(self.encode_header(i, &zero, 0, &mut heap)?.len() as u64))
            .collect::<io::Result<_>>()?;
        if heap.objects.len() > usize::from(u16::MAX) {
            return Err(io::Error::other(format!(
                "{} variable-length values (strings, dimension lists) are more than one HDF5 global heap holds (65535)",
                heap.objects.len()
            )));
        }
        let heap_addr = self.pos;
        let heap_len = heap.len();
        let mut addresses = Vec::with_capacity(sizes.len());
        let mut at = heap_addr + heap_len;
        for s in &sizes {
            addresses.push(at);
            at += s;
        }
        // Pass 2, for real.
        let mut heap = Heap::default();
        let headers: Vec<Vec<u8>> = (0..self.objects.len())
            .map(|i| self.encode_header(i, &addresses, heap_addr, &mut heap))
            .collect::<io::Result<_>>()?;
        let heap_bytes = heap.encode();
        debug_assert_eq!(heap_bytes.len() as u64, heap_len);
        self.write_raw(&heap_bytes)?;
        for h in &headers {
            self.write_raw(h)?;
        }
        let eof = self.pos;
        let mut sb = Vec::with_capacity(SUPERBLOCK_LEN as usize);
        sb.extend_from_slice(SIGNATURE);
        sb.extend_from_slice(&[2, 8, 8, 0]);
        sb.extend_from_slice(&0u64.to_le_bytes()); // base address
        sb.extend_from_slice(&UNDEF.to_le_bytes()); // no superblock extension
        sb.extend_from_slice(&eof.to_le_bytes());
        sb.extend_from_slice(&addresses[0].to_le_bytes()); // the root group
        let sum = checksum(&sb);
        sb.extend_from_slice(&sum.to_le_bytes());
        self.out.seek(SeekFrom::Start(0))?;
        self.out.write_all(&sb)?;
        self.out.seek(SeekFrom::Start(eof))?;
        self.out.flush()?;
        Ok((self.out, eof))
    }

    /// Object `i`'s header (version 2): its messages, then a checksum.
    fn encode_header(
        &self,
        i: usize,
        addresses: &[u64],
        heap_addr: u64,
        heap: &mut Heap,
    ) -> io::Result<Vec<u8>> {
        let object = &self.objects[i];
        let mut messages: Vec<(u8, u8, Vec<u8>)> = Vec::new();
        match &object.kind {
            ObjectKind::Group { links } => {
                // Link info: creation order tracked, links compact.
                let mut m = vec![0, 1];
                m.extend_from_slice(&(links.len() as u64).to_le_bytes());
                m.extend_from_slice(&UNDEF.to_le_bytes());
                m.extend_from_slice(&UNDEF.to_le_bytes());
                messages.push((0x02, 0, m));
                // Group info: as many compact links as there are.
                let mut m = vec![0, 1];
                m.extend_from_slice(&(links.len().clamp(8, 0xffff) as u16).to_le_bytes());
                m.extend_from_slice(&6u16.to_le_bytes());
                messages.push((0x0a, 0, m));
                for (order, (name, target)) in links.iter().enumerate() {
                    let mut m = vec![1];
                    let utf8 = !name.is_ascii();
                    let width: u8 = if name.len() < 0x100 { 0 } else { 1 };
                    m.push(width | 0x04 | if utf8 { 0x10 } else { 0 });
                    m.extend_from_slice(&(order as u64).to_le_bytes());
                    if utf8 {
                        m.push(1);
                    }
                    if width == 0 {
                        m.push(name.len() as u8);
                    } else {
                        m.extend_from_slice(&(name.len() as u16).to_le_bytes());
                    }
                    m.extend_from_slice(name.as_bytes());
                    m.extend_from_slice(&addresses[*target].to_le_bytes());
                    messages.push((0x06, 0, m));
                }
            }
            ObjectKind::Dataset {
                dtype,
                space,
                layout,
                fill,
                filters,
            } => {
                let mut m = Vec::new();
                space.encode(&mut m);
                messages.push((0x01, 0, m));
                let mut m = Vec::new();
                dtype.encode(&mut m);
                messages.push((0x03, 1, m));
                // Fill value: allocated late (contiguous, compact) or
                // incrementally (chunked); written only where defined.
                let alloc = match layout {
                    Layout::Compact(_) => 1,
                    Layout::Contiguous { .. } => 2,
                    Layout::Chunked { .. } => 3,
                };
                let mut m = vec![3];
                match fill {
                    Some(v) => {
                        m.push(alloc | 2 << 2 | 1 << 5);
                        m.extend_from_slice(&(v.len() as u32).to_le_bytes());
                        m.extend_from_slice(v);
                    }
                    None => m.push(alloc | 2 << 2),
                }
                messages.push((0x05, 1, m));
                let mut m = vec![3];
                match layout {
                    Layout::Compact(data) => {
                        m.push(0);
                        m.extend_from_slice(&(data.len() as u16).to_le_bytes());
                        m.extend_from_slice(data);
                    }
                    Layout::Contiguous { address, size } => {
                        m.push(1);
                        m.extend_from_slice(&address.to_le_bytes());
                        m.extend_from_slice(&size.to_le_bytes());
                    }
                    Layout::Chunked { btree, chunk } => {
                        m.push(2);
                        m.push(chunk.len() as u8 + 1);
                        m.extend_from_slice(&btree.to_le_bytes());
                        for c in chunk {
                            m.extend_from_slice(&(*c as u32).to_le_bytes());
                        }
                        m.extend_from_slice(&dtype.size().to_le_bytes());
                    }
                }
                messages.push((0x08, 0, m));
                if !filters.is_empty() {
                    let mut m = vec![2, filters.len() as u8];
                    for f in filters {
                        let (id, value) = match *f {
                            Filter::Shuffle { elem_size } => (2u16, elem_size),
                            Filter::Deflate { level } => (1, level),
                        };
                        m.extend_from_slice(&id.to_le_bytes());
                        m.extend_from_slice(&1u16.to_le_bytes()); // optional
                        m.extend_from_slice(&1u16.to_le_bytes()); // one value
                        m.extend_from_slice(&value.to_le_bytes());
                    }
                    messages.push((0x0b, 1, m));
                }
            }
        }
        // Attribute info: creation order tracked, attributes compact.
        let mut m = vec![0, 1];
        m.extend_from_slice(&(object.attrs.len() as u16).to_le_bytes());
        m.extend_from_slice(&UNDEF.to_le_bytes());
        m.extend_from_slice(&UNDEF.to_le_bytes());
        messages.push((0x15, 0, m));
        for a in &object.attrs {
            messages.push((0x0c, 0, encode_attribute(a, addresses, heap_addr, heap)));
        }

        let body: usize = messages.iter().map(|(_, _, m)| 6 + m.len()).sum();
        let (width, width_bits) = match body {
            0..=0xff => (1, 0u8),
            0x100..=0xffff => (2, 1),
            _ => (4, 2),
        };
        let mut h = Vec::with_capacity(16 + body);
        h.extend_from_slice(b"OHDR");
        h.push(2);
        // Attribute creation order tracked; phase change values stored.
        h.push(width_bits | 0x04 | 0x10);
        h.extend_from_slice(&(object.attrs.len().clamp(8, 0xffff) as u16).to_le_bytes());
        h.extend_from_slice(&6u16.to_le_bytes());
        h.extend_from_slice(&(body as u64).to_le_bytes()[..width]);
        let mut attr_order = 0u16;
        for (kind, flags, m) in &messages {
            let len = u16::try_from(m.len()).map_err(|_| {
                io::Error::other(format!(
                    "an object header message (type {kind:#04x}) of {} bytes is over the {MAX_MESSAGE_LEN} one message holds",
                    m.len()
                ))
            })?;
            h.push(*kind);
            h.extend_from_slice(&len.to_le_bytes());
            h.push(*flags);
            let order = if *kind == 0x0c {
                attr_order += 1;
                attr_order - 1
            } else {
                0
            };
            h.extend_from_slice(&order.to_le_bytes());
            h.extend_from_slice(m);
        }
        let sum = checksum(&h);
        h.extend_from_slice(&sum.to_le_bytes());
        Ok(h)
    }
}

/// The attribute message (version 3) of `a`, its variable-length parts put
/// in `heap`.
fn encode_attribute(a: &Attribute, addresses: &[u64], heap_addr: u64, heap: &mut Heap) -> Vec<u8> {
    let heap_id = |b: &mut Vec<u8>, len: u32, index: u16| {
        b.extend_from_slice(&len.to_le_bytes());
        b.extend_from_slice(&heap_addr.to_le_bytes());
        b.extend_from_slice(&u32::from(index).to_le_bytes());
    };
    let (dtype, space, data) = match &a.value {
        Value::Data(t, s, d) => (t.clone(), s.clone(), d.clone()),
        Value::Strings(strings) => {
            let utf8 = strings.iter().any(|s| !s.is_ascii());
            let mut data = Vec::new();
            for s in strings {
                let index = heap.push(s.as_bytes().to_vec());
                heap_id(&mut data, s.len() as u32, index);
            }
            let space = Dataspace::Simple(vec![strings.len() as u64]);
            (Dtype::VlenString { utf8 }, space, data)
        }
        Value::ObjectRefLists(lists) => {
            let mut data = Vec::new();
            for list in lists {
                let refs: Vec<u8> = list
                    .iter()
                    .flat_map(|o| addresses[*o].to_le_bytes())
                    .collect();
                let index = heap.push(refs);
                heap_id(&mut data, list.len() as u32, index);
            }
            let space = Dataspace::Simple(vec![lists.len() as u64]);
            (Dtype::Vlen(Box::new(Dtype::ObjectRef)), space, data)
        }
        Value::RefIndexPairs(pairs) => {
            let t = Dtype::Compound(vec![
                ("dataset".into(), 0, Dtype::ObjectRef),
                (
                    "dimension".into(),
                    8,
                    Dtype::Int {
                        size: 4,
                        signed: true,
                    },
                ),
            ]);
            let mut data = Vec::new();
            for (o, d) in pairs {
                data.extend_from_slice(&addresses[*o].to_le_bytes());
                data.extend_from_slice(&d.to_le_bytes());
            }
            (t, Dataspace::Simple(vec![pairs.len() as u64]), data)
        }
    };
    let (mut t, mut s) = (Vec::new(), Vec::new());
    dtype.encode(&mut t);
    space.encode(&mut s);
    let mut m = vec![3, 0];
    m.extend_from_slice(&(a.name.len() as u16 + 1).to_le_bytes());
    m.extend_from_slice(&(t.len() as u16).to_le_bytes());
    m.extend_from_slice(&(s.len() as u16).to_le_bytes());
    m.push(u8::from(!a.name.is_ascii()));
    m.extend_from_slice(a.name.as_bytes());
    m.push(0);
    m.extend_from_slice(&t);
    m.extend_from_slice(&s);
    m.extend_from_slice(&data);
    m
}

/// One global heap collection (III.E) holding every variable-length value.
#[derive(Default)]
struct Heap {
    objects: Vec<Vec<u8>>,
}

impl Heap {
    /// Adds an object; returns its index (from 1; [`File::finish`] refuses
    /// a heap past 65535 before any index wraps into the file).
    fn push(&mut self, bytes: Vec<u8>) -> u16 {
        self.objects.push(bytes);
        self.objects.len() as u16
    }

    fn used(&self) -> u64 {
        16 + self
            .objects
            .iter()
            .map(|o| 16 + (o.len() as u64).next_multiple_of(8))
            .sum::<u64>()
    }

    /// The collection's size: at least the 4096 bytes readers expect, and
    /// room for the free-space object that ends it.
    fn len(&self) -> u64 {
        (self.used() + 16).max(4096).next_multiple_of(8)
    }

    fn encode(&self) -> Vec<u8> {
        let len = self.len();
        let mut b = Vec::with_capacity(len as usize);
        b.extend_from_slice(b"GCOL");
        b.extend_from_slice(&[1, 0, 0, 0]);
        b.extend_from_slice(&len.to_le_bytes());
        for (i, o) in self.objects.iter().enumerate() {
            b.extend_from_slice(&(i as u16 + 1).to_le_bytes());
            b.extend_from_slice(&[0; 6]); // reference count, reserved
            b.extend_from_slice(&(o.len() as u64).to_le_bytes());
            b.extend_from_slice(o);
            b.resize(b.len().next_multiple_of(8), 0);
        }
        // Object 0, the free space: its size counts its own header.
        let free = len - b.len() as u64;
        b.extend_from_slice(&[0; 8]);
        b.extend_from_slice(&free.to_le_bytes());
        b.resize(len as usize, 0);
        b
    }
}

/// HDF5's shuffle filter: the first byte of every element, then every
/// second byte, and so on, which deflate compresses better.
pub fn shuffle(bytes: &[u8], elem_size: usize) -> Vec<u8> {
    if elem_size <= 1 {
        return bytes.to_vec();
    }
    let n = bytes.len() / elem_size;
    let mut out = vec![0u8; bytes.len()];
    for (i, elem) in bytes.chunks_exact(elem_size).enumerate() {
        for (j, byte) in elem.iter().enumerate() {
            out[j * n + i] = *byte;
        }
    }
    // Bytes past the last whole element stay where they were.
    let whole = n * elem_size;
    out[whole..].copy_from_slice(&bytes[whole..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checksum_is_lookup3_hashlittle() {
        // Bob Jenkins' own test vectors (lookup3.c, driver5).
        assert_eq!(checksum(b""), 0xdead_beef);
        assert_eq!(checksum(b"Four score and seven years ago"), 0x1777_0551);
    }

    #[test]
    fn shuffle_gathers_bytes_by_significance() {
        let bytes = [1u8, 2, 3, 4, 5, 6, 7];
        assert_eq!(shuffle(&bytes, 2), vec![1, 3, 5, 2, 4, 6, 7]);
        assert_eq!(shuffle(&bytes, 1), bytes.to_vec());
    }
}
