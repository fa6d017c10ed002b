//! # terrabake-capi
//!
//! A C ABI over the asset reader of `terrabake-format`, for renderers that
//! are not written in Rust (Unreal and Godot in C++, Unity in C# through
//! P/Invoke, simulator engines). The header, `include/terrabake.h`, is
//! generated from this file by cbindgen and committed; `make capi` builds
//! `libterrabake_c.so` and `libterrabake_c.a` beside it.
//!
//! **Handles.** `tb_open` gives a `tb_asset *`, which `tb_close` frees. An
//! asset is read-only and safe to use from many threads at once, as the
//! Rust reader is; only `tb_close` must not race the others.
//!
//! **Errors.** Every function but `tb_close`, `tb_last_error`,
//! `tb_status_name` and `tb_format_version` returns a `tb_status`: `TB_OK`,
//! or what went wrong, with the message (naming the file, layer and tile
//! where there is one) in `tb_last_error()`, kept per thread until that
//! thread's next failing call. No panic crosses the boundary: a panic
//! inside is caught and returned as `TB_PANIC` with its message.
//!
//! **Borrowed memory.** Strings and arrays in `tb_layer` and tiles from
//! `tb_tile` point into the open asset (its manifest, or its memory
//! mapping): valid until `tb_close`, never to be freed or written.
//!
//! **Lazily built readers.** The ray tracer and the horizon map are built
//! on first use and kept inside the handle, which owns the asset they
//! borrow; they are declared before it so that they are dropped first.

use std::cell::RefCell;
use std::ffi::{c_char, c_void, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::OnceLock;

use terrabake_format::horizons::HorizonMap;
use terrabake_format::trace::{Method, Ray, Tracer};
use terrabake_format::{Asset, Error, Mmap};

/// What a call came to.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TbStatus {
    TbOk = 0,
    /// A pointer argument was NULL.
    TbNullArgument = 1,
    /// An argument is out of its domain (not UTF-8, an unknown method, a
    /// buffer of the wrong length, a NaN ray).
    TbInvalidArgument = 2,
    /// The file system failed (a missing asset, a permission).
    TbIo = 3,
    /// The asset is damaged: bad magic, checksum, truncated, bad manifest.
    TbCorrupt = 4,
    /// Written by a newer format version than this library reads.
    TbUnsupportedVersion = 5,
    /// No such layer, or the layer lacks what the call needs (no horizons,
    /// no pyramid for hierarchical tracing).
    TbNoLayer = 6,
    /// The layer holds another element type, or its tile is compressed and
    /// cannot be borrowed (read a window instead).
    TbWrongType = 7,
    /// A band, tile, post or window outside the layer.
    TbOutOfRange = 8,
    /// A bug in terrabake: a panic, caught at the boundary.
    TbPanic = 9,
}

/// One layer of an asset, as `tb_layer_info` describes it. The pointers
/// borrow the open asset.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct TbLayer {
    /// NUL-terminated (`height`, `horizon`, `cone_slope`, ...).
    pub name: *const c_char,
    /// Pyramid level (0: full resolution).
    pub level: u32,
    /// The stored element type: 1 f32, 2 u16, 3 u8, 4 i16, 5 f16, 6 u32.
    pub elem: u32,
    /// Bytes per element.
    pub elem_bytes: u32,
    pub bands: u32,
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    /// Compass azimuth (degrees clockwise from north) of each band, for
    /// layers with a band per direction; NULL and 0 otherwise.
    pub band_azimuths: *const f64,
    pub band_azimuth_count: usize,
}

/// A ray in the asset's local metres: x east and y north from the DEM's
/// south-west post, z the height; `origin + t * dir` for `t` in
/// `[t_min, t_max]`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct TbRay {
    pub origin: [f64; 3],
    pub dir: [f64; 3],
    pub t_min: f64,
    pub t_max: f64,
}

/// A window of a layer: columns `x0 .. x0 + width`, rows `y0 .. y0 + height`
/// (row 0 is the north edge).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct TbWindow {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

/// The sun: centre of its disc at `azimuth` (compass degrees, clockwise
/// from north) and `elevation` (degrees above the horizontal), angular
/// `radius` (degrees; the sun's is about 0.27).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct TbSun {
    pub azimuth: f64,
    pub elevation: f64,
    pub radius: f64,
}

