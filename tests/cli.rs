//! The `terrabake` binary end to end: synth -> ingest -> info/verify ->
//! export -> re-ingest, bake with a recipe (resumable), exit codes, and
//! errors that name the file.

mod common;

use std::path::Path;

use common::*;
use terrabake_format::{Asset, MANIFEST_FILE};

fn ok(args: &[&str]) -> String {
    let out = terrabake(args);
    assert!(
        out.status.success(),
        "terrabake {args:?} failed: {}",
        stderr(&out)
    );
    stdout(&out)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Writes `text` as a recipe next to `asset` and bakes `tif` into `asset`
/// with it.
fn bake_recipe(tif: &Path, asset: &Path, text: &str) -> std::process::Output {
    let recipe = asset.with_extension("toml");
    std::fs::write(&recipe, text).unwrap();
    terrabake(&["bake", s(tif), "-o", s(asset), "--recipe", s(&recipe), "-q"])
}

#[test]
fn every_synthetic_kind_ingests_verifies_and_round_trips_through_geotiff() {
    let dir = tempfile::tempdir().unwrap();
    for kind in [
        "fractal",
        "flat",
        "spike",
        "bowl",
        "sine",
        "blocks",
        "noise",
        "quantised",
        "holes",
    ] {
        let tif = dir.path().join(format!("{kind}.tif"));
        let asset = dir.path().join(format!("{kind}.tbake"));
        ok(&[
            "synth",
            kind,
            "--size",
            "150x97",
            "--seed",
            "5",
            "-o",
            s(&tif),
            "-q",
        ]);
        ok(&["ingest", s(&tif), "-o", s(&asset), "--tile", "32", "-q"]);
        ok(&["verify", s(&asset)]);
        let info: serde_json::Value =
            serde_json::from_str(&ok(&["info", s(&asset), "--json"])).unwrap();
        assert_eq!(info["width"], 150);
        assert_eq!(info["height"], 97);
        assert_eq!(info["cell_size"]["dx"], 30.0);
        let original = heights(&Asset::open(&asset).unwrap());
        for (x, y) in [(0u32, 0u32), (75, 48), (149, 96)] {
            let want = terrabake::io::synth::height(
                match kind {
                    "fractal" => terrabake::io::synth::SynthKind::Fractal,
                    "flat" => terrabake::io::synth::SynthKind::Flat,
                    "spike" => terrabake::io::synth::SynthKind::Spike,
                    "bowl" => terrabake::io::synth::SynthKind::Bowl,
                    "sine" => terrabake::io::synth::SynthKind::Sine,
                    "blocks" => terrabake::io::synth::SynthKind::Blocks,
                    "noise" => terrabake::io::synth::SynthKind::Noise,
                    "quantised" => terrabake::io::synth::SynthKind::Quantised,
                    _ => terrabake::io::synth::SynthKind::Holes,
                },
                x,
                y,
                150,
                97,
                5,
            );
            assert!(
                same_heights(original[(y * 150 + x) as usize], want),
                "{kind} ({x}, {y})"
            );
        }
        // GeoTIFF out and back in: same heights, georeferencing and nodata.
        let exported = dir.path().join(format!("{kind}_out.tif"));
        ok(&[
            "export",
            s(&asset),
            "--layer",
            "height",
            "-o",
            s(&exported),
            "-q",
        ]);
        let again = dir.path().join(format!("{kind}_again.tbake"));
        ok(&["ingest", s(&exported), "-o", s(&again), "-q"]);
        let (a, b) = (Asset::open(&asset).unwrap(), Asset::open(&again).unwrap());
        assert_eq!(a.manifest().georef, b.manifest().georef, "{kind}");
        assert_eq!(
            a.manifest().nodata.count,
            b.manifest().nodata.count,
            "{kind}"
        );
        let roundtrip = heights(&b);
        assert!(
            original
                .iter()
                .zip(&roundtrip)
                .all(|(x, y)| same_heights(*x, *y)),
            "{kind}: GeoTIFF round trip changed heights"
        );
    }
}

#[test]
fn srtm_geotiff_export_keeps_the_geotransform() {
    let dir = tempfile::tempdir().unwrap();
    let asset = dir.path().join("srtm.tbake");
    let src = repo_file("data/srtm3_n07w006_geographic_int16.tif");
    ok(&["ingest", s(&src), "-o", s(&asset), "-q"]);
    let out = dir.path().join("srtm.tif");
    ok(&["export", s(&asset), "-o", s(&out), "-q"]);
    let again = dir.path().join("again.tbake");
    ok(&["ingest", s(&out), "-o", s(&again), "-q"]);
    let (a, b) = (Asset::open(&asset).unwrap(), Asset::open(&again).unwrap());
    assert_eq!(a.manifest().georef, b.manifest().georef);
    assert_eq!(
        a.manifest().nodata.source_value,
        b.manifest().nodata.source_value
    );
    assert_eq!(heights(&a), heights(&b));
}

#[test]
fn png_and_exr_exports() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("holes.tif");
    let asset = dir.path().join("holes.tbake");
    ok(&["synth", "holes", "--size", "300x200", "-o", s(&tif), "-q"]);
    ok(&["ingest", s(&tif), "-o", s(&asset), "-q"]);
    let png_path = dir.path().join("relief.png");
    ok(&["export", s(&asset), "-o", s(&png_path), "-q"]);
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(&png_path).unwrap(),
    ));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    // The map, then its legend under it.
    let legend_rows = terrabake::present::legend::height(300);
    assert_eq!(
        (info.width, info.height, info.color_type),
        (300, 200 + legend_rows, png::ColorType::Rgba)
    );
    let original = heights(&Asset::open(&asset).unwrap());
    // Nodata is transparent, everything else opaque.
    for (i, z) in original.iter().enumerate() {
        assert_eq!(buf[i * 4 + 3] == 0, z.is_nan(), "pixel {i}");
    }
    // The legend is opaque, with text in black ink.
    let legend = &buf[300 * 200 * 4..];
    assert!(legend.chunks(4).all(|p| p[3] == 255));
    assert!(legend.chunks(4).filter(|p| p[..3] == [0, 0, 0]).count() > 100);
    let exr_path = dir.path().join("height.exr");
    ok(&["export", s(&asset), "-o", s(&exr_path), "-q"]);
    let back = dir.path().join("back.tbake");
    ok(&["ingest", s(&exr_path), "-o", s(&back), "-q"]);
    assert!(heights(&Asset::open(&back).unwrap())
        .iter()
        .zip(&original)
        .all(|(a, b)| same_heights(*a, *b)));
}

