//! Bridges to the lab: UDP visualisation stream, motion capture input, real-truck output.
//!
//! Everything here is plain Rust (no ECS): the app layer wraps each bridge in a plugin that
//! copies world state in or out. Every socket binds to loopback unless the caller gives an
//! address; a bad packet is logged and dropped, never fatal.
//! - [`viz`]: the 2015 visualisation datagram over UDP (sender, receiver, split extension);
//! - [`qualisys`]: Qualisys Track Manager real-time protocol 1.11 client and body tracker;
//! - [`mock_mocap`]: a mock Qualisys server streaming scripted trajectories;
//! - [`trucks`]: one TCP server per real truck sending the 2015 status line at 20 Hz.

pub mod viz;
