//! `vkrt animate` as a user runs it: frame files named by the pattern, each equal bit for bit
//! to `vkrt render --frame k` of the same scene, an animated PNG preview, per-frame JSON; and
//! every class of bad input a clear error that leaves no frame file.

mod common;

use std::path::{Path, PathBuf};

use common::{vkrt, vkrt_ok};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vkrt-cli-animate-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A small animated scene: a keyframed quad turning and rising, a sphere orbiting it, a
/// mirror behind; 4 frames at 8 fps.
const SCENE: &str = r#"
[settings]
width = 40
height = 30
spp = 1
max_depth = 2

[camera]
position = [0, 1, 4]
look_at = [0, 0.5, 0]
fov = 50

[animation]
fps = 8
frames = 4

[materials.white]
diffuse = [0.8, 0.8, 0.8]

[materials.mirror]
diffuse = [0.1, 0.1, 0.1]
mirror = 0.8

[[lights]]
type = "point"
position = [1, 3, 2]
intensity = 20

[[meshes]]
name = "quad"
positions = [[-0.5, 0, 0], [0.5, 0, 0], [0.5, 1, 0], [-0.5, 1, 0]]
indices = [[0, 1, 2], [0, 2, 3]]
material = "white"

[[meshes.keyframes]]
time = 0.0

[[meshes.keyframes]]
time = 0.5
translate = [0, 0.3, 0]
rotate = [0, 60, 0]

[[meshes]]
name = "mirror"
positions = [[-2, -1, -1], [2, -1, -1], [2, 2, -1], [-2, 2, -1]]
indices = [[0, 1, 2], [0, 2, 3]]
material = "mirror"

[[spheres]]
center = [1, 0.5, 0]
radius = 0.25
material = "white"
orbit = { center = [0, 0.5, 0], axis = [0, 1, 0], degrees_per_second = 90 }
"#;

fn scene_file(dir: &Path) -> PathBuf {
    let p = dir.join("anim.toml");
    std::fs::write(&p, SCENE).unwrap();
    p
}

