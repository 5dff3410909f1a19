//! How a check splits its items over the threads without changing what it reports: contiguous
//! chunks, and the first failure in item order whatever the thread count.
//!
//! ```text
//!   items:   [ chunk 0 | chunk 1 | chunk 2 ✗ | chunk 3 ✗ | chunk 4 ]
//!   runs:      whole     whole     to its ✗    may stop    may not run
//!   result:  chunk 2's first failure — the one a single thread, walking in order, finds
//! ```

use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

/// How many chunks `n` items get: one on one thread; else one per `min` items, at most
/// `per_thread` per thread.
pub fn chunk_count(n: usize, min: usize, per_thread: usize) -> usize {
    let threads = rayon::current_num_threads();
    if threads <= 1 {
        1
    } else {
        (n / min.max(1)).clamp(1, per_thread.max(1) * threads)
    }
}

/// The CPU time of a parallel section beyond its wall time on the calling thread, in
/// nanoseconds: the chunks' own times summed, less the section's wall time. A stage timed by
/// the wall clock on its thread adds it to count its chunks as CPU time summed over the
/// threads, as the checks' stages count theirs (the wall time a waiting thread spends on
/// another candidate's work, stolen meanwhile, drops out too). 0 where the section ran as one
/// chunk on this thread.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Excess(pub i64);

impl Excess {
    /// Adds `o`.
    pub fn add(&mut self, o: Excess) {
        self.0 += o.0;
    }
    /// `seconds` of wall time on the calling thread, with this excess: CPU seconds.
    pub fn cpu_seconds(self, seconds: f64) -> f64 {
        (seconds + self.0 as f64 * 1e-9).max(0.0)
    }
}

/// Runs `work` as the chunks of a parallel section: each chunk's own time summed, and the
/// section's [`Excess`] over its wall time.
fn timed_section<R>(section: impl FnOnce(&(dyn Fn(std::time::Instant) + Sync)) -> R) -> (R, Excess) {
    let spent = std::sync::atomic::AtomicU64::new(0);
    let t = std::time::Instant::now();
    let r = section(&|since| {
        spent.fetch_add(since.elapsed().as_nanos() as u64, Ordering::Relaxed);
    });
    let wall = t.elapsed().as_nanos() as i64;
    (r, Excess(spent.load(Ordering::Relaxed) as i64 - wall))
}

/// Runs `work(offset, chunk, scratch)` on contiguous chunks of `items` over the threads
/// ([`chunk_count`] of them, `offset` the chunk's first index) and concatenates what they
/// return, in item order, so the result is the one a single walk gives. With one chunk it is
/// one call on this thread with `scratch`; otherwise each chunk has a fresh `S::default()`.
/// Also returns the section's [`Excess`] CPU time.
pub fn flat_map_chunks<T: Sync, R: Send, S: Default>(
    items: &[T],
    min: usize,
    per_thread: usize,
    scratch: &mut S,
    work: impl Fn(usize, &[T], &mut S) -> Vec<R> + Sync,
) -> (Vec<R>, Excess) {
    let chunks = chunk_count(items.len(), min, per_thread);
    if chunks <= 1 {
        return (work(0, items, scratch), Excess::default());
    }
    let size = items.len().div_ceil(chunks);
    timed_section(|done| {
        items
            .par_chunks(size)
            .enumerate()
            .flat_map_iter(|(k, chunk)| {
                let t = std::time::Instant::now();
                let r = work(k * size, chunk, &mut S::default());
                done(t);
                r
            })
            .collect()
    })
}

/// Runs `work(chunk, stop)` on `chunks` contiguous chunks of `items` over the threads and
/// returns the results of the chunks that ran, in item order. Every chunk before the first
/// failing one runs whole; a chunk after it may stop early (`stop()` turns true) or not run at
/// all (then it is left out), since its result is not needed. So the first `Err` returned is
/// the first failure of a walk in item order. With `chunks` ≤ 1 it is one call on this thread.
pub fn run_to_first_failure<T: Sync, R: Send, E: Send>(
    items: &[T],
    chunks: usize,
    work: impl Fn(&[T], &dyn Fn() -> bool) -> Result<R, E> + Sync,
) -> Vec<Result<R, E>> {
    run_to_first_failure_timed(items, chunks, work).0
}

