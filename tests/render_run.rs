//! `smlworld run --frames DIR --gif FILE`: frames at their own rate, vehicles where the
//! trajectories say, and the simulation's results unchanged by recording.

mod scratch_support;

use scratch_support::Scratch;
use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DVec2;
use smlworld::map::LaneletMap;
use smlworld::render::BirdseyeView;

fn smlworld(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().expect("runs smlworld");
    assert!(out.status.success(), "smlworld {args:?} failed: {}", String::from_utf8_lossy(&out.stderr));
}

fn tmp(name: &str) -> Scratch {
    Scratch::new("smlworld-render-run", name)
}

/// Position of every vehicle at time `t` [s], extrapolated with its velocity from its last row
/// of a trajectories.csv (t, id, x, y, yaw, vx, vy).
fn positions_at(csv: &Path, t: f64) -> Vec<(i32, DVec2)> {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut last = std::collections::BTreeMap::new();
    for line in text.lines().skip(1) {
        let f: Vec<f64> = line.split(',').take(7).map(|v| v.parse().unwrap()).collect();
        let (p, v) = (DVec2::new(f[2], f[3]), DVec2::new(f[5], f[6]));
        last.insert(f[1] as i32, p + v * (t - f[0]));
    }
    last.into_iter().collect()
}

#[test]
fn recording_writes_frames_and_gif_without_changing_results() {
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/highway.toml");
    let plain = tmp("plain");
    let rec = tmp("rec");
    let frames = rec.join("frames");
    let gif = rec.join("run.gif");
    smlworld(&["run", scenario, "--duration", "2", "--out", plain.to_str().unwrap()]);
    smlworld(&[
        "run",
        scenario,
        "--duration",
        "2",
        "--out",
        rec.to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--gif",
        gif.to_str().unwrap(),
        "--frame-rate",
        "5",
        "--width",
        "640",
        "--height",
        "360",
    ]);
    let a = std::fs::read(plain.join("trajectories.csv")).unwrap();
    let b = std::fs::read(rec.join("trajectories.csv")).unwrap();
    assert_eq!(a, b, "recording must not change the trajectories");

    // 2 s at 5 Hz: frame k at t = k / 5 Hz from t = 0 (issue 61: the first frame showed 0.2 s).
    let mut names: Vec<_> = std::fs::read_dir(&frames).unwrap().map(|e| e.unwrap().file_name()).collect();
    names.sort();
    assert_eq!(names.len(), 11, "{names:?}");
    assert_eq!(names[0], "frame_000000.png");
    let decoder =
        image::codecs::gif::GifDecoder::new(std::io::BufReader::new(std::fs::File::open(&gif).unwrap())).unwrap();
    let gif_frames = image::AnimationDecoder::into_frames(decoder).collect_frames().unwrap();
    assert_eq!(gif_frames.len(), 11);
    assert_eq!(gif_frames[0].buffer().dimensions(), (640, 360));

    // In the last frame (t = 2 s), each vehicle's centre pixel differs from the bare map, and a
    // corner far from the road equals it (same view: the whole map fitted into 640x360).
    let map_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("maps/highway_ring.osm");
    let env_png = rec.join("env.png");
    smlworld(&[
        "map",
        "render",
        map_path.to_str().unwrap(),
        "--out",
        env_png.to_str().unwrap(),
        "--width",
        "640",
        "--height",
        "360",
    ]);
    let env = image::open(&env_png).unwrap().to_rgba8();
    let last = image::open(frames.join("frame_000010.png")).unwrap().to_rgba8();
    let view = BirdseyeView::fit_map(640, 360, &LaneletMap::load(&map_path).unwrap()).unwrap();
    let positions = positions_at(&rec.join("trajectories.csv"), 2.0);
    assert_eq!(positions.len(), 12);
    for (id, p) in positions {
        let px = view.world_to_pixel(p);
        let (x, y) = (px.x.round() as u32, px.y.round() as u32);
        let (e, f) = (env.get_pixel(x, y).0, last.get_pixel(x, y).0);
        let diff: u32 = e.iter().zip(f.iter()).map(|(a, b)| a.abs_diff(*b) as u32).sum();
        assert!(diff > 30, "vehicle {id} at {p} (pixel {x},{y}) is not drawn: env {e:?} frame {f:?}");
    }
    assert_eq!(env.get_pixel(2, 2), last.get_pixel(2, 2), "the corner is bare ground in both");

    // The GIF stores only what changed between frames; composed, its last frame is the last PNG
    // frame up to palette quantisation (256 colours per frame): mean channel error below 6.
    let composed = gif_frames[10].buffer();
    let total: u64 = composed
        .pixels()
        .zip(last.pixels())
        .map(|(a, b)| a.0.iter().zip(b.0.iter()).take(3).map(|(x, y)| x.abs_diff(*y) as u64).sum::<u64>())
        .sum();
    let mean = total as f64 / (640.0 * 360.0 * 3.0);
    assert!(mean < 6.0, "GIF frame 10 differs from the PNG frame by {mean} per channel on average");
}

