//! Textures for shaders (`export ... -o X.ktx2`): the files parse with an
//! independent KTX2 reader (the `ktx2` crate) as the formats they claim;
//! horizon arrays decode to the stored angles; and the cone texture is
//! conservative under bilinear filtering, checked against every cell of
//! the DEM from thousands of filtered samples, where the undilated planes,
//! filtered the same way, are not.

mod common;

use std::path::Path;

use common::{stderr, terrabake};
use terrabake_format::Asset;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn run(args: &[&str]) {
    let o = terrabake(args);
    assert!(o.status.success(), "{args:?}: {}", stderr(&o));
}

/// A fractal DEM with holes, 90 x 70 posts 30 x 20 m apart, baked with
/// `recipe` (its stages; the ingest table is added).
fn baked(dir: &Path, recipe: &str) -> std::path::PathBuf {
    let (tif, toml, asset) = (
        dir.join("dem.tif"),
        dir.join("r.toml"),
        dir.join("dem.tbake"),
    );
    std::fs::write(
        &toml,
        format!("[ingest]\ncell_size = [30.0, 20.0]\n{recipe}"),
    )
    .unwrap();
    run(&["synth", "holes", "--size", "90x70", "-o", s(&tif), "-q"]);
    run(&["bake", s(&tif), "-o", s(&asset), "--recipe", s(&toml), "-q"]);
    asset
}

fn kv(reader: &ktx2::Reader<Vec<u8>>, key: &str) -> String {
    reader
        .key_value_data()
        .find(|(k, _)| *k == key)
        .map(|(_, v)| {
            String::from_utf8_lossy(v)
                .trim_end_matches('\0')
                .to_string()
        })
        .unwrap_or_else(|| panic!("no key {key}"))
}

#[test]
fn horizon_arrays_decode_to_the_stored_angles() {
    for (encoding, format, bits) in [
        ("u8", ktx2::Format::R8_UNORM, 8u32),
        ("f32", ktx2::Format::R16_UNORM, 16),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let asset = baked(
            dir.path(),
            &format!("[[stage]]\nname = \"horizons\"\nsectors = 6\nencoding = \"{encoding}\"\n"),
        );
        let out = dir.path().join("h.ktx2");
        run(&[
            "export",
            s(&asset),
            "--layer",
            "horizon",
            "-o",
            s(&out),
            "-q",
        ]);
        let reader = ktx2::Reader::new(std::fs::read(&out).unwrap()).unwrap();
        let header = reader.header();
        assert_eq!(header.format, Some(format), "{encoding}");
        assert_eq!(
            (
                header.pixel_width,
                header.pixel_height,
                header.layer_count,
                header.level_count
            ),
            (90, 70, 6, 1)
        );
        let block = reader.dfd_blocks().next().unwrap();
        let basic = ktx2::DfdBlockBasic::parse(block.data).unwrap();
        let samples: Vec<_> = basic.sample_information().collect();
        assert_eq!(samples.len(), 1);
        assert_eq!(u32::from(samples[0].bit_length.get()), bits);
        let decode: serde_json::Value =
            serde_json::from_str(&kv(&reader, "terrabake.decode")).unwrap();
        let (offset, scale) = (
            decode["offset"].as_f64().unwrap(),
            decode["scale"].as_f64().unwrap(),
        );
        let azimuths: Vec<f64> =
            serde_json::from_str(&kv(&reader, "terrabake.band_azimuths")).unwrap();
        let a = Asset::open(&asset).unwrap();
        let layer = a.layer("horizon", 0).unwrap();
        assert_eq!(azimuths, layer.entry().band_azimuths);
        let data = reader.levels().next().unwrap().data;
        let posts = 90 * 70;
        let mut want = vec![0f32; posts];
        for b in 0..6 {
            layer.read_rows_f32(b, 0, &mut want).unwrap();
            for (i, &deg) in want.iter().enumerate() {
                let k = b as usize * posts + i;
                let code = if bits == 8 {
                    u32::from(data[k])
                } else {
                    u32::from(u16::from_le_bytes([data[2 * k], data[2 * k + 1]]))
                };
                if deg.is_nan() {
                    assert_eq!(code, 0);
                    continue;
                }
                let got = offset + scale * f64::from(code);
                // u8: the stored code itself; f32: 16 bits, nearest.
                let tolerance = if bits == 8 { 1e-4 } else { scale / 2.0 + 1e-6 };
                assert!(
                    (got - f64::from(deg)).abs() <= tolerance,
                    "{encoding} band {b} post {i}: {got} against {deg}"
                );
            }
        }
    }
}

