//! The stage interface that later stages (pyramid, cones, horizons) plug
//! into: layers in, layers out, recorded in the manifest, skipped when done,
//! and never leaving a half-written asset when a stage fails.

mod common;

use std::path::Path;

use common::*;
use terrabake::plumbing::progress::Progress;
use terrabake::stage::sight::SightLines;
use terrabake::stage::{run_stage, Stage};
use terrabake::stages::ingest::{ingest, IngestOptions};
use terrabake::terrain::tiling::push_tile_row;
use terrabake_format::{Asset, Codec, ElemType, LayerEntry, LayerSpec, LayerWriter, Mmap};

/// A test stage: `offset` = height + `add`, written band by band; fails
/// halfway when `fail` is set.
struct Offset {
    add: f32,
    fail: bool,
}

impl Stage for Offset {
    fn name(&self) -> &'static str {
        "offset"
    }
    fn outputs(&self, _: &terrabake_format::Manifest) -> Vec<String> {
        vec!["offset@0".into()]
    }
    fn params(&self) -> serde_json::Value {
        serde_json::json!({ "add": self.add })
    }
    fn run(
        &self,
        asset: &Asset<Mmap>,
        dir: &Path,
        _: &terrabake::stage::Share,
        _progress: Progress,
    ) -> terrabake::Result<Vec<LayerEntry>> {
        let height = asset.height()?;
        let (w, h, ts) = (height.width(), height.height(), height.tile_size());
        let spec = LayerSpec {
            name: "offset".into(),
            level: 0,
            elem: ElemType::F32,
            bands: 1,
            width: w,
            height: h,
            tile_size: ts,
            codec: Codec::Raw,
            fill_bits: u64::from(f32::NAN.to_bits()),
            stage: "offset".into(),
            description: "height + add".into(),
        };
        let mut writer = LayerWriter::create(dir, spec)?;
        for y0 in (0..h).step_by(ts as usize) {
            if self.fail && y0 > 0 {
                return Err(anyhow::anyhow!("offset stage failed on purpose at row {y0}").into());
            }
            let rows = ts.min(h - y0);
            let mut band = vec![0f32; (w * rows) as usize];
            height.read_window(0, 0, y0, w, rows, &mut band)?;
            band.iter_mut().for_each(|z| *z += self.add);
            push_tile_row(&mut writer, &band, w as usize, f32::NAN)?;
        }
        Ok(vec![writer.finish()?])
    }
}

fn asset_files(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    names
}

/// A fresh asset in `parent` with the float32 fixture's heights, tiles of 16.
fn ingested(parent: &Path) -> std::path::PathBuf {
    let dir = parent.join("a.tbake");
    let opts = IngestOptions {
        tile_size: 16,
        ..Default::default()
    };
    ingest(
        &fixture("tiff/float32_strip_none.tif"),
        &dir,
        &opts,
        Progress::hidden(),
    )
    .unwrap();
    dir
}

#[test]
fn stages_add_layers_record_themselves_and_resume() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = ingested(tmp.path());

    let first = run_stage(
        &dir,
        &Offset {
            add: 10.0,
            fail: false,
        },
        false,
        Progress::hidden(),
    )
    .unwrap();
    assert!(!first.skipped);
    assert_eq!(first.outputs, vec!["offset@0".to_string()]);
    let asset = Asset::open(&dir).unwrap();
    let (height, offset) = (asset.height().unwrap(), asset.layer("offset", 0).unwrap());
    for (x, y) in [(0, 0), (69, 44), (33, 17)] {
        assert_eq!(
            offset.get::<f32>(0, x, y).unwrap(),
            height.get::<f32>(0, x, y).unwrap() + 10.0
        );
    }
    let record = asset.manifest().provenance.stages.last().unwrap();
    assert_eq!(
        (record.stage.as_str(), record.params["add"].as_f64()),
        ("offset", Some(10.0))
    );
    drop(asset);

    // Same parameters: skipped, nothing rewritten.
    let files = asset_files(&dir);
    assert!(
        run_stage(
            &dir,
            &Offset {
                add: 10.0,
                fail: false
            },
            false,
            Progress::hidden()
        )
        .unwrap()
        .skipped
    );
    assert_eq!(asset_files(&dir), files);

    // New parameters: the layer is replaced by a new generation; the old
    // file is retired (kept a grace period for readers that read the
    // previous manifest, then removed: docs/RELIABILITY.md).
    assert!(
        !run_stage(
            &dir,
            &Offset {
                add: -1.0,
                fail: false
            },
            false,
            Progress::hidden()
        )
        .unwrap()
        .skipped
    );
    let after = asset_files(&dir);
    let asset = Asset::open(&dir).unwrap();
    let retired: Vec<&str> = asset
        .manifest()
        .retired
        .iter()
        .map(|r| r.file.as_str())
        .collect();
    assert!(
        after.contains(&"offset.L0.g1.tbl".to_string())
            && asset.manifest().layer("offset", 0).unwrap().file == "offset.L0.g1.tbl"
            && retired == ["offset.L0.g0.tbl"],
        "{after:?} {retired:?}"
    );
    assert_eq!(
        asset
            .manifest()
            .provenance
            .stages
            .iter()
            .filter(|r| r.stage == "offset")
            .count(),
        1
    );
    assert_eq!(
        asset
            .layer("offset", 0)
            .unwrap()
            .get::<f32>(0, 3, 4)
            .unwrap(),
        fixture_value("float32", 3, 4) - 1.0
    );
}

