//! The surface model's ray-cell test against an independent evaluation of
//! the two triangles (barycentric interpolation of their vertices, sampled
//! densely along the ray): the hit is on the surface, and no earlier point
//! of the ray is below it.

use proptest::prelude::*;
use terrabake_format::surface::{intersect_cell, Cell, GridRay};

/// Height of the cell at (east, north) by barycentric interpolation of the
/// triangle's three posts: written from the definition, not from `Cell`.
fn reference_height(c: &Cell, e: f64, n: f64) -> f64 {
    let [nw, ne, sw, se] = [c.nw, c.ne, c.sw, c.se].map(f64::from);
    // Vertices (east, north, z).
    let tri = if e >= n {
        [(0.0, 0.0, sw), (1.0, 0.0, se), (1.0, 1.0, ne)]
    } else {
        [(0.0, 0.0, sw), (1.0, 1.0, ne), (0.0, 1.0, nw)]
    };
    let [(x1, y1, z1), (x2, y2, z2), (x3, y3, z3)] = tri;
    let det = (y2 - y3) * (x1 - x3) + (x3 - x2) * (y1 - y3);
    let l1 = ((y2 - y3) * (e - x3) + (x3 - x2) * (n - y3)) / det;
    let l2 = ((y3 - y1) * (e - x3) + (x1 - x3) * (n - y3)) / det;
    l1 * z1 + l2 * z2 + (1.0 - l1 - l2) * z3
}

fn corners() -> impl Strategy<Value = Cell> {
    (-50f32..50.0, -50f32..50.0, -50f32..50.0, -50f32..50.0).prop_map(|(nw, ne, sw, se)| Cell {
        nw,
        ne,
        sw,
        se,
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]
    #[test]
    fn first_hit_is_on_the_surface_and_nothing_earlier_is_below(
        cell in corners(),
        start in (0.0f64..1.0, 0.0f64..1.0, -60.0f64..80.0),
        end in (0.0f64..1.0, 0.0f64..1.0, -60.0f64..80.0),
    ) {
        // Cell (3, 5): u in [3, 4], v (southwards) in [5, 6]; north = 6 - v.
        let (c, r) = (3u32, 5u32);
        let p0 = [3.0 + start.0, 6.0 - start.1, start.2];
        let p1 = [3.0 + end.0, 6.0 - end.1, end.2];
        let ray = GridRay { origin: p0, dir: [p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]] };
        let surface = |t: f64| {
            let p = ray.at(t);
            reference_height(&cell, p[0] - 3.0, 6.0 - p[1])
        };
        let tol = 1e-6 * 100.0;
        let hit = intersect_cell(&cell, c, r, &ray, 0.0, 1.0);
        let end_t = hit.unwrap_or(1.0);
        for i in 0..200 {
            let t = end_t * f64::from(i) / 200.0;
            if hit.is_some() && t >= end_t { break; }
            prop_assert!(ray.z(t) > surface(t) - tol, "ray below the surface at t = {t} before the hit {hit:?}");
        }
        if let Some(t) = hit {
            prop_assert!((0.0..=1.0).contains(&t));
            let gap = ray.z(t) - surface(t);
            prop_assert!(gap <= tol, "hit at {t} is {gap} above the surface");
            prop_assert!(t == 0.0 || gap >= -tol, "hit at {t} is {gap} below the surface");
        } else {
            prop_assert!(ray.z(1.0) > surface(1.0) - tol);
        }
    }
}

#[test]
fn cells_with_nodata_have_no_surface() {
    let cell = Cell {
        nw: 1.0,
        ne: f32::NAN,
        sw: 0.0,
        se: 0.0,
    };
    assert!(!cell.exists());
    assert_eq!(cell.max(), f32::NEG_INFINITY);
    assert_eq!(cell.min(), f32::INFINITY);
    let ray = GridRay {
        origin: [0.5, 0.5, -100.0],
        dir: [0.0, 0.0, 1.0],
    };
    assert_eq!(intersect_cell(&cell, 0, 0, &ray, 0.0, 1000.0), None);
}

#[test]
fn the_diagonal_runs_south_west_to_north_east() {
    // NE and SW high, NW and SE low: the SW-NE diagonal is a ridge.
    let cell = Cell {
        nw: 0.0,
        ne: 10.0,
        sw: 10.0,
        se: 0.0,
    };
    assert_eq!(cell.height(0.5, 0.5), 10.0);
    assert_eq!(cell.height(1.0, 0.0), 0.0);
    assert_eq!(cell.height(0.75, 0.25), 5.0);
}