/// The filtered sample at grid point `p` (posts; cell `(c, r)` spans
/// `c..c+1`, `r..r+1`) of a one-texel-per-cell plane: bilinear between
/// texel centres, clamped at the edges, as a GPU samples.
fn bilinear(plane: &[f32], (cw, ch): (usize, usize), (px, py): (f64, f64)) -> f64 {
    let (u, v) = (px - 0.5, py - 0.5);
    let (i0, j0) = (u.floor(), v.floor());
    let (fx, fy) = (u - i0, v - j0);
    let at = |i: f64, j: f64| {
        let (i, j) = (
            i.clamp(0.0, (cw - 1) as f64) as usize,
            j.clamp(0.0, (ch - 1) as f64) as usize,
        );
        f64::from(plane[j * cw + i])
    };
    (1.0 - fy) * ((1.0 - fx) * at(i0, j0) + fx * at(i0 + 1.0, j0))
        + fy * ((1.0 - fx) * at(i0, j0 + 1.0) + fx * at(i0 + 1.0, j0 + 1.0))
}

#[test]
fn cone_textures_are_conservative_under_bilinear_filtering() {
    let dir = tempfile::tempdir().unwrap();
    let asset = baked(
        dir.path(),
        "[[stage]]\nname = \"pyramid\"\n[[stage]]\nname = \"cones\"\nslices = \"exact\"\n",
    );
    let out = dir.path().join("cones.ktx2");
    run(&[
        "export",
        s(&asset),
        "--layer",
        "cone_slope",
        "-o",
        s(&out),
        "-q",
    ]);
    let reader = ktx2::Reader::new(std::fs::read(&out).unwrap()).unwrap();
    let header = reader.header();
    assert_eq!(header.format, Some(ktx2::Format::R32G32_SFLOAT));
    let (cw, ch) = (header.pixel_width as usize, header.pixel_height as usize);
    assert_eq!((cw, ch), (89, 69), "one texel per cell");
    let data = reader.levels().next().unwrap().data;
    let f = |k: usize| f32::from_le_bytes(data[4 * k..4 * k + 4].try_into().unwrap());
    let apex: Vec<f32> = (0..cw * ch).map(|i| f(2 * i)).collect();
    let slope: Vec<f32> = (0..cw * ch).map(|i| f(2 * i + 1)).collect();
    assert!(apex.iter().chain(&slope).all(|v| v.is_finite()));

    // The stored planes, undilated, filtered the same way.
    let a = Asset::open(&asset).unwrap();
    let read = |name: &str| {
        let l = a.layer(name, 0).unwrap();
        let mut v = vec![0f32; cw * ch];
        l.read_rows_f32(0, 0, &mut v).unwrap();
        v.iter()
            .map(|&x| if x.is_infinite() { 1e30 } else { x })
            .collect::<Vec<f32>>()
    };
    let (raw_apex, raw_slope) = (read("cone_apex"), read("cone_slope"));

    // Every cell with a surface and its tallest corner.
    let z = common::heights(&a);
    let w = cw + 1;
    let cells: Vec<(usize, usize, f64)> = (0..ch)
        .flat_map(|r| (0..cw).map(move |c| (c, r)))
        .filter_map(|(c, r)| {
            let corners = [
                z[r * w + c],
                z[r * w + c + 1],
                z[(r + 1) * w + c],
                z[(r + 1) * w + c + 1],
            ];
            corners.iter().all(|v| !v.is_nan()).then(|| {
                (
                    c,
                    r,
                    corners.iter().fold(f64::MIN, |m, &v| m.max(f64::from(v))),
                )
            })
        })
        .collect();
    let cell = &a.manifest().cell_size;
    assert_eq!((cell.dx, cell.dy), (30.0, 20.0));
    let (dx, dy) = (cell.dx, cell.dy);
    // Terrain inside the cone from p: a cell taller than the apex nearer
    // than the slope allows.
    let violations = |apex: f64, slope: f64, (px, py): (f64, f64)| {
        cells
            .iter()
            .filter(|&&(c, r, top)| {
                let ex = (c as f64 - px).max(px - (c + 1) as f64).max(0.0) * dx;
                let ey = (r as f64 - py).max(py - (r + 1) as f64).max(0.0) * dy;
                top > apex && (ex * ex + ey * ey).sqrt() < slope * (top - apex) - 1e-6
            })
            .count()
    };
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut ours, mut plain, samples) = (0, 0, 3000);
    for _ in 0..samples {
        let p = (next() * cw as f64, next() * ch as f64);
        ours += violations(
            bilinear(&apex, (cw, ch), p),
            bilinear(&slope, (cw, ch), p),
            p,
        );
        plain += violations(
            bilinear(&raw_apex, (cw, ch), p),
            bilinear(&raw_slope, (cw, ch), p),
            p,
        );
    }
    assert_eq!(
        ours, 0,
        "the dilated cone texture let terrain into a filtered cone"
    );
    assert!(
        plain > 0,
        "the undilated planes, filtered, were conservative here too: the test terrain shows nothing"
    );
    eprintln!(
        "{samples} filtered samples: undilated planes {plain} cells inside a cone, dilated 0"
    );
}

