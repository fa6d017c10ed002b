//! Layers out of an asset: Cloud-Optimized GeoTIFF ([`crate::io::cog`]:
//! georeferencing, nodata and band descriptions kept, so GDAL and QGIS read
//! back the same geotransform and know each band's azimuth), OpenEXR (float,
//! for engines), PNG previews for people, and Zarr v3 ([`zarr`]) and
//! NetCDF-4 ([`netcdf`]): several layers as one CF dataset, [`dataset`],
//! for xarray, the cloud tools and the NetCDF world.
//!
//! Every writer here goes through [`write_atomically`] (a directory through
//! [`crate::plumbing::output::write_dir_atomically`]): a failed export
//! never leaves a half-written file where a good one stood.

pub mod correction;
pub mod dataset;
pub mod engine;
pub mod grass;
pub mod hdf5;
pub mod netcdf;
pub mod texture;
pub mod viewshed;
pub mod zarr;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{anyhow, Result};
use terrabake_format::{Asset, Layer, Mmap};

use crate::error::bail;
use crate::io::cog::{Cog, Compression, GeoTags, Resampling};
use crate::plumbing::output::write_atomically;
use crate::plumbing::progress::Progress;
use crate::present::legend::{Legend, Ramp, Stretch};
use crate::stage::session::{Run, Session};

/// The command that makes layer `name`, for a message about its absence.
fn stage_making(name: &str) -> Option<&'static str> {
    use terrabake_format::layers as l;
    Some(match name {
        l::PYRAMID_MAX | l::PYRAMID_MIN => "pyramid",
        l::CONE_APEX | l::CONE_SLOPE => "cones",
        l::HORIZON | l::HORIZON_DISTANCE => "horizons",
        l::SVF | l::SVF_COSINE | l::OPENNESS | l::HORIZON_EDGE => "sky",
        l::VIEWSHED | l::VIEWSHED_ANGLE => "viewshed",
        l::TOTAL_VIEWSHED => "total-viewshed",
        _ => return None,
    })
}

/// Output kinds, by file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportKind {
    GeoTiff,
    Exr,
    Png,
    Ktx2,
    Zarr,
    NetCdf,
}

impl ExportKind {
    pub(crate) fn from_path(path: &Path) -> Result<Self> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("tif" | "tiff") => Ok(Self::GeoTiff),
            Some("exr") => Ok(Self::Exr),
            Some("png") => Ok(Self::Png),
            Some("ktx2") => Ok(Self::Ktx2),
            Some("zarr") => Ok(Self::Zarr),
            Some("nc") => Ok(Self::NetCdf),
            _ => bail!(
                "{}: export writes .tif, .exr, .png, .ktx2, .zarr or .nc",
                path.display()
            ),
        }
    }
}

/// How a PNG preview colours a layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PngStyle {
    /// 16-bit gray, no legend: a heightmap for engines, not a picture.
    /// Heights from min (black) to max (white); other layers from their 1st
    /// to their 99th percentile.
    Gray,
    /// Hypsometric tint (green lowlands to brown and white peaks) times a
    /// hillshade lit from the north-west at 45 degrees, with a legend;
    /// nodata is transparent. The default for heights.
    Relief,
    /// Viridis from the 1st to the 99th percentile, with a legend; nodata
    /// is transparent. The default for every other layer.
    Ramp,
}

impl PngStyle {
    /// The style for `layer` when none is asked for.
    pub(crate) fn default_for(layer: &str) -> Self {
        if is_height_like(layer) {
            PngStyle::Relief
        } else {
            PngStyle::Ramp
        }
    }
}

/// Heights and their pyramids: metres of the DEM, stretched over its range.
fn is_height_like(layer: &str) -> bool {
    layer == terrabake_format::HEIGHT_LAYER || layer.starts_with("pyramid")
}

