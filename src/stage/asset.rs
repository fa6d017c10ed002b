//! An asset open for writing: its directory, prepared, and its writer lock,
//! held for as long as the value lives.
//!
//! Every command that writes an asset (ingest, each stage, a whole bake)
//! goes through [`AssetWriter::open`], which is where the rules of
//! `terrabake_format::writer` meet the command line:
//!
//! - the directory is created when missing, or accepted when it is empty, an
//!   asset, or holds nothing but a dead writer's leftovers (layer files,
//!   temporaries, the lock file): a kill during a first ingest never blocks
//!   the next run, while a stranger's non-empty folder is still refused;
//! - the writer lock is taken, waiting for its holder (with a message
//!   naming the pid) or failing at once when the user asked `--no-wait`;
//! - the garbage of dead writers is reclaimed under the lock before any
//!   work, and [`AssetWriter::fail`] reclaims a failed stage's own files, so
//!   a failure (out of space, say) never leaves files that make the retry
//!   fail too.

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use terrabake_format::{WriteLock, LOCK_FILE, MANIFEST_FILE};

use crate::error::bail;

/// An asset directory whose writer lock this process holds.
#[derive(Debug)]
pub struct AssetWriter {
    lock: WriteLock,
    path: PathBuf,
    /// This writer created the directory (removed again if nothing lands).
    created: bool,
}

/// Whether a writer should wait for another to finish, or fail at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Wait {
    #[default]
    Wait,
    NoWait,
}

impl Wait {
    /// From the command line's `--no-wait`.
    pub fn unless(no_wait: bool) -> Self {
        if no_wait {
            Wait::NoWait
        } else {
            Wait::Wait
        }
    }
}

impl AssetWriter {
    /// Opens the existing asset `dir` for writing (a stage's case).
    pub fn open(dir: &Path, wait: Wait) -> crate::Result<Self> {
        expect_directory(dir)?;
        match fs::symlink_metadata(dir.join(MANIFEST_FILE)) {
            Ok(meta) if meta.file_type().is_file() => {}
            Ok(_) => bail!(
                "{}: cannot open asset: {MANIFEST_FILE} is not a regular file (a link, FIFO, device or directory)",
                dir.display()
            ),
            Err(_) => bail!(
                "{}: cannot open asset: no {MANIFEST_FILE} (not an asset, or never ingested)",
                dir.display()
            ),
        }
        Ok(Self::lock(dir, wait, false)?)
    }

    /// Opens `dir` for an ingest: creates it when missing; accepts an empty
    /// directory, an asset, or the leftovers of a dead writer; refuses
    /// anything else rather than writing into a stranger's folder.
    pub fn create(dir: &Path, wait: Wait) -> crate::Result<Self> {
        let created = match fs::symlink_metadata(dir) {
            Err(_) => {
                fs::create_dir_all(dir).with_context(|| {
                    format!("{}: cannot create the asset directory", dir.display())
                })?;
                true
            }
            Ok(_) if !dir.is_dir() => {
                bail!("{}: exists and is not an asset directory", dir.display())
            }
            Ok(_) => {
                let foreign = fs::read_dir(dir)
                    .with_context(|| format!("{}: cannot list", dir.display()))?
                    .flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .find(|name| !is_asset_file(name));
                if let Some(name) = foreign {
                    bail!(
                        "{}: is a non-empty directory that is not an asset (it holds {name:?}); refusing to write an asset into it",
                        dir.display()
                    );
                }
                false
            }
        };
        Ok(Self::lock(dir, wait, created)?)
    }

    fn lock(dir: &Path, wait: Wait, created: bool) -> Result<Self> {
        let lock = WriteLock::acquire(dir, wait == Wait::Wait, |pid| {
            eprintln!(
                "{}: waiting for the writer that holds it (pid {}) to finish; --no-wait fails instead",
                dir.display(),
                pid.map_or("unknown".into(), |p| p.to_string())
            );
        })?;
        lock.reclaim_garbage()
            .with_context(|| format!("{}: cannot remove a dead writer's files", dir.display()))?;
        Ok(Self {
            lock,
            path: dir.to_path_buf(),
            created,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.path
    }

    pub(crate) fn lock_held(&self) -> &WriteLock {
        &self.lock
    }

    /// After a failed write: removes its files, and the directory itself when
    /// this writer created it and nothing was ever committed there.
    pub fn fail(&self) {
        let _ = self.lock.reclaim_garbage();
        if self.created && !self.path.join(MANIFEST_FILE).exists() {
            let _ = fs::remove_dir_all(&self.path);
        }
    }
}

/// Whether a file name is one a writer puts in an asset directory: the
/// manifest, the lock, and the names the format's writer gives layers and
/// temporaries (a user's `lineitem.tbl` is none of them).
fn is_asset_file(name: &str) -> bool {
    name == MANIFEST_FILE || name == LOCK_FILE || terrabake_format::fsio::is_reclaimable_name(name)
}

/// Opens the asset `path` for reading, with the command line's messages.
pub fn open(path: &Path) -> crate::Result<terrabake_format::Asset<terrabake_format::Mmap>> {
    let opened = expect_directory(path).and_then(|()| {
        terrabake_format::Asset::open(path)
            .with_context(|| format!("{}: cannot open asset", path.display()))
    });
    Ok(opened.map_err(|e| crate::error::mark(crate::ErrorKind::Asset, e))?)
}

/// Refuses `path` unless it is a directory: missing, or a file (a DEM,
/// most likely, which `ingest` makes an asset of), each said plainly.
fn expect_directory(path: &Path) -> Result<()> {
    if !path.exists() {
        bail!("{}: no such asset directory", path.display());
    }
    if !path.is_dir() {
        bail!(
            "{}: not an asset directory (a DEM? `terrabake ingest {} -o ASSET` makes one)",
            path.display(),
            path.display()
        );
    }
    Ok(())
}
