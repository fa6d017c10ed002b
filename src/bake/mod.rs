//! Bakes above the stages: the registry and recipes that `bake` runs
//! ([`recipe`]), and partitioned bakes with the join that assembles them
//! ([`partition`]).

pub mod partition;
pub mod recipe;