/// What a layer's map shows, with its unit, for legends.
pub(crate) fn layer_title(layer: &str, band: u32, bands: u32) -> String {
    use terrabake_format::layers as l;
    let band = if bands > 1 {
        format!(", band {band} of {bands}")
    } else {
        String::new()
    };
    match layer {
        l::HEIGHT => "height (m)".into(),
        l::PYRAMID_MAX => "pyramid: tallest corner below (m)".into(),
        l::PYRAMID_MIN => "pyramid: lowest corner below (m)".into(),
        l::CONE_APEX => "cone apex height (m)".into(),
        l::CONE_SLOPE => "cone slope (m across per m up)".into(),
        l::HORIZON => format!("horizon angle (degrees){band}"),
        l::HORIZON_DISTANCE => format!("distance to the horizon (m){band}"),
        l::SVF => "sky-view factor (0-1)".into(),
        l::SVF_COSINE => "cosine sky-view factor (0-1)".into(),
        l::OPENNESS => "positive openness (degrees)".into(),
        l::HORIZON_EDGE => "bands open past the DEM's edge".into(),
        l::VIEWSHED => format!("seen from the observer (1 seen, 0 hidden){band}"),
        l::VIEWSHED_ANGLE => format!("elevation angle from the observer (degrees){band}"),
        l::TOTAL_VIEWSHED => "total viewshed: area seen (m2)".into(),
        l::SOLAR_GLOBAL => format!("global irradiation (Wh/m2 per day){band}"),
        l::SOLAR_BEAM => format!("beam irradiation (Wh/m2 per day){band}"),
        l::SOLAR_DIFFUSE => format!("diffuse irradiation (Wh/m2 per day){band}"),
        l::SOLAR_REFLECTED => format!("reflected irradiation (Wh/m2 per day){band}"),
        l::SUN_HOURS => format!("sun hours (h per day){band}"),
        other => format!("{other}{band}"),
    }
}

/// How a layer becomes a GeoTIFF (`export --compress/--tile/--resampling`).
#[derive(Debug, Clone, clap::Args)]
pub struct TiffOptions {
    /// GeoTIFF compression, after the floating-point predictor.
    #[arg(long, value_enum, default_value = "deflate")]
    pub compress: Compression,
    /// GeoTIFF tile edge in pixels (a multiple of 16).
    #[arg(long, default_value_t = crate::io::cog::DEFAULT_TILE, value_parser = clap::value_parser!(u32).range(16..=4096))]
    pub tile: u32,
    /// How the GeoTIFF's overviews are made: `nearest` (the default for angles, codes and
    /// counts) or `average` (the default for heights, sky-view factors and areas).
    #[arg(long, value_enum)]
    pub resampling: Option<Resampling>,
    /// Memory the GeoTIFF writer may hold, MiB (a tile row per overview level: 8 GB for a
    /// 4,000,000-post-wide layer in tiles of 256); a layer that needs more is refused before
    /// anything is written (default: the memory available).
    #[arg(long = "max-memory", value_name = "MIB", value_parser = crate::stage::mib::parse)]
    pub max_memory: Option<u64>,
}

impl Default for TiffOptions {
    fn default() -> Self {
        Self {
            compress: Compression::default(),
            tile: crate::io::cog::DEFAULT_TILE,
            resampling: None,
            max_memory: None,
        }
    }
}

/// Overviews that suit a layer: averages of continuous quantities, the
/// nearest post for angles, codes and counts.
pub(crate) fn default_resampling(layer: &str) -> Resampling {
    use terrabake_format::layers as l;
    if is_height_like(layer) || [l::SVF, l::SVF_COSINE, l::TOTAL_VIEWSHED].contains(&layer) {
        Resampling::Average
    } else {
        Resampling::Nearest
    }
}

