//! Parallel steps whose results are written in a fixed order.
//!
//! A stage that computes several independent jobs step by step (the
//! horizons stage's bands, each swept tile row by tile row) and appends
//! every step's tiles to one layer file must append them in an order that
//! does not depend on which thread finished first, or two runs give two
//! different files. [`steps_in_order`] runs the jobs on a few workers
//! without a barrier between steps: a free worker always takes the job
//! that is furthest behind, results that finish early wait in a small
//! buffer, and they are written step-major, job-minor: `(0, 0), (0, 1), ...,
//! (1, 0), ...`. No job runs more than [`LEAD`] steps ahead of the writing,
//! which bounds the buffer at about `jobs x (LEAD + 1)` results.

use std::collections::BTreeMap;
use std::sync::{Condvar, Mutex};

use anyhow::Result;

/// How many steps a job may run ahead of the step being written.
pub const LEAD: usize = 1;

struct State<S, R, W> {
    /// Each job, or `None` while a worker computes its next step.
    jobs: Vec<Option<S>>,
    /// Each job's next step.
    next: Vec<usize>,
    /// Finished steps not yet written, by `(step, job)`.
    pending: BTreeMap<(usize, usize), R>,
    /// The next `(step, job)` to write.
    cursor: (usize, usize),
    write: W,
    failed: Option<anyhow::Error>,
}

/// Runs `steps` steps of every job (`step(&mut job, k)`) on `threads`
/// workers and calls `write(job, k, result)` in step-major, job-minor
/// order. The first error stops all workers and is returned.
pub(crate) fn steps_in_order<S, R, W>(
    jobs: Vec<S>,
    steps: usize,
    threads: usize,
    step: impl Fn(&mut S, usize) -> Result<R> + Sync,
    write: W,
) -> Result<()>
where
    S: Send,
    R: Send,
    W: FnMut(usize, usize, R) -> Result<()> + Send,
{
    let n = jobs.len();
    if n == 0 || steps == 0 {
        return Ok(());
    }
    let state = Mutex::new(State {
        jobs: jobs.into_iter().map(Some).collect(),
        next: vec![0; n],
        pending: BTreeMap::new(),
        cursor: (0, 0),
        write,
        failed: None,
    });
    let wake = Condvar::new();
    let worker = || {
        let mut st = state.lock().expect("no panic under the lock");
        loop {
            if st.failed.is_some() || st.cursor.0 == steps {
                return;
            }
            let limit = st.cursor.0 + LEAD;
            let pick = (0..n)
                .filter(|&j| st.jobs[j].is_some() && st.next[j] < steps && st.next[j] <= limit)
                .min_by_key(|&j| (st.next[j], j));
            let Some(j) = pick else {
                st = wake.wait(st).expect("no panic under the lock");
                continue;
            };
            let (mut job, k) = (st.jobs[j].take().expect("picked"), st.next[j]);
            drop(st);
            let result = step(&mut job, k);
            st = state.lock().expect("no panic under the lock");
            st.jobs[j] = Some(job);
            st.next[j] += 1;
            match result {
                Err(e) => {
                    st.failed.get_or_insert(e);
                }
                Ok(r) => {
                    st.pending.insert((k, j), r);
                    let st = &mut *st;
                    while let Some(r) = st.pending.remove(&st.cursor) {
                        let (k, j) = st.cursor;
                        if let Err(e) = (st.write)(j, k, r) {
                            st.failed.get_or_insert(e);
                            break;
                        }
                        st.cursor = if j + 1 == n { (k + 1, 0) } else { (k, j + 1) };
                    }
                }
            }
            wake.notify_all();
        }
    };
    std::thread::scope(|s| {
        for _ in 0..threads.clamp(1, n) {
            s.spawn(worker);
        }
    });
    let st = state.into_inner().expect("no panic under the lock");
    match st.failed {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_are_written_step_major_whatever_the_timing() {
        for threads in [1, 2, 3, 8] {
            let mut order = Vec::new();
            steps_in_order(
                (0..5usize).collect(),
                7,
                threads,
                |&mut j, k| {
                    // Uneven work, so finishing order varies.
                    std::thread::sleep(std::time::Duration::from_micros(
                        ((j * 7 + k * 3) % 5) as u64 * 200,
                    ));
                    Ok(j * 100 + k)
                },
                |j, k, r| {
                    assert_eq!(r, j * 100 + k);
                    order.push((k, j));
                    Ok(())
                },
            )
            .unwrap();
            let want: Vec<(usize, usize)> =
                (0..7).flat_map(|k| (0..5).map(move |j| (k, j))).collect();
            assert_eq!(order, want, "{threads} threads");
        }
    }

    #[test]
    fn the_first_error_stops_the_work() {
        let mut written = 0;
        let err = steps_in_order(
            vec![(); 3],
            100,
            2,
            |_, k| {
                if k == 4 {
                    anyhow::bail!("step {k} failed")
                } else {
                    Ok(k)
                }
            },
            |_, _, _| {
                written += 1;
                Ok(())
            },
        )
        .unwrap_err();
        assert!(err.to_string().contains("failed"));
        assert!(written <= 3 * 5);
    }
}
