//! # terrabake
//!
//! The pipeline that turns DEMs into terrabake assets. The asset format and
//! its reader live in `terrabake-format`; this crate reads sources, runs the
//! bake stages and writes their layers, and hosts the CLI (`src/main.rs`).
//! Its rooms, from the bottom up (a room imports only the rooms listed
//! before it; ARCHITECTURE.md maps them, and `tests/architecture.rs` holds
//! the order and checks the map against the folders):
//!
//! - [`error`]: the library's [`Error`] and its [`ErrorKind`], which the
//!   entry points return (anyhow inside, with its chain of causes).
//! - [`plumbing`]: the process's edges: files written whole or not at all,
//!   parallel work in a fixed order, Ctrl-C, free disk and memory, progress.
//! - [`terrain`]: the shared terrain kernel: the grid the algorithms see
//!   ([`terrain::Terrain`]), a DEM held in memory, geodesy, tile rows, the sun.
//! - [`io`]: DEM readers row band by row band, the one GeoTIFF writer,
//!   synthetic terrains.
//! - [`algorithms`]: the papers' algorithms, pure functions over slices.
//! - [`views`]: the built-in cameras over an asset and their primary rays,
//!   the one tracing workload that renders, plans, checks and benchmarks time.
//! - [`stage`]: the stage interface, the asset's writer lock and the flag
//!   parsers every stage's parameters use.
//! - [`stages`]: ingest, pyramid, cones, horizons, sky, viewsheds.
//! - [`plan`]: the error budget: the planner, the exact references, `check`.
//! - [`bake`]: recipes, the registry above the stages, partitioned bakes.
//! - [`present`]: renders, shaded maps, legends, the demo page, the text
//!   the command line prints.
//! - [`export`]: layers out as GeoTIFF, OpenEXR, PNG, GRASS and engine
//!   textures.
//! - [`cli`]: the command line: its grammar and each command's run (the binary parses and runs with it).

pub mod algorithms;
pub mod bake;
pub mod cli;
pub mod error;
pub mod export;
pub mod io;
pub mod plan;
pub mod plumbing;
pub mod present;
pub mod stage;
pub mod stages;
pub mod terrain;
pub mod views;

pub use error::{Error, ErrorKind, Result};

/// `terrabake <version>`, recorded in every manifest.
pub(crate) fn tool_version() -> String {
    format!("terrabake {}", env!("CARGO_PKG_VERSION"))
}