/// Run `scenarios/<scenario>.toml` for `duration` s writing both PNG frames and a GIF (overlay
/// on both) at `rate` Hz and `size` px into `tmp(name)`: the decoded GIF frames and the PNG
/// frames' paths in order, with the folder (removed when dropped).
fn gif_and_png_frames(
    name: &str,
    scenario: &str,
    duration: &str,
    rate: &str,
    (width, height): (&str, &str),
) -> (Scratch, Vec<image::RgbaImage>, Vec<PathBuf>) {
    use image::AnimationDecoder;
    let dir = tmp(name);
    let (frames, gif) = (dir.join("frames"), dir.join("run.gif"));
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenarios/{scenario}.toml"));
    smlworld(&[
        "run",
        scenario.to_str().unwrap(),
        "--duration",
        duration,
        "--frames",
        frames.to_str().unwrap(),
        "--gif",
        gif.to_str().unwrap(),
        "--frame-rate",
        rate,
        "--width",
        width,
        "--height",
        height,
        "--overlay",
        "--out",
        dir.join("out").to_str().unwrap(),
    ]);
    let file = std::io::BufReader::new(std::fs::File::open(&gif).unwrap());
    let decoded: Vec<image::RgbaImage> = image::codecs::gif::GifDecoder::new(file)
        .unwrap()
        .into_frames()
        .collect_frames()
        .unwrap()
        .into_iter()
        .map(|f| f.into_buffer())
        .collect();
    let mut pngs: Vec<PathBuf> = std::fs::read_dir(&frames).unwrap().map(|e| e.unwrap().path()).collect();
    pngs.sort();
    (dir, decoded, pngs)
}

/// Issue 23 item 2: every GIF frame shows what the PNG frame of the same time shows (no ghosts,
/// smears or stale pixels from frame differencing): on a run with 45 moving vehicles and the
/// overlay on both, fewer than 1 % of the channel values differ by more than 48 (the palette's
/// quantisation moves colours a little; a ghost or a stale vehicle moves whole patches).
#[test]
fn gif_frames_match_the_png_frames_of_the_same_time() {
    let (_dir, decoded, pngs) = gif_and_png_frames("gif-vs-png", "highway_traffic", "8", "2", ("320", "180"));
    assert_eq!(decoded.len(), pngs.len(), "one GIF frame per PNG frame");
    assert!(decoded.len() >= 10, "{} frames", decoded.len());
    // The first frame, and later ones after many vehicles moved (differencing errors add up).
    for k in [0, decoded.len() / 2, decoded.len() - 1] {
        let png = image::open(&pngs[k]).unwrap().to_rgba8();
        let (a, b) = (&decoded[k], &png);
        assert_eq!(a.dimensions(), b.dimensions());
        let (mut off, mut all) = (0usize, 0usize);
        for (p, q) in a.pixels().zip(b.pixels()) {
            for c in 0..3 {
                all += 1;
                off += usize::from(p.0[c].abs_diff(q.0[c]) > 48);
            }
        }
        let share = off as f64 / all as f64;
        assert!(share < 0.01, "frame {k}: {:.2} % of the channel values differ by more than 48", share * 100.0);
    }
}

/// Issue 61: frame 300 of the overtaking GIF had grey smears along the ring where labels had
/// passed, while the PNG frame of the same time was clean (each GIF frame had its own palette,
/// and pixels a label left were written back in the new palette's nearest colour). Now one
/// colour of a PNG frame is one colour of the GIF everywhere, in every frame: checked on the
/// first, mid and last frames of the overtaking run, together with a small mean error.
#[test]
fn overtaking_gif_has_no_ghost_trails() {
    let (_dir, decoded, pngs) = gif_and_png_frames("overtaking-ghosts", "overtaking", "30", "4", ("640", "360"));
    assert_eq!(decoded.len(), pngs.len(), "one GIF frame per PNG frame");
    let mut shown_as: std::collections::HashMap<[u8; 3], [u8; 3]> = std::collections::HashMap::new();
    for k in [0, decoded.len() / 2, decoded.len() - 1] {
        let png = image::open(&pngs[k]).unwrap().to_rgba8();
        let mut total = 0u64;
        for (x, y, q) in png.enumerate_pixels() {
            let p = decoded[k].get_pixel(x, y);
            let (want, got) = ([q.0[0], q.0[1], q.0[2]], [p.0[0], p.0[1], p.0[2]]);
            total += want.iter().zip(&got).map(|(a, b)| u64::from(a.abs_diff(*b))).sum::<u64>();
            let first = *shown_as.entry(want).or_insert(got);
            assert_eq!(
                first, got,
                "frame {k} pixel {x},{y}: PNG colour {want:?} shown as {got:?} here, {first:?} elsewhere (a ghost)"
            );
        }
        let mean = total as f64 / (640.0 * 360.0 * 3.0);
        assert!(mean < 4.0, "frame {k}: mean channel error {mean:.2}");
    }
}

