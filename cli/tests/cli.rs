//! The `vkrt` binary as a user runs it.

mod common;

use common::{no_gpu_allowed, vkrt, vkrt_ok};

#[test]
fn info_json_has_the_documented_keys() {
    let Some(out) = vkrt_ok(&["info", "--json"]) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in [
        "device",
        "driver",
        "api_version",
        "subgroup_size",
        "subgroup_ops",
        "max_storage_buffer_range",
        "max_shared_memory",
        "timestamp_period_ns",
    ] {
        assert!(v.get(key).is_some(), "missing key {key} in {v}");
    }
    // The walk and the nodes it reads follow the device's measured fact, unless the
    // environment names a walk.
    if std::env::var_os("VKRT_TRAVERSAL").is_none() {
        let wide = v["wide_walks"].as_bool().unwrap();
        assert_eq!(v["bvh_walk"], if wide { "wide" } else { "stack" }, "{v}");
        let nodes = v["bvh_nodes"].as_str().unwrap();
        assert_eq!(nodes.starts_with("4-wide"), wide, "{nodes}");
        assert_eq!(nodes.starts_with("binary"), !wide, "{nodes}");
    }
    let sg = v["subgroup_size"].as_u64().unwrap();
    assert!(sg.is_power_of_two() && sg >= 4, "{v}");
    let ops: Vec<&str> = v["subgroup_ops"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o.as_str().unwrap())
        .collect();
    for op in [
        "basic",
        "arithmetic",
        "ballot",
        "shuffle",
        "shuffle_relative",
    ] {
        assert!(ops.contains(&op), "{ops:?}");
    }
}

