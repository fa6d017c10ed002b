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
