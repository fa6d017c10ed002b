//! What the command line prints about an asset and a stage run, for
//! people (`terrabake info`, the one-line stage summaries). Scripts read
//! `--json` instead, which is the manifest or the outcome as they are.

use std::path::Path;

use crate::plumbing::resources::human_bytes;
use crate::stage::StageOutcome;

/// Human-readable summary of a manifest.
/// What `terrabake info` prints: the summary, or the manifest as JSON.
pub fn info(path: &Path, json: bool) -> crate::Result<String> {
    let asset = crate::stage::asset::open(path)?;
    Ok(if json {
        serde_json::to_string_pretty(asset.manifest())? + "\n"
    } else {
        describe(path, asset.manifest())
    })
}

pub(crate) fn describe(path: &Path, m: &terrabake_format::Manifest) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let posts = u64::from(m.width) * u64::from(m.height);
    let _ = writeln!(s, "asset       {}", path.display());
    let _ = writeln!(s, "format      v{}", m.format_version);
    let _ = writeln!(
        s,
        "shape       {} x {} posts, tiles of {}",
        m.width, m.height, m.tile_size
    );
    let _ = writeln!(
        s,
        "cell size   {:.3} x {:.3} m ({})",
        m.cell_size.dx, m.cell_size.dy, m.cell_size.source
    );
    let _ = writeln!(
        s,
        "extent      0 .. {:.0} m east, 0 .. {:.0} m north of the south-west post (render's --camera and --look-at)",
        f64::from(m.width.saturating_sub(1)) * m.cell_size.dx,
        f64::from(m.height.saturating_sub(1)) * m.cell_size.dy
    );
    match &m.georef {
        Some(g) => {
            let epsg = g
                .epsg
                .map_or("no EPSG code".to_string(), |c| format!("EPSG:{c}"));
            let _ = writeln!(
                s,
                "georef      {:?}, {epsg}, pixel is {:?}",
                g.crs_kind, g.raster_type
            );
            let t = g.geotransform;
            let _ = writeln!(
                s,
                "            origin ({}, {}), pixel scale ({}, {})",
                t[0], t[3], t[1], t[5]
            );
        }
        None => {
            let _ = writeln!(s, "georef      none");
        }
    }
    let _ = writeln!(
        s,
        "heights     {} (x {} + {})",
        m.vertical.units, m.vertical.scale, m.vertical.offset
    );
    if let Some(r) = m.height_range {
        let _ = writeln!(s, "range       {} .. {}", r.min, r.max);
    }
    let _ = writeln!(
        s,
        "nodata      {} posts ({:.3} %), source value {}",
        m.nodata.count,
        100.0 * m.nodata.count as f64 / posts.max(1) as f64,
        m.nodata.source_value.as_deref().unwrap_or("none")
    );
    let _ = writeln!(s, "layers");
    for l in &m.layers {
        let _ = writeln!(
            s,
            "  {:<16} {:>4} x{} {:>6} x {:<6} {:?} {:>10} stored, {}/{} chunks constant  {}",
            l.key(),
            l.elem.name(),
            l.bands,
            l.width,
            l.height,
            l.codec,
            human_bytes(l.stored_bytes),
            l.constant_chunks,
            l.chunks,
            l.file
        );
        if !l.band_azimuths.is_empty() {
            let azimuths: Vec<String> = l.band_azimuths.iter().map(|a| format!("{a:.2}")).collect();
            let _ = writeln!(
                s,
                "  {:<16} band azimuths (deg): {}",
                "",
                azimuths.join(" ")
            );
        }
        if let Some(f) = l.features.as_ref().filter(|f| !f.posts.is_empty()) {
            let _ = writeln!(
                s,
                "  {:<16} features: {} post{} served exactly between bands, the highest-rising at ({}, {}), {} m",
                "",
                f.posts.len(),
                if f.posts.len() == 1 { "" } else { "s" },
                f.posts[0].x,
                f.posts[0].y,
                f.posts[0].z[0]
            );
        }
    }
    let _ = writeln!(
        s,
        "provenance  {} ({}, {} bytes), by {}",
        m.provenance.source, m.provenance.source_format, m.provenance.source_len, m.provenance.tool
    );
    for r in &m.provenance.stages {
        let _ = writeln!(
            s,
            "  stage {:<10} -> {}  {}",
            r.stage,
            r.outputs.join(", "),
            r.params
        );
    }
    s
}

