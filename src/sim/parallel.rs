//! Splitting per-vehicle work over a few persistent threads.
//!
//! The heavy per-vehicle systems (sensors, path following, dynamics, the lane systems) compute
//! each vehicle's outputs from read-only shared data and that vehicle's own components only, so
//! cutting the vehicles into contiguous chunks and running the chunks on different threads gives
//! the same bits for any thread count. The helper threads are started once per thread count and
//! kept for the life of the process (no thread is spawned per tick); small worlds stay on the
//! calling thread, where handing work over costs more than it saves. This is not bevy's
//! multi-threaded executor (see DESIGN.md): the schedules still run one system at a time.
//!
//! A tick runs a dozen such sections a few tens of microseconds apart (the serial gathering of
//! the next system in between). A rayon pool's idle workers sleep almost at once, and waking a
//! sleeping thread costs 50-90 µs on the virtual machines we run on (measured: a section with a
//! 33 µs serial gap before it took 55 µs longer than its work), so a 10,000-vehicle tick lost a
//! section's worth of time to every hand-over. The [`Team`] here keeps its helpers spinning for
//! `SPIN` after each section (a tick's sections reach them within a microsecond), then parks
//! them until the next one: the same fork-join, without the wake-up on the hot path.
//!
//! The systems gather their query items into a vector each tick; [`recycle`] keeps that
//! vector's allocation between ticks, so the steady state allocates nothing.

use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, OnceLock, TryLockError};
use std::time::{Duration, Instant};

use bevy_ecs::prelude::Resource;

/// How long a helper keeps looking for the next section before it parks.
///
/// Longer than a tick's longest serial stretch at 10,000 vehicles (the wifi round's gathering of
/// the senders, about 0.6 ms; a grid rebuild, about 0.2 ms): at 200 µs the helpers parked in
/// those stretches, and every section after one waited for a wake-up while the calling thread
/// worked its chunk alone (paired, 10,000 vehicles on 2 threads: 8 % less wall time at 3 ms;
/// 1 ms and 3 ms alike). A parked helper costs nothing; a spinning one yields between looks.
const SPIN: Duration = Duration::from_micros(2000);

/// How long a helper looks for the next section without giving its core away between looks.
/// A tick's sections follow each other within tens of microseconds; a helper that yielded
/// between every look (a system call, and the scheduler's pass) was often inside one when the
/// next section came, and joined it late (10,000 vehicles on 2 threads, paired over 16 turns:
/// 0.981 of the wall time without the yields in the first 50 µs, `--lane-change` 0.977-0.981;
/// 500 µs could not be told apart from 50).
const SPIN_ONLY: Duration = Duration::from_micros(50);

/// How long the calling thread spins for its helpers to finish before it yields between looks
/// (a helper may have been descheduled on a busy machine).
const WAIT_SPIN: Duration = Duration::from_micros(100);

/// Chunks a section is cut into per thread, so that a thread which finishes early finds half of
/// the other's share left to take. Measured on 2 threads (`bench`, instrumented): at 10,000
/// vehicles the caller waited 50-120 ms a run with one chunk a thread, 28-49 ms with 2, 12-24 ms
/// with 4, but at 100,000 vehicles 4 made the wifi round 10-30 % slower than 2 (0.98 -> 1.08 s
/// and 0.83 -> 1.12 s), and wall time at 10,000 could not tell 2 and 4 apart; 8 was slower.
/// Four of falling size (`chunk_start`) instead of two equal: paired, 2 threads, 0.99 of the
/// wall time at 10,000 vehicles (plain and `--lane-change`) and at 100,000. Five halving ones
/// (8, 4, 2, 1, 1 sixteenths of a share: the last chunk running when the other runs out a
/// thirty-second of the section, not a twentieth) instead of those four: paired, 2 threads, 30
/// turns, 0.976 of the wall time at 10,000 vehicles (the caller's wait for its helper at the
/// ends of the sections, instrumented, was 3.5 % of the run), 0.993 with `--lane-change` (12
/// turns) and 0.999 at 100,000 (8 turns); six of 6, 5, 4, 3, 2, 1 gave 0.980 and 1.018.
pub const CHUNKS_PER_THREAD: usize = 5;

