//! Property/fuzz tests with a fixed budget (issue 15): every input decoder must return an error,
//! never panic, on mutated real input. `proptest` generates and shrinks.
//!
//! The normal suite runs a fixed number of cases per target (a few seconds in all); a developer
//! runs each target for a time budget with `SMLWORLD_FUZZ_SECS=600 cargo test --release fuzz`
//! (the cases tried are printed). A failure's shrunk input is saved under
//! `tests/fuzz-corpus/<target>/crash-*.bin`; with `SMLWORLD_FUZZ_SAVE=1` a long run also keeps
//! the first input of every distinct outcome it reached (each error kind, each kind of success:
//! the corpus) as `tests/fuzz-corpus/<target>/<outcome hash>.bin`. `fuzz_corpus_replay` runs every
//! file there in the normal suite.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestError, TestRng, TestRunner};
use smlworld::io::qualisys::{PacketDecoder, parse_data};
use smlworld::io::trucks::{Lane, TruckState, format_truck_line};
use smlworld::io::viz::decode_datagram;
use smlworld::prelude::*;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Where a target's corpus and crashes live.
fn corpus_dir(name: &str) -> PathBuf {
    root().join("tests/fuzz-corpus").join(name)
}

/// Most corpus files one run adds per target.
const CORPUS_PER_TARGET: usize = 64;

/// An outcome as a short signature: the letters of `text` (numbers, names and positions left
/// out, so one kind of error is one outcome however its values differ).
fn outcome(text: &str) -> String {
    let words: Vec<&str> = text.split(|c: char| !c.is_ascii_alphabetic()).filter(|w| w.len() > 1).take(8).collect();
    words.join(" ")
}

/// Run `target` on inputs from `strategy`: `cases` of them, or batches until
/// `SMLWORLD_FUZZ_SECS` have passed. A failure saves its shrunk input and fails the test; with
/// `SMLWORLD_FUZZ_SAVE=1` the first input of each new outcome is kept in the corpus.
fn fuzz(name: &str, cases: u32, strategy: impl Strategy<Value = Vec<u8>>, target: fn(&[u8]) -> String) {
    let budget = std::env::var("SMLWORLD_FUZZ_SECS").ok().and_then(|s| s.parse::<f64>().ok());
    let save = std::env::var("SMLWORLD_FUZZ_SAVE").is_ok_and(|v| v == "1");
    let deadline = budget.map(|s| Instant::now() + Duration::from_secs_f64(s));
    let batch = if deadline.is_some() { 256 } else { cases };
    let mut tried = 0u64;
    let outcomes: RefCell<BTreeMap<String, Vec<u8>>> = RefCell::default();
    for round in 0u64.. {
        let mut seed = [0u8; 32];
        seed[..8].copy_from_slice(&round.to_le_bytes());
        let config = Config { cases: batch, failure_persistence: None, ..Config::default() };
        let mut runner = TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &seed));
        let result = runner.run(&strategy, |input| {
            let seen = target(&input);
            let mut outcomes = outcomes.borrow_mut();
            if outcomes.len() < CORPUS_PER_TARGET {
                outcomes.entry(seen).or_insert(input);
            }
            Ok(())
        });
        tried += u64::from(batch);
        if let Err(TestError::Fail(reason, input)) = result {
            let dir = corpus_dir(name);
            std::fs::create_dir_all(&dir).unwrap();
            let file = dir.join(format!("crash-{:016x}.bin", fxhash(&input)));
            std::fs::write(&file, &input).unwrap();
            panic!("fuzz {name}: {reason}; shrunk input saved as {}", file.display());
        }
        result.unwrap();
        if deadline.is_none_or(|d| Instant::now() >= d) {
            break;
        }
    }
    let outcomes = outcomes.into_inner();
    if save {
        let dir = corpus_dir(name);
        std::fs::create_dir_all(&dir).unwrap();
        for (seen, input) in &outcomes {
            std::fs::write(dir.join(format!("{:016x}.bin", fxhash(seen.as_bytes()))), input).unwrap();
        }
    }
    eprintln!("fuzz {name}: {tried} cases, 0 crashes, {} distinct outcomes", outcomes.len());
}

fn fxhash(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(*b)).wrapping_mul(0x100_0000_01b3))
}