/// `--fourier K`: 2K + 1 float layers, coefficient by coefficient, each
/// post's the least-squares fit of its bands (the same as fitting the
/// asset's bands here), and they give the bands back at the band azimuths
/// no worse than the fit allows.
#[test]
fn fourier_horizon_textures_hold_each_posts_fit() {
    use terrabake::algorithms::horizon::fourier::FourierBasis;
    let dir = tempfile::tempdir().unwrap();
    let asset = baked(
        dir.path(),
        "[[stage]]\nname = \"horizons\"\nsectors = 16\nencoding = \"f32\"\n",
    );
    let out = dir.path().join("f.ktx2");
    run(&[
        "export",
        s(&asset),
        "--layer",
        "horizon",
        "--fourier",
        "4",
        "-o",
        s(&out),
        "-q",
    ]);
    let reader = ktx2::Reader::new(std::fs::read(&out).unwrap()).unwrap();
    let header = reader.header();
    assert_eq!(header.format, Some(ktx2::Format::R32_SFLOAT));
    assert_eq!(
        (header.layer_count, header.pixel_width, header.pixel_height),
        (9, 90, 70)
    );
    assert!(kv(&reader, "terrabake.fourier").contains("cos(k a)"));
    let data = reader.levels().next().unwrap().data;
    let coefficient = |j: usize, i: usize| {
        let k = 4 * (j * 90 * 70 + i);
        f32::from_le_bytes(data[k..k + 4].try_into().unwrap())
    };
    let a = Asset::open(&asset).unwrap();
    let (bands, azimuths) = terrabake::stages::horizons::read_horizons(&a).unwrap();
    let fit = FourierBasis::new(&azimuths, 4).unwrap();
    let (mut post, mut want, mut back) = (vec![0f32; 16], vec![0f32; 9], vec![0f64; 16]);
    let mut checked = 0;
    for i in 0..90 * 70 {
        post.iter_mut().zip(&bands).for_each(|(p, b)| *p = b[i]);
        let got: Vec<f32> = (0..9).map(|j| coefficient(j, i)).collect();
        if post.iter().any(|v| v.is_nan()) {
            assert!(got.iter().all(|c| c.is_nan()), "nodata post {i}");
            continue;
        }
        fit.fit(&post, &mut want);
        assert_eq!(got, want, "post {i}");
        // Nothing fits the bands better with 9 coefficients than the
        // least squares does: no worse than the post's own mean.
        fit.reconstruct(&got, &mut back);
        let mean = post.iter().map(|&v| f64::from(v)).sum::<f64>() / 16.0;
        let sq = |f: &dyn Fn(usize) -> f64| {
            (0..16)
                .map(|b| (f(b) - f64::from(post[b])).powi(2))
                .sum::<f64>()
        };
        assert!(sq(&|b| back[b]) <= sq(&|_| mean) + 1e-6, "post {i}");
        checked += 1;
    }
    assert!(checked > 90 * 70 / 2);
}