/// A stage asked for zstd tiles (`codec = "zstd"`) stores, chunk for
/// chunk, the bytes the raw bake stores, compressed; records the codec it
/// was asked for; and the asset verifies.
#[test]
fn zstd_layers_hold_the_raw_bake_chunk_for_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("holes.tif");
    ok(&[
        "synth",
        "holes",
        "--size",
        "150x97",
        "--seed",
        "3",
        "-o",
        s(&tif),
        "-q",
    ]);
    let recipe = |codec: &str| {
        format!(
            "[ingest]\ntile = 32\ncodec = \"{codec}\"\n\
             [[stage]]\nname = \"cones\"\nslices = 8\nencoding = \"u16\"\ncodec = \"{codec}\"\n\
             [[stage]]\nname = \"horizons\"\nsectors = 8\ndistance = true\ncodec = \"{codec}\"\n\
             [[stage]]\nname = \"sky\"\ncodec = \"{codec}\"\n\
             [[stage]]\nname = \"solar\"\ndays = \"172\"\nstep_minutes = 60\nlatitude = 40.0\ncodec = \"{codec}\"\n\
             [[stage]]\nname = \"total_viewshed\"\ndirections = 4\ncodec = \"{codec}\"\n\
             [[stage]]\nname = \"viewshed\"\nobservers = [[40.0, 30.0]]\ncrs = \"grid\"\ncodec = \"{codec}\"\n"
        )
    };
    let (raw, packed) = (dir.path().join("raw.tbake"), dir.path().join("zstd.tbake"));
    for (asset, codec) in [(&raw, "raw"), (&packed, "zstd")] {
        let out = bake_recipe(&tif, asset, &recipe(codec));
        assert!(out.status.success(), "{codec}: {}", stderr(&out));
    }
    ok(&["verify", s(&packed)]);
    let (raw, packed) = (Asset::open(&raw).unwrap(), Asset::open(&packed).unwrap());
    let mut compressed = std::collections::BTreeMap::new();
    for entry in &raw.manifest().layers {
        let (a, b) = (
            raw.layer(&entry.name, entry.level).unwrap(),
            packed.layer(&entry.name, entry.level).unwrap(),
        );
        let elem = entry.elem.size();
        for chunk in 0..a.entry().chunks {
            let want = a.stored_chunk(chunk).unwrap();
            assert_eq!(want.codec, terrabake_format::Codec::Raw);
            let got = b.stored_chunk(chunk).unwrap();
            let mut decoded = vec![0u8; got.raw_len as usize];
            assert_eq!(got.decode_into(elem, &mut decoded).unwrap(), decoded.len());
            assert!(
                decoded == want.bytes,
                "{} chunk {chunk} differs",
                entry.key()
            );
            *compressed.entry(format!("{:?}", got.codec)).or_insert(0) += 1;
        }
    }
    // Plain zstd (angle codes, counts) and shuffled zstd (floats) both
    // occur; the pyramid has no codec and stays raw.
    assert!(
        compressed.contains_key("Zstd") && compressed.contains_key("ShuffledZstd"),
        "{compressed:?}"
    );
    let record = |asset: &Asset<terrabake_format::Mmap>, stage: &str| {
        let records = &asset.manifest().provenance.stages;
        records
            .iter()
            .find(|r| r.stage == stage)
            .unwrap()
            .params
            .clone()
    };
    for stage in [
        "cones",
        "horizons",
        "sky",
        "solar",
        "total_viewshed",
        "viewshed",
    ] {
        assert_eq!(record(&packed, stage)["codec"], "zstd", "{stage}");
        assert!(
            record(&raw, stage).get("codec").is_none(),
            "{stage}: raw is not recorded"
        );
    }
    assert!(
        packed
            .manifest()
            .layers
            .iter()
            .map(|l| l.stored_bytes)
            .sum::<u64>()
            < raw
                .manifest()
                .layers
                .iter()
                .map(|l| l.stored_bytes)
                .sum::<u64>()
                * 2
                / 3
    );
}

