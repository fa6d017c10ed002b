//! Heightmaps for game engines (`terrabake export --layer height --for
//! unreal|unity|godot -o DIR`): the heights in the file type, size, row
//! order and height scale each engine's terrain importer takes, and a JSON
//! sidecar (`heightmap.json`) with the numbers to type into the importer
//! and the georeferencing, so that the heights come back within one
//! quantisation step.
//!
//! | engine | file | posts per side | rows | heights |
//! | --- | --- | --- | --- | --- |
//! | Unreal (landscape) | 16-bit gray PNG | 127, 253, 505, 1009, 2017, 4033 or 8129, padded; past 8129, World Partition tiles of 2017 named `heightmap_x{X}_y{Y}.png` | north first (image order: +X east, +Y south) | `z_cm = location_z + scale_z * (v - 32768) / 128` |
//! | Unity (terrain) | 16-bit RAW, little-endian ("Windows" byte order) | 2^n + 1 (33 to 4097), padded; past 4097, tiles of 4097 named `heightmap_{X}_{Z}.raw` | south first (Unity's row 0 is the terrain's z = 0 edge: "Flip Vertically" off) | `y = position_y + size_y * v / 65535` |
//! | Godot (Terrain3D) | 32-bit float EXR, channel R | the DEM's own | north first | metres, as they are |
//!
//! Sizes are reached by padding, never by resampling: the posts past the
//! DEM's east and south edges repeat the edge post (no cliff at the seam),
//! and the sidecar says where the DEM lies. Tiles share their edge posts,
//! as terrain tiles must to meet without a gap. Nodata, which engines do
//! not have, becomes the DEM's lowest height (said in the sidecar).
//! Quantised heights span the DEM's range in 65535 steps, rounded to the
//! nearest: at most half a step off.

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use serde::Serialize;
use terrabake_format::{Asset, Layer, Mmap};

use crate::error::bail;
use crate::plumbing::output::write_atomically;
use crate::plumbing::progress::Progress;

/// The engines `export --for` writes heightmaps for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Engine {
    Unreal,
    Unity,
    Godot,
}

/// Unreal's recommended landscape sizes (posts per side).
pub const UNREAL_SIZES: [u32; 7] = [127, 253, 505, 1009, 2017, 4033, 8129];
/// Unreal tiles past one landscape: World Partition regions of this many
/// posts per side.
pub const UNREAL_TILE: u32 = 2017;
/// Unity's largest heightmap resolution.
pub const UNITY_MAX: u32 = 4097;
/// Terrain3D takes any size; one EXR holds at most this many posts (the
/// EXR writer holds the image).
const GODOT_MAX_POSTS: u64 = 1 << 28;

impl Engine {
    pub fn name(self) -> &'static str {
        match self {
            Engine::Unreal => "unreal",
            Engine::Unity => "unity",
            Engine::Godot => "godot",
        }
    }

    /// The padded grid and its tiles for a `w x h` DEM: `(side_x, side_y,
    /// tile)`, where `tile` is the posts per side of each file (the whole
    /// grid when it is one file). `max_tile` overrides the engine's limit
    /// (tests use it to reach tiling on small DEMs).
    pub fn layout(self, (w, h): (u32, u32), max_tile: Option<u32>) -> crate::Result<Layout> {
        let fit = |sizes: &[u32], n: u32| sizes.iter().copied().find(|&s| s >= n);
        let tiled = |tile: u32| {
            let per = |n: u32| (n.max(2) - 1).div_ceil(tile - 1);
            let (nx, ny) = (per(w), per(h));
            Layout {
                size: (nx * (tile - 1) + 1, ny * (tile - 1) + 1),
                tile,
                tiles: (nx, ny),
            }
        };
        Ok(match self {
            Engine::Unreal => {
                let largest = max_tile
                    .unwrap_or(UNREAL_SIZES[UNREAL_SIZES.len() - 1])
                    .max(3);
                let sizes: Vec<u32> = UNREAL_SIZES.into_iter().filter(|&s| s <= largest).collect();
                match fit(&sizes, w.max(h)) {
                    Some(side) => Layout::one(side, side),
                    None => tiled(max_tile.unwrap_or(UNREAL_TILE).max(3)),
                }
            }
            Engine::Unity => {
                let largest = max_tile.unwrap_or(UNITY_MAX).max(33);
                let sizes: Vec<u32> = (5..=12)
                    .map(|n| (1u32 << n) + 1)
                    .filter(|&s| s <= largest)
                    .collect();
                match fit(&sizes, w.max(h)) {
                    Some(side) => Layout::one(side, side),
                    None => tiled(*sizes.last().expect("33 at least")),
                }
            }
            Engine::Godot => {
                if u64::from(w) * u64::from(h) > GODOT_MAX_POSTS {
                    bail!("the DEM is {w} x {h} posts; --for godot writes one EXR of at most 2^28 posts (16384 x 16384): export a window of it, or use --for unreal (tiled)");
                }
                Layout::one(w, h)
            }
        })
    }
}

