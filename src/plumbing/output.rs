//! Files written whole or not at all.
//!
//! Every writer of a single output file (exports, pages, renders) goes
//! through [`write_atomically`]: a fresh, exclusively created temporary
//! beside the output, renamed over it on success, so a failed write never
//! leaves a half-written file where a good one stood, and a link planted at
//! a temporary name is never written through. No output goes inside an
//! asset directory: only the asset's writer writes there, under its lock.

use std::fs::{self, File};
use std::io::BufWriter;
use std::path::Path;

use anyhow::{Context, Result};

/// Writes `path` through a temporary file beside it
/// ([`terrabake_format::fsio::create_temp`]): `write` fills it, and it is
/// fsynced and renamed into place (replacing a link at `path`, never
/// writing through one); on error it is removed.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> crate::Result<()> {
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
    refuse_inside_asset(path, parent.unwrap_or(Path::new(".")))?;
    // A missing directory is made, as the asset writers make theirs.
    if let Some(parent) = parent {
        fs::create_dir_all(parent)
            .with_context(|| format!("{}: cannot create the directory", parent.display()))?;
    }
    let (file, tmp) = terrabake_format::fsio::create_temp(path).with_context(|| {
        format!(
            "{}: cannot create a temporary file beside it",
            path.display()
        )
    })?;
    let result = (|| -> Result<()> {
        let mut out = BufWriter::with_capacity(1 << 20, file);
        write(&mut out)?;
        let file = out.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        fs::rename(&tmp, path)
            .with_context(|| format!("{}: cannot rename into place", path.display()))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    Ok(result?)
}

/// Refuses an output whose directory `parent` is an asset (it holds a
/// manifest or a writer lock): `profile A --at .. -o A/manifest.tba` must
/// not replace the asset's own files behind its writer's back.
fn refuse_inside_asset(path: &Path, parent: &Path) -> Result<()> {
    use terrabake_format::{LOCK_FILE, MANIFEST_FILE};
    let is_asset = [MANIFEST_FILE, LOCK_FILE]
        .iter()
        .any(|f| fs::symlink_metadata(parent.join(f)).is_ok());
    if is_asset {
        crate::error::bail!(
            "{}: is inside the asset directory {}; only the asset's writer writes there. Write the output outside it",
            path.display(),
            parent.display()
        );
    }
    Ok(())
}

/// Writes the directory `path` whole or not at all: `write` fills a fresh
/// directory beside it, which is flushed to disk and then takes `path`'s
/// place (Linux exchanges the two in one step; elsewhere, or where the
/// file system cannot, the old one is moved aside first). The directory
/// that stood there is removed only after. A `path` that exists and is not
/// `what` (by `is_ours`: a Zarr store is replaced, a user's other
/// directory, a file or a link is not) is an error, and nothing is
/// written. An interrupt removes the fresh directory.
pub fn write_dir_atomically(
    path: &Path,
    what: &str,
    is_ours: impl Fn(&Path) -> bool,
    write: impl FnOnce(&Path) -> Result<()>,
) -> crate::Result<()> {
    let parent = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    refuse_inside_asset(path, parent)?;
    let existing = fs::symlink_metadata(path).ok();
    if let Some(m) = &existing {
        if !m.is_dir() || !is_ours(path) {
            crate::error::bail!(
                "{}: exists and is not {what}; not replacing it (remove it or write elsewhere)",
                path.display()
            );
        }
    }
    fs::create_dir_all(parent)
        .with_context(|| format!("{}: cannot create the directory", parent.display()))?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let unique = |kind: &str| {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        parent.join(format!(".{name}.{}-{nanos:08x}.{kind}", std::process::id()))
    };
    let fresh = unique("tmp");
    fs::create_dir(&fresh)
        .with_context(|| format!("{}: cannot create a directory beside it", path.display()))?;
    crate::plumbing::interrupt::scratch(fresh.clone());
    let result = write(&fresh).and_then(|()| {
        flush_file_system(&fresh)?;
        if existing.is_none() {
            return fs::rename(&fresh, path)
                .with_context(|| format!("{}: cannot rename into place", path.display()));
        }
        if exchange(&fresh, path).is_ok() {
            // `fresh` now names the old directory.
            return fs::remove_dir_all(&fresh)
                .with_context(|| format!("{}: cannot remove the old copy", fresh.display()));
        }
        let old = unique("old");
        fs::rename(path, &old).with_context(|| format!("{}: cannot move aside", path.display()))?;
        fs::rename(&fresh, path)
            .with_context(|| format!("{}: cannot rename into place", path.display()))?;
        fs::remove_dir_all(&old)
            .with_context(|| format!("{}: cannot remove the old copy", old.display()))
    });
    if result.is_err() {
        let _ = fs::remove_dir_all(&fresh);
    }
    Ok(result?)
}

/// Swaps two directories in one step (`renameat2`'s `RENAME_EXCHANGE`).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use rustix::fs::{renameat_with, RenameFlags, CWD};
    Ok(renameat_with(CWD, a, CWD, b, RenameFlags::EXCHANGE)?)
}

#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> std::io::Result<()> {
    Err(std::io::ErrorKind::Unsupported.into())
}

/// Flushes the file system holding `dir` (one `syncfs` for a directory
/// of many files, rather than an fsync each).
#[cfg(target_os = "linux")]
fn flush_file_system(dir: &Path) -> Result<()> {
    let d = File::open(dir)?;
    rustix::fs::syncfs(&d)?;
    Ok(())
}

#[cfg(not(target_os = "linux"))]
fn flush_file_system(_: &Path) -> Result<()> {
    Ok(())
}
