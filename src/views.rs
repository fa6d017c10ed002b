//! The sixteen built-in views of an asset and their primary rays: the
//! workload of Paglieroni and Petersen's Table 1 that `terrabake render
//! --view`, the tracing benchmark, the planner's tracing pilot and `check`
//! share, so that a steps or rays figure means the same rays everywhere.
//! Only tracing here; [`render`](crate::present::render) shades the hits.

use rayon::prelude::*;
use serde::Serialize;
use terrabake_format::trace::{Counters, Method, Ray, Tracer};
use terrabake_format::{Asset, Mmap};

/// A pinhole camera: horizontal field of view, up is +z.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Camera {
    pub eye: [f64; 3],
    pub look_at: [f64; 3],
    /// Horizontal field of view, degrees.
    pub fov: f64,
}

pub(crate) fn normalize(v: [f64; 3]) -> [f64; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / l, v[1] / l, v[2] / l]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

impl Camera {
    /// The camera's basis for a `w x h` image, computed once per image.
    pub(crate) fn projector(&self, w: u32, h: u32) -> Projector {
        let forward = normalize([
            self.look_at[0] - self.eye[0],
            self.look_at[1] - self.eye[1],
            self.look_at[2] - self.eye[2],
        ]);
        // Looking straight up or down: any horizontal right vector will do.
        let right = if forward[0].abs() < 1e-12 && forward[1].abs() < 1e-12 {
            [1.0, 0.0, 0.0]
        } else {
            normalize(cross(forward, [0.0, 0.0, 1.0]))
        };
        let up = cross(right, forward);
        let half = (self.fov.to_radians() / 2.0).tan();
        let aspect = f64::from(h) / f64::from(w);
        Projector {
            eye: self.eye,
            forward,
            right: right.map(|c| c * half),
            up: up.map(|c| c * half * aspect),
            size: (f64::from(w), f64::from(h)),
        }
    }
}

/// Primary rays of one camera and image size.
#[derive(Debug, Clone, Copy)]
pub struct Projector {
    eye: [f64; 3],
    forward: [f64; 3],
    /// Right and up, scaled to the half-width and half-height of the image plane.
    right: [f64; 3],
    up: [f64; 3],
    size: (f64, f64),
}

impl Projector {
    /// The primary ray through the centre of pixel `(px, py)`.
    pub fn ray(&self, px: f64, py: f64) -> Ray {
        let (sx, sy) = (
            2.0 * (px + 0.5) / self.size.0 - 1.0,
            1.0 - 2.0 * (py + 0.5) / self.size.1,
        );
        let dir = [0, 1, 2].map(|i| self.forward[i] + sx * self.right[i] + sy * self.up[i]);
        Ray {
            origin: self.eye,
            dir,
            t_min: 0.0,
            t_max: f64::INFINITY,
        }
    }
}

/// The sixteen built-in oblique views of an asset (`--view 1..=16`), after
/// Paglieroni and Petersen's Table 1: cameras inside the bounding box, at
/// heights from just above the terrain's top to well above it, looking in
/// sixteen azimuths with tilts from slightly up to steeply down, 104 degree
/// field of view (their 50 mm lens on a 128 mm focal plane).
pub fn builtin_views(tracer: &Tracer<'_, Mmap>, asset: &Asset<Mmap>) -> Vec<Camera> {
    let (xm, ym) = tracer.extent();
    let r = asset
        .manifest()
        .height_range
        .map_or((0.0, 1.0), |r| (f64::from(r.min), f64::from(r.max)));
    let relief = (r.1 - r.0).max(1.0);
    (0..16)
        .map(|k| {
            let k = f64::from(k);
            let az = (k * 22.5 + 10.0).to_radians();
            // Cameras on a ring inside the box, looking across it.
            let (ex, ey) = (
                0.5 * xm - 0.3 * xm * az.sin(),
                0.5 * ym - 0.3 * ym * az.cos(),
            );
            let ez = r.1 + relief * (0.05 + 0.5 * ((k * 7.0) % 16.0) / 16.0);
            // Depression below the horizontal: -5 (slightly up) to 33 degrees.
            let depression = (-5.0 + 38.0 * ((k * 5.0) % 16.0) / 15.0).to_radians();
            let d = 0.5 * xm.max(ym);
            Camera {
                eye: [ex, ey, ez],
                look_at: [
                    ex + d * az.sin(),
                    ey + d * az.cos(),
                    ez - d * depression.tan(),
                ],
                fov: 104.0,
            }
        })
        .collect()
}

/// What tracing the primary rays of the built-in views cost, one pass.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct ViewsCost {
    pub rays: u64,
    pub hits: u64,
    /// Wall seconds over every view, on the threads of the current pool.
    pub seconds: f64,
    /// Means over the rays.
    pub mean_steps: f64,
    pub mean_cells: f64,
    pub mean_nodes_pushed: f64,
}

/// Traces the primary rays of the built-in views (`size x size`, every
/// `every`-th pixel in x and y) with `method`, once, rows in parallel on
/// the current pool. Hits are not shaded: the cost is the tracer's.
pub fn views_cost(
    asset: &Asset<Mmap>,
    tracer: &Tracer<'_, Mmap>,
    method: Method,
    (size, every): (u32, u32),
) -> terrabake_format::Result<ViewsCost> {
    let every = every.max(1) as usize;
    let views = builtin_views(tracer, asset);
    let start = std::time::Instant::now();
    let rows: Vec<(u64, u64, Counters)> = views
        .iter()
        .flat_map(|camera| {
            let projector = camera.projector(size, size);
            (0..size).step_by(every).map(move |py| (projector, py))
        })
        .collect::<Vec<_>>()
        .par_iter()
        .map(|&(projector, py)| {
            let (mut rays, mut hits, mut counters) = (0, 0, Counters::default());
            for px in (0..size).step_by(every) {
                let (hit, c) =
                    tracer.trace(&projector.ray(f64::from(px), f64::from(py)), method)?;
                rays += 1;
                hits += u64::from(hit.is_some());
                counters += c;
            }
            Ok((rays, hits, counters))
        })
        .collect::<terrabake_format::Result<_>>()?;
    let mut cost = ViewsCost {
        seconds: start.elapsed().as_secs_f64(),
        ..Default::default()
    };
    let mut totals = Counters::default();
    for (rays, hits, counters) in rows {
        cost.rays += rays;
        cost.hits += hits;
        totals += counters;
    }
    let n = cost.rays.max(1) as f64;
    cost.mean_steps = totals.steps as f64 / n;
    cost.mean_cells = totals.cells as f64 / n;
    cost.mean_nodes_pushed = totals.nodes_pushed as f64 / n;
    Ok(cost)
}