/// The DEM's grid: posts and their spacing in metres (the tracer's local
/// frame spans `[0, (width - 1) * dx] x [0, (height - 1) * dy]`).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct TbGrid {
    pub width: u32,
    pub height: u32,
    pub dx: f64,
    pub dy: f64,
}

/// Ray tracing methods (docs/TRACING.md): the same hit from each.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TbMethod {
    /// Cell by cell (Musgrave).
    TbIncremental = 0,
    /// Runs of cells (Henning and Stephenson).
    TbRuns = 1,
    /// Down the max pyramid (needs the pyramid layers).
    TbHierarchical = 2,
    /// Cone steps through the parameter planes (needs the cone planes).
    TbParametric = 3,
    /// Every cell: the reference.
    TbBruteForce = 4,
}

/// Where a ray met the terrain, and what finding it cost.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct TbHit {
    /// 1 if the ray hit the terrain (the other fields but the counts are
    /// then set), 0 if it left the DEM.
    pub hit: u32,
    /// The cell hit, between posts `cell..=cell + 1`.
    pub cell: [u32; 2],
    pub t: f64,
    /// Local metres.
    pub point: [f64; 3],
    /// Unit upward normal of the triangle hit.
    pub normal: [f32; 3],
    /// Cells whose surface was tested against the ray.
    pub cells_tested: u64,
    /// Traversal steps (cells, runs, pyramid nodes or cone steps).
    pub steps: u64,
}

/// An open asset (opaque to C).
pub struct TbAsset {
    // Borrowers of `asset` first: fields drop in declaration order.
    tracer: OnceLock<Result<Tracer<'static, Mmap>, String>>,
    horizons: OnceLock<Result<HorizonMap<'static, Mmap>, String>>,
    /// NUL-terminated layer names, in the asset's order.
    names: Vec<CString>,
    asset: Box<Asset<Mmap>>,
}

impl std::fmt::Debug for TbAsset {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TbAsset")
            .field("dir", &self.asset.dir())
            .finish()
    }
}

impl TbAsset {
    /// The asset, for the lifetime of the handle: the box never moves and
    /// is dropped after every borrower (see the field order).
    fn asset_static(&self) -> &'static Asset<Mmap> {
        // SAFETY: `asset` is boxed (a stable address) and never replaced;
        // the only holders of the 'static reference are `tracer` and
        // `horizons`, which are dropped before it.
        unsafe { &*(&*self.asset as *const Asset<Mmap>) }
    }

    fn tracer(&self) -> Result<&Tracer<'static, Mmap>, Failure> {
        self.tracer
            .get_or_init(|| Tracer::new(self.asset_static()).map_err(|e| e.to_string()))
            .as_ref()
            .map_err(|m| Failure::new(TbStatus::TbNoLayer, m.clone()))
    }

    fn horizons(&self) -> Result<&HorizonMap<'static, Mmap>, Failure> {
        self.horizons
            .get_or_init(|| HorizonMap::open(self.asset_static()).map_err(|e| e.to_string()))
            .as_ref()
            .map_err(|m| Failure::new(TbStatus::TbNoLayer, m.clone()))
    }

    fn layer(&self, index: usize) -> Result<&terrabake_format::Layer<Mmap>, Failure> {
        let layers = self.asset.layers();
        layers.get(index).ok_or_else(|| {
            Failure::new(
                TbStatus::TbOutOfRange,
                format!(
                    "{}: layer index {index} out of range (the asset has {} layers)",
                    self.asset.dir().display(),
                    layers.len()
                ),
            )
        })
    }
}

/// A failed call: its status and message.
struct Failure {
    status: TbStatus,
    message: String,
}

impl Failure {
    fn new(status: TbStatus, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }
}

