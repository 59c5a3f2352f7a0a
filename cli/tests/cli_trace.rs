//! `vkrt trace` as a user runs it: a round trip through ray and hit files against brute
//! force, and every class of bad input (clear error, nonzero exit, no output file).

mod common;

use std::path::{Path, PathBuf};

use common::{no_gpu_allowed, vkrt, vkrt_ok, Rng};
use glam::Vec3;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::scene::Scene;
use vkrt::trace::{cpu, files, Hit, Intersector, Query, Ray, TraceOptions};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vkrt-cli-trace-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes")
        .join(name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Rays over the scene's box: from outside towards random points inside, from inside in
/// random directions (unbounded: `tmax = inf`), axis-parallel with ±0 components, and five
/// invalid ones (two NaN, an infinite direction, a zero direction, tmin > tmax).
fn rays_for(g: &TraceGeometry, n: usize, seed: u64) -> Vec<Ray> {
    let mut lo = Vec3::splat(f32::MAX);
    let mut hi = Vec3::splat(f32::MIN);
    for b in &g.boxes {
        lo = lo.min(b.min);
        hi = hi.max(b.max);
    }
    let (c, ext) = ((lo + hi) * 0.5, (hi - lo).max(Vec3::splat(1e-3)));
    let mut rng = Rng(seed);
    let v = |rng: &mut Rng| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
    let mut rays: Vec<Ray> = (0..n)
        .map(|i| {
            let inside = c + v(&mut rng) * ext * 0.5;
            match i % 3 {
                0 => {
                    let from = c + v(&mut rng).normalize_or(Vec3::X) * ext.length();
                    Ray::new(from, inside - from, 0.0, f32::MAX)
                }
                1 => Ray::new(inside, v(&mut rng), 0.0, f32::INFINITY), // unbounded
                _ => {
                    let mut d = [-0.0f32, 0.0, -0.0];
                    d[(rng.next_u64() % 3) as usize] = if i % 2 == 0 { 1.0 } else { -1.0 };
                    Ray::new(inside, Vec3::from_array(d), 0.0, 1e30)
                }
            }
        })
        .collect();
    let nan = f32::NAN;
    rays.push(Ray::new(Vec3::new(nan, 0.0, 0.0), Vec3::X, 0.0, f32::MAX));
    rays.push(Ray::new(
        c,
        Vec3::new(0.0, f32::INFINITY, 0.0),
        0.0,
        f32::MAX,
    ));
    rays.push(Ray::new(c, Vec3::ZERO, 0.0, f32::MAX));
    rays.push(Ray::new(c, Vec3::X, 1.0, 0.5));
    rays.push(Ray::new(c, Vec3::X, 0.0, nan));
    rays
}

fn same_answer(a: &Hit, b: &Hit) -> bool {
    if a.is_hit() != b.is_hit() {
        return false;
    }
    !a.is_hit() || (a.t - b.t).abs() <= 1e-5 * a.t.abs().max(b.t.abs()).max(1e-30)
}

fn read_hits(path: &Path) -> Vec<Hit> {
    let bytes = std::fs::read(path).unwrap();
    if path.extension().is_some_and(|e| e == "csv") {
        let text = String::from_utf8(bytes).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("t,prim,u,v"));
        lines
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                assert_eq!(f.len(), 4, "{l}");
                if f[1] == "-1" {
                    assert_eq!(f[0], "inf");
                    Hit::MISS
                } else {
                    Hit {
                        t: f[0].parse().unwrap(),
                        prim: f[1].parse().unwrap(),
                        u: f[2].parse().unwrap(),
                        v: f[3].parse().unwrap(),
                    }
                }
            })
            .collect()
    } else {
        assert_eq!(bytes.len() % 16, 0);
        bytemuck::pod_collect_to_vec(&bytes)
    }
}

