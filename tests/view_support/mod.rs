//! Helpers of the viewer tests: child processes that die with the test, a 2015 stream sender
//! written from the format (not with our encoder), pixel colour checks.
#![allow(dead_code)]

use std::net::{Ipv4Addr, SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::process::Child;

/// Kills and reaps the child when dropped, so a failing test leaves no process behind.
pub struct ChildGuard(pub Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A free loopback UDP port (bound and released: the viewer binds it right after).
pub fn free_udp_port() -> SocketAddr {
    let s = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind an ephemeral UDP port");
    s.local_addr().expect("local address")
}

/// A fresh temporary folder for this test.
pub fn temp_dir(name: &str) -> PathBuf {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    let dir = std::env::temp_dir().join(format!("smlworld_{name}_{}_{nanos}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("create temp dir");
    dir
}

/// One vehicle of a scene: id, x [m], y [m], yaw [deg], class.
pub type Car = (i32, f64, f64, f64, &'static str);

/// Send one 2015 datagram `<counter>#id=..;x=..;y=..;yaw=..;class_name=..!...` to `to`.
pub fn send_scene(socket: &UdpSocket, to: SocketAddr, counter: u64, scene: &[Car]) {
    let body: Vec<String> = scene
        .iter()
        .map(|(id, x, y, yaw, class)| format!("id={id};x={x};y={y};yaw={yaw};class_name={class}"))
        .collect();
    let datagram = format!("{counter}#{}", body.join("!"));
    socket.send_to(datagram.as_bytes(), to).expect("send datagram");
}

/// Truck and car body colours of the renderer (sRGB), as the rendering issue fixed them.
pub const TRUCK: [u8; 3] = [242, 128, 24];
/// Car body colour.
pub const CAR: [u8; 3] = [40, 116, 230];

/// How many pixels within `radius` px of (`cx`, `cy`) have `colour` (each channel within 40:
/// anti-aliasing and sRGB rounding move edges, not body centres, by more than a few levels).
pub fn count_colour(
    pixel: impl Fn(i64, i64) -> Option<[u8; 3]>,
    cx: f64,
    cy: f64,
    radius: i64,
    colour: [u8; 3],
) -> usize {
    let (cx, cy) = (cx.round() as i64, cy.round() as i64);
    let mut n = 0;
    for y in cy - radius..=cy + radius {
        for x in cx - radius..=cx + radius {
            if let Some(p) = pixel(x, y)
                && p.iter().zip(colour).all(|(a, b)| (i16::from(*a) - i16::from(b)).abs() <= 40)
            {
                n += 1;
            }
        }
    }
    n
}
