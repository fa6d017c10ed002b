//! Pictures: every tracer renders the same image, the image shows terrain,
//! sky and shadows, and a spike casts its shadow where geometry says.

mod common;

use terrabake::io::synth::SynthKind;
use terrabake::plumbing::progress::Progress;
use terrabake::present::render::{render, RenderOptions};
use terrabake::stage::run_stage;
use terrabake::stages::cones::ConesStage;
use terrabake::stages::ingest::{ingest, IngestOptions};
use terrabake::stages::pyramid::PyramidStage;
use terrabake::terrain::sun::Sun;
use terrabake::views::builtin_views;
use terrabake_format::trace::{Method, Ray, Tracer};
use terrabake_format::Asset;

fn srtm_with_pyramid(dir: &std::path::Path) -> std::path::PathBuf {
    let out = dir.join("srtm.tbake");
    ingest(
        &common::repo_file("data/srtm3_n07w006_geographic_int16.tif"),
        &out,
        &IngestOptions::default(),
        Progress::hidden(),
    )
    .unwrap();
    run_stage(&out, &PyramidStage, false, Progress::hidden()).unwrap();
    run_stage(&out, &ConesStage::default(), false, Progress::hidden()).unwrap();
    out
}

#[test]
fn every_method_renders_the_same_picture() {
    let dir = tempfile::tempdir().unwrap();
    let asset = Asset::open(srtm_with_pyramid(dir.path())).unwrap();
    let tracer = Tracer::new(&asset).unwrap();
    let views = builtin_views(&tracer, &asset);
    assert_eq!(views.len(), 16);
    for view in [0, 5, 13] {
        let mut images = Vec::new();
        for method in [
            Method::Incremental,
            Method::Runs,
            Method::Hierarchical,
            Method::Parametric,
        ] {
            let opts = RenderOptions {
                width: 80,
                height: 60,
                method,
                sun: Sun {
                    azimuth: 250.0,
                    elevation: 4.0,
                },
                every: 1,
                shadows: terrabake::present::render::Shadows::Rays,
                exaggeration: 1.0,
                normals: terrabake::present::render::Normals::Smooth,
            };
            let (image, stats) = render(&asset, &tracer, &views[view], &opts).unwrap();
            assert_eq!(stats.primary_rays, 80 * 60);
            images.push(image.rgb);
        }
        assert!(
            images.windows(2).all(|w| w[0] == w[1]),
            "view {} differs between methods",
            view + 1
        );
        // Terrain, sky, and more than a handful of shades.
        let mut colours: Vec<[u8; 3]> = images[0].chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        colours.sort_unstable();
        colours.dedup();
        assert!(
            colours.len() > 50,
            "view {}: {} colours",
            view + 1,
            colours.len()
        );
    }
}

#[test]
fn a_spike_shadows_the_ground_behind_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = common::synth_with_pyramid(
        dir.path(),
        SynthKind::Spike,
        65,
        65,
        1,
        IngestOptions {
            tile_size: 16,
            ..Default::default()
        },
    );
    run_stage(&out, &ConesStage::default(), false, Progress::hidden()).unwrap();
    let asset = Asset::open(&out).unwrap();
    let tracer = Tracer::new(&asset).unwrap();
    // The spike: post (32, 32), 1000 m, on flat 0 m ground with 30 m posts.
    let top = [32.0 * 30.0, 32.0 * 30.0, 1000.0];
    let sun = Sun {
        azimuth: 90.0,
        elevation: 45.0,
    }
    .direction(); // from the east
    for method in [
        Method::Incremental,
        Method::Runs,
        Method::Hierarchical,
        Method::Parametric,
        Method::BruteForce,
    ] {
        // 500 m west of the spike the sun (45 degrees up) is behind its flank.
        let behind = Ray {
            origin: [top[0] - 500.0, top[1], 0.01],
            dir: sun,
            t_min: 0.0,
            t_max: f64::INFINITY,
        };
        let (hit, _) = tracer.trace(&behind, method).unwrap();
        let hit = hit.unwrap_or_else(|| panic!("{}: no shadow behind the spike", method.name()));
        assert!(
            hit.point[0] > top[0] - 30.0 && hit.point[0] <= top[0],
            "{}: {:?}",
            method.name(),
            hit.point
        );
        // 1100 m west the ray passes above the top (1100 m up when it gets there).
        let clear = Ray {
            origin: [top[0] - 1100.0, top[1], 0.01],
            dir: sun,
            t_min: 0.0,
            t_max: f64::INFINITY,
        };
        assert!(
            tracer.trace(&clear, method).unwrap().0.is_none(),
            "{}",
            method.name()
        );
        // North of the spike's shadow, in the sun.
        let beside = Ray {
            origin: [top[0] - 500.0, top[1] + 90.0, 0.01],
            dir: sun,
            t_min: 0.0,
            t_max: f64::INFINITY,
        };
        assert!(
            tracer.trace(&beside, method).unwrap().0.is_none(),
            "{}",
            method.name()
        );
    }
}

