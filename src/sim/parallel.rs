//! Splitting per-vehicle work over a few threads with `std::thread::scope`.
//!
//! The heavy per-vehicle systems (sensors, path following, dynamics) compute each vehicle's
//! outputs from read-only shared data and that vehicle's own components only, so cutting the
//! vehicles into contiguous chunks and running the chunks on different threads gives the same
//! bits for any thread count. Small worlds stay on the calling thread: spawning threads costs
//! more than it saves there. This is not bevy's multi-threaded executor (see DESIGN.md): the
//! schedules still run one system at a time.

use bevy_ecs::prelude::Resource;

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

    /// Threads to use for `items` vehicles.
    fn threads_for(&self, items: usize) -> usize {
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
        let size = items.len().div_ceil(threads);
        std::thread::scope(|scope| {
            let mut chunks = items.chunks_mut(size).zip(scratch.iter_mut());
            let first = chunks.next();
            let f = &f;
            for (chunk, s) in chunks {
                scope.spawn(move || f(chunk, s));
            }
            if let Some((chunk, s)) = first {
                f(chunk, s);
            }
        });
    }
}
