//! A uniform spatial hash grid rebuilt once per tick: O(N) to build, O(neighbours) per query.
//!
//! Cells are squares of side `cell` \[m\]; cell coordinates are hashed into a power-of-two
//! number of buckets (at least the number of entries) and the entries are counting-sorted by
//! bucket, so a rebuild is O(N) with no allocation once the buffers have grown. A query visits
//! the cells its disc overlaps and accepts an entry only if it lies in the visited cell, so hash
//! collisions cost a few extra comparisons but never a duplicate.

use glam::DVec2;

use super::candidates::Candidates;
use crate::sim::parallel::Parallelism;
use crate::sim::trig::floor_i32;
use crate::world::VehicleId;

/// One vehicle in the grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridEntry {
    /// Position \[m\].
    pub position: DVec2,
    /// Velocity [m/s].
    pub velocity: DVec2,
    /// Vehicle id.
    pub id: VehicleId,
    /// Caller-defined index (e.g. into a list of senders).
    pub index: u32,
}

/// What a query hands out of an entry: all but its velocity ([`SpatialGrid::get`] gives the
/// whole entry). Queries scan the positions alone (two arrays of coordinates) and read an
/// entry's id and index only when it is within range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridPoint {
    /// Position \[m\].
    pub position: DVec2,
    /// Vehicle id.
    pub id: VehicleId,
    /// Caller-defined index.
    pub index: u32,
}

/// One bucket: where its entries start in the slots (they end where the next bucket's start),
/// and whose they are: one cell's (`mixed` false: a query takes or skips the whole bucket by
/// comparing `cell` once) or, after a hash collision, several cells' (a query then compares
/// each entry's cell). Buckets are at least as many as entries, so collisions are rare. Four
/// buckets fill a cache line.
#[derive(Debug, Clone, Copy, Default)]
#[repr(align(16))]
struct Bucket {
    start: u32,
    mixed: bool,
    cell: (i32, i32),
}

/// The grid; keep one per use and call [`SpatialGrid::rebuild`] every tick.
#[derive(Debug, Clone, Default)]
pub struct SpatialGrid {
    cell: f64,
    mask: u64,
    /// One more than there are buckets: the last one only ends the one before.
    buckets: Vec<Bucket>,
    /// Entries in bucket order; their coordinates, ids and indices again as arrays of their
    /// own (what queries scan: structure of arrays, so a scan reads 16 bytes a candidate and
    /// vectorises); and the cell of each (read only in mixed buckets).
    slots: Vec<GridEntry>,
    xs: Vec<f64>,
    ys: Vec<f64>,
    ids: Vec<VehicleId>,
    indices: Vec<u32>,
    cells: Vec<(i32, i32)>,
    /// Each entry's cell and bucket, in entry order (the first pass of a rebuild).
    placed: Vec<((i32, i32), u32)>,
    /// Per chunk of entries in a rebuild on several threads: its count of entries in each
    /// bucket, then its insertion cursor in each ([`SpatialGrid::rebuild_on`]).
    chunks: Vec<ChunkCounts>,
    /// Each bucket's first slot, and running sums (scratch of [`SpatialGrid::rebuild_on`]).
    starts: Vec<u32>,
    acc: Vec<u32>,
}

/// One entry chunk's counts or cursors per bucket, on cache lines of its own.
#[derive(Debug, Clone, Default)]
#[repr(align(128))]
struct ChunkCounts(Vec<u32>);

/// The columns a rebuild on several threads writes, as pointers: each thread writes the slots
/// its cursors give it, which no other thread's give ([`SpatialGrid::rebuild_on`]).
struct Scatter {
    slots: *mut GridEntry,
    xs: *mut f64,
    ys: *mut f64,
    ids: *mut VehicleId,
    indices: *mut u32,
    cells: *mut (i32, i32),
    len: usize,
}

// SAFETY: the threads of a rebuild write disjoint slots through it (see `Scatter::write`), and
// the columns' element types are `Send`.
unsafe impl Sync for Scatter {}

