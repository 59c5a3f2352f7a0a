//! An application written against the Khronos API alone (tests/common/app.rs), run as a
//! child process: natively where the driver has ray query, through `VK_LAYER_VKRT_ray_query`
//! (forced on there), under the validation layer with synchronization validation below or
//! above it. Every run's hits are held to a CPU reference of the same scene, and the layer's
//! to the driver's own.

mod common;

use std::path::PathBuf;
use std::process::Command;

use ash::vk;
use common::app::{self, Hit, Placement, Validation};

// ----- the child -----

/// The child's entry: does nothing unless a parent test started this process for a run.
#[test]
fn child() {
    let Ok(mode) = std::env::var("VKRT_LAYER_APP") else {
        return;
    };
    let out = PathBuf::from(std::env::var("VKRT_LAYER_APP_OUT").unwrap());
    let text = match mode.as_str() {
        "extensions" => extensions_text(),
        "old-api" => format!("{:?}\n", app::create_only(vk::API_VERSION_1_1)),
        "misuse" => {
            app::misuse();
            "torn down\n".to_string()
        }
        m => {
            let validation = match m {
                "below" | "sync2" | "push" | "update-into" => Validation::Below,
                "above" => Validation::Above,
                _ => Validation::Off,
            };
            let frames = match m {
                "sync2" => app::run_sync2(validation),
                "push" => app::run_push_template(validation),
                "update-into" => app::run_update_into(validation),
                _ => app::run(validation),
            }
            .expect("the application's device");
            let mut text = String::new();
            for m in app::messages() {
                text += &format!("message {}\n", m.replace('\n', " "));
            }
            for (f, hits) in frames.iter().enumerate() {
                for h in hits {
                    text += &format!(
                        "hit {f} {} {} {} {} {} {} {} {}\n",
                        h.t, h.kind, h.custom, h.instance, h.geometry, h.primitive, h.u, h.v
                    );
                }
            }
            text
        }
    };
    std::fs::write(out, text).unwrap();
}

/// The first device's extensions and ray-tracing features, one per line.
fn extensions_text() -> String {
    // SAFETY: plain queries of a fresh instance.
    unsafe {
        let entry = ash::Entry::load().unwrap();
        let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_2);
        let instance = entry
            .create_instance(
                &vk::InstanceCreateInfo::default().application_info(&app),
                None,
            )
            .unwrap();
        let pd = instance.enumerate_physical_devices().unwrap()[0];
        let mut names: Vec<String> = instance
            .enumerate_device_extension_properties(pd)
            .unwrap()
            .iter()
            .map(|e| {
                e.extension_name_as_c_str()
                    .unwrap()
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        names.sort();
        let mut asf = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
        let mut rq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default()
            .push_next(&mut asf)
            .push_next(&mut rq);
        instance.get_physical_device_features2(pd, &mut f2);
        let mut text: String = names.iter().map(|n| format!("extension {n}\n")).collect();
        text += &format!(
            "feature accelerationStructure {} rayQuery {} hostCommands {} indirectBuild {}\n",
            asf.acceleration_structure,
            rq.ray_query,
            asf.acceleration_structure_host_commands,
            asf.acceleration_structure_indirect_build
        );
        instance.destroy_instance(None);
        text
    }
}

// ----- the parent -----

/// How a child runs: with the layer (forced or not), or natively.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Through {
    Native,
    Layer {
        force: bool,
    },
    /// The layer's manifest found, the application enabling it (after the validation layer).
    LayerByApp {
        force: bool,
    },
}

fn manifest_dir() -> PathBuf {
    app::manifest_dir(std::path::Path::new(env!("CARGO_TARGET_TMPDIR")))
}

/// Runs the child in `mode` and returns what it wrote, and its standard error.
fn run_child(mode: &str, through: Through) -> (String, String) {
    run_child_with(mode, through, &[])
}

