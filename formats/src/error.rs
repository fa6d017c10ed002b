//! Errors carry what a user needs to find the problem: the file, the layer,
//! the tile, and what was expected against what was found.

use std::path::PathBuf;

/// Where in an asset a problem was found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    pub file: PathBuf,
    /// `name@level`, when the problem is inside a layer.
    pub layer: Option<String>,
    /// `(band, tx, ty)`, when the problem is inside a tile.
    pub tile: Option<(u32, u32, u32)>,
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(layer) = &self.layer {
            write!(f, ", layer {layer}")?;
        }
        if let Some((band, tx, ty)) = self.tile {
            write!(f, ", tile ({tx}, {ty}) band {band}")?;
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    #[error("{at}: {source}")]
    Io {
        at: Location,
        #[source]
        source: std::io::Error,
    },
    #[error("{at}: not a terrabake file (magic {got:?}, expected {expected:?})")]
    Magic {
        at: Location,
        expected: [u8; 8],
        got: [u8; 8],
    },
    #[error("{at}: format version {got} is not supported (this reader knows version {expected})")]
    Version {
        at: Location,
        expected: u32,
        got: u32,
    },
    #[error("{at}: checksum mismatch in {what} (stored {expected:#018x}, computed {got:#018x})")]
    Checksum {
        at: Location,
        what: &'static str,
        expected: u64,
        got: u64,
    },
    #[error("{at}: file is truncated or malformed: {what}")]
    Malformed { at: Location, what: String },
    #[error("{at}: manifest is not valid JSON for this format: {source}")]
    Manifest {
        at: Location,
        #[source]
        source: serde_json::Error,
    },
    #[error("{at}: cannot decompress tile: {source}")]
    Decompress {
        at: Location,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: asset has no layer {name}@{level}{}", asset.display(), if available.is_empty() { String::new() } else { format!(" (it has {})", available.join(", ")) })]
    NoLayer {
        /// The asset's directory.
        asset: std::path::PathBuf,
        name: String,
        level: u32,
        /// The layers the asset does have, `name@level`, when known.
        available: Vec<String>,
    },
    #[error("layer {layer} holds {stored} elements, not {requested}")]
    ElemType {
        layer: String,
        stored: &'static str,
        requested: &'static str,
    },
    #[error("layer {layer}: {what} ({index}) out of range (limit {limit})")]
    OutOfRange {
        layer: String,
        what: &'static str,
        index: u64,
        limit: u64,
    },
    #[error("invalid layer specification: {0}")]
    Spec(String),
    #[error("{}: another writer holds the asset (pid {}); wait for it, or run again later", dir.display(), pid.map_or("unknown".to_string(), |p| p.to_string()))]
    Locked {
        dir: PathBuf,
        /// The holder's process id, as it recorded it in the lock file.
        pid: Option<u32>,
    },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Location {
    pub fn file(file: impl Into<PathBuf>) -> Self {
        Self {
            file: file.into(),
            layer: None,
            tile: None,
        }
    }
    pub fn layer(file: impl Into<PathBuf>, layer: impl Into<String>) -> Self {
        Self {
            file: file.into(),
            layer: Some(layer.into()),
            tile: None,
        }
    }
    pub fn with_tile(mut self, tile: (u32, u32, u32)) -> Self {
        self.tile = Some(tile);
        self
    }
}

impl Error {
    pub(crate) fn malformed(at: Location, what: impl Into<String>) -> Self {
        Self::Malformed {
            at,
            what: what.into(),
        }
    }
}
