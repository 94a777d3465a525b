//! `smlworld view --frames DIR` without a display: it says so and writes the streamed scene as
//! PNG frames, vehicles where the view puts them (pixel = centre + 8 px/m * position, y up).

mod view_support;

use std::net::{Ipv4Addr, UdpSocket};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use view_support::{CAR, Car, ChildGuard, TRUCK, count_colour, free_udp_port, send_scene, temp_dir};

#[test]
fn without_a_display_the_viewer_writes_frames() {
    let addr = free_udp_port();
    let dir = temp_dir("view_frames");
    let log = dir.join("viewer.log");
    let viewer = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["view", "--listen", &addr.to_string(), "--width", "320", "--height", "240"])
        .args(["--pixels-per-meter", "8", "--center", "0,0", "--duration", "120", "--frames"])
        .arg(dir.join("frames"))
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).expect("log file"))
        .spawn()
        .expect("start smlworld view");
    let mut viewer = ChildGuard(viewer);

    // Truck at (10, 0) m -> pixel (160 + 80, 120) = (240, 120); car at (-10, 5) m -> (80, 80).
    let scene: [Car; 2] = [(0, 10.0, 0.0, 90.0, "Truck"), (-1, -10.0, 5.0, 0.0, "Car")];
    let sender = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind sender");
    let deadline = Instant::now() + Duration::from_secs(90);
    let mut counter = 0;
    let found = loop {
        send_scene(&sender, addr, counter, &scene);
        counter += 1;
        let newest = std::fs::read_dir(dir.join("frames"))
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "png"))
            .max();
        if let Some(path) = newest
            && let Ok(img) = image::open(&path)
        {
            break Some(img.to_rgb8());
        }
        if let Ok(Some(status)) = viewer.0.try_wait() {
            panic!("the viewer exited ({status}): {}", std::fs::read_to_string(&log).unwrap_or_default());
        }
        if Instant::now() > deadline {
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let img = found
        .unwrap_or_else(|| panic!("no frame written in 90 s: {}", std::fs::read_to_string(&log).unwrap_or_default()));
    assert_eq!(img.dimensions(), (320, 240));
    let pixel = |x: i64, y: i64| (x >= 0 && y >= 0 && x < 320 && y < 240).then(|| img.get_pixel(x as u32, y as u32).0);
    assert!(count_colour(pixel, 240.0, 120.0, 3, TRUCK) >= 10, "no truck at (240, 120)");
    assert!(count_colour(pixel, 80.0, 80.0, 3, CAR) >= 10, "no car at (80, 80)");
    // Nothing of either colour where no vehicle is.
    assert_eq!(count_colour(pixel, 160.0, 200.0, 6, TRUCK) + count_colour(pixel, 160.0, 200.0, 6, CAR), 0);
    let said = std::fs::read_to_string(&log).unwrap_or_default();
    assert!(said.contains("no display") && said.contains("DISPLAY is not set"), "the viewer must say why: {said}");
    drop(viewer);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn without_a_display_or_frames_the_viewer_fails_clearly() {
    let addr = free_udp_port();
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["view", "--listen", &addr.to_string(), "--width", "64", "--height", "48", "--duration", "30"])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("run smlworld view");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no display") && err.contains("--frames DIR"), "{err}");
}

/// Issue 10: `--frame-rate` caps the frames written: a 50 Hz stream for 3 s at `--frame-rate 2`
/// writes about 6 frames, not 150.
#[test]
fn view_frame_rate_caps_the_frames_written() {
    let addr = free_udp_port();
    let dir = temp_dir("view_frame_rate");
    let viewer = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["view", "--listen", &addr.to_string(), "--width", "64", "--height", "48", "--frame-rate", "2"])
        .args(["--duration", "30", "--frames"])
        .arg(dir.join("frames"))
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start smlworld view");
    let viewer = ChildGuard(viewer);
    let scene: [Car; 1] = [(0, 0.0, 0.0, 0.0, "Car")];
    let sender = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind sender");
    let count = || std::fs::read_dir(dir.join("frames")).into_iter().flatten().flatten().count();
    // Wait for the first frame (the renderer may take a while to start), then stream 3 s at 50 Hz.
    let deadline = Instant::now() + Duration::from_secs(25);
    let mut counter = 0;
    while count() == 0 && Instant::now() < deadline {
        send_scene(&sender, addr, counter, &scene);
        counter += 1;
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(count() > 0, "no frame written");
    for _ in 0..150 {
        send_scene(&sender, addr, counter, &scene);
        counter += 1;
        std::thread::sleep(Duration::from_millis(20));
    }
    drop(viewer);
    let n = count();
    let _ = std::fs::remove_dir_all(&dir);
    assert!((3..=10).contains(&n), "{n} frames for about 3 s at --frame-rate 2");
}
