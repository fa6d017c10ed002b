//! # terrabake
//!
//! The pipeline that turns DEMs into terrabake assets. The asset format and
//! its reader live in `terrabake-format`; this crate reads sources, runs the
//! bake stages and writes their layers, and hosts the CLI (`src/main.rs`).
//!
//! - [`args`]: value parsers for command-line flags (the CLI's and the
//!   stages' parameter types').
//! - [`asset`]: an asset open for writing: its directory, its writer lock,
//!   and the reclaiming of a dead or failed writer's files.
//! - [`source`]: DEM readers (GeoTIFF, SRTM .hgt, raw, PNG, OpenEXR), row
//!   band by row band, never holding a whole DEM.
//! - [`interrupt`]: Ctrl-C and SIGTERM: temporaries removed, a message,
//!   exit status 130.
//! - [`ingest`]: the first stage: a source becomes the asset's `height` layer.
//! - [`stage`]: the stage interface (layers in, layers out, recorded in the
//!   manifest), run under the asset's writer lock.
//! - [`recipe`]: the registry above the stages and the recipes that `bake`
//!   runs in order, resumably.
//! - [`pyramid`]: the max/min pyramid stage, for hierarchical tracing.
//! - [`cones`]: the parameter-plane stage (cone apex and slope per cell),
//!   for parametric tracing.
//! - [`edt`]: exact Euclidean distance transforms (the cone stage's slices).
//! - [`horizon`]: the horizons stage (line, sector and sampled horizon maps)
//!   and its algorithms.
//! - [`sky`]: the sky stage (sky-view factors, openness, the edge count)
//!   from the committed horizons.
//! - [`viewshed`]: observer viewsheds and Timonen's total viewshed (the
//!   `viewshed` and `total_viewshed` stages, `terrabake viewshed`).
//! - [`ordered`]: parallel steps written in a fixed order, so that files
//!   do not depend on thread timing.
//! - [`partition`]: partitioned bakes (one part of N, on any node) and the
//!   join that assembles them, bit for bit as one machine bakes.
//! - [`cli`]: the command line's grammar (the binary parses with it).
//! - [`report`]: what the command line prints for people.
//! - [`resources`]: free disk and available memory, checked before work
//!   that would need more.
//! - [`render`]: perspective views traced through an asset (any method).
//! - [`shade`]: overhead maps shaded from stored horizons (sky, sun).
//! - [`synth`]: synthetic terrains for tests and benchmarks.
//! - [`profile`]: the exact horizon around one point (`terrabake profile`).
//! - [`export`]: layers out as GeoTIFF, OpenEXR or a PNG preview.
//! - [`cog`]: the Cloud-Optimized GeoTIFF writer (tiled, band-interleaved,
//!   overviews, GDAL metadata), in one streaming pass.
//! - [`output`]: files written whole or not at all.
//! - [`simd`]: how wide the vector kernels may go (`TERRABAKE_SIMD`).

pub mod args;
pub mod asset;
pub mod budget;
pub mod check;
pub mod cli;
pub mod cog;
pub mod cones;
pub mod edt;
pub mod export;
pub mod geo;
pub mod horizon;
pub mod ingest;
pub mod interrupt;
pub mod legend;
pub mod ordered;
pub mod output;
pub mod page;
pub mod pages;
pub mod partition;
pub mod plan;
pub mod profile;
pub mod progress;
pub mod pyramid;
pub mod recipe;
pub mod reference;
pub mod render;
pub mod report;
pub mod resources;
pub mod shade;
pub mod simd;
pub mod sky;
pub mod source;
pub mod stage;
pub mod synth;
pub mod tiling;
pub mod viewshed;

/// `terrabake <version>`, recorded in every manifest.
pub fn tool_version() -> String {
    format!("terrabake {}", env!("CARGO_PKG_VERSION"))
}
