//! The reference WGSL shader against the CPU parametric tracer, on the
//! bundled SRTM tile (1201 x 1201 posts, 92 m) baked with the exact cone
//! planes and exported as the cone texture (dilated for filtering): the
//! same rays, the same hits within f32's reach. Runs on whatever Vulkan
//! adapter the machine has (lavapipe where there is no GPU; the test
//! script installs it); with none, it says so and passes only when
//! `TERRABAKE_REQUIRE_GPU` is unset.

use std::path::Path;

use terrabake::bake::recipe::{bake, Recipe};
use terrabake::plumbing::progress::Progress;
use terrabake::stage::asset::Wait;
use terrabake_format::trace::{Method, Ray, Tracer};
use terrabake_format::Asset;
use terrabake_gpu::{Gpu, Scene, Shading};

fn repo(path: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

#[test]
fn the_shader_finds_the_cpu_tracers_hits() {
    let gpu = match Gpu::new() {
        Ok(g) => g,
        Err(why) if std::env::var_os("TERRABAKE_REQUIRE_GPU").is_none() => {
            eprintln!("shader test skipped: {why}");
            return;
        }
        Err(why) => panic!("{why}"),
    };
    eprintln!("adapter: {}", gpu.adapter);
    let dir = tempfile::tempdir().unwrap();
    let asset_dir = dir.path().join("srtm.tbake");
    let recipe_path = dir.path().join("r.toml");
    let recipe = Recipe::parse(
        &recipe_path,
        "[[stage]]\nname = \"pyramid\"\n[[stage]]\nname = \"cones\"\nslices = \"exact\"\n\
         [[stage]]\nname = \"horizons\"\nsectors = 16\nencoding = \"u16\"\n"
            .into(),
    )
    .unwrap();
    bake(
        &repo("data/srtm3_n07w006_geographic_int16.tif"),
        &asset_dir,
        &recipe,
        Wait::Wait,
        Progress::hidden(),
    )
    .unwrap();
    let asset = Asset::open(&asset_dir).unwrap();
    let m = asset.manifest();
    let (pw, ph) = (m.width, m.height);
    let mut heights = vec![0f32; pw as usize * ph as usize];
    asset
        .height()
        .unwrap()
        .read_rows_f32(0, 0, &mut heights)
        .unwrap();
    // The exported texture's texels (what `export -o cones.ktx2` writes).
    let texture = terrabake::export::texture::texture_for_layer(
        &asset,
        asset.layer("cone_slope", 0).unwrap(),
    )
    .unwrap();
    let cones: Vec<[f32; 2]> = texture
        .data
        .chunks(8)
        .map(|b| {
            [
                f32::from_le_bytes(b[..4].try_into().unwrap()),
                f32::from_le_bytes(b[4..].try_into().unwrap()),
            ]
        })
        .collect();
    // The exported horizon array (16-bit codes) and a low sun.
    let horizons =
        terrabake::export::texture::texture_for_layer(&asset, asset.layer("horizon", 0).unwrap())
            .unwrap();
    let codes: Vec<u16> = horizons
        .data
        .chunks(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    let map = terrabake_format::horizons::HorizonMap::open(&asset).unwrap();
    let q = map.encoding().quantization().unwrap();
    let sun = [250.0, 3.0, 0.27];
    let scene = Scene {
        heights: &heights,
        posts: (pw, ph),
        spacing: (m.cell_size.dx, m.cell_size.dy),
        cones: &cones,
        shading: Some(Shading {
            codes: &codes,
            decode: (q.offset, q.scale),
            azimuths: map.azimuths(),
            sun,
        }),
    };
    // Rays from above the terrain at random places, in every direction,
    // down at random angles from 0.1 to 30 degrees below the horizontal,
    // most of them shallow (long, grazing: where leaps and rounding matter).
    let tracer = Tracer::new(&asset).unwrap();
    let (x_max, y_max) = tracer.extent();
    let top = f64::from(m.height_range.unwrap().max);
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let rays: Vec<Ray> = (0..20000)
        .map(|_| {
            let shallow = next();
            let (az, down) = (
                next() * std::f64::consts::TAU,
                (0.1 + 29.9 * shallow * shallow).to_radians(),
            );
            Ray {
                origin: [next() * x_max, next() * y_max, top + 10.0 + 300.0 * next()],
                dir: [az.sin() * down.cos(), az.cos() * down.cos(), -down.sin()],
                t_min: 0.0,
                t_max: f64::INFINITY,
            }
        })
        .collect();
    let got = gpu.trace(&scene, &rays);
    let cells_x = pw - 1;
    let (mut same_cell, mut near_cell, mut both_miss) = (0, 0, 0);
    let mut worst_t = 0f64;
    let (mut worst_lit, mut shaded, mut partial, mut dark) = (0f64, 0, 0, 0);
    let (mut steps_gpu, mut steps_cpu) = (0u64, 0u64);
    for (ray, g) in rays.iter().zip(&got) {
        let (cpu, cost) = tracer.trace(ray, Method::Parametric).unwrap();
        steps_cpu += cost.steps;
        steps_gpu += u64::from(g.cells_tested);
        match (cpu, g.cell(cells_x)) {
            (None, None) => both_miss += 1,
            (Some(h), Some((c, r))) => {
                // f32 against f64: the hit parameter within 1e-4 of the
                // ray's length to it, and the same cell or a neighbour (a
                // grazing ray may meet the surface at a shared edge).
                let dt = (f64::from(g.t) - h.t).abs() / h.t.max(1.0);
                worst_t = worst_t.max(dt);
                assert!(dt < 1e-4, "ray {ray:?}: GPU t {} against CPU {}", g.t, h.t);
                let (dc, dr) = (c.abs_diff(h.cell.0), r.abs_diff(h.cell.1));
                assert!(
                    dc <= 1 && dr <= 1,
                    "ray {ray:?}: GPU cell ({c}, {r}) against CPU {:?}",
                    h.cell
                );
                if (dc, dr) == (0, 0) {
                    same_cell += 1;
                } else {
                    near_cell += 1;
                }
                // The shading, at the post nearest the GPU's hit, against
                // the Rust reader's lit fraction there.
                let post =
                    |v: f64, last: u32| v.round_ties_even().clamp(0.0, f64::from(last)) as u32;
                let g_point = tracer.grid_ray(ray).at(f64::from(g.t));
                let (x, y) = (post(g_point[0], pw - 1), post(g_point[1], ph - 1));
                let want = map.lit_fraction(x, y, sun[0], sun[1], sun[2]).unwrap();
                match want {
                    None => assert_eq!(g.lit, -1.0, "nodata post ({x}, {y})"),
                    Some(w) => {
                        let dl = (f64::from(g.lit) - w).abs();
                        worst_lit = worst_lit.max(dl);
                        assert!(
                            dl < 2e-3,
                            "ray {ray:?}: GPU lit {} against {w} at ({x}, {y})",
                            g.lit
                        );
                        shaded += 1;
                        if w > 0.0 && w < 1.0 {
                            partial += 1;
                        }
                        if w == 0.0 {
                            dark += 1;
                        }
                    }
                }
            }
            (cpu, gpu_cell) => panic!("ray {ray:?}: CPU {cpu:?}, GPU {gpu_cell:?} ({g:?})"),
        }
    }
    eprintln!(
        "shading: {shaded} hits shaded, {dark} in shadow, {partial} under a partly hidden sun, largest difference from the Rust reader {worst_lit:.1e}"
    );
    eprintln!(
        "{} rays: {same_cell} hits in the same cell, {near_cell} in a neighbouring one (a shared edge), {both_miss} misses by both; worst relative t difference {worst_t:.2e}; cells tested per ray: GPU {:.1}, CPU steps {:.1}",
        rays.len(),
        steps_gpu as f64 / rays.len() as f64,
        steps_cpu as f64 / rays.len() as f64
    );
    assert!(same_cell > 9 * (same_cell + near_cell) / 10);
    assert!(
        dark > 100 && shaded - dark > 100,
        "the sun lights some hits and not others"
    );
}