impl Scatter {
    /// Write `entry` (in `cell`) into slot `at`.
    ///
    /// # Safety
    /// `at < len`, and no other thread writes or reads slot `at` during the scatter.
    #[inline]
    unsafe fn write(&self, at: usize, entry: GridEntry, cell: (i32, i32)) {
        debug_assert!(at < self.len);
        // SAFETY: `at` is within the columns (each `len` long) and this thread's alone.
        unsafe {
            self.slots.add(at).write(entry);
            self.xs.add(at).write(entry.position.x);
            self.ys.add(at).write(entry.position.y);
            self.ids.add(at).write(entry.id);
            self.indices.add(at).write(entry.index);
            self.cells.add(at).write(cell);
        }
    }
}

/// The cell of side `size` [m] holding `p`.
#[inline]
fn cell_at(p: DVec2, size: f64) -> (i32, i32) {
    (floor_i32(p.x / size), floor_i32(p.y / size))
}

/// Cells of one column that hash to one run of consecutive buckets (a cache line), so the three cells a
/// query visits in a column are mostly found together, and their entries lie next to each
/// other.
const RUN: u64 = 4;

/// Columns of a block: a block of `BLOCK` x [`RUN`] cells hashes to one stretch of consecutive
/// buckets (four cache lines), runs side by side, so the queries of neighbouring vehicles
/// (neighbours in the query order when the vehicles lie in road order) mostly read bucket lines
/// the last query read: far fewer cache misses than a hash per column.
const BLOCK: u64 = 4;

/// The bucket of `cell` among `mask + 1` (a power of two, at least [`RUN`] x [`BLOCK`]).
fn bucket_of(cell: (i32, i32), mask: u64) -> usize {
    // The 64-bit finaliser of MurmurHash3 on the block (x / BLOCK, y / RUN): neighbouring blocks
    // land in unrelated places; x's and y's remainders pick the run and the bucket within it.
    let (bx, ry) = (BLOCK.trailing_zeros(), RUN.trailing_zeros());
    let mut h = ((cell.0 >> bx) as u32 as u64) << 32 | (cell.1 >> ry) as u32 as u64;
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    h ^= h >> 33;
    let within = ((cell.0 as u32 as u64 & (BLOCK - 1)) << ry) | (cell.1 as u32 as u64 & (RUN - 1));
    (((h << (bx + ry)) | within) & mask) as usize
}

impl SpatialGrid {
    /// The cell holding `p`.
    pub fn cell_of(&self, p: DVec2) -> (i32, i32) {
        cell_at(p, self.cell)
    }

    /// Refill the grid with `entries` using square cells of side `cell` \[m\] (> 0); queries are
    /// cheapest when `cell` is about the largest query radius.
    ///
    /// `entries` is read twice (a clone of it first): once for each entry's cell, then again
    /// to scatter the entries into their buckets, so only 12 bytes an entry (its cell and
    /// bucket) are staged, not a copy of each entry (72 bytes written and read again). Both
    /// passes must yield the same entries in the same order (a slice's or a query's iterator,
    /// unchanged in between, does).
    ///
    /// On one thread; [`SpatialGrid::rebuild_on`] splits it over several.
    pub fn rebuild(&mut self, cell: f64, entries: impl Iterator<Item = GridEntry> + Clone) {
        let size = self.set_cell(cell);
        self.placed.clear();
        self.placed.extend(entries.clone().map(|entry| (cell_at(entry.position, size), 0)));
        let n = self.placed.len();
        let buckets = self.set_buckets(n);
        self.buckets.clear();
        self.buckets.resize(buckets + 1, Bucket::default());
        // Count each bucket's entries in the start of the bucket after it.
        for (cell, bucket) in &mut self.placed {
            *bucket = bucket_of(*cell, self.mask) as u32;
            let b = *bucket as usize;
            let (owner, count) = (self.buckets[b].cell, self.buckets[b + 1].start);
            if count == 0 {
                self.buckets[b].cell = *cell;
            } else {
                self.buckets[b].mixed |= owner != *cell;
            }
            self.buckets[b + 1].start += 1;
        }
        for b in 0..buckets {
            self.buckets[b + 1].start += self.buckets[b].start;
        }
        self.size_columns(n);
        // `buckets[b].start` is used as the insertion cursor of bucket b, then restored.
        let mut scattered = 0;
        for (entry, &(cell, bucket)) in entries.zip(&self.placed) {
            let b = bucket as usize;
            let at = self.buckets[b].start as usize;
            self.slots[at] = entry;
            (self.xs[at], self.ys[at]) = (entry.position.x, entry.position.y);
            (self.ids[at], self.indices[at]) = (entry.id, entry.index);
            self.cells[at] = cell;
            self.buckets[b].start += 1;
            scattered += 1;
        }
        debug_assert_eq!(scattered, n, "a grid's entries must yield the same entries twice");
        for b in (1..=buckets).rev() {
            self.buckets[b].start = self.buckets[b - 1].start;
        }
        self.buckets[0].start = 0;
    }

