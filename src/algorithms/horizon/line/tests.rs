use super::*;

#[test]
fn fast_arctangent_is_within_two_tenths_of_a_microradian() {
    let mut worst = 0f64;
    for i in -200_000..=200_000 {
        let x = (i as f64 / 10_000.0).powi(3);
        let got = f64::from(atan_deg(x)).to_radians();
        worst = worst.max((got - x.atan()).abs());
    }
    assert!(worst < 2e-7, "{worst}");
    assert_eq!(atan_deg(0.0), 0.0);
    assert_eq!(atan_deg(f64::INFINITY), 90.0);
}

#[test]
fn stencil_of_axis_and_diagonal_steps() {
    // East: no crossing, the next post only.
    assert_eq!(Stencil::new((1, 0)).len(), 1);
    // North-east (col + 1, row - 1) runs along the diagonals.
    assert_eq!(Stencil::new((1, -1)).len(), 1);
    // South-east crosses one diagonal, in the middle of the cell.
    let se = Stencil::new((1, 1));
    assert_eq!(se.len(), 2);
    assert_eq!(se.vertices[0].s, 0.5);
    // (2, 1): a vertical line at s = 1/2, diagonals at 1/3 and 2/3.
    assert_eq!(Stencil::new((2, 1)).len(), 4);
}

#[test]
fn directions_are_near_their_nominal_azimuth() {
    for count in [4, 7, 16, 64, 256] {
        let tol = default_tolerance(count);
        let dirs = grid_directions(count, 30.0, 30.0, tol);
        for d in &dirs {
            assert!(angle_between(d.azimuth, d.nominal) <= tol, "{d:?}");
        }
        for w in dirs.windows(2) {
            assert!(w[0].azimuth < w[1].azimuth);
        }
    }
    let north = grid_direction(0.0, 30.0, 30.0, 1.0);
    assert_eq!(north.step, (0, -1));
    let east = grid_direction(90.0, 20.0, 30.0, 1.0);
    assert_eq!(east.step, (1, 0));
}

/// The sorted table picks the step a scan of every step picks (the
/// fewest posts within the tolerance, then the closest, then the first
/// in `a`, `b` order; the closest of all where none is within), at
/// azimuths on and off the axes and the wrap (and outside 0..360), on
/// square and oblong cells, from no tolerance to a wide one.
#[test]
fn the_step_table_picks_what_a_scan_of_every_step_picks() {
    let scan = |nominal: f64, dx: f64, dy: f64, tolerance: f64| {
        let mut within: Option<(i64, f64, (i64, i64))> = None;
        let mut closest: Option<(f64, (i64, i64))> = None;
        for a in -MAX_STEP..=MAX_STEP {
            for b in -MAX_STEP..=MAX_STEP {
                if gcd(a.abs(), b.abs()) != 1 {
                    continue;
                }
                let err = angle_between(step_azimuth((a, b), dx, dy), nominal);
                let len = a.abs().max(b.abs());
                if err <= tolerance && within.is_none_or(|(l, e, _)| (len, err) < (l, e)) {
                    within = Some((len, err, (a, b)));
                }
                if closest.is_none_or(|(e, _)| err < e) {
                    closest = Some((err, (a, b)));
                }
            }
        }
        within
            .map(|(_, _, s)| s)
            .or(closest.map(|(_, s)| s))
            .unwrap()
    };
    for (dx, dy) in [(30.0, 30.0), (20.0, 30.0), (92.6, 61.3)] {
        let steps = Steps::new(dx, dy);
        for tolerance in [0.0, 0.01, 0.1, 1.0, 2.8125, 11.25] {
            let nominals = (0..97)
                .map(|i| i as f64 * 360.0 / 97.0)
                .chain([0.0, 45.0, 90.0, 180.0, 359.99, 0.004, 359.0, -30.0, 400.0]);
            for nominal in nominals {
                let got = steps.direction(nominal, tolerance);
                assert_eq!(
                    got.step,
                    scan(nominal, dx, dy, tolerance),
                    "{nominal} within {tolerance} on {dx} x {dy}"
                );
                assert_eq!(got.azimuth, step_azimuth(got.step, dx, dy));
            }
        }
    }
}

/// What a planner adds up for the sweeps in flight is what a sweep
/// allocates: the same lanes or none, their arrays to the byte, for steps
/// short and long, narrow and wide DEMs, and budgets that make the lanes
/// shallower or leave them out.
#[test]
fn most_carried_bytes_are_what_the_lanes_allocate() {
    let steps = [
        (1, 0),
        (-1, 0),
        (0, 1),
        (1, -1),
        (3, 2),
        (-7, 5),
        (1, 17),
        (40, -33),
    ];
    for &step in &steps {
        for width in [7, 300, 5000] {
            for bytes in [0, 64 << 10, 1 << 20, 4 << 20, 1 << 30] {
                let dir = GridDirection {
                    step,
                    azimuth: 0.0,
                    nominal: 0.0,
                };
                let sweep =
                    BandedSweep::new(&dir, (width, 64), (30.0, 30.0), RowScale::default(), false)
                        .with_lane_memory(bytes);
                let stated = BandedSweep::most_carried_bytes(&dir, width, false, bytes);
                match &sweep.simd {
                    Some(lanes) => {
                        assert_eq!(stated, lanes.held_bytes(), "{step:?} {width} {bytes}")
                    }
                    None => {
                        // The scalar sweep's lines, carried unless east-west.
                        let lines = step.1.unsigned_abs() as usize
                            * (width + step.0.unsigned_abs() as usize);
                        assert_eq!(stated == 0, lines == 0, "{step:?} {width} {bytes}");
                    }
                }
            }
        }
    }
    // A DEM with nodata posts takes the scalar sweep: its lines' state.
    let dir = GridDirection {
        step: (3, 2),
        azimuth: 0.0,
        nominal: 0.0,
    };
    assert_eq!(
        BandedSweep::most_carried_bytes(&dir, 100, true, 1 << 30),
        2 * 103 * (std::mem::size_of::<Lane>() + 2 * TRIM_FROM * 16)
    );
}