fn decode(p: &Path) -> Vec<u8> {
    image::open(p).unwrap().into_rgba8().into_raw()
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn frames_equal_single_renders_and_the_preview_animates() {
    let dir = scratch("frames");
    let scene = scene_file(&dir);
    let out = dir.join("out");
    let pattern = out.join("f_%03d.png");
    let preview = dir.join("preview.png");
    for update in ["rebuild", "refit"] {
        let Some(run) = vkrt_ok(&[
            "animate",
            s(&scene),
            "-o",
            s(&pattern),
            "--update",
            update,
            "--preview",
            s(&preview),
            "--json",
            "--validate",
        ]) else {
            return;
        };
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(!err.contains("validation"), "{err}");
        let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        let frames = v["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 4, "{v}");
        for (k, f) in frames.iter().enumerate() {
            assert_eq!(f["frame"], k, "{v}");
            assert!(
                (f["time"].as_f64().unwrap() - k as f64 / 8.0).abs() < 1e-6,
                "{v}"
            );
            assert_eq!(f["built"], k == 0 || update == "rebuild", "{v}");
            assert!(f["render_ms"].as_f64().unwrap() > 0.0, "{v}");
            assert!(f["rays"].as_u64().unwrap() > 0, "{v}");
            // One submission per frame (one more per redone record); read back: the image
            // (RGBA8) and the frame's counters (a few words), per submission.
            let redone = f["redone"].as_u64().unwrap();
            let submits = f["submits"].as_u64().unwrap();
            assert_eq!(submits, 1 + redone, "{v}");
            let (w, h) = (v["width"].as_u64().unwrap(), v["height"].as_u64().unwrap());
            let read = f["readback_bytes"].as_u64().unwrap();
            assert!(
                (w * h * 4..=(w * h * 4 + 256) * submits).contains(&read),
                "{read} bytes read back: {v}"
            );
        }
        let sum = |key: &str| frames.iter().map(|f| f[key].as_u64().unwrap()).sum::<u64>();
        assert_eq!(v["submits"].as_u64().unwrap(), sum("submits"), "{v}");
        assert_eq!(
            v["readback_bytes"].as_u64().unwrap(),
            sum("readback_bytes"),
            "{v}"
        );
        assert_eq!(
            files_in(&out),
            ["f_000.png", "f_001.png", "f_002.png", "f_003.png"]
        );
        let mut previous: Option<Vec<u8>> = None;
        for k in 0..4u32 {
            let single = dir.join(format!("single_{k}.png"));
            vkrt_ok(&[
                "render",
                s(&scene),
                "--frame",
                &k.to_string(),
                "-o",
                s(&single),
            ])
            .unwrap();
            let frame = decode(&out.join(format!("f_{k:03}.png")));
            assert!(
                frame == decode(&single),
                "{update}: frame {k} differs from render --frame"
            );
            if let Some(p) = &previous {
                assert!(p != &frame, "{update}: frame {k} did not move");
            }
            previous = Some(frame);
        }
        // An animated PNG: its acTL chunk says 4 frames, played forever.
        let bytes = std::fs::read(&preview).unwrap();
        let at = bytes
            .windows(4)
            .position(|w| w == b"acTL")
            .expect("an acTL chunk");
        assert_eq!(
            u32::from_be_bytes(bytes[at + 4..at + 8].try_into().unwrap()),
            4
        );
        assert_eq!(
            u32::from_be_bytes(bytes[at + 8..at + 12].try_into().unwrap()),
            0
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_animation_input_is_a_clear_error_and_leaves_no_frame() {
    let dir = scratch("bad");
    let scene = scene_file(&dir);
    let still = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/hard_shadows.toml");
    let out = dir.join("out");
    let pattern = out.join("f_%03d.png");
    let p = s(&pattern);
    let blocked = dir.join("file");
    std::fs::write(&blocked, b"not a directory").unwrap();
    let under_file = blocked.join("f_%d.png");
    let no_number = out.join("frame.png");
    let tiff = out.join("f_%d.tiff");
    let gif = dir.join("p.gif");
    let single = dir.join("x.png");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["animate", s(&scene), "-o", p, "--length", "0"],
            "--length must be 1..=",
        ),
        (
            vec!["animate", s(&scene), "-o", p, "--length", "100000000"],
            "--length must be 1..=",
        ),
        (
            vec!["animate", s(&scene), "-o", p, "--frames", "2..2"],
            "is empty",
        ),
        (
            vec!["animate", s(&scene), "-o", p, "--frames", "3..1"],
            "is empty",
        ),
        (
            vec!["animate", s(&scene), "-o", p, "--frames", "2..9"],
            "outside the animation's frames 0..4",
        ),
        (
            vec!["animate", s(&scene), "-o", p, "--frames", "4"],
            "outside the animation's frames 0..4",
        ),
        (
            vec!["animate", s(&scene), "-o", p, "--frames", "1-3"],
            "expected A..B",
        ),
        (
            vec!["animate", s(&scene), "-o", p, "--frames", "..x"],
            "expected A..B",
        ),
        (vec!["animate", s(&still), "-o", p], "no [animation]"),
        (
            vec!["animate", s(&scene), "-o", s(&no_number)],
            "frame number",
        ),
        (vec!["animate", s(&scene), "-o", s(&tiff)], ".exr"),
        (
            vec!["animate", s(&scene), "-o", s(&under_file)],
            "cannot write frames",
        ),
        (
            vec![
                "animate",
                s(&scene),
                "-o",
                p,
                "--accel",
                "kdtree",
                "--update",
                "refit",
            ],
            "cannot be refit",
        ),
        (
            vec!["animate", s(&scene), "-o", p, "--preview", s(&gif)],
            "animated PNG",
        ),
        (
            vec!["render", s(&scene), "--frame", "4", "-o", s(&single)],
            "frames 0..4",
        ),
        (
            vec!["render", s(&still), "--frame", "0", "-o", s(&single)],
            "no [animation]",
        ),
    ];
    for (args, why) in cases {
        let run = vkrt(&args);
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "{args:?} succeeded");
        assert!(err.contains(why), "{args:?}: {err}");
        let left = if out.exists() {
            files_in(&out)
        } else {
            Vec::new()
        };
        assert!(left.is_empty(), "{args:?} left {left:?}");
        assert!(!dir.join("x.png").exists(), "{args:?} left an image");
    }
    // Bad animation in the scene file: its own clear errors (see tests/scene_animation.rs).
    for (bad, why) in [("fps = 8", "fps = -8"), ("frames = 4", "frames = 0")] {
        let text = SCENE.replace(bad, why);
        let f = dir.join("bad.toml");
        std::fs::write(&f, text).unwrap();
        let run = vkrt(&["animate", s(&f), "-o", p]);
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "{why} succeeded");
        assert!(
            err.contains("bad.toml:") && err.contains("animation"),
            "{why}: {err}"
        );
        assert!(!out.exists() || files_in(&out).is_empty());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `vkrt bench animate`: every structure and update mode in one run, a report and a plot.
#[test]
fn bench_animate_reports_every_structure_and_update_mode() {
    let dir = scratch("bench");
    let scene = scene_file(&dir);
    let out = dir.join("report");
    let args = [
        "bench",
        "animate",
        s(&scene),
        "--frames",
        "2",
        "--step",
        "2",
        "--width",
        "32",
        "--height",
        "24",
        "-o",
        s(&out),
        "--json",
    ];
    let Some(run) = vkrt_ok(&args) else { return };
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let runs = v["runs"].as_array().unwrap();
    let has = |accel: &str, update: &str| {
        runs.iter()
            .any(|r| r["accel"].as_str().unwrap().starts_with(accel) && r["update"] == update)
    };
    for kind in ["kdtree", "sah-bvh", "lbvh", "ploc"] {
        assert!(has(kind, "rebuild"), "{kind}: {v}");
    }
    for kind in ["sah-bvh", "lbvh", "ploc"] {
        assert!(has(kind, "refit"), "{kind}: {v}");
    }
    for r in runs {
        let frames = r["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 2, "{r}");
        // Frame 1 is frame 2 of the animation (--step 2).
        assert!(
            (frames[1]["time"].as_f64().unwrap() - 2.0 / 8.0).abs() < 1e-6,
            "{r}"
        );
        for f in frames {
            assert!(f["render_ms"].as_f64().unwrap() > 0.0, "{r}");
        }
        if r["update"] == "refit" && !r["accel"].as_str().unwrap().starts_with("driver") {
            let f = &frames[1];
            let (now, fresh) = (
                f["sah_cost"].as_f64().unwrap(),
                f["rebuilt_sah_cost"].as_f64().unwrap(),
            );
            assert!(now.is_finite() && fresh.is_finite() && fresh > 0.0, "{r}");
        }
    }
    let svg = std::fs::read_to_string(out.join("frames.svg")).unwrap();
    assert!(
        svg.starts_with("<svg") && svg.contains("render ms per frame"),
        "{svg:.200}"
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["runs"].as_array().unwrap().len(), runs.len());
    let bad = vkrt(&[
        "bench",
        "animate",
        s(&scene),
        "--frames",
        "3",
        "--step",
        "2",
        "-o",
        s(&out),
    ]);
    assert!(String::from_utf8_lossy(&bad.stderr).contains("frames 0..4"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A soak: the dynamic demo over 60 frames at low resolution, refit every frame, flat and as
/// two levels (the icospheres repeat: each frame refits the top level): device memory and
/// host RSS flat from frame 10 to the last (growth ≤ 1 %), one submission per frame; and no
/// validation message over 12 frames of each under validation. Memory is measured without
/// the layer: its own bookkeeping grows by about 48 KB a frame in either mode (measured with
/// `MALLOC_MMAP_THRESHOLD_=65536`: 1.0-1.8 % over the 50 frames, which glibc's heap sometimes
/// hides), vkrt's about 5 KB (0.11-0.15 %). `vkrt animate … --frames 500` is the long form:
/// docs/testing.md.
#[test]
fn a_long_animation_holds_memory_flat() {
    let dir = scratch("soak");
    let scene =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/dynamic_demo.toml");
    let pattern = dir.join("f_%03d.png");
    let runs: [(&[&str], &str, u64); 4] = [
        (&["--flatten"], "60", 1),
        (&[], "60", 2),
        (&["--flatten", "--validate"], "12", 1),
        (&["--validate"], "12", 2),
    ];
    for (extra, length, levels) in runs {
        let what = format!("{extra:?}");
        let args = [
            "animate",
            s(&scene),
            "-o",
            s(&pattern),
            "--length",
            length,
            "--width",
            "32",
            "--height",
            "24",
            "--spp",
            "1",
            "--accel",
            "lbvh",
            "--update",
            "refit",
            "--json",
        ];
        let Some(run) = vkrt_ok(&[&args[..], extra].concat()) else {
            return;
        };
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(!err.contains("validation"), "{what}: {err}");
        let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        assert_eq!(v["levels"], levels, "{what}");
        let frames = v["frames"].as_array().unwrap();
        assert_eq!(frames.len().to_string(), length, "{what}");
        for f in frames {
            assert_eq!(
                f["submits"].as_u64().unwrap(),
                1 + f["redone"].as_u64().unwrap(),
                "{what}"
            );
            assert!(f["device_bytes"].as_u64().unwrap() > 0, "{what}: {f}");
        }
        if extra.contains(&"--validate") {
            continue;
        }
        let m = &v["memory"];
        println!("{what}: {m}");
        assert_eq!(m["from_frame"], 10, "{what}: {m}");
        let device = m["device_growth"].as_f64().unwrap();
        assert!(
            device.abs() <= 0.01,
            "{what}: device memory grew {:.2} %: {m}",
            device * 100.0
        );
        if let Some(rss) = m["host_rss_growth"].as_f64() {
            assert!(
                rss <= 0.01,
                "{what}: host RSS grew {:.2} %: {m}",
                rss * 100.0
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Float frames: `.exr` and `.pfm` patterns hold the linear radiance, each frame the same
/// bytes as `vkrt render --frame k -o x.exr` (or `.pfm`) of the same scene.
#[test]
fn float_frames_equal_single_float_renders() {
    let dir = scratch("float");
    let scene = scene_file(&dir);
    for ext in ["exr", "pfm"] {
        let pattern = dir.join(format!("f_%02d.{ext}"));
        let Some(_) = vkrt_ok(&[
            "animate",
            s(&scene),
            "-o",
            s(&pattern),
            "--frames",
            "0..2",
            "--update",
            "refit",
            "--validate",
        ]) else {
            return;
        };
        for k in 0..2u32 {
            let single = dir.join(format!("single_{k}.{ext}"));
            vkrt_ok(&[
                "render",
                s(&scene),
                "--frame",
                &k.to_string(),
                "-o",
                s(&single),
            ])
            .unwrap();
            let frame = std::fs::read(dir.join(format!("f_{k:02}.{ext}"))).unwrap();
            if ext == "pfm" {
                // Three floats a pixel after the header: the radiance, not 8-bit values.
                assert!(
                    frame.len() > 40 * 30 * 12,
                    "frame {k}: {} bytes",
                    frame.len()
                );
            }
            assert!(
                frame == std::fs::read(&single).unwrap(),
                "{ext}: frame {k} differs from render --frame"
            );
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A render farm's split: the animation rendered in pieces (in processes each starting
/// fresh) gives the same frame files as one whole run, byte for byte, for every structure
/// and both update modes — each frame rendered alone, the hardest split, since a refit
/// then starts from that frame's build; `A..=B`, `A..`, `..B` and halves name the same
/// frames (range parsing and the frames' times, which no structure changes: one structure
/// and update mode, a refitted one, runs them).
#[test]
fn any_split_into_ranges_gives_the_same_frames() {
    let dir = scratch("split");
    let scene = scene_file(&dir);
    let mut runs = vec![
        ("kdtree", "rebuild"),
        ("sah-bvh", "rebuild"),
        ("sah-bvh", "refit"),
        ("lbvh", "rebuild"),
        ("lbvh", "refit"),
        ("ploc", "rebuild"),
        ("ploc", "refit"),
    ];
    if String::from_utf8_lossy(&vkrt(&["info", "--json"]).stdout).contains("\"ray_query\": true") {
        runs.extend([("driver", "rebuild"), ("driver", "refit")]);
    }
    for (accel, update) in runs {
        let render = |sub: &str, ranges: &[&str]| -> Option<Vec<Vec<u8>>> {
            let out = dir.join(format!("{accel}-{update}-{sub}"));
            for range in ranges {
                let pattern = out.join("f_%02d.png");
                let mut args = vec!["animate", s(&scene), "-o", s(&pattern)];
                args.extend(["--accel", accel, "--update", update]);
                if !range.is_empty() {
                    args.extend(["--frames", range]);
                }
                vkrt_ok(&args)?;
            }
            Some(
                (0..4)
                    .map(|k| std::fs::read(out.join(format!("f_{k:02}.png"))).unwrap())
                    .collect(),
            )
        };
        let Some(whole) = render("whole", &[""]) else {
            return;
        };
        let mut splits = vec![("singles", &["3", "1", "0", "2"][..])];
        if (accel, update) == ("lbvh", "refit") {
            splits.extend([
                ("halves", &["0..2", "2..4"][..]),
                ("inclusive", &["..=0", "1..=2", "3.."][..]),
            ]);
        }
        for (sub, ranges) in splits {
            let split = render(sub, ranges).unwrap();
            for k in 0..4 {
                assert!(
                    split[k] == whole[k],
                    "{accel} {update}, {sub}: frame {k} differs from the whole run"
                );
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A re-queued task: `--skip-existing` leaves complete frame files alone and renders the
/// missing and the broken ones again, equal to a whole run's; with `--preview` it is refused.
#[test]
fn skip_existing_renders_only_missing_or_broken_frames() {
    let dir = scratch("skip");
    let scene = scene_file(&dir);
    for ext in ["png", "pfm"] {
        let pattern = dir.join(format!("f_%d.{ext}"));
        let frame = |k: u32| dir.join(format!("f_{k}.{ext}"));
        let args = ["animate", s(&scene), "-o", s(&pattern), "--update", "refit"];
        let Some(_) = vkrt_ok(&args) else {
            return;
        };
        let whole: Vec<Vec<u8>> = (0..4).map(|k| std::fs::read(frame(k)).unwrap()).collect();
        std::fs::remove_file(frame(1)).unwrap();
        std::fs::write(frame(2), &whole[2][..whole[2].len() / 2]).unwrap(); // cut short
        let mut again = args.to_vec();
        again.extend(["--skip-existing", "--json"]);
        let run = vkrt_ok(&again).unwrap();
        let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        assert_eq!(v["skipped"], serde_json::json!([0, 3]), "{ext}: {v}");
        let rendered: Vec<_> = v["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["frame"].clone())
            .collect();
        assert_eq!(rendered, [1, 2], "{ext}: {v}");
        for k in 0..4 {
            assert!(
                std::fs::read(frame(k)).unwrap() == whole[k as usize],
                "{ext}: frame {k}"
            );
        }
    }
    let preview = dir.join("p.png");
    let pattern = dir.join("g_%d.png");
    let run = vkrt(&[
        "animate",
        s(&scene),
        "-o",
        s(&pattern),
        "--skip-existing",
        "--preview",
        s(&preview),
    ]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("--skip-existing"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--plan`: chunks that tile the range, each with a command that renders its chunk (run
/// here: together they give the whole run's frames).
#[test]
fn plan_splits_the_animation_into_task_commands() {
    let dir = scratch("plan");
    let scene = scene_file(&dir);
    let pattern = dir.join("f_%d.png");
    let args = ["animate", s(&scene), "-o", s(&pattern), "--update", "refit"];
    let mut plan_args = args.to_vec();
    plan_args.extend(["--plan", "--task-seconds", "0.000001", "--frames", "1.."]);
    let Some(run) = vkrt_ok(&plan_args) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(v["frames"], 3, "{v}");
    assert_eq!(v["chunk"], 1, "{v}");
    let chunks = v["chunks"].as_array().unwrap();
    let ranges: Vec<&str> = chunks
        .iter()
        .map(|c| c["frames"].as_str().unwrap())
        .collect();
    assert_eq!(ranges, ["1..2", "2..3", "3..4"]);
    assert!(
        files_in(&dir).iter().all(|f| !f.starts_with("f_")),
        "--plan wrote frames"
    );
    for c in chunks {
        let cmd: Vec<&str> = c["command"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a.as_str().unwrap())
            .collect();
        assert_eq!(cmd[0], "vkrt");
        assert!(
            !cmd.contains(&"--plan") && cmd.ends_with(&["--skip-existing"]),
            "{cmd:?}"
        );
        vkrt_ok(&cmd[1..]).unwrap();
    }
    let whole = dir.join("whole");
    let mut whole_args = args.to_vec();
    let whole_pattern = whole.join("f_%d.png");
    whole_args[3] = s(&whole_pattern);
    vkrt_ok(&whole_args).unwrap();
    for k in 1..4 {
        let name = format!("f_{k}.png");
        assert!(
            std::fs::read(dir.join(&name)).unwrap() == std::fs::read(whole.join(&name)).unwrap(),
            "{name}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
