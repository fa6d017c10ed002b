//! The fuzz targets: what a hostile asset or source may do to the reader
//! and to ingest. Shared by the fixed-iteration loop in `tests/fuzz.rs`
//! (`make test`) and the coverage-guided cargo-fuzz targets in `fuzz/`
//! (`make fuzz`), so both exercise the same code. A target passes when it
//! returns: an error is fine, a panic, an abort or a hang is a failure.
#![allow(dead_code)]

use std::collections::HashMap;
use std::path::Path;

use terrabake_format::horizons::HorizonMap;
use terrabake_format::trace::{Method, Ray, Tracer};
use terrabake_format::Asset;

/// A small asset with every layer the pipeline writes (heights, pyramid,
/// cone planes, horizons, sky layers), baked into `dir` and read back as
/// file name -> bytes: the seed every reader input mutates.
pub fn seed_asset(dir: &Path) -> HashMap<String, Vec<u8>> {
    use terrabake::plumbing::progress::Progress;
    let tif = dir.join("seed.tif");
    terrabake::io::synth::write_geotiff(
        &tif,
        terrabake::io::synth::SynthKind::Fractal,
        40,
        36,
        3,
        Progress::hidden(),
    )
    .expect("seed DEM");
    let recipe = dir.join("seed.toml");
    std::fs::write(
        &recipe,
        "[ingest]\ntile = 16\ncodec = \"zstd\"\n[[stage]]\nname = \"pyramid\"\n[[stage]]\nname = \"cones\"\nslices = 4\nencoding = \"u16\"\n[[stage]]\nname = \"horizons\"\nsectors = 6\n[[stage]]\nname = \"sky\"\n",
    )
    .expect("seed recipe");
    let asset = dir.join("seed.tbake");
    let recipe = terrabake::bake::recipe::Recipe::load(&recipe).expect("recipe");
    terrabake::bake::recipe::bake(
        &tif,
        &asset,
        &recipe,
        Default::default(),
        Progress::hidden(),
    )
    .expect("seed bake");
    std::fs::read_dir(&asset)
        .expect("seed asset")
        .map(|e| e.expect("entry"))
        .filter(|e| e.file_name() != terrabake_format::LOCK_FILE)
        .map(|e| {
            let name = e.file_name().into_string().expect("name");
            (name, std::fs::read(e.path()).expect("read"))
        })
        .collect()
}

/// Applies the edits that `ops` encodes to the seed's files, then reads
/// the result every way a renderer would. Each op is 8 bytes: which file,
/// what to do (overwrite a byte, flip a bit, truncate, copy a run of bytes
/// from elsewhere in the file, set a number in the manifest's JSON to an
/// extreme, or reseal), where, and a value. Resealing recomputes every
/// checksum afterwards, so the reader meets absurd values behind valid
/// checksums, not only the checksum errors that stop it at the door.
pub fn reader(seed: &HashMap<String, Vec<u8>>, ops: &[u8]) -> bool {
    let mut names: Vec<&String> = seed.keys().collect();
    names.sort();
    let mut files: HashMap<String, Vec<u8>> = seed.clone();
    let mut reseal = false;
    for op in ops.chunks_exact(8) {
        let name = names[op[0] as usize % names.len()];
        let at = u32::from_le_bytes([op[2], op[3], op[4], op[5]]) as usize;
        let value = op[6];
        match op[1] % 9 {
            6 | 7 => {
                edit_manifest_number(&mut files, at, value);
                reseal = true;
                continue;
            }
            8 => {
                reseal = true;
                continue;
            }
            _ => {}
        }
        let bytes = files.get_mut(name).expect("named");
        if bytes.is_empty() {
            continue;
        }
        let at = at % bytes.len();
        match op[1] % 9 {
            0 => bytes[at] = value,
            1 => bytes[at] ^= 1 << (value % 8),
            2 => bytes.truncate(at),
            3 => {
                let from = (at + value as usize * 31) % bytes.len();
                let n = (op[7] as usize)
                    .min(bytes.len() - at)
                    .min(bytes.len() - from);
                bytes.copy_within(from..from + n, at);
            }
            // Values a checker might forget: 0, all ones, sign bits.
            4 => bytes[at] = [0x00, 0xff, 0x7f, 0x80][value as usize % 4],
            _ => {
                // A little-endian u32 of an extreme value (sizes, counts).
                let v = [0u32, 1, u32::MAX, 0x8000_0000, 4096][value as usize % 5];
                let end = (at + 4).min(bytes.len());
                bytes[at..end].copy_from_slice(&v.to_le_bytes()[..end - at]);
            }
        }
    }
    if reseal {
        reseal_checksums(&mut files);
    }
    read_everything(files)
}

