//! Visibility: one observer's viewshed on the two-triangle surface
//! ([`observer`]) and Timonen's total viewshed ([`total`], over the convex
//! hull tree of [`hull_tree`]). docs/VISIBILITY.md is the long form.

pub mod hull_tree;
pub mod observer;
pub mod total;