    /// Take `cell` [m] as the cells' side (1 m unless finite and positive); returns it.
    fn set_cell(&mut self, cell: f64) -> f64 {
        self.cell = if cell.is_finite() && cell > 0.0 { cell } else { 1.0 };
        self.cell
    }

    /// Size the hash for `n` entries: a power of two buckets, at least `n` and a block's;
    /// returns how many.
    fn set_buckets(&mut self, n: usize) -> usize {
        let buckets = n.max((RUN * BLOCK) as usize).next_power_of_two();
        self.mask = buckets as u64 - 1;
        buckets
    }

    /// Make every column `n` long: a rebuild writes every slot, so they are grown without a
    /// fill of the old length (only new places are initialised).
    fn size_columns(&mut self, n: usize) {
        self.slots.resize(n, EMPTY);
        self.xs.resize(n, 0.0);
        self.ys.resize(n, 0.0);
        self.ids.resize(n, VehicleId(0));
        self.indices.resize(n, 0);
        self.cells.resize(n, (0, 0));
    }

    /// [`SpatialGrid::rebuild`] from the `n` entries `entry(0)`, `entry(1)`, ..., split over
    /// the threads of `parallelism`: the same grid, bit for bit, on any thread count.
    ///
    /// A parallel counting sort: each thread takes a contiguous chunk of entries, finds each
    /// one's cell and bucket and counts its chunk's entries per bucket; one thread then turns
    /// the counts into each chunk's first slot in each bucket (chunk after chunk, so a bucket
    /// keeps its entries in entry order); each thread scatters its own chunk's entries; one
    /// thread notes each bucket's cell. Each thread reads only its own chunk's entries (an
    /// earlier split by bucket range, every thread reading entries the other had staged, was
    /// slower on two threads than on one). `entry` must give the same entry for an index both
    /// times it is asked.
    pub fn rebuild_on(
        &mut self,
        parallelism: Parallelism,
        cell: f64,
        n: usize,
        entry: impl Fn(usize) -> GridEntry + Sync,
    ) {
        let threads = parallelism.threads_for(n);
        if threads <= 1 {
            self.rebuild(cell, (0..n).map(&entry));
            return;
        }
        let size = self.set_cell(cell);
        let buckets = self.set_buckets(n);
        let mask = self.mask;
        self.placed.resize(n, ((0, 0), 0));
        // Each chunk's cells and buckets, and its count per bucket.
        parallelism.for_each_chunk_at(&mut self.placed, &mut self.chunks, |start, chunk, counts| {
            counts.0.clear();
            counts.0.resize(buckets, 0);
            for (k, placed) in chunk.iter_mut().enumerate() {
                let cell = cell_at(entry(start + k).position, size);
                let bucket = bucket_of(cell, mask);
                *placed = (cell, bucket as u32);
                counts.0[bucket] += 1;
            }
        });
        // The chunks `for_each_chunk_at` made (the same cut both times: same length, same
        // threads). Each bucket's first slot (`starts`: the exclusive prefix sum of its counts
        // over the chunks), then each chunk's counts become its cursors: the bucket's start plus
        // the counts of the chunks before it. Passes over whole arrays without a branch (the
        // compiler vectorises the sums), not a loop over buckets and chunks.
        let chunks = parallelism.chunks_for(n);
        let (starts, acc) = (&mut self.starts, &mut self.acc);
        starts.clear();
        starts.resize(buckets + 1, 0);
        for counts in &self.chunks[..chunks] {
            for (total, &count) in starts[..buckets].iter_mut().zip(&counts.0) {
                *total += count;
            }
        }
        let mut running = 0;
        for start in starts.iter_mut() {
            let count = *start;
            *start = running;
            running += count;
        }
        acc.clear();
        acc.extend_from_slice(&starts[..buckets]);
        for counts in &mut self.chunks[..chunks] {
            for (cursor, at) in counts.0.iter_mut().zip(acc.iter_mut()) {
                let count = *cursor;
                *cursor = *at;
                *at += count;
            }
        }
        self.size_columns(n);
        let out = Scatter {
            slots: self.slots.as_mut_ptr(),
            xs: self.xs.as_mut_ptr(),
            ys: self.ys.as_mut_ptr(),
            ids: self.ids.as_mut_ptr(),
            indices: self.indices.as_mut_ptr(),
            cells: self.cells.as_mut_ptr(),
            len: n,
        };
        parallelism.for_each_chunk_at(&mut self.placed, &mut self.chunks, |start, chunk, cursors| {
            for (k, &(cell, bucket)) in chunk.iter().enumerate() {
                let cursor = &mut cursors.0[bucket as usize];
                let at = *cursor as usize;
                *cursor += 1;
                assert!(at < out.len, "grid rebuild: a chunk's cursor ran past the entries");
                // SAFETY: chunk c's cursor for bucket b runs over its own entries of b only:
                // from the slots of b's entries in the chunks before c to those of c itself
                // (the prefix above), so no two threads write one slot, and `at < len`.
                unsafe { out.write(at, entry(start + k), cell) };
            }
        });
        // Each bucket's start, and its cell (its first entry's; mixed if another entry's
        // differs), a range of buckets a thread.
        let (starts, cells) = (&self.starts, &self.cells);
        self.buckets.resize(buckets + 1, Bucket::default());
        parallelism.for_each_chunk_at(&mut self.buckets, &mut Vec::<()>::new(), |first, chunk, _| {
            for (k, bucket) in chunk.iter_mut().enumerate() {
                let b = first + k;
                let start = starts[b] as usize;
                let end = starts.get(b + 1).map_or(start, |&end| end as usize);
                *bucket = Bucket { start: start as u32, ..Bucket::default() };
                if start < end {
                    let cell = cells[start];
                    bucket.cell = cell;
                    bucket.mixed = cells[start + 1..end].iter().any(|&c| c != cell);
                }
            }
        });
    }

