//! The library's error: what went wrong, with its chain of causes, and a
//! kind a caller can act on without reading the message, as
//! `std::io::Error` pairs an `ErrorKind` with its payload.
//!
//! Everything public returns [`Result`]: the entry points, the
//! [`Stage`](crate::stage::Stage) trait a stage implements and the
//! [`Run`](crate::stage::session::Run) trait a command implements.
//! Private work inside the pipeline returns `anyhow::Result` and adds
//! context as it unwinds (`?` turns it into an [`Error`], and this module's
//! `bail!` and `ensure!` serve both); the kinds come from typed errors in
//! that chain: the format crate's [`terrabake_format::Error`] (the
//! asset), a [`Shortage`] of memory or disk, and the marks [`mark`] puts
//! where a source DEM or a parameter is at fault. [`error_chain`] is how
//! the chain reads on one line, for the command line, Python and
//! [`Error`]'s `Display` alike. The Python package raises one exception
//! class a kind, and a Rust caller can match on [`Error::kind`].

use std::fmt;

/// What kind of failure an [`Error`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The asset is missing, damaged, of another format version, or lacks
    /// a layer the work needs ([`Error::format_error`] has the details).
    Asset,
    /// The source DEM cannot be read: missing, unreadable, or a header or
    /// value that terrabake refuses.
    Source,
    /// A parameter or request that makes no sense (what a stage's check or
    /// a budget's validation refuses), before any work.
    Parameters,
    /// Not enough memory or disk for the work asked.
    Resources,
    /// Anything else: the message says what.
    Other,
}

/// A failure of the library, its causes and its [`ErrorKind`].
#[derive(Debug)]
pub struct Error {
    kind: ErrorKind,
    inner: anyhow::Error,
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn kind(&self) -> ErrorKind {
        self.kind
    }

    /// The format crate's error behind an [`ErrorKind::Asset`] failure.
    pub fn format_error(&self) -> Option<&terrabake_format::Error> {
        self.inner.chain().find_map(|c| c.downcast_ref())
    }

    /// The whole chain as `anyhow` holds it (for `{:?}` and downcasts).
    pub fn as_anyhow(&self) -> &anyhow::Error {
        &self.inner
    }

    /// The chain, for work that goes on adding context to it.
    pub fn into_anyhow(self) -> anyhow::Error {
        self.inner
    }
}

impl fmt::Display for Error {
    /// The message and its causes on one line ([`error_chain`]).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&error_chain(&self.inner))
    }
}

/// An error and its causes on one line, each cause said once: a cause
/// whose text an outer message already carries (an OS error that the
/// format's message quotes) is not repeated.
pub fn error_chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.inner.source()
    }
}

impl From<anyhow::Error> for Error {
    /// The kind of the first mark in the chain, else of the first typed
    /// error that has one.
    fn from(inner: anyhow::Error) -> Self {
        let kind = inner
            .chain()
            .find_map(|c| {
                if let Some(m) = c.downcast_ref::<Marked>() {
                    Some(m.kind)
                } else if let Some(e) = c.downcast_ref::<Error>() {
                    Some(e.kind)
                } else if c.is::<terrabake_format::Error>() {
                    Some(ErrorKind::Asset)
                } else if c.is::<Shortage>() {
                    Some(ErrorKind::Resources)
                } else {
                    None
                }
            })
            .unwrap_or(ErrorKind::Other);
        Self { kind, inner }
    }
}

/// `?` on the typed errors public functions meet most: each becomes the
/// one cause of its chain, its kind found as for any chain.
macro_rules! from_typed {
    ($($typed:ty),+) => {$(
        impl From<$typed> for Error {
            fn from(e: $typed) -> Self {
                anyhow::Error::new(e).into()
            }
        }
    )+};
}

from_typed!(
    terrabake_format::Error,
    Shortage,
    std::io::Error,
    serde_json::Error
);

