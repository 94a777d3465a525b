//! A uniform spatial hash grid rebuilt once per tick: O(N) to build, O(neighbours) per query.
//!
//! Cells are squares of side `cell` [m]; cell coordinates are hashed into a power-of-two
//! number of buckets (at least the number of entries) and the entries are counting-sorted by
//! bucket, so a rebuild is O(N) with no allocation once the buffers have grown. A query visits
//! the cells its disc overlaps and accepts an entry only if it lies in the visited cell, so hash
//! collisions cost a few extra comparisons but never a duplicate.

use glam::DVec2;

use crate::world::VehicleId;

/// One vehicle in the grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridEntry {
    /// Position [m].
    pub position: DVec2,
    /// Velocity [m/s].
    pub velocity: DVec2,
    /// Vehicle id.
    pub id: VehicleId,
    /// Caller-defined index (e.g. into a list of senders).
    pub index: u32,
}

#[derive(Debug, Clone, Copy)]
struct Slot {
    entry: GridEntry,
    cell: (i32, i32),
}

/// The grid; keep one per use and call [`SpatialGrid::rebuild`] every tick.
#[derive(Debug, Clone, Default)]
pub struct SpatialGrid {
    cell: f64,
    mask: u64,
    starts: Vec<u32>,
    slots: Vec<Slot>,
    staging: Vec<Slot>,
}

fn bucket_of(cell: (i32, i32), mask: u64) -> usize {
    // The 64-bit finaliser of MurmurHash3: neighbouring cells land in unrelated buckets.
    let mut h = ((cell.0 as u32 as u64) << 32) | cell.1 as u32 as u64;
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    h ^= h >> 33;
    (h & mask) as usize
}

impl SpatialGrid {
    /// The cell holding `p`.
    pub fn cell_of(&self, p: DVec2) -> (i32, i32) {
        ((p.x / self.cell).floor() as i32, (p.y / self.cell).floor() as i32)
    }

    /// Refill the grid with `entries` using square cells of side `cell` [m] (> 0); queries are
    /// cheapest when `cell` is about the largest query radius.
    pub fn rebuild(&mut self, cell: f64, entries: impl Iterator<Item = GridEntry>) {
        self.cell = if cell.is_finite() && cell > 0.0 { cell } else { 1.0 };
        self.staging.clear();
        for entry in entries {
            let cell = self.cell_of(entry.position);
            self.staging.push(Slot { entry, cell });
        }
        let buckets = self.staging.len().max(1).next_power_of_two();
        self.mask = buckets as u64 - 1;
        self.starts.clear();
        self.starts.resize(buckets + 1, 0);
        for s in &self.staging {
            self.starts[bucket_of(s.cell, self.mask) + 1] += 1;
        }
        for b in 0..buckets {
            self.starts[b + 1] += self.starts[b];
        }
        self.slots.clear();
        self.slots.resize(self.staging.len(), Slot { entry: EMPTY, cell: (0, 0) });
        // `starts[b]` is used as the insertion cursor of bucket b, then restored.
        for s in &self.staging {
            let b = bucket_of(s.cell, self.mask);
            let at = self.starts[b] as usize;
            self.slots[at] = *s;
            self.starts[b] += 1;
        }
        for b in (1..=buckets).rev() {
            self.starts[b] = self.starts[b - 1];
        }
        self.starts[0] = 0;
    }

    /// Call `f(slot, entry)` for every entry of `cell`.
    pub fn for_each_in_cell(&self, cell: (i32, i32), mut f: impl FnMut(u32, &GridEntry)) {
        if self.slots.is_empty() {
            return;
        }
        let b = bucket_of(cell, self.mask);
        let (start, end) = (self.starts[b] as usize, self.starts[b + 1] as usize);
        for (i, s) in self.slots[start..end].iter().enumerate() {
            if s.cell == cell {
                f((start + i) as u32, &s.entry);
            }
        }
    }

    /// Side of the cells [m].
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
        self.slots.iter().map(|s| &s.entry)
    }

    /// The entry in slot `slot` (as passed to [`SpatialGrid::for_each_within`]).
    pub fn get(&self, slot: u32) -> &GridEntry {
        &self.slots[slot as usize].entry
    }

    /// Call `f(slot, entry, squared distance [m²])` with every entry within `radius` [m] of `p`
    /// (inclusive), each exactly once.
    pub fn for_each_within(&self, p: DVec2, radius: f64, mut f: impl FnMut(u32, &GridEntry, f64)) {
        if self.slots.is_empty() {
            return;
        }
        let r2 = radius * radius;
        let lo = self.cell_of(p - DVec2::splat(radius));
        let hi = self.cell_of(p + DVec2::splat(radius));
        let cells = (hi.0 as i64 - lo.0 as i64 + 1) * (hi.1 as i64 - lo.1 as i64 + 1);
        if cells > self.slots.len() as i64 {
            // A disc far larger than the cells: scanning everything is cheaper.
            for (i, s) in self.slots.iter().enumerate() {
                let d2 = s.entry.position.distance_squared(p);
                if d2 <= r2 {
                    f(i as u32, &s.entry, d2);
                }
            }
            return;
        }
        for cx in lo.0..=hi.0 {
            for cy in lo.1..=hi.1 {
                let b = bucket_of((cx, cy), self.mask);
                let (start, end) = (self.starts[b] as usize, self.starts[b + 1] as usize);
                for (i, s) in self.slots[start..end].iter().enumerate() {
                    if s.cell != (cx, cy) {
                        continue;
                    }
                    let d2 = s.entry.position.distance_squared(p);
                    if d2 <= r2 {
                        f((start + i) as u32, &s.entry, d2);
                    }
                }
            }
        }
    }
}

const EMPTY: GridEntry = GridEntry { position: DVec2::ZERO, velocity: DVec2::ZERO, id: VehicleId(0), index: 0 };