/// Issue 61: `replay RUN --gif out.gif --follow -2` of the overtaking run wrote 459 MB silently
/// (600 frames of 1280x720, each new: the ground moves). A followed GIF takes at most 5 Hz at
/// 640 px wide unless --full-gif, and the size written is printed.
#[test]
fn a_followed_gif_stays_small_and_says_its_size() {
    let dir = tmp("follow-gif");
    let (out, gif) = (dir.join("out"), dir.join("follow.gif"));
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/overtaking.toml");
    smlworld(&["run", scenario.to_str().unwrap(), "--duration", "10", "--out", out.to_str().unwrap()]);
    let o = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["replay", out.to_str().unwrap(), "--gif", gif.to_str().unwrap(), "--follow", "-2"])
        .output()
        .expect("runs smlworld");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let bytes = std::fs::metadata(&gif).unwrap().len();
    assert!(stderr.contains(&format!("{:.1} MB)", bytes as f64 / 1e6)), "the size written is printed: {stderr}");
    let decoder =
        image::codecs::gif::GifDecoder::new(std::io::BufReader::new(std::fs::File::open(&gif).unwrap())).unwrap();
    let (w, h) = image::ImageDecoder::dimensions(&decoder);
    assert_eq!((w, h), (640, 360), "a followed GIF at most 640 px wide");
    let frames = image::AnimationDecoder::into_frames(decoder).collect_frames().unwrap();
    // 0 .. 10 s at 10 Hz drawn, every second frame kept: 0, 0.2, ..., 10 s.
    assert_eq!(frames.len(), 51, "5 Hz of 10 s from t = 0");
    assert!(bytes < 15_000_000, "{bytes} bytes for 10 s");
}

/// Issue 60 §5: `--overlay none` (a space, as other flags take their value) was refused with
/// "unexpected argument 'none'"; only `--overlay=none` worked. Both spellings now give the same
/// frames, for `none` and `all`, and they differ from each other.
#[test]
fn overlay_takes_its_value_after_a_space_or_an_equals_sign() {
    let dir = tmp("overlay-space");
    let frame = |flags: &[&str], name: &str| {
        let frames = dir.join(name);
        let mut args = vec!["run", "scenarios/highway.toml", "--duration", "0.1", "--frame-rate", "10"];
        args.extend_from_slice(&["--width", "320", "--height", "180", "--frames", frames.to_str().unwrap()]);
        let out = dir.join(format!("{name}-out"));
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        args.extend_from_slice(flags);
        smlworld(&args);
        std::fs::read(frames.join("frame_000001.png")).unwrap()
    };
    let none_space = frame(&["--overlay", "none"], "none-space");
    let none_equals = frame(&["--overlay=none"], "none-equals");
    let all_space = frame(&["--overlay", "all"], "all-space");
    let all_equals = frame(&["--overlay=all"], "all-equals");
    assert_eq!(none_space, none_equals, "--overlay none = --overlay=none");
    assert_eq!(all_space, all_equals, "--overlay all = --overlay=all");
    assert_ne!(none_space, all_space, "the overlay is drawn with all, not with none");
}

/// Decode every frame of an MP4 `--video` file (H.264 in the one track): its frames as RGBA, with
/// the track's width, height and frame rate.
fn decode_video(path: &Path) -> (Vec<image::RgbaImage>, (u16, u16), f64) {
    let bytes = std::fs::read(path).unwrap();
    let size = bytes.len() as u64;
    let mut mp4 = mp4::Mp4Reader::read_header(std::io::Cursor::new(bytes), size).unwrap();
    let (id, track) = mp4.tracks().iter().next().map(|(id, t)| (*id, t)).unwrap();
    assert_eq!(track.media_type().unwrap(), mp4::MediaType::H264);
    let (w, h, rate) = (track.width(), track.height(), track.frame_rate());
    // Annex B for the decoder: the parameter sets first, then each length-prefixed NAL unit
    // behind a start code.
    let mut annex_b = Vec::new();
    for set in [track.sequence_parameter_set().unwrap(), track.picture_parameter_set().unwrap()] {
        annex_b.extend_from_slice(&[0, 0, 0, 1]);
        annex_b.extend_from_slice(set);
    }
    let count = track.sample_count();
    let mut decoder = openh264::decoder::Decoder::new().unwrap();
    let mut frames = Vec::new();
    let mut rgba = vec![0u8; usize::from(w) * usize::from(h) * 4];
    for i in 1..=count {
        let sample = mp4.read_sample(id, i).unwrap().unwrap();
        let mut data: &[u8] = &sample.bytes;
        while data.len() >= 4 {
            let len = u32::from_be_bytes([data[0], data[1], data[2], data[3]]) as usize;
            annex_b.extend_from_slice(&[0, 0, 0, 1]);
            annex_b.extend_from_slice(&data[4..4 + len]);
            data = &data[4 + len..];
        }
        if let Some(yuv) = decoder.decode(&annex_b).unwrap() {
            yuv.write_rgba8(&mut rgba);
            frames.push(image::RgbaImage::from_raw(u32::from(w), u32::from(h), rgba.clone()).unwrap());
        }
        annex_b.clear();
    }
    for yuv in decoder.flush_remaining().unwrap() {
        yuv.write_rgba8(&mut rgba);
        frames.push(image::RgbaImage::from_raw(u32::from(w), u32::from(h), rgba.clone()).unwrap());
    }
    (frames, (w, h), rate)
}

