//! `terrabake._native`: the Rust half of the Python package (`python/`).
//!
//! Thin by design: every value comes from the same functions the command
//! line calls (the format crate's reader and decoder, the horizon methods,
//! the sky sums, `recipe::bake`), so Python gets exactly the CLI's numbers.
//! What this file adds is the boundary: numpy arrays checked before any
//! work (dtype, shape, contiguity, size, all-NaN: `ValueError` naming the
//! problem), the GIL released while Rust works, a progress callback called
//! between batches of bands, and errors raised as `terrabake.Error` with the
//! CLI's message. A Rust panic is a bug, but it never reaches Python as
//! pyo3's `PanicException` (a `BaseException` that `except Exception`
//! misses): every entry point runs under [`guarded`], which raises it as
//! `terrabake.Error`, and a `bake` that panicked removes the asset it
//! created. The Python side (`terrabake/__init__.py`) adds the numpy and
//! xarray conventions: dtypes, masks, a scalar cell size, the curvature
//! rule, rioxarray's georeferencing.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::ndarray::{Array2, Array3, ArrayView2};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use rayon::prelude::*;
use terrabake::algorithms::horizon::sky::{svf_of_horizons, BandIntegrals};
use terrabake::algorithms::horizon::{band_bounds, band_horizons, plan_bands, BandOptions, Method};
use terrabake::terrain::{curvature_coefficient, Terrain, DEFAULT_REFRACTION};
use terrabake::ErrorKind;
use terrabake_format::{ElemType, Mmap, Tile};

pyo3::create_exception!(
    _native,
    Error,
    PyException,
    "A terrabake operation failed; the message is the command line's."
);

pyo3::create_exception!(
    _native,
    AssetError,
    Error,
    "The asset is missing, damaged, of another format version, or lacks a layer the call needs."
);
pyo3::create_exception!(
    _native,
    SourceError,
    Error,
    "The source DEM cannot be read: missing, unreadable, or a header or value terrabake refuses."
);
pyo3::create_exception!(
    _native,
    ParameterError,
    Error,
    "A parameter or budget that makes no sense, refused before any work."
);
pyo3::create_exception!(
    _native,
    ResourceError,
    Error,
    "The work needs more memory or disk than the machine has; refused before it starts."
);

/// The library's error as the exception of its kind, with the command
/// line's message.
fn raise(e: impl Into<terrabake::Error>) -> PyErr {
    let e: terrabake::Error = e.into();
    let message = e.to_string();
    match e.kind() {
        ErrorKind::Asset => AssetError::new_err(message),
        ErrorKind::Source => SourceError::new_err(message),
        ErrorKind::Parameters => ParameterError::new_err(message),
        ErrorKind::Resources => ResourceError::new_err(message),
        _ => Error::new_err(message),
    }
}

/// Runs `f`, turning a panic into `terrabake.Error` naming `what`.
fn guarded<T>(what: &str, f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(result) => result,
        Err(payload) => {
            let message = payload
                .downcast_ref::<&str>()
                .map(|s| (*s).to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Err(Error::new_err(format!(
                "{what}: an internal error, a bug in terrabake (please report it): {message}"
            )))
        }
    }
}

/// An asset open for reading: its layers as numpy arrays.
#[pyclass(frozen, module = "terrabake")]
struct Asset {
    inner: Arc<terrabake_format::Asset<Mmap>>,
}

/// Keeps a cached (decompressed) tile alive under a numpy view of it.
#[pyclass(frozen, module = "terrabake")]
struct TileOwner {
    _tile: Tile<'static, u8>,
}

#[pymethods]
impl Asset {
    /// The asset directory.
    #[getter]
    fn path(&self) -> PathBuf {
        self.inner.dir().to_path_buf()
    }

    /// Width and height of the DEM in posts.
    #[getter]
    fn shape(&self) -> (u32, u32) {
        let m = self.inner.manifest();
        (m.height, m.width)
    }

