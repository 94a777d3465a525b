//! Running a scenario: scenario files, the headless and real-time runners, step-by-step
//! sessions, per-run metrics, background traffic, benchmarks and the run's summary.

pub mod bench;
pub mod bench_city;
pub mod bench_map;
pub mod bench_render;
pub mod interrupt;
pub mod metrics;
pub mod random_trips;
pub mod runner;
pub mod scenario;
pub mod session;
pub mod signals;
pub mod soak;
pub mod summary;
pub mod traffic;
pub mod trips;