/// [`run_to_first_failure`], with the section's [`Excess`] CPU time.
pub fn run_to_first_failure_timed<T: Sync, R: Send, E: Send>(
    items: &[T],
    chunks: usize,
    work: impl Fn(&[T], &dyn Fn() -> bool) -> Result<R, E> + Sync,
) -> (Vec<Result<R, E>>, Excess) {
    if chunks <= 1 || items.len() < 2 {
        return (vec![work(items, &|| false)], Excess::default());
    }
    let failed = AtomicUsize::new(usize::MAX);
    let size = items.len().div_ceil(chunks);
    let (parts, excess) = timed_section(|done| {
        items
            .par_chunks(size)
            .enumerate()
            .map(|(ci, chunk)| {
                let stop = || failed.load(Ordering::Relaxed) < ci;
                if stop() {
                    return None;
                }
                let t = std::time::Instant::now();
                let r = work(chunk, &stop);
                done(t);
                if r.is_err() {
                    failed.fetch_min(ci, Ordering::Relaxed);
                }
                Some(r)
            })
            .collect::<Vec<Option<Result<R, E>>>>()
    });
    (parts.into_iter().flatten().collect(), excess)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_map_in_item_order_with_their_offsets() {
        // Each item paired with its index from the chunk's offset, the odd ones kept: the
        // same list a single walk gives, on any thread count.
        let items: Vec<u32> = (0..1000).map(|i| i * 3).collect();
        let want: Vec<(usize, u32)> = items.iter().copied().enumerate().filter(|e| e.1 % 2 == 1).collect();
        for threads in [1, 2, 5] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let (got, _) = pool.install(|| {
                flat_map_chunks(&items, 16, 4, &mut (), |offset, chunk, _| chunk.iter().enumerate().map(|(k, &x)| (offset + k, x)).filter(|e| e.1 % 2 == 1).collect())
            });
            assert_eq!(got, want, "{threads} threads");
        }
    }

    #[test]
    fn a_parallel_section_counts_its_chunks_at_their_own_times() {
        // Eight chunks that each take at least 20 ms: on two threads the section's wall time
        // is about half their sum, and wall + excess is the sum (never less, whatever else the
        // machine runs: a chunk cannot take less than its sleep); on one thread the section is
        // one call on this thread, its wall time its CPU time, no excess.
        let items: Vec<u32> = (0..8).collect();
        let nap = std::time::Duration::from_millis(20);
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let t = std::time::Instant::now();
            let (got, excess) = pool.install(|| {
                flat_map_chunks(&items, 1, 4, &mut (), |_, chunk, _| {
                    std::thread::sleep(nap * chunk.len() as u32);
                    chunk.to_vec()
                })
            });
            let wall = t.elapsed().as_secs_f64();
            assert_eq!(got, items);
            if threads == 1 {
                assert_eq!(excess, Excess::default());
            } else {
                let summed = excess.cpu_seconds(wall);
                assert!(summed >= 0.16 - 1e-3, "{threads} threads: the chunks' 160 ms counted as {summed:.3} s (wall {wall:.3} s)");
                assert!(excess.0 > 0, "two threads ran the chunks at once: {excess:?}");
            }
        }
    }

    #[test]
    fn the_first_failure_is_the_one_in_item_order() {
        // Items fail where they are multiples of 7 from 300 on; every thread count and chunk
        // count must report 301 (the first such item), and pass the items before it whole.
        let items: Vec<u32> = (0..1000).collect();
        for threads in [1, 2, 5] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            for chunks in [1, 2, 7, 64] {
                let parts = pool.install(|| {
                    run_to_first_failure(&items, chunks, |chunk, stop| {
                        let mut seen = 0;
                        for &x in chunk {
                            if stop() {
                                break;
                            }
                            if x >= 300 && x % 7 == 0 {
                                return Err(x);
                            }
                            seen += 1;
                        }
                        Ok(seen)
                    })
                });
                let first = parts.iter().position(|r| r.is_err()).expect("a failure");
                assert_eq!(parts[first], Err(301), "{threads} threads, {chunks} chunks");
                let before: u32 = parts[..first].iter().map(|r| *r.as_ref().unwrap()).sum();
                let size = 1000usize.div_ceil(chunks.max(1)) as u32;
                assert_eq!(before, if chunks <= 1 { 0 } else { 301 / size * size }, "the chunks before run whole");
            }
        }
    }
}