    /// Every layer: a dict of name, level, elem, bands, width, height,
    /// tile_size, codec, description and band_azimuths.
    #[getter]
    fn layers<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        for l in &self.inner.manifest().layers {
            let d = PyDict::new(py);
            d.set_item("name", &l.name)?;
            d.set_item("level", l.level)?;
            d.set_item("elem", l.elem.name())?;
            d.set_item("bands", l.bands)?;
            d.set_item("width", l.width)?;
            d.set_item("height", l.height)?;
            d.set_item("tile_size", l.tile_size)?;
            d.set_item("codec", format!("{:?}", l.codec).to_lowercase())?;
            d.set_item("description", &l.description)?;
            d.set_item("band_azimuths", l.band_azimuths.clone())?;
            list.append(d)?;
        }
        Ok(list)
    }

    /// The manifest as JSON text.
    fn manifest_json(&self) -> PyResult<String> {
        serde_json::to_string(self.inner.manifest()).map_err(|e| raise(anyhow::Error::new(e)))
    }

    /// Layer `name` at `level`, every band, decoded to float32 (quantised
    /// codes to degrees, nodata to NaN): shape (bands, height, width), or
    /// (height, width) for a layer of one band.
    #[pyo3(signature = (name, level = 0))]
    fn read<'py>(
        &self,
        py: Python<'py>,
        name: &str,
        level: u32,
    ) -> PyResult<Bound<'py, PyUntypedArray>> {
        guarded("read", || {
            let inner = self.inner.clone();
            let name = name.to_string();
            let values = py
                .detach(move || -> anyhow::Result<Array3<f32>> {
                    let layer = inner.layer(&name, level)?;
                    let (w, h, b) = (
                        layer.width() as usize,
                        layer.height() as usize,
                        layer.bands(),
                    );
                    let mut all = Array3::<f32>::zeros((b as usize, h, w));
                    for (band, mut plane) in all.outer_iter_mut().enumerate() {
                        let out = plane.as_slice_mut().expect("a fresh array is contiguous");
                        layer.read_rows_f32(band as u32, 0, out)?;
                    }
                    Ok(all)
                })
                .map_err(raise)?;
            if values.shape()[0] == 1 {
                let (h, w) = (values.shape()[1], values.shape()[2]);
                let plane = values
                    .into_shape_with_order((h, w))
                    .expect("one band is h x w values");
                return Ok(plane
                    .into_pyarray(py)
                    .into_any()
                    .cast_into::<PyUntypedArray>()?);
            }
            Ok(values
                .into_pyarray(py)
                .into_any()
                .cast_into::<PyUntypedArray>()?)
        })
    }

    /// The window of `rows` x `columns` posts from `(x0, y0)` of bands
    /// `bands` (a start and an end) of layer `name` at `level`, decoded to
    /// float32 as `read` decodes: shape (bands, rows, columns). Reads only
    /// the tiles the window touches: the xarray backend's one read.
    #[pyo3(signature = (name, level, bands, y0, x0, rows, columns))]
    #[allow(clippy::too_many_arguments)]
    fn read_window<'py>(
        &self,
        py: Python<'py>,
        name: &str,
        level: u32,
        bands: (u32, u32),
        y0: u32,
        x0: u32,
        rows: u32,
        columns: u32,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let layer = self.inner.layer(name, level).map_err(raise)?;
        let (b0, b1) = bands;
        let inside = b0 <= b1
            && b1 <= layer.bands()
            && x0
                .checked_add(columns)
                .is_some_and(|x1| x1 <= layer.width())
            && y0.checked_add(rows).is_some_and(|y1| y1 <= layer.height());
        if !inside {
            return Err(PyValueError::new_err(format!(
                "bands {b0}..{b1}, rows {y0}..+{rows}, columns {x0}..+{columns} are outside layer {} ({} bands, {} x {} posts)",
                layer.entry().key(),
                layer.bands(),
                layer.width(),
                layer.height()
            )));
        }
        let values = guarded("read_window", || {
            let inner = self.inner.clone();
            let name = name.to_string();
            py.detach(move || -> anyhow::Result<Array3<f32>> {
                let layer = inner.layer(&name, level)?;
                let shape = ((b1 - b0) as usize, rows as usize, columns as usize);
                let mut all = Array3::<f32>::zeros(shape);
                for (band, mut plane) in (b0..b1).zip(all.outer_iter_mut()) {
                    let out = plane.as_slice_mut().expect("a fresh array is contiguous");
                    if !out.is_empty() {
                        layer.read_window_f32(band, [x0, y0, columns, rows], out)?;
                    }
                }
                Ok(all)
            })
            .map_err(raise)
        })?;
        Ok(values.into_pyarray(py))
    }

    /// Tile `(tx, ty)` of band `band` of layer `name` at `level`, as stored
    /// (raw codes, not decoded; f16 as uint16 bits), read-only, without a
    /// copy: a view of the file's mapping (or of the decompressed tile in
    /// the reader's cache), which the array keeps alive.
    #[pyo3(signature = (name, level, tx, ty, band = 0))]
    fn tile<'py>(
        slf: &Bound<'py, Self>,
        name: &str,
        level: u32,
        tx: u32,
        ty: u32,
        band: u32,
    ) -> PyResult<Bound<'py, PyUntypedArray>> {
        let py = slf.py();
        let this = slf.get();
        let layer = this.inner.layer(name, level).map_err(raise)?;
        let t = layer.tile_size() as usize;
        if tx >= layer.tiles_x() || ty >= layer.tiles_y() || band >= layer.bands() {
            return Err(PyValueError::new_err(format!(
                "tile ({tx}, {ty}) band {band} is outside layer {} ({} x {} tiles, {} bands)",
                layer.entry().key(),
                layer.tiles_x(),
                layer.tiles_y(),
                layer.bands()
            )));
        }
        macro_rules! view {
            ($t:ty) => {{
                let tile = layer.tile::<$t>(band, tx, ty).map_err(raise)?;
                // SAFETY: the slice lives in the mapping owned by `this.inner`
                // (Borrowed) or in the cached buffer moved into `owner`
                // (Cached); `container` keeps that owner alive as long as the
                // array, and neither is ever written.
                let (slice, owner): (&[$t], Bound<'py, PyAny>) = match tile {
                    Tile::Borrowed(s) => {
                        // SAFETY: the mapping outlives the array (above).
                        let s: &'static [$t] = unsafe { std::mem::transmute(s) };
                        (s, slf.clone().into_any())
                    }
                    Tile::Cached(buf, _) => {
                        let cached: Tile<'static, u8> = Tile::Cached(buf, std::marker::PhantomData);
                        let bytes: &[u8] = &cached;
                        // SAFETY: the buffer moves into `owner`, which outlives
                        // the array (above); the reader aligned it for `$t`
                        // and its length is whole values.
                        let s: &'static [$t] = unsafe {
                            std::slice::from_raw_parts(
                                bytes.as_ptr().cast::<$t>(),
                                bytes.len() / std::mem::size_of::<$t>(),
                            )
                        };
                        (s, Bound::new(py, TileOwner { _tile: cached })?.into_any())
                    }
                };
                let view = ArrayView2::from_shape((t, t), slice)
                    .map_err(|e| PyValueError::new_err(e.to_string()))?;
                // SAFETY: `owner` keeps the viewed values alive and unwritten
                // as long as the array (above).
                let array = unsafe { PyArray2::<$t>::borrow_from_array(&view, owner) };
                array.getattr("flags")?.setattr("writeable", false)?;
                array.into_any().cast_into::<PyUntypedArray>()?
            }};
        }
        Ok(match layer.entry().elem {
            ElemType::F32 => view!(f32),
            ElemType::U16 | ElemType::F16 => view!(u16),
            ElemType::U8 => view!(u8),
            ElemType::I16 => view!(i16),
            ElemType::U32 => view!(u32),
            other => {
                return Err(PyValueError::new_err(format!(
                    "layer {:?} holds {other:?} values, which this package cannot view yet",
                    layer.entry().name
                )))
            }
        })
    }

    /// GDAL's six numbers (origin x, pixel width, row rotation, origin y,
    /// column rotation, pixel height) of the posts' pixels, or None: the
    /// pixel's corner, as GDAL reports it, also for point rasters (SRTM),
    /// whose posts sit at the pixels' centres.
    #[getter]
    fn transform(&self) -> Option<[f64; 6]> {
        Some(self.inner.manifest().georef.as_ref()?.corner_geotransform())
    }

    /// The CRS as WKT (WGS 84 and its UTM zones), `EPSG:n` for other EPSG
    /// codes, or None.
    #[getter]
    fn crs(&self) -> Option<String> {
        let g = self.inner.manifest().georef.as_ref()?;
        let epsg = g.epsg?;
        Some(terrabake::terrain::geo::wkt(epsg).unwrap_or_else(|| format!("EPSG:{epsg}")))
    }

    /// The compass azimuth (degrees clockwise from north) of each band of
    /// layer `name` at level 0; empty for layers without directions.
    fn band_azimuths(&self, name: &str) -> PyResult<Vec<f64>> {
        let layer = self.inner.layer(name, 0).map_err(raise)?;
        Ok(layer.entry().band_azimuths.clone())
    }

    /// What the GeoTIFF export says of layer `name` at `level`: its units,
    /// method, description, version and source, and each band's
    /// description (the attributes `to_xarray` gives).
    #[pyo3(signature = (name, level = 0))]
    fn attributes<'py>(
        &self,
        py: Python<'py>,
        name: &str,
        level: u32,
    ) -> PyResult<Bound<'py, PyDict>> {
        let layer = self.inner.layer(name, level).map_err(raise)?;
        let cog = guarded("attributes", || {
            terrabake::export::cog_for_layer(&self.inner, layer, &Default::default()).map_err(raise)
        })?;
        let d = PyDict::new(py);
        for (k, v) in &cog.metadata.dataset {
            d.set_item(k.to_lowercase(), v)?;
        }
        let first = cog.metadata.bands.first();
        d.set_item("units", first.map(|b| b.unit.clone()).unwrap_or_default())?;
        let descriptions: Vec<String> = cog
            .metadata
            .bands
            .iter()
            .map(|b| b.description.clone())
            .collect();
        d.set_item("band_descriptions", descriptions)?;
        Ok(d)
    }

    /// The CF attributes of layer `name` at `level`, as JSON: what the Zarr
    /// export writes on its variable (UDUNITS units, long_name, the stage
    /// and its parameters, each band's description) and, for quantised
    /// codes, their packing (scale_factor, add_offset, _FillValue). The
    /// xarray backend's attributes.
    #[pyo3(signature = (name, level = 0))]
    fn cf_attributes(&self, name: &str, level: u32) -> PyResult<String> {
        let layer = self.inner.layer(name, level).map_err(raise)?;
        guarded("cf_attributes", || {
            let (_, attrs) = terrabake::export::dataset::variable_attributes(&self.inner, layer)
                .map_err(raise)?;
            serde_json::to_string(&attrs).map_err(|e| raise(anyhow::Error::new(e)))
        })
    }

    /// The layer as an `xarray.DataArray` (dims band, y, x; coordinates
    /// from the transform at pixel centres, azimuths for directional
    /// layers; attributes from `attributes`). Needs xarray.
    #[pyo3(signature = (name, level = 0))]
    fn to_xarray<'py>(
        slf: &Bound<'py, Self>,
        name: &str,
        level: u32,
    ) -> PyResult<Bound<'py, PyAny>> {
        let py = slf.py();
        py.import("terrabake")?
            .getattr("to_xarray")?
            .call1((slf, name, level))
    }

    fn __repr__(&self) -> String {
        let m = self.inner.manifest();
        format!(
            "terrabake.Asset({:?}, {} x {} posts, {} layers)",
            self.inner.dir(),
            m.width,
            m.height,
            m.layers.len()
        )
    }
}