/// The COG for a layer: georeferencing at its level, nodata (the source's
/// value for heights, NaN for the rest: a real horizon or svf could equal
/// the source's), and GDAL metadata that says what each band is.
pub fn cog_for_layer(
    asset: &Asset<Mmap>,
    layer: &Layer<Mmap>,
    tiff: &TiffOptions,
) -> crate::Result<Cog> {
    let manifest = asset.manifest();
    let entry = layer.entry();
    let name = entry.name.as_str();
    let bands = u16::try_from(layer.bands())
        .map_err(|_| anyhow!("{} bands is more than TIFF holds", layer.bands()))?;
    let nodata = Some(
        match (&manifest.nodata.source_value, is_height_like(name)) {
            (Some(v), true) => v.clone(),
            _ => "nan".into(),
        },
    );
    let stage = manifest
        .provenance
        .stages
        .iter()
        .rev()
        .find(|s| s.outputs.contains(&entry.key()));
    let param = |key: &str| {
        stage
            .and_then(|s| s.params.get(key))
            .filter(|v| !v.is_null())
    };
    let mut dataset = vec![
        (
            "TERRABAKE_VERSION".to_string(),
            env!("CARGO_PKG_VERSION").to_string(),
        ),
        (
            "TERRABAKE_SOURCE".into(),
            manifest.provenance.source.clone(),
        ),
        ("TERRABAKE_LAYER".into(), entry.key()),
        ("TERRABAKE_DESCRIPTION".into(), entry.description.clone()),
    ];
    if let Some(s) = stage {
        dataset.push(("TERRABAKE_STAGE".into(), s.stage.clone()));
        dataset.push(("TERRABAKE_PARAMS".into(), s.params.to_string()));
    }
    let method = param("method").and_then(|m| m.as_str()).unwrap_or("");
    let unit = layer_unit(name);
    // The solar stage's bands are periods: each named by its days.
    let periods: Vec<String> = stage
        .filter(|s| s.stage == "solar")
        .and_then(|s| {
            serde_json::from_value::<crate::stages::solar::SolarStage>(s.params.clone()).ok()
        })
        .map(|s| s.periods().into_iter().map(|p| p.label).collect())
        .unwrap_or_default();
    let band_metadata = (0..layer.bands())
        .map(|b| {
            let mut items = Vec::new();
            let description = match entry.band_azimuths.get(b as usize) {
                Some(az) => {
                    items.push(("AZIMUTH".to_string(), format!("{az:.4}")));
                    let what = name.replace('_', " ");
                    if method.is_empty() {
                        format!("{what} azimuth {az:.2} deg")
                    } else {
                        format!("{what} azimuth {az:.2} deg, {method}")
                    }
                }
                None => match periods.get(b as usize) {
                    Some(period) => format!("{}, {period}", layer_title(name, 0, 1)),
                    None => layer_title(name, b, layer.bands()),
                },
            };
            crate::io::cog::BandMetadata {
                description,
                unit: unit.to_string(),
                items,
            }
        })
        .collect();
    if !entry.band_azimuths.is_empty() {
        dataset.push((
            "AZIMUTH_CONVENTION".into(),
            "compass: degrees clockwise from north; each band's AZIMUTH item gives its direction"
                .into(),
        ));
        if !method.is_empty() {
            dataset.push(("METHOD".into(), method.to_string()));
        }
        dataset.push(("SECTORS".into(), entry.band_azimuths.len().to_string()));
    }
    if name == terrabake_format::layers::SVF || name == terrabake_format::layers::SVF_COSINE {
        dataset.push(("SVF_DEFINITION".into(), entry.description.clone()));
    }
    Ok(Cog {
        width: layer.width(),
        height: layer.height(),
        bands,
        tile: tiff.tile,
        compression: tiff.compress,
        resampling: tiff.resampling.unwrap_or_else(|| default_resampling(name)),
        tags: GeoTags::for_level(manifest.georef.as_ref(), nodata, entry.level),
        metadata: crate::io::cog::Metadata {
            dataset,
            bands: band_metadata,
        },
        overviews: true,
    })
}

/// Several layers of one shape as one GeoTIFF, their bands one after
/// another in the order given, each band named as its layer's export
/// names it; the dataset's items are the first layer's, its layer item
/// lists them all.
pub fn export_stack(
    asset: &Asset<Mmap>,
    names: &[&str],
    out: &Path,
    tiff: &TiffOptions,
    progress: Progress,
) -> crate::Result<()> {
    let layers = names
        .iter()
        .map(|n| asset.layer(n, 0))
        .collect::<terrabake_format::Result<Vec<_>>>()?;
    let first = layers.first().ok_or_else(|| anyhow!("no layer to write"))?;
    let mut cog = cog_for_layer(asset, first, tiff)?;
    let mut bands = Vec::new();
    let mut of_band = Vec::new();
    for layer in &layers {
        crate::error::ensure!(
            (layer.width(), layer.height()) == (first.width(), first.height()),
            "layers {} and {} differ in size; one GeoTIFF holds one grid",
            first.entry().key(),
            layer.entry().key()
        );
        bands.extend(cog_for_layer(asset, layer, tiff)?.metadata.bands);
        of_band.extend((0..layer.bands()).map(|b| (*layer, b)));
    }
    cog.bands = u16::try_from(of_band.len())
        .map_err(|_| anyhow!("{} bands is more than TIFF holds", of_band.len()))?;
    cog.metadata.bands = bands;
    if let Some(item) = cog
        .metadata
        .dataset
        .iter_mut()
        .find(|(k, _)| k == "TERRABAKE_LAYER")
    {
        item.1 = names.join(",");
    }
    let bar = progress.bar(
        u64::from(first.height()) * of_band.len() as u64,
        "export",
        "rows",
    );
    cog.write(
        out,
        |band, y0, rows| {
            let (layer, b) = of_band[band as usize];
            Ok(layer.read_rows_f32(b, y0, rows)?)
        },
        |n| bar.inc(n),
    )?;
    bar.finish_and_clear();
    Ok(())
}

