//! `vkrt verify`'s checks, run here with validation on: no required check may fail on the
//! drivers CI runs (the driver's own hard cases are reported, not required). And the
//! command: its JSON and its exit status.

mod common;

use vkrt::verify::{self, Options};

#[test]
fn every_check_passes_on_this_device() {
    let Some(ctx) = common::context() else { return };
    let report = verify::run(&ctx, &Options { quick: true }, &mut |_| {});
    let failures: Vec<String> = report
        .results
        .iter()
        .filter(|c| c.required && !c.passed)
        .map(|c| format!("{} / {}: {}", c.group, c.name, c.detail))
        .collect();
    assert!(
        failures.is_empty(),
        "{} failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert_eq!(report.failed, 0);
    for group in [
        "rounding",
        "primitives",
        "builders",
        "walks",
        "instances",
        "hard cases",
    ] {
        assert!(report.groups.contains_key(group), "no {group} checks");
    }
    // Every structure and walk against brute force, both tests, both queries, two scenes.
    assert_eq!(report.groups["walks"].checks, 10 * 2 * 2 * 2);
    // Boxes at 5 or 6 sizes; 4 kinds of bottom level × 2 tests × 2 queries.
    assert!(report.groups["instances"].checks >= 5 + 4 * 2 * 2);
    // The validation layer was on and stayed silent (a check of its own).
    if ctx.validation_enabled() {
        assert_eq!(report.groups["validation"].failed, 0);
    }
    common::assert_silent(&ctx);
}

#[test]
fn the_command_prints_its_report_and_exits_zero() {
    let _turn = common::vulkan_turn();
    let out = common::vkrt(&["verify", "--quick", "--json"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(report["device"].is_string() && report["driver"].is_string());
    assert_eq!(report["failed"], 0);
    assert!(report["checks"].as_u64().unwrap() > 200, "{report}");
    assert_eq!(report["groups"]["walks"]["failed"], 0);
    // A device that does not exist: a clear error and a non-zero exit, no report.
    let out = common::vkrt(&["verify", "--quick", "--device", "no such device anywhere"]);
    assert!(!out.status.success());
    assert!(out.stdout.is_empty());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no such device anywhere"));
}