/// What `terrabake verify` prints: each problem and a summary line, or the
/// JSON record `{asset, layers, chunks, ok, problems}`.
/// `terrabake verify ASSET [--same-as OTHER]`: what to print, and whether
/// all was well. An asset too damaged to open (a truncated layer or
/// manifest, a bad checksum, a link where a layer should be) is a problem
/// found, not an error; a path that holds no asset, or an asset of a newer
/// format, is an error.
pub fn verify_asset(
    path: &Path,
    same_as: Option<&Path>,
    json: bool,
) -> crate::Result<(String, bool)> {
    use anyhow::Context;
    if !path.join(terrabake_format::MANIFEST_FILE).exists() {
        crate::error::bail!(
            "{}: not an asset (it has no {})",
            path.display(),
            terrabake_format::MANIFEST_FILE
        );
    }
    let opened = match terrabake_format::Asset::open(path) {
        Ok(a) => a,
        Err(e @ terrabake_format::Error::Version { .. }) => {
            return Err(e)
                .with_context(|| format!("{}: cannot open asset", path.display()))
                .map_err(Into::into);
        }
        Err(e) => {
            let report = terrabake_format::VerifyReport {
                layers: 0,
                chunks: 0,
                problems: vec![e],
            };
            return Ok((verify(path, &report, &[], json)?, false));
        }
    };
    let report = opened.verify();
    let differences = match same_as {
        Some(other) => {
            crate::stage::same::differences(&opened, &crate::stage::asset::open(other)?)?
        }
        None => Vec::new(),
    };
    let good = report.problems.is_empty() && differences.is_empty();
    Ok((verify(path, &report, &differences, json)?, good))
}

/// `verify`'s report: the reader's problems, then how the values differ
/// from the asset given with `--same-as` (if one was).
pub fn verify(
    asset: &Path,
    report: &terrabake_format::VerifyReport,
    differences: &[String],
    json: bool,
) -> serde_json::Result<String> {
    let problems: Vec<String> = report
        .problems
        .iter()
        .map(|p| p.to_string())
        .chain(differences.iter().cloned())
        .collect();
    if json {
        let out = serde_json::json!({
            "asset": asset.display().to_string(),
            "layers": report.layers,
            "chunks": report.chunks,
            "ok": problems.is_empty(),
            "problems": problems,
        });
        return Ok(serde_json::to_string_pretty(&out)? + "\n");
    }
    let mut s: String = problems.iter().map(|p| format!("problem: {p}\n")).collect();
    let verdict = if problems.is_empty() {
        "all checksums and structure valid".to_string()
    } else {
        format!("{} problems", problems.len())
    };
    s += &format!(
        "{}: {} layers, {} chunks, {verdict}\n",
        asset.display(),
        report.layers,
        report.chunks
    );
    Ok(s)
}

/// `horizons --json`: the stage's outcome and what its layer holds.
pub fn horizons_json(
    outcome: &StageOutcome,
    entry: Option<&terrabake_format::LayerEntry>,
) -> serde_json::Result<serde_json::Value> {
    let mut v = serde_json::to_value(outcome)?;
    if let Some(e) = entry {
        v["horizon"] = serde_json::json!({
            "description": e.description,
            "encoding": e.elem.name(),
            "band_azimuths": e.band_azimuths,
            "features": e.features.as_ref().map_or(0, |f| f.posts.len()),
        });
    }
    Ok(v)
}

/// `ingest`'s summary line.
pub fn ingested(
    src: &Path,
    output: &Path,
    m: &terrabake_format::Manifest,
    took: std::time::Duration,
) -> String {
    let assumed = if m.cell_size.source == "assumed" {
        "\nnote: the source has no georeferencing: posts 1 m apart were assumed; give the spacing with --cell-size DX[,DY] (metres)"
    } else {
        ""
    };
    format!(
        "ingested {} ({} x {}, {} nodata) into {} in {:.2} s{assumed}",
        src.display(),
        m.width,
        m.height,
        m.nodata.count,
        output.display(),
        took.as_secs_f64()
    )
}