/// Whether a layer's previews show kWh/m^2 (the irradiation layers, which
/// store Wh/m^2).
fn preview_in_kwh(layer: &str) -> bool {
    use terrabake_format::layers as l;
    [
        l::SOLAR_GLOBAL,
        l::SOLAR_BEAM,
        l::SOLAR_DIFFUSE,
        l::SOLAR_REFLECTED,
    ]
    .contains(&layer)
}

/// The unit of a layer's values, as GDAL's unit type says it.
fn layer_unit(layer: &str) -> &'static str {
    use terrabake_format::layers as l;
    match layer {
        _ if is_height_like(layer) => "m",
        l::CONE_APEX => "m",
        l::HORIZON | l::OPENNESS | l::VIEWSHED_ANGLE => "deg",
        l::HORIZON_DISTANCE => "m",
        l::TOTAL_VIEWSHED => "m2",
        l::SOLAR_GLOBAL | l::SOLAR_BEAM | l::SOLAR_DIFFUSE | l::SOLAR_REFLECTED => "Wh/m2",
        l::SUN_HOURS => "h",
        _ => "",
    }
}

/// `terrabake export`.
#[derive(Debug, Clone, clap::Args)]
pub struct ExportArgs {
    /// The asset directory (made by `terrabake ingest` or `terrabake bake`).
    pub asset: PathBuf,
    /// Layer name (see `terrabake info`). A .zarr store or .nc file takes several (`--layer
    /// horizon --layer svf`) or `all`: every layer at --level, as one dataset.
    #[arg(long, default_value = "height")]
    pub layer: Vec<String>,
    /// Pyramid level of the layer.
    #[arg(long, default_value_t = 0)]
    pub level: u32,
    /// PNG style: `relief` (hypsometric tint with hillshade and a legend; the default for
    /// heights), `ramp` (viridis from the 1st to the 99th percentile with a legend; the
    /// default for other layers) or `gray` (16-bit, min to max, no legend: a heightmap for
    /// engines). Nodata is transparent (black in `gray`).
    #[arg(long, value_enum)]
    pub style: Option<PngStyle>,
    /// The band a PNG shows (GeoTIFF and EXR carry all bands).
    #[arg(long, default_value_t = 0)]
    pub band: u32,
    #[command(flatten)]
    pub tiff: TiffOptions,
    /// Write for another program instead, into the directory -o names: `grass` writes the
    /// horizon layer as `r.horizon` does (one GeoTIFF per direction, radians, counter-clockwise
    /// from east, named for `r.sun horizon_basename=horizon horizon_step=STEP`); `unreal`,
    /// `unity` and `godot` write the height layer as their terrain importers take it (16-bit
    /// PNG, 16-bit RAW, float EXR; padded to the sizes they accept, tiled past one terrain)
    /// with heightmap.json, the scale, offset and cell size that give the heights back.
    #[arg(long = "for", value_enum, value_name = "PROGRAM")]
    pub for_program: Option<ExportFor>,
    /// With --for grass: degrees between directions, 0.1 to 360 (360 / the layer's bands by default);
    /// give `r.sun` the same `horizon_step`.
    #[arg(long, requires = "for_program", value_parser = crate::stage::args::parse_grass_step)]
    pub step: Option<f64>,
    /// With a .ktx2 horizon export: the horizons as 2K + 1 Fourier coefficients per post for K
    /// harmonics (at most (bands - 1) / 2), a float array texture, instead of the bands.
    #[arg(long, value_name = "K")]
    pub fourier: Option<usize>,
    /// The file to write: .tif (GeoTIFF), .exr, .png (a preview), .ktx2 (a texture for
    /// shaders: horizons as an array, cone planes as an RG texture conservative under bilinear
    /// filtering), .zarr (a Zarr v3 store) or .nc (NetCDF-4): CF-1.8 attributes, an azimuth
    /// dimension, chunks = the asset's tiles, quantised layers as their codes with scale_factor
    /// and add_offset. By its extension; a directory with --for.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// The programs `export --for` writes for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFor {
    /// GRASS GIS: `r.horizon`'s files, for `r.sun`.
    Grass,
    /// Unreal Engine's landscape: a 16-bit PNG (tiles for World Partition past 8129 posts).
    Unreal,
    /// Unity's terrain: a 16-bit little-endian RAW of 2^n + 1 posts.
    Unity,
    /// Godot's Terrain3D: a float EXR of heights in metres.
    Godot,
}