/// [`run_child`] with `env` set in the child's environment.
fn run_child_with(mode: &str, through: Through, env: &[(&str, &str)]) -> (String, String) {
    static RUNS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let run = RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!(
        "layer-app-{}-{run}-{mode}-{}.txt",
        std::process::id(),
        match through {
            Through::Native => "native",
            Through::Layer { .. } => "layer",
            Through::LayerByApp { .. } => "layer-by-app",
        }
    ));
    let mut cmd = app::this_binary_again();
    cmd.args(["child", "--exact", "--nocapture", "--test-threads=1"])
        .env("VKRT_LAYER_APP", mode)
        .env("VKRT_LAYER_APP_OUT", &out)
        .env_remove("VK_INSTANCE_LAYERS")
        .env_remove("VK_LOADER_LAYERS_ENABLE")
        .env_remove("VKRT_LAYER_FORCE")
        .envs(env.iter().copied());
    match through {
        Through::Native => {}
        Through::Layer { force } => {
            app::add_layer_path(&mut cmd, &manifest_dir());
            cmd.env("VK_INSTANCE_LAYERS", "VK_LAYER_VKRT_ray_query");
            if force {
                cmd.env("VKRT_LAYER_FORCE", "1");
            }
        }
        Through::LayerByApp { force } => {
            app::add_layer_path(&mut cmd, &manifest_dir());
            if force {
                cmd.env("VKRT_LAYER_FORCE", "1");
            }
        }
    }
    common::run_to_file(cmd, &out, &format!("the child ({mode})"))
}

/// Whether the driver has its own ray query.
fn driver_has_ray_query() -> bool {
    let (text, _) = run_child("extensions", Through::Native);
    text.lines().any(|l| l == "extension VK_KHR_ray_query")
}

/// The frames' hits and the validation messages a child wrote.
fn parse(text: &str) -> (Vec<Vec<Hit>>, Vec<String>) {
    let mut frames: Vec<Vec<Hit>> = Vec::new();
    let mut messages = Vec::new();
    for line in text.lines() {
        if let Some(m) = line.strip_prefix("message ") {
            messages.push(m.to_string());
        } else if let Some(h) = line.strip_prefix("hit ") {
            let w: Vec<&str> = h.split(' ').collect();
            let f: usize = w[0].parse().unwrap();
            if frames.len() <= f {
                frames.resize(f + 1, Vec::new());
            }
            frames[f].push(Hit {
                t: w[1].parse().unwrap(),
                kind: w[2].parse().unwrap(),
                custom: w[3].parse().unwrap(),
                instance: w[4].parse().unwrap(),
                geometry: w[5].parse().unwrap(),
                primitive: w[6].parse().unwrap(),
                u: w[7].parse().unwrap(),
                v: w[8].parse().unwrap(),
            });
        }
    }
    (frames, messages)
}

// ----- the reference -----

fn level_triangles(level: usize, frame: u32) -> Vec<(u32, u32, [[f64; 3]; 3], bool)> {
    let to64 = |v: [f32; 3]| v.map(f64::from);
    let mut out = Vec::new();
    match level {
        0 => {
            let (v, idx) = app::grid(0.25 * frame as f32);
            for (p, t) in idx.chunks(3).enumerate() {
                out.push((0, p as u32, [0, 1, 2].map(|k| to64(v[t[k] as usize])), true));
            }
        }
        1 => {
            let (v, idx) = app::fan();
            for (p, t) in idx.chunks(3).enumerate() {
                out.push((
                    0,
                    p as u32,
                    [0, 1, 2].map(|k| to64(v[t[k] as usize])),
                    false,
                ));
            }
            // Moved by its transform as the build reads it (in single precision, left to
            // right, as Vulkan's builders apply VkTransformMatrixKHR).
            let m = app::SOUP_TRANSFORM;
            let moved = |v: [f32; 3]| {
                [0, 1, 2].map(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2] + m[r][3])
            };
            for (p, t) in app::soup().chunks(3).enumerate() {
                out.push((1, p as u32, [0, 1, 2].map(|k| to64(moved(t[k]))), true));
            }
        }
        _ => {}
    }
    out
}