#[test]
fn a_failing_stage_leaves_the_asset_as_it_was() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = ingested(tmp.path());
    run_stage(
        &dir,
        &Offset {
            add: 1.0,
            fail: false,
        },
        false,
        Progress::hidden(),
    )
    .unwrap();
    let files = asset_files(&dir);
    let manifest = std::fs::read(dir.join("manifest.tba")).unwrap();

    let err = run_stage(
        &dir,
        &Offset {
            add: 2.0,
            fail: true,
        },
        false,
        Progress::hidden(),
    )
    .unwrap_err();
    assert!(format!("{err:#}").contains("on purpose"));
    assert_eq!(asset_files(&dir), files, "temporary files left behind");
    assert_eq!(std::fs::read(dir.join("manifest.tba")).unwrap(), manifest);
    let asset = Asset::open(&dir).unwrap();
    assert!(asset.verify().problems.is_empty());
    assert_eq!(
        asset
            .layer("offset", 0)
            .unwrap()
            .get::<f32>(0, 0, 0)
            .unwrap(),
        fixture_value("float32", 0, 0) + 1.0
    );
}

/// The record a stage leaves in the manifest, by stage name.
fn record(asset: &Path, stage: &str) -> serde_json::Value {
    let a = Asset::open(asset).unwrap();
    let r = a
        .manifest()
        .provenance
        .stages
        .iter()
        .rev()
        .find(|r| r.stage == stage);
    r.unwrap_or_else(|| panic!("no {stage} record"))
        .params
        .clone()
}

/// One parameter type per stage: the same parameters from the command line
/// and from a recipe give the same manifest record.
#[test]
fn command_line_and_recipe_record_the_same_parameters() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("t.tif");
    terrabake::io::synth::write_geotiff(
        &tif,
        terrabake::io::synth::SynthKind::Fractal,
        50,
        40,
        2,
        Progress::hidden(),
    )
    .unwrap();
    let (by_cli, by_recipe) = (
        dir.path().join("cli.tbake"),
        dir.path().join("recipe.tbake"),
    );
    let run = |args: &[&str]| {
        let out = terrabake(args);
        assert!(out.status.success(), "{args:?}: {}", stderr(&out));
    };
    let p = |p: &Path| p.to_str().unwrap().to_string();
    run(&["ingest", &p(&tif), "-o", &p(&by_cli), "--tile", "16", "-q"]);
    run(&[
        "cones",
        &p(&by_cli),
        "--slices",
        "auto",
        "--apex-gap",
        "2.5",
        "--encoding",
        "u16",
        "--max-memory",
        "64",
        "-q",
    ]);
    run(&[
        "horizons",
        &p(&by_cli),
        "--sectors",
        "8",
        "--method",
        "sector",
        "--max-distance",
        "300",
        "--curvature",
        "off",
        "--aoi",
        "2,3,40,30",
        "--encoding",
        "u16",
        "--no-narrow-check",
        "-q",
    ]);
    run(&[
        "solar",
        &p(&by_cli),
        "--days",
        "80-82",
        "--monthly",
        "--step",
        "30",
        "--linke",
        "2.5",
        "--albedo",
        "0.3",
        "--lat",
        "46.5",
        "-q",
    ]);
    let recipe = dir.path().join("r.toml");
    std::fs::write(
        &recipe,
        "[ingest]\ntile = 16\n\n[[stage]]\nname = \"cones\"\nslices = \"auto\"\napex_gap = 2.5\nencoding = \"u16\"\nmax_memory_mib = 64\n\n\
         [[stage]]\nname = \"horizons\"\nsectors = 8\nmethod = \"sector\"\nmax_distance = 300\ncurvature = false\naoi = [2, 3, 40, 30]\nencoding = \"u16\"\nnarrow_check = false\n\n\
         [[stage]]\nname = \"sky\"\n\n[[stage]]\nname = \"solar\"\ndays = \"80-82\"\nmonthly = true\nstep_minutes = 30\nlinke = 2.5\nalbedo = 0.3\nlatitude = 46.5\n",
    )
    .unwrap();
    run(&[
        "bake",
        &p(&tif),
        "-o",
        &p(&by_recipe),
        "--recipe",
        &p(&recipe),
        "-q",
    ]);
    for stage in ["ingest", "cones", "horizons", "sky", "solar"] {
        assert_eq!(record(&by_cli, stage), record(&by_recipe, stage), "{stage}");
    }
    assert_eq!(record(&by_cli, "horizons")["method"], "sector");
    assert_eq!(record(&by_cli, "cones")["max_memory_mib"], 64.0);
}