    /// The slots of `cell`'s bucket, and whether they all lie in `cell` (else each must be
    /// checked against [`SpatialGrid::cells`]; an empty range when none can).
    #[inline]
    fn bucket(&self, cell: (i32, i32)) -> (std::ops::Range<usize>, bool) {
        let b = bucket_of(cell, self.mask);
        let (this, next) = (self.buckets[b], self.buckets[b + 1]);
        let range = this.start as usize..next.start as usize;
        if this.mixed {
            (range, false)
        } else if this.cell == cell {
            (range, true)
        } else {
            (0..0, true)
        }
    }

    /// The entry of slot `i` without its velocity.
    #[inline]
    fn point(&self, i: usize) -> GridPoint {
        GridPoint { position: DVec2::new(self.xs[i], self.ys[i]), id: self.ids[i], index: self.indices[i] }
    }

    /// Call `f(slot, point)` for every entry of `cell`.
    #[inline]
    pub fn for_each_in_cell(&self, cell: (i32, i32), mut f: impl FnMut(u32, &GridPoint)) {
        if self.slots.is_empty() {
            return;
        }
        let (range, pure) = self.bucket(cell);
        for i in range {
            if pure || self.cells[i] == cell {
                f(i as u32, &self.point(i));
            }
        }
    }

    /// Append the entries of `cell` to `out` (element by element, a cell holds a few;
    /// [`SpatialGrid::gather_cells`] copies whole runs where it can).
    #[inline]
    pub fn gather_cell(&self, cell: (i32, i32), out: &mut Candidates) {
        self.for_each_in_cell(cell, |slot, e| out.push(slot, e.position.x, e.position.y, e.id));
    }

