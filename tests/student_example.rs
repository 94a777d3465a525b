//! The student example (`examples/student_controller.rs`) compiled into this test: its plugin
//! registers `my_cautious`, and the same controller keeps its gap on the kinematic model as on
//! the acceleration model, because it writes an acceleration demand and not a command.

#[allow(dead_code)] // main() is the example's own entry point
#[path = "../examples/student_controller.rs"]
mod student;

use std::path::Path;

use smlworld::prelude::*;

fn min_gap_of_follower(model: &str) -> f64 {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(manifest.join("scenarios/student.toml")).expect("shipped scenario");
    let text =
        text.replace("model = { type = \"acceleration\" }      #", &format!("model = {{ type = \"{model}\" }} #"));
    assert!(text.contains(&format!("type = \"{model}\" }} #")), "the follower's model line was found");
    let mut b = SimBuilder::new();
    b.add_plugin(student::CautiousPlugin);
    assert!(b.controllers().contains("my_cautious"));
    let scenario = Scenario::parse_str_with(&text, &manifest.join("scenarios/student.toml"), b.controllers())
        .expect("the registered controller is accepted");
    let out = std::env::temp_dir().join(format!("smlworld-student-example-{model}-{}", std::process::id()));
    let options = RunOptions { progress: false, ..RunOptions::default() }.out(&out).plugin(student::CautiousPlugin);
    let summary = run_scenario(scenario, options).expect("run");
    let _ = std::fs::remove_dir_all(&out);
    let metrics = summary.metrics.expect("metrics");
    assert_eq!(metrics.collision_count, 0);
    metrics.followers.iter().find(|f| f.id == VehicleId(-2)).expect("-2 follows").min_gap
}

#[test]
fn the_controller_keeps_its_gap_on_both_models() {
    for model in ["acceleration", "kinematic"] {
        let gap = min_gap_of_follower(model);
        assert!(gap > 19.0 && gap < 28.0, "{model} model: smallest gap {gap} m for a 25 m gap");
    }
}

#[test]
fn a_bad_gap_is_refused_with_its_key() {
    let text = "map = \"../maps/highway_ring.osm\"\n[[vehicles]]\nid = -1\nroute = { loop = \"right_lane_node\" }\n\
                controller = { type = \"my_cautious\", gap = -3.0 }\n";
    let mut b = SimBuilder::new();
    b.add_plugin(student::CautiousPlugin);
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let e = Scenario::parse_str_with(text, &manifest.join("scenarios/x.toml"), b.controllers())
        .expect_err("negative gap")
        .to_string();
    assert!(e.contains("controller.gap") && e.contains("-3"), "{e}");
}
