//! The codecs the plan bakes with, from the bytes budget: raw tiles where
//! they fit (a renderer reads them in place from the memory mapping, with
//! no decode), zstd where only that fits. First the heights (encoded on a
//! sample of tile rows, as ingest encodes them), then the horizon and sky
//! layers: the horizons of one tile at the DEM's centre, swept with the
//! plan's own directions inside a crop of 3 x 3 tiles (so that the tile's
//! lines run at least a tile past it), quantised and encoded as the stage
//! encodes them (the smallest of raw, zstd and shuffled zstd per tile);
//! their ratio to raw scales the layers, and the tile's sky-view factor
//! stands for every sky layer. One tile is a sample, so the derived layers
//! are chosen zstd only when the prediction fits in [`BYTES_SHARE`] of the
//! limit; `check` measures the bytes on disk.

use anyhow::Result;
use terrabake_format::{Asset, Codec, Mmap};

use crate::algorithms::horizon::line::line_horizons;
use crate::algorithms::horizon::sky::{svf_of_horizons, BandIntegrals};
use crate::algorithms::horizon::BandKind;
use crate::plan::budget::Budget;
use crate::plan::{Candidate, Choice};
use crate::terrain::held::HeldDem;
use crate::terrain::tiling::encode_tile_row;
use crate::terrain::{RowScale, Terrain};

/// The share of the bytes limit a predicted zstd size of the derived
/// layers may take: the rest is kept for the sample's error.
pub(super) const BYTES_SHARE: f64 = 0.9;

/// The horizons the plan bakes, for the derived layers' prediction.
pub(super) struct Derived<'a> {
    pub(super) dem: &'a HeldDem,
    pub(super) curvature: f64,
    pub(super) chosen: &'a Candidate,
    pub(super) sky_layers: usize,
}

/// What [`choose`] decided: the heights' codec and the derived layers'.
pub(super) struct Codecs {
    pub(super) heights: Codec,
    pub(super) derived: Codec,
    /// MiB of decoded horizon tiles the sky stage's reader keeps in its
    /// cache (bounded by [`terrabake_format::reader::DEFAULT_CACHE_BYTES`])
    /// when the horizons are zstd: on the SRTM tile at 24 directions the
    /// peak rose from 131 to 176 MiB.
    pub(super) cache_mib: f64,
}

