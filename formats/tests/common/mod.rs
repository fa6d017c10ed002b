//! Shared by the format crate's tests and benchmarks.
#![allow(dead_code)]

use terrabake_format::manifest::*;
use terrabake_format::{LayerEntry, FORMAT_VERSION};

/// A manifest for a `width x height` grid of tiles of `tile`, `dx x dy`
/// metres apart, with these layers, nodata count and height range.
pub fn manifest(
    (width, height, tile): (u32, u32, u32),
    (dx, dy): (f64, f64),
    layers: Vec<LayerEntry>,
    nodata: u64,
    height_range: Option<HeightRange>,
) -> Manifest {
    Manifest {
        format_version: FORMAT_VERSION,
        width,
        height,
        tile_size: tile,
        cell_size: CellSize {
            dx,
            dy,
            source: "given".into(),
        },
        georef: None,
        vertical: Vertical {
            units: "metre".into(),
            scale: 1.0,
            offset: 0.0,
        },
        nodata: Nodata {
            source_value: None,
            count: nodata,
        },
        height_range,
        provenance: Provenance {
            source: "test".into(),
            source_len: 0,
            source_format: "test".into(),
            tool: "test".into(),
            stages: vec![],
        },
        layers,
        retired: vec![],
    }
}