#[test]
fn render_command_writes_a_png_and_statistics() {
    let dir = tempfile::tempdir().unwrap();
    let asset = srtm_with_pyramid(dir.path());
    let png_path = dir.path().join("view.png");
    let out = common::terrabake(&[
        "render",
        asset.to_str().unwrap(),
        "--view",
        "7",
        "--size",
        "64x48",
        "--method",
        "runs",
        "--json",
        "-o",
        png_path.to_str().unwrap(),
        "-q",
    ]);
    assert!(out.status.success(), "{}", common::stderr(&out));
    let report: serde_json::Value = serde_json::from_str(&common::stdout(&out)).unwrap();
    assert_eq!(report["method"], "runs");
    assert_eq!(report["stats"]["primary_rays"], 64 * 48);
    assert!(report["stats"]["mean_steps"].as_f64().unwrap() > 1.0);
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(&png_path).unwrap(),
    ));
    let info = decoder.read_info().unwrap().info().clone();
    assert_eq!((info.width, info.height), (64, 48));
    // Free camera, and a clear error without a pyramid for hierarchical.
    let plain = dir.path().join("plain.tbake");
    common::terrabake(&[
        "ingest",
        "data/srtm3_n07w006_geographic_int16.tif",
        "-o",
        plain.to_str().unwrap(),
        "-q",
    ]);
    let free_camera = |extra: &[&str]| {
        let mut args = vec![
            "render",
            plain.to_str().unwrap(),
            "--camera",
            "50000,50000,900",
            "--look-at",
            "60000,60000,300",
            "--size",
            "32x24",
        ];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["-o", png_path.to_str().unwrap()]);
        common::terrabake(&args)
    };
    let out = free_camera(&[]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        common::stderr(&out).contains("pyramid"),
        "{}",
        common::stderr(&out)
    );
    let out = free_camera(&["--method", "incremental"]);
    assert!(out.status.success(), "{}", common::stderr(&out));
}

#[test]
fn horizon_shadows_agree_with_shadow_rays() {
    // The same view of a fractal DEM lit with shadow rays and with the
    // stored horizons (32 exact sight-line directions, f32 angles, no
    // curvature: the tracer's geometry): the pictures agree but for soft edges and the sun's
    // azimuth falling between two directions.
    let dir = tempfile::tempdir().unwrap();
    let out = common::synth_with_pyramid(
        dir.path(),
        SynthKind::Fractal,
        160,
        160,
        3,
        IngestOptions::default(),
    );
    let stage = terrabake::stages::horizons::HorizonsStage {
        sectors: 32,
        sight: terrabake::stage::sight::SightLines {
            curvature: Some(false),
            ..Default::default()
        },
        encoding: Some(terrabake_format::horizons::AngleEncoding::F32),
        ..Default::default()
    };
    run_stage(&out, &stage, false, Progress::hidden()).unwrap();
    let asset = Asset::open(&out).unwrap();
    let tracer = Tracer::new(&asset).unwrap();
    let views = builtin_views(&tracer, &asset);
    let picture = |view: &terrabake::views::Camera, shadows| {
        let opts = RenderOptions {
            width: 160,
            height: 100,
            method: Method::Hierarchical,
            sun: Sun {
                azimuth: 250.0,
                elevation: 8.0,
            },
            every: 1,
            shadows,
            exaggeration: 1.0,
            normals: terrabake::present::render::Normals::Smooth,
        };
        render(&asset, &tracer, view, &opts).unwrap().0.rgb
    };
    use terrabake::present::render::Shadows;
    let differ = |a: &[u8], b: &[u8]| {
        a.chunks(3)
            .zip(b.chunks(3))
            .filter(|(p, q)| p.iter().zip(q.iter()).any(|(x, y)| x.abs_diff(*y) > 3))
            .count()
    };
    // The built-in view with the most shadow in it.
    let (shadowed, view, rays) = views
        .iter()
        .map(|v| {
            let rays = picture(v, Shadows::Rays);
            (differ(&rays, &picture(v, Shadows::Off)), v, rays)
        })
        .max_by_key(|r| r.0)
        .unwrap();
    assert!(
        shadowed > 160 * 100 / 50,
        "the views have shadows: {shadowed}"
    );
    let disagree = differ(&rays, &picture(view, Shadows::Horizons));
    eprintln!("{disagree} of {shadowed} shadowed pixels disagree");
    assert!(
        disagree * 10 < shadowed,
        "{disagree} pixels disagree, {shadowed} shadowed"
    );
}

