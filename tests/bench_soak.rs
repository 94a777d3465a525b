//! The memory of `smlworld bench`'s process: `--soak` (issue 24) samples it over wall time, flat
//! after the warm-up (the suite runs a few seconds; the README gives the hour-long figure); the
//! heap is on transparent huge pages where the kernel gives them on request (issue 25).

use std::process::Command;

#[test]
fn a_short_soak_samples_memory_and_stays_flat() {
    // On 4 KiB pages: this soak's heap is about 17 MB, so on 2 MiB huge pages one page the heap
    // first touches late (a few kB past a boundary) reads as 12 % growth (seen once in a suite
    // run under load: 17.0 MB for 3 s, then 19.0 MB at the last sample), while on 4 KiB pages
    // the same run settles within 0.4 %. The hour-long figure in the README is on huge pages.
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["bench", "--soak", "4", "--sample-every", "0.5", "--vehicles", "300", "--threads", "1"])
        .env("SMLWORLD_HUGE_PAGES", "0")
        .env_remove("GLIBC_TUNABLES")
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
    assert!(replaced >= 15 && replaced.is_multiple_of(15), "{replaced} vehicles replaced, in rounds of 15");
    let growth = report["growth"].as_f64().unwrap();
    assert!(growth <= 0.05 && report["flat"] == true, "memory grew {:.1} % after the warm-up: {rss:?}", growth * 100.0);
    assert_eq!(err.lines().filter(|l| l.starts_with("soak ")).count(), samples.len(), "one progress line per sample");
}

/// `huge_pages_mb` of a 3,000-vehicle bench (a heap of a few huge pages), with `SMLWORLD_HUGE_PAGES`
/// set to `switch` or left out.
fn huge_pages_mb(switch: Option<&str>) -> f64 {
    let mut command = Command::new(env!("CARGO_BIN_EXE_smlworld"));
    command.args(["bench", "--vehicles", "3000", "--duration", "1", "--threads", "1"]);
    command.env_remove("GLIBC_TUNABLES").env_remove("SMLWORLD_HUGE_PAGES");
    if let Some(value) = switch {
        command.env("SMLWORLD_HUGE_PAGES", value);
    }
    let out = command.output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON report on stdout");
    report["huge_pages_mb"].as_f64().expect("huge_pages_mb (Linux)")
}

#[test]
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn the_heap_is_on_huge_pages_where_the_kernel_gives_them_on_request_unless_turned_off() {
    let mode = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled").unwrap_or_default();
    let (on, off) = (huge_pages_mb(None), huge_pages_mb(Some("0")));
    if mode.contains("[madvise]") {
        // smlworld restarted itself with glibc's malloc asking for them.
        assert!(on >= 2.0, "{on} MB on huge pages in the {mode:?} mode");
        assert_eq!(off, 0.0, "SMLWORLD_HUGE_PAGES=0 asked for none");
    } else if mode.contains("[never]") || mode.is_empty() {
        assert_eq!((on, off), (0.0, 0.0), "no huge pages to be had: {mode:?}");
    }
    // `[always]`: the kernel's choice, with or without the restart; both were measured above.
}