/// One section's work as the helpers see it: call `run(data, chunk)` for their chunk.
struct Job {
    data: *const (),
    run: unsafe fn(*const (), usize),
}

/// What a [`Team`]'s caller and helpers share.
struct Shared {
    /// Bumped by the caller for each section (helpers run each epoch once); `u64::MAX`: stop.
    epoch: AtomicU64,
    /// The current section's [`Job`], valid while `pending` > 0.
    job: AtomicPtr<Job>,
    /// Helpers that have not finished the current section.
    pending: AtomicUsize,
    /// Some helper's chunk panicked in the current section.
    panicked: AtomicBool,
    /// Helpers parked (or about to park) on `wake`.
    sleepers: AtomicUsize,
    /// The current section's chunks each participant (0: the caller, k: helper k) has still to
    /// run, as a range packed by [`pack`]: its owner takes from the front, the others, once
    /// their own are done, from the back.
    ranges: Box<[Padded<AtomicU64>]>,
    lock: Mutex<()>,
    wake: Condvar,
}

/// `helpers` persistent threads that share each section's chunks with the caller
/// (`Team::run`). One section at a time: a second caller (another thread, or a
/// chunk that itself splits its work) finds the team busy and runs its chunks itself.
pub struct Team {
    shared: Arc<Shared>,
    helpers: usize,
    busy: Mutex<()>,
}

impl Team {
    /// Start `helpers` threads, or `None` when the system refuses to start one.
    fn start(helpers: usize) -> Option<Team> {
        let shared = Arc::new(Shared {
            epoch: AtomicU64::new(0),
            job: AtomicPtr::new(std::ptr::null_mut()),
            pending: AtomicUsize::new(0),
            panicked: AtomicBool::new(false),
            sleepers: AtomicUsize::new(0),
            ranges: (0..=helpers).map(|_| Padded(AtomicU64::new(0))).collect(),
            lock: Mutex::new(()),
            wake: Condvar::new(),
        });
        for k in 0..helpers {
            let shared = Arc::clone(&shared);
            let started =
                std::thread::Builder::new().name(format!("smlworld-worker-{k}")).spawn(move || help(&shared, k + 1));
            if let Err(e) = started {
                tracing::warn!("cannot start worker threads ({e}); running on one thread");
                return None;
            }
        }
        Some(Team { shared, helpers, busy: Mutex::new(()) })
    }

    /// Call `f(k)` for every chunk `k` in `0..chunks`, on this thread and the helpers; returns
    /// when all are done (a helper's panic is raised here). When the team is running another
    /// section, every chunk runs here, in order.
    ///
    /// Each participant owns a contiguous run of the chunks (this thread the first) and works
    /// it front to back; one that finishes early takes the others' last chunks (work stealing
    /// from the back, as in Cilk's and rayon's deques). The participants keep to their own
    /// vehicles section after section, as with a fixed split, but a thread that was descheduled
    /// or runs slower chunks no longer makes the other wait: on 10,000 vehicles and 2 threads
    /// the caller waited 50-120 ms of a 0.45-0.55 s run for the helper, which ran its fixed half
    /// 8-25 % slower. What a chunk computes depends on its number only, never on who runs it.
    fn run<F: Fn(usize) + Sync>(&self, chunks: usize, f: &F) {
        let _guard = match self.busy.try_lock() {
            Ok(guard) => guard,
            Err(TryLockError::Poisoned(e)) => e.into_inner(),
            Err(TryLockError::WouldBlock) => {
                (0..chunks).for_each(f);
                return;
            }
        };
        /// Calls the `F` behind `data` (a `&F` made below, alive until every helper is done).
        unsafe fn call<F: Fn(usize)>(data: *const (), chunk: usize) {
            // SAFETY: `data` is the `&F` of the section being run, which outlives it.
            unsafe { (*data.cast::<F>())(chunk) }
        }
        let job = Job { data: (f as *const F).cast(), run: call::<F> };
        let s = &*self.shared;
        let participants = self.helpers + 1;
        for (p, range) in s.ranges.iter().enumerate() {
            range.0.store(pack(p * chunks / participants, (p + 1) * chunks / participants), Ordering::Relaxed);
        }
        s.panicked.store(false, Ordering::Relaxed);
        s.job.store((&job as *const Job).cast_mut(), Ordering::Relaxed);
        s.pending.store(self.helpers, Ordering::Relaxed);
        // SeqCst pairs with the helpers' parking (sleepers, then epoch): either a helper sees
        // the new epoch before it parks, or this sees it parking and wakes it.
        s.epoch.fetch_add(1, Ordering::SeqCst);
        if s.sleepers.load(Ordering::SeqCst) > 0 {
            let _lock = s.lock.lock().unwrap_or_else(|e| e.into_inner());
            s.wake.notify_all();
        }
        // Our own chunks, then any left; a panic waits for the helpers (they still read `job`
        // and `f`).
        let own = catch_unwind(AssertUnwindSafe(|| work(&s.ranges, 0, f)));
        let started = Instant::now();
        while s.pending.load(Ordering::Acquire) != 0 {
            if started.elapsed() < WAIT_SPIN {
                std::hint::spin_loop();
            } else {
                std::thread::yield_now();
            }
        }
        if let Err(payload) = own {
            resume_unwind(payload);
        }
        if s.panicked.load(Ordering::Relaxed) {
            panic!("a worker thread panicked in a per-vehicle system");
        }
    }
}