/// Where the files of an engine export lie on the padded grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Layout {
    /// Posts of the padded grid, `(x, y)`.
    pub size: (u32, u32),
    /// Posts per side of one file (tiles share their edge posts); the whole
    /// grid's `x` when there is one file.
    pub tile: u32,
    /// Files along x and y.
    pub tiles: (u32, u32),
}

impl Layout {
    fn one(x: u32, y: u32) -> Self {
        Self {
            size: (x, y),
            tile: x,
            tiles: (1, 1),
        }
    }

    /// The padded grid's posts of file `(i, j)` (`j` from the north): `[x0,
    /// y0, width, height]`.
    fn window(&self, (i, j): (u32, u32)) -> [u32; 4] {
        if self.tiles == (1, 1) {
            return [0, 0, self.size.0, self.size.1];
        }
        let t = self.tile;
        [i * (t - 1), j * (t - 1), t, t]
    }
}

/// The JSON sidecar: how to import the files and get the heights back.
#[derive(Debug, Serialize)]
pub struct Sidecar {
    pub engine: &'static str,
    pub source: String,
    /// The files, with where each lies on the padded grid.
    pub files: Vec<SidecarFile>,
    pub layout: Layout,
    /// The DEM's posts on the padded grid: `[x0, y0, width, height]` (the
    /// rest is padding that repeats the edge posts).
    pub dem_window: [u32; 4],
    /// Metres between posts, east-west and north-south.
    pub cell_size_m: [f64; 2],
    /// Real height = `offset_m + scale_m * value` for 16-bit files (the
    /// stored integer); `scale_m` 1 and `offset_m` 0 for float files.
    pub height: HeightMap,
    /// Which file row is the north edge: `north_first` or `south_first`.
    pub row_order: &'static str,
    /// `little_endian` for raw files; `big_endian` for PNG (its format).
    pub byte_order: &'static str,
    /// What nodata posts hold: the DEM's lowest height, metres.
    pub nodata_filled_with_m: Option<f64>,
    /// Unreal's landscape import: Location and Scale in centimetres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unreal: Option<UnrealImport>,
    /// Unity's terrain import: resolution, byte order and terrain size.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unity: Option<UnityImport>,
    /// Terrain3D's importer.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub godot: Option<GodotImport>,
    /// The asset's georeferencing (CRS and GDAL geotransform of the DEM's
    /// posts), where it has one.
    pub georef: Option<terrabake_format::manifest::Georef>,
}