/// Opens an asset directory (validated, memory-mapped).
#[pyfunction]
fn open(path: PathBuf) -> PyResult<Asset> {
    guarded("open", || {
        let inner = terrabake::stage::asset::open(&path).map_err(raise)?;
        Ok(Asset {
            inner: Arc::new(inner),
        })
    })
}

/// The heights of a numpy DEM, checked: float32 or float64, 2-D,
/// C-contiguous, not empty, not all NaN, and small enough that `bands`
/// bands of angles fit the memory available (refused before the heights
/// are copied, as the CLI refuses, rather than killed half way).
fn dem_of(dem: &Bound<'_, PyAny>, bands: usize) -> PyResult<(Vec<f32>, usize, usize)> {
    let array = dem.cast::<PyUntypedArray>().map_err(|_| {
        PyValueError::new_err(format!(
            "dem: expected a numpy array, got {}",
            dem.get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default()
        ))
    })?;
    if array.ndim() != 2 {
        return Err(PyValueError::new_err(format!(
            "dem: expected a 2-D array (rows, columns), got {} dimensions",
            array.ndim()
        )));
    }
    if !array.is_c_contiguous() {
        return Err(PyValueError::new_err(
            "dem: the array is not C-contiguous; pass numpy.ascontiguousarray(dem)",
        ));
    }
    let (h, w) = (array.shape()[0], array.shape()[1]);
    if h < 2 || w < 2 {
        return Err(PyValueError::new_err(format!(
            "dem: {h} x {w} posts; a DEM needs at least 2 x 2"
        )));
    }
    // The heights, the angles of every band, and a band in flight per core.
    let held = 1 + bands as u64 + rayon::current_num_threads() as u64;
    terrabake::plumbing::resources::ensure_memory(
        (w * h) as u64 * 4 * held,
        &format!("horizons of a {w} x {h} DEM in {bands} directions"),
    )
    .map_err(raise)?;
    // A copy: the GIL is released while Rust reads the heights, and Python
    // code on another thread could write the array meanwhile.
    let z: Vec<f32> = if let Ok(a) = dem.cast::<PyArray2<f32>>() {
        a.readonly().as_slice()?.to_vec()
    } else if let Ok(a) = dem.cast::<PyArray2<f64>>() {
        a.readonly().as_slice()?.iter().map(|&v| v as f32).collect()
    } else {
        return Err(PyValueError::new_err(format!(
            "dem: expected float32 or float64 heights, got dtype {}",
            array.dtype()
        )));
    };
    if z.iter().all(|v| v.is_nan()) {
        return Err(PyValueError::new_err("dem: every post is NaN (nodata)"));
    }
    Ok((z, w, h))
}

