//! `vkrt bench accuracy --quick` as a user runs it: the report folder holds an
//! `index.html` with one inline plot per group, a `report.json` whose every group has
//! points with finite numbers, a Pareto front and recommendations for every use, and the
//! images it compared; the validation layer stays silent. Bad output folders are refused
//! before the run and nothing is written or lost.

mod common;

use std::path::{Path, PathBuf};

use common::{vkrt, vkrt_ok};
use serde_json::Value;

const GROUPS: [&str; 8] = [
    "structure",
    "kd-termination",
    "bvh-leaf",
    "traversal",
    "intersector",
    "spp",
    "depth",
    "refit",
];

/// A fresh folder of this test's own, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("vkrt-accuracy-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn num(v: &Value, what: &str) -> f64 {
    let x = v
        .as_f64()
        .unwrap_or_else(|| panic!("{what} is not a number: {v}"));
    assert!(x.is_finite() && x >= 0.0, "{what} = {x}");
    x
}

/// Every number anywhere under `v` is finite (serde writes NaN and infinities as null, so
/// a null where a number belongs is caught by the explicit checks below).
fn all_finite(v: &Value, path: &str) {
    match v {
        Value::Number(n) => assert!(n.as_f64().is_some_and(f64::is_finite), "{path} = {n}"),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, x)| all_finite(x, &format!("{path}[{i}]"))),
        Value::Object(o) => o
            .iter()
            .for_each(|(k, x)| all_finite(x, &format!("{path}.{k}"))),
        _ => {}
    }
}

#[test]
fn quick_report_is_complete_and_finite() {
    let dir = TempDir::new("quick");
    let out = dir.path().join("report");
    let mut args = vec!["bench", "accuracy", "--quick", "-o", out.to_str().unwrap()];
    if !std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "0") {
        args.push("--validate");
    }
    let Some(run) = vkrt_ok(&args) else {
        return;
    };
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!err.contains("validation:"), "validation messages:\n{err}");

    let json: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    all_finite(&json, "report");
    assert!(json["quick"].as_bool().unwrap());
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    let groups = json["groups"].as_array().unwrap();
    let ids: Vec<&str> = groups.iter().map(|g| g["id"].as_str().unwrap()).collect();
    assert_eq!(ids, GROUPS);
    assert_eq!(
        html.matches("<svg").count(),
        groups.len(),
        "one plot per group"
    );
    for g in groups {
        let id = g["id"].as_str().unwrap();
        let points = g["points"].as_array().unwrap();
        assert!(points.len() >= 2, "{id}: {} points", points.len());
        for p in points {
            let what = format!("{id}/{}", p["setting"]);
            num(&p["time_ms"], &format!("{what} time_ms"));
            num(&p["error"], &format!("{what} error"));
        }
        let front = g["front"].as_array().unwrap();
        assert!(!front.is_empty(), "{id}: empty front");
        for i in front {
            assert!((i.as_u64().unwrap() as usize) < points.len());
        }
        // The fastest point of a group is always on its front.
        let fastest = (0..points.len())
            .min_by(|&a, &b| {
                points[a]["time_ms"]
                    .as_f64()
                    .unwrap()
                    .total_cmp(&points[b]["time_ms"].as_f64().unwrap())
            })
            .unwrap();
        let on_front: Vec<usize> = front.iter().map(|i| i.as_u64().unwrap() as usize).collect();
        let t = |i: usize| points[i]["time_ms"].as_f64().unwrap();
        assert!(
            on_front.iter().any(|&i| t(i) == t(fastest)),
            "{id}: the fastest setting is not on the front"
        );
    }

    // Structure settings: hard cases and traces measured; spp settings: errors fall.
    let structure = &groups[0]["points"].as_array().unwrap();
    // The driver's structures where the device has ray query, else a note that says why not.
    let driver_rows = structure
        .iter()
        .any(|p| p["setting"].as_str().unwrap().starts_with("driver"));
    let skipped = json["notes"]
        .as_array()
        .unwrap()
        .iter()
        .any(|n| n.as_str().unwrap().starts_with("driver: skipped"));
    assert!(
        driver_rows != skipped,
        "driver rows {driver_rows}, skip note {skipped}"
    );
    let kd = &structure[0];
    assert!(num(&kd["accuracy"]["hard_cases"]["rays"], "hard-case rays") > 0.0);
    assert_eq!(
        kd["accuracy"]["hit_differences"], 0,
        "the reference differs from itself"
    );
    num(&kd["costs"]["trace_ms"]["primary"], "primary trace ms");
    num(&kd["costs"]["sah_cost"], "SAH cost");
    num(&kd["costs"]["bytes"], "bytes");
    let spp = groups[5]["points"].as_array().unwrap();
    let e = |i: usize| spp[i]["error"].as_f64().unwrap();
    assert!(
        e(spp.len() - 1) < e(0),
        "more samples, larger error: {} -> {}",
        e(0),
        e(spp.len() - 1)
    );

    // A recommendation per use and group it applies to.
    let recs = json["recommendations"].as_array().unwrap();
    for use_case in [
        "interactive preview",
        "final frame",
        "physics/visibility queries",
    ] {
        assert!(
            recs.iter().any(|r| r["use_case"] == use_case),
            "no recommendation for {use_case}"
        );
    }

    // Every image the report names is there, and is a PNG.
    for scene in json["image_scenes"].as_array().unwrap() {
        png(&out, scene["reference_file"].as_str().unwrap());
    }
    for g in groups {
        for p in g["points"].as_array().unwrap() {
            for im in p["accuracy"]["images"].as_array().unwrap() {
                png(&out, im["file"].as_str().unwrap());
            }
        }
    }
}

fn png(dir: &Path, file: &str) {
    let bytes = std::fs::read(dir.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
    assert!(bytes.starts_with(b"\x89PNG"), "{file} is not a PNG");
}

#[test]
fn bad_output_folders_are_refused_before_the_run() {
    let dir = TempDir::new("bad");
    // A file where the folder should be: refused, untouched.
    let file = dir.path().join("report");
    std::fs::write(&file, b"mine").unwrap();
    let out = vkrt(&["bench", "accuracy", "--quick", "-o", file.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("report"), "{err}");
    assert_eq!(std::fs::read(&file).unwrap(), b"mine");
    // A folder of something else: refused, untouched.
    let other = dir.path().join("photos");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("cat.jpg"), b"meow").unwrap();
    let out = vkrt(&[
        "bench",
        "accuracy",
        "--quick",
        "-o",
        other.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert_eq!(std::fs::read(other.join("cat.jpg")).unwrap(), b"meow");
    assert_eq!(std::fs::read_dir(&other).unwrap().count(), 1);
    // A missing parent: refused, nothing created.
    let deep = dir.path().join("missing/report");
    let out = vkrt(&["bench", "accuracy", "--quick", "-o", deep.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(!dir.path().join("missing").exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
}