/// The world-to-object map of an instance: the inverse of its rows.
fn to_object(p: &Placement, x: [f64; 3], point: bool) -> [f64; 3] {
    let m: [[f64; 4]; 3] = p.rows.map(|r| r.map(f64::from));
    let a = [
        [m[0][0], m[0][1], m[0][2]],
        [m[1][0], m[1][1], m[1][2]],
        [m[2][0], m[2][1], m[2][2]],
    ];
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    let inv = [
        [
            (a[1][1] * a[2][2] - a[1][2] * a[2][1]) / det,
            (a[0][2] * a[2][1] - a[0][1] * a[2][2]) / det,
            (a[0][1] * a[1][2] - a[0][2] * a[1][1]) / det,
        ],
        [
            (a[1][2] * a[2][0] - a[1][0] * a[2][2]) / det,
            (a[0][0] * a[2][2] - a[0][2] * a[2][0]) / det,
            (a[0][2] * a[1][0] - a[0][0] * a[1][2]) / det,
        ],
        [
            (a[1][0] * a[2][1] - a[1][1] * a[2][0]) / det,
            (a[0][1] * a[2][0] - a[0][0] * a[2][1]) / det,
            (a[0][0] * a[1][1] - a[0][1] * a[1][0]) / det,
        ],
    ];
    let y = match point {
        true => [x[0] - m[0][3], x[1] - m[1][3], x[2] - m[2][3]],
        false => x,
    };
    [0, 1, 2].map(|r| inv[r][0] * y[0] + inv[r][1] * y[1] + inv[r][2] * y[2])
}

/// The closest committed hit of every ray of `frame`, and whether it is too close to a tie
/// or an edge for the specification to fix which primitive wins.
fn reference(frame: u32) -> Vec<(Hit, bool)> {
    let placements = app::instances(frame);
    let spheres = app::spheres();
    let force_opaque = vk::GeometryInstanceFlagsKHR::FORCE_OPAQUE.as_raw();
    (0..app::WIDTH * app::WIDTH)
        .map(|i| {
            let (o, d) = app::ray(i, 5.0);
            let (o, d) = (o.map(f64::from), d.map(f64::from));
            // Every accepted hit: (t, hit, near an edge).
            let mut found: Vec<(f64, Hit, bool)> = Vec::new();
            for (k, p) in placements.iter().enumerate() {
                if p.mask & app::CULL_MASK == 0 {
                    continue;
                }
                let (oo, od) = (to_object(p, o, true), to_object(p, d, false));
                for (geometry, primitive, t, opaque) in level_triangles(p.level, frame) {
                    let Some((tt, u, v)) = intercept_ok(common::intersect(oo, od, &t)) else {
                        continue;
                    };
                    let opaque = opaque || p.flags & force_opaque != 0;
                    if !opaque && primitive % 2 != 0 {
                        continue;
                    }
                    let edge = u.min(v).min(1.0 - u - v) < 1e-4;
                    let hit = Hit {
                        t: tt as f32,
                        kind: 1,
                        custom: p.custom,
                        instance: k as u32,
                        geometry,
                        primitive,
                        u: u as f32,
                        v: v as f32,
                    };
                    found.push((tt, hit, edge));
                }
                if p.level == 2 {
                    for (primitive, s) in spheres.iter().enumerate() {
                        let c = [s[0], s[1], s[2]].map(f64::from);
                        let r = f64::from(s[3]);
                        let oc = [oo[0] - c[0], oo[1] - c[1], oo[2] - c[2]];
                        let a = od[0] * od[0] + od[1] * od[1] + od[2] * od[2];
                        let b = oc[0] * od[0] + oc[1] * od[1] + oc[2] * od[2];
                        let cc = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - r * r;
                        let disc = b * b - a * cc;
                        if disc < 0.0 {
                            continue;
                        }
                        let tt = (-b - disc.sqrt()) / a;
                        if tt < 0.0 {
                            continue;
                        }
                        let hit = Hit {
                            t: tt as f32,
                            kind: 2,
                            custom: p.custom,
                            instance: k as u32,
                            geometry: 0,
                            primitive: primitive as u32,
                            u: 0.0,
                            v: 0.0,
                        };
                        found.push((tt, hit, disc < 1e-3 * a));
                    }
                }
            }
            found.sort_by(|a, b| a.0.total_cmp(&b.0));
            match found.first() {
                None => (Hit::default(), false),
                Some(&(t, hit, edge)) => {
                    let tie = found.get(1).is_some_and(|n| n.0 - t < 1e-4 * (1.0 + t));
                    (hit, edge || tie)
                }
            }
        })
        .collect()
}

