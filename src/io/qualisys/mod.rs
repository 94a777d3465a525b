//! Qualisys Track Manager (QTM) real-time protocol 1.11 client, as the 2015 code used it, and a
//! tracker that turns motion-capture bodies into real-vehicle states.
//!
//! # Wire format
//! TCP (default port 22224). Every packet: big-endian i32 size (the 8-byte header included),
//! big-endian i32 type ([`PacketType`]), then the payload. Commands (type 1) are ASCII text ending
//! with one NUL byte. A data packet (type 3) holds an i64 timestamp \[µs\], an i32 frame number, an
//! i32 component count, then components: i32 size (its 8-byte header included), i32 type (6 =
//! 6DOF Euler), and for 6DOF Euler an i32 body count, 4 bytes of drop-rate/out-of-sync counters
//! and per body six f32: x, y, z \[mm\], roll, pitch, yaw \[degrees\]. All integers and floats are
//! big-endian. Sizes are never trusted: a packet larger than the configured bound (default
//! [`MAX_PACKET_LEN`]) is refused before anything is allocated.
//!
//! # Session
//! The client connects, sends `Version 1.11`, then `TakeControl <password>` when a password is
//! configured (i.e. when it is not master), then `New`, then polls `GetCurrentFrame 6DEuler` at a
//! fixed rate (default 24 Hz). Bad packets are logged and dropped; a broken stream (bad size, EOF)
//! makes it reconnect after a delay. It never panics on input.
//!
//! Layout: [`wire`] (packet framing, types, parsing and encoding of data frames, bounds on size
//! fields), [`client`] (the TCP client thread and its session), [`tracker`] (bodies -> vehicle
//! states, staleness). Everything is re-exported here.

pub mod client;
pub mod tracker;
pub mod wire;

pub use client::{
    DEFAULT_POLL_RATE_HZ, DEFAULT_QTM_ADDR, DEFAULT_QTM_PORT, QtmClient, QtmClientConfig, QtmStats, TimedFrame,
};
pub use tracker::{BodyMapping, TrackedBody, Tracker, TrackerConfig};
pub use wire::{
    BODY_LEN, Body6DEuler, COMPONENT_6D_EULER, COMPONENT_6D_EULER_HEADER_LEN, DATA_HEADER_LEN, DataFrame, HEADER_LEN,
    MAX_PACKET_LEN, POLL_COMMAND, Packet, PacketDecoder, PacketType, QtmError, VERSION_COMMAND, encode_6d_euler_packet,
    encode_command, encode_packet, encode_text, parse_data, parse_data_packet,
};