fn method_of(method: &str) -> PyResult<Method> {
    method
        .parse::<Method>()
        .map_err(|e| PyValueError::new_err(format!("method: {e}")))
}

fn cell_size_of((dx, dy): (f64, f64)) -> PyResult<(f64, f64)> {
    if !(dx.is_finite() && dy.is_finite() && dx > 0.0 && dy > 0.0) {
        return Err(PyValueError::new_err(format!(
            "cell_size: ({dx}, {dy}) must be two positive metres"
        )));
    }
    Ok((dx, dy))
}

/// What both compute functions share: the DEM, its bands, their horizons.
struct Horizons {
    z: Vec<f32>,
    w: usize,
    h: usize,
    azimuths: Vec<f64>,
    angles: Vec<Vec<f32>>,
}

#[allow(clippy::too_many_arguments)]
fn compute_horizons(
    py: Python<'_>,
    dem: &Bound<'_, PyAny>,
    cell_size: (f64, f64),
    sectors: usize,
    method: &str,
    max_distance: Option<f64>,
    curvature: bool,
    refraction: f64,
    progress: Option<&Bound<'_, PyAny>>,
) -> PyResult<Horizons> {
    // A panic (a bug) is raised as terrabake.Error, not PanicException.
    guarded("horizons", || {
        let method = method_of(method)?;
        // The stage's own checks of what it shares with this call (the sector
        // count, the distance), with the CLI's messages.
        let stage = terrabake::stages::horizons::HorizonsStage {
            sectors,
            method,
            sight: terrabake::stage::sight::SightLines {
                max_distance,
                curvature: Some(curvature),
                refraction,
            },
            ..Default::default()
        };
        terrabake::stage::Stage::check(&stage)
            .map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
        let (z, w, h) = dem_of(dem, sectors)?;
        let (dx, dy) = cell_size_of(cell_size)?;
        if let Some(p) = progress {
            if !p.is_callable() {
                return Err(PyValueError::new_err(
                    "progress: expected a callable(done, total)",
                ));
            }
        }
        let curvature = if curvature {
            curvature_coefficient(refraction)
        } else {
            0.0
        };
        let bands = plan_bands(method, sectors, dx, dy, None);
        let opts = BandOptions {
            max_distance,
            narrow_check: true,
        };
        // Bands in batches of four per core, so that cheap bands (the axes,
        // one vertex a step) and dear ones (oblique lines, several crossings a
        // step) share the cores evenly; the callback and Ctrl-C are looked at
        // between batches.
        let mut angles = Vec::with_capacity(bands.len());
        let threads = rayon::current_num_threads().max(1);
        for batch in bands.chunks(threads * 4) {
            let done = py.detach(|| {
                let mut terrain = Terrain::new(&z, w, h, dx, dy);
                terrain.curvature = curvature;
                batch
                    .par_iter()
                    .map(|band| band_horizons(&terrain, band, opts).0)
                    .collect::<Vec<_>>()
            });
            angles.extend(done);
            py.check_signals()?;
            if let Some(p) = progress {
                for i in angles.len() + 1 - batch.len()..=angles.len() {
                    p.call1((i, bands.len()))?;
                }
            }
        }
        Ok(Horizons {
            z,
            w,
            h,
            azimuths: bands.iter().map(|b| b.azimuth).collect(),
            angles,
        })
    })
}

