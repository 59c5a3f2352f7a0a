//! `vkrt bench accuracy`'s report folder and page on a synthetic report (no GPU): the page's
//! plots and escaping, the folder's files, and that only a previous report is replaced.

use std::path::{Path, PathBuf};

use vkrt_cli::accuracy::pareto::{fill_fronts, recommend, USES};
use vkrt_cli::accuracy::report::{html, plot_svg, write};
use vkrt_cli::accuracy::{
    Accuracy, AccuracyReport, Costs, HardCases, ImageError, ImageFile, ImageScene, KnobGroup,
    Point, RayCountsInfo, TraceMs,
};

const SCENES: [&str; 2] = ["cornell", "bunny-mirror"];

fn point(setting: &str, time_ms: f64, error: f64) -> Point {
    Point {
        setting: setting.into(),
        time_ms,
        error,
        costs: Costs::default(),
        accuracy: Accuracy::default(),
        use_times: None,
        note: None,
    }
}

/// A point of the structure group: every cost and accuracy measured, images included.
fn structure(setting: &str, time_ms: f64, error: f64, failures: u64) -> Point {
    let mut p = point(setting, time_ms, error);
    p.costs = Costs {
        build_ms: Some(time_ms * 0.7),
        update_ms: None,
        trace_ms: Some(TraceMs {
            primary: time_ms * 0.5,
            shadow: time_ms * 0.2,
            secondary: time_ms * 0.3,
        }),
        render_ms: Some(time_ms * 3.0),
        sah_cost: Some(40.0 + time_ms),
        bytes: Some((time_ms * 123_456.0) as u64),
    };
    let file = |scene: &str| format!("images/{scene}-{}.png", slug(setting));
    p.accuracy = Accuracy {
        hard_cases: Some(HardCases {
            rays: 123_456,
            misses: failures / 2,
            self_hits: failures - failures / 2,
            wrong_hits: 0,
            errors: 0,
        }),
        hit_differences: Some(failures * 10),
        images: SCENES
            .iter()
            .map(|s| ImageError {
                scene: s.to_string(),
                rmse: error,
                worst: (error * 8.0).min(1.0),
                file: file(s),
            })
            .collect(),
        sah_ratio: None,
    };
    p
}