#[test]
fn bake_is_resumable() {
    let dir = tempfile::tempdir().unwrap();
    let asset = dir.path().join("srtm.tbake");
    let src = repo_file("data/srtm3_n07w006_geographic_int16.tif");
    let recipe = repo_file("pipelines/demo.toml");
    let bake = |recipe: &Path| -> serde_json::Value {
        serde_json::from_str(&ok(&[
            "bake",
            s(&src),
            "-o",
            s(&asset),
            "--recipe",
            s(recipe),
            "--json",
            "-q",
        ]))
        .unwrap()
    };
    let first = bake(&recipe);
    assert_eq!(first[0]["stage"], "ingest");
    assert_eq!(first[0]["skipped"], false);
    let second = bake(&recipe);
    assert_eq!(
        second[0]["skipped"], true,
        "an up-to-date asset was baked again"
    );
    // A different recipe (zstd tiles) is a different ingest.
    let third = bake(&repo_file("pipelines/archive.toml"));
    assert_eq!(third[0]["skipped"], false);
    let a = Asset::open(&asset).unwrap();
    assert!(
        a.manifest().layers[0].stored_bytes < 1201 * 1201 * 4 / 2,
        "zstd should halve this DEM"
    );
    // Nothing else is left: the manifest, the writer lock, the layer files
    // it names, and the old generation it retired (kept a grace period for
    // readers that read the previous manifest; docs/RELIABILITY.md).
    let m = a.manifest();
    assert!(!m.retired.is_empty(), "the previous height file is retired");
    for entry in std::fs::read_dir(&asset).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        let known = name == "manifest.tba"
            || name == "writer.lock"
            || m.layers.iter().any(|l| l.file == name)
            || m.retired.iter().any(|r| r.file == name);
        assert!(known, "leftover {name}");
    }
}

#[test]
fn verify_fails_with_status_3_on_a_corrupt_tile() {
    let dir = tempfile::tempdir().unwrap();
    let asset = dir.path().join("a.tbake");
    ok(&[
        "ingest",
        s(&fixture("tiff/float32_strip_none.tif")),
        "-o",
        s(&asset),
        "--tile",
        "16",
        "-q",
    ]);
    let layer = std::fs::read_dir(&asset)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "tbl"))
        .unwrap();
    let mut bytes = std::fs::read(&layer).unwrap();
    bytes[64 + 200] ^= 0x10;
    std::fs::write(&layer, bytes).unwrap();
    let out = terrabake(&["verify", s(&asset), "--json"]);
    assert_eq!(out.status.code(), Some(3));
    let report: serde_json::Value = serde_json::from_str(&stdout(&out)).unwrap();
    assert_eq!(report["ok"], false);
    assert!(
        report["problems"][0]
            .as_str()
            .unwrap()
            .contains("tile (0, 0)"),
        "{report}"
    );

    // Truncated, the layer or the manifest cannot even be opened: still a
    // problem verify found (3), named; a directory with no asset is an
    // error (1).
    let manifest = asset.join(MANIFEST_FILE);
    for (file, keep) in [(&layer, 1000usize), (&manifest, 40)] {
        let good = std::fs::read(file).unwrap();
        std::fs::write(file, &good[..keep]).unwrap();
        let out = terrabake(&["verify", s(&asset)]);
        assert_eq!(out.status.code(), Some(3), "{}", stderr(&out));
        assert!(stdout(&out).contains("problem: "), "{}", stdout(&out));
        std::fs::write(file, good).unwrap();
    }
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let out = terrabake(&["verify", s(&empty)]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("not an asset"), "{}", stderr(&out));
}

#[test]
fn errors_name_the_file_and_exit_1() {
    let dir = tempfile::tempdir().unwrap();
    let bogus = dir.path().join("bogus.tif");
    std::fs::write(&bogus, "hello").unwrap();
    let out = terrabake(&["ingest", s(&bogus), "-o", s(&dir.path().join("x.tbake"))]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("bogus.tif") && stderr(&out).contains("not a TIFF"),
        "{}",
        stderr(&out)
    );
    assert!(!dir.path().join("x.tbake").exists());

    let out = terrabake(&["info", s(&dir.path().join("nowhere.tbake"))]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("nowhere.tbake"));

    let out = terrabake(&["synth", "fractal", "--size", "12by5", "-o", "x.tif"]);
    assert_eq!(out.status.code(), Some(2), "usage errors exit 2");

    let out = terrabake(&[
        "export",
        s(&dir.path().join("nowhere.tbake")),
        "-o",
        "x.bmp",
    ]);
    assert_eq!(out.status.code(), Some(1));

    // A layer or a stage that is missing: what there is, and what adds it.
    let tif = dir.path().join("t.tif");
    ok(&["synth", "fractal", "--size", "40x30", "-o", s(&tif), "-q"]);
    let bare = dir.path().join("bare.tbake");
    ok(&["ingest", s(&tif), "-o", s(&bare), "-q"]);
    let png = dir.path().join("x.png");
    let out = terrabake(&["export", s(&bare), "--layer", "nosuch", "-o", s(&png)]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("bare.tbake: asset has no layer nosuch@0 (it has height@0)"),
        "{}",
        stderr(&out)
    );
    let out = terrabake(&["render", s(&bare), "--shade", "sky", "-o", s(&png)]);
    assert_eq!(out.status.code(), Some(1));
    let msg = stderr(&out);
    assert!(
        msg.contains(&format!("terrabake horizons {}", s(&bare))),
        "{msg}"
    );
    for (method, command) in [
        ("hierarchical", "terrabake pyramid"),
        ("parametric", "terrabake cones"),
    ] {
        let out = terrabake(&[
            "render",
            s(&bare),
            "--view",
            "1",
            "--method",
            method,
            "-o",
            s(&png),
        ]);
        assert_eq!(out.status.code(), Some(1));
        let msg = stderr(&out);
        assert!(msg.contains(command) && msg.contains("bare.tbake"), "{msg}");
    }
}

