from os import PathLike
from typing import Any, Callable, Optional, Union

import numpy as np
import numpy.typing as npt

__version__: str

Path = Union[str, PathLike[str]]
Progress = Callable[[int, int], Any]

class Error(Exception):
    """A terrabake operation failed; the message is the command line's."""

class AssetError(Error):
    """The asset is missing, damaged, of another format version, or lacks a layer the call needs."""

class SourceError(Error):
    """The source DEM cannot be read: missing, unreadable, or a header or value terrabake refuses."""

class ParameterError(Error):
    """A parameter or budget that makes no sense, refused before any work."""

class ResourceError(Error):
    """The work needs more memory or disk than the machine has; refused before it starts."""

TerrabakeError = Error

class Asset:
    """An asset open for reading (validated, memory-mapped)."""

    @property
    def path(self) -> str: ...
    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of the DEM."""
    @property
    def layers(self) -> list[dict[str, Any]]:
        """name, level, elem, bands, width, height, tile_size, codec, description, band_azimuths."""
    @property
    def transform(self) -> Optional[tuple[float, float, float, float, float, float]]:
        """GDAL's geotransform of the posts' pixels, or None."""
    @property
    def crs(self) -> Optional[str]:
        """WKT (WGS 84 and its UTM zones), EPSG:n, or None."""
    def read(self, name: str, level: int = 0) -> npt.NDArray[np.float32]:
        """Every band decoded to float32, NaN for nodata: (bands, rows, columns),
        or (rows, columns) for a layer of one band."""
    def read_window(
        self, name: str, level: int, bands: tuple[int, int], y0: int, x0: int, rows: int, columns: int
    ) -> npt.NDArray[np.float32]:
        """Bands ``bands[0]..bands[1]`` of a window, decoded: (bands, rows, columns)."""
    def tile(self, name: str, level: int, tx: int, ty: int, band: int = 0) -> npt.NDArray[Any]:
        """A read-only view of a stored tile (raw codes), without a copy."""
    def band_azimuths(self, name: str) -> list[float]:
        """Compass azimuth of each band (degrees clockwise from north)."""
    def attributes(self, name: str, level: int = 0) -> dict[str, Any]:
        """Units, method, description, version and source of a layer."""
    def cf_attributes(self, name: str, level: int = 0) -> str:
        """The layer's CF attributes as the Zarr export writes them, as JSON."""
    def to_xarray(self, name: str, level: int = 0) -> Any:
        """The layer as an xarray.DataArray (needs xarray)."""
    def manifest_json(self) -> str: ...

def open(path: Path) -> Asset:
    """Opens an asset directory."""

# The native halves of terrabake.horizons and terrabake.sky_view_factor:
# C-contiguous float32/float64 heights, the cell size as a pair, curvature
# decided (the package's wrappers apply the command line's rule).
def horizons(
    dem: npt.NDArray[np.floating[Any]],
    cell_size: tuple[float, float],
    sectors: int = 16,
    method: str = "line",
    max_distance: Optional[float] = None,
    curvature: bool = False,
    refraction: float = 0.13,
    progress: Optional[Progress] = None,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float64]]:
    """(angles, band_azimuths): angles in degrees, (sectors, rows, columns)."""

def sky_view_factor(
    dem: npt.NDArray[np.floating[Any]],
    cell_size: tuple[float, float],
    sectors: int = 16,
    method: str = "line",
    max_distance: Optional[float] = None,
    curvature: bool = False,
    refraction: float = 0.13,
    progress: Optional[Progress] = None,
) -> npt.NDArray[np.float32]:
    """Sky-view factor over the horizontal (0-1), (rows, columns)."""

def bake(
    src: Path,
    out: Path,
    recipe: Optional[Path] = None,
    budget: Optional[str] = None,
    needs: Optional[str] = None,
    progress: Optional[Callable[[str, int, int], Any]] = None,
) -> str:
    """Bakes a DEM into an asset, as `terrabake bake`; returns the stages' outcomes as JSON.

    progress(stage, done, total) is called as each stage is committed; an
    exception it raises stops the bake there (committed stages stay). A bake
    that fails otherwise raises Error, and a planned one removes the asset it
    created."""


def profiles(
    path: Path,
    points: list[tuple[float, float]],
    crs: str = "native",
    step: float = 1.0,
    max_distance: Optional[float] = None,
    curvature: Optional[bool] = None,
    refraction: float = 0.13,
) -> list[tuple[tuple[int, int], npt.NDArray[np.float64], npt.NDArray[np.float32], npt.NDArray[np.float64]]]:
    """Per point: the post, azimuths, horizons and distances of its exact profile."""

def bake_part(src: Path, out: Path, recipe: Path, part: int, parts: int) -> str:
    """Part `part` of `parts` of a partitioned bake; its records as JSON."""

def assemble(out: Path) -> str:
    """Joins a partitioned bake's parts into the asset; the records as JSON."""

def solar(path: str, params: str, force: bool = False) -> str:
    """Runs the solar stage (after sky where needed); params and the result are JSON."""

def direct_correction(
    path: str, suns: list[tuple[float, float]], per_horizontal_area: bool = False
) -> npt.NDArray[np.float32]:
    """HORAYZON's direct-shortwave correction factor, (suns, rows, columns)."""