fn slug(s: &str) -> String {
    s.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

fn group(id: &str, title: &str, uses: &[&str], points: Vec<Point>) -> KnobGroup {
    KnobGroup {
        id: id.into(),
        title: title.into(),
        time_axis: "trace ms (primary + shadow + secondary, GPU)".into(),
        error_axis: "RMSE vs reference".into(),
        preview_error_max: 0.02,
        uses: uses.iter().map(|u| u.to_string()).collect(),
        points,
        front: Vec::new(),
    }
}

/// Four groups: a full one (with a setting named `<b>&`), one of a single point, one with a
/// NaN error, one whose errors are all 0; two image scenes.
fn sample() -> (AccuracyReport, Vec<ImageFile>) {
    let mut exact = structure("kd-tree watertight", 63.0, 0.0, 0);
    exact.note = Some("the reference <setting>".into());
    let all = USES.to_vec();
    let mut groups = vec![
        group(
            "structure",
            "Structure and builder",
            &all,
            vec![
                exact,
                structure("kd-tree SAH 12 bins", 9.5, 0.004, 3),
                structure("BVH binned SAH", 4.1, 0.012, 0),
                structure("BVH LBVH", 2.2, 0.03, 12),
                structure("<b>&", 3.0, 0.05, 37),
                structure("BVH median split", 14.0, 0.02, 1),
            ],
        ),
        group(
            "spp",
            "Samples per pixel",
            &["final frame"],
            vec![structure("64 spp", 120.0, 0.01, 0)],
        ),
        group(
            "intersector",
            "Triangle intersector",
            &["physics/visibility queries"],
            vec![
                structure("Möller–Trumbore", 5.0, f64::NAN, 40),
                structure("watertight", 5.6, 0.0, 0),
                structure("Baldwin–Weber", 4.8, 0.0, 5),
            ],
        ),
        group(
            "refit",
            "Refit vs rebuild after motion",
            &["interactive preview"],
            vec![
                point("rebuild", 5.0, 0.0),
                point("refit", 5.0, 0.0),
                point("refit, rebuild every 8", 5.0, 0.0),
            ],
        ),
    ];
    for (k, p) in groups[3].points.iter_mut().enumerate() {
        p.costs.update_ms = Some(5.0);
        p.accuracy.sah_ratio = Some(1.0 + k as f64 * 0.2);
    }
    fill_fronts(&mut groups);
    let recommendations = recommend(&groups);
    let image_scenes = SCENES
        .iter()
        .map(|s| ImageScene {
            name: s.to_string(),
            width: 32,
            height: 24,
            reference_spp: 4096,
            reference_depth: 16,
            reference_file: format!("images/{s}-reference.png"),
        })
        .collect();
    let mut files: Vec<String> = SCENES
        .iter()
        .map(|s| format!("images/{s}-reference.png"))
        .collect();
    for g in &groups {
        for p in &g.points {
            files.extend(p.accuracy.images.iter().map(|e| e.file.clone()));
        }
    }
    let images = files
        .into_iter()
        .enumerate()
        .map(|(k, file)| ImageFile {
            file,
            width: 32,
            height: 24,
            rgba: (0..32 * 24)
                .flat_map(|i| [(i % 32 * 8) as u8, (i / 32 * 10) as u8, (k * 20) as u8, 255])
                .collect(),
        })
        .collect();
    let report = AccuracyReport {
        device: "llvmpipe (LLVM 15.0.6, 256 bits)".into(),
        driver: "Mesa 22.3.6".into(),
        command: "vkrt bench accuracy --quick --out 'a & b'".into(),
        quick: true,
        wall_s: 42.5,
        mesh: "bunny (69,451 triangles)".into(),
        rays: RayCountsInfo {
            primary: 65_536,
            shadow: 65_536,
            secondary: 32_768,
        },
        hard_cases: "6 suites, 123,456 rays".into(),
        image_scenes,
        groups,
        recommendations,
        notes: vec!["driver: skipped <no ray query>".into()],
    };
    (report, images)
}

fn temp(name: &str) -> PathBuf {
    let root = std::env::temp_dir().join(format!("vkrt-accuracy-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    root
}

/// The names in `root`, sorted.
fn names(root: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(root)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn html_has_one_plot_per_group_and_escapes_text() {
    let (report, _) = sample();
    let page = html(&report);
    assert_eq!(page.matches("<svg").count(), report.groups.len());
    assert!(page.contains("&lt;b&gt;&amp;"), "setting escaped");
    assert!(!page.contains("<b>&"), "raw setting in the page");
    assert!(page.contains("&lt;setting&gt;") && page.contains("&#39;a &amp; b&#39;"));
    assert!(page.contains("★ BVH binned SAH"), "front rows are marked");
    assert!(page.contains("not plotted (time or error not a number): Möller–Trumbore"));
    assert!(page.contains("Recommendations") && page.contains("interactive preview"));
    assert!(
        page.contains("driver: skipped &lt;no ray query&gt;"),
        "the run's notes"
    );
    assert!(page.contains("src=\"images/cornell-reference.png\""));
    assert!(page.contains("src=\"images/cornell-BVH_LBVH.png\""));
    for external in ["<link", "<script", "src=\"http", "href=\"http", "url("] {
        assert!(
            !page.contains(external),
            "{external} in a self-contained page"
        );
    }
    // KiB/MiB bytes, thousands separators, and "—" for what a group did not measure.
    assert!(page.contains("MiB") && page.contains("123,456") && page.contains("—"));
}

#[test]
fn plot_survives_degenerate_groups() {
    let (report, _) = sample();
    let g = |points: Vec<Point>| group("g", "G", &[], points);
    let cases = [
        g(vec![]),
        g(vec![point("one", 3.0, 0.1)]),
        g(vec![point("a", 2.0, 0.1), point("b", 2.0, 0.3)]),
        g(vec![point("zero", 0.0, 0.1), point("big", 500.0, 0.0)]),
        g(vec![
            point("nan", f64::NAN, f64::NAN),
            point("inf", f64::INFINITY, 1.0),
        ]),
        g(vec![point("neg", -1.0, -0.5), point("a", 0.0, 0.0)]),
        report.groups[3].clone(),
    ];
    for c in &cases {
        let svg = plot_svg(c);
        assert!(svg.starts_with("<svg"), "{svg}");
    }
}

#[test]
fn write_produces_the_page_the_json_and_the_images() {
    let root = temp("write");
    let dir = root.join("report");
    let (report, images) = sample();
    write(&dir, &report, &images).unwrap();
    assert!(dir.join("index.html").is_file());
    for im in &images {
        let bytes = std::fs::read(dir.join(&im.file)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{}", im.file);
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    let groups = json["groups"].as_array().unwrap();
    assert_eq!(groups.len(), 4);
    assert_eq!(groups[0]["points"][4]["setting"], "<b>&");
    assert_eq!(json["recommendations"].as_array().unwrap().len(), 6);
    assert_eq!(names(&root), ["report"], "no temporary folder left");
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn write_replaces_a_previous_report_or_an_empty_folder() {
    let root = temp("replace");
    let dir = root.join("report");
    std::fs::create_dir(&dir).unwrap();
    let (mut report, images) = sample();
    write(&dir, &report, &images).unwrap();
    std::fs::write(dir.join("stale.txt"), "old").unwrap();
    report.device = "second device".into();
    write(&dir, &report, &images[..1]).unwrap();
    assert!(!dir.join("stale.txt").exists());
    assert!(!dir.join(&images[1].file).exists(), "old images gone");
    let json = std::fs::read_to_string(dir.join("report.json")).unwrap();
    assert!(json.contains("second device"));
    assert_eq!(names(&root), ["report"]);
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn write_refuses_what_is_not_a_report_and_leaves_it() {
    let root = temp("refuse");
    let (report, images) = sample();
    let file = root.join("file");
    std::fs::write(&file, "mine").unwrap();
    let e = write(&file, &report, &images).unwrap_err().to_string();
    assert!(e.contains("not a folder") && e.contains("file"), "{e}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
    let foreign = root.join("photos");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("keep.jpg"), "x").unwrap();
    let e = write(&foreign, &report, &images).unwrap_err().to_string();
    assert!(e.contains("report.json") && e.contains("photos"), "{e}");
    assert_eq!(names(&foreign), ["keep.jpg"]);
    assert_eq!(names(&root), ["file", "photos"], "no temporary folder left");
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn write_fails_clearly_and_leaves_nothing() {
    let root = temp("fail");
    let (report, mut images) = sample();
    let missing = root.join("no-such-parent").join("report");
    let e = write(&missing, &report, &images).unwrap_err().to_string();
    assert!(
        e.contains("no-such-parent") && e.contains("does not exist"),
        "{e}"
    );
    // A file name that would leave the folder fails after some files were written.
    images.push(ImageFile {
        file: "../escape.png".into(),
        width: 1,
        height: 1,
        rgba: vec![0; 4],
    });
    let dir = root.join("report");
    let e = write(&dir, &report, &images).unwrap_err().to_string();
    assert!(e.contains("../escape.png"), "{e}");
    assert!(names(&root).is_empty(), "{:?}", names(&root));
    std::fs::remove_dir_all(&root).unwrap();
}

/// Writes the sample report for a look in a browser (`VKRT_ACCURACY_SAMPLE`, default
/// `/tmp/accuracy-sample`).
#[test]
#[ignore = "writes a sample report to look at, not a check"]
fn write_sample_report() {
    let dir = std::env::var("VKRT_ACCURACY_SAMPLE").unwrap_or("/tmp/accuracy-sample".into());
    let (report, images) = sample();
    write(Path::new(&dir), &report, &images).unwrap();
    println!("{dir}/index.html");
}
