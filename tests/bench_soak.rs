//! `smlworld bench --soak` (issue 24): memory sampled over wall time, flat after the warm-up.
//! The suite runs a few seconds; the README gives the hour-long figure.

use std::process::Command;

#[test]
fn a_short_soak_samples_memory_and_stays_flat() {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["bench", "--soak", "4", "--sample-every", "0.5", "--vehicles", "300", "--threads", "1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON report on stdout");
    let samples = report["samples"].as_array().expect("samples");
    assert!((8..=10).contains(&samples.len()), "a sample every 0.5 s for 4 s: {}", samples.len());
    let rss: Vec<f64> = samples.iter().map(|s| s["rss_mb"].as_f64().unwrap()).collect();
    assert!(rss.iter().all(|&r| r > 1.0), "resident memory is measured: {rss:?}");
    let sim: Vec<f64> = samples.iter().map(|s| s["sim_s"].as_f64().unwrap()).collect();
    assert!(sim.windows(2).all(|w| w[1] > w[0]), "the simulation advances between samples: {sim:?}");
    assert_eq!(report["vehicles"], 300);
    // Lane changes and traffic churn: 5 % of the vehicles replaced every 10 s of sim time.
    let replaced = report["vehicles_replaced"].as_u64().expect("vehicles_replaced");
    assert!(replaced >= 15 && replaced % 15 == 0, "{replaced} vehicles replaced, in rounds of 15");
    let growth = report["growth"].as_f64().unwrap();
    assert!(growth <= 0.05 && report["flat"] == true, "memory grew {:.1} % after the warm-up: {rss:?}", growth * 100.0);
    assert_eq!(err.lines().filter(|l| l.starts_with("soak ")).count(), samples.len(), "one progress line per sample");
}