/// A misspelled recipe key is refused by name, with the stage and the file,
/// before any work.
#[test]
fn a_misspelled_recipe_key_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("t.tif");
    terrabake::io::synth::write_geotiff(
        &tif,
        terrabake::io::synth::SynthKind::Flat,
        20,
        20,
        1,
        Progress::hidden(),
    )
    .unwrap();
    for (stage, key) in [
        ("cones", "slicez = 8"),
        ("horizons", "sector = 8"),
        ("pyramid", "levels = 3"),
        ("sky", "layer = [\"svf\"]"),
        ("ingest", "tiles = 16"),
    ] {
        let recipe = dir.path().join(format!("{stage}.toml"));
        let text = if stage == "ingest" {
            format!("[ingest]\n{key}\n")
        } else {
            format!("[[stage]]\nname = \"{stage}\"\n{key}\n")
        };
        std::fs::write(&recipe, text).unwrap();
        let asset = dir.path().join(format!("{stage}.tbake"));
        let out = terrabake(&[
            "bake",
            tif.to_str().unwrap(),
            "-o",
            asset.to_str().unwrap(),
            "--recipe",
            recipe.to_str().unwrap(),
        ]);
        assert_eq!(out.status.code(), Some(1));
        let msg = stderr(&out);
        let name = key.split(' ').next().unwrap();
        assert!(
            msg.contains(&format!("{stage}.toml"))
                && msg.contains(stage)
                && msg.contains(&format!("`{name}`")),
            "{msg}"
        );
        assert!(!asset.exists(), "work began before the recipe was checked");
    }
}

/// The command line's defaults are the stage types' defaults (what a recipe
/// that leaves a key out gets), for every stage with parameters.
#[test]
fn command_line_defaults_are_the_stage_defaults() {
    use clap::Parser;
    #[derive(Parser)]
    struct Cones {
        #[command(flatten)]
        stage: terrabake::stages::cones::ConesStage,
    }
    #[derive(Parser)]
    struct Horizons {
        #[command(flatten)]
        stage: terrabake::stages::horizons::HorizonsStage,
    }
    #[derive(Parser)]
    struct Ingest {
        #[command(flatten)]
        opts: terrabake::stages::ingest::IngestOptions,
    }
    #[derive(Parser)]
    struct Sky {
        #[command(flatten)]
        stage: terrabake::stages::sky::SkyStage,
    }
    #[derive(Parser)]
    struct Solar {
        #[command(flatten)]
        stage: terrabake::stages::solar::SolarStage,
    }
    #[derive(Parser)]
    struct TotalViewshed {
        #[command(flatten)]
        stage: terrabake::stages::viewshed::stage::TotalViewshedStage,
    }
    #[derive(Parser)]
    struct Viewshed {
        #[command(flatten)]
        stage: terrabake::stages::viewshed::stage::ViewshedStage,
    }
    assert_eq!(Ingest::parse_from(["x"]).opts, Default::default());
    assert_eq!(Sky::parse_from(["x"]).stage, Default::default());
    assert_eq!(Cones::parse_from(["x"]).stage, Default::default());
    assert_eq!(Horizons::parse_from(["x"]).stage, Default::default());
    assert_eq!(TotalViewshed::parse_from(["x"]).stage, Default::default());
    assert_eq!(Solar::parse_from(["x"]).stage, Default::default());
    // A recipe's table that leaves every key out gets the same.
    fn from_recipe<T: serde::de::DeserializeOwned>(text: &str) -> T {
        toml::from_str(text).unwrap()
    }
    assert_eq!(
        from_recipe::<terrabake::stages::horizons::HorizonsStage>(""),
        Default::default()
    );
    assert_eq!(
        from_recipe::<terrabake::stages::cones::ConesStage>(""),
        Default::default()
    );
    assert_eq!(
        from_recipe::<terrabake::stages::sky::SkyStage>(""),
        Default::default()
    );
    assert_eq!(
        from_recipe::<terrabake::stages::solar::SolarStage>(""),
        Default::default()
    );
    assert_eq!(
        from_recipe::<terrabake::stages::ingest::IngestOptions>(""),
        Default::default()
    );
    // The viewshed stage has no default observers: with one given, the
    // command line and a recipe agree on everything else. (The pyramid
    // stage has no parameters.)
    assert_eq!(
        Viewshed::parse_from(["x", "--observer", "1,2"]).stage,
        from_recipe("observers = [[1.0, 2.0]]")
    );
}