impl From<Error> for Failure {
    fn from(e: Error) -> Self {
        let status = match &e {
            Error::Io { .. } | Error::Locked { .. } => TbStatus::TbIo,
            Error::Version { .. } => TbStatus::TbUnsupportedVersion,
            Error::NoLayer { .. } => TbStatus::TbNoLayer,
            Error::ElemType { .. } => TbStatus::TbWrongType,
            Error::OutOfRange { .. } => TbStatus::TbOutOfRange,
            Error::Spec(_) => TbStatus::TbInvalidArgument,
            Error::Magic { .. }
            | Error::Checksum { .. }
            | Error::Malformed { .. }
            | Error::Manifest { .. }
            | Error::Decompress { .. } => TbStatus::TbCorrupt,
            // A kind this boundary does not know yet (the enum may grow):
            // refused as damage, its message saying which.
            _ => TbStatus::TbCorrupt,
        };
        Self::new(status, e.to_string())
    }
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(message: &str) {
    // A NUL inside a message (a path) would end it early: replaced.
    let message = CString::new(message.replace('\0', "\u{fffd}")).expect("no NUL left");
    LAST_ERROR.with(|e| *e.borrow_mut() = message);
}

/// Runs `f`, turning a failure or a panic into a status and the thread's
/// last error.
fn guard(f: impl FnOnce() -> Result<(), Failure>) -> TbStatus {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => TbStatus::TbOk,
        Ok(Err(failure)) => {
            set_last_error(&failure.message);
            failure.status
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "a panic without a message".into());
            set_last_error(&format!(
                "internal error in terrabake (please report it): {what}"
            ));
            TbStatus::TbPanic
        }
    }
}

/// `p` as a reference, or the failure that names the argument.
///
/// # Safety
/// `p` is NULL or points to a live `T`.
unsafe fn arg<'a, T>(p: *const T, name: &str) -> Result<&'a T, Failure> {
    // SAFETY: the caller's promise.
    unsafe { p.as_ref() }
        .ok_or_else(|| Failure::new(TbStatus::TbNullArgument, format!("{name} is NULL")))
}

/// `p` as a mutable reference, or the failure that names the argument.
///
/// # Safety
/// `p` is NULL or points to a live, writable `T` no one else uses.
unsafe fn out<'a, T>(p: *mut T, name: &str) -> Result<&'a mut T, Failure> {
    // SAFETY: the caller's promise.
    unsafe { p.as_mut() }
        .ok_or_else(|| Failure::new(TbStatus::TbNullArgument, format!("{name} is NULL")))
}

/// The format version this library reads (`FORMAT_VERSION`).
#[no_mangle]
pub extern "C" fn tb_format_version() -> u32 {
    terrabake_format::FORMAT_VERSION
}

/// The message of this thread's last failed call ("" if none): valid until
/// this thread's next failing call; never NULL.
#[no_mangle]
pub extern "C" fn tb_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// The name of a `tb_status` (`"TB_OK"`, ...; `"TB_UNKNOWN"` for another
/// number), static; never NULL.
#[no_mangle]
pub extern "C" fn tb_status_name(status: u32) -> *const c_char {
    const NAMES: [&CStr; 10] = [
        c"TB_OK",
        c"TB_NULL_ARGUMENT",
        c"TB_INVALID_ARGUMENT",
        c"TB_IO",
        c"TB_CORRUPT",
        c"TB_UNSUPPORTED_VERSION",
        c"TB_NO_LAYER",
        c"TB_WRONG_TYPE",
        c"TB_OUT_OF_RANGE",
        c"TB_PANIC",
    ];
    NAMES
        .get(status as usize)
        .copied()
        .unwrap_or(c"TB_UNKNOWN")
        .as_ptr()
}

/// Opens the asset directory `path` (UTF-8, NUL-terminated) and sets
/// `*asset`; checks the manifest and every layer's header, footer and index
/// (tiles are checksummed by `terrabake verify`, not here).
///
/// # Safety
/// `path` is NULL or a NUL-terminated string; `asset` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_open(path: *const c_char, asset: *mut *mut TbAsset) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let asset = unsafe { out(asset, "asset") }?;
        *asset = std::ptr::null_mut();
        if path.is_null() {
            return Err(Failure::new(TbStatus::TbNullArgument, "path is NULL"));
        }
        // SAFETY: the caller's promise.
        let path = unsafe { CStr::from_ptr(path) }
            .to_str()
            .map_err(|_| Failure::new(TbStatus::TbInvalidArgument, "path is not UTF-8"))?;
        let opened = Asset::open(path)?;
        let names = opened
            .layers()
            .iter()
            .map(|l| CString::new(l.entry().name.as_str()))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|_| {
                Failure::new(
                    TbStatus::TbCorrupt,
                    format!("{path}: a layer name holds a NUL"),
                )
            })?;
        *asset = Box::into_raw(Box::new(TbAsset {
            tracer: OnceLock::new(),
            horizons: OnceLock::new(),
            names,
            asset: Box::new(opened),
        }));
        Ok(())
    })
}