/// `horizons`' result: angles (S, H, W) and the bands' azimuths.
type AnglesAndAzimuths<'py> = (Bound<'py, PyArray3<f32>>, Bound<'py, PyArray1<f64>>);

/// Horizon angles of a numpy DEM: (angles, band_azimuths), angles float32
/// degrees of shape (sectors, rows, columns), NaN where the DEM is.
#[pyfunction]
#[pyo3(signature = (dem, cell_size, sectors = 16, method = "line", max_distance = None, curvature = false, refraction = DEFAULT_REFRACTION, progress = None))]
#[allow(clippy::too_many_arguments)]
fn horizons<'py>(
    py: Python<'py>,
    dem: &Bound<'py, PyAny>,
    cell_size: (f64, f64),
    sectors: usize,
    method: &str,
    max_distance: Option<f64>,
    curvature: bool,
    refraction: f64,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<AnglesAndAzimuths<'py>> {
    let hz = compute_horizons(
        py,
        dem,
        cell_size,
        sectors,
        method,
        max_distance,
        curvature,
        refraction,
        progress,
    )?;
    let (s, h, w) = (hz.angles.len(), hz.h, hz.w);
    let flat: Vec<f32> = hz.angles.into_iter().flatten().collect();
    let angles = Array3::from_shape_vec((s, h, w), flat).expect("S x H x W values");
    Ok((angles.into_pyarray(py), hz.azimuths.into_pyarray(py)))
}

