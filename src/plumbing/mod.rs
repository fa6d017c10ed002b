//! The process's plumbing, beneath everything else: files written whole or
//! not at all ([`output`]), parallel work in a fixed order ([`ordered`]),
//! Ctrl-C ([`interrupt`]), free disk and memory ([`resources`]), progress
//! bars ([`progress`]), huge pages ([`pages`]) and the vector width cap
//! ([`simd`]).

pub mod interrupt;
pub mod ordered;
pub mod output;
pub mod pages;
pub mod progress;
pub mod resources;
pub mod simd;
