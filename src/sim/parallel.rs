//! Splitting per-vehicle work over a few threads of a persistent rayon pool.
//!
//! The heavy per-vehicle systems (sensors, path following, dynamics) compute each vehicle's
//! outputs from read-only shared data and that vehicle's own components only, so cutting the
//! vehicles into contiguous chunks and running the chunks on different threads gives the same
//! bits for any thread count. The pool's threads are started once per thread count and kept
//! for the life of the process (no thread is spawned per tick); small worlds stay on the calling
//! thread, where handing work to the pool costs more than it saves. This is not bevy's
//! multi-threaded executor (see DESIGN.md): the schedules still run one system at a time.
//!
//! The systems gather their query items into a vector each tick; [`recycle`] keeps that
//! vector's allocation between ticks, so the steady state allocates nothing.

use std::collections::BTreeMap;
use std::sync::{Mutex, OnceLock};

use bevy_ecs::prelude::Resource;

/// The persistent pool with `threads` threads (started on first use, then shared), or `None`
/// when the system refuses to start threads (the work then runs on the calling thread).
fn pool(threads: usize) -> Option<&'static rayon::ThreadPool> {
    static POOLS: OnceLock<Mutex<BTreeMap<usize, Option<&'static rayon::ThreadPool>>>> = OnceLock::new();
    let mut pools = POOLS.get_or_init(|| Mutex::new(BTreeMap::new())).lock().unwrap_or_else(|e| e.into_inner());
    *pools.entry(threads).or_insert_with(|| {
        match rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("smlworld-worker-{i}"))
            .build()
        {
            Ok(p) => Some(&*Box::leak(Box::new(p))),
            Err(e) => {
                tracing::warn!("cannot start {threads} worker threads ({e}); running on one thread");
                None
            }
        }
    })
}

/// Empty `v` and reuse its allocation for a vector of another item type of the same layout:
/// a system keeps `Local<Vec<Item<'static>>>` between ticks and turns it into this tick's
/// `Vec<Item<'w>>` and back, so gathering query items allocates only while the world grows.
/// (It relies on the standard library collecting `Vec::into_iter().map(..)` in place.)
/// Hint to the processor that the memory at `p` will be read soon (no effect off x86-64): the
/// per-vehicle loops ask for what a vehicle a few places on will read (its centre line, its
/// detections), so those loads, far apart in memory on a big world, overlap this vehicle's work.
#[inline]
pub fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is only a hint; it never faults, whatever the address.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(p.cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

pub fn recycle<T, U>(mut v: Vec<T>) -> Vec<U> {
    v.clear();
    v.into_iter().map(|_| -> U { unreachable!("the vector was emptied") }).collect()
}

/// How many threads the per-vehicle systems may use.
#[derive(Resource, Debug, Clone, Copy, PartialEq, Eq)]
pub struct Parallelism {
    /// Most threads one system uses (1 = everything on the calling thread).
    pub threads: usize,
    /// Fewest vehicles a system needs before it uses more than one thread; below this the
    /// thread start-up costs more than the work it shares.
    pub min_vehicles: usize,
}

impl Default for Parallelism {
    /// The machine's available parallelism capped at 4, from 2,000 vehicles on.
    fn default() -> Self {
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(4);
        Parallelism { threads, min_vehicles: 2000 }
    }
}

impl Parallelism {
    /// Everything on the calling thread.
    pub fn single() -> Parallelism {
        Parallelism { threads: 1, min_vehicles: usize::MAX }
    }

    /// At most `threads` threads, split at any vehicle count when above 1 (so that a small
    /// scenario can check that the results do not depend on the thread count).
    pub fn split(threads: usize) -> Parallelism {
        if threads > 1 { Parallelism { threads, min_vehicles: 0 } } else { Parallelism::single() }
    }

    /// Threads to use for `items` vehicles.
    pub fn threads_for(&self, items: usize) -> usize {
        if items < self.min_vehicles.max(2) { 1 } else { self.threads.clamp(1, items) }
    }

    /// Call `f(chunk, scratch)` on contiguous chunks of `items`, one chunk per thread, each
    /// with its own scratch value from `scratch` (grown to the thread count and kept by the
    /// caller between ticks). `f` must write only through its chunk and its scratch.
    pub fn for_each_chunk<T: Send, S: Send + Default>(
        &self,
        items: &mut [T],
        scratch: &mut Vec<S>,
        f: impl Fn(&mut [T], &mut S) + Sync,
    ) {
        let threads = self.threads_for(items.len());
        if scratch.len() < threads {
            scratch.resize_with(threads, S::default);
        }
        if threads <= 1 {
            f(items, &mut scratch[0]);
            return;
        }
        // The calling thread works the first chunk itself; the pool's threads - 1 workers take
        // the others.
        let Some(pool) = pool(threads - 1) else {
            f(items, &mut scratch[0]);
            return;
        };
        let size = items.len().div_ceil(threads);
        pool.in_place_scope(|scope| {
            let f = &f;
            let mut chunks = items.chunks_mut(size).zip(scratch.iter_mut());
            let first = chunks.next();
            for (chunk, s) in chunks {
                scope.spawn(move |_| f(chunk, s));
            }
            if let Some((chunk, s)) = first {
                f(chunk, s);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recycle_keeps_the_allocation() {
        let mut v: Vec<&u64> = Vec::with_capacity(1000);
        let x = 7;
        v.extend(std::iter::repeat_n(&x, 500));
        let ptr = v.as_ptr() as usize;
        let w: Vec<&i64> = recycle(v);
        assert!(w.is_empty());
        assert_eq!(w.capacity(), 1000);
        assert_eq!(w.as_ptr() as usize, ptr, "same allocation");
    }

    #[test]
    fn chunks_cover_every_item_once_on_any_thread_count() {
        for threads in [1, 2, 3, 4] {
            let p = Parallelism { threads, min_vehicles: 1 };
            let mut items: Vec<u32> = (0..1001).collect();
            let mut scratch: Vec<u64> = Vec::new();
            p.for_each_chunk(&mut items, &mut scratch, |chunk, s| {
                for x in chunk.iter_mut() {
                    *x += 1;
                    *s += 1;
                }
            });
            assert_eq!(items, (1..1002).collect::<Vec<u32>>(), "{threads} threads");
            assert_eq!(scratch.iter().sum::<u64>(), 1001);
        }
    }
}