/// Extreme numbers a mutation writes over a number.
const EXTREMES: [&str; 12] =
    ["nan", "inf", "-inf", "-1.0", "0.0", "1e300", "-1e300", "1e-300", "-0.0", "1e308", "4294967296", "-5.0"];

/// Byte ranges of the numbers (digits, sign, dot, exponent) in `text`.
fn numbers(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < text.len() {
        let starts =
            text[i].is_ascii_digit() && (i == 0 || !(text[i - 1].is_ascii_alphanumeric() || text[i - 1] == b'_'));
        if starts {
            let s = if i > 0 && text[i - 1] == b'-' { i - 1 } else { i };
            let mut e = i;
            while e < text.len() && (text[e].is_ascii_digit() || matches!(text[e], b'.' | b'e' | b'E')) {
                e += 1;
            }
            out.push((s, e));
            i = e;
        } else {
            i += 1;
        }
    }
    out
}

/// Mutations of a real input: flip a byte, truncate, duplicate or delete a line range, or set a
/// number to an extreme value.
fn mutated(base: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let nums = numbers(&base);
    let len = base.len();
    (0u8..5, any::<prop::sample::Index>(), any::<prop::sample::Index>(), any::<u8>(), 0usize..EXTREMES.len()).prop_map(
        move |(kind, a, b, byte, extreme)| {
            let mut v = base.clone();
            let (p, q) = (a.index(len), b.index(len));
            let (lo, hi) = (p.min(q), p.max(q));
            match kind {
                0 => v[p] ^= byte.max(1),
                1 => v.truncate(p),
                2 => {
                    let copy = v[lo..hi.min(lo + 4096)].to_vec();
                    v.splice(hi..hi, copy);
                }
                3 => {
                    v.drain(lo..hi.min(lo + 4096));
                }
                _ => {
                    let (s, e) = nums[a.index(nums.len())];
                    v.splice(s..e, EXTREMES[extreme].bytes());
                }
            }
            v
        },
    )
}

fn osm_target(bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(bytes);
    match LaneletMap::parse_str(&text, Path::new("fuzz.osm")) {
        Ok(map) => {
            for l in &map.lanelets {
                let _ = l.polygon();
            }
            let warning = map.warnings.first().map_or(String::new(), |w| outcome(&w.message));
            format!("ok {} {warning}", map.lanelets.len().min(2))
        }
        Err(e) => outcome(&e.to_string()),
    }
}

#[test]
fn fuzz_osm_reader_on_mutated_map() {
    let base = std::fs::read(root().join("maps/highway_ring.osm")).unwrap();
    fuzz("osm", 48, mutated(base), osm_target);
}

/// The shipped scenarios without lab bridges (those open sockets); one is picked by the first
/// byte of the input so regression files replay.
const SCENARIOS: [&str; 5] = ["highway", "acc_highway", "intersection", "platoon_brake", "platoon_merge"];

fn scenario_target(bytes: &[u8]) -> String {
    let (which, text) = bytes.split_first().unwrap_or((&0, &[]));
    let name = SCENARIOS[usize::from(*which) % SCENARIOS.len()];
    let path = root().join(format!("scenarios/{name}.toml"));
    let text = String::from_utf8_lossy(text);
    let scenario = match Scenario::parse_str(&text, &path) {
        Ok(s) => s,
        Err(e) => return format!("{name} load {}", outcome(&e.to_string().replace(&path.display().to_string(), ""))),
    };
    let builder = match scenario.builder() {
        Ok(b) => b,
        Err(e) => return format!("{name} build {}", outcome(&e.to_string())),
    };
    let mut sim = builder.build();
    sim.run_for(0.5);
    for (id, s) in sim.states() {
        assert!(
            s.position.is_finite() && s.yaw.is_finite() && s.velocity.is_finite(),
            "{name}: vehicle {id} has a non-finite state {s:?} after a scenario that passed validation"
        );
    }
    format!("{name} ran")
}

fn scenario_inputs() -> impl Strategy<Value = Vec<u8>> {
    let per_file: Vec<_> = SCENARIOS
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let base = std::fs::read(root().join(format!("scenarios/{name}.toml"))).unwrap();
            mutated(base).prop_map(move |mut v| {
                v.insert(0, i as u8);
                v
            })
        })
        .collect();
    prop::strategy::Union::new(per_file)
}

#[test]
fn fuzz_scenario_loader_on_mutated_scenarios() {
    fuzz("scenario", 40, scenario_inputs(), scenario_target);
}

