//! `vkrt bench history` and `vkrt bench compare` as a user runs them: a run at tiny sizes
//! appends one well-formed line to the history it is given (never the repository's), every
//! metric present (the ray-query include's too), with the validation layer silent; compare flags a regression of a run made from it and passes
//! an improvement; a missing file, a malformed line and a history without an earlier run of
//! the device are clear errors.

mod common;

use std::path::{Path, PathBuf};

use common::{checkout, no_gpu_allowed, vkrt, vkrt_command};
use serde_json::Value;

fn temp_file(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vkrt-history-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join("history.jsonl")
}

fn path_str(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `vkrt bench history` at tiny sizes on a 2 K icosphere (VKRT_MESH unset), appending to
/// `file`, with `extra` arguments; `None` where it failed and no device is allowed.
fn history_run(file: &Path, extra: &[&str]) -> Option<std::process::Output> {
    let mut args = vec![
        "bench",
        "history",
        "--icosphere",
        "2000",
        "--size",
        "16",
        "--scan-n",
        "65536",
        "--reps",
        "1",
        "--file",
        path_str(file),
    ];
    args.extend_from_slice(extra);
    if !std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "0") {
        args.push("--validate");
    }
    let out = vkrt_command()
        .current_dir(checkout())
        .env_remove("VKRT_MESH")
        .args(&args)
        .output()
        .expect("run vkrt");
    if !out.status.success() && no_gpu_allowed() {
        return None;
    }
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "vkrt bench history: {err}");
    assert!(!err.contains("validation:"), "validation messages:\n{err}");
    Some(out)
}

/// `vkrt bench compare --file FILE` with `extra`.
fn compare(file: &Path, extra: &[&str]) -> (bool, String, String) {
    let mut args = vec!["bench", "compare", "--file", path_str(file)];
    args.extend_from_slice(extra);
    let out = vkrt(&args);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `run` with every time and ratio multiplied by `factor` (the baseline unchanged), a
/// minute later.
fn scaled(run: &Value, factor: f64) -> Value {
    let mut run = run.clone();
    for m in run["metrics"].as_object_mut().unwrap().values_mut() {
        for key in ["ms", "ratio"] {
            let x = m[key].as_f64().unwrap();
            m[key] = Value::from(x * factor);
        }
    }
    run["date"] = Value::from("2100-01-01T00:01:00Z");
    run
}

fn write_lines(file: &Path, lines: &[&Value]) {
    let text: String = lines.iter().map(|v| format!("{v}\n")).collect();
    std::fs::write(file, text).unwrap();
}

#[test]
fn a_run_appends_one_well_formed_line_and_compare_judges_the_next() {
    let file = temp_file("run");
    std::fs::remove_file(&file).ok();
    let Some(_) = history_run(&file, &[]) else {
        return;
    };
    let text = std::fs::read_to_string(&file).unwrap();
    assert_eq!(text.lines().count(), 1, "{text}");
    let run: Value = serde_json::from_str(text.lines().next().unwrap()).unwrap();
    assert_eq!(run["schema"], 1);
    for key in ["date", "device", "driver"] {
        assert!(
            run[key].as_str().is_some_and(|s| !s.is_empty()),
            "{key}: {run}"
        );
    }
    assert_eq!(run["set"]["scene"], "icosphere2k");
    assert_eq!(run["set"]["rays"], 16 * 16);
    let copy_ms = run["copy"]["ms"].as_f64().unwrap();
    assert!(copy_ms > 0.0 && copy_ms.is_finite(), "{run}");
    let metrics = run["metrics"].as_object().unwrap();
    let mut expected = vec![
        "build.kdtree",
        "build.lbvh",
        "build.ploc",
        "scan.u32",
        "trace.best",
        "trace.kdtree",
        "trace.lbvh/stack",
        "trace.lbvh/wide",
        "trace.ploc/bitstack",
        "trace.sah-bvh/stack",
    ];
    // The ray-query include's closest hit (examples/ray_queries/closest_hit.comp, compiled
    // with glslc, which `./x setup` installs), and the driver's where it has ray query.
    expected.push("query.include");
    let driver = metrics.contains_key("trace.driver");
    if driver {
        expected.extend([
            "trace.best_over_driver",
            "query.driver",
            "query.include_over_driver",
        ]);
    }
    for name in expected {
        let m = &metrics
            .get(name)
            .unwrap_or_else(|| panic!("{name} missing: {run}"));
        let (ms, base, ratio) = (
            m["ms"].as_f64().unwrap(),
            m["baseline_ms"].as_f64().unwrap(),
            m["ratio"].as_f64().unwrap(),
        );
        assert!(ms > 0.0 && base > 0.0 && ratio.is_finite(), "{name}: {m}");
        assert!((ratio - ms / base).abs() <= 1e-9 * ratio, "{name}: {m}");
    }
    let best = metrics["trace.best"]["ms"].as_f64().unwrap();
    for (name, m) in metrics.iter().filter(|(n, _)| n.starts_with("trace.")) {
        if name != "trace.driver" {
            assert!(m["ms"].as_f64().unwrap() >= best, "{name} beats trace.best");
        }
    }

    // One run only: nothing to compare with.
    let (ok, _, err) = compare(&file, &[]);
    assert!(!ok && err.contains("no earlier run"), "{err}");

    // 50 % worse everywhere: a regression at the default 25 %, none at 60 %.
    let worse = scaled(&run, 1.5);
    write_lines(&file, &[&run, &worse]);
    let (ok, out, err) = compare(&file, &[]);
    assert!(!ok, "{out}");
    assert!(
        out.contains("REGRESSION") && err.contains("scan.u32"),
        "{out}\n{err}"
    );
    assert!(compare(&file, &["--threshold", "60"]).0);

    // Every ratio 50 % higher with the same times (a baseline that measured faster): no
    // regression.
    let mut shifted = run.clone();
    for m in shifted["metrics"].as_object_mut().unwrap().values_mut() {
        let r = m["ratio"].as_f64().unwrap();
        m["ratio"] = Value::from(r * 1.5);
    }
    write_lines(&file, &[&run, &shifted]);
    let (ok, out, err) = compare(&file, &[]);
    assert!(ok && !out.contains("REGRESSION"), "{out}\n{err}");

    // Better everywhere passes, and --json names each change.
    let better = scaled(&run, 0.5);
    write_lines(&file, &[&run, &better]);
    let (ok, out, err) = compare(&file, &["--json"]);
    assert!(ok, "{err}");
    let cmp: Value = serde_json::from_str(&out).unwrap();
    let changes = cmp["changes"].as_array().unwrap();
    assert_eq!(changes.len(), metrics.len());
    for c in changes {
        assert!((c["change"].as_f64().unwrap() + 0.5).abs() < 1e-9, "{c}");
        assert!((c["ms_change"].as_f64().unwrap() + 0.5).abs() < 1e-9, "{c}");
        assert_eq!(c["regressed"], false);
    }
}

#[test]
fn a_query_shader_that_cannot_be_read_leaves_its_metrics_out_and_says_why() {
    let file = temp_file("no-query");
    std::fs::remove_file(&file).ok();
    let missing = std::env::temp_dir().join("vkrt-history-no-such-shader.comp");
    let Some(out) = history_run(&file, &["--query-shader", path_str(&missing)]) else {
        return;
    };
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no query.* metrics") && err.contains("cannot read the shader"),
        "{err}"
    );
    let text = std::fs::read_to_string(&file).unwrap();
    let run: Value = serde_json::from_str(text.lines().next().unwrap()).unwrap();
    let metrics = run["metrics"].as_object().unwrap();
    assert!(metrics.contains_key("trace.best"), "{run}");
    assert!(!metrics.keys().any(|k| k.starts_with("query.")), "{run}");
}