/// Sets the `at`-th number of the manifest's JSON to an extreme value.
fn edit_manifest_number(files: &mut HashMap<String, Vec<u8>>, at: usize, value: u8) {
    let Some(bytes) = files.get_mut(terrabake_format::MANIFEST_FILE) else {
        return;
    };
    let Ok(mut json) = serde_json::from_slice::<serde_json::Value>(bytes.get(32..).unwrap_or(&[]))
    else {
        return;
    };
    fn count(v: &serde_json::Value) -> usize {
        match v {
            serde_json::Value::Number(_) => 1,
            serde_json::Value::Array(a) => a.iter().map(count).sum(),
            serde_json::Value::Object(o) => o.values().map(count).sum(),
            _ => 0,
        }
    }
    /// Replaces the `n`-th number (depth first); true once done.
    fn set_nth(v: &mut serde_json::Value, n: &mut usize, new: &serde_json::Value) -> bool {
        match v {
            serde_json::Value::Number(_) if *n == 0 => {
                *v = new.clone();
                true
            }
            serde_json::Value::Number(_) => {
                *n -= 1;
                false
            }
            serde_json::Value::Array(a) => a.iter_mut().any(|x| set_nth(x, n, new)),
            serde_json::Value::Object(o) => o.values_mut().any(|x| set_nth(x, n, new)),
            _ => false,
        }
    }
    let total = count(&json);
    if total == 0 {
        return;
    }
    let extremes = [
        0.0,
        -1.0,
        1.0,
        1e300,
        -1e300,
        1e-30,
        4096.0,
        4294967296.0,
        0.5,
        65535.0,
    ];
    let new = serde_json::json!(extremes[value as usize % extremes.len()]);
    set_nth(&mut json, &mut (at % total), &new);
    let text = serde_json::to_vec(&json).expect("serialises");
    bytes.truncate(32);
    bytes.extend_from_slice(&text);
}

/// Recomputes every checksum (tiles, index, headers, the manifest's
/// bindings and its own), leaving every value as the edits made it.
fn reseal_checksums(files: &mut HashMap<String, Vec<u8>>) {
    use terrabake_format::layout::xxh3;
    let le64 = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().expect("8"));
    let mut bindings = HashMap::new();
    for (name, b) in files.iter_mut() {
        if name == terrabake_format::MANIFEST_FILE || b.len() < 128 {
            continue;
        }
        let header = xxh3(&b[..56]);
        b[56..64].copy_from_slice(&header.to_le_bytes());
        let f = b.len() - 64;
        b[f + 24..f + 32].copy_from_slice(&header.to_le_bytes());
        let (index_offset, count) = (le64(b, f) as usize, le64(b, f + 8) as usize);
        let index_ok = count
            .checked_mul(32)
            .and_then(|n| n.checked_add(index_offset))
            .is_some_and(|end| end == f);
        if !index_ok {
            continue;
        }
        for i in 0..count {
            let e = index_offset + i * 32;
            let (off, len) = (le64(b, e) as usize, le64(b, e + 8) as usize);
            if let Some(stored) = off.checked_add(len).and_then(|end| b.get(off..end)) {
                let sum = xxh3(stored);
                b[e + 24..e + 32].copy_from_slice(&sum.to_le_bytes());
            }
        }
        let index = xxh3(&b[index_offset..f]);
        b[f + 16..f + 24].copy_from_slice(&index.to_le_bytes());
        bindings.insert(name.clone(), (b.len() as u64, format!("{index:016x}")));
    }
    let Some(m) = files.get_mut(terrabake_format::MANIFEST_FILE) else {
        return;
    };
    if m.len() < 32 {
        return;
    }
    if let Ok(mut json) = serde_json::from_slice::<serde_json::Value>(&m[32..]) {
        if let Some(layers) = json["layers"].as_array_mut() {
            for l in layers {
                let file = l["file"].as_str().unwrap_or_default().to_string();
                if let Some((len, index)) = bindings.get(&file) {
                    l["file_len"] = (*len).into();
                    l["index_xxh3"] = index.clone().into();
                }
            }
        }
        let text = serde_json::to_vec(&json).expect("serialises");
        m.truncate(32);
        m.extend_from_slice(&text);
    }
    let json_len = (m.len() - 32) as u64;
    let sum = xxh3(&m[32..]);
    m[16..24].copy_from_slice(&json_len.to_le_bytes());
    m[24..32].copy_from_slice(&sum.to_le_bytes());
}