/// A `--json` report's memory: the process's peak resident set, per triangle of the scene,
/// and the device's peak bytes, all positive.
#[track_caller]
fn assert_memory_reported(v: &serde_json::Value, triangles: usize) {
    assert_eq!(v["triangles"], triangles, "{v}");
    if std::path::Path::new("/proc/self/status").exists() {
        let peak = v["host_peak_rss_bytes"].as_u64().unwrap_or(0);
        assert!(peak > 0, "{v}");
        let per = v["host_peak_rss_bytes_per_triangle"]
            .as_f64()
            .unwrap_or(0.0);
        assert!(
            (per - peak as f64 / triangles as f64).abs() <= 1e-6 * per,
            "{v}"
        );
    }
    assert!(v["device_peak_bytes"].as_u64().unwrap_or(0) > 0, "{v}");
}

/// Writes rays, traces them with the CLI (in small batches, so batching is exercised),
/// reads the hits back and compares every ray with brute force on the same geometry.
fn round_trip(scene: &str, out_name: &str, extra: &[&str], opt: TraceOptions) {
    let dir = scratch(&format!("rt-{}", out_name.replace('.', "-")));
    let scene_path = example(scene);
    let loaded = Scene::load(&scene_path).unwrap().scene;
    let g = TraceGeometry::at_time(&loaded, loaded.camera.shutter_open);
    let rays = rays_for(&g, 3000, 7);
    let ray_path = dir.join("in.rays");
    std::fs::write(&ray_path, files::encode_rays(&rays)).unwrap();
    let out = dir.join(out_name);
    let mut args = vec![
        "trace",
        s(&scene_path),
        "--rays",
        s(&ray_path),
        // `-o/--output`; the tests below use its old name `--out`, kept as an alias.
        "-o",
        s(&out),
        "--json",
        "--batch-rays",
        "1000",
    ];
    args.extend_from_slice(extra);
    let Some(run) = vkrt_ok(&args) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let keys: Vec<&String> = v.as_object().unwrap().keys().collect();
    let two_levels = v["levels"] == 2;
    let mut want = vec![
        "accel",
        "build_attempts",
        "build_ms",
        "device_peak_bytes",
        "exhausted",
        "hits",
        "host_peak_rss_bytes",
        "host_peak_rss_bytes_per_triangle",
        "invalid",
        "invalid_by_reason",
        "levels",
        "mrays_per_s",
        "rays",
        "readback_bytes",
        "readback_bytes_total",
        "submits",
        "trace_ms",
        "triangles",
        // The median of 3 warm runs, their range, the first run apart.
        "build_ms_max",
        "build_ms_min",
        "first_build_ms",
        "first_trace_ms",
        "reps",
        "trace_ms_max",
        "trace_ms_min",
    ];
    want.sort();
    if two_levels {
        want.retain(|k| !["readback_bytes", "readback_bytes_total", "submits"].contains(k));
        want.extend([
            "bottom_build_ms",
            "bottom_bytes",
            "bottom_levels",
            "instances",
            "rest_pieces",
            "top_build_ms",
            "top_bytes",
            "unique_primitives",
        ]);
        want.sort();
        assert!(v["instances"].as_u64().unwrap() >= 2, "{v}");
        // (a scene this small is one piece)
        assert_eq!(v["rest_pieces"], 1, "{v}");
        assert!(v["top_bytes"].as_u64().unwrap() > 0, "{v}");
        assert!(
            v["unique_primitives"].as_u64().unwrap() < g.primitive_count() as u64,
            "{v}"
        );
    }
    assert_eq!(keys, want, "{v}");
    assert_eq!(v["rays"], rays.len());
    assert_memory_reported(&v, loaded.triangle_count());
    if !two_levels {
        // Upload, build and the first batch's trace are one submission with nothing read
        // back between build and trace; every further batch of 1000 rays is one more
        // submission.
        assert_eq!(v["build_attempts"], 1, "{v}");
        assert_eq!(v["submits"], rays.len().div_ceil(1000), "{v}");
        assert_eq!(v["readback_bytes"], 0, "{v}");
        // What comes back: the hits and the error counters of each batch (and a kd-tree's
        // 16-byte build report).
        let batches = rays.len().div_ceil(1000) as u64;
        let report = if v["accel"] == "kdtree" { 16 } else { 0 };
        assert_eq!(
            v["readback_bytes_total"],
            16 * rays.len() as u64 + 4 * batches + report,
            "{v}"
        );
    }
    // rays_for's five invalid rays, by class; and a warning that says so.
    assert_eq!(v["invalid"], 5, "{v}");
    let by_reason = &v["invalid_by_reason"];
    assert_eq!(
        (
            &by_reason["nan"],
            &by_reason["infinite"],
            &by_reason["zero_direction"],
            &by_reason["empty_interval"]
        ),
        (&2.into(), &1.into(), &1.into(), &1.into()),
        "{v}"
    );
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("warning: 5 of 3005 rays are invalid"), "{err}");
    assert!(v["trace_ms"].as_f64().unwrap() > 0.0, "{v}");
    assert!(v["mrays_per_s"].as_f64().unwrap() > 0.0, "{v}");
    assert_eq!(v["reps"], 3, "{v}");
    let f = |k: &str| v[k].as_f64().unwrap();
    assert!(
        f("trace_ms_min") <= f("trace_ms") && f("trace_ms") <= f("trace_ms_max"),
        "{v}"
    );
    let hits = read_hits(&out);
    assert_eq!(hits.len(), rays.len());
    let driver = extra.contains(&"driver");
    let mut n_hits = 0;
    for (i, (r, h)) in rays.iter().zip(&hits).enumerate() {
        let bf = cpu::brute_force(&g, r, 0.0, &opt);
        n_hits += h.is_hit() as usize;
        if opt.query == Query::Any {
            assert_eq!(h.is_hit(), bf.is_hit(), "ray {i} {r:?}: {h:?} vs {bf:?}");
        } else if driver {
            // The driver's triangle test is its own (not vkrt's watertight one): t within
            // 1e-4 relative.
            let close = (h.t - bf.t).abs() <= 1e-4 * h.t.abs().max(bf.t.abs());
            assert!(
                h.is_hit() == bf.is_hit() && (!h.is_hit() || close),
                "ray {i} {r:?}: {h:?} vs {bf:?}"
            );
        } else {
            assert!(same_answer(h, &bf), "ray {i} {r:?}: {h:?} vs {bf:?}");
        }
        if !r.is_valid() {
            assert_eq!(*h, Hit::MISS, "invalid ray {i} {r:?}");
        }
    }
    assert_eq!(v["hits"], n_hits);
    assert!(n_hits > rays.len() / 4, "only {n_hits} hits");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn round_trip_binary_closest_hit_matches_brute_force() {
    // Moving meshes and a sphere: geometry at the shutter-open time.
    round_trip("motion_blur.toml", "hits.bin", &[], TraceOptions::default());
}