    /// Append the entries of the cells (x, y) with x in `xs` and y in `ys` to `out`, each once.
    ///
    /// A column's cells that share a run of buckets (`RUN`) sit in consecutive buckets, so
    /// their entries are one range of the arrays when each of those buckets holds only its own
    /// cell's entries or none (the common case: buckets are at least as many as entries): that
    /// range is copied whole (three copies and a count instead of an element at a time). Any
    /// other bucket's cell goes through [`SpatialGrid::gather_cell`].
    pub fn gather_cells(
        &self,
        xs: std::ops::RangeInclusive<i32>,
        ys: std::ops::RangeInclusive<i32>,
        out: &mut Candidates,
    ) {
        if self.slots.is_empty() {
            return;
        }
        let shift = RUN.trailing_zeros();
        for x in xs {
            let mut y = *ys.start();
            while y <= *ys.end() {
                // The cells y..=last of this column share one run.
                let last = (((y >> shift) << shift) + (RUN as i32 - 1)).min(*ys.end());
                let first = bucket_of((x, y), self.mask);
                let own = (y..=last).zip(first..).all(|(cy, b)| {
                    let (this, next) = (self.buckets[b], self.buckets[b + 1]);
                    this.start == next.start || (!this.mixed && this.cell == (x, cy))
                });
                if own {
                    let count = (last - y) as usize + 1;
                    self.gather_slots(
                        self.buckets[first].start as usize..self.buckets[first + count].start as usize,
                        out,
                    );
                } else {
                    for cy in y..=last {
                        self.gather_cell((x, cy), out);
                    }
                }
                y = last + 1;
            }
        }
    }

    /// Append every entry to `out`.
    pub fn gather_all(&self, out: &mut Candidates) {
        self.gather_slots(0..self.slots.len(), out);
    }

    /// Append the entries of slots `range` to `out`, a copy of each array.
    fn gather_slots(&self, range: std::ops::Range<usize>, out: &mut Candidates) {
        out.xs.extend_from_slice(&self.xs[range.clone()]);
        out.ys.extend_from_slice(&self.ys[range.clone()]);
        out.ids.extend_from_slice(&self.ids[range.clone()]);
        out.slots.extend(range.start as u32..range.end as u32);
    }

    /// Side of the cells \[m\].
    pub fn cell_size(&self) -> f64 {
        self.cell
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether the grid is empty.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// All entries, in bucket order.
    pub fn entries(&self) -> impl Iterator<Item = &GridEntry> {
        self.slots.iter()
    }

    /// The caller-defined index of the entry in slot `slot`.
    pub fn index_of(&self, slot: u32) -> u32 {
        self.indices[slot as usize]
    }

    /// Gather into `out` every entry that may lie within `radius` \[m\] of a point of `cell` (the
    /// square of cells as far as the radius reaches, or everything when that square has more
    /// cells than the grid has entries); returns whether it gathered everything.
    pub fn gather_around(&self, cell: (i32, i32), radius: f64, out: &mut Candidates) -> bool {
        out.clear();
        let reach = (radius / self.cell).ceil().max(1.0);
        let side = 2.0 * reach + 1.0;
        if side * side > self.slots.len() as f64 {
            self.gather_all(out);
            return true;
        }
        let reach = reach as i32;
        self.gather_cells(cell.0 - reach..=cell.0 + reach, cell.1 - reach..=cell.1 + reach, out);
        false
    }

    /// The entry in slot `slot` (as passed to [`SpatialGrid::for_each_within`]).
    pub fn get(&self, slot: u32) -> &GridEntry {
        &self.slots[slot as usize]
    }

    /// Call `f(slot, point, squared distance [m²])` with every entry within `radius` \[m\] of `p`
    /// (inclusive), each exactly once.
    pub fn for_each_within(&self, p: DVec2, radius: f64, mut f: impl FnMut(u32, &GridPoint, f64)) {
        if self.slots.is_empty() {
            return;
        }
        let r2 = radius * radius;
        let lo = self.cell_of(p - DVec2::splat(radius));
        let hi = self.cell_of(p + DVec2::splat(radius));
        let cells = (hi.0 as i64 - lo.0 as i64 + 1) * (hi.1 as i64 - lo.1 as i64 + 1);
        let mut test = |slot: u32, e: &GridPoint| {
            let d2 = e.position.distance_squared(p);
            if d2 <= r2 {
                f(slot, e, d2);
            }
        };
        if cells > self.slots.len() as i64 {
            // A disc far larger than the cells: scanning everything is cheaper.
            (0..self.slots.len()).for_each(|i| test(i as u32, &self.point(i)));
            return;
        }
        for cx in lo.0..=hi.0 {
            for cy in lo.1..=hi.1 {
                self.for_each_in_cell((cx, cy), &mut test);
            }
        }
    }
}

const EMPTY: GridEntry = GridEntry { position: DVec2::ZERO, velocity: DVec2::ZERO, id: VehicleId(0), index: 0 };

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of a fixed pseudo-random sequence in a square of side `side` [m].
    fn points(n: usize, side: f64) -> Vec<GridEntry> {
        let mut next = crate::world::random::draws(0x9e37_79b9_7f4a_7c15);
        (0..n)
            .map(|i| GridEntry {
                position: DVec2::new(next() * side - 0.5 * side, next() * side - 0.5 * side),
                velocity: DVec2::ZERO,
                id: VehicleId(i as i32),
                index: i as u32,
            })
            .collect()
    }

