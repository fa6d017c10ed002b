//! DEMs in and GeoTIFFs out, knowing nothing of stages: the source readers
//! ([`source`]), the one GeoTIFF writer ([`cog`]) and synthetic terrains
//! ([`synth`]).

pub mod cog;
pub mod source;
pub mod synth;