/// The sky-view factor (over the horizontal, Zakšek's) of a numpy DEM from
/// its horizons, as the `sky` stage computes it: float32 (rows, columns).
#[pyfunction]
#[pyo3(signature = (dem, cell_size, sectors = 16, method = "line", max_distance = None, curvature = false, refraction = DEFAULT_REFRACTION, progress = None))]
#[allow(clippy::too_many_arguments)]
fn sky_view_factor<'py>(
    py: Python<'py>,
    dem: &Bound<'py, PyAny>,
    cell_size: (f64, f64),
    sectors: usize,
    method: &str,
    max_distance: Option<f64>,
    curvature: bool,
    refraction: f64,
    progress: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let hz = compute_horizons(
        py,
        dem,
        cell_size,
        sectors,
        method,
        max_distance,
        curvature,
        refraction,
        progress,
    )?;
    let svf = guarded("sky_view_factor", || {
        Ok(py.detach(|| {
            let integrals: Vec<BandIntegrals> = band_bounds(&hz.azimuths)
                .into_iter()
                .map(|(lo, hi)| BandIntegrals::new(lo, hi))
                .collect();
            // The svf of a post is its horizons' alone (the sky stage's
            // normals enter only svf_cosine); nodata posts stay NaN.
            let values: Vec<f32> = (0..hz.w * hz.h)
                .into_par_iter()
                .map(|i| {
                    if hz.z[i].is_nan() {
                        return f32::NAN;
                    }
                    svf_of_horizons(&integrals, hz.angles.iter().map(|band| f64::from(band[i])))
                        as f32
                })
                .collect();
            Array2::from_shape_vec((hz.h, hz.w), values).expect("H x W values")
        }))
    })?;
    Ok(svf.into_pyarray(py))
}

/// Bakes `src` (a DEM file) into the asset `out`, as `terrabake bake`
/// does: with a recipe file, or planned from a budget (`"horizon=0.5"`,
/// the CLI's --budget syntax) and needs (`"horizons,svf"`).
/// `progress(stage, done, total)` is called as each stage is committed; an
/// exception it raises stops the bake there (what is committed stays, and
/// the same call resumes from it). A bake that panics (a bug) raises
/// `terrabake.Error` and removes the asset if this call created it, as a
/// failed planned bake does.
#[pyfunction]
#[pyo3(signature = (src, out, recipe = None, budget = None, needs = None, progress = None))]
fn bake(
    py: Python<'_>,
    src: PathBuf,
    out: PathBuf,
    recipe: Option<PathBuf>,
    budget: Option<String>,
    needs: Option<String>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    if progress.as_ref().is_some_and(|p| !p.is_callable()) {
        return Err(PyValueError::new_err(
            "progress: expected a callable(stage, done, total)",
        ));
    }
    let progress = progress.map(Bound::unbind);
    let recipe = match (recipe, budget) {
        (Some(_), Some(_)) => {
            return Err(PyValueError::new_err("give a recipe or a budget, not both"))
        }
        (Some(r), None) => terrabake::bake::recipe::Recipe::load(&r).map_err(raise)?,
        (None, budget) => {
            let plan = match budget {
                None => None,
                Some(b) => Some(terrabake::plan::budget::Request {
                    budget: b
                        .parse()
                        .map_err(|e| PyValueError::new_err(format!("budget: {e}")))?,
                    needs: match needs {
                        Some(n) => n
                            .parse()
                            .map_err(|e| PyValueError::new_err(format!("needs: {e}")))?,
                        None => Default::default(),
                    },
                    ..Default::default()
                }),
            };
            terrabake::bake::recipe::Recipe {
                plan,
                ..Default::default()
            }
        }
    };
    // The callback's exception, kept to be raised as itself.
    let mut raised: Option<PyErr> = None;
    let created = !out.exists();
    let result = guarded("bake", || {
        Ok(py.detach(|| {
            terrabake::bake::recipe::bake_with(
                &src,
                &out,
                &recipe,
                terrabake::stage::asset::Wait::unless(false),
                terrabake::plumbing::progress::Progress::new(true),
                &mut |outcome, done, total| {
                    let Some(cb) = &progress else { return Ok(()) };
                    Python::attach(|py| {
                        let called = py
                            .check_signals()
                            .and_then(|()| cb.call1(py, (outcome.stage.as_str(), done, total)));
                        match called {
                            Ok(_) => Ok(()),
                            Err(e) => {
                                raised = Some(e);
                                Err(anyhow::anyhow!("stopped by the progress callback").into())
                            }
                        }
                    })
                },
            )
        }))
    });
    if result.is_err() && created {
        // Only a panic gets here; the bake's own errors are in Ok(Err(_)).
        let _ = std::fs::remove_dir_all(&out);
    }
    let result = result?;
    if let Some(e) = raised {
        return Err(e);
    }
    let outcomes = result.map_err(raise)?;
    serde_json::to_string(&outcomes).map_err(|e| raise(anyhow::Error::new(e)))
}

