//! Nothing to link: this crate holds the criterion benchmarks (its
//! `[[bench]]` targets) apart from the crates they measure.