/// `anyhow::bail!` for a function that returns either [`Result`] or
/// `anyhow::Result`: the message becomes the error the function returns.
macro_rules! bail {
    ($($message:tt)+) => {
        return ::core::result::Result::Err(::anyhow::anyhow!($($message)+).into())
    };
}

/// `anyhow::ensure!` for a function that returns either [`Result`] or
/// `anyhow::Result`.
macro_rules! ensure {
    ($condition:expr, $($message:tt)+) => {
        if !$condition {
            $crate::error::bail!($($message)+);
        }
    };
}

pub(crate) use {bail, ensure};

/// `e`, marked as a failure of `kind` (a source DEM's, a parameter's):
/// its message and causes unchanged.
pub(crate) fn mark(kind: ErrorKind, e: impl Into<anyhow::Error>) -> anyhow::Error {
    anyhow::Error::new(Marked {
        kind,
        inner: e.into(),
    })
}

/// An error marked with its kind; it reads as the error it carries.
#[derive(Debug)]
struct Marked {
    kind: ErrorKind,
    inner: anyhow::Error,
}

impl fmt::Display for Marked {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&self.inner, f)
    }
}

impl std::error::Error for Marked {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.inner.source()
    }
}

/// Work refused before it starts: it needs more memory or disk than the
/// machine has (an [`ErrorKind::Resources`] failure).
#[derive(Debug, Clone, PartialEq)]
pub struct Shortage {
    /// The work, as the message names it.
    pub what: String,
    /// `memory` or `disk`.
    pub resource: &'static str,
    /// Bytes it needs, and bytes there are.
    pub needed: u64,
    pub available: u64,
    /// The file system's directory, for disk.
    pub place: Option<std::path::PathBuf>,
}

impl std::fmt::Display for Shortage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let gib = |b: u64| format!("{:.1} GiB", b as f64 / f64::from(1u32 << 30));
        let (what, needed, available) = (&self.what, gib(self.needed), gib(self.available));
        match &self.place {
            Some(dir) => write!(
                f,
                "{what} needs {needed}, and {} has {available} free",
                dir.display()
            ),
            None => write!(
                f,
                "{what} needs about {needed} of {}, and {available} is available",
                self.resource
            ),
        }
    }
}

impl std::error::Error for Shortage {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds_come_from_marks_and_typed_causes_and_messages_stay() {
        let plain = anyhow::anyhow!("a cause").context("what failed");
        let e = Error::from(plain);
        assert_eq!(e.kind(), ErrorKind::Other);
        assert_eq!(e.to_string(), "what failed: a cause");
        let marked = mark(
            ErrorKind::Parameters,
            anyhow::anyhow!("sectors = 2").context("horizons"),
        );
        let e = Error::from(marked.context("bake"));
        assert_eq!(e.kind(), ErrorKind::Parameters);
        assert_eq!(e.to_string(), "bake: horizons: sectors = 2");
        let shortage = Shortage {
            what: "holding the DEM".into(),
            resource: "memory",
            needed: 8 << 30,
            available: 1 << 30,
            place: None,
        };
        let e = Error::from(anyhow::Error::new(shortage).context("horizons"));
        assert_eq!(e.kind(), ErrorKind::Resources);
        let format = terrabake_format::Error::NoLayer {
            asset: "a.tbake".into(),
            name: "horizon".into(),
            level: 0,
            available: Vec::new(),
        };
        let e = Error::from(anyhow::Error::new(format));
        assert_eq!(e.kind(), ErrorKind::Asset);
        assert!(e.format_error().is_some());
    }

    #[test]
    fn an_error_chain_says_each_cause_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file or directory");
        let e = anyhow::Error::new(io)
            .context("x/manifest.tba: No such file or directory")
            .context("x: cannot open asset");
        assert_eq!(
            error_chain(&e),
            "x: cannot open asset: x/manifest.tba: No such file or directory"
        );
    }
}