/// The horizon profile around each of `points` (X,Y in `crs`: "native",
/// "lonlat" or "grid"), as `terrabake profile` computes one: the exact
/// sight line at every `step` degrees from north, clockwise. Returns per
/// point `(post, azimuths, horizons, distances)`: the (column, row) used,
/// float64 compass degrees, float32 degrees (-90 where nothing lies
/// ahead), float64 metres (NaN there).
#[pyfunction]
#[pyo3(signature = (path, points, crs = "native", step = 1.0, max_distance = None, curvature = None, refraction = DEFAULT_REFRACTION))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn profiles<'py>(
    py: Python<'py>,
    path: PathBuf,
    points: Vec<(f64, f64)>,
    crs: &str,
    step: f64,
    max_distance: Option<f64>,
    curvature: Option<bool>,
    refraction: f64,
) -> PyResult<
    Vec<(
        (usize, usize),
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<f32>>,
        Bound<'py, PyArray1<f64>>,
    )>,
> {
    use terrabake::stages::viewshed::Crs;
    let crs = match crs {
        "native" => Crs::Native,
        "lonlat" => Crs::Lonlat,
        "grid" => Crs::Grid,
        _ => {
            return Err(PyValueError::new_err(format!(
                "crs={crs:?}: give native, lonlat or grid"
            )))
        }
    };
    let sight = terrabake::stage::sight::SightLines {
        max_distance,
        curvature,
        refraction,
    };
    let all = guarded("profile", || {
        Ok(py.detach(|| -> terrabake::Result<_> {
            let asset = terrabake::stage::asset::open(&path)?;
            terrabake::present::profile::profiles(&asset, &points, crs, step, &sight)
        }))
    })?
    .map_err(raise)?;
    Ok(all
        .into_iter()
        .map(|p| {
            let azimuths: Vec<f64> = p.points.iter().map(|q| q.azimuth_deg).collect();
            let horizons: Vec<f32> = p.points.iter().map(|q| q.horizon_deg).collect();
            let distances: Vec<f64> = p
                .points
                .iter()
                .map(|q| q.distance_m.unwrap_or(f64::NAN))
                .collect();
            (
                p.post,
                azimuths.into_pyarray(py),
                horizons.into_pyarray(py),
                distances.into_pyarray(py),
            )
        })
        .collect())
}

/// Runs `work` (given the CLI's wait for the writer lock and no progress
/// bars) with the GIL released, under [`guarded`]; its stage records as
/// JSON. What the bakes without a callback share.
fn records_of(
    py: Python<'_>,
    what: &str,
    work: impl FnOnce(
            terrabake::stage::asset::Wait,
            terrabake::plumbing::progress::Progress,
        ) -> terrabake::Result<Vec<terrabake::stage::StageOutcome>>
        + Send,
) -> PyResult<String> {
    let outcomes = guarded(what, || {
        Ok(py.detach(|| {
            work(
                terrabake::stage::asset::Wait::unless(false),
                terrabake::plumbing::progress::Progress::new(true),
            )
        }))
    })?
    .map_err(raise)?;
    serde_json::to_string(&outcomes).map_err(|e| raise(anyhow::Error::new(e)))
}