fn intercept_ok(h: Option<(f64, f64, f64)>) -> Option<(f64, f64, f64)> {
    h.filter(|&(t, _, _)| (0.0..=f64::from(app::T_MAX)).contains(&t))
}

/// Whether two hits agree: the same primitive of the same instance, t and barycentrics
/// within single precision's reach.
fn agree(a: &Hit, b: &Hit) -> bool {
    a.kind == b.kind
        && (a.kind == 0
            || (a.custom == b.custom
                && a.instance == b.instance
                && a.geometry == b.geometry
                && a.primitive == b.primitive
                && (a.t - b.t).abs() <= 1e-4 * (1.0 + b.t.abs())
                && (a.u - b.u).abs() <= 1e-3
                && (a.v - b.v).abs() <= 1e-3))
}

/// Holds `frames` to the reference: every unambiguous ray agrees; returns how many rays hit.
fn check_against_reference(what: &str, frames: &[Vec<Hit>]) -> usize {
    assert_eq!(
        frames.len(),
        4,
        "{what}: three frames and the fragment shader's pass"
    );
    let mut hits = 0;
    for (f, hits_f) in frames.iter().enumerate() {
        // The third frame and the fragment shader trace the second frame's scene.
        let want = reference(f.min(1) as u32);
        assert_eq!(hits_f.len(), want.len());
        let mut wrong = Vec::new();
        for (i, (got, (want, ambiguous))) in hits_f.iter().zip(&want).enumerate() {
            hits += usize::from(got.kind != 0);
            if !ambiguous && !agree(got, want) {
                wrong.push(format!("ray {i}: got {got:?}, want {want:?}"));
            }
        }
        assert!(
            wrong.is_empty(),
            "{what}, frame {f}: {} of {} rays differ from the reference:\n{}",
            wrong.len(),
            hits_f.len(),
            wrong[..wrong.len().min(8)].join("\n")
        );
    }
    hits
}

/// Runs the child in `mode` under the validation layer (`place` names where, for the
/// message): no validation message, no complaint of the layer's; the frames' hits.
fn run_validated(mode: &str, through: Through, place: &str) -> Vec<Vec<Hit>> {
    let (text, stderr) = run_child(mode, through);
    let (frames, messages) = parse(&text);
    assert!(messages.is_empty(), "{place}:\n{}", messages.join("\n"));
    let budget_warnings = assert_layer_quiet(&stderr);
    // The one thing the layer says unasked: where the driver has a loop budget (Mesa
    // 22.3), that an app's own loops can be cut short, once per device.
    let warned = budget_warnings > 0;
    let expected = !matches!(through, Through::Native) && device_has_loop_budget();
    assert_eq!(warned, expected, "the loop-budget warning:\n{stderr}");
    frames
}

/// The layer's own complaints (it logs what it cannot do); how many loop-budget warnings it
/// gave besides.
fn assert_layer_quiet(stderr: &str) -> usize {
    let (warnings, lines): (Vec<&str>, Vec<&str>) = stderr
        .lines()
        .filter(|l| l.starts_with("vkrt layer:"))
        .partition(|l| l.contains("loops once they have run a budget of iterations"));
    assert!(lines.is_empty(), "the layer logged:\n{}", lines.join("\n"));
    warnings.len()
}

/// Whether the test device's driver ends an invocation's loops after a budget
/// (`DeviceInfo::loop_budget`: Mesa 22.3's lavapipe).
fn device_has_loop_budget() -> bool {
    static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *HAS.get_or_init(|| {
        let ctx = vkrt::Context::new(&vkrt::gpu::ContextOptions::default())
            .expect("a Vulkan device for the test");
        ctx.info().loop_budget.is_some()
    })
}

#[test]
fn the_app_traces_through_the_layer_as_the_reference_says_with_validation_below() {
    let frames = run_validated(
        "below",
        Through::Layer {
            force: driver_has_ray_query(),
        },
        "validation below the layer:",
    );
    let hits = check_against_reference("through the layer", &frames);
    // The scene is seen: every instance the cull mask lets through, triangles of both
    // geometries of the second level, and generated hits.
    assert!(
        hits > 800,
        "{hits} hits over two frames of {} rays",
        app::WIDTH * app::WIDTH
    );
    let seen = |f: &dyn Fn(&Hit) -> u32| {
        let mut v: Vec<u32> = frames
            .iter()
            .flatten()
            .filter(|h| h.kind != 0)
            .map(f)
            .collect();
        v.sort();
        v.dedup();
        v
    };
    assert_eq!(seen(&|h| h.custom), [10, 11, 12, 13, 15]);
    assert_eq!(seen(&|h| h.kind), [1, 2]);
    assert_eq!(seen(&|h| h.geometry), [0, 1]);
}