    /// Everything a rebuild writes, for comparing two grids.
    #[allow(clippy::type_complexity)]
    fn layout(
        grid: &SpatialGrid,
    ) -> (Vec<(u32, bool, (i32, i32))>, Vec<GridEntry>, Vec<f64>, Vec<f64>, Vec<(i32, i32)>) {
        let buckets = grid.buckets.iter().map(|b| (b.start, b.mixed, b.cell)).collect();
        assert_eq!(grid.ids, grid.slots.iter().map(|e| e.id).collect::<Vec<_>>());
        assert_eq!(grid.indices, grid.slots.iter().map(|e| e.index).collect::<Vec<_>>());
        (buckets, grid.slots.clone(), grid.xs.clone(), grid.ys.clone(), grid.cells.clone())
    }

    #[test]
    fn a_reused_grid_lays_out_what_a_fresh_one_does_each_entry_in_its_cells_bucket_in_order() {
        // Hash collisions (few cells over many buckets and many entries a cell), an empty grid,
        // and a grid that shrinks after a larger one: the columns are not cleared, so left-overs
        // must not show.
        let mut reused = SpatialGrid::default();
        for (n, side, cell) in
            [(5000, 2000.0, 10.0), (3000, 400.0, 25.0), (0, 1.0, 1.0), (2500, 100.0, 3.0), (7, 50.0, 5.0)]
        {
            let entries = points(n, side);
            let mut single = SpatialGrid::default();
            single.rebuild(cell, entries.iter().copied());
            reused.rebuild(cell, entries.iter().copied());
            assert_eq!(layout(&reused), layout(&single), "{n} entries");
            assert_eq!(reused.mask, single.mask);
            // The layout a query reads: every entry in its own cell's bucket, in entry order.
            let mut seen = 0;
            for b in 0..single.buckets.len() - 1 {
                let (start, end) = (single.buckets[b].start as usize, single.buckets[b + 1].start as usize);
                let slots = &single.slots[start..end];
                assert!(slots.windows(2).all(|w| w[0].index < w[1].index));
                for e in slots {
                    assert_eq!(bucket_of(single.cell_of(e.position), single.mask), b);
                }
                seen += slots.len();
            }
            assert_eq!(seen, n);
        }
    }

    #[test]
    fn a_rebuild_on_several_threads_lays_out_what_one_thread_does() {
        // Collisions (many entries in few cells over many buckets), fewer entries than threads,
        // an empty grid, and a reused grid that shrinks and grows between thread counts.
        let mut reused = SpatialGrid::default();
        let mut mixed_seen = false;
        for threads in [2, 3, 1, 4, 2] {
            for (n, side, cell) in
                [(5000, 2000.0, 10.0), (3000, 400.0, 25.0), (0, 1.0, 1.0), (2, 50.0, 5.0), (2500, 100.0, 3.0)]
            {
                let entries = points(n, side);
                let mut single = SpatialGrid::default();
                single.rebuild(cell, entries.iter().copied());
                mixed_seen |= single.buckets.iter().any(|b| b.mixed);
                reused.rebuild_on(Parallelism::split(threads), cell, n, |i| entries[i]);
                assert_eq!(layout(&reused), layout(&single), "{n} entries, {threads} threads");
                assert_eq!((reused.mask, reused.cell), (single.mask, single.cell));
            }
        }
        assert!(mixed_seen, "no bucket was shared by two cells: the mixed flags went untested");
    }

