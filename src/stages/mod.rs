//! The bake stages, each one module with one entry point (a parameter
//! type that implements [`crate::stage::Stage`]): [`ingest`] creates the
//! asset, then [`pyramid`], [`cones`], [`horizons`], [`sky`] and
//! [`viewshed`]. A stage imports no other stage.

pub mod cones;
pub mod horizons;
pub mod ingest;
pub mod pyramid;
pub mod sky;
pub mod solar;
pub mod viewshed;
