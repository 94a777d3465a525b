//! The spatial grid and what is built over it, shared by the sensors and the V2V rounds.
//!
//! [`spatial`]: a uniform spatial hash grid rebuilt once per tick, O(N) to build and
//! O(neighbours) per query; [`candidates`]: the candidates a query gathers, in arrays for the
//! vector units; `lists`: the Verlet neighbour lists the sensors build over the grid and the
//! wifi round reads; [`pass`]: loop bodies compiled for AVX2 where the processor has it.

pub mod candidates;
pub(crate) mod lists;
pub mod pass;
pub mod spatial;

pub use candidates::Candidates;
pub(crate) use candidates::within_reach;
#[cfg(target_arch = "x86_64")]
pub use pass::with_avx2;
pub use pass::{Pass, pack, vectorised};
pub use spatial::{GridEntry, GridPoint, SpatialGrid};