    #[test]
    fn queries_find_what_a_scan_of_every_entry_finds_with_and_without_hash_collisions() {
        let mut mixed_seen = false;
        // Few entries over many cells (buckets shared by cells), and many over few.
        for (n, side, cell) in [(40, 2000.0, 10.0), (64, 500.0, 3.0), (3000, 400.0, 25.0), (1, 10.0, 1.0)] {
            let entries = points(n, side);
            let mut grid = SpatialGrid::default();
            grid.rebuild(cell, entries.iter().copied());
            mixed_seen |= grid.buckets.iter().any(|b| b.mixed);
            assert_eq!(grid.len(), n);
            for (k, centre) in points(50, side).iter().enumerate() {
                let radius = [0.0, 0.5 * cell, cell, 3.3 * cell, side][k % 5];
                let mut got = Vec::new();
                grid.for_each_within(centre.position, radius, |slot, e, d2| {
                    let whole = grid.get(slot);
                    assert_eq!((whole.position, whole.id, whole.index), (e.position, e.id, e.index));
                    assert_eq!(d2, e.position.distance_squared(centre.position));
                    got.push(e.index);
                });
                got.sort_unstable();
                let want: Vec<u32> = entries
                    .iter()
                    .filter(|e| e.position.distance_squared(centre.position) <= radius * radius)
                    .map(|e| e.index)
                    .collect();
                assert_eq!(got, want, "n {n}, radius {radius}");
                // What is gathered around the centre's cell, tested by the vector pass, is the
                // same, less the vehicle excluded.
                let exclude = VehicleId(k as i32 % 7);
                let mut around = Candidates::default();
                grid.gather_around(grid.cell_of(centre.position), radius, &mut around);
                let (mut marks, mut slots) = (Vec::new(), Vec::new());
                around.within(centre.position, radius, exclude, &mut marks, &mut slots);
                let mut near: Vec<u32> = slots.iter().map(|&slot| grid.index_of(slot)).collect();
                near.sort_unstable();
                let want_near: Vec<u32> = want.iter().copied().filter(|&i| entries[i as usize].id != exclude).collect();
                assert_eq!(near, want_near, "n {n}, radius {radius}");
                // Each cell holds exactly the entries that lie in it.
                let c = grid.cell_of(centre.position);
                let mut in_cell = Vec::new();
                grid.for_each_in_cell(c, |_, e| in_cell.push(e.index));
                in_cell.sort_unstable();
                let want: Vec<u32> =
                    entries.iter().filter(|e| grid.cell_of(e.position) == c).map(|e| e.index).collect();
                assert_eq!(in_cell, want);
                // Gathering the cell appends the same entries, whole, after what was there.
                let mut gathered = Candidates::default();
                grid.gather_all(&mut gathered);
                assert_eq!(gathered.len(), n);
                grid.gather_cell(c, &mut gathered);
                let mut got: Vec<u32> = (n..gathered.len())
                    .map(|k| {
                        let e = grid.get(gathered.slots[k]);
                        assert_eq!(
                            (e.position.x, e.position.y, e.id),
                            (gathered.xs[k], gathered.ys[k], gathered.ids[k])
                        );
                        e.index
                    })
                    .collect();
                got.sort_unstable();
                assert_eq!(got, want);
                // A block of cells gathers what its cells gather one by one.
                let (mut block, mut one_by_one) = (Candidates::default(), Candidates::default());
                let (xs, ys) = (c.0 - 2..=c.0 + 1, c.1 - 3..=c.1 + 2);
                grid.gather_cells(xs.clone(), ys.clone(), &mut block);
                for x in xs {
                    for y in ys.clone() {
                        grid.gather_cell((x, y), &mut one_by_one);
                    }
                }
                let sorted = |c: &Candidates| {
                    let mut v: Vec<(u32, u64, u64, i32)> =
                        (0..c.len()).map(|k| (c.slots[k], c.xs[k].to_bits(), c.ys[k].to_bits(), c.ids[k].0)).collect();
                    v.sort_unstable();
                    v
                };
                assert_eq!(sorted(&block), sorted(&one_by_one));
            }
        }
        assert!(mixed_seen, "no bucket was shared by two cells: the collision path went untested");
    }
}