impl Run for ExportArgs {
    fn run(&self, s: &Session) -> crate::Result<ExitCode> {
        let progress = s.progress;
        let asset = crate::stage::asset::open(&self.asset)?;
        let kind = ExportKind::from_path(&self.output).ok();
        if let Some(kind @ (ExportKind::Zarr | ExportKind::NetCdf)) = kind {
            return self.run_dataset(&asset, kind, s);
        }
        let layer_name = self.one_layer()?;
        if self.for_program == Some(ExportFor::Grass) {
            if layer_name != terrabake_format::layers::HORIZON || self.level != 0 {
                bail!("--for grass exports the horizon layer: add --layer horizon");
            }
            let (files, step) =
                grass::export_horizons(&asset, &self.output, self.step, &self.tiff, progress)?;
            s.say(format!(
                "wrote {} horizon files to {} (r.sun horizon_basename={} horizon_step={})",
                files.len(),
                self.output.display(),
                grass::BASENAME,
                format_step(step)
            ));
            return Ok(ExitCode::SUCCESS);
        }
        if let Some(program) = self.for_program {
            self.run_for_engine(&asset, program, s)?;
            return Ok(ExitCode::SUCCESS);
        }
        if let Some(harmonics) = self.fourier {
            self.run_fourier(&asset, harmonics, s)?;
            return Ok(ExitCode::SUCCESS);
        }
        let layer = self.open_layer(&asset, layer_name)?;
        export_layer(
            &asset,
            layer,
            &self.output,
            self.style,
            self.band,
            &self.tiff,
            progress,
        )?;
        s.say(format!("wrote {}", self.output.display()));
        Ok(ExitCode::SUCCESS)
    }
}

impl ExportArgs {
    /// The one layer every export but Zarr and NetCDF takes.
    fn one_layer(&self) -> Result<&str> {
        match self.layer.as_slice() {
            [one] if one != "all" => Ok(one),
            _ => bail!(
                "{}: only a .zarr store or a .nc file takes several layers or `all`; give one --layer",
                self.output.display()
            ),
        }
    }

