//! Engine heightmaps (`export --for unreal|unity|godot`): the files read
//! back as each engine reads them (PNG big-endian north first, RAW
//! little-endian south first, EXR float), with the sidecar's numbers, give
//! the asset's heights back within half a quantisation step (exactly from
//! the EXR); padding repeats the edge posts, nodata holds the lowest
//! height, and tiles share their edge posts.

mod common;

use std::path::Path;

use common::{heights, stderr, terrabake};
use terrabake::export::engine::{export_heightmap, Engine};
use terrabake::plumbing::progress::Progress;
use terrabake_format::Asset;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A 150 x 100 fractal with nodata holes, posts 25 x 40 m apart.
fn asset(dir: &Path) -> std::path::PathBuf {
    let (tif, asset) = (dir.join("dem.tif"), dir.join("dem.tbake"));
    for args in [
        vec!["synth", "holes", "--size", "150x100", "-o", s(&tif), "-q"],
        vec![
            "ingest",
            s(&tif),
            "-o",
            s(&asset),
            "--cell-size",
            "25,40",
            "--tile",
            "16",
            "-q",
        ],
    ] {
        let o = terrabake(&args);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    asset
}

/// The file as its engine reads it: values row by row, north first.
fn read_back(engine: Engine, path: &Path, (w, h): (u32, u32)) -> Vec<f64> {
    match engine {
        Engine::Unreal => {
            let decoder =
                png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
            let mut reader = decoder.read_info().unwrap();
            let mut buf = vec![0; reader.output_buffer_size().unwrap()];
            let info = reader.next_frame(&mut buf).unwrap();
            assert_eq!(
                (info.width, info.height, info.bit_depth, info.color_type),
                (w, h, png::BitDepth::Sixteen, png::ColorType::Grayscale)
            );
            buf.chunks(2)
                .map(|b| f64::from(u16::from_be_bytes([b[0], b[1]])))
                .collect()
        }
        Engine::Unity => {
            let bytes = std::fs::read(path).unwrap();
            assert_eq!(bytes.len() as u64, u64::from(w) * u64::from(h) * 2);
            let values: Vec<f64> = bytes
                .chunks(2)
                .map(|b| f64::from(u16::from_le_bytes([b[0], b[1]])))
                .collect();
            // South first in the file.
            values.chunks(w as usize).rev().flatten().copied().collect()
        }
        Engine::Godot => {
            use exr::prelude::*;
            let image = read_first_flat_layer_from_file(path).unwrap();
            let layer = image.layer_data;
            assert_eq!(layer.size, Vec2(w as usize, h as usize));
            let channels = &layer.channel_data.list;
            assert_eq!(channels.len(), 1);
            assert_eq!(channels[0].name.to_string(), "R");
            match &channels[0].sample_data {
                FlatSamples::F32(v) => v.iter().map(|&z| f64::from(z)).collect(),
                other => panic!("{other:?}"),
            }
        }
    }
}

#[test]
fn engine_heightmaps_give_the_heights_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = asset(dir.path());
    let a = Asset::open(&path).unwrap();
    let z = heights(&a);
    let (w, h) = (150usize, 100usize);
    let lowest = z
        .iter()
        .filter(|v| !v.is_nan())
        .fold(f32::INFINITY, |m, &v| m.min(v));
    assert!(z.iter().any(|v| v.is_nan()), "the DEM has holes");
    // `None`: the engine's own sizes (one file); 33: tiles of 33 posts.
    for (engine, max_tile) in [
        (Engine::Unreal, None),
        (Engine::Unreal, Some(33)),
        (Engine::Unity, None),
        (Engine::Unity, Some(33)),
        (Engine::Godot, None),
    ] {
        let out = dir.path().join(format!("{}_{max_tile:?}", engine.name()));
        let car = export_heightmap(&a, engine, &out, max_tile, Progress::hidden()).unwrap();
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("heightmap.json")).unwrap()).unwrap();
        let (offset, scale) = (
            json["height"]["offset_m"].as_f64().unwrap(),
            json["height"]["scale_m"].as_f64().unwrap(),
        );
        let tolerance = json["height"]["max_error_m"].as_f64().unwrap() + 1e-9 * 2000.0;
        if engine == Engine::Godot {
            assert_eq!((offset, scale), (0.0, 1.0));
        }
        let (sx, sy) = car.layout.size;
        assert!(sx as usize >= w && sy as usize >= h);
        if max_tile.is_some() {
            assert!(car.files.len() > 1, "{engine:?}: tiled");
        }
        // The padded grid, assembled from the files (tiles overlap on their
        // shared edges, which must agree).
        let mut grid = vec![f64::NAN; sx as usize * sy as usize];
        for f in &car.files {
            let [x0, y0, fw, fh] = f.window;
            let values = read_back(engine, &out.join(&f.file), (fw, fh));
            for r in 0..fh as usize {
                for c in 0..fw as usize {
                    let cell = &mut grid[(y0 as usize + r) * sx as usize + x0 as usize + c];
                    let v = values[r * fw as usize + c];
                    assert!(
                        cell.is_nan() || *cell == v,
                        "{engine:?}: tiles disagree on a shared post"
                    );
                    *cell = v;
                }
            }
        }
        for y in 0..sy as usize {
            for x in 0..sx as usize {
                let value = grid[y * sx as usize + x];
                assert!(!value.is_nan(), "{engine:?}: post ({x}, {y}) in no file");
                let got = offset + scale * value;
                // Past the DEM: its edge post; nodata: the lowest height.
                let source = z[y.min(h - 1) * w + x.min(w - 1)];
                let want = f64::from(if source.is_nan() { lowest } else { source });
                assert!(
                    (got - want).abs() <= tolerance,
                    "{engine:?} {max_tile:?} at ({x}, {y}): {got} against {want}"
                );
                // The engines' own formulas from the sidecar.
                if engine == Engine::Unreal {
                    let loc = json["unreal"]["location_cm"][2].as_f64().unwrap();
                    let scale_z = json["unreal"]["scale_cm"][2].as_f64().unwrap();
                    let cm = loc + scale_z * (value - 32768.0) / 128.0;
                    assert!(
                        (cm / 100.0 - want).abs() <= tolerance,
                        "unreal's Z at ({x}, {y})"
                    );
                }
                if engine == Engine::Unity {
                    let size_y = json["unity"]["size_m"][1].as_f64().unwrap();
                    let pos_y = json["unity"]["position_m"][1].as_f64().unwrap();
                    let m = pos_y + size_y * value / 65535.0;
                    assert!(
                        (m - want).abs() <= tolerance,
                        "unity's height at ({x}, {y})"
                    );
                }
            }
        }
        if engine == Engine::Unreal {
            assert_eq!(json["unreal"]["scale_cm"][0].as_f64(), Some(2500.0));
            assert_eq!(json["unreal"]["scale_cm"][1].as_f64(), Some(4000.0));
        }
        if engine == Engine::Unity {
            let res = json["unity"]["resolution"].as_u64().unwrap() as u32;
            assert!((res - 1).is_power_of_two(), "{res}");
            assert_eq!(
                json["unity"]["size_m"][0].as_f64(),
                Some(f64::from(res - 1) * 25.0)
            );
        }
    }
}

#[test]
fn export_for_an_engine_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = asset(dir.path());
    let out = dir.path().join("unreal");
    let o = terrabake(&["export", s(&path), "--for", "unreal", "-o", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("253 x 253"), "{}", stderr(&o));
    assert!(out.join("heightmap.png").is_file() && out.join("heightmap.json").is_file());
    // Engines take heights only.
    let o = terrabake(&[
        "export",
        s(&path),
        "--for",
        "unity",
        "--layer",
        "pyramid_max",
        "-o",
        s(&out),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("height layer"), "{}", stderr(&o));
}