/// The heights' and the derived layers' codecs, with the plan's bytes so
/// far (`bytes`, every layer raw but heights already stored as zstd), its
/// bytes then.
pub(super) fn choose(
    asset: &Asset<Mmap>,
    budget: &Budget,
    (w, h, tile): (usize, usize, usize),
    mut bytes: u64,
    derived: Option<Derived<'_>>,
    choices: &mut Vec<Choice>,
) -> Result<(Codecs, u64)> {
    let heights = asset.manifest().layer(terrabake_format::HEIGHT_LAYER, 0);
    let ingested_codec = heights.map_or(Codec::Raw, |l| l.codec);
    let mut codec = ingested_codec;
    let mut derived_codec = Codec::Raw;
    let mut cache_mib = 0.0;
    if let Some(limit) = budget.bytes {
        let raw_heights = super::layer_bytes(w, h, tile, 4, 1);
        // The heights' zstd bytes, encoded once for both tries below.
        let mut heights_zstd = None;
        let mut zstd_heights = || -> Result<u64> {
            match heights_zstd {
                Some(z) => Ok(z),
                None => Ok(*heights_zstd.insert(zstd_height_bytes(asset, tile)?)),
            }
        };
        if codec == Codec::Raw && bytes > limit && bytes - raw_heights < limit {
            let zstd = zstd_heights()?;
            if bytes - raw_heights + zstd <= limit {
                choices.push(Choice {
                    what: "codec".into(),
                    chosen: "zstd heights (ingest again)".into(),
                    why: format!(
                        "raw heights ({:.1} MiB) would pass the bytes limit; zstd tiles take {:.1} MiB (encoded on a sample of tile rows)",
                        raw_heights as f64 / 1048576.0,
                        zstd as f64 / 1048576.0
                    ),
                    rejected: Some("raw: over the bytes limit".into()),
                });
                bytes = bytes - raw_heights + zstd;
                codec = Codec::Zstd;
            }
        }
        if let Some(d) = derived.filter(|_| bytes > limit) {
            let enc = d.chosen.encoding;
            let bands = d.chosen.stage().bands(d.dem.dx, d.dem.dy).len();
            let raw_horizons = super::layer_bytes(w, h, tile, enc.elem().size(), bands);
            let raw_sky = super::layer_bytes(w, h, tile, 4, d.sky_layers);
            let (horizon_ratio, sky_ratio) = zstd_derived_ratios(&d, tile);
            let zstd = (raw_horizons as f64 * horizon_ratio + raw_sky as f64 * sky_ratio) as u64;
            let fits = |bytes: u64| bytes as f64 <= BYTES_SHARE * limit as f64;
            let mut predicted = bytes - raw_horizons - raw_sky + zstd;
            // The heights as zstd too, where the derived layers alone do
            // not fit and the heights are not zstd yet.
            let mut heights_too = None;
            if !fits(predicted) && codec == Codec::Raw {
                let z = zstd_heights()?;
                heights_too = Some(z);
                predicted = predicted - raw_heights + z;
            }
            if fits(predicted) {
                choices.push(Choice {
                    what: "codec of the horizon and sky layers".into(),
                    chosen: "zstd".into(),
                    why: format!(
                        "raw they take {:.1} MiB and pass the bytes limit; zstd {:.1} MiB (horizons {:.2}x, sky {:.2}x of raw, measured on one tile swept at the DEM's centre){}, within {:.0} % of the limit",
                        (raw_horizons + raw_sky) as f64 / 1048576.0,
                        zstd as f64 / 1048576.0,
                        horizon_ratio,
                        sky_ratio,
                        heights_too.map_or(String::new(), |z| format!(
                            ", with zstd heights ({:.1} MiB, ingest again)",
                            z as f64 / 1048576.0
                        )),
                        100.0 * BYTES_SHARE
                    ),
                    rejected: Some("raw: over the bytes limit (raw tiles are read in place, zstd tiles decoded on every read)".into()),
                });
                if heights_too.is_some() {
                    codec = Codec::Zstd;
                }
                derived_codec = Codec::Zstd;
                bytes = predicted;
                cache_mib = raw_horizons.min(terrabake_format::reader::DEFAULT_CACHE_BYTES) as f64
                    / 1048576.0;
            } else {
                crate::error::bail!(
                    "budget {budget}: the plan that meets the error budget needs bytes {bytes}, or about {predicted} with zstd horizon, sky and height tiles (horizons {horizon_ratio:.2}x, sky {sky_ratio:.2}x of raw on a sample tile), over {:.0} % of the limit {limit}; relax bytes to at least {:.0}, or horizon (fewer directions)",
                    100.0 * BYTES_SHARE,
                    predicted as f64 / BYTES_SHARE
                );
            }
        }
    }
    if codec == Codec::Zstd && ingested_codec == Codec::Zstd {
        choices.push(Choice {
            what: "codec".into(),
            chosen: "zstd heights".into(),
            why: "the ingest's".into(),
            rejected: None,
        });
    } else if codec == Codec::Raw {
        choices.push(Choice {
            what: "codec of the heights".into(),
            chosen: "raw".into(),
            why: "tiles are read in place from the memory mapping, no decode per read".into(),
            rejected: Some("zstd: fewer bytes, a decode on every tile read (chosen, heights first, when only it fits the bytes limit)".into()),
        });
    }
    Ok((
        Codecs {
            heights: codec,
            derived: derived_codec,
            cache_mib,
        },
        bytes,
    ))
}