    /// Layer `name` at --level, or an error that says which stage makes it.
    fn open_layer<'a>(&self, asset: &'a Asset<Mmap>, name: &str) -> Result<&'a Layer<Mmap>> {
        asset
            .layer(name, self.level)
            .map_err(|e| match stage_making(name) {
                Some(stage) => {
                    anyhow::anyhow!("{e}; `terrabake {stage} {}` makes it", self.asset.display())
                }
                None => e.into(),
            })
    }

    /// `-o X.zarr` or `-o X.nc`: the layers asked for as one dataset.
    fn run_dataset(
        &self,
        asset: &Asset<Mmap>,
        kind: ExportKind,
        s: &Session,
    ) -> crate::Result<ExitCode> {
        if self.for_program.is_some() || self.fourier.is_some() {
            bail!(
                "--for and --fourier write other formats; a .zarr or .nc export takes --layer and --level"
            );
        }
        let mut skipped = Vec::new();
        let layers: Vec<&Layer<Mmap>> = if self.layer.iter().any(|l| l == "all") {
            // The grid of the first layer at the level (the heights at 0):
            // the pyramids, over cells rather than posts, are another.
            let at_level = || {
                asset
                    .layers()
                    .iter()
                    .filter(|l| l.entry().level == self.level)
            };
            let grid = at_level().next().map(|l| (l.width(), l.height()));
            let (same, other): (Vec<_>, Vec<_>) =
                at_level().partition(|l| Some((l.width(), l.height())) == grid);
            skipped = other.iter().map(|l| l.entry().key()).collect();
            same
        } else {
            self.layer
                .iter()
                .map(|name| self.open_layer(asset, name))
                .collect::<Result<_>>()?
        };
        crate::error::ensure!(
            !layers.is_empty(),
            "{}: no layer at level {}",
            self.asset.display(),
            self.level
        );
        let summary = if kind == ExportKind::NetCdf {
            let r = netcdf::export_netcdf(asset, &layers, &self.output, s.progress)?;
            format!(
                "{} variables, {} chunks, {:.1} MiB",
                r.variables,
                r.chunks,
                r.bytes as f64 / f64::from(1 << 20)
            )
        } else {
            let r = zarr::export_zarr(asset, &layers, &self.output, s.progress)?;
            format!(
                "{} arrays, {} chunks of which {} copied as stored, {:.1} MiB",
                r.arrays,
                r.chunks,
                r.copied,
                r.bytes as f64 / f64::from(1 << 20)
            )
        };
        if !skipped.is_empty() {
            s.say(format!(
                "left out {} (another grid; export them to a dataset of their own)",
                skipped.join(", ")
            ));
        }
        s.say(format!(
            "wrote {} ({} layer(s), {summary})",
            self.output.display(),
            layers.len(),
        ));
        Ok(ExitCode::SUCCESS)
    }

    /// `--for unreal|unity|godot`: the heights as the engine imports them.
    fn run_for_engine(&self, asset: &Asset<Mmap>, program: ExportFor, s: &Session) -> Result<()> {
        let engine = match program {
            ExportFor::Unreal => engine::Engine::Unreal,
            ExportFor::Unity => engine::Engine::Unity,
            ExportFor::Godot => engine::Engine::Godot,
            ExportFor::Grass => unreachable!("run handles grass"),
        };
        if self.layer != [terrabake_format::HEIGHT_LAYER] || self.level != 0 {
            bail!(
                "--for {} exports the height layer at level 0: drop --layer {} --level {}",
                engine.name(),
                self.layer.join(" --layer "),
                self.level
            );
        }
        let sidecar = engine::export_heightmap(asset, engine, &self.output, None, s.progress)?;
        s.say(format!(
            "wrote {} file(s) of {} x {} posts and heightmap.json to {} (heights within {:.3} m)",
            sidecar.files.len(),
            sidecar.layout.size.0,
            sidecar.layout.size.1,
            self.output.display(),
            sidecar.height.max_error_m
        ));
        Ok(())
    }

    /// `--fourier K`: the horizons as Fourier coefficients, a KTX2 texture.
    fn run_fourier(&self, asset: &Asset<Mmap>, harmonics: usize, s: &Session) -> Result<()> {
        if self.layer != [terrabake_format::layers::HORIZON]
            || ExportKind::from_path(&self.output)? != ExportKind::Ktx2
        {
            bail!("--fourier writes the horizon layer as a texture: give --layer horizon and an -o ending in .ktx2");
        }
        texture::write_ktx2(&self.output, &texture::fourier_texture(asset, harmonics)?)?;
        s.say(format!(
            "wrote {} ({} coefficients per post)",
            self.output.display(),
            2 * harmonics + 1
        ));
        Ok(())
    }
}

/// A step as GRASS should be given it: the fewest decimals that say it.
pub(crate) fn format_step(step: f64) -> String {
    format!("{step:.*}", grass::step_decimals(step))
}

