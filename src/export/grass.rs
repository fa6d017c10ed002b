//! Horizons as GRASS GIS's `r.horizon` writes them, so that `r.sun` reads
//! them as its own (`terrabake export --layer horizon --for grass`).
//!
//! `r.horizon` writes one raster per direction and `r.sun
//! horizon_basename=B horizon_step=S` looks them up by name: `B_` and the
//! direction's angle formatted by GRASS's `G_generate_basename`, three
//! digits, then as many decimals as the step has, the point written as an
//! underscore (`horizon_000_0`, `horizon_022_5` for a step of 22.5;
//! `horizon_000`, `horizon_030` for 30). The angle counts counter-clockwise
//! from east (ours: clockwise from north, so `grass = 90 - compass`), and
//! the values are the horizon's elevation angle in radians, clamped at 0:
//! r.sun stores each one in an unsigned byte, where a negative angle
//! wraps round to a horizon near the zenith (a ridge post's view down into
//! a valley would shade it all day). `terrabake export --layer horizon`
//! without `--for grass` keeps the negative angles.
//!
//! We write each direction as a single-band COG named so that
//! `r.in.gdal` or `r.import` imports it under the map name `r.sun` expects.
//! A stored band sits at its own azimuth (a line band at 21.80 degrees, not
//! 22.5), so each file's horizon is interpolated linearly between the two
//! stored bands around the GRASS direction, as every reader of the asset
//! interpolates ([`terrabake_format::horizons::bands_around`]); where the
//! direction is a stored band's, the value is that band's exactly.
//! `docs/GIS.md` gives the commands; `pipelines/gis/check_grass.sh` runs
//! them when GRASS is installed.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use terrabake_format::horizons::{bands_around, HorizonMap, HORIZON};
use terrabake_format::{Asset, Mmap};

use super::{cog_for_layer, TiffOptions};
use crate::error::bail;
use crate::io::cog::{BandMetadata, Cog, Metadata, Resampling};
use crate::plumbing::progress::Progress;

/// The map name prefix; `r.sun horizon_basename=horizon`.
pub const BASENAME: &str = "horizon";

/// One file `r.horizon` would have written.
#[derive(Debug, Clone, PartialEq)]
pub struct GrassHorizon {
    /// Counter-clockwise from east, degrees: GRASS's angle.
    pub grass_angle: f64,
    /// The same direction as a compass azimuth, degrees.
    pub azimuth: f64,
    pub file: PathBuf,
}

/// Decimals of `step` as GRASS counts them from the number as typed: we
/// type it with the fewest that say it exactly (up to 6).
pub(crate) fn step_decimals(step: f64) -> usize {
    (0..=6)
        .find(|&d| {
            let scale = 10f64.powi(d as i32);
            ((step * scale).round() - step * scale).abs() < 1e-6
        })
        .unwrap_or(6)
}

/// `G_generate_basename(basename, angle, 3, decimals)`.
pub(crate) fn map_name(angle: f64, decimals: usize) -> String {
    let width = 3 + if decimals > 0 { decimals + 1 } else { 0 };
    let number = format!("{angle:0width$.decimals$}").replace('.', "_");
    format!("{BASENAME}_{number}")
}

/// The directions for `step` degrees (360 / bands by default): 0, step, ...
/// below 360, counter-clockwise from east.
pub fn directions(dir: &Path, step: f64) -> crate::Result<Vec<GrassHorizon>> {
    if !(0.1..=360.0).contains(&step) {
        bail!("--step {step}: give 0.1 to 360 degrees (at most 3600 files)");
    }
    let decimals = step_decimals(step);
    let n = (360.0 / step - 1e-9).ceil() as usize;
    Ok((0..n)
        .map(|i| {
            let grass_angle = i as f64 * step;
            GrassHorizon {
                grass_angle,
                azimuth: (90.0 - grass_angle).rem_euclid(360.0),
                file: dir.join(format!("{}.tif", map_name(grass_angle, decimals))),
            }
        })
        .collect())
}