/// Bytes of the heights stored as zstd tiles of `tile` posts: up to eight
/// tile rows spread over the DEM, encoded as ingest encodes them, scaled to
/// every row.
pub(super) fn zstd_height_bytes(asset: &Asset<Mmap>, tile: usize) -> Result<u64> {
    let height = asset.height()?;
    let (w, h) = (height.width() as usize, height.height() as usize);
    let bands = crate::terrain::tiling::row_bands(h, tile);
    let stride = bands.len().div_ceil(8);
    let (mut sampled, mut stored) = (0, 0);
    for band in bands.iter().step_by(stride) {
        let mut z = vec![0f32; w * band.len()];
        height.read_rows_f32(0, band.start as u32, &mut z)?;
        let tiles = crate::terrain::tiling::encode_tile_row(&z, w, tile, f32::NAN, Codec::Zstd);
        sampled += 1;
        stored += tiles.iter().map(|t| t.bytes.len() as u64).sum::<u64>();
    }
    Ok(stored * bands.len() as u64 / sampled.max(1))
}

/// Compressed bytes over raw bytes of the horizon layer and of a sky layer,
/// on the centre tile of a crop of up to 3 x 3 tiles at the DEM's centre
/// (the crop's own edge limits the tile's lines to at least a tile).
fn zstd_derived_ratios(d: &Derived<'_>, tile: usize) -> (f64, f64) {
    let dem = d.dem;
    let (cw, ch) = ((3 * tile).min(dem.width), (3 * tile).min(dem.height));
    let (x0, y0) = ((dem.width - cw) / 2, (dem.height - ch) / 2);
    let z: Vec<f32> = (y0..y0 + ch)
        .flat_map(|r| {
            dem.z()[r * dem.width + x0..r * dem.width + x0 + cw]
                .iter()
                .copied()
        })
        .collect();
    let scale = RowScale::new(&dem.row_scale).crop(y0..y0 + ch);
    let terrain = Terrain::new(&z, cw, ch, dem.dx, dem.dy)
        .with_row_scale(scale)
        .with_curvature(d.curvature);
    // The centre tile of the crop (all of it, where the DEM is smaller).
    let (tx, ty) = (cw.saturating_sub(tile) / 2, ch.saturating_sub(tile) / 2);
    let (tw, th) = (tile.min(cw), tile.min(ch));
    let bands =
        super::line_stage(d.chosen.sectors, d.chosen.direction_tolerance).bands(dem.dx, dem.dy);
    let enc = d.chosen.encoding;
    let mut angles = vec![0f32; cw * ch];
    let mut centre: Vec<Vec<f32>> = Vec::with_capacity(bands.len());
    let (mut raw, mut stored) = (0u64, 0u64);
    for band in &bands {
        let BandKind::Line(dir) = &band.kind else {
            continue;
        };
        line_horizons(&terrain, dir, &mut angles);
        let degs: Vec<f32> = (ty..ty + th)
            .flat_map(|r| angles[r * cw + tx..r * cw + tx + tw].iter().copied())
            .collect();
        let tiles = crate::stages::horizons::encode_angles(enc, &degs, tw, tile, Codec::Zstd);
        raw += tiles.iter().map(|t| u64::from(t.raw_len)).sum::<u64>();
        stored += tiles.iter().map(|t| t.bytes.len() as u64).sum::<u64>();
        centre.push(degs);
    }
    let azimuths: Vec<f64> = bands.iter().map(|b| b.azimuth).collect();
    let integrals = BandIntegrals::of_azimuths(&azimuths);
    let svf: Vec<f32> = (0..tw * th)
        .map(|i| svf_of_horizons(&integrals, centre.iter().map(|b| f64::from(b[i]))) as f32)
        .collect();
    let (sky_raw, sky_stored) = tile_bytes(&svf, tw, tile, f32::NAN);
    (
        stored as f64 / raw.max(1) as f64,
        sky_stored as f64 / sky_raw.max(1) as f64,
    )
}

/// Raw and zstd-stored bytes of `values` (rows `width` wide) as tiles.
fn tile_bytes<T: terrabake_format::Element>(
    values: &[T],
    width: usize,
    tile: usize,
    fill: T,
) -> (u64, u64) {
    let tiles = encode_tile_row(values, width, tile, fill, Codec::Zstd);
    (
        tiles.iter().map(|t| u64::from(t.raw_len)).sum(),
        tiles.iter().map(|t| t.bytes.len() as u64).sum(),
    )
}