/// Every stage's declared reach is honest: a region baked from a crop of
/// the DEM that adds the reach on every side equals the whole DEM's bake
/// there, bit for bit.
#[test]
fn a_region_baked_with_its_declared_reach_equals_the_whole() {
    use terrabake::algorithms::horizon::Method;
    use terrabake::io::cog::{write_f32, GeoTags};
    use terrabake::stage::Reach;
    use terrabake::stages::horizons::HorizonsStage;
    use terrabake::stages::pyramid::PyramidStage;
    use terrabake::stages::sky::{SkyLayer, SkyStage};

    let (w, h) = (64u32, 56u32);
    let region = (20u32, 15u32, 44u32, 37u32); // posts x0..x1, y0..y1
    let dir = tempfile::tempdir().unwrap();
    let z = |x: u32, y: u32| {
        terrabake::io::synth::height(terrabake::io::synth::SynthKind::Fractal, x, y, w, h, 9)
    };
    // A DEM of posts [x0, x1) x [y0, y1) of the whole, as its own asset.
    let asset_of = |name: &str, (x0, y0, x1, y1): (u32, u32, u32, u32)| {
        let tif = dir.path().join(format!("{name}.tif"));
        write_f32(&tif, (x1 - x0, y1 - y0), &GeoTags::default(), |r0, rows| {
            for (i, v) in rows.iter_mut().enumerate() {
                let (x, y) = (i as u32 % (x1 - x0), r0 + i as u32 / (x1 - x0));
                *v = z(x0 + x, y0 + y);
            }
            Ok(())
        })
        .unwrap();
        let out = dir.path().join(format!("{name}.tbake"));
        let opts = IngestOptions {
            tile_size: 16,
            cell_size: Some((30.0, 30.0)),
            ..Default::default()
        };
        ingest(&tif, &out, &opts, Progress::hidden()).unwrap();
        out
    };
    // Layer `name@level` of `asset` (origin `o` in the whole's posts) at
    // the whole's post `(x, y)`, every band.
    let values = |asset: &Path, name: &str, level: u32| {
        let a = Asset::open(asset).unwrap();
        let l = a.layer(name, level).unwrap();
        let (lw, lh) = (l.width() as usize, l.height() as usize);
        let mut all = vec![0f32; lw * lh * l.bands() as usize];
        for (b, band) in all.chunks_mut(lw * lh).enumerate() {
            l.read_rows_f32(b as u32, 0, band).unwrap();
        }
        (all, lw, lh)
    };
    let whole = asset_of("whole", (0, 0, w, h));
    let m = Asset::open(&whole).unwrap().manifest().clone();
    let stages: Vec<(Box<dyn Stage>, Vec<&str>)> = vec![
        (Box::new(PyramidStage), vec!["pyramid_max", "pyramid_min"]),
        (
            Box::new(HorizonsStage {
                sectors: 8,
                sight: SightLines::within(Some(200.0)),
                ..Default::default()
            }),
            vec!["horizon"],
        ),
        (
            Box::new(HorizonsStage {
                sectors: 8,
                method: Method::Sector,
                sight: SightLines::within(Some(150.0)),
                ..Default::default()
            }),
            vec!["horizon"],
        ),
    ];
    let sky = SkyStage {
        layers: vec![SkyLayer::Svf, SkyLayer::SvfCosine, SkyLayer::Openness],
        ..Default::default()
    };
    for (i, (stage, layers)) in stages.iter().enumerate() {
        let Reach::Posts(r) = stage.reach(&m) else {
            panic!("{}: declared the whole DEM", stage.name());
        };
        // Horizons are followed by sky, whose reach adds to theirs.
        let with_sky = stage.name() == "horizons";
        let r_total = r + if with_sky {
            let Reach::Posts(s) = sky.reach(&m) else {
                panic!("sky declared the whole DEM")
            };
            s
        } else {
            0
        };
        let (x0, y0, x1, y1) = region;
        let crop = (x0 - r_total, y0 - r_total, x1 + r_total, y1 + r_total);
        let part = asset_of(&format!("part{i}"), crop);
        run_stage(&whole, stage.as_ref(), true, Progress::hidden()).unwrap();
        run_stage(&part, stage.as_ref(), true, Progress::hidden()).unwrap();
        let mut compared: Vec<&str> = layers.clone();
        if with_sky {
            run_stage(&whole, &sky, true, Progress::hidden()).unwrap();
            run_stage(&part, &sky, true, Progress::hidden()).unwrap();
            compared.extend(["svf", "svf_cosine", "openness"]);
        }
        for name in compared {
            let (a, aw, ah) = values(&whole, name, 0);
            let (b, bw, bh) = values(&part, name, 0);
            let mut n = 0;
            for band in 0..a.len() / (aw * ah) {
                // Level 0 of the pyramid has one element per cell, cell
                // (x, y) south-east of post (x, y): the region's cells.
                for y in y0..y1 {
                    for x in x0..x1 {
                        let got = b
                            [band * bw * bh + ((y - crop.1) as usize) * bw + (x - crop.0) as usize];
                        let want = a[band * aw * ah + y as usize * aw + x as usize];
                        assert!(
                            got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                            "{} {name} band {band} ({x}, {y}): {got} in the part, {want} in the whole",
                            stage.name()
                        );
                        n += 1;
                    }
                }
            }
            assert!(n > 400, "{name}: compared {n} values");
        }
    }
}