/// Descriptors pushed through a template (`vkCmdPushDescriptorSetWithTemplateKHR`) before
/// the builds are pushed again after them: the dispatch that follows, without a push of its
/// own, reads the application's.
#[test]
fn descriptors_pushed_through_a_template_survive_the_builds() {
    let frames = run_validated(
        "push",
        Through::Layer {
            force: driver_has_ray_query(),
        },
        "validation below the layer, descriptors pushed:",
    );
    check_against_reference("descriptors pushed through a template", &frames);
}

/// An update from one structure into another (`src` ≠ `dst`): the second frame updates the
/// grid and the top level each into a second structure, which the instances and the
/// descriptor name from then on, and the third frame updates those in place.
#[test]
fn an_update_into_another_structure_traces_as_the_reference_says() {
    let frames = run_validated(
        "update-into",
        Through::Layer {
            force: driver_has_ray_query(),
        },
        "validation below the layer, an update into another structure:",
    );
    check_against_reference("an update into another structure", &frames);
}

/// An embedder's command buffer is the embedder's: recording a build, update or copy
/// creates no Vulkan object. vkrt's kernels are compiled when the device is created, and
/// on a device with push descriptors (all three lavapipes) the build kernels push the
/// application's ranges rather than bind descriptor sets.
#[test]
fn recording_builds_updates_and_copies_creates_no_object() {
    let (_, stderr) = run_child_with(
        "off",
        Through::Layer {
            force: driver_has_ray_query(),
        },
        &[(vkrt_layer::STATS_VARIABLE, "1")],
    );
    let created = common::objects_created_while_recording(&stderr);
    let calls = |name: &str| created.iter().filter(|(c, _)| c == name).count();
    // Per frame a bottom-level call and a top-level call: build, update, the same update;
    // and the compaction's two copies.
    assert_eq!(
        calls("vkCmdBuildAccelerationStructuresKHR"),
        6,
        "{created:?}"
    );
    assert_eq!(calls("vkCmdCopyAccelerationStructureKHR"), 2, "{created:?}");
    assert!(
        created.iter().all(|&(_, n)| n == 0),
        "objects created while recording: {created:?}"
    );
}

#[test]
fn validation_above_the_layer_is_silent_about_the_apps_use_of_the_extensions() {
    let frames = run_validated(
        "above",
        Through::LayerByApp {
            force: driver_has_ray_query(),
        },
        "validation above the layer:",
    );
    check_against_reference("through the layer, validated above", &frames);
}

#[test]
fn the_drivers_own_ray_query_gives_what_the_layer_gives() {
    if !driver_has_ray_query() {
        eprintln!("the driver has no ray query: the layer's runs are held to the reference only");
        return;
    }
    let (native, _) = run_child("below", Through::Native);
    let (native, messages) = parse(&native);
    assert!(
        messages.is_empty(),
        "validation of the native run:\n{}",
        messages.join("\n")
    );
    check_against_reference("natively", &native);
    let (layered, _) = run_child("off", Through::Layer { force: true });
    let (layered, _) = parse(&layered);
    let mut differ = 0;
    for f in 0..4 {
        let want = reference(f.min(1) as u32);
        for ((a, b), (_, ambiguous)) in native[f].iter().zip(&layered[f]).zip(&want) {
            differ += usize::from(!ambiguous && !agree(b, a));
        }
    }
    assert_eq!(differ, 0, "rays where the layer and the driver differ");
}

