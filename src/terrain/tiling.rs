//! Cutting row bands into tiles: every stage produces its output one tile
//! row at a time (a band of `tile_size` rows across the whole grid) and hands
//! it here, which pads, encodes (in parallel) and appends the tiles in order.

use rayon::prelude::*;
use terrabake_format::writer::ZSTD_LEVEL;
use terrabake_format::{encode_tile, Codec, Element, EncodedTile, LayerWriter};
use zerocopy::IntoBytes;

/// Consecutive bands of at most `rows` rows covering `0..height`, north to
/// south.
pub(crate) fn row_bands(height: usize, rows: usize) -> Vec<std::ops::Range<usize>> {
    (0..height)
        .step_by(rows)
        .map(|r0| r0..(r0 + rows).min(height))
        .collect()
}

/// Appends one row of tiles taken from `band`, a row-major block of
/// `width x rows` elements (`rows <= tile_size`; the last band of a grid may
/// be short). Elements past the grid are `fill`; tiles are in the layer's
/// codec.
pub fn push_tile_row<T: Element>(
    writer: &mut LayerWriter,
    band: &[T],
    width: usize,
    fill: T,
) -> terrabake_format::Result<()> {
    let (ts, codec) = (writer.spec().tile_size as usize, writer.spec().codec);
    for tile in encode_tile_row(band, width, ts, fill, codec) {
        writer.push(tile)?;
    }
    Ok(())
}

/// Appends one row of tiles of the layer's fill value: a row that another
/// part of a partitioned bake computes.
pub(crate) fn push_fill_row(writer: &mut LayerWriter) -> terrabake_format::Result<()> {
    for _ in 0..writer.spec().tiles_x() {
        writer.push_fill_at(writer.chunks_written())?;
    }
    Ok(())
}

/// The tiles (west to east) of one row band, encoded in parallel: for
/// [`LayerWriter::push_at`] when tile rows come out of order.
pub(crate) fn encode_tile_row<T: Element>(
    band: &[T],
    width: usize,
    ts: usize,
    fill: T,
    codec: Codec,
) -> Vec<EncodedTile> {
    let rows = band.len() / width;
    debug_assert!(rows <= ts && band.len() == rows * width);
    let tiles_x = width.div_ceil(ts);
    (0..tiles_x)
        .into_par_iter()
        .map(|tx| {
            let x0 = tx * ts;
            let w = ts.min(width - x0);
            let mut tile = vec![fill; ts * ts];
            for y in 0..rows {
                tile[y * ts..y * ts + w].copy_from_slice(&band[y * width + x0..y * width + x0 + w]);
            }
            encode_tile(tile.as_bytes(), size_of::<T>(), codec, ZSTD_LEVEL)
        })
        .collect()
}
