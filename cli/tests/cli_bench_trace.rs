//! `vkrt bench trace --quick` as a user runs it: every structure and walk in the
//! report, the driver's rows exactly where the device has ray query (else the note that
//! says why not), every number finite, vkrt's structures finding the same hits and the
//! driver within 0.1 % of them, and the validation layer silent.

mod common;

use common::vkrt_ok;
use serde_json::Value;

/// `vkrt bench trace --quick` with `extra`, with the validation layer on unless
/// VKRT_VALIDATION=0 (as for every GPU test); `None` where no device is allowed.
fn bench_trace(extra: &[&str]) -> Option<std::process::Output> {
    let mut args = vec!["bench", "trace", "--quick"];
    args.extend_from_slice(extra);
    if !std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "0") {
        args.push("--validate");
    }
    let out = vkrt_ok(&args)?;
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("validation:"), "validation messages:\n{err}");
    Some(out)
}

/// The rows every ray set has, in order, on a device with (or without) ray query.
fn expected_structures(ray_query: bool) -> Vec<&'static str> {
    let mut s = vec![
        "kdtree",
        "sah-bvh/stack",
        "sah-bvh/bitstack",
        "sah-bvh/wide",
        "lbvh/stack",
        "lbvh/bitstack",
        "lbvh/wide",
        "ploc/stack",
        "ploc/bitstack",
        "ploc/wide",
    ];
    if ray_query {
        s.extend(["driver", "driver/fast-build"]);
    }
    s.push("obvhs");
    s
}

/// The `structure` of each row, in order.
fn row_labels(rows: &[Value]) -> Vec<&str> {
    rows.iter()
        .map(|r| r["structure"].as_str().unwrap())
        .collect()
}

fn finite(v: &Value, what: &str) -> f64 {
    let x = v
        .as_f64()
        .unwrap_or_else(|| panic!("{what} is not a number: {v}"));
    assert!(x.is_finite() && x >= 0.0, "{what} = {x}");
    x
}

#[test]
fn quick_json_has_every_structure_and_agreeing_hits() {
    let Some(out) = bench_trace(&["--json"]) else {
        return;
    };
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let ray_query = v["ray_query"].as_bool().unwrap();
    let device = v["device"].as_str().unwrap();
    match v["driver_note"].as_str() {
        None => assert!(ray_query, "{v}"),
        Some(note) => {
            assert!(!ray_query);
            assert!(
                note.contains(device) && note.contains("VK_KHR_ray_query"),
                "{note}"
            );
        }
    }
    let expected = expected_structures(ray_query);
    // One row per walk, read the device's way.
    let access = v["node_access"].as_array().unwrap();
    assert_eq!(access.len(), 1, "{v}");
    let scenes = v["scenes"].as_array().unwrap();
    // The example scenes and the small icosphere.
    assert!(scenes.len() >= 12, "{} scenes", scenes.len());
    for scene in scenes {
        let name = scene["name"].as_str().unwrap();
        let spheres = scene["spheres"].as_u64().unwrap() > 0;
        let builds: Vec<&str> = scene["builds"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| {
                finite(&b["ms"], &format!("{name} build ms"));
                b["structure"].as_str().unwrap()
            })
            .collect();
        // A BVH walked wide is built for it (its wide nodes follow the build).
        let mut want_builds = vec![
            "kdtree",
            "sah-bvh",
            "sah-bvh/wide",
            "lbvh",
            "lbvh/wide",
            "ploc",
            "ploc/wide",
        ];
        if ray_query {
            want_builds.extend(["driver", "driver/fast-build"]);
        }
        want_builds.push("obvhs");
        assert_eq!(builds, want_builds, "{name}");
        let sets = scene["ray_sets"].as_array().unwrap();
        let kinds: Vec<&str> = sets.iter().map(|s| s["kind"].as_str().unwrap()).collect();
        assert_eq!(kinds, ["primary", "shadow", "mirror"], "{name}");
        for set in sets {
            let what = format!("{name} {}", set["kind"]);
            let rays = set["rays"].as_u64().unwrap() as i64;
            let rows = set["rows"].as_array().unwrap();
            assert_eq!(row_labels(rows), expected, "{what}");
            for r in rows {
                let label = format!("{what} {}", r["structure"]);
                for key in ["build_ms", "trace_ms", "mrays_per_s"] {
                    finite(&r[key], &format!("{label} {key}"));
                }
                assert_eq!(r["over_driver"].is_null(), !ray_query, "{label}");
                if ray_query {
                    finite(&r["over_driver"], &format!("{label} ×driver"));
                }
                let diff = r["hits_vs_first"].as_i64();
                match r["backend"].as_str().unwrap() {
                    // One watertight test, conservative walks: the same hits, exactly.
                    "vkrt" => {
                        assert_eq!(diff, Some(0), "{label}: {r}");
                        assert_eq!(r["node_access"], access[0], "{label}");
                    }
                    // The driver's own intersector: at most 0.1 % of the rays apart.
                    "driver" => {
                        let d = diff.unwrap().abs();
                        assert!(d * 1000 <= rays, "{label}: {d} of {rays} rays differ");
                    }
                    // obvhs sees no spheres: its hits are not compared there.
                    "cpu-peer" => {
                        assert_eq!(diff.is_none(), spheres, "{label}: {r}");
                        if spheres {
                            assert_eq!(r["note"], "triangles only", "{label}");
                        }
                    }
                    other => panic!("{label}: backend {other}"),
                }
            }
            assert_eq!(set["vkrt_hits_agree"], true, "{what}");
            if set["kind"] == "primary" {
                assert!(rows[0]["hits"].as_u64().unwrap() > 0, "{what}: no hits");
            }
        }
    }
}

