//! What people look at: perspective views ([`render`]) of the built-in
//! cameras ([`crate::views`]), maps shaded from
//! horizons ([`shade`]), colour ramps and legends ([`legend`]), the demo
//! page ([`page`]), the text the command line prints ([`report`]) and one
//! point's exact horizon ([`profile`]).

pub mod image;
pub mod legend;
pub mod page;
pub mod profile;
pub mod render;
pub mod report;
pub mod shade;