#[test]
fn round_trip_sah_bvh_stack_and_bitstack_match_brute_force() {
    // `auto`: the device's walk (the 4-wide one on Mesa 26's lavapipe).
    for traversal in ["stack", "bitstack", "auto"] {
        round_trip(
            "motion_blur.toml",
            &format!("hits-bvh-{traversal}.bin"),
            &["--accel", "sah-bvh", "--traversal", traversal],
            TraceOptions::default(),
        );
    }
}

/// Scenes that name a mesh more than once trace as two levels (bottom levels under
/// instances) with the flat scene's primitive ids: brute force's answers, under every kind
/// of bottom level and BVH walk, closest and any hit.
#[test]
fn round_trip_two_levels_where_a_mesh_repeats() {
    for (scene, extra) in [
        ("mesh_file.toml", &[][..]),
        ("mesh_file.toml", &["--accel", "kdtree"][..]),
        (
            "mesh_file.toml",
            &["--accel", "lbvh", "--traversal", "wide"][..],
        ),
        (
            "dynamic_demo.toml",
            &["--accel", "sah-bvh", "--traversal", "bitstack"][..],
        ),
    ] {
        let name = format!(
            "hits-2l-{}-{}.bin",
            scene.replace('.', "-"),
            extra.join("-")
        );
        round_trip(scene, &name, extra, TraceOptions::default());
    }
    // `vkrt build` reports the bytes of both levels beside the flat structure's.
    let scene = example("mesh_file.toml");
    if let Some(run) = vkrt_ok(&["build", s(&scene), "--accel", "lbvh", "--json"]) {
        let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        let levels = &v["levels"];
        assert_eq!(levels["instances"], 2, "{v}");
        assert_eq!(levels["bottom_levels"], 2, "{v}");
        assert!(levels["bottom_bytes"].as_u64().unwrap() > 0, "{v}");
        assert!(levels["top_bytes"].as_u64().unwrap() > 0, "{v}");
    }
    round_trip(
        "mesh_file.toml",
        "hits-2l-any.csv",
        &[
            "--any-hit",
            "--intersector",
            "moller-trumbore",
            "--accel",
            "ploc",
        ],
        TraceOptions {
            intersector: Intersector::MollerTrumbore,
            query: Query::Any,
            ..TraceOptions::default()
        },
    );
}