/// Exports `layer` to `out`: every band to GeoTIFF (one TIFF band each) and
/// OpenEXR (one channel each, `B0`, `B1`, ...), band `band` to a PNG.
pub(crate) fn export_layer(
    asset: &Asset<Mmap>,
    layer: &Layer<Mmap>,
    out: &Path,
    style: Option<PngStyle>,
    band: u32,
    tiff: &TiffOptions,
    progress: Progress,
) -> Result<()> {
    let style = style.unwrap_or_else(|| PngStyle::default_for(&layer.entry().name));
    let (w, h, bands) = (layer.width(), layer.height(), layer.bands());
    if band >= bands {
        bail!(
            "layer {} has {bands} band(s); --band {band} is past them",
            layer.entry().key()
        );
    }
    let manifest = asset.manifest();
    let height_like = is_height_like(&layer.entry().name);
    match ExportKind::from_path(out)? {
        ExportKind::GeoTiff => {
            let cog = cog_for_layer(asset, layer, tiff)?;
            if let Some(budget) = tiff.max_memory {
                crate::error::ensure!(
                    cog.memory() <= budget,
                    "{}: a {w} x {h} GeoTIFF in tiles of {} holds about {} MiB at once (a tile row per overview level), over --max-memory {} MiB; give a smaller --tile or raise --max-memory",
                    out.display(),
                    tiff.tile,
                    cog.memory() >> 20,
                    budget >> 20
                );
            }
            let bar = progress.bar(u64::from(h) * u64::from(bands), "export", "rows");
            cog.write(
                out,
                |band, y0, rows| Ok(layer.read_rows_f32(band, y0, rows)?),
                |n| bar.inc(n),
            )?;
            bar.finish_and_clear();
            Ok(())
        }
        ExportKind::Exr => {
            // The exr crate encodes whole images: bound what we hold.
            if u64::from(w) * u64::from(h) * u64::from(bands) > 1 << 28 {
                bail!("layer {} is {w} x {h} x {bands}: EXR export holds the whole layer and is limited to 2^28 values; export GeoTIFF instead", layer.entry().key());
            }
            let mut channels = Vec::new();
            for b in 0..bands {
                let mut all = vec![0f32; w as usize * h as usize];
                layer.read_rows_f32(b, 0, &mut all)?;
                let name = if bands == 1 {
                    "Y".to_string()
                } else {
                    format!("B{b}")
                };
                channels.push((name, all));
            }
            Ok(write_atomically(out, |file| {
                use exr::prelude::*;
                let channels = channels
                    .into_iter()
                    .map(|(name, all)| AnyChannel::new(name.as_str(), FlatSamples::F32(all)))
                    .collect();
                let image =
                    Image::from_channels((w as usize, h as usize), AnyChannels::sort(channels));
                image
                    .write()
                    .to_buffered(file)
                    .map_err(|e| anyhow!("writing EXR: {e}"))
            })?)
        }
        ExportKind::Png => write_png_preview(out, layer, manifest, style, band, height_like),
        ExportKind::Ktx2 => texture::write_ktx2(out, &texture::texture_for_layer(asset, layer)?),
        ExportKind::Zarr => Ok(zarr::export_zarr(asset, &[layer], out, progress).map(|_| ())?),
        ExportKind::NetCdf => {
            Ok(netcdf::export_netcdf(asset, &[layer], out, progress).map(|_| ())?)
        }
    }
}

/// Largest side of a PNG preview; larger layers are subsampled.
pub const PREVIEW_MAX_SIDE: u32 = 4096;