/// A helper's loop: wait for the next epoch (spinning for [`SPIN`], then parked), run its
/// share of that section's chunks ([`work`]), report done.
fn help(s: &Shared, me: usize) {
    let mut seen = 0u64;
    loop {
        let mut since = None;
        let epoch = loop {
            let e = s.epoch.load(Ordering::Acquire);
            if e != seen {
                break e;
            }
            let spinning = since.get_or_insert_with(Instant::now);
            let waited = spinning.elapsed();
            if waited < SPIN {
                // Between looks, a short spin; past the first `SPIN_ONLY`, the core to any other
                // runnable thread too (on a busy machine a spinning helper would take a core from
                // the work itself).
                for _ in 0..32 {
                    std::hint::spin_loop();
                }
                if waited >= SPIN_ONLY {
                    std::thread::yield_now();
                }
                continue;
            }
            let mut lock = s.lock.lock().unwrap_or_else(|e| e.into_inner());
            s.sleepers.fetch_add(1, Ordering::SeqCst);
            while s.epoch.load(Ordering::SeqCst) == seen {
                lock = s.wake.wait(lock).unwrap_or_else(|e| e.into_inner());
            }
            s.sleepers.fetch_sub(1, Ordering::SeqCst);
            since = None;
        };
        seen = epoch;
        // SAFETY: the caller published `job` before bumping the epoch (Acquire above) and keeps
        // it and what it points to alive until `pending` reaches 0, which this has not done.
        let job = unsafe { &*s.job.load(Ordering::Relaxed) };
        // SAFETY: as above: `job.data` is the section's `&F`, `job.run` its matching caller.
        let result = catch_unwind(AssertUnwindSafe(|| work(&s.ranges, me, &|k| unsafe { (job.run)(job.data, k) })));
        if result.is_err() {
            s.panicked.store(true, Ordering::Relaxed);
        }
        s.pending.fetch_sub(1, Ordering::Release);
    }
}

/// A range of chunks `front..back` in one atomic word (front in the high half).
fn pack(front: usize, back: usize) -> u64 {
    ((front as u64) << 32) | back as u64
}

/// Take chunk `front` (the owner) or `back - 1` (a thief) of `range`, if any is left.
fn take(range: &AtomicU64, from_back: bool) -> Option<usize> {
    let mut now = range.load(Ordering::Relaxed);
    loop {
        let (front, back) = (now >> 32, now & 0xffff_ffff);
        if front >= back {
            return None;
        }
        let (next, chunk) =
            if from_back { (pack(front as usize, back as usize - 1), back - 1) } else { (now + (1 << 32), front) };
        // Relaxed: the chunks' data was published with the section (epoch) and is handed back
        // with `pending`; the range only has to be taken once per chunk.
        match range.compare_exchange_weak(now, next, Ordering::Relaxed, Ordering::Relaxed) {
            Ok(_) => return Some(chunk as usize),
            Err(actual) => now = actual,
        }
    }
}