/// `bake --help` lists the stages a recipe may name, by hand: every one of
/// `recipe::STAGES` must be there (ARCHITECTURE.md, "Adding a stage").
#[test]
fn bake_help_names_every_stage() {
    let text = ok(&["bake", "--help"]);
    for stage in terrabake::bake::recipe::STAGES {
        assert!(text.contains(stage), "bake --help does not name {stage}");
    }
}

#[test]
fn help_teaches() {
    let text = ok(&["--help"]);
    for word in [
        "ingest",
        "info",
        "verify",
        "export",
        "synth",
        "bake",
        "Exit status",
    ] {
        assert!(text.contains(word), "--help lacks {word}");
    }
    let text = ok(&["ingest", "--help"]);
    assert!(
        text.contains("--raw-shape") && text.contains("--z-scale") && text.contains("power of two")
    );
    let text = ok(&["bake", "--help"]);
    for word in [
        "[[stage]]",
        "[ingest]",
        "max_distance",
        "--parts",
        "--part",
        "assemble",
        "--json",
    ] {
        assert!(text.contains(word), "bake --help lacks {word}: {text}");
    }
    // The recipe it shows is one that bakes.
    let shown: String = text
        .split("A recipe (a shorter pipelines/demo.toml):\n")
        .nth(1)
        .expect("a recipe in bake --help")
        .lines()
        .map(|l| l.trim_start().to_string() + "\n")
        .collect();
    let recipe = terrabake::bake::recipe::Recipe::parse(Path::new("bake --help"), shown).unwrap();
    assert_eq!(recipe.resolve_stages().unwrap().len(), 3);
}

#[test]
fn cones_from_the_command_line_and_from_recipes() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("t.tif");
    ok(&["synth", "sine", "--size", "60x40", "-o", s(&tif), "-q"]);
    let asset = dir.path().join("t.tbake");
    ok(&["ingest", s(&tif), "-o", s(&asset), "-q"]);
    let out: serde_json::Value = serde_json::from_str(&ok(&[
        "cones",
        s(&asset),
        "--slices",
        "exact",
        "--json",
        "-q",
    ]))
    .unwrap();
    assert_eq!(out["skipped"], false);
    assert!(out["planes"].as_str().unwrap().contains("exact"), "{out}");
    // Auto says what it chose and why.
    let out: serde_json::Value =
        serde_json::from_str(&ok(&["cones", s(&asset), "--json", "-q"])).unwrap();
    assert!(
        out["planes"].as_str().unwrap().contains("slices: relief"),
        "{out}"
    );
    ok(&[
        "render",
        s(&asset),
        "--view",
        "2",
        "--method",
        "parametric",
        "--size",
        "40x30",
        "-o",
        s(&dir.path().join("v.png")),
        "-q",
    ]);
    ok(&["pyramid", s(&asset), "-q"]);

    let bad = terrabake(&["cones", s(&asset), "--slices", "0"]);
    assert_eq!(bad.status.code(), Some(2), "{}", stderr(&bad));
    let bad = terrabake(&["cones", s(&asset), "--slices", "16", "--apex-gap", "3"]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(stderr(&bad).contains("--apex-gap"), "{}", stderr(&bad));

    let baked = bake_recipe(
        &tif,
        &asset,
        "[[stage]]\nname = \"cones\"\nslices = 64\nencoding = \"u16\"\n",
    );
    assert!(baked.status.success(), "{}", stderr(&baked));
    let a = Asset::open(&asset).unwrap();
    let slope = a.layer("cone_slope", 0).unwrap().entry();
    assert_eq!(slope.elem, terrabake_format::ElemType::U16);
    assert!(slope.description.contains("64 slices"));
    assert!(a
        .layer("cone_apex", 0)
        .unwrap()
        .entry()
        .quantization
        .is_some());

    let bad = bake_recipe(&tif, &asset, "[[stage]]\nname = \"cones\"\nslice = 64\n");
    assert_eq!(bad.status.code(), Some(1));
    assert!(stderr(&bad).contains("`slice`"), "{}", stderr(&bad));
}

