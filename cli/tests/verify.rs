//! `vkrt verify`'s checks, run here as the command with validation on: no required check may
//! fail on the drivers CI runs (the driver's own hard cases are reported, not required), the
//! report holds every group, and its JSON and exit status say so. One run: the command is
//! `verify::run` on a context of its own, so running it in-process as well would check the
//! same thing twice.

mod common;

#[test]
fn the_command_passes_every_check_and_prints_its_report() {
    let _turn = common::vulkan_turn();
    let validate = !std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "0");
    let mut args = vec!["verify", "--quick", "--json"];
    if validate {
        args.push("--validate");
    }
    let out = common::vkrt(&args);
    let stdout = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() && common::no_gpu_allowed() && stdout.is_empty() {
        return;
    }
    let report: serde_json::Value = serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("{e}: {stdout}\n{}", String::from_utf8_lossy(&out.stderr)));
    let failures: Vec<String> = report["groups"]
        .as_object()
        .into_iter()
        .flatten()
        .flat_map(|(group, g)| {
            g["failures"]
                .as_array()
                .into_iter()
                .flatten()
                .map(move |f| format!("{group}: {f}"))
        })
        .collect();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(report["device"].is_string() && report["driver"].is_string());
    assert_eq!(report["failed"], 0, "{}", failures.join("\n"));
    assert!(report["checks"].as_u64().unwrap() > 200, "{report}");
    let groups = &report["groups"];
    for group in [
        "rounding",
        "primitives",
        "builders",
        "walks",
        "instances",
        "hard cases",
    ] {
        assert!(groups[group].is_object(), "no {group} checks");
    }
    // Every structure and walk against brute force, both tests, both queries, two scenes.
    assert_eq!(groups["walks"]["checks"], 10 * 2 * 2 * 2);
    assert_eq!(groups["walks"]["failed"], 0);
    // Boxes at 5 or 6 sizes; 4 kinds of bottom level × 2 tests × 2 queries.
    assert!(groups["instances"]["checks"].as_u64().unwrap() >= 5 + 4 * 2 * 2);
    // The validation layer was on and stayed silent (a check of its own).
    if validate {
        assert_eq!(
            groups["validation"]["failed"], 0,
            "{}",
            groups["validation"]
        );
    }
}

/// A device that does not exist: a clear error and a non-zero exit, no report.
#[test]
fn an_unknown_device_is_a_clear_error() {
    let _turn = common::vulkan_turn();
    let out = common::vkrt(&["verify", "--quick", "--device", "no such device anywhere"]);
    assert!(!out.status.success());
    assert!(out.stdout.is_empty());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no such device anywhere"));
}