/// Participant `me`'s share of a section: its own chunks front to back, then the others' from
/// their backs.
fn work(ranges: &[Padded<AtomicU64>], me: usize, f: &dyn Fn(usize)) {
    while let Some(k) = take(&ranges[me].0, false) {
        f(k);
    }
    for d in 1..ranges.len() {
        let other = &ranges[(me + d) % ranges.len()].0;
        while let Some(k) = take(other, true) {
            f(k);
        }
    }
}

/// The persistent team with `helpers` helper threads (started on first use, then shared), or
/// `None` when the system refuses to start threads (the work then runs on the calling thread).
fn team(helpers: usize) -> Option<&'static Team> {
    static TEAMS: OnceLock<Mutex<BTreeMap<usize, Option<&'static Team>>>> = OnceLock::new();
    let mut teams = TEAMS.get_or_init(|| Mutex::new(BTreeMap::new())).lock().unwrap_or_else(|e| e.into_inner());
    *teams.entry(helpers).or_insert_with(|| Team::start(helpers).map(|t| &*Box::leak(Box::new(t))))
}

pub use crate::world::prefetch;

/// Empty `v` and reuse its allocation for a vector of another item type of the same layout:
/// a system keeps `Local<Vec<Item<'static>>>` between ticks and turns it into this tick's
/// `Vec<Item<'w>>` and back, so gathering query items allocates only while the world grows.
/// (It relies on the standard library collecting `Vec::into_iter().map(..)` in place.)
pub fn recycle<T, U>(mut v: Vec<T>) -> Vec<U> {
    v.clear();
    v.into_iter().map(|_| -> U { unreachable!("the vector was emptied") }).collect()
}