/// Opens an asset from bytes and reads it every way a renderer would:
/// verify, every tile of every layer, tracing with every method, the
/// horizon map. Returns whether the asset opened.
pub fn read_everything(files: HashMap<String, Vec<u8>>) -> bool {
    let Ok(asset) = Asset::from_files("fuzz", files) else {
        return false;
    };
    let _ = asset.verify();
    for layer in asset.layers() {
        for band in 0..layer.bands().min(4) {
            for ty in 0..layer.tiles_y().min(8) {
                for tx in 0..layer.tiles_x().min(8) {
                    let _ = match layer.entry().elem.size() {
                        4 => layer.tile::<f32>(band, tx, ty).map(|t| t.len()),
                        2 => layer.tile::<u16>(band, tx, ty).map(|t| t.len()),
                        _ => layer.tile::<u8>(band, tx, ty).map(|t| t.len()),
                    };
                }
            }
        }
    }
    if let Ok(h) = asset.height() {
        let _ = h.bilinear(3.25, 2.5);
        let _ = h.bilinear(f64::from(h.width()) - 1.0, f64::from(h.height()) - 1.0);
    }
    if let Ok(tracer) = Tracer::new(&asset) {
        let (xmax, ymax) = tracer.extent();
        for i in 0..8 {
            let f = f64::from(i) / 8.0;
            let ray = Ray {
                origin: [xmax * f, ymax * (1.0 - f), 500.0 + 100.0 * f],
                dir: [0.3 - f, f - 0.6, -0.1 - f * 0.2],
                t_min: 0.0,
                t_max: f64::INFINITY,
            };
            for method in Method::ALL {
                let _ = tracer.trace(&ray, method);
            }
        }
    }
    if let Ok(map) = HorizonMap::open(&asset) {
        for (x, y) in [(0, 0), (5, 7), (39, 35)] {
            let _ = map.lit_fraction(x, y, 135.0, 10.0, 0.27);
            let _ = map.horizon_at(x, y, 359.9);
        }
    }
    true
}

/// Ingests `data` as a DEM file (named by `ext`) into a fresh asset under
/// `dir`, with a 64 MiB memory budget; a source that ingests must give an
/// asset that verifies.
/// Returns whether the source ingested.
pub fn ingest(data: &[u8], ext: &str, dir: &Path) -> bool {
    let src = dir.join(format!("input.{ext}"));
    let out = dir.join("out.tbake");
    let _ = std::fs::remove_dir_all(&out);
    std::fs::write(&src, data).expect("write input");
    // Huge sparse rasters ingest correctly, just slowly: the fuzzer keeps
    // to inputs it can run a thousand of.
    let small = terrabake::io::source::open(&src, None, 16, 64 << 20)
        .is_ok_and(|s| u64::from(s.info().width) * u64::from(s.info().height) <= 1 << 20);
    if !small {
        return false;
    }
    let opts = terrabake::stages::ingest::IngestOptions {
        tile_size: 16,
        max_memory: 64 << 20,
        ..Default::default()
    };
    let hidden = terrabake::plumbing::progress::Progress::hidden();
    if terrabake::stages::ingest::ingest(&src, &out, &opts, hidden).is_err() {
        return false;
    }
    let asset = Asset::open(&out).expect("an ingested asset opens");
    let report = asset.verify();
    assert!(report.problems.is_empty(), "{:?}", report.problems);
    true
}
