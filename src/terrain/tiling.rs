//! Cutting row bands into tiles: every stage produces its output one tile
//! row at a time (a band of `tile_size` rows across the whole grid) and hands
//! it here, which pads, encodes (in parallel) and appends the tiles in order.
//! A stage that reads a mapped layer a tile row at a time gives the row's
//! pages back behind itself here too ([`release_tile_row`]).

use rayon::prelude::*;
use terrabake_format::writer::ZSTD_LEVEL;
use terrabake_format::{encode_tile, Codec, Element, EncodedTile, Layer, LayerWriter, Mmap};
use zerocopy::IntoBytes;

/// Consecutive bands of at most `rows` rows covering `0..height`, north to
/// south.
pub(crate) fn row_bands(height: usize, rows: usize) -> Vec<std::ops::Range<usize>> {
    (0..height)
        .step_by(rows)
        .map(|r0| r0..(r0 + rows).min(height))
        .collect()
}

/// Gives the kernel back the mapped pages of tile row `ty` of every band
/// of `layer`, read and not needed again: a stage that reads a layer a
/// tile row at a time otherwise keeps the whole layer resident, which a
/// planned bake's peak memory counts (the sky stage grew to 195 MiB on a
/// 2048² fractal at 16 u16 directions, against the 142 its bake planned;
/// 83 with this). Each band's tile row is one run of chunks in the file
/// (`(band * tiles_y + ty) * tiles_x + tx`); a layer written in another
/// order keeps its pages.
pub(crate) fn release_tile_row(layer: &Layer<Mmap>, ty: u32) -> terrabake_format::Result<()> {
    for band in 0..layer.bands() {
        let first = layer.stored_tile(band, 0, ty)?.bytes.as_ptr_range();
        let last = layer
            .stored_tile(band, layer.tiles_x() - 1, ty)?
            .bytes
            .as_ptr_range();
        if last.end >= first.start {
            // SAFETY: both ends lie in the layer's file, mapped read-only
            // (`Mmap`), and so does every byte between them.
            unsafe {
                let span = std::slice::from_raw_parts(
                    first.start,
                    last.end.offset_from(first.start) as usize,
                );
                crate::plumbing::pages::release_file_pages(span);
            }
        }
    }
    Ok(())
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