/// Mean absolute difference per colour channel of two images of one size.
fn mean_channel_error(a: &image::RgbaImage, b: &image::RgbaImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let total: u64 =
        a.pixels().zip(b.pixels()).map(|(p, q)| (0..3).map(|c| u64::from(p.0[c].abs_diff(q.0[c]))).sum::<u64>()).sum();
    total as f64 / (f64::from(a.width()) * f64::from(a.height()) * 3.0)
}

/// Issue 61: a followed view as a GIF is either huge (every frame new: 459 MB for 60 s) or thinned
/// (5 Hz, 640 px). `--video FILE.mp4` keeps every frame at full size in a few MB: on the
/// overtaking run followed from vehicle -2, the MP4 holds one H.264 frame per PNG frame (10 Hz,
/// from t = 0), each showing what the PNG of its time shows (H.264 is lossy, and the tree texture
/// of a moving ground the costliest to keep: a mean error of 5-6 per channel, a third of that
/// against the PNG a second later), and the size written is printed.
#[test]
fn a_followed_video_keeps_every_frame_and_matches_the_pngs() {
    let dir = tmp("follow-video");
    let (out, video, frames) = (dir.join("out"), dir.join("follow.mp4"), dir.join("frames"));
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/overtaking.toml");
    smlworld(&["run", scenario.to_str().unwrap(), "--duration", "10", "--out", out.to_str().unwrap()]);
    let o = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["replay", out.to_str().unwrap(), "--video", video.to_str().unwrap(), "--follow", "-2"])
        .args(["--frames", frames.to_str().unwrap(), "--overlay", "all", "--width", "640", "--height", "360"])
        .output()
        .expect("runs smlworld");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let bytes = std::fs::metadata(&video).unwrap().len();
    assert!(stderr.contains(&format!("{:.1} MB)", bytes as f64 / 1e6)), "the size written is printed: {stderr}");
    let (decoded, size, rate) = decode_video(&video);
    assert_eq!(size, (640, 360));
    assert!((rate - 10.0).abs() < 1e-6, "{rate} Hz");
    let mut pngs: Vec<PathBuf> = std::fs::read_dir(&frames).unwrap().map(|e| e.unwrap().path()).collect();
    pngs.sort();
    assert_eq!(pngs.len(), 101, "0 .. 10 s at 10 Hz");
    assert_eq!(decoded.len(), pngs.len(), "one video frame per PNG frame, none skipped");
    for k in [0, 50, 100] {
        let png = image::open(&pngs[k]).unwrap().to_rgba8();
        let same = mean_channel_error(&decoded[k], &png);
        assert!(same < 8.0, "frame {k}: mean channel error {same:.2} against its PNG");
        let other = image::open(&pngs[(k + 10) % pngs.len()]).unwrap().to_rgba8();
        let shifted = mean_channel_error(&decoded[k], &other);
        assert!(shifted > 2.0 * same, "frame {k}: {shifted:.2} against the PNG 1 s away, {same:.2} against its own");
    }
    assert!(bytes < 3_000_000, "{bytes} bytes for 10 s at 640x360");
}

/// `--video` names an MP4: another extension is refused before anything runs, naming the option.
#[test]
fn a_video_without_the_mp4_extension_is_refused() {
    let dir = tmp("video-ext");
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/overtaking.toml");
    let o = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", scenario.to_str().unwrap(), "--duration", "1", "--out", dir.join("out").to_str().unwrap()])
        .args(["--video", dir.join("v.webm").to_str().unwrap()])
        .output()
        .expect("runs smlworld");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("--video") && stderr.contains(".mp4"), "{stderr}");
    assert!(!dir.join("v.webm").exists());
}