#[test]
fn quick_table_has_a_block_per_scene_and_ray_set_and_the_driver_note() {
    let Some(out) = bench_trace(&["--size", "16"]) else {
        return;
    };
    let text = String::from_utf8_lossy(&out.stdout);
    let header = text.lines().filter(|l| l.starts_with("structure ")).count();
    assert_eq!(header % 3, 0, "{text}");
    assert!(header >= 36, "{header} blocks:\n{text}");
    let note = text.lines().find(|l| l.starts_with("driver: skipped — "));
    let driver_rows = text.lines().any(|l| l.starts_with("driver "));
    assert_ne!(note.is_some(), driver_rows, "{text}");
    if let Some(note) = note {
        assert!(note.contains("has no VK_KHR_ray_query"), "{note}");
    }
}

#[test]
fn both_node_accesses_give_every_walk_two_rows_with_the_same_hits() {
    let Some(out) = bench_trace(&["--size", "16", "--node-access", "both", "--json"]) else {
        return;
    };
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        v["node_access"],
        serde_json::json!(["storage", "texel"]),
        "{v}"
    );
    let ray_query = v["ray_query"].as_bool().unwrap();
    // Every vkrt walk twice, storage first; the driver's and the peer's rows once.
    let mut expected = Vec::new();
    for s in expected_structures(ray_query) {
        match s {
            "driver" | "driver/fast-build" | "obvhs" => expected.push(s.to_string()),
            walk => {
                expected.push(format!("{walk} (storage)"));
                expected.push(format!("{walk} (texel)"));
            }
        }
    }
    let mut compared = 0;
    for scene in v["scenes"].as_array().unwrap() {
        for set in scene["ray_sets"].as_array().unwrap() {
            let what = format!("{} {}", scene["name"], set["kind"]);
            let rows = set["rows"].as_array().unwrap();
            assert_eq!(row_labels(rows), expected, "{what}");
            for r in rows {
                let label = format!("{what} {}", r["structure"]);
                let name = r["structure"].as_str().unwrap();
                match r["backend"].as_str().unwrap() {
                    "vkrt" => {
                        let access = r["node_access"].as_str().unwrap();
                        assert!(name.ends_with(&format!("({access})")), "{label}");
                        // The texel row's hits, ray by ray, against the storage row's.
                        match access {
                            "texel" => {
                                assert_eq!(r["same_hits_as_storage"], true, "{label}: {r}");
                                compared += 1;
                            }
                            _ => assert!(r["same_hits_as_storage"].is_null(), "{label}"),
                        }
                        assert_eq!(r["hits_vs_first"], 0, "{label}: {r}");
                    }
                    _ => assert!(r["node_access"].is_null(), "{label}"),
                }
            }
            assert_eq!(set["vkrt_hits_agree"], true, "{what}");
        }
    }
    assert!(compared >= 12 * 3 * 10, "{compared} comparisons");
}