/// Writes the horizon layer of `asset` into `dir`, one file per direction
/// `step` degrees apart (360 / bands when `None`). Returns the files and
/// the `r.sun` step to give with them.
pub(crate) fn export_horizons(
    asset: &Asset<Mmap>,
    dir: &Path,
    step: Option<f64>,
    tiff: &TiffOptions,
    progress: Progress,
) -> Result<(Vec<GrassHorizon>, f64)> {
    let layer = asset.layer(HORIZON, 0)?;
    let azimuths = layer.entry().band_azimuths.clone();
    if azimuths.len() != layer.bands() as usize || azimuths.is_empty() {
        bail!(
            "{}: the horizon layer has {} bands but {} band azimuths",
            asset.dir().display(),
            layer.bands(),
            azimuths.len()
        );
    }
    let step = step.unwrap_or(360.0 / azimuths.len() as f64);
    let files = directions(dir, step)?;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    let base = cog_for_layer(asset, layer, tiff)?;
    let map = HorizonMap::open(asset)?;
    let h = layer.height();
    let bar = progress.bar(u64::from(h) * files.len() as u64, "export", "rows");
    for f in &files {
        let (i, j, t) = bands_around(&azimuths, f.azimuth);
        let description = format!(
            "horizon angle, radians, {:.4} deg counter-clockwise from east (compass {:.4})",
            f.grass_angle, f.azimuth
        );
        let mut dataset = base.metadata.dataset.clone();
        dataset.retain(|(k, _)| k.starts_with("TERRABAKE_"));
        // The layer's description says degrees; this file holds radians.
        for (k, v) in &mut dataset {
            if k == "TERRABAKE_DESCRIPTION" {
                *v = format!("{description}; from the layer: {v}");
            }
        }
        dataset.push((
            "GRASS_ANGLE".into(),
            "degrees counter-clockwise from east (r.horizon, r.sun)".into(),
        ));
        dataset.push((
            "INTERPOLATED_FROM".into(),
            format!(
                "bands {i} ({:.4} deg) and {j} ({:.4} deg), weight {t:.6} on band {j}",
                azimuths[i], azimuths[j]
            ),
        ));
        let cog = Cog {
            bands: 1,
            resampling: tiff.resampling.unwrap_or(Resampling::Nearest),
            metadata: Metadata {
                dataset,
                bands: vec![BandMetadata {
                    description,
                    unit: "rad".into(),
                    items: vec![("GRASS_ANGLE".into(), format!("{}", f.grass_angle))],
                }],
            },
            ..base.clone()
        };
        cog.write(
            &f.file,
            |_, y0, rows| {
                map.served_rows(f.azimuth, y0, rows)?;
                // r.sun keeps each horizon as one unsigned byte of 1/150 rad
                // (main.c, INPUT_part), so a negative angle wraps to about
                // 95 degrees and shades that direction all day. It never
                // weighs a sun below the horizontal, so 0 reads the same;
                // `< 0.0` keeps nodata's NaN.
                for v in rows.iter_mut() {
                    *v = if *v < 0.0 { 0.0 } else { v.to_radians() };
                }
                Ok(())
            },
            |n| bar.inc(n),
        )?;
    }
    bar.finish_and_clear();
    Ok((files, step))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_g_generate_basename() {
        assert_eq!(step_decimals(22.5), 1);
        assert_eq!(step_decimals(30.0), 0);
        assert_eq!(step_decimals(11.25), 2);
        assert_eq!(map_name(0.0, 1), "horizon_000_0");
        assert_eq!(map_name(22.5, 1), "horizon_022_5");
        assert_eq!(map_name(337.5, 1), "horizon_337_5");
        assert_eq!(map_name(30.0, 0), "horizon_030");
        assert_eq!(map_name(11.25, 2), "horizon_011_25");
    }

    #[test]
    fn directions_turn_counter_clockwise_from_east() {
        let d = directions(Path::new("x"), 22.5).unwrap();
        assert_eq!(d.len(), 16);
        // East, then north-north-east ... : compass 90, 67.5, ...
        assert_eq!(d[0].azimuth, 90.0);
        assert_eq!(d[1].azimuth, 67.5);
        assert_eq!(d[4].azimuth, 0.0);
        assert_eq!(d[5].azimuth, 337.5);
        assert_eq!(d[1].file, Path::new("x/horizon_022_5.tif"));
        assert!(directions(Path::new("x"), 0.0).is_err());
        assert!(directions(Path::new("x"), f64::NAN).is_err());
    }
}