/// A per-thread value on cache lines of its own: `T` aligned to 128 bytes (two lines, which the
/// processor's adjacent-line prefetcher fetches together).
///
/// The scratch values of [`Parallelism::for_each_chunk`] lie side by side in one vector, and
/// most are written for every item (counts, buffer lengths): two threads writing neighbours on
/// one line pass it back and forth at every write. Each scratch type a system writes per item
/// is `#[repr(align(128))]`, or wrapped in this (10,000 vehicles, 2 threads, paired: 13 % less
/// wall time once the sensors', the wifi round's, the deliveries' and the lane changes' were).
#[derive(Debug, Default, Clone, Copy, PartialEq)]
#[repr(align(128))]
pub struct Padded<T>(pub T);

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

    /// The split for per-vehicle work on a share of a world of `vehicles` vehicles (a plugin
    /// sensor on a tenth of them, each item as costly as a vehicle's sensing): the threads the
    /// whole world gets, used at any item count; one thread where the world is too small.
    pub fn for_share_of(&self, vehicles: usize) -> Parallelism {
        match self.threads_for(vehicles) {
            1 => Parallelism::single(),
            threads => Parallelism { threads, min_vehicles: 0 },
        }
    }

    /// Chunks [`Parallelism::for_each_chunk`] cuts `items` items into: [`CHUNKS_PER_THREAD`] a
    /// thread (1 on one thread). Fewer are non-empty when `items` is not much larger.
    pub fn chunks_for(&self, items: usize) -> usize {
        match self.threads_for(items) {
            1 => 1,
            threads => (threads * CHUNKS_PER_THREAD).min(items),
        }
    }

    /// Call `f(chunk, scratch)` on contiguous chunks of `items` ([`Parallelism::chunks_for`]
    /// of them, shared out over the threads), each with its own scratch value from `scratch`
    /// (grown to the chunk count and kept by the caller between ticks: chunk k always gets
    /// value k, whichever thread runs it). `f` must write only through its chunk and its scratch.
    pub fn for_each_chunk<T: Send, S: Send + Default>(
        &self,
        items: &mut [T],
        scratch: &mut Vec<S>,
        f: impl Fn(&mut [T], &mut S) + Sync,
    ) {
        self.for_each_chunk_at(items, scratch, |_, chunk, s| f(chunk, s));
    }

    /// [`Parallelism::for_each_chunk`] that also tells `f` where its chunk starts in `items`:
    /// `f(start, chunk, scratch)`, for work whose records name items by their position.
    pub fn for_each_chunk_at<T: Send, S: Send + Default>(
        &self,
        items: &mut [T],
        scratch: &mut Vec<S>,
        f: impl Fn(usize, &mut [T], &mut S) + Sync,
    ) {
        // A second slice of zero-sized values: no allocation, cut alongside and ignored.
        let mut none = vec![(); items.len()];
        self.for_each_chunk_pair_at(items, &mut none, scratch, |start, chunk, _, s| f(start, chunk, s));
    }

    /// [`Parallelism::for_each_chunk_at`] over two slices of equal length cut at the same
    /// places: `f(start, chunk of a, chunk of b, scratch)`, for systems that write two
    /// components of each vehicle straight in the ECS table's slices.
    pub fn for_each_chunk_pair_at<A: Send, B: Send, S: Send + Default>(
        &self,
        a: &mut [A],
        b: &mut [B],
        scratch: &mut Vec<S>,
        f: impl Fn(usize, &mut [A], &mut [B], &mut S) + Sync,
    ) {
        // A third slice of zero-sized values: no allocation, cut alongside and ignored.
        let mut none = vec![(); a.len().min(b.len())];
        self.for_each_chunk_triple_at(a, b, &mut none, scratch, |start, a, b, _, s| f(start, a, b, s));
    }

    /// [`Parallelism::for_each_chunk_at`] over three slices of equal length cut at the same
    /// places: `f(start, chunk of a, chunk of b, chunk of c, scratch)`, for systems that write
    /// three components of each vehicle straight in the ECS table's slices.
    pub fn for_each_chunk_triple_at<A: Send, B: Send, C: Send, S: Send + Default>(
        &self,
        a: &mut [A],
        b: &mut [B],
        c: &mut [C],
        scratch: &mut Vec<S>,
        f: impl Fn(usize, &mut [A], &mut [B], &mut [C], &mut S) + Sync,
    ) {
        let len = a.len().min(b.len()).min(c.len());
        let (a, b, c) = (&mut a[..len], &mut b[..len], &mut c[..len]);
        let threads = self.threads_for(len);
        let chunks = self.chunks_for(len);
        if scratch.len() < chunks {
            scratch.resize_with(chunks, S::default);
        }
        // The calling thread and the team's threads - 1 helpers share the chunks out
        // ([`Team::run`]); on one thread, or without a team, one chunk holds everything.
        let team = if threads > 1 { team(threads - 1) } else { None };
        let Some(team) = team else {
            f(0, a, b, c, &mut scratch[0]);
            return;
        };
        let parts = Parts { items: a.as_mut_ptr(), len, scratch: scratch.as_mut_ptr(), chunks };
        let seconds = Parts { items: b.as_mut_ptr(), len, scratch: std::ptr::null_mut::<()>(), chunks };
        let thirds = Parts { items: c.as_mut_ptr(), len, scratch: std::ptr::null_mut::<()>(), chunks };
        team.run(chunks, &|k: usize| {
            // SAFETY: the team calls every chunk number in 0..chunks once, `scratch` holds at
            // least `chunks` values (grown above), and chunk k of `a`, `b` and `c` are the same
            // disjoint range of three slices of length `len`, all borrowed mutably for this
            // whole call. The others' scratch is never read (`take_items` does not touch it).
            if let (Some((chunk, s)), Some(second), Some(third)) =
                unsafe { (parts.take(k), seconds.take_items(k), thirds.take_items(k)) }
            {
                f(chunk_start(len, chunks, k), chunk, second, third, s);
            }
        });
    }
}

/// Where chunk `k` of `chunks` over `len` items starts (`k == chunks`: `len`). Cut as
/// [`Team::run`] shares them out, [`CHUNKS_PER_THREAD`] to each participant: each participant's
/// equal share in chunks of falling size ([`CHUNK_SHARES`]), so that whichever chunk is still
/// running when the other participant runs out of work is a small one (the wait at the end of a
/// section is about half the chunk in progress). Otherwise equal chunks. Either way, with
/// `chunks <= len` ([`Parallelism::chunks_for`]) no chunk is empty.
pub(crate) fn chunk_start(len: usize, chunks: usize, k: usize) -> usize {
    let participants = chunks / CHUNKS_PER_THREAD;
    let total = CHUNK_SHARES[CHUNKS_PER_THREAD];
    // (Only where every chunk gets an item: a share of `total` or more.)
    if chunks > 1 && chunks.is_multiple_of(CHUNKS_PER_THREAD) && len >= total * participants {
        let (p, j) = (k / CHUNKS_PER_THREAD, k % CHUNKS_PER_THREAD);
        let from = p * len / participants;
        let share = (p + 1) * len / participants - from;
        // What is left after the chunk's start rounded down, so the sizes fall even where the
        // share is not a multiple of `total` (rounding the starts down gave 9, 5, 2, 1, 2).
        from + share - share * (total - CHUNK_SHARES[j]) / total
    } else {
        k * len / chunks.max(1)
    }
}

