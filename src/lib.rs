//! # terrabake
//!
//! The pipeline that turns DEMs into terrabake assets. The asset format and
//! its reader live in `terrabake-format`; this crate reads sources, runs the
//! bake stages and writes their layers, and hosts the CLI (`src/main.rs`).
//!
//! - [`asset`]: an asset open for writing: its directory, its writer lock,
//!   and the reclaiming of a dead or failed writer's files.
//! - [`source`]: DEM readers (GeoTIFF, SRTM .hgt, raw, PNG, OpenEXR), row
//!   band by row band, never holding a whole DEM.
//! - [`ingest`]: the first stage: a source becomes the asset's `height` layer.
//! - [`stage`]: the stage interface (layers in, layers out, recorded in the
//!   manifest) and recipes, which `bake` runs in order, resumably.
//! - [`pyramid`]: the max/min pyramid stage, for hierarchical tracing.
//! - [`cones`]: the parameter-plane stage (cone apex and slope per cell),
//!   for parametric tracing.
//! - [`edt`]: exact Euclidean distance transforms (the cone stage's slices).
//! - [`horizon`]: the horizons stage (line, sector and sampled horizon maps,
//!   sky-view factors, openness) and its algorithms.
//! - [`ordered`]: parallel steps written in a fixed order, so that files
//!   do not depend on thread timing.
//! - [`render`]: perspective views traced through an asset (any method).
//! - [`shade`]: overhead maps shaded from stored horizons (sky, sun).
//! - [`bench`](mod@bench): the cone planes' speed against their bake time.
//! - [`synth`]: synthetic terrains for tests and benchmarks.
//! - [`export`]: layers out as GeoTIFF, OpenEXR or a PNG preview.

pub mod asset;
pub mod bench;
pub mod chart;
pub mod cones;
pub mod edt;
pub mod export;
pub mod geo;
pub mod horizon;
pub mod ingest;
pub mod ordered;
pub mod progress;
pub mod pyramid;
pub mod render;
pub mod shade;
pub mod source;
pub mod stage;
pub mod synth;
pub mod tiling;

/// `terrabake <version>`, recorded in every manifest.
pub fn tool_version() -> String {
    format!("terrabake {}", env!("CARGO_PKG_VERSION"))
}