#[derive(Debug, Serialize)]
pub struct SidecarFile {
    pub file: String,
    /// Index along x (east) and y (`y` counts from the north for Unreal
    /// and Godot, from the south for Unity, as their tile names do).
    pub index: [u32; 2],
    /// The file's posts on the padded grid, `[x0, y0, width, height]` (y from the north).
    pub window: [u32; 4],
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct HeightMap {
    pub offset_m: f64,
    pub scale_m: f64,
    /// Half a step: the most a quantised height is off (0 for floats).
    pub max_error_m: f64,
}

/// Unreal: `z_cm = location_cm[2] + scale_cm[2] * (v - 32768) / 128`; x and
/// y at `location + scale * (column, row)`.
#[derive(Debug, Serialize)]
pub struct UnrealImport {
    pub location_cm: [f64; 3],
    pub scale_cm: [f64; 3],
    pub note: &'static str,
}

/// Unity: `y = position_m[1] + size_m[1] * v / 65535`.
#[derive(Debug, Serialize)]
pub struct UnityImport {
    pub resolution: u32,
    pub depth: u32,
    pub byte_order: &'static str,
    pub flip_vertically: bool,
    /// Terrain Width (x), Height (y) and Length (z), metres, per tile.
    pub size_m: [f64; 3],
    /// Where the terrain (tile 0, 0) stands: x, y (the lowest height), z.
    pub position_m: [f64; 3],
}

/// Terrain3D: EXR heights in metres.
#[derive(Debug, Serialize)]
pub struct GodotImport {
    pub vertex_spacing: f64,
    pub height_offset: f64,
    pub note: &'static str,
}

/// Writes the heights of `asset` into `dir` for `engine` and the sidecar
/// beside them; returns the sidecar.
pub fn export_heightmap(
    asset: &Asset<Mmap>,
    engine: Engine,
    dir: &Path,
    max_tile: Option<u32>,
    progress: Progress,
) -> crate::Result<Sidecar> {
    let height = asset.height()?;
    let m = asset.manifest();
    let (w, h) = (height.width(), height.height());
    let layout = engine.layout((w, h), max_tile)?;
    let (zmin, zmax) = m
        .height_range
        .map(|r| (f64::from(r.min), f64::from(r.max)))
        .ok_or_else(|| anyhow!("{}: the DEM has no valid height", asset.dir().display()))?;
    let float = engine == Engine::Godot;
    // 65535 steps over the range (a flat DEM gets a millimetre's).
    let scale = if float {
        1.0
    } else {
        ((zmax - zmin) / 65535.0).max(1e-3 / 65535.0)
    };
    let offset = if float { 0.0 } else { zmin };
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    let (dx, dy) = (m.cell_size.dx, m.cell_size.dy);
    let rows_total: u64 = (0..layout.tiles.1)
        .flat_map(|j| (0..layout.tiles.0).map(move |i| (i, j)))
        .map(|t| u64::from(layout.window(t)[3]))
        .sum();
    let bar = progress.bar(rows_total, "export", "rows");
    let mut files = Vec::new();
    for j in 0..layout.tiles.1 {
        for i in 0..layout.tiles.0 {
            let window = layout.window((i, j));
            let (name, index) = match (engine, layout.tiles) {
                (Engine::Unreal, (1, 1)) => ("heightmap.png".to_string(), [0, 0]),
                (Engine::Unreal, _) => (format!("heightmap_x{i}_y{j}.png"), [i, j]),
                (Engine::Unity, (1, 1)) => ("heightmap.raw".to_string(), [0, 0]),
                (Engine::Unity, (_, ny)) => {
                    let z = ny - 1 - j;
                    (format!("heightmap_{i}_{z}.raw"), [i, z])
                }
                (Engine::Godot, _) => ("heightmap.exr".to_string(), [0, 0]),
            };
            let heights = padded_window(height, window, zmin as f32)?;
            bar.inc(u64::from(window[3]));
            let path = dir.join(&name);
            let [_, _, fw, fh] = window;
            let code = |z: f32| {
                ((f64::from(z) - offset) / scale)
                    .round()
                    .clamp(0.0, 65535.0) as u16
            };
            match engine {
                Engine::Unreal => write_png16(&path, (fw, fh), heights.iter().map(|&z| code(z)))?,
                Engine::Unity => {
                    // South first: the file's first row is the tile's south edge.
                    let bytes: Vec<u8> = heights
                        .chunks(fw as usize)
                        .rev()
                        .flatten()
                        .flat_map(|&z| code(z).to_le_bytes())
                        .collect();
                    write_atomically(&path, |f| Ok(std::io::Write::write_all(f, &bytes)?))?;
                }
                Engine::Godot => write_exr_r(&path, (fw, fh), heights)?,
            }
            files.push(SidecarFile {
                file: name,
                index,
                window,
            });
        }
    }
    bar.finish_and_clear();
    let tile_span = |n: u32, d: f64| f64::from(n - 1) * d;
    let sidecar = Sidecar {
        engine: engine.name(),
        source: asset.dir().display().to_string(),
        files,
        layout,
        dem_window: [0, 0, w, h],
        cell_size_m: [dx, dy],
        height: HeightMap {
            offset_m: offset,
            scale_m: scale,
            max_error_m: if float { 0.0 } else { scale / 2.0 },
        },
        row_order: if engine == Engine::Unity {
            "south_first"
        } else {
            "north_first"
        },
        byte_order: match engine {
            Engine::Unreal => "big_endian",
            Engine::Unity => "little_endian",
            Engine::Godot => "little_endian",
        },
        nodata_filled_with_m: (m.nodata.count > 0).then_some(zmin),
        unreal: (engine == Engine::Unreal).then(|| {
            // One unit of v is scale_z / 128 cm: scale_z = 12800 * step.
            let scale_z = scale * 100.0 * 128.0;
            UnrealImport {
                location_cm: [0.0, 0.0, zmin * 100.0 + scale_z * 256.0],
                scale_cm: [dx * 100.0, dy * 100.0, scale_z],
                note: "Landscape mode, Import from File: give this Location and Scale; tile files (heightmap_x*_y*.png) import together with World Partition",
            }
        }),
        unity: (engine == Engine::Unity).then(|| UnityImport {
            resolution: layout.tile,
            depth: 16,
            byte_order: "Windows (little-endian)",
            flip_vertically: false,
            size_m: [
                tile_span(layout.tile, dx),
                scale * 65535.0,
                tile_span(layout.tile, dy),
            ],
            position_m: [0.0, zmin, 0.0],
        }),
        godot: (engine == Engine::Godot).then_some(GodotImport {
            vertex_spacing: dx,
            height_offset: 0.0,
            note: "Terrain3D importer: the EXR's R channel is the height in metres; Terrain3D spaces vertices equally, so a DEM with dx != dy is stretched by dy/dx north-south",
        }),
        georef: m.georef.clone(),
    };
    let json = serde_json::to_string_pretty(&sidecar)?;
    write_atomically(&dir.join("heightmap.json"), |f| {
        Ok(std::io::Write::write_all(f, json.as_bytes())?)
    })?;
    Ok(sidecar)
}

/// The heights of `window` of the padded grid, north first: posts past the
/// DEM repeat its edge posts, nodata becomes `fill`. Only the window's own
/// columns of the DEM are read (tiles side by side share no reads).
fn padded_window(height: &Layer<Mmap>, [x0, y0, w, h]: [u32; 4], fill: f32) -> Result<Vec<f32>> {
    let (dw, dh) = (height.width(), height.height());
    // The DEM's columns under the window (the last one when it lies past
    // the east edge).
    let c0 = x0.min(dw - 1);
    let c1 = (x0 + w).min(dw).max(c0 + 1);
    let mut out = Vec::with_capacity(w as usize * h as usize);
    let mut row = vec![0f32; (c1 - c0) as usize];
    for y in y0..y0 + h {
        // Rows past the south edge repeat the last: read it once.
        if y < dh || y == y0 {
            height.read_window_f32(0, [c0, y.min(dh - 1), c1 - c0, 1], &mut row)?;
        }
        out.extend((x0..x0 + w).map(|x| {
            let z = row[(x.clamp(c0, c1 - 1) - c0) as usize];
            if z.is_nan() {
                fill
            } else {
                z
            }
        }));
    }
    Ok(out)
}

fn write_png16(path: &Path, (w, h): (u32, u32), values: impl Iterator<Item = u16>) -> Result<()> {
    // PNG stores 16-bit samples big-endian.
    let bytes: Vec<u8> = values.flat_map(u16::to_be_bytes).collect();
    Ok(write_atomically(path, |file| {
        let mut enc = png::Encoder::new(file, w, h);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let mut writer = enc.write_header()?;
        writer.write_image_data(&bytes)?;
        writer.finish()?;
        Ok(())
    })?)
}

fn write_exr_r(path: &Path, (w, h): (u32, u32), heights: Vec<f32>) -> Result<()> {
    Ok(write_atomically(path, |file| {
        use exr::prelude::*;
        let channel = AnyChannel::new("R", FlatSamples::F32(heights));
        let image = Image::from_channels(
            (w as usize, h as usize),
            AnyChannels::sort(std::iter::once(channel).collect()),
        );
        image
            .write()
            .to_buffered(file)
            .map_err(|e| anyhow!("writing EXR: {e}"))
    })?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_pad_to_the_engines_sizes() {
        let one = |e: Engine, w, h| e.layout((w, h), None).unwrap();
        assert_eq!(one(Engine::Unreal, 1201, 1201).size, (2017, 2017));
        assert_eq!(one(Engine::Unreal, 100, 40).size, (127, 127));
        assert_eq!(one(Engine::Unreal, 1009, 10).size, (1009, 1009));
        assert_eq!(one(Engine::Unity, 1201, 900).size, (2049, 2049));
        assert_eq!(one(Engine::Unity, 33, 2).size, (33, 33));
        assert_eq!(one(Engine::Godot, 1201, 900).size, (1201, 900));
        // Past one landscape: tiles sharing their edge posts.
        let t = one(Engine::Unreal, 9000, 2100);
        assert_eq!((t.tile, t.tiles), (2017, (5, 2)));
        assert_eq!(t.size, (5 * 2016 + 1, 2 * 2016 + 1));
        assert_eq!(t.window((1, 1)), [2016, 2016, 2017, 2017]);
        let u = one(Engine::Unity, 5000, 4097);
        assert_eq!((u.tile, u.tiles), (4097, (2, 1)));
    }
}
