//! Atomic outputs everywhere (issue 24): images, `.meta`, maps, GIFs and figures are written
//! aside and renamed into place, with their parent folders created; a command that fails keeps
//! the good file that was there.

use std::path::{Path, PathBuf};
use std::process::Command;

fn smlworld(args: &[&str]) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().unwrap();
    (o.status.success(), format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)))
}

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

const MAP: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/maps/intersection3.osm");
const SCENARIO: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/highway.toml");

#[test]
fn map_generate_and_render_create_missing_folders_and_leave_no_temporary_file() {
    let dir = scratch("atomic_folders");
    let osm = dir.join("new/maps/ring.osm");
    let (ok, log) = smlworld(&["map", "generate", "ring", "--out", osm.to_str().unwrap()]);
    assert!(ok, "{log}");
    assert!(std::fs::read_to_string(&osm).unwrap().trim_end().ends_with("</osm>"));
    assert_eq!(files_in(osm.parent().unwrap()), ["ring.osm"]);

    let png = dir.join("new/images/i.png");
    let (ok, log) =
        smlworld(&["map", "render", MAP, "--out", png.to_str().unwrap(), "--width", "80", "--height", "60"]);
    assert!(ok, "{log}");
    assert_eq!(files_in(png.parent().unwrap()), ["i.meta", "i.png"]);
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
}

#[test]
fn a_bad_map_generate_keeps_the_map_that_was_there() {
    let dir = scratch("atomic_generate");
    let osm = dir.join("ring.osm");
    std::fs::write(&osm, "good map\n").unwrap();
    let (ok, log) = smlworld(&["map", "generate", "ring", "--lanes", "0", "--out", osm.to_str().unwrap()]);
    assert!(!ok, "zero lanes must be refused: {log}");
    assert_eq!(std::fs::read_to_string(&osm).unwrap(), "good map\n");
    assert_eq!(files_in(&dir), ["ring.osm"]);
}

#[test]
fn a_run_failing_after_its_gif_began_keeps_the_earlier_gif() {
    let dir = scratch("atomic_gif");
    let (gif, frames, out) = (dir.join("run.gif"), dir.join("frames"), dir.join("out"));
    std::fs::write(&gif, "earlier GIF").unwrap();
    // The third frame's file name is taken by a folder: the run fails after its GIF has begun.
    std::fs::create_dir_all(frames.join("frame_000002.png")).unwrap();
    let (ok, log) = smlworld(&[
        "run",
        SCENARIO,
        "--duration",
        "1",
        "--out",
        out.to_str().unwrap(),
        "--gif",
        gif.to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--width",
        "64",
        "--height",
        "64",
    ]);
    assert!(!ok, "the run should fail on the frame it cannot write:\n{log}");
    assert_eq!(std::fs::read_to_string(&gif).unwrap(), "earlier GIF");
    assert_eq!(files_in(&dir), ["frames", "out", "run.gif"], "no temporary GIF left");
}

#[test]
fn gif_and_figures_go_into_folders_that_did_not_exist() {
    let dir = scratch("atomic_gif_folders");
    let out = dir.join("out");
    let gif = dir.join("a/b/run.gif");
    let (ok, log) = smlworld(&[
        "run",
        SCENARIO,
        "--duration",
        "1",
        "--out",
        out.to_str().unwrap(),
        "--gif",
        gif.to_str().unwrap(),
        "--width",
        "64",
        "--height",
        "64",
    ]);
    assert!(ok, "{log}");
    let bytes = std::fs::read(&gif).unwrap();
    assert!(bytes.starts_with(b"GIF89a") && bytes.ends_with(&[0x3b]), "a whole GIF");
    assert_eq!(files_in(gif.parent().unwrap()), ["run.gif"]);

    let figures = dir.join("c/d");
    let (ok, log) = smlworld(&["plot", out.to_str().unwrap(), "--out", figures.to_str().unwrap()]);
    assert!(ok, "{log}");
    let names = files_in(&figures);
    assert!(names.contains(&"speed.png".to_string()) && names.contains(&"speed.svg".to_string()), "{names:?}");
    assert!(names.iter().all(|n| !n.contains("partial")), "{names:?}");
}