/// Closes an asset from `tb_open` (NULL is ignored). Every pointer into it
/// dies with it.
///
/// # Safety
/// `asset` is NULL or from `tb_open`, not closed before, and no other
/// thread is using it.
#[no_mangle]
pub unsafe extern "C" fn tb_close(asset: *mut TbAsset) {
    if !asset.is_null() {
        // A panic while dropping cannot cross the boundary either.
        let _ = catch_unwind(AssertUnwindSafe(|| {
            // SAFETY: the caller's promise: it came from Box::into_raw.
            drop(unsafe { Box::from_raw(asset) });
        }));
    }
}

/// The DEM's grid in `*grid`.
///
/// # Safety
/// `asset` is NULL or open; `grid` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_grid_info(asset: *const TbAsset, grid: *mut TbGrid) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let (asset, grid) = unsafe { (arg(asset, "asset")?, out(grid, "grid")?) };
        let m = asset.asset.manifest();
        *grid = TbGrid {
            width: m.width,
            height: m.height,
            dx: m.cell_size.dx,
            dy: m.cell_size.dy,
        };
        Ok(())
    })
}

/// The number of layers in `*count`.
///
/// # Safety
/// `asset` is NULL or open; `count` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_layer_count(asset: *const TbAsset, count: *mut usize) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let (asset, count) = unsafe { (arg(asset, "asset")?, out(count, "count")?) };
        *count = asset.asset.layers().len();
        Ok(())
    })
}

/// Layer `index` (0 .. count) described in `*layer`.
///
/// # Safety
/// `asset` is NULL or open; `layer` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_layer_info(
    asset: *const TbAsset,
    index: usize,
    layer: *mut TbLayer,
) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let (asset, info) = unsafe { (arg(asset, "asset")?, out(layer, "layer")?) };
        let l = asset.layer(index)?;
        let e = l.entry();
        *info = TbLayer {
            name: asset.names[index].as_ptr(),
            level: e.level,
            elem: e.elem as u32,
            elem_bytes: e.elem.size() as u32,
            bands: e.bands,
            width: e.width,
            height: e.height,
            tile_size: e.tile_size,
            tiles_x: l.tiles_x(),
            tiles_y: l.tiles_y(),
            band_azimuths: if e.band_azimuths.is_empty() {
                std::ptr::null()
            } else {
                e.band_azimuths.as_ptr()
            },
            band_azimuth_count: e.band_azimuths.len(),
        };
        Ok(())
    })
}

/// The index of layer `name` at `level` in `*index`; `TB_NO_LAYER` (the
/// message lists the layers there are) if the asset has none.
///
/// # Safety
/// `asset` is NULL or open; `name` is NULL or NUL-terminated; `index` is
/// NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_find_layer(
    asset: *const TbAsset,
    name: *const c_char,
    level: u32,
    index: *mut usize,
) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let (asset, index) = unsafe { (arg(asset, "asset")?, out(index, "index")?) };
        if name.is_null() {
            return Err(Failure::new(TbStatus::TbNullArgument, "name is NULL"));
        }
        // SAFETY: the caller's promise.
        let name = unsafe { CStr::from_ptr(name) }
            .to_str()
            .map_err(|_| Failure::new(TbStatus::TbInvalidArgument, "name is not UTF-8"))?;
        // The reader's lookup gives the error that lists the layers.
        let wanted = asset.asset.layer(name, level)?;
        *index = asset
            .asset
            .layers()
            .iter()
            .position(|l| std::ptr::eq(l, wanted))
            .expect("the layer is the asset's");
        Ok(())
    })
}

