//! The facts `examples/c/sample.c` prints through the C ABI, printed from
//! the Rust reader itself (terrabake-format, not this crate's functions),
//! line for line in the same format: `diff` of the two outputs is empty
//! when the C ABI gives the Rust reader's values.
//!
//! `cargo run --release -p terrabake-capi --example reference -- ASSET`

use terrabake_format::horizons::HorizonMap;
use terrabake_format::trace::{Method, Ray, Tracer};
use terrabake_format::{Asset, Codec, FORMAT_VERSION};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: reference ASSET")?;
    println!("format {FORMAT_VERSION}");
    let asset = match Asset::open(&path) {
        Ok(a) => a,
        Err(e) => {
            println!("open failed: {e}");
            return Ok(());
        }
    };
    println!("layers {}", asset.layers().len());
    for l in asset.layers() {
        let e = l.entry();
        print!(
            "layer {}@{} elem {} bytes {} bands {} size {}x{} tile {} tiles {}x{} azimuths",
            e.name,
            e.level,
            e.elem as u32,
            e.elem.size(),
            e.bands,
            e.width,
            e.height,
            e.tile_size,
            l.tiles_x(),
            l.tiles_y()
        );
        for a in &e.band_azimuths {
            print!(" {:016x}", a.to_bits());
        }
        println!();
        let (ww, wh) = (e.width.min(5), e.height.min(4));
        let x0 = (e.width / 3).min(e.width - ww);
        let y0 = (e.height / 2).min(e.height - wh);
        for band in [0, e.bands - 1] {
            let mut v = vec![0f32; (ww * wh) as usize];
            l.read_window_f32(band, [x0, y0, ww, wh], &mut v)?;
            print!("window {}@{} band {band} at {x0},{y0}:", e.name, e.level);
            for x in v {
                print!(" {:08x}", x.to_bits());
            }
            println!();
        }
        let stored = l.stored_chunk(0)?;
        if stored.codec == Codec::Raw {
            let fnv = stored.bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
                (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
            });
            println!(
                "tile {}@{} 0,0 bytes {} fnv {fnv:016x}",
                e.name,
                e.level,
                stored.bytes.len()
            );
        } else {
            println!("tile {}@{} 0,0 compressed", e.name, e.level);
        }
    }

    let height = asset.height()?;
    let (w, h) = (height.width(), height.height());
    for k in 0..7 {
        let mut gx = f64::from(w - 1) * (0.1 + 0.13 * f64::from(k));
        let gy = f64::from(h - 1) * (0.85 - 0.11 * f64::from(k));
        if k == 6 {
            gx = -1.0;
        }
        let z = height.bilinear(gx, gy)?.unwrap_or(f32::NAN);
        println!(
            "bilinear {:016x} {:016x} {:08x}",
            gx.to_bits(),
            gy.to_bits(),
            z.to_bits()
        );
    }

    let m = asset.manifest();
    let mut z = vec![0f32; (w * h) as usize];
    height.read_window_f32(0, [0, 0, w, h], &mut z)?;
    let top = z
        .iter()
        .fold(f32::NEG_INFINITY, |a, &b| if b > a { b } else { a });
    let dirs = [
        (1.0, 0.0),
        (0.7, 0.7),
        (0.0, 1.0),
        (-0.7, 0.7),
        (-1.0, 0.0),
        (-0.7, -0.7),
        (0.0, -1.0),
        (0.7, -0.7),
        (0.3, 0.2),
    ];
    let rays: Vec<Ray> = dirs
        .iter()
        .enumerate()
        .map(|(k, &(dx, dy))| Ray {
            origin: [
                0.5 * f64::from(w - 1) * m.cell_size.dx,
                0.5 * f64::from(h - 1) * m.cell_size.dy,
                f64::from(top) + 50.0,
            ],
            dir: [
                dx,
                dy,
                if k == dirs.len() - 1 {
                    0.5
                } else {
                    -0.05 - 0.02 * k as f64
                },
            ],
            t_min: 0.0,
            t_max: f64::INFINITY,
        })
        .collect();
    let tracer = Tracer::new(&asset)?;
    for (code, method) in Method::ALL.into_iter().enumerate() {
        let available = match method {
            Method::Hierarchical => tracer.has_pyramid(),
            Method::Parametric => tracer.has_cones(),
            _ => true,
        };
        if !available {
            println!("trace method {code} unavailable");
            continue;
        }
        for (k, ray) in rays.iter().enumerate() {
            let (hit, _) = tracer.trace(ray, method)?;
            let (cell, t) = hit.map_or(((0, 0), 0.0), |h| (h.cell, h.t));
            println!(
                "trace method {code} ray {k} hit {} cell {},{} t {:016x}",
                u32::from(hit.is_some()),
                cell.0,
                cell.1,
                f64::to_bits(t)
            );
        }
    }
    println!("threads 4 agree");

    let suns = [(90.0, 2.0), (200.0, 4.0), (300.0, 1.0), (45.0, 8.0)];
    match HorizonMap::open(&asset) {
        Err(_) => println!("lit unavailable"),
        Ok(map) => {
            for p in 0..6 {
                let (x, y) = (w / 8 + p * w / 7, h / 9 + p * h / 8);
                for (k, &(az, el)) in suns.iter().enumerate() {
                    let f = map.lit_fraction(x, y, az, el, 0.27)?.unwrap_or(f64::NAN);
                    println!("lit {x},{y} sun {k} {:016x}", f.to_bits());
                }
            }
        }
    }
    Ok(())
}