#[test]
fn round_trip_csv_any_hit_moller_trumbore_matches_brute_force() {
    round_trip(
        "ambient_occlusion.toml",
        "hits.csv",
        &["--any-hit", "--intersector", "moller-trumbore"],
        TraceOptions {
            intersector: Intersector::MollerTrumbore,
            query: Query::Any,
            ..TraceOptions::default()
        },
    );
}

#[test]
fn csv_rays_and_human_output() {
    let dir = scratch("csv");
    let rays = dir.join("r.csv");
    std::fs::write(
        &rays,
        "ox,oy,oz,dx,dy,dz\n# a comment\n0,1,10,0,0,-1\n0,1,10,0,0,-1,0,0.5\n0,1,10,0,0,1\n",
    )
    .unwrap();
    let out = dir.join("h.csv");
    let Some(run) = vkrt_ok(&[
        "trace",
        s(&example("house.obj")),
        "--rays",
        s(&rays),
        "--out",
        s(&out),
    ]) else {
        return;
    };
    let text = String::from_utf8_lossy(&run.stdout);
    assert!(text.contains("3 rays"), "{text}");
    assert!(text.contains("Mrays/s"), "{text}");
    let hits = read_hits(&out);
    assert_eq!(hits.len(), 3);
    assert!(!hits[1].is_hit() && !hits[2].is_hit(), "{hits:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `tmax = +inf` is unbounded (Embree's `tfar = inf`): such rays hit exactly what the same
/// rays with `tmax = f32::MAX` hit, and every class of invalid ray is counted, not traced.
#[test]
fn unbounded_rays_and_invalid_rays_counted_by_class() {
    let dir = scratch("unbounded");
    let (mesh, rays_n) = match common::bunny_path() {
        Some(p) => (p, 20_000),
        None => (example("house.obj"), 3_000),
    };
    let loaded = Scene::load(&mesh).unwrap().scene;
    let g = TraceGeometry::at_time(&loaded, loaded.camera.shutter_open);
    let bounded: Vec<Ray> = rays_for(&g, rays_n, 11)
        .into_iter()
        .filter(Ray::is_valid)
        .map(|r| Ray {
            tmax: f32::MAX,
            ..r
        })
        .collect();
    let unbounded: Vec<Ray> = bounded
        .iter()
        .map(|r| Ray {
            tmax: f32::INFINITY,
            ..*r
        })
        .collect();
    let (inf, nan) = (f32::INFINITY, f32::NAN);
    let c = Vec3::ZERO;
    let invalid = [
        (Ray::new(Vec3::new(nan, 0.0, 0.0), Vec3::X, 0.0, inf), "nan"),
        (Ray::new(c, Vec3::new(0.0, nan, 0.0), 0.0, inf), "nan"),
        (Ray::new(c, Vec3::X, nan, inf), "nan"),
        (Ray::new(c, Vec3::X, 0.0, nan), "nan"),
        (
            Ray::new(Vec3::new(0.0, 0.0, -inf), Vec3::X, 0.0, inf),
            "infinite",
        ),
        (Ray::new(c, Vec3::new(inf, 0.0, 0.0), 0.0, inf), "infinite"),
        (Ray::new(c, Vec3::X, -inf, inf), "infinite"),
        (Ray::new(c, Vec3::X, inf, inf), "infinite"),
        (Ray::new(c, Vec3::ZERO, 0.0, inf), "zero_direction"),
        (Ray::new(c, Vec3::splat(-0.0), 0.0, 1.0), "zero_direction"),
        (Ray::new(c, Vec3::X, 2.0, 1.0), "empty_interval"),
        (Ray::new(c, Vec3::X, 0.0, -inf), "empty_interval"),
    ];
    let hits_of = |name: &str, rays: &[Ray]| -> Option<(serde_json::Value, Vec<Hit>)> {
        let (path, out) = (
            dir.join(format!("{name}.rays")),
            dir.join(format!("{name}.hits")),
        );
        std::fs::write(&path, files::encode_rays(rays)).unwrap();
        let run = vkrt_ok(&[
            "trace",
            s(&mesh),
            "--rays",
            s(&path),
            "--out",
            s(&out),
            "--json",
        ])?;
        Some((
            serde_json::from_slice(&run.stdout).unwrap(),
            read_hits(&out),
        ))
    };
    let Some((vb, hb)) = hits_of("bounded", &bounded) else {
        return;
    };
    let (vu, hu) = hits_of("unbounded", &unbounded).unwrap();
    assert!(hb.iter().filter(|h| h.is_hit()).count() > bounded.len() / 4);
    assert_eq!(vu["hits"], vb["hits"]);
    assert_eq!(vu["invalid"], 0);
    assert!(
        hb == hu,
        "tmax = inf and tmax = f32::MAX rays hit differently"
    );

    let mixed: Vec<Ray> = invalid.iter().map(|(r, _)| *r).chain(unbounded).collect();
    let (v, h) = hits_of("mixed", &mixed).unwrap();
    assert_eq!(v["invalid"], invalid.len(), "{v}");
    for class in ["nan", "infinite", "zero_direction", "empty_interval"] {
        let want = invalid.iter().filter(|(_, c)| *c == class).count();
        assert_eq!(v["invalid_by_reason"][class], want, "{class}: {v}");
    }
    for (k, (r, class)) in invalid.iter().enumerate() {
        assert_eq!(r.invalid_reason().unwrap().name(), *class, "{r:?}");
        assert_eq!(h[k], Hit::MISS, "{r:?}");
    }
    assert!(
        h[invalid.len()..] == hu[..],
        "valid rays beside invalid ones changed"
    );
    assert_eq!(v["hits"], vu["hits"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs a failing trace and checks the error names `needle`, the exit is nonzero without a
/// panic, and no output file (nor a temporary) is left behind.
fn fails(dir: &Path, scene: &Path, rays: &Path, out: &Path, needle: &str) {
    let run = vkrt(&["trace", s(scene), "--rays", s(rays), "--out", s(out)]);
    let err = String::from_utf8_lossy(&run.stderr);
    if no_gpu_allowed() && !run.status.success() && err.contains("Vulkan") {
        return;
    }
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(err.contains("vkrt: error:"), "{err}");
    assert!(err.contains(needle), "want `{needle}` in: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out.exists(), "{} was left behind", out.display());
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("hits"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn bad_input_is_a_clear_error_and_leaves_no_file() {
    let dir = scratch("bad");
    let house = example("house.obj");
    let good = dir.join("good.rays");
    std::fs::write(
        &good,
        files::encode_rays(&[Ray::new(Vec3::new(0.0, 1.0, 10.0), -Vec3::Z, 0.0, 1e30)]),
    )
    .unwrap();
    let out = dir.join("hits.bin");

    // missing scene, missing ray file
    fails(&dir, &dir.join("nope.obj"), &good, &out, "nope.obj");
    fails(&dir, &house, &dir.join("nope.rays"), &out, "nope.rays");
    // truncated binary rays
    let truncated = dir.join("cut.rays");
    std::fs::write(&truncated, vec![0u8; 32 * 3 + 5]).unwrap();
    fails(&dir, &house, &truncated, &out, "cut.rays: 101 bytes");
    // bad CSV: a word, then a wrong field count, each with file:line
    let csv = dir.join("bad.csv");
    std::fs::write(&csv, "ox,oy,oz,dx,dy,dz\n0,0,0,1,0,0\n0,0,zero,1,0,0\n").unwrap();
    fails(&dir, &house, &csv, &out, "bad.csv:3");
    std::fs::write(&csv, "0,0,0,1,0,0\n\n0,0,0,1,0\n").unwrap();
    fails(&dir, &house, &csv, &out, "bad.csv:3: 5 values");
    // geometry with NaN is rejected at load
    let nan_obj = dir.join("nan.obj");
    std::fs::write(&nan_obj, "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n").unwrap();
    fails(&dir, &nan_obj, &good, &out, "nan.obj");
    // unwritable output (its directory does not exist)
    let missing_dir_out = dir.join("no-such-dir").join("hits.bin");
    fails(&dir, &house, &good, &missing_dir_out, "hits.bin");
    assert!(!dir.join("no-such-dir").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--accel driver`: the driver's structure answers like brute force where the device has
/// ray query; elsewhere a clear error naming the extension, and no hit file.
#[test]
fn trace_with_the_drivers_structure_or_a_clear_error() {
    let Some(info) = vkrt_ok(&["info", "--json"]) else {
        return;
    };
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    if info["features"]["ray_query"] == true {
        round_trip(
            "motion_blur.toml",
            "hits-driver.bin",
            &["--accel", "driver"],
            TraceOptions::default(),
        );
        // Two levels as the driver's own: bottom-level structures under a top level of
        // instances (the demo: icospheres repeated, the rest with its spheres).
        for (scene, extra) in [
            ("mesh_file.toml", &["--accel", "driver"][..]),
            ("dynamic_demo.toml", &["--accel", "driver-fast-build"][..]),
        ] {
            let name = format!("hits-driver-2l-{}.bin", scene.replace('.', "-"));
            round_trip(scene, &name, extra, TraceOptions::default());
        }
        round_trip(
            "dynamic_demo.toml",
            "hits-driver-2l-any.bin",
            &["--accel", "driver", "--any-hit"],
            TraceOptions {
                query: Query::Any,
                ..TraceOptions::default()
            },
        );
        return;
    }
    let dir = scratch("no-ray-query");
    let rays = dir.join("in.csv");
    std::fs::write(&rays, "0,0,5,0,0,-1\n").unwrap();
    let out = dir.join("hits.csv");
    let scene = example("motion_blur.toml");
    let args = [
        "trace",
        s(&scene),
        "--rays",
        s(&rays),
        "--out",
        s(&out),
        "--accel",
        "driver",
    ];
    let run = vkrt(&args);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "{err}");
    assert!(err.contains("VK_KHR_ray_query"), "{err}");
    assert!(!out.exists(), "a hit file after an error");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The Stanford bunny named 64 times (an 8×8 grid of turned copies, 4.4 M triangles): one
/// bottom level under 64 instances traces it, each hit a point of the triangle it names;
/// flattened, the same scene is refused with the limit it exceeds, and no hit file. `vkrt
/// render` draws it the same way, and refuses it flat; `vkrt build` reports both.
#[test]
fn a_scene_naming_the_bunny_64_times_traces_as_instances() {
    let Some(bunny) = common::bunny_path() else {
        return;
    };
    let dir = scratch("bunnies");
    let mut toml =
        String::from("ambient = [0.4, 0.4, 0.4]\n[camera]\nposition = [0.0, 0.1, 6.0]\n");
    toml += "look_at = [0.0, 0.1, 0.0]\n";
    for j in 0..8 {
        for i in 0..8 {
            toml += &format!(
                "\n[[meshes]]\npath = {:?}\ntranslate = [{}, {}, 0.0]\nrotate = [0.0, {}, 0.0]\n",
                s(&bunny),
                (i as f32 - 3.5) * 0.3,
                (j as f32 - 3.5) * 0.3,
                i * 45 + j * 10
            );
        }
    }
    let scene_path = dir.join("bunnies.toml");
    std::fs::write(&scene_path, toml).unwrap();
    let n = 64;
    let rays: Vec<Ray> = (0..n * n)
        .map(|k| {
            let (x, y) = ((k % n) as f32, (k / n) as f32);
            let o = Vec3::new(0.0, 0.1, 6.0);
            let t = Vec3::new(
                -1.2 + 2.4 * (x + 0.5) / n as f32,
                -1.1 + 2.4 * (y + 0.5) / n as f32,
                0.0,
            );
            Ray::new(o, t - o, 0.0, f32::INFINITY)
        })
        .collect();
    let ray_path = dir.join("in.rays");
    std::fs::write(&ray_path, files::encode_rays(&rays)).unwrap();
    let out = dir.join("hits.bin");
    let args = [
        "trace",
        s(&scene_path),
        "--rays",
        s(&ray_path),
        "--out",
        s(&out),
        "--json",
    ];
    let Some(run) = vkrt_ok(&args) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(
        (v["levels"].as_u64(), v["instances"].as_u64()),
        (Some(2), Some(64)),
        "{v}"
    );
    assert_eq!(v["bottom_levels"], 1, "{v}");
    assert_eq!(v["exhausted"], 0, "{v}");
    let scene = Scene::load(&scene_path).unwrap().scene;
    let per_mesh = scene.meshes[0].indices.len();
    assert_eq!(v["unique_primitives"], per_mesh, "{v}");
    let hits = read_hits(&out);
    let mut n_hits = 0;
    for (r, h) in rays.iter().zip(&hits) {
        if !h.is_hit() {
            continue;
        }
        n_hits += 1;
        let mesh = &scene.meshes[h.prim as usize / per_mesh];
        let m = mesh.world_matrix(0.0);
        let [p0, p1, p2] = mesh.indices[h.prim as usize % per_mesh]
            .map(|i| m.transform_point3(mesh.positions[i as usize]));
        let on_triangle = p0 * (1.0 - h.u - h.v) + p1 * h.u + p2 * h.v;
        let on_ray = r.o() + r.d() * h.t;
        assert!(
            (on_triangle - on_ray).length() < 1e-4,
            "{h:?}: {on_triangle} vs {on_ray}"
        );
    }
    assert_eq!(v["hits"], n_hits);
    assert!(n_hits > 300, "{n_hits} hits");
    // The driver's own two levels (where it has ray query): the same hits, but for its own
    // triangle test (t within 1e-4, the triangle the same but for ties).
    let driver_out = dir.join("hits-driver.bin");
    let driver_args = [&args[..4], &["--out", s(&driver_out), "--accel", "driver"]].concat();
    if vkrt_ok(&["info", "--json"]).is_some_and(|i| {
        serde_json::from_slice::<serde_json::Value>(&i.stdout).unwrap()["features"]["ray_query"]
            == true
    }) {
        let run = vkrt(&driver_args);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let theirs = read_hits(&driver_out);
        let mut other = 0;
        for (a, b) in hits.iter().zip(&theirs) {
            assert_eq!(a.is_hit(), b.is_hit(), "{a:?} vs the driver's {b:?}");
            assert!(
                !a.is_hit() || (a.t - b.t).abs() <= 1e-4 * a.t.abs(),
                "{a:?} vs {b:?}"
            );
            other += usize::from(a.prim != b.prim);
        }
        assert!(other * 100 <= n_hits, "{other} other triangles");
    }
    // Flat, the scene needs more than one buffer's range: a clear error, no file.
    std::fs::remove_file(&out).unwrap();
    let run = vkrt(&[&args[..6], &["--flatten"]].concat());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && err.contains("maxStorageBufferRange"),
        "{err}"
    );
    assert!(!out.exists());
    // It renders as two levels too (shading reads the one bunny, placed per instance); flat
    // it is refused before any file is written.
    let image = dir.join("bunnies.png");
    let render = |extra: &[&str]| {
        let size = [
            "--width", "40", "--height", "40", "--accel", "lbvh", "--json",
        ];
        let args = [
            &["render", s(&scene_path), "-o", s(&image)],
            &size[..],
            extra,
        ]
        .concat();
        vkrt(&args)
    };
    let run = render(&[]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(v["levels"], 2, "{v}");
    assert_memory_reported(&v, scene.triangle_count());
    // (no light: the bunnies in ambient light on the black background)
    let img = image::open(&image).unwrap().to_rgb8();
    let background = *img.get_pixel(0, 0);
    let drawn = img.pixels().filter(|&&p| p != background).count();
    assert!(drawn > 40, "{drawn} bunny pixels of 1,600");
    std::fs::remove_file(&image).unwrap();
    let run = render(&["--flatten"]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && err.contains("maxStorageBufferRange"),
        "{err}"
    );
    assert!(!image.exists());
    // `vkrt build` says why it does not build flat, and what the two levels take.
    let run = vkrt(&["build", s(&scene_path), "--accel", "lbvh", "--json"]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let flat = v["flat_error"].as_str().unwrap_or_default();
    assert!(flat.contains("maxStorageBufferRange"), "{v}");
    assert_eq!(
        (
            v["levels"]["instances"].as_u64(),
            v["levels"]["bottom_levels"].as_u64()
        ),
        (Some(64), Some(1)),
        "{v}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// 1,024 copies of an 81,920-triangle sphere (84 M triangles placed, five times a scene's
/// 2²⁴ held triangles): the scene holds the sphere once, `vkrt scene` counts both, `vkrt
/// trace` answers it as two levels (each hit on the sphere copy whose centre the ray points
/// at), and flattened it is refused before any work, naming the bytes it would need.
#[test]
fn a_thousand_copies_of_a_mesh_load_once_and_trace_as_instances() {
    let dir = scratch("copies");
    let mut toml = String::from(
        "ambient = [0.4, 0.4, 0.4]\n[camera]\nposition = [0.0, 0.0, 40.0]\nlook_at = [0.0, 0.0, 0.0]\n",
    );
    for j in 0..32 {
        for i in 0..32 {
            toml += &format!(
                "\n[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 6\ntranslate = [{}, {}, 0.0]\nscale = 0.45\n",
                i as f32 - 15.5,
                j as f32 - 15.5
            );
        }
    }
    let scene_path = dir.join("copies.toml");
    std::fs::write(&scene_path, toml).unwrap();
    let Some(run) = vkrt_ok(&["scene", s(&scene_path), "--json"]) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(
        (v["triangles"].as_u64(), v["unique_triangles"].as_u64()),
        (Some(1024 * 81_920), Some(81_920)),
        "{v}"
    );
    // One ray straight down the z axis through each sphere's centre.
    let rays: Vec<Ray> = (0..1024)
        .map(|k| {
            let c = Vec3::new((k % 32) as f32 - 15.5, (k / 32) as f32 - 15.5, 0.0);
            Ray::new(c + Vec3::Z * 10.0, -Vec3::Z, 0.0, f32::INFINITY)
        })
        .collect();
    let ray_path = dir.join("in.rays");
    std::fs::write(&ray_path, files::encode_rays(&rays)).unwrap();
    let out = dir.join("hits.bin");
    let args = [
        "trace",
        s(&scene_path),
        "--rays",
        s(&ray_path),
        "-o",
        s(&out),
        "--accel",
        "lbvh",
        "--json",
    ];
    let run = vkrt(&args);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(
        (v["levels"].as_u64(), v["instances"].as_u64()),
        (Some(2), Some(1024)),
        "{v}"
    );
    for (k, h) in read_hits(&out).iter().enumerate() {
        // The scene's primitive ids: copy k holds triangles k·81,920 ...
        assert_eq!(h.prim as usize / 81_920, k, "ray {k}: {h:?}");
        // ... and the ray meets it on its near pole, 10 − 0.45 away (the icosphere's
        // vertices lie on the sphere, its faces within 0.05 % of the radius inside).
        assert!((h.t - 9.55).abs() < 1e-3, "ray {k}: {h:?}");
    }
    std::fs::remove_file(&out).unwrap();
    let info = vkrt_ok(&["info", "--json"]).unwrap();
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let flat_bytes = 36u64 * 1024 * 81_920;
    if info["max_storage_buffer_range"].as_u64().unwrap() >= flat_bytes {
        // (a device whose buffers hold 3 GB traces it flat too)
        std::fs::remove_dir_all(&dir).unwrap();
        return;
    }
    let start = std::time::Instant::now();
    let run = vkrt(&[&args[..], &["--flatten"]].concat());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && err.contains("maxStorageBufferRange"),
        "{err}"
    );
    assert!(err.contains(&flat_bytes.to_string()), "{err}");
    assert!(!out.exists());
    eprintln!("flat refused after {:.2} s", start.elapsed().as_secs_f64());
    std::fs::remove_dir_all(&dir).unwrap();
}