/// Borrows tile `(tx, ty)` of `band` of layer `layer`, zero-copy: `*data`
/// points at its `tile_size²` elements (row-major, stored type, edge tiles
/// padded) in the asset's memory mapping and `*bytes` is their length;
/// valid until `tb_close`. Raw tiles only: a compressed (zstd) tile is `TB_WRONG_TYPE`
/// (read it with `tb_read_window`).
///
/// # Safety
/// `asset` is NULL or open; `data` and `bytes` are NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_tile(
    asset: *const TbAsset,
    layer: usize,
    band: u32,
    tx: u32,
    ty: u32,
    data: *mut *const c_void,
    bytes: *mut usize,
) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let (asset, data, bytes) = unsafe {
            (
                arg(asset, "asset")?,
                out(data, "data")?,
                out(bytes, "bytes")?,
            )
        };
        let l = asset.layer(layer)?;
        let stored = l.stored_tile(band, tx, ty)?;
        if stored.codec != terrabake_format::Codec::Raw {
            return Err(Failure::new(
                TbStatus::TbWrongType,
                format!(
                    "{}: layer {}: tile ({tx}, {ty}) band {band} is compressed (zstd) and cannot be borrowed; read it with tb_read_window",
                    asset.asset.dir().display(),
                    l.entry().key(),
                ),
            ));
        }
        let align = l.entry().elem.size();
        if !(stored.bytes.as_ptr() as usize).is_multiple_of(align) {
            return Err(Failure::new(
                TbStatus::TbWrongType,
                format!(
                    "{}: layer {}: tile ({tx}, {ty}) band {band} is not aligned to its {align}-byte elements in the mapping; read it with tb_read_window",
                    asset.asset.dir().display(),
                    l.entry().key(),
                ),
            ));
        }
        *data = stored.bytes.as_ptr().cast();
        *bytes = stored.bytes.len();
        Ok(())
    })
}

/// Reads `window` of `band` of layer `layer` into `out` (`out_len` =
/// `width * height` floats, row-major), decoded to real values whatever the stored type and
/// quantisation (degrees for horizons, metres for heights), NaN for
/// nodata.
///
/// # Safety
/// `asset` is NULL or open; `out` is NULL or `out_len` writable floats.
#[no_mangle]
pub unsafe extern "C" fn tb_read_window(
    asset: *const TbAsset,
    layer: usize,
    band: u32,
    window: TbWindow,
    out: *mut f32,
    out_len: usize,
) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let asset = unsafe { arg(asset, "asset")? };
        if out.is_null() {
            return Err(Failure::new(TbStatus::TbNullArgument, "out is NULL"));
        }
        // SAFETY: the caller's promise: out_len writable floats.
        let values = unsafe { std::slice::from_raw_parts_mut(out, out_len) };
        let l = asset.layer(layer)?;
        let w = window;
        l.read_window_f32(band, [w.x0, w.y0, w.width, w.height], values)?;
        Ok(())
    })
}

/// The height at grid coordinates `(gx, gy)` (post `(x, y)` at `(x, y)`,
/// rows from the north edge), bilinear between the four posts around it, in
/// `*z`: NaN outside the DEM or beside nodata.
///
/// # Safety
/// `asset` is NULL or open; `z` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_height_bilinear(
    asset: *const TbAsset,
    gx: f64,
    gy: f64,
    z: *mut f32,
) -> TbStatus {
    // SAFETY: the caller's promise, passed on.
    unsafe { height_into(asset, z, |a| a.height()?.bilinear(gx, gy)) }
}

/// The height at CRS coordinates `(x, y)` of the asset's georeferencing,
/// bilinear, in `*z`: NaN outside the DEM, beside nodata, or where the asset
/// has no georeferencing.
///
/// # Safety
/// `asset` is NULL or open; `z` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_height_at_world(
    asset: *const TbAsset,
    x: f64,
    y: f64,
    z: *mut f32,
) -> TbStatus {
    // SAFETY: the caller's promise, passed on.
    unsafe { height_into(asset, z, |a| a.height_at_world(x, y)) }
}

/// `*z` from `height` (NaN where it gives none): the two height lookups.
///
/// # Safety
/// `asset` is NULL or open; `z` is NULL or writable.
unsafe fn height_into(
    asset: *const TbAsset,
    z: *mut f32,
    height: impl FnOnce(&Asset<Mmap>) -> Result<Option<f32>, Error>,
) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let (asset, z) = unsafe { (arg(asset, "asset")?, out(z, "z")?) };
        *z = height(&asset.asset)?.unwrap_or(f32::NAN);
        Ok(())
    })
}

