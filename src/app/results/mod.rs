//! What a run leaves behind and what reads it afterwards: the trajectory log written while it
//! runs, `smlworld replay` (frames and GIFs from `trajectories.csv`) and `smlworld plot`.

pub mod foxglove;
pub mod foxglove_encode;
pub mod foxglove_tick;
pub mod lights;
pub mod mcap_file;
pub mod output;
pub mod plot;
pub mod replay;
pub mod ros2;
pub mod snapshot;