#[test]
fn horizons_from_the_command_line_export_shade_and_recipes() {
    use terrabake_format::horizons::{HorizonMap, HORIZON, SVF};
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("t.tif");
    ok(&["synth", "fractal", "--size", "70x50", "-o", s(&tif), "-q"]);
    let asset = dir.path().join("t.tbake");
    ok(&["ingest", s(&tif), "-o", s(&asset), "--tile", "32", "-q"]);
    let out: serde_json::Value = serde_json::from_str(&ok(&[
        "horizons",
        s(&asset),
        "--sectors",
        "8",
        "--max-error",
        "0.01",
        "--json",
        "-q",
    ]))
    .unwrap();
    assert_eq!(out["horizon"]["encoding"], "u16", "{out}");
    let azimuths = out["horizon"]["band_azimuths"].as_array().unwrap();
    assert_eq!(azimuths.len(), 8);
    assert_eq!(azimuths[2], 90.0);

    // The loader: lit_fraction agrees with the stored horizon.
    let a = Asset::open(&asset).unwrap();
    let map = HorizonMap::open(&a).unwrap();
    let h = map.angle(35, 25, 2).unwrap().unwrap();
    assert_eq!(
        map.lit_fraction(35, 25, 90.0, h + 1.0, 0.27).unwrap(),
        Some(1.0)
    );
    assert_eq!(
        map.lit_fraction(35, 25, 90.0, h - 1.0, 0.27).unwrap(),
        Some(0.0)
    );
    let half = map.lit_fraction(35, 25, 90.0, h, 0.27).unwrap().unwrap();
    assert!((half - 0.5).abs() < 1e-9);
    for layer in [SVF, "svf_cosine", "openness", "horizon_edge"] {
        assert!(a.layer(layer, 0).is_ok(), "{layer}");
    }
    ok(&["verify", s(&asset)]);

    // Export: one GeoTIFF band per sector, decoded to degrees, each band
    // its own tiles (band-interleaved): band 2 is chunk 2 of a one-tile image.
    let hz = dir.path().join("hz.tif");
    ok(&["export", s(&asset), "--layer", HORIZON, "-o", s(&hz), "-q"]);
    let mut decoder = tiff::decoder::Decoder::new(std::fs::File::open(&hz).unwrap()).unwrap();
    assert_eq!(decoder.dimensions().unwrap(), (70, 50));
    let (cw, _) = decoder.chunk_data_dimensions(2);
    let tiff::decoder::DecodingResult::F32(values) = decoder.read_chunk(2).unwrap() else {
        panic!("f32 expected")
    };
    let stored = values[25 * cw as usize + 35];
    assert!((f64::from(stored) - h).abs() < 1e-4, "{stored} vs {h}");
    ok(&[
        "export",
        s(&asset),
        "--layer",
        SVF,
        "--style",
        "gray",
        "-o",
        s(&dir.path().join("svf.png")),
        "-q",
    ]);
    ok(&[
        "render",
        s(&asset),
        "--shade",
        "sky",
        "-o",
        s(&dir.path().join("sky.png")),
        "-q",
    ]);
    ok(&[
        "render",
        s(&asset),
        "--shade",
        "sun:120,20",
        "-o",
        s(&dir.path().join("sun.png")),
        "-q",
    ]);

    // An area of interest: the same angles inside, nothing outside.
    let aoi = dir.path().join("aoi.tbake");
    ok(&["ingest", s(&tif), "-o", s(&aoi), "--tile", "32", "-q"]);
    ok(&[
        "horizons",
        s(&aoi),
        "--sectors",
        "8",
        "--max-error",
        "0.01",
        "--aoi",
        "30,20,50,40",
        "-q",
    ]);
    let b = Asset::open(&aoi).unwrap();
    let inner = HorizonMap::open(&b).unwrap();
    assert_eq!(inner.angle(35, 25, 2).unwrap(), Some(h));
    assert_eq!(inner.angle(10, 10, 2).unwrap(), None);

    // Bad input: a clear error and a non-zero exit, the asset untouched.
    for (args, says, code) in [
        (vec!["--sectors", "2"], "--sectors", 2),
        (vec!["--aoi", "10,10,5,5"], "X0 < X1", 2),
        (vec!["--aoi", "0,0,500,10"], "--aoi", 1),
        (
            vec!["--sectors", "128", "--direction-tolerance", "4.5"],
            "half the spacing",
            1,
        ),
    ] {
        let mut all = vec!["horizons", s(&aoi), "--force"];
        all.extend(args);
        let bad = terrabake(&all);
        assert_eq!(bad.status.code(), Some(code), "{all:?}");
        assert!(stderr(&bad).contains(says), "{all:?}: {}", stderr(&bad));
    }
    ok(&["verify", s(&aoi)]);
    let bare = dir.path().join("bare.tbake");
    ok(&["ingest", s(&tif), "-o", s(&bare), "-q"]);
    let bad = terrabake(&[
        "render",
        s(&bare),
        "--shade",
        "sky",
        "-o",
        s(&dir.path().join("x.png")),
    ]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(stderr(&bad).contains("horizons"), "{}", stderr(&bad));

    // A recipe step, and its typo caught before any work.
    let baked = bake_recipe(
        &tif,
        &asset,
        "[[stage]]\nname = \"horizons\"\nsectors = 7\nmethod = \"sector\"\nencoding = \"f32\"\n",
    );
    assert!(baked.status.success(), "{}", stderr(&baked));
    let a = Asset::open(&asset).unwrap();
    let entry = a.layer(HORIZON, 0).unwrap().entry();
    assert_eq!(entry.bands, 7);
    assert!(entry.description.contains("Stewart"));
    let bad = bake_recipe(&tif, &asset, "[[stage]]\nname = \"horizons\"\nsector = 7\n");
    assert_eq!(bad.status.code(), Some(1));
    assert!(stderr(&bad).contains("`sector`"), "{}", stderr(&bad));

    // Unbounded sectors would hold a 300 x 300 DEM in more than 1 MiB:
    // refused before any work, the routes named; bounded sectors run.
    let big_tif = dir.path().join("big.tif");
    ok(&[
        "synth",
        "fractal",
        "--size",
        "300x300",
        "-o",
        s(&big_tif),
        "-q",
    ]);
    let big = dir.path().join("big.tbake");
    ok(&["ingest", s(&big_tif), "-o", s(&big), "-q"]);
    let sector = [
        "horizons",
        s(&big),
        "--method",
        "sector",
        "--max-memory",
        "1",
    ];
    let refused = terrabake(&sector);
    assert_eq!(refused.status.code(), Some(1));
    for says in ["--max-memory 1 MiB", "--max-distance", "--method line"] {
        assert!(stderr(&refused).contains(says), "{}", stderr(&refused));
    }
    assert!(Asset::open(&big).unwrap().layer(HORIZON, 0).is_err());
    // Out of core, bounded sectors hold a tile row's window per thread
    // (1.3 MiB here, which the stage states and refuses at 1 MiB).
    let bounded_sector = [
        "horizons",
        s(&big),
        "--method",
        "sector",
        "--max-distance",
        "60",
    ];
    let over = terrabake(&[&bounded_sector[..], &["--max-memory", "1"]].concat());
    assert!(
        stderr(&over).contains("over --max-memory 1 MiB"),
        "{}",
        stderr(&over)
    );
    ok(&[&bounded_sector[..], &["--max-memory", "2", "-q"]].concat());

    // Bounded sectors, out of core tile row by tile row (32-post tiles,
    // 3 rows of reach): the library's answer on the whole DEM in memory.
    use terrabake::algorithms::horizon::{band_horizons, plan_bands};
    use terrabake::terrain::held::read_heights;
    use terrabake::terrain::Terrain;
    let bounded = dir.path().join("bounded.tbake");
    ok(&["ingest", s(&tif), "-o", s(&bounded), "--tile", "32", "-q"]);
    // Sectors baked as f32 without curvature, as the library computes them.
    let bake_sectors = |more: &[&str]| {
        let sectors = ["horizons", s(&bounded), "--method", "sector"];
        let exact = ["--curvature", "off", "--encoding", "f32", "-q"];
        ok(&[&sectors[..], more, &exact].concat());
    };
    bake_sectors(&["--sectors", "7", "--max-distance", "100"]);
    let c = Asset::open(&bounded).unwrap();
    let (z, w, h) = read_heights(&c).unwrap();
    let cs = c.manifest().cell_size.clone();
    let terrain = Terrain::new(&z, w, h, cs.dx, cs.dy);
    // Every band the stage stored against the library's, `same` at each
    // post (the stored angle, none for nodata).
    let each_band_is_the_librarys =
        |count, opts, same: &dyn Fn(Option<f64>, f32) -> bool, what: &str| {
            let stored = Asset::open(&bounded).unwrap();
            let stored = HorizonMap::open(&stored).unwrap();
            let bands = plan_bands(
                terrabake::algorithms::horizon::Method::Sector,
                count,
                cs.dx,
                cs.dy,
                None,
            );
            for (b, band) in bands.iter().enumerate() {
                let (want, _) = band_horizons(&terrain, band, opts);
                for (i, want) in want.iter().enumerate() {
                    let got = stored
                        .angle((i % w) as u32, (i / w) as u32, b as u32)
                        .unwrap();
                    assert!(
                        same(got, *want),
                        "{what} band {b} post {i}: {got:?} vs {want}"
                    );
                }
            }
        };
    let opts = terrabake::algorithms::horizon::BandOptions {
        max_distance: Some(100.0),
        narrow_check: true,
    };
    let near =
        |got: Option<f64>, want: f32| got.is_some_and(|g| (g - f64::from(want)).abs() < 1e-5);
    each_band_is_the_librarys(7, opts, &near, "bounded");

    // Unbounded sectors, an even count: the stage sweeps each beside its
    // opposite, on its ranks reversed, and gives the library's answer for
    // each sector alone, bit for bit.
    bake_sectors(&["--sectors", "8", "--force"]);
    let bits = |got: Option<f64>, want: f32| got.map_or(want.is_nan(), |g| g as f32 == want);
    each_band_is_the_librarys(8, Default::default(), &bits, "unbounded");
}

/// Values no command can use are usage errors (exit 2, clap's convention)
/// with a message that says what is wanted, before any work; a camera that
/// looks at itself is refused.
#[test]
fn unusable_values_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let dem = repo_file("data/srtm3_n07w006_geographic_int16.tif");
    let out = dir.path().join("x.tbake");
    let (dem, out) = (dem.to_str().unwrap(), out.to_str().unwrap());
    for (args, says) in [
        (
            vec!["ingest", dem, "-o", out, "--tile", "100"],
            "power of two",
        ),
        (vec!["ingest", dem, "-o", out, "--z-scale", "nan"], "finite"),
        (
            vec!["ingest", dem, "-o", out, "--z-offset", "inf"],
            "finite",
        ),
        (vec!["horizons", out, "--sectors", "2"], "3 to 4096"),
        (vec!["horizons", out, "--aoi", "10,10,5,5"], "X0 < X1"),
        (vec!["horizons", out, "--max-error", "-1"], "positive"),
        (vec!["horizons", out, "--max-distance", "-5"], "positive"),
        (
            vec!["render", out, "--view", "1", "--fov", "200", "-o", "x.png"],
            "between 0 and 180",
        ),
        (
            vec![
                "render",
                out,
                "--view",
                "1",
                "--exaggerate",
                "-2",
                "-o",
                "x.png",
            ],
            "positive",
        ),
    ] {
        let o = terrabake(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(says), "{args:?}: {}", stderr(&o));
    }
    assert!(!Path::new(out).exists(), "work was done");

    ok(&["ingest", dem, "-o", out, "-q"]);
    let png = dir.path().join("x.png");
    let o = terrabake(&[
        "render",
        out,
        "--camera",
        "1,2,3",
        "--look-at",
        "1,2,3",
        "--method",
        "incremental",
        "-o",
        png.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("looks at its own position"),
        "{}",
        stderr(&o)
    );
    assert!(!png.exists());
}

/// What a new user is told: that 1 m posts were assumed for a source with
/// no georeferencing (at ingest, not only in `info`), the extent in the
/// coordinates `render` takes, and an image written into a directory that
/// did not exist yet.
#[test]
fn ingest_info_and_render_guide_a_new_user() {
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("dem.f32");
    let heights: Vec<u8> = (0..20 * 10)
        .flat_map(|i| ((i % 20) as f32 * 0.5 + (i / 20) as f32).to_le_bytes())
        .collect();
    std::fs::write(&raw, heights).unwrap();
    let asset = dir.path().join("dem.tbake");
    let o = terrabake(&[
        "ingest",
        s(&raw),
        "-o",
        s(&asset),
        "--raw-shape",
        "20x10",
        "--raw-type",
        "f32",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("1 m apart were assumed") && stderr(&o).contains("--cell-size"),
        "{}",
        stderr(&o)
    );
    let info = ok(&["info", s(&asset)]);
    assert!(
        info.contains("extent      0 .. 19 m east, 0 .. 9 m north"),
        "{info}"
    );
    let png = dir.path().join("new/dir/view.png");
    ok(&[
        "render",
        s(&asset),
        "--camera",
        "-5,-5,30",
        "--look-at",
        "10,5,0",
        "--method",
        "incremental",
        "--size",
        "32x24",
        "-o",
        s(&png),
        "-q",
    ]);
    assert!(png.is_file());
}

/// Issue #55, item 7 (in part): the messages a new user meets say what to
/// run: `info` on a DEM points to `ingest`; exporting a layer not baked
/// names the stage that makes it; `horizons --directions` is `--sectors`;
/// the PVGIS header says where the point is (longitude and latitude), the
/// GeoTIFF's azimuth convention is a whole sentence, and stage lines align
/// whatever the stage's name.
#[test]
fn messages_tell_a_new_user_what_to_run() {
    let dir = tempfile::tempdir().unwrap();
    let dem = common::repo_file("data/srtm3_n07w006_geographic_int16.tif");
    let info = terrabake(&["info", s(&dem)]);
    assert!(
        stderr(&info).contains("terrabake ingest"),
        "{}",
        stderr(&info)
    );
    let asset = dir.path().join("a.tbake");
    ok(&["ingest", s(&dem), "-o", s(&asset), "-q"]);
    let out = dir.path().join("c.tif");
    let cones = terrabake(&["export", s(&asset), "--layer", "cone_slope", "-o", s(&out)]);
    assert!(
        stderr(&cones).contains("`terrabake cones"),
        "{}",
        stderr(&cones)
    );
    let horizons = terrabake(&[
        "horizons",
        s(&asset),
        "--directions",
        "8",
        "--aoi",
        "0,0,64,64",
    ]);
    assert!(horizons.status.success(), "{}", stderr(&horizons));
    let said = stderr(&horizons);
    let lines: Vec<&str> = said.lines().collect();
    let horizon_line = lines.iter().position(|l| l.starts_with("horizons "));
    let sky_line = lines.iter().position(|l| l.starts_with("sky "));
    assert!(horizon_line < sky_line && sky_line.is_some(), "{lines:?}");
    let pvgis = ok(&[
        "profile",
        s(&asset),
        "--at",
        "-5.5,7.5",
        "--crs",
        "lonlat",
        "--format",
        "pvgis",
    ]);
    assert!(
        pvgis.starts_with("# terrabake horizon at longitude -5.50"),
        "{pvgis}"
    );
    assert!(
        pvgis.lines().next().unwrap().contains("latitude 7.50"),
        "{pvgis}"
    );
    let tif = dir.path().join("h.tif");
    ok(&[
        "export",
        s(&asset),
        "--layer",
        "horizon",
        "-o",
        s(&tif),
        "-q",
    ]);
    let bytes = std::fs::read(&tif).unwrap();
    let text = String::from_utf8_lossy(&bytes);
    assert!(
        text.contains("each band's AZIMUTH item gives its direction"),
        "convention cut"
    );
    let total = terrabake(&[
        "total-viewshed",
        s(&asset),
        "--max-distance",
        "300",
        "--directions",
        "8",
    ]);
    let line = stderr(&total)
        .lines()
        .last()
        .unwrap_or_default()
        .to_string();
    let sky = lines[sky_line.unwrap()];
    assert_eq!(
        line.find(" s  "),
        sky.find(" s  "),
        "{line:?} against {sky:?}"
    );
    // `bake` without a recipe names both ways to say what to bake.
    let bake = terrabake(&["bake", s(&dem), "-o", s(&dir.path().join("b.tbake"))]);
    assert_eq!(bake.status.code(), Some(2));
    assert!(
        stderr(&bake).contains("--recipe") && stderr(&bake).contains("--budget"),
        "{}",
        stderr(&bake)
    );
    // The cone planes' description says its slice count once.
    ok(&["cones", s(&asset), "--slices", "16", "-q"]);
    let info = ok(&["info", s(&asset), "--json"]);
    let apex = info
        .split("cone apex")
        .nth(1)
        .unwrap_or_default()
        .split('"')
        .next()
        .unwrap_or_default()
        .to_string();
    assert!(apex.contains("(16 slices as asked)"), "{apex}");
    assert_eq!(apex.matches("slices").count(), 1, "{apex}");
    // GRASS's files hold radians, and their description says so.
    let grass = dir.path().join("grass");
    ok(&[
        "export",
        s(&asset),
        "--layer",
        "horizon",
        "--for",
        "grass",
        "-o",
        s(&grass),
        "-q",
    ]);
    let first = std::fs::read_dir(&grass)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "tif"))
        .unwrap();
    let bytes = std::fs::read(first).unwrap();
    let text = String::from_utf8_lossy(&bytes);
    let described = text
        .split("<Item name=\"TERRABAKE_DESCRIPTION\">")
        .nth(1)
        .unwrap_or_default()
        .split("</Item>")
        .next()
        .unwrap_or_default()
        .to_string();
    assert!(
        described.starts_with("horizon angle, radians"),
        "{described}"
    );
}

