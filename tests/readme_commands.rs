//! The README's commands as a new user copies them (issue 10).

/// The README's platoon GIF command must last past the leader's braking (`dip.at` in the
/// scenario) and its recovery, or the GIF shows nothing happen.
#[test]
fn readme_platoon_command_covers_the_braking() {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    let line = readme
        .lines()
        .find(|l| l.starts_with("smlworld run scenarios/platoon_brake.toml"))
        .expect("README has the platoon command");
    let words: Vec<&str> = line.split_whitespace().collect();
    let duration: f64 = words[words.iter().position(|w| *w == "--duration").expect("--duration") + 1].parse().unwrap();
    let scenario =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/platoon_brake.toml")).unwrap();
    let dip = scenario.split("dip = { at = ").nth(1).expect("the leader has a dip");
    let at: f64 = dip.split([',', ' ']).next().unwrap().parse().unwrap();
    let hold: f64 = dip.split("hold = ").nth(1).unwrap().split([' ', '}']).next().unwrap().parse().unwrap();
    assert!(duration >= at + hold + 5.0, "README runs {duration} s, the leader brakes at {at} s and holds {hold} s");
}