/// Every number of every shipped scenario set to each extreme value in turn: exhaustive, not
/// random (a few hundred loads).
#[test]
fn fuzz_scenario_every_number_extreme() {
    for (i, name) in SCENARIOS.iter().enumerate() {
        let base = std::fs::read(root().join(format!("scenarios/{name}.toml"))).unwrap();
        for (s, e) in numbers(&base) {
            for x in ["nan", "inf", "-1.0", "0.0", "1e300"] {
                let mut v = base.clone();
                v.splice(s..e, x.bytes());
                v.insert(0, i as u8);
                let run = std::panic::catch_unwind(|| scenario_target(&v));
                assert!(run.is_ok(), "{name}: the number at byte {s} set to {x} panicked");
            }
        }
    }
}

fn viz_target(bytes: &[u8]) -> String {
    match decode_datagram(bytes) {
        Ok(d) => format!("ok {} {}", d.part.is_some(), d.vehicles.len().min(2)),
        Err(e) => outcome(&format!("{e:?}")),
    }
}

#[test]
fn fuzz_viz_decoder() {
    let bytes = prop::collection::vec(any::<u8>(), 0..1500);
    fuzz("viz", 2000, bytes, viz_target);
}

fn qualisys_target(bytes: &[u8]) -> String {
    let data = match parse_data(bytes) {
        Ok(_) => "ok".to_string(),
        Err(e) => outcome(&format!("{e:?}")),
    };
    let mut decoder = PacketDecoder::new(1 << 16);
    let mut packets = 0;
    for chunk in bytes.chunks(97) {
        decoder.push(chunk);
        while let Some(Ok(_)) = decoder.next_packet() {
            packets += 1;
        }
    }
    format!("{data} packets {}", packets.min(2))
}

#[test]
fn fuzz_qualisys_decoder() {
    let bytes = prop::collection::vec(any::<u8>(), 0..1500);
    fuzz("qualisys", 2000, bytes, qualisys_target);
}

/// The first 73 bytes are 9 f64 and a lane; what the line encoder makes of them must be one line.
fn truck_target(bytes: &[u8]) -> String {
    let mut b = bytes.to_vec();
    b.resize(8 * 9 + 1, 0);
    let f = |i: usize| f64::from_le_bytes(b[8 * i..8 * i + 8].try_into().unwrap());
    let lane = [Lane::Left, Lane::Center, Lane::Right][usize::from(b[72]) % 3];
    let state = TruckState {
        time: f(0),
        lane,
        current_distance: f(1),
        desired_distance: f(2),
        velocity: f(3),
        x: f(4),
        y: f(5),
        yaw: f(6),
        lane_offset: f(7),
    };
    let mut line = String::new();
    format_truck_line(&mut line, i32::from_le_bytes(b[64..68].try_into().unwrap()), &state, f(8));
    assert!(line.ends_with("\r\n") && !line[..line.len() - 2].contains(['\r', '\n']), "not one line: {line:?}");
    outcome(&line.replace(|c: char| c.is_ascii_digit(), ""))
}

#[test]
fn fuzz_truck_line_encoder_extreme_states() {
    let special =
        prop::sample::select(vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, f64::MAX, f64::MIN, -0.0, 1e-310]);
    let value = prop_oneof![any::<f64>(), special];
    let bytes = (prop::collection::vec(value, 9), any::<u8>()).prop_map(|(v, lane)| {
        let mut b: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        b.push(lane);
        b
    });
    fuzz("truck_line", 2000, bytes, truck_target);
}

/// Every corpus file and saved crash replays without a panic (and the corpus is not empty:
/// a long run's findings are kept).
#[test]
fn fuzz_corpus_replay() {
    type Target = (&'static str, fn(&[u8]) -> String);
    let targets: [Target; 5] = [
        ("osm", osm_target),
        ("scenario", scenario_target),
        ("viz", viz_target),
        ("qualisys", qualisys_target),
        ("truck_line", truck_target),
    ];
    let mut replayed = 0;
    for (name, target) in targets {
        let Ok(entries) = std::fs::read_dir(corpus_dir(name)) else { continue };
        for entry in entries {
            let path = entry.unwrap().path();
            target(&std::fs::read(&path).unwrap());
            replayed += 1;
        }
    }
    assert!(replayed > 0, "tests/fuzz-corpus holds no input; run the long mode with SMLWORLD_FUZZ_SAVE=1");
}