/// Bakes part `part` of `parts` of `src` into the asset `out` with the
/// recipe `recipe`, as `terrabake bake SRC -o OUT --recipe R --parts N
/// --part I`: what one task of a partitioned bake runs, on any machine that
/// sees `out`. Returns the part's stage records as JSON.
#[pyfunction]
#[pyo3(signature = (src, out, recipe, part, parts))]
fn bake_part(
    py: Python<'_>,
    src: PathBuf,
    out: PathBuf,
    recipe: PathBuf,
    part: u32,
    parts: u32,
) -> PyResult<String> {
    let recipe = terrabake::bake::recipe::Recipe::load(&recipe).map_err(raise)?;
    let part = terrabake::bake::partition::Part::new(part, parts).map_err(raise)?;
    records_of(py, "bake_part", |wait, progress| {
        terrabake::bake::partition::bake_part(&src, &out, &recipe, part, wait, progress)
    })
}

/// Joins the baked parts of the asset `out` into it, as `terrabake
/// assemble OUT`; returns the stage records as JSON.
#[pyfunction]
fn assemble(py: Python<'_>, out: PathBuf) -> PyResult<String> {
    records_of(py, "assemble", |wait, progress| {
        terrabake::bake::partition::assemble(&out, false, wait, progress)
    })
}

/// Runs the solar stage on the asset at `path` (after the sky stage where
/// it has no `svf_cosine`), as `terrabake solar` does; `params` is the
/// stage's parameters as JSON, a recipe's keys (unknown keys refused).
/// Returns the stage records as JSON.
#[pyfunction]
#[pyo3(signature = (path, params, force = false))]
fn solar(py: Python<'_>, path: PathBuf, params: &str, force: bool) -> PyResult<String> {
    let stage: terrabake::stages::solar::SolarStage =
        serde_json::from_str(params).map_err(|e| ParameterError::new_err(format!("solar: {e}")))?;
    records_of(py, "solar", |wait, progress| {
        terrabake::bake::recipe::solar_after_sky(&path, &stage, force, wait, progress)
    })
}

/// HORAYZON's terrain correction factor for direct shortwave of the asset
/// at `path`, one plane per `(azimuth, elevation)` in `suns` (true
/// azimuth, degrees): float32 (suns, rows, columns), as `terrabake solar
/// --sun` writes it.
#[pyfunction]
#[pyo3(signature = (path, suns, per_horizontal_area = false))]
fn direct_correction<'py>(
    py: Python<'py>,
    path: PathBuf,
    suns: Vec<(f64, f64)>,
    per_horizontal_area: bool,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let suns = suns
        .iter()
        .map(|&(az, el)| {
            terrabake::stage::args::parse_sun(&format!("{az},{el}"))
                .map_err(|e| PyValueError::new_err(format!("suns: {e}")))
        })
        .collect::<PyResult<Vec<_>>>()?;
    let values = guarded("direct_correction", || {
        Ok(py.detach(|| -> terrabake::Result<Array3<f32>> {
            let asset = terrabake::stage::asset::open(&path)?;
            let mut correction = terrabake::export::correction::Correction::new(&asset)?;
            correction.per_horizontal_area = per_horizontal_area;
            let m = asset.manifest();
            let (h, w) = (m.height as usize, m.width as usize);
            let mut all = Array3::<f32>::zeros((suns.len(), h, w));
            for (sun, mut plane) in suns.iter().zip(all.outer_iter_mut()) {
                let out = plane.as_slice_mut().expect("a fresh array is contiguous");
                correction.rows(*sun, 0, out)?;
            }
            Ok(all)
        }))
    })?
    .map_err(raise)?;
    Ok(values.into_pyarray(py))
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Asset>()?;
    m.add_function(wrap_pyfunction!(open, m)?)?;
    m.add_function(wrap_pyfunction!(horizons, m)?)?;
    m.add_function(wrap_pyfunction!(sky_view_factor, m)?)?;
    m.add_function(wrap_pyfunction!(bake, m)?)?;
    m.add_function(wrap_pyfunction!(profiles, m)?)?;
    m.add_function(wrap_pyfunction!(bake_part, m)?)?;
    m.add_function(wrap_pyfunction!(assemble, m)?)?;
    m.add_function(wrap_pyfunction!(solar, m)?)?;
    m.add_function(wrap_pyfunction!(direct_correction, m)?)?;
    m.add("Error", m.py().get_type::<Error>())?;
    m.add("AssetError", m.py().get_type::<AssetError>())?;
    m.add("SourceError", m.py().get_type::<SourceError>())?;
    m.add("ParameterError", m.py().get_type::<ParameterError>())?;
    m.add("ResourceError", m.py().get_type::<ResourceError>())?;
    // The exception's first name, kept: `except terrabake.TerrabakeError` works.
    m.add("TerrabakeError", m.py().get_type::<Error>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
