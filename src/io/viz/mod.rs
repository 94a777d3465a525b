//! The 2015 visualisation datagram over UDP: encoder (with a backward-compatible split of big
//! frames), decoder, reassembler, sender and receiver.
//!
//! # Format (as the 2015 tools spoke it)
//! One UDP datagram per frame, ASCII:
//! `<counter>#id=<id>;x=<x>;y=<y>;yaw=<deg>;class_name=<Class>!id=...`
//! - `counter`: a non-negative integer, 0 for the first frame, +1 per frame;
//! - after `#`, one record per vehicle, records separated by `!`; an empty body means "no vehicles";
//! - a record is `;`-separated `key=value` fields: `id` (integer), `x`, `y` \[m\], `yaw` \[degrees\],
//!   `class_name` (text without `#`, `!`, `;`, `=`).
//!
//! A receiver drops a datagram whose counter is not newer than the last one it accepted.
//! The 2015 receiver read one datagram into a 4096-byte buffer ([`MAX_DATAGRAM_LEN`]).
//!
//! # Split extension (big frames)
//! When a frame does not fit in [`MAX_DATAGRAM_LEN`] bytes, the encoder splits its vehicles over
//! several datagrams ("parts"), each at most 4096 bytes and each a complete, valid 2015 datagram:
//! - every part carries the **same** counter, the frame's counter;
//! - the first record of every part gets two extra trailing fields, `part=<i>` (0-based) and
//!   `parts=<n>` (the number of parts of the frame), e.g.
//!   `17#id=0;x=1.000;y=2.000;yaw=90.00;class_name=Truck;part=0;parts=3!id=1;...`.
//!
//! Why it is backward compatible: a 2015 receiver splits on `#`, `!`, `;` and `=` and reads the
//! keys it knows, so it ignores the two extra integer fields; it accepts the first part it sees of
//! a frame (its counter is new) and drops the other parts as stale (same counter), so it shows the
//! first part of every frame, steadily, instead of flickering between parts. A new receiver
//! ([`VizReassembler`]) recognises `part`/`parts`, does not treat parts of the frame it is
//! assembling as stale, and delivers the frame once all its parts have arrived. A frame that fits
//! in one datagram is sent exactly as in 2015, without the extra fields. Unknown keys are ignored
//! by the decoder, so later extensions stay compatible too.
//!
//! # Lights extension (our format only)
//! Traffic-light states travel in datagrams of their own, sent just before the frame they
//! belong to: `L<counter>#<junction>=<state>;<junction>=<state>...`, e.g. `L17#1=GGgrrr;2=rrrGGg`
//! (junction ids and link order as `smlworld map info` lists them, one signal character per
//! link), with the counter of that frame, split over several datagrams of at most
//! [`MAX_DATAGRAM_LEN`] bytes when needed (each complete on its own: a receiver merges them by
//! junction id). A new receiver ([`VizReassembler`]) keeps the latest state of every junction and
//! hands it out with every frame ([`VizFrame::lights`]). Why it is backward compatible: an older
//! receiver reads `L17` as a counter that is not a number and drops the datagram as undecodable
//! (counted, logged at debug level), so it goes on showing the vehicles; the vehicle datagrams
//! are unchanged. Only [`StreamFormat::Smlworld`] streams send them (never the 2015 format).
//!
//! Which class names and reference point a stream carries: [`format`](mod@format) (ours by default, the
//! 2015 viewers' with `--stream-format 2015`).
//!
//! Layout: [`codec`] (datagram text encoding and decoding, the stream's errors), [`reassembly`]
//! (stale counters and split frames -> whole frames), [`sockets`] (UDP sender and receiver
//! thread). Everything is re-exported here.

pub mod codec;
pub mod format;
pub mod reassembly;
pub mod sockets;

pub use codec::{
    LIGHTS_PREFIX, MAX_CLASS_NAME_LEN, MAX_DATAGRAM_LEN, MAX_PARTS, PART_KEY, PARTS_KEY, VizDatagram, VizEncoder,
    VizError, VizLight, VizPart, VizVehicle, decode_datagram, decode_lights, encode_frame, encode_lights,
    is_lights_datagram,
};
pub use format::{REAR_AXLE_FROM_REAR, StreamFormat, class_name_2015, viewer_body, viewer_footprint};
pub use reassembly::{
    MAX_LIGHTS, MAX_VEHICLES_PER_DATAGRAM, MAX_VEHICLES_PER_FRAME, RESTART_AFTER, VizFrame, VizReassembler, VizStats,
};
pub use sockets::{DEFAULT_VIZ_ADDR, DEFAULT_VIZ_RATE_HZ, RECV_BUFFER_LEN, VizReceiver, VizSender, VizSenderConfig};