/// Under a vertical exaggeration the shadows are those of the exaggerated
/// surface that is shaded (a lower sun over the true heights): the demo's
/// view at 8x casts shadows over a tenth of the picture (it cast them on 79
/// of 655,360 pixels when shadow rays used the true surface).
#[test]
fn shadows_fall_on_the_exaggerated_surface() {
    use terrabake::present::render::Shadows;
    use terrabake::views::Camera;
    let dir = tempfile::tempdir().unwrap();
    let srtm = Asset::open(srtm_with_pyramid(dir.path())).unwrap();
    let tracer = Tracer::new(&srtm).unwrap();
    let demo_view = Camera {
        eye: [30000.0, 8000.0, 4500.0],
        look_at: [55000.0, 60000.0, 500.0],
        fov: 60.0,
    };
    let cast = |e: f64| {
        let picture = |shadows| {
            let opts = RenderOptions {
                width: 256,
                height: 160,
                method: Method::Hierarchical,
                sun: Sun {
                    azimuth: 290.0,
                    elevation: 10.0,
                },
                every: 1,
                shadows,
                exaggeration: e,
                normals: terrabake::present::render::Normals::Smooth,
            };
            render(&srtm, &tracer, &demo_view, &opts).unwrap().0.rgb
        };
        let (a, b) = (picture(Shadows::Rays), picture(Shadows::Off));
        a.chunks(3).zip(b.chunks(3)).filter(|(p, q)| p != q).count()
    };
    let (true_surface, exaggerated) = (cast(1.0), cast(8.0));
    assert!(
        exaggerated > 256 * 160 / 20 && exaggerated > 5 * true_surface,
        "{exaggerated} pixels in cast shadow at 8x, {true_surface} at 1x"
    );
}

/// Smooth normals take the facets out of the picture: on the demo's view,
/// the light changes less from one pixel to the next than with each
/// triangle's own normal, while every hit, and so the silhouette, stays.
#[test]
fn smooth_normals_show_no_facets() {
    use terrabake::present::render::{Normals, Shadows};
    use terrabake::views::Camera;
    let dir = tempfile::tempdir().unwrap();
    let srtm = Asset::open(srtm_with_pyramid(dir.path())).unwrap();
    let tracer = Tracer::new(&srtm).unwrap();
    let view = Camera {
        eye: [30000.0, 8000.0, 4500.0],
        look_at: [55000.0, 60000.0, 500.0],
        fov: 60.0,
    };
    let picture = |normals| {
        let opts = RenderOptions {
            width: 320,
            height: 200,
            method: Method::Hierarchical,
            sun: Sun {
                azimuth: 290.0,
                elevation: 30.0,
            },
            every: 1,
            shadows: Shadows::Off,
            exaggeration: 4.0,
            normals,
        };
        render(&srtm, &tracer, &view, &opts).unwrap().0.rgb
    };
    let (smooth, flat) = (picture(Normals::Smooth), picture(Normals::Flat));
    // The sky is where it was: same hits.
    let sky =
        |rgb: &[u8]| -> Vec<bool> { rgb.chunks(3).map(|p| p[2] > p[0] && p[2] > 200).collect() };
    assert_eq!(sky(&smooth), sky(&flat));
    // Total variation of the green channel along rows.
    let variation = |rgb: &[u8]| -> u64 {
        rgb.chunks(3 * 320)
            .flat_map(|row| {
                row.chunks(3)
                    .collect::<Vec<_>>()
                    .windows(2)
                    .map(|w| u64::from(w[0][1].abs_diff(w[1][1])))
                    .collect::<Vec<_>>()
            })
            .sum()
    };
    let (s, f) = (variation(&smooth), variation(&flat));
    eprintln!("variation smooth {s}, flat {f}");
    assert!(s * 2 < f, "smooth {s} against flat {f}");
}
