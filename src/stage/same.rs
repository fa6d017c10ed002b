//! Whether two assets hold the same values: what `verify --same-as`
//! reports and what a partitioned bake's join is held to. Layers compare
//! by what their stored values mean and by the values decoded, never by
//! how they are tiled or compressed, so a zstd asset equals its raw twin.

use terrabake_format::{Asset, LayerEntry, Manifest, Mmap};

/// How the layers of `a` differ from those of `b` once decoded (empty: the
/// same layers, every value the same bit for bit, any NaN equal to any
/// other), with the manifest's statistics: one line per difference, the
/// first post that differs in each band. What `verify --same-as` reports
/// and the partitioned bake's tests hold the join to.
pub fn differences(a: &Asset<Mmap>, b: &Asset<Mmap>) -> crate::Result<Vec<String>> {
    let (ma, mb) = (a.manifest(), b.manifest());
    let keys = |m: &Manifest| {
        let mut k: Vec<String> = m.layers.iter().map(LayerEntry::key).collect();
        k.sort();
        k
    };
    let mut out = Vec::new();
    if keys(ma) != keys(mb) {
        out.push(format!("layers {:?} against {:?}", keys(ma), keys(mb)));
    }
    if (
        ma.width,
        ma.height,
        &ma.cell_size,
        ma.nodata.count,
        ma.height_range,
    ) != (
        mb.width,
        mb.height,
        &mb.cell_size,
        mb.nodata.count,
        mb.height_range,
    ) {
        out.push("grid, cell size, nodata count or height range differ".into());
    }
    for la in a.layers() {
        let e = la.entry();
        let Ok(lb) = b.layer(&e.name, e.level) else {
            continue;
        };
        let eb = lb.entry();
        if meaning(e) != meaning(eb) {
            out.push(format!(
                "{}: element type, shape, azimuths or quantisation differ",
                e.key()
            ));
            continue;
        }
        // A band of rows at a time (about 4 MiB a side), not whole layers:
        // comparing two large assets holds no more than that.
        let (w, h) = (e.width as usize, e.height as usize);
        let rows = ((1 << 20) / w).clamp(1, h);
        let (mut va, mut vb) = (vec![0f32; rows * w], vec![0f32; rows * w]);
        'band: for band in 0..e.bands {
            for y0 in (0..h).step_by(rows) {
                let n = rows.min(h - y0) * w;
                la.read_rows_f32(band, y0 as u32, &mut va[..n])?;
                lb.read_rows_f32(band, y0 as u32, &mut vb[..n])?;
                let same = |i: usize| {
                    va[i].to_bits() == vb[i].to_bits() || (va[i].is_nan() && vb[i].is_nan())
                };
                if let Some(i) = (0..n).find(|&i| !same(i)) {
                    out.push(format!(
                        "{} band {band}: post ({}, {}) is {} here, {} in the other",
                        e.key(),
                        i % w,
                        y0 + i / w,
                        va[i],
                        vb[i]
                    ));
                    continue 'band;
                }
            }
        }
    }
    Ok(out)
}

/// What a layer's stored values mean: type, bands, grid, the bands'
/// azimuths, quantisation, the horizon's features (not how it is tiled or
/// compressed).
pub(crate) type Meaning<'a> = (
    terrabake_format::ElemType,
    [u32; 3],
    &'a [f64],
    Option<terrabake_format::Quantization>,
    Option<&'a terrabake_format::features::HorizonFeatures>,
);

pub(crate) fn meaning(e: &LayerEntry) -> Meaning<'_> {
    (
        e.elem,
        [e.bands, e.width, e.height],
        &e.band_azimuths,
        e.quantization,
        e.features.as_ref(),
    )
}