/// An area of interest costs only its posts (and their reach) where the
/// method allows, and gives exactly the whole DEM's angles and sky layers
/// inside it, nodata outside: every method, bounded and not.
#[test]
fn an_area_of_interest_equals_the_whole_inside_and_is_nodata_outside() {
    use terrabake::algorithms::horizon::Method;
    use terrabake::stages::horizons::HorizonsStage;
    use terrabake::stages::sky::SkyStage;

    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("t.tif");
    terrabake::io::synth::write_geotiff(
        &tif,
        terrabake::io::synth::SynthKind::Fractal,
        90,
        70,
        4,
        Progress::hidden(),
    )
    .unwrap();
    let opts = IngestOptions {
        tile_size: 16,
        ..Default::default()
    };
    let aoi = [23u32, 18, 61, 41];
    let values = |asset: &Path, name: &str| {
        let a = Asset::open(asset).unwrap();
        let l = a.layer(name, 0).unwrap();
        let n = (l.width() * l.height()) as usize;
        let mut all = vec![0f32; n * l.bands() as usize];
        for (b, band) in all.chunks_mut(n).enumerate() {
            l.read_rows_f32(b as u32, 0, band).unwrap();
        }
        all
    };
    for (method, max_distance) in [
        (Method::Line, Some(400.0)),
        (Method::Sector, Some(300.0)),
        (Method::Sampled, Some(300.0)),
        (Method::Line, None),
        (Method::Sector, None),
    ] {
        let stage = |aoi| HorizonsStage {
            sectors: 8,
            method,
            sight: SightLines::within(max_distance),
            aoi,
            ..Default::default()
        };
        let (whole, part) = (dir.path().join("whole.tbake"), dir.path().join("aoi.tbake"));
        for (asset, area) in [(&whole, None), (&part, Some(aoi))] {
            ingest(&tif, asset, &opts, Progress::hidden()).unwrap();
            run_stage(asset, &stage(area), true, Progress::hidden()).unwrap();
            run_stage(asset, &SkyStage::default(), true, Progress::hidden()).unwrap();
        }
        for name in ["horizon", "svf", "svf_cosine", "openness", "horizon_edge"] {
            let (a, b) = (values(&whole, name), values(&part, name));
            for (i, (&want, &got)) in a.iter().zip(&b).enumerate() {
                let (x, y) = ((i % 90) as u32, (i / 90 % 70) as u32);
                let inside = (aoi[0]..aoi[2]).contains(&x) && (aoi[1]..aoi[3]).contains(&y);
                let nothing = if name == "horizon_edge" {
                    got == 0.0
                } else {
                    got.is_nan()
                };
                assert!(
                    if inside { got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()) } else { nothing },
                    "{method:?} within {max_distance:?}: {name} at ({x}, {y}): {got}, whole DEM {want}"
                );
            }
        }
    }
}