#[test]
fn bench_copy_writes_a_perfetto_trace() {
    let dir = std::env::temp_dir().join(format!("vkrt-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let trace = dir.join("trace.json");
    let Some(out) = vkrt_ok(&[
        "bench",
        "copy",
        "--mib",
        "2",
        "--reps",
        "1",
        "--json",
        "--profile",
        trace.to_str().unwrap(),
    ]) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let results = v["results"].as_array().unwrap();
    assert!(results.iter().any(|r| r["method"] == "vkCmdCopyBuffer"));
    assert!(results.iter().any(|r| r["method"]
        .as_str()
        .unwrap()
        .starts_with("copy_kernel.uvec4")));
    let t: serde_json::Value = serde_json::from_slice(&std::fs::read(&trace).unwrap()).unwrap();
    let events = t["traceEvents"].as_array().unwrap();
    assert!(events
        .iter()
        .any(|e| e["ph"] == "X" && e["name"] == "vkCmdCopyBuffer"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A `--profile` trace of `args`: valid JSON with a CPU and a GPU track, host spans around
/// every submission, GPU passes, and the device in its metadata.
fn profiled(args: &[&str], pass: &str) {
    let dir = std::env::temp_dir().join(format!("vkrt-cli-profile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let trace = dir.join(format!("{}.json", args[0]));
    let mut all: Vec<&str> = args.to_vec();
    all.extend(["--profile", trace.to_str().unwrap()]);
    let Some(_) = vkrt_ok(&all) else {
        return;
    };
    let t: serde_json::Value = serde_json::from_slice(&std::fs::read(&trace).unwrap()).unwrap();
    let events = t["traceEvents"].as_array().unwrap();
    let on = |tid: u64, name: &str| {
        events
            .iter()
            .any(|e| e["ph"] == "X" && e["tid"] == tid && e["name"] == name)
    };
    let gpu_tid = events
        .iter()
        .find(|e| e["ph"] == "M" && e["args"]["name"].as_str().unwrap_or("").starts_with("GPU"))
        .map(|e| e["tid"].as_u64().unwrap())
        .expect("a GPU track");
    for span in ["vkrt.record", "vkrt.submit", "vkrt.wait"] {
        assert!(
            on(1, span),
            "vkrt {}: no `{span}` on the CPU track",
            args[0]
        );
    }
    assert!(
        on(gpu_tid, pass),
        "vkrt {}: no `{pass}` on the GPU track",
        args[0]
    );
    assert!(!t["otherData"]["device"].as_str().unwrap().is_empty());
    assert!(!t["otherData"]["calibration"].as_str().unwrap().is_empty());
    std::fs::remove_file(&trace).unwrap();
}

#[test]
fn profile_is_global_and_writes_a_trace_for_build_and_render() {
    profiled(&["build", "--accel", "lbvh"], "build");
    let image = std::env::temp_dir().join(format!("vkrt-cli-profile-{}.png", std::process::id()));
    let image = image.to_str().unwrap();
    let small = ["--width", "16", "--height", "16", "--spp", "1"];
    profiled(
        &[&["render", "-o", image][..], &small].concat(),
        "render.sample",
    );
    std::fs::remove_file(image).unwrap();
}

#[test]
fn profile_stats_puts_invocations_beside_each_render_pass() {
    let image = std::env::temp_dir().join(format!("vkrt-cli-stats-{}.png", std::process::id()));
    let image = image.to_str().unwrap();
    let args = [
        "render", "-o", image, "--width", "16", "--height", "16", "--spp", "1",
    ];
    let Some(out) = vkrt_ok(&[&args[..], &["--json", "--profile-stats"]].concat()) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for pass in v["passes"].as_array().unwrap() {
        let (rays, n) = (pass["rays"].as_u64().unwrap(), pass["invocations"].as_u64());
        // Where the device counts: at least one invocation per ray the pass handled.
        if let Some(n) = n {
            assert!(n >= rays, "{pass}");
        }
    }
    let camera = &v["passes"][0];
    assert_eq!(camera["name"], "camera");
    if camera["invocations"].is_u64() {
        assert!(camera["invocations"].as_u64().unwrap() >= 256);
    }
    // Without the flag nothing is counted.
    let Some(out) = vkrt_ok(&[&args[..], &["--json"]].concat()) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["passes"][0]["invocations"].is_null());
    std::fs::remove_file(image).unwrap();
}

#[test]
fn an_unwritable_profile_path_is_an_error_and_leaves_no_file() {
    let dir = std::env::temp_dir().join(format!("vkrt-cli-missing-{}", std::process::id()));
    let trace = dir.join("sub").join("trace.json");
    let out = vkrt(&[
        "bench",
        "copy",
        "--mib",
        "1",
        "--reps",
        "1",
        "--profile",
        trace.to_str().unwrap(),
    ]);
    if no_gpu_allowed()
        && !out.status.success()
        && !String::from_utf8_lossy(&out.stderr).contains("trace.json")
    {
        return;
    }
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("trace.json"), "{err}");
    assert!(!trace.exists() && !dir.exists());
}

#[test]
fn unknown_commands_fail_with_usage() {
    let out = vkrt(&["no-such-command"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("Usage"));
}

#[test]
fn scene_summary_json_and_errors() {
    let out = vkrt(&["scene", "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in [
        "triangles",
        "spheres",
        "lights",
        "materials",
        "bounds",
        "effects",
    ] {
        assert!(v.get(key).is_some(), "missing {key} in {v}");
    }
    let effects: Vec<&str> = v["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e.as_str().unwrap())
        .collect();
    assert!(
        effects.contains(&"refraction") && effects.contains(&"reflection"),
        "{effects:?}"
    );

    let out = vkrt(&["scene", "/no/such/scene.toml"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/no/such/scene.toml"));
}

#[test]
fn every_example_scene_loads() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path
            .extension()
            .is_some_and(|e| e == "toml" || e == "obj" || e == "scn")
        {
            let out = vkrt(&["scene", path.to_str().unwrap(), "--json"]);
            assert!(
                out.status.success(),
                "{}: {}",
                path.display(),
                String::from_utf8_lossy(&out.stderr)
            );
            count += 1;
        }
    }
    assert!(count >= 10, "expected the example scenes, found {count}");
}

/// `vkrt build HOUSE --accel ACCEL --reference --json`, its report checked for `keys`
/// (`None` without a GPU).
fn build_report(accel: &str, keys: &[&str]) -> Option<serde_json::Value> {
    let house = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/house.obj");
    let out = vkrt_ok(&[
        "build",
        house.to_str().unwrap(),
        "--accel",
        accel,
        "--reference",
        "--json",
    ])?;
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in keys {
        assert!(v.get(key).is_some(), "missing {key} in {v}");
    }
    Some(v)
}

#[test]
fn build_kdtree_reports_and_equals_its_twin() {
    let keys = [
        "primitives",
        "build_ms",
        "build_ms_min",
        "build_ms_max",
        "first_build_ms",
        "reps",
        "phases",
        "levels",
        "nodes",
        "leaves",
        "max_depth",
        "sah_cost",
        "references",
        "bytes",
        "equal_to_cpu_twin",
        "cpu_twin_ms",
        "full_clip_sah_cost",
        "full_clip_ms",
        "device_bytes",
        "device_bytes_per_primitive",
    ];
    let Some(v) = build_report("kdtree", &keys) else {
        return;
    };
    assert_eq!(v["equal_to_cpu_twin"], true);
    assert_device_bytes(&v);
    assert_repeated(&v);
    assert!(v["build_ms"].as_f64().unwrap() > 0.0);
    // No warm run to report: refused.
    let out = vkrt(&["build", "--reps", "0"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--reps"));
    let out = vkrt(&["build", "--accel", "bvh"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("bvh"));
    // The default structure is the BVH: a kd-tree option without --accel kdtree is an error,
    // not silently ignored.
    let out = vkrt(&["build", "--kolodzey-termination"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--accel kdtree"));
}

/// The build time is the median of the default 3 warm builds, within their range; the
/// first is apart.
fn assert_repeated(v: &serde_json::Value) {
    assert_eq!(v["reps"], 3, "{v}");
    let f = |k: &str| v[k].as_f64().unwrap();
    assert!(
        f("build_ms_min") <= f("build_ms") && f("build_ms") <= f("build_ms_max"),
        "{v}"
    );
    assert!(f("first_build_ms") > 0.0, "{v}");
}

/// The device memory a build needed at its peak covers at least the structure, and per
/// primitive is that over the primitive count.
fn assert_device_bytes(v: &serde_json::Value) {
    let bytes = v["device_bytes"].as_u64().unwrap();
    let n = v["primitives"].as_u64().unwrap();
    assert!(bytes > v["bytes"].as_u64().unwrap(), "{v}");
    let per = v["device_bytes_per_primitive"].as_f64().unwrap();
    assert!((per - bytes as f64 / n as f64).abs() < 1e-6 * per, "{v}");
}

#[test]
fn build_gpu_bvhs_report_and_equal_their_twins() {
    let keys = [
        "kind",
        "primitives",
        "build_ms",
        "build_ms_min",
        "build_ms_max",
        "first_build_ms",
        "reps",
        "passes_ms",
        "nodes",
        "leaves",
        "sah_cost",
        "bytes",
        "equal_to_cpu_twin",
        "device_bytes",
        "device_bytes_per_primitive",
    ];
    for kind in ["lbvh", "ploc"] {
        let Some(v) = build_report(kind, &keys) else {
            return;
        };
        assert_eq!(v["kind"], kind, "{v}");
        assert_eq!(v["equal_to_cpu_twin"], true, "{v}");
        assert_device_bytes(&v);
        assert_repeated(&v);
    }
}

#[test]
fn build_sah_bvh_reports_and_equals_its_single_thread_build() {
    let keys = [
        "kind",
        "primitives",
        "build_ms",
        "build_ms_min",
        "build_ms_max",
        "first_build_ms",
        "reps",
        "threads",
        "nodes",
        "leaves",
        "max_depth",
        "sah_cost",
        "bytes",
    ];
    let Some(v) = build_report("sah-bvh", &keys) else {
        return;
    };
    assert_eq!(v["kind"], "sah_bvh");
    assert_eq!(v["equal_to_single_thread"], true);
    assert_repeated(&v);
    let (nodes, leaves) = (v["nodes"].as_u64().unwrap(), v["leaves"].as_u64().unwrap());
    assert!(leaves == nodes + 1 || (nodes, leaves) == (1, 1), "{v}");
}