#[test]
fn the_layer_lists_its_extensions_and_is_inert_where_the_driver_has_ray_query() {
    let (native, _) = run_child("extensions", Through::Native);
    let (layered, _) = run_child("extensions", Through::Layer { force: false });
    let (forced, _) = run_child("extensions", Through::Layer { force: true });
    let has = |t: &str, e: &str| t.lines().any(|l| l == format!("extension {e}"));
    for t in [&layered, &forced] {
        for e in [
            "VK_KHR_acceleration_structure",
            "VK_KHR_ray_query",
            "VK_KHR_deferred_host_operations",
        ] {
            assert!(has(t, e), "{e} not listed:\n{t}");
        }
        assert!(
            t.contains("feature accelerationStructure 1 rayQuery 1 hostCommands 0 indirectBuild 0"),
            "{t}"
        );
    }
    if has(&native, "VK_KHR_ray_query") {
        // Inert: the driver's own list and features, untouched.
        assert_eq!(native, layered);
        // Forced: the driver's ray-tracing extensions beyond the three are hidden.
        assert!(
            !has(&forced, "VK_KHR_ray_tracing_position_fetch"),
            "{forced}"
        );
    } else {
        assert!(!has(&native, "VK_KHR_acceleration_structure"));
    }
}

#[test]
fn an_instance_below_vulkan_1_2_gets_feature_not_present_and_a_reason() {
    let force = driver_has_ray_query();
    let (text, stderr) = run_child("old-api", Through::Layer { force });
    assert_eq!(
        text.trim(),
        format!("{:?}", vk::Result::ERROR_FEATURE_NOT_PRESENT)
    );
    assert!(
        stderr.contains("vkrt layer:") && stderr.contains("Vulkan 1.2"),
        "no reason given: {stderr}"
    );
}

#[test]
fn misuse_is_logged_and_nothing_crashes() {
    let force = driver_has_ray_query();
    let (text, stderr) = run_child("misuse", Through::Layer { force });
    assert_eq!(text.trim(), "torn down");
    for expected in [
        // A build into a structure too small for it.
        "its geometries need",
        // A vertex format the extension does not require.
        "vertex format R8G8B8A8_SNORM",
    ] {
        assert!(
            stderr.contains(expected),
            "no log line with {expected:?}:\n{stderr}"
        );
    }
}

/// `vulkaninfo` (Debian: vulkan-tools) through the layer, forced where the driver has ray
/// query: the extensions, their features and the required limits.
#[test]
fn vulkaninfo_lists_the_extensions_and_features_through_the_layer() {
    // A program started under a runner's other glibc cannot load that driver.
    let runner = std::env::var("CARGO_TARGET_X86_64_UNKNOWN_LINUX_GNU_RUNNER");
    if runner.is_ok_and(|r| !r.is_empty())
        || Command::new("vulkaninfo").arg("--help").output().is_err()
    {
        eprintln!("vulkaninfo not runnable here: skipped");
        return;
    }
    let force = driver_has_ray_query();
    let mut cmd = Command::new("vulkaninfo");
    app::add_layer_path(&mut cmd, &manifest_dir());
    cmd.env("VK_INSTANCE_LAYERS", "VK_LAYER_VKRT_ray_query")
        .env_remove("VKRT_LAYER_FORCE");
    if force {
        cmd.env("VKRT_LAYER_FORCE", "1");
    }
    let o = cmd.output().expect("vulkaninfo");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "vulkaninfo failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    for expected in [
        "VK_KHR_acceleration_structure",
        "VK_KHR_ray_query",
        "VK_KHR_deferred_host_operations",
    ] {
        assert!(text.contains(expected), "{expected} not listed");
    }
    let value = |key: &str| {
        text.lines()
            .find(|l| l.trim_start().starts_with(key) && l.contains('='))
            .map(|l| l.rsplit('=').next().unwrap().trim().to_string())
            .unwrap_or_else(|| panic!("{key} not in vulkaninfo's output"))
    };
    assert_eq!(value("accelerationStructure "), "true");
    assert_eq!(value("accelerationStructureHostCommands"), "false");
    assert_eq!(value("rayQuery "), "true");
    assert_eq!(value("maxPrimitiveCount"), (1u64 << 29).to_string());
    assert_eq!(value("maxInstanceCount"), (1u64 << 24).to_string());
}

#[test]
fn a_synchronization_2_application_runs_through_the_layer_with_validation_below() {
    let frames = run_validated(
        "sync2",
        Through::Layer {
            force: driver_has_ray_query(),
        },
        "validation below the layer:",
    );
    check_against_reference("through the layer, synchronization 2", &frames);
}