/// `map render` writes an image and its `.meta`; when either cannot be written the command fails
/// and both earlier files stay as they were (neither is replaced alone).
#[test]
fn a_failing_map_render_keeps_the_earlier_image_and_meta() {
    let render = |png: &Path| {
        smlworld(&["map", "render", MAP, "--out", png.to_str().unwrap(), "--width", "80", "--height", "60"])
    };
    // The image cannot be written: its temporary file's name is taken by a folder.
    let dir = scratch("atomic_render_image");
    let png = dir.join("i.png");
    std::fs::write(&png, "earlier image").unwrap();
    std::fs::write(dir.join("i.meta"), "earlier meta").unwrap();
    std::fs::create_dir(dir.join(".i.partial.png")).unwrap();
    let (ok, log) = render(&png);
    assert!(!ok, "the image cannot be written:\n{log}");
    assert!(log.contains("i.png"), "the error names the file:\n{log}");
    assert_eq!(std::fs::read_to_string(&png).unwrap(), "earlier image");
    assert_eq!(std::fs::read_to_string(dir.join("i.meta")).unwrap(), "earlier meta");

    // The `.meta` cannot be written (a folder has its name): the image is not replaced either.
    let dir = scratch("atomic_render_meta");
    let png = dir.join("i.png");
    std::fs::write(&png, "earlier image").unwrap();
    std::fs::create_dir(dir.join("i.meta")).unwrap();
    let (ok, log) = render(&png);
    assert!(!ok, "the .meta cannot be written:\n{log}");
    assert!(log.contains("i.meta"), "the error names the file:\n{log}");
    assert!(std::fs::read(&png).unwrap() == b"earlier image", "the image was replaced alone");
    assert_eq!(files_in(&dir), ["i.meta", "i.png"], "no temporary file left");
}

/// A short run to replay (`dir/run`).
fn run_to_replay(dir: &Path) -> PathBuf {
    let out = dir.join("run");
    let (ok, log) = smlworld(&["run", SCENARIO, "--duration", "2", "--out", out.to_str().unwrap()]);
    assert!(ok, "{log}");
    out
}

/// `smlworld replay RUN ARGS... --width 64 --height 64`: small frames, quick to draw.
fn replay_64(run: &Path, args: &[&str]) -> (bool, String) {
    let mut all = vec!["replay", run.to_str().unwrap()];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--width", "64", "--height", "64"]);
    smlworld(&all)
}

#[test]
fn a_replay_failing_after_its_gif_began_keeps_the_earlier_gif() {
    let dir = scratch("atomic_replay_gif");
    let run = run_to_replay(&dir);
    let (gif, frames) = (dir.join("replay.gif"), dir.join("frames"));
    std::fs::write(&gif, "earlier GIF").unwrap();
    // The third frame's file name is taken by a folder: the replay fails after its GIF has begun.
    std::fs::create_dir_all(frames.join("frame_000002.png")).unwrap();
    let (ok, log) = replay_64(&run, &["--gif", gif.to_str().unwrap(), "--frames", frames.to_str().unwrap()]);
    assert!(!ok, "the replay should fail on the frame it cannot write:\n{log}");
    assert!(log.contains("frame_000002.png"), "the error names the file:\n{log}");
    assert_eq!(std::fs::read_to_string(&gif).unwrap(), "earlier GIF");
    assert_eq!(files_in(&dir), ["frames", "replay.gif", "run"], "no temporary GIF left");
}

#[test]
fn a_replay_failing_on_a_frame_keeps_that_frames_earlier_file() {
    let dir = scratch("atomic_replay_frames");
    let run = run_to_replay(&dir);
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    std::fs::write(frames.join("frame_000001.png"), "earlier frame").unwrap();
    // The second frame's temporary file cannot be created: a folder has its name.
    std::fs::create_dir(frames.join(".frame_000001.partial.png")).unwrap();
    let (ok, log) = replay_64(&run, &["--frames", frames.to_str().unwrap()]);
    assert!(!ok, "the replay should fail on the frame it cannot write:\n{log}");
    assert!(log.contains("frame_000001.png"), "the error names the file:\n{log}");
    assert_eq!(std::fs::read_to_string(frames.join("frame_000001.png")).unwrap(), "earlier frame");
    assert_eq!(files_in(&frames), [".frame_000001.partial.png", "frame_000000.png", "frame_000001.png"]);
    assert!(std::fs::read(frames.join("frame_000000.png")).unwrap().starts_with(b"\x89PNG"), "frame 0 is whole");
}