/// A planned bake whose stage fails removes the asset it created: what it
/// would leave (the heights alone, a lock) meets no budget. An asset that
/// was there before is left as it was.
#[test]
fn a_failed_planned_bake_removes_the_asset_it_created() {
    let dir = tempfile::tempdir().unwrap();
    let (dem, asset) = (dir.path().join("d.tif"), dir.path().join("a.tbake"));
    ok(&["synth", "fractal", "--size", "400x300", "-o", s(&dem), "-q"]);
    let recipe = dir.path().join("r.toml");
    std::fs::write(
        &recipe,
        "[plan]\nneeds = [\"horizons\"]\nbudget = { horizon = 1 }\n\n\
         [[stage]]\nname = \"horizons\"\nmax_memory_mib = 1\n",
    )
    .unwrap();
    let o = terrabake(&["bake", s(&dem), "-o", s(&asset), "--recipe", s(&recipe)]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("removed the asset"), "{}", stderr(&o));
    assert!(!asset.exists());
    // Over an asset that was there, the failure keeps what was committed.
    ok(&["ingest", s(&dem), "-o", s(&asset), "-q"]);
    let o = terrabake(&["bake", s(&dem), "-o", s(&asset), "--recipe", s(&recipe)]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    ok(&["verify", s(&asset)]);
}

/// Sizes that the disk or the memory cannot serve are refused at once,
/// saying what they need and what there is, and nothing is left behind.
#[test]
fn sizes_that_cannot_be_served_are_refused_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("huge.tif");
    let start = std::time::Instant::now();
    let o = terrabake(&[
        "synth",
        "fractal",
        "--size",
        "2000000x2000000",
        "-o",
        s(&tif),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("GiB free"), "{}", stderr(&o));
    let (small, asset) = (dir.path().join("small.tif"), dir.path().join("a.tbake"));
    ok(&["synth", "sine", "--size", "40x30", "-o", s(&small), "-q"]);
    ok(&["ingest", s(&small), "-o", s(&asset), "-q"]);
    let png = dir.path().join("huge.png");
    let o = terrabake(&[
        "render",
        s(&asset),
        "--camera",
        "1,2,300",
        "--look-at",
        "20,20,0",
        "--method",
        "incremental",
        "--size",
        "4000000x4000000",
        "-o",
        s(&png),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("of memory"), "{}", stderr(&o));
    assert!(
        start.elapsed().as_secs() < 30,
        "refused only after {:?}",
        start.elapsed()
    );
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert!(!left.iter().any(|n| n.starts_with("huge")), "{left:?}");
}

/// Every argument of every command says what it is in `--help`.
#[test]
fn every_argument_has_a_help_line() {
    use clap::CommandFactory;
    let cli = terrabake::cli::Cli::command();
    let mut missing = Vec::new();
    for command in cli.get_subcommands() {
        for arg in command.get_arguments() {
            let id = arg.get_id().as_str();
            if id == "help" || id == "version" {
                continue;
            }
            if arg.get_help().is_none() && arg.get_long_help().is_none() {
                missing.push(format!("{} {id}", command.get_name()));
            }
        }
    }
    assert!(missing.is_empty(), "no help line: {missing:?}");
}

/// `TERRABAKE_SIMD` caps the vector kernels (the cone planes' scans, the
/// line sweep's lanes, the sky stage's sums): every cap gives the layers
/// the widest kernels give, bit for bit (on a CPU without them, the same
/// code runs), and a value it cannot use is refused before any work,
/// named.
#[test]
fn vector_caps_change_no_layer() {
    let tmp = tempfile::tempdir().unwrap();
    let tif = tmp.path().join("fractal.tif");
    ok(&["synth", "fractal", "--size", "300x200", "-o", s(&tif), "-q"]);
    let run = |cap: Option<&str>, args: &[&str]| {
        terrabake_with(
            (
                terrabake::plumbing::simd::VAR,
                cap.map(std::ffi::OsStr::new),
            ),
            args,
        )
    };
    let bake = |cap: Option<&str>| {
        let asset = tmp
            .path()
            .join(format!("{}.tbake", cap.unwrap_or("widest")));
        ok(&["ingest", s(&tif), "-o", s(&asset), "-q"]);
        for stage in [
            &["cones", "--slices", "64"][..],
            &["horizons", "--sectors", "16"],
        ] {
            let out = run(cap, &[stage, &[s(&asset), "-q"]].concat());
            assert!(out.status.success(), "{cap:?} {stage:?}: {}", stderr(&out));
        }
        asset
    };
    let widest = bake(None);
    for cap in ["avx2", "scalar", "AVX512"] {
        let capped = bake(Some(cap));
        ok(&["verify", s(&capped), "--same-as", s(&widest)]);
    }
    let refused = run(Some("sse9"), &["info", s(&widest)]);
    assert_eq!(refused.status.code(), Some(1));
    assert!(
        stderr(&refused).contains("TERRABAKE_SIMD=\"sse9\""),
        "{}",
        stderr(&refused)
    );
}
