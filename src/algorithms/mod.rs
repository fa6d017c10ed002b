//! The papers' algorithms, pure functions over height slices that the
//! stages, the checks and the tests all call: horizons (Stewart's sectors,
//! Timonen's lines, sampled and brute-force references, the sky integrals),
//! the parameter planes of Paglieroni and Petersen, the exact distance
//! transforms they are sliced with, and visibility (observer and total
//! viewsheds). Nothing here reads or writes an asset.

pub mod edt;
pub mod horizon;
pub mod planes;
pub mod solar;
pub mod viewshed;