fn write_png_preview(
    out: &Path,
    layer: &Layer<Mmap>,
    manifest: &terrabake_format::Manifest,
    style: PngStyle,
    band: u32,
    height_like: bool,
) -> Result<()> {
    let (w, h) = (layer.width(), layer.height());
    let step = w.max(h).div_ceil(PREVIEW_MAX_SIDE).max(1);
    let (pw, ph) = (w.div_ceil(step), h.div_ceil(step));
    // Irradiation reads better in kWh than in thousands of Wh.
    let (scale, title) = match preview_in_kwh(&layer.entry().name) {
        true => (
            1e-3,
            layer_title(&layer.entry().name, band, layer.bands()).replace("Wh/m2", "kWh/m2"),
        ),
        false => (1.0, layer_title(&layer.entry().name, band, layer.bands())),
    };
    let row_at = |y: u32| -> Result<Vec<f32>> {
        let mut full = vec![0f32; w as usize];
        layer.read_rows_f32(band, y.min(h - 1), &mut full)?;
        Ok((0..pw).map(|x| full[(x * step) as usize] * scale).collect())
    };
    // Heights scale by the DEM's range; other layers by percentiles.
    let mut stretch = match (height_like, manifest.height_range) {
        (true, Some(r)) => Stretch::linear(r.min, r.max, "the DEM's full range"),
        _ => {
            let mut values = Vec::with_capacity(pw as usize * ph as usize);
            for py in 0..ph {
                values.extend(row_at(py * step)?);
            }
            Stretch::percentiles(values).unwrap_or_else(|| Stretch::linear(0.0, 1.0, "no values"))
        }
    };
    if style == PngStyle::Relief {
        stretch.note += "; lit from the north-west";
    }
    let legend = Legend {
        title,
        ramp: match style {
            PngStyle::Relief => Ramp::Hypsometric,
            _ => Ramp::Viridis,
        },
        stretch,
    };
    // Metres per preview pixel, for the hillshade's slopes.
    let (dx, dy) = (
        manifest.cell_size.dx * f64::from(step),
        manifest.cell_size.dy * f64::from(step),
    );
    let legend_rows = match style {
        PngStyle::Gray => 0,
        _ => crate::present::legend::height(pw),
    };
    Ok(write_atomically(out, |file| {
        let mut enc = png::Encoder::new(file, pw, ph + legend_rows);
        match style {
            PngStyle::Gray => {
                enc.set_color(png::ColorType::Grayscale);
                enc.set_depth(png::BitDepth::Sixteen);
            }
            PngStyle::Relief | PngStyle::Ramp => {
                enc.set_color(png::ColorType::Rgba);
                enc.set_depth(png::BitDepth::Eight);
            }
        }
        let mut header = enc.write_header()?;
        let mut writer = header.stream_writer()?;
        let (mut above, mut here) = (row_at(0)?, row_at(0)?);
        for py in 0..ph {
            let below = row_at(((py + 1) * step).min(h - 1))?;
            let mut bytes = Vec::with_capacity(pw as usize * 4);
            for px in 0..pw as usize {
                let z = here[px];
                let t = legend.stretch.position(z);
                match style {
                    PngStyle::Gray => {
                        let v = if z.is_nan() {
                            0
                        } else {
                            (t * 65535.0).round() as u16
                        };
                        bytes.extend_from_slice(&v.to_be_bytes());
                    }
                    _ if z.is_nan() => bytes.extend_from_slice(&[0, 0, 0, 0]),
                    PngStyle::Ramp => {
                        let [r, g, b] = legend.ramp.colour(t);
                        bytes.extend_from_slice(&[r, g, b, 255]);
                    }
                    PngStyle::Relief => {
                        let pick = |v: f32| if v.is_nan() { z } else { v };
                        let left = pick(here[px.saturating_sub(1)]);
                        let right = pick(here[(px + 1).min(pw as usize - 1)]);
                        let (up, down) = (pick(above[px]), pick(below[px]));
                        let shade = hillshade(
                            f64::from(right - left) / (2.0 * dx),
                            f64::from(down - up) / (2.0 * dy),
                        );
                        let [r, g, b] = crate::present::legend::hypsometric(t);
                        let s = 0.35 + 0.65 * shade;
                        bytes.extend_from_slice(&[
                            (r * s) as u8,
                            (g * s) as u8,
                            (b * s) as u8,
                            255,
                        ]);
                    }
                }
            }
            writer.write_all(&bytes)?;
            above = std::mem::replace(&mut here, below);
        }
        if legend_rows > 0 {
            let panel: Vec<u8> = crate::present::legend::render(pw, &legend)
                .into_iter()
                .flat_map(|[r, g, b]| [r, g, b, 255])
                .collect();
            writer.write_all(&panel)?;
        }
        writer.finish()?;
        header.finish()?;
        Ok(())
    })?)
}

/// Lambert shading of a surface with slopes dz/dx (east) and dz/dy (south),
/// lit from azimuth 315 degrees (north-west) at 45 degrees elevation.
fn hillshade(dzdx: f64, dzdy: f64) -> f32 {
    let normal = [-dzdx, dzdy, 1.0];
    let len = (normal[0] * normal[0] + normal[1] * normal[1] + 1.0).sqrt();
    let (az, el) = (315f64.to_radians(), 45f64.to_radians());
    // x east, y north, z up.
    let light = [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()];
    let d = (normal[0] * light[0] + normal[1] * light[1] + normal[2] * light[2]) / len;
    d.clamp(0.0, 1.0) as f32
}
