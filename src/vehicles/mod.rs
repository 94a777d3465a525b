//! Controllers (path following, cruise control, ACC, platooning) as plugins, one per file.
//!
//! Each controller follows the contract documented in [`crate::app`]: systems in the
//! [`crate::sim::Control`] schedule that read state, readings, mail and route, and write
//! [`crate::world::ControlCommand`] and out-going messages.

pub mod path_following;

pub use path_following::{PathFollower, PathFollowing, PathFollowingPlugin, follow_paths};