/// Traces `ray` with `method` (a `tb_method`) into `*hit`: the first point
/// where it meets the terrain (exact on the two-triangle surface, the same
/// from every method), and what finding it cost. Hierarchical tracing needs
/// the pyramid layers and parametric the cone planes (`TB_NO_LAYER`
/// otherwise); another number is `TB_INVALID_ARGUMENT`.
///
/// # Safety
/// `asset` is NULL or open; `ray` is NULL or readable; `hit` is NULL or
/// writable.
#[no_mangle]
pub unsafe extern "C" fn tb_trace(
    asset: *const TbAsset,
    ray: *const TbRay,
    method: u32,
    hit: *mut TbHit,
) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let (asset, ray, hit) =
            unsafe { (arg(asset, "asset")?, arg(ray, "ray")?, out(hit, "hit")?) };
        let tracer = asset.tracer()?;
        // A number, not the enum: a C caller may pass any integer, and a
        // Rust enum with an undeclared value is undefined behaviour.
        let method = match method {
            m if m == TbMethod::TbIncremental as u32 => Method::Incremental,
            m if m == TbMethod::TbRuns as u32 => Method::Runs,
            m if m == TbMethod::TbHierarchical as u32 => Method::Hierarchical,
            m if m == TbMethod::TbParametric as u32 => Method::Parametric,
            m if m == TbMethod::TbBruteForce as u32 => Method::BruteForce,
            m => {
                return Err(Failure::new(
                    TbStatus::TbInvalidArgument,
                    format!("method {m} is not a tb_method (0 to 4)"),
                ))
            }
        };
        let missing = match method {
            Method::Hierarchical if !tracer.has_pyramid() => Some("pyramid (terrabake pyramid)"),
            Method::Parametric if !tracer.has_cones() => Some("cone planes (terrabake cones)"),
            _ => None,
        };
        if let Some(what) = missing {
            return Err(Failure::new(
                TbStatus::TbNoLayer,
                format!(
                    "{}: {} tracing needs the {what}",
                    asset.asset.dir().display(),
                    method.name()
                ),
            ));
        }
        let r = Ray {
            origin: ray.origin,
            dir: ray.dir,
            t_min: ray.t_min,
            t_max: ray.t_max,
        };
        let (found, counters) = tracer.trace(&r, method)?;
        *hit = TbHit {
            cells_tested: counters.cells,
            steps: counters.steps,
            ..TbHit::default()
        };
        if let Some(h) = found {
            hit.hit = 1;
            hit.cell = [h.cell.0, h.cell.1];
            hit.t = h.t;
            hit.point = h.point;
            hit.normal = h.normal;
        }
        Ok(())
    })
}

/// The fraction (0 to 1) of the sun's disc above the stored horizon of
/// post `(x, y)` (the horizon between the two nearest bands, linear), in
/// `*fraction`: sun shadows without tracing. NaN at nodata. Needs the
/// `horizon` layer (`TB_NO_LAYER` otherwise).
///
/// # Safety
/// `asset` is NULL or open; `fraction` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn tb_lit_fraction(
    asset: *const TbAsset,
    x: u32,
    y: u32,
    sun: TbSun,
    fraction: *mut f64,
) -> TbStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let (asset, fraction) = unsafe { (arg(asset, "asset")?, out(fraction, "fraction")?) };
        let TbSun {
            azimuth,
            elevation,
            radius,
        } = sun;
        if !(azimuth.is_finite() && elevation.is_finite() && radius >= 0.0) {
            return Err(Failure::new(
                TbStatus::TbInvalidArgument,
                format!("sun {{azimuth {azimuth}, elevation {elevation}, radius {radius}}}: give finite degrees and a radius >= 0"),
            ));
        }
        *fraction = asset
            .horizons()?
            .lit_fraction(x, y, azimuth, elevation, radius)?
            .unwrap_or(f64::NAN);
        Ok(())
    })
}

/// `TbLayer::elem`: the stored element types (the format's codes, which
/// a test holds equal to `ElemType`'s).
pub const TB_ELEM_F32: u32 = 1;
pub const TB_ELEM_U16: u32 = 2;
pub const TB_ELEM_U8: u32 = 3;
pub const TB_ELEM_I16: u32 = 4;
pub const TB_ELEM_F16: u32 = 5;
pub const TB_ELEM_U32: u32 = 6;

#[cfg(test)]
mod tests {
    use super::*;
    use terrabake_format::ElemType;

    #[test]
    fn element_codes_are_the_formats() {
        for (code, elem) in [
            (TB_ELEM_F32, ElemType::F32),
            (TB_ELEM_U16, ElemType::U16),
            (TB_ELEM_U8, ElemType::U8),
            (TB_ELEM_I16, ElemType::I16),
            (TB_ELEM_F16, ElemType::F16),
            (TB_ELEM_U32, ElemType::U32),
        ] {
            assert_eq!(code, elem as u32);
        }
    }
}