/// The running sums of the chunk sizes within a participant's share ([`chunk_start`]).
const CHUNK_SHARES: [usize; CHUNKS_PER_THREAD + 1] = [0, 8, 12, 14, 15, 16];

/// The items and scratch values of one [`Parallelism::for_each_chunk_at`] call, cut into
/// `chunks` chunks ([`chunk_start`]) without an allocation per call.
struct Parts<T, S> {
    items: *mut T,
    len: usize,
    scratch: *mut S,
    chunks: usize,
}

// SAFETY: `Parts` only hands out the disjoint chunk `k` to whoever runs chunk `k` (see
// `Parts::take`); the items and scratch values are `Send`.
unsafe impl<T: Send, S: Send> Sync for Parts<T, S> {}

impl<T, S> Parts<T, S> {
    /// Chunk `k`'s items and scratch value (`None` past the items' end).
    ///
    /// # Safety
    /// Each `k` must be taken at most once while the borrowed slices live, and `scratch` must
    /// hold more than `k` values.
    unsafe fn take<'a>(&self, k: usize) -> Option<(&'a mut [T], &'a mut S)> {
        // SAFETY: the caller's promises, passed on; `take_items` returned a chunk, so `k` is a
        // chunk number and `scratch` holds more than `k` values.
        unsafe { self.take_items(k).map(|chunk| (chunk, &mut *self.scratch.add(k))) }
    }

    /// Chunk `k`'s items alone (`None` past the items' end); the scratch pointer is not used.
    ///
    /// # Safety
    /// Each `k` must be taken at most once while the borrowed slice lives.
    unsafe fn take_items<'a>(&self, k: usize) -> Option<&'a mut [T]> {
        if k >= self.chunks {
            return None;
        }
        let start = chunk_start(self.len, self.chunks, k);
        let len = chunk_start(self.len, self.chunks, k + 1) - start;
        if len == 0 {
            return None;
        }
        // SAFETY: `start + len <= self.len`, and chunk `k` is taken once (the caller's promise).
        unsafe { Some(std::slice::from_raw_parts_mut(self.items.add(start), len)) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn padded_neighbours_in_a_vector_share_no_cache_line() {
        let v = vec![Padded(0u64); 3];
        for pair in v.windows(2) {
            let (a, b) = (&pair[0].0 as *const u64 as usize, &pair[1].0 as *const u64 as usize);
            assert!(b - a >= 128, "neighbours {} bytes apart", b - a);
            assert_eq!(a % 128, 0);
        }
    }

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

    #[test]
    fn a_share_of_a_large_world_splits_at_any_count_and_of_a_small_one_never() {
        let p = Parallelism { threads: 2, min_vehicles: 2000 };
        assert_eq!(p.threads_for(1000), 1, "1,000 items alone stay on one thread");
        let share = p.for_share_of(10_000);
        assert_eq!((share.threads_for(1000), share.threads_for(3)), (2, 2));
        assert_eq!(share.threads_for(1), 1);
        assert_eq!(p.for_share_of(1999).threads_for(1000), 1, "a world under the threshold");
        assert_eq!(Parallelism::single().for_share_of(10_000).threads_for(1000), 1);
    }

    #[test]
    fn pair_chunks_cut_both_slices_at_the_same_places() {
        for threads in [1, 2, 3, 4] {
            let p = Parallelism { threads, min_vehicles: 1 };
            let mut a: Vec<usize> = vec![usize::MAX; 1001];
            let mut b: Vec<(usize, usize)> = (0..1001).map(|i| (i, 0)).collect();
            let mut scratch: Vec<u64> = Vec::new();
            p.for_each_chunk_pair_at(&mut a, &mut b, &mut scratch, |start, xs, ys, s| {
                assert_eq!(xs.len(), ys.len());
                for (k, (x, y)) in xs.iter_mut().zip(ys.iter_mut()).enumerate() {
                    *x = start + k;
                    y.1 = y.0 + 1;
                    *s += 1;
                }
            });
            assert_eq!(a, (0..1001).collect::<Vec<usize>>(), "{threads} threads");
            assert!(b.iter().all(|&(i, j)| j == i + 1), "{threads} threads");
            assert_eq!(scratch.iter().sum::<u64>(), 1001);
            assert_eq!(scratch.iter().filter(|&&n| n > 0).count(), p.chunks_for(1001));
            assert_eq!(p.chunks_for(1001), if threads == 1 { 1 } else { threads * CHUNKS_PER_THREAD });
        }
    }

    #[test]
    fn triple_chunks_cut_three_slices_at_the_same_places() {
        for threads in [1, 2, 3, 4] {
            let p = Parallelism { threads, min_vehicles: 1 };
            let mut a: Vec<usize> = vec![usize::MAX; 1001];
            let mut b: Vec<usize> = (0..1001).collect();
            let mut c: Vec<usize> = vec![0; 1002];
            let mut scratch: Vec<u64> = Vec::new();
            p.for_each_chunk_triple_at(&mut a, &mut b, &mut c, &mut scratch, |start, xs, ys, zs, s| {
                assert_eq!((xs.len(), ys.len()), (zs.len(), zs.len()));
                for (k, ((x, y), z)) in xs.iter_mut().zip(ys.iter_mut()).zip(zs.iter_mut()).enumerate() {
                    *x = start + k;
                    *z = *y + 1;
                    *s += 1;
                }
            });
            assert_eq!(a, (0..1001).collect::<Vec<usize>>(), "{threads} threads");
            assert_eq!(c[..1001], (1..1002).collect::<Vec<usize>>(), "{threads} threads");
            assert_eq!(c[1001], 0, "past the shortest slice: not visited");
            assert_eq!(scratch.iter().sum::<u64>(), 1001);
        }
    }

    #[test]
    fn each_chunk_is_told_where_it_starts() {
        for threads in [1, 2, 3, 4] {
            let p = Parallelism { threads, min_vehicles: 1 };
            let mut items: Vec<(usize, usize)> = (0..1001).map(|i| (i, usize::MAX)).collect();
            let mut scratch: Vec<u64> = Vec::new();
            p.for_each_chunk_at(&mut items, &mut scratch, |start, chunk, _| {
                for (k, x) in chunk.iter_mut().enumerate() {
                    x.1 = start + k;
                }
            });
            assert!(items.iter().all(|&(i, at)| i == at), "{threads} threads");
        }
    }

    #[test]
    fn each_participants_share_is_cut_into_falling_chunks_none_empty() {
        for threads in [2, 3, 4] {
            let p = Parallelism { threads, min_vehicles: 0 };
            for len in [1, 2, 7, 8, 9, 12, 39, 40, 41, 47, 48, 49, 63, 64, 65, 100, 1001, 10_000, 10_007] {
                let chunks = p.chunks_for(len);
                let starts: Vec<usize> = (0..=chunks).map(|k| chunk_start(len, chunks, k)).collect();
                assert_eq!((starts[0], starts[chunks]), (0, len), "{threads} threads, {len} items");
                assert!(starts.windows(2).all(|w| w[0] < w[1]), "none empty: {starts:?}");
                if len >= CHUNK_SHARES[CHUNKS_PER_THREAD] * threads {
                    // Each participant's chunks (as `Team::run` shares them out) fall in size,
                    // its last at most half its first.
                    for share in starts.windows(CHUNKS_PER_THREAD + 1).step_by(CHUNKS_PER_THREAD) {
                        let sizes: Vec<usize> = share.windows(2).map(|w| w[1] - w[0]).collect();
                        assert!(sizes.windows(2).all(|w| w[0] >= w[1]), "{sizes:?}");
                        assert!(sizes[sizes.len() - 1] * 2 <= sizes[0], "{sizes:?}");
                    }
                    // And the shares are equal to an item.
                    let share = |q: usize| starts[(q + 1) * CHUNKS_PER_THREAD] - starts[q * CHUNKS_PER_THREAD];
                    assert!((0..threads).all(|q| share(q).abs_diff(len / threads) <= 1), "{starts:?}");
                }
            }
        }
    }

    #[test]
    fn the_caller_takes_the_chunks_of_a_helper_that_is_held_up() {
        let p = Parallelism { threads: 2, min_vehicles: 0 };
        let caller = std::thread::current().id();
        let mut items: Vec<usize> = (0..800).collect();
        // Per chunk: its first item and whether the calling thread ran it.
        let mut scratch: Vec<Option<(usize, bool)>> = Vec::new();
        let held = AtomicBool::new(false);
        p.for_each_chunk(&mut items, &mut scratch, |chunk, s| {
            let here = std::thread::current().id() == caller;
            if here {
                // Time for the helper to wake and take its first chunk.
                std::thread::sleep(Duration::from_millis(5));
            } else if !held.swap(true, Ordering::Relaxed) {
                // The helper's first chunk takes long (a descheduled thread, a slow chunk).
                std::thread::sleep(Duration::from_millis(300));
            }
            assert!(s.is_none(), "chunk from {} ran twice", chunk[0]);
            *s = Some((chunk[0], here));
        });
        let chunks = p.chunks_for(800);
        assert_eq!(scratch.len(), chunks);
        for (k, s) in scratch.iter().enumerate() {
            assert_eq!(s.map(|s| s.0), Some(chunk_start(800, chunks, k)), "chunk {k} ran on its own items once");
        }
        let by_caller = scratch.iter().filter(|s| s.is_some_and(|s| s.1)).count();
        // The caller's own half, and all but the held chunk of the helper's.
        assert!(by_caller >= chunks - 1, "the caller ran {by_caller} of {chunks} chunks");
    }

    #[test]
    fn a_chunk_that_splits_again_or_a_second_caller_runs_on_its_own_thread() {
        let p = Parallelism { threads: 2, min_vehicles: 0 };
        // Nested: each chunk splits its items again (the team is busy: they run in place).
        let mut outer: Vec<Vec<u32>> = (0..4).map(|k| (0..100).map(|x| x + k * 100).collect()).collect();
        p.for_each_chunk(&mut outer, &mut Vec::<()>::new(), |chunk, _| {
            for inner in chunk.iter_mut() {
                p.for_each_chunk(inner, &mut Vec::<()>::new(), |c, _| c.iter_mut().for_each(|x| *x *= 2));
            }
        });
        assert_eq!(outer.concat(), (0..400).map(|x| x * 2).collect::<Vec<u32>>());
        // Two threads splitting at once, many times: every item once, no deadlock.
        std::thread::scope(|scope| {
            for t in 0..2u64 {
                scope.spawn(move || {
                    for round in 0..300u64 {
                        let mut items: Vec<u64> = (0..64).collect();
                        let mut scratch: Vec<u64> = Vec::new();
                        p.for_each_chunk(&mut items, &mut scratch, |c, s| {
                            for x in c.iter_mut() {
                                *x += t + round;
                                *s += 1;
                            }
                        });
                        assert_eq!(items, (0..64).map(|x| x + t + round).collect::<Vec<u64>>());
                        assert_eq!(scratch.iter().sum::<u64>(), 64);
                    }
                });
            }
        });
    }

    #[test]
    fn a_panic_in_a_helper_chunk_reaches_the_caller_and_the_team_goes_on() {
        let p = Parallelism { threads: 2, min_vehicles: 0 };
        let mut items: Vec<u32> = (0..10).collect();
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            p.for_each_chunk(&mut items, &mut Vec::<()>::new(), |c, _| {
                // The second chunk (items 5..10) runs on the helper.
                assert!(c[0] < 5, "chunk from {} refuses", c[0]);
            });
        }));
        assert!(caught.is_err(), "the helper's panic was lost");
        let mut items: Vec<u32> = (0..10).collect();
        p.for_each_chunk(&mut items, &mut Vec::<()>::new(), |c, _| c.iter_mut().for_each(|x| *x += 1));
        assert_eq!(items, (1..11).collect::<Vec<u32>>());
    }
}
