//! `smlworld view` for real under Xvfb: start a virtual X server on a free display, open the
//! viewer with the ring map as background, stream a known scene, screenshot the root window
//! with `xwd`, and check the vehicles are drawn where the view puts them; then move them and
//! check the window follows. Fails (never skips) when Xvfb or xwd is missing: `scripts/test.sh`
//! installs them (Debian packages `xvfb` and `x11-apps`).

mod view_support;
mod xvfb_support;

use std::net::{Ipv4Addr, UdpSocket};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use view_support::{CAR, Car, ChildGuard, TRUCK, count_colour, free_udp_port, send_scene, temp_dir};
use xvfb_support::start_xvfb;

const W: i64 = 640;
const H: i64 = 480;
/// View scale [px/m] and centre (0, 0): pixel = (W/2 + 3 x, H/2 - 3 y).
const PPM: f64 = 3.0;

fn to_pixel(x: f64, y: f64) -> (f64, f64) {
    (W as f64 / 2.0 + PPM * x, H as f64 / 2.0 - PPM * y)
}

/// A screenshot of the root window: width, height and 0xRRGGBB pixels.
struct Shot {
    width: i64,
    height: i64,
    pixels: Vec<[u8; 3]>,
}

impl Shot {
    fn pixel(&self, x: i64, y: i64) -> Option<[u8; 3]> {
        (x >= 0 && y >= 0 && x < self.width && y < self.height).then(|| self.pixels[(y * self.width + x) as usize])
    }
}

/// Parse an XWD file (X Window Dump, version 7): a header of big-endian u32 fields, the window
/// name, `ncolors` 12-byte colour entries, then a ZPixmap of 32-bit pixels in the header's byte
/// order, channels picked out by the header's masks.
fn parse_xwd(data: &[u8]) -> Shot {
    let field = |i: usize| u32::from_be_bytes(data[4 * i..4 * i + 4].try_into().expect("4 bytes"));
    assert!(data.len() >= 100, "XWD too short");
    let (header_size, version, format) = (field(0) as usize, field(1), field(2));
    assert_eq!(version, 7, "XWD version");
    assert_eq!(format, 2, "ZPixmap expected");
    let (width, height) = (field(4) as i64, field(5) as i64);
    let byte_order = field(7);
    let bits_per_pixel = field(11);
    assert_eq!(bits_per_pixel, 32, "32-bit pixels expected (Xvfb depth 24)");
    let bytes_per_line = field(12) as usize;
    let masks = [field(14), field(15), field(16)];
    let ncolors = field(19) as usize;
    let start = header_size + 12 * ncolors;
    assert!(data.len() >= start + bytes_per_line * height as usize, "XWD pixel data truncated");
    let mut pixels = Vec::with_capacity((width * height) as usize);
    for y in 0..height as usize {
        for x in 0..width as usize {
            let at = start + y * bytes_per_line + 4 * x;
            let b: [u8; 4] = data[at..at + 4].try_into().expect("4 bytes");
            let v = if byte_order == 0 { u32::from_le_bytes(b) } else { u32::from_be_bytes(b) };
            pixels.push(masks.map(|m| ((v & m) >> m.trailing_zeros()) as u8));
        }
    }
    Shot { width, height, pixels }
}

fn screenshot(display: &str) -> Shot {
    let out = Command::new("xwd")
        .args(["-root", "-silent", "-display", display])
        .output()
        .unwrap_or_else(|e| panic!("cannot run xwd ({e}): install it with `apt-get install x11-apps` (.ci/run does)"));
    assert!(out.status.success(), "xwd failed: {}", String::from_utf8_lossy(&out.stderr));
    parse_xwd(&out.stdout)
}

/// Whether the screenshot shows the truck and the car of `scene` at their pixels.
fn shows(shot: &Shot, scene: &[Car; 2]) -> bool {
    let (tx, ty) = to_pixel(scene[0].1, scene[0].2);
    let (cx, cy) = to_pixel(scene[1].1, scene[1].2);
    // At 3 px/m a car is 12 x 5 px, partly windows: a few body pixels near its centre suffice.
    count_colour(|x, y| shot.pixel(x, y), tx, ty, 2, TRUCK) >= 6
        && count_colour(|x, y| shot.pixel(x, y), cx, cy, 3, CAR) >= 3
}

#[test]
fn the_viewer_window_shows_the_streamed_vehicles_under_xvfb() {
    let dir = temp_dir("view_xvfb");
    let (_xvfb, display) = start_xvfb(&dir);
    let addr = free_udp_port();
    let map = concat!(env!("CARGO_MANIFEST_DIR"), "/maps/highway_ring.osm");
    let log = dir.join("viewer.log");
    let viewer = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["view", "--listen", &addr.to_string(), "--map", map, "--width", "640", "--height", "480"])
        .args(["--pixels-per-meter", "3", "--center", "0,0", "--duration", "170"])
        .env("DISPLAY", &display)
        .env_remove("WAYLAND_DISPLAY")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).expect("log file"))
        .spawn()
        .expect("start smlworld view");
    let mut viewer = ChildGuard(viewer);
    let sender = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind sender");
    let log_text = || std::fs::read_to_string(&log).unwrap_or_default();

    // A truck on the right lane (radius 60 m) heading north, a car on the left lane heading
    // south; then both moved a quarter turn on.
    let first: [Car; 2] = [(0, 60.0, 0.0, 90.0, "Truck"), (-1, -52.0, 0.0, 270.0, "Car")];
    let second: [Car; 2] = [(0, 0.0, 60.0, 180.0, "Truck"), (-1, 0.0, -52.0, 0.0, "Car")];
    let mut counter = 0;
    for scene in [&first, &second] {
        let deadline = Instant::now() + Duration::from_secs(60);
        let shot = loop {
            for _ in 0..5 {
                send_scene(&sender, addr, counter, scene);
                counter += 1;
                std::thread::sleep(Duration::from_millis(40));
            }
            if let Ok(Some(status)) = viewer.0.try_wait() {
                panic!("the viewer exited ({status}): {}", log_text());
            }
            let shot = screenshot(&display);
            if shows(&shot, scene) || Instant::now() > deadline {
                break shot;
            }
        };
        assert!(shows(&shot, scene), "the window does not show {scene:?} after 60 s; viewer log: {}", log_text());
        // The map is drawn behind: the road between the vehicles is grey asphalt, not forest.
        let (rx, ry) = to_pixel(0.0, -60.0 + 4.0 * f64::from(scene == &second));
        let road = shot.pixel(rx.round() as i64, ry.round() as i64).expect("inside the screen");
        assert!(road[0].abs_diff(road[1]) < 25 && road[1].abs_diff(road[2]) < 25, "no road at ({rx}, {ry}): {road:?}");
    }
    // The vehicles left their first places.
    let shot = screenshot(&display);
    let (tx, ty) = to_pixel(60.0, 0.0);
    assert_eq!(count_colour(|x, y| shot.pixel(x, y), tx, ty, 2, TRUCK), 0, "the truck is still drawn at its old place");
    drop(viewer);
    let _ = std::fs::remove_dir_all(&dir);
}