#[test]
fn compare_errors_clearly_on_bad_input() {
    let file = temp_file("bad");
    std::fs::remove_file(&file).ok();
    let (ok, _, err) = compare(&file, &[]);
    assert!(!ok && err.contains("cannot read the history"), "{err}");

    std::fs::write(&file, "\n").unwrap();
    let (ok, _, err) = compare(&file, &[]);
    assert!(!ok && err.contains("holds no run"), "{err}");

    let run = serde_json::json!({
        "schema": 1, "date": "2100-01-01T00:00:00Z", "commit": null,
        "device": "a", "driver": "d",
        "set": {"scene": "s", "triangles": 1, "rays": 1,
                "options": {"size": 1, "scan_n": 32, "reps": 1}},
        "copy": {"kernel": "k", "bytes": 128, "ms": 1.0},
        "metrics": {"scan.u32": {"ms": 2.0, "baseline_ms": 1.0, "ratio": 2.0}}
    });
    std::fs::write(&file, format!("{run}\nnot json\n")).unwrap();
    let (ok, _, err) = compare(&file, &[]);
    assert!(
        !ok && err.contains("line 2 is not a benchmark run"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    let mut other = run.clone();
    other["device"] = Value::from("b");
    write_lines(&file, &[&run, &other]);
    let (ok, _, err) = compare(&file, &[]);
    assert!(
        !ok && err.contains("no earlier run of the same set on b"),
        "{err}"
    );

    write_lines(&file, &[&run, &run]);
    assert!(compare(&file, &[]).0);
    let (ok, _, err) = compare(&file, &["--threshold=-1"]);
    assert!(!ok && err.contains("--threshold"), "{err}");
}
