//! Measuring every setting of [`super::knobs`], in one run on one device.
//!
//! - **Structure settings** (structures, builders' parameters, kd-tree termination, BVH leaf
//!   size, traversal, intersector): the structure is built over the bunny (best of
//!   `reps`), then the bunny's primary rays (closest hit), shadow rays from their hits (any
//!   hit) and mirror rays (closest hit) are traced through it — the rays of `vkrt bench
//!   trace`, the same for every setting. Costs: build ms, trace ms per ray kind, SAH cost,
//!   bytes. Accuracy: the robustness suite's hard cases run with the setting's builder and
//!   trace options (misses, self-hits, wrong hits, errors), and the bunny's rays whose
//!   answer differs from the reference setting's. Time axis: build + the three traces;
//!   error axis: hard-case failures + differing rays (both are wrong answers).
//! - **Image settings** (samples per pixel, ray depth): the default scene and every effect
//!   scene rendered with the setting on the watertight kd-tree. Time axis: the renders' GPU
//!   ms, summed; error axis: the mean RMSE against the reference.
//! - **Motion settings** (refit vs rebuild): Kolodzey's demo animated (`vkrt bench animate`'s
//!   loop). Time axis: mean update + render ms per frame after the first; error axis: the
//!   last frame's SAH cost over a fresh build's, minus 1.
//!
//! The reference of every image is the same scene at `reference_spp` samples and depth
//! `reference_depth` on the watertight kd-tree with its fp64 fallback; images are compared
//! on display values (the 8-bit sRGB the renderer writes, as [0, 1]), so the error is what a
//! viewer sees and emission scenes do not dominate the mean. The reference's own noise is
//! part of every error (a setting at a quarter of its samples reads ~12 % high).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use super::knobs::StructureSetting;
use super::knobs::{self, Build, GroupSpec, MotionSetting, Settings, Sizes};
use super::{
    pareto, Accuracy, AccuracyReport, Costs, HardCases, ImageFile, KnobGroup, Point, RayCountsInfo,
    TraceMs, UseTimes,
};
use crate::trace_bench::{self as trace_bench, scenes, BenchScene, RayKind, RaySet};
use vkrt::accel::bvh::{self, BvhParams};
use vkrt::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::host::HostStructure;
use vkrt::accel::kdtree::{full_clip, stats, KdNode};
use vkrt::gpu::{Context, GpuError};
use vkrt::render::animate::{self, AnimateOptions};
use vkrt::render::RenderOptions;
use vkrt::scene::Scene;
use vkrt::trace::gpu::Tracer;
use vkrt::trace::robust::{self, SuiteConfig, SuiteSize};
use vkrt::trace::{Hit, Query, TraceOptions};

mod images;

use images::{image_scenes, measure_image, render_all, slug, Compared};

type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// What to run.
#[derive(Clone, Debug)]
pub struct AccuracyOptions {
    /// A smaller run (`--quick`): fewer settings, smaller images, ray sets and hard cases,
    /// one repetition.
    pub quick: bool,
    /// The mesh whose rays time the structures (default: the bunny in `../shared`, else an
    /// icosphere of as many triangles).
    pub mesh: Option<PathBuf>,
    /// The folder of the effect scenes (`scenes/`).
    pub scenes_dir: PathBuf,
    /// The animated scene of the motion group (`scenes/dynamic_demo.toml`).
    pub motion_scene: PathBuf,
    /// The command line, for the report.
    pub command: String,
}

/// Triangles of the stand-in mesh where no mesh is given (the Stanford bunny's count).
/// The structure every reference answer and image is made with: the kd-tree with the
/// watertight test and its fp64 fallback, walked its one way.
const REFERENCE_ACCEL: AccelChoice = AccelChoice {
    kind: AccelKind::KdTree,
    walk: vkrt::accel::walk::Traversal::Stack,
    prefer: vkrt::accel::walk::Prefer::FastTrace,
};

const STAND_IN_TRIANGLES: u64 = 69_451;
/// Triangles of the mesh pipelines are warmed up on.
const WARM_UP_TRIANGLES: u64 = 320;

/// Runs every group; returns the report (fronts and recommendations filled) and the images
/// it compared. `progress(line)` after each setting.
pub fn run(
    ctx: &Context,
    opt: &AccuracyOptions,
    mut progress: impl FnMut(&str),
) -> Result<(AccuracyReport, Vec<ImageFile>), BoxError> {
    let start = Instant::now();
    let sizes = Sizes::new(opt.quick);
    let mut images = Vec::new();

    let rays = RayBench::new(ctx, opt, &sizes)?;
    progress(&format!(
        "rays: {} on {} ({} primary, {} shadow, {} mirror)",
        rays.name,
        rays.scene.geometry.triangle_count(),
        rays.sets[0].rays.len(),
        rays.sets[1].rays.len(),
        rays.sets[2].rays.len()
    ));
    let scenes = image_scenes(ctx, opt, &sizes, &mut images, &mut progress)?;
    let suite = if opt.quick {
        SuiteSize::tiny()
    } else {
        SuiteSize {
            big_soup: 0,
            ..SuiteSize::test()
        }
    };

    let mut groups = Vec::new();
    for spec in knobs::groups(ctx, opt.quick) {
        let GroupSpec {
            id,
            title,
            settings,
        } = spec;
        let (points, axes) = match &settings {
            Settings::Structures(list) => {
                let mut points = Vec::new();
                for s in list {
                    let p =
                        measure_structure(ctx, &rays, &scenes, &sizes, &suite, s, id, &mut images)?;
                    progress(&format!(
                        "{id}: {} — {:.1} ms, error {}",
                        s.label, p.time_ms, p.error
                    ));
                    points.push(p);
                }
                let axes = Axes::structure(&points);
                (points, axes)
            }
            Settings::Images(list) => {
                let mut points = Vec::new();
                for s in list {
                    let p = measure_image(ctx, &scenes, &sizes, s, id, &mut images)?;
                    progress(&format!(
                        "{id}: {} — {:.1} ms, RMSE {:.4}",
                        s.label, p.time_ms, p.error
                    ));
                    points.push(p);
                }
                (points, Axes::image())
            }
            Settings::Motion(list) => {
                let scene = Scene::load(&opt.motion_scene)?.scene;
                let mut points = Vec::new();
                for s in list {
                    let p = measure_motion(ctx, &scene, &sizes, s)?;
                    progress(&format!(
                        "{id}: {} — {:.1} ms/frame, SAH +{:.3}",
                        s.label, p.time_ms, p.error
                    ));
                    points.push(p);
                }
                (points, Axes::motion())
            }
        };
        groups.push(KnobGroup {
            id: id.to_string(),
            title: title.to_string(),
            time_axis: axes.time.into(),
            error_axis: axes.error.into(),
            preview_error_max: axes.preview_error_max,
            uses: axes.uses.iter().map(|u| u.to_string()).collect(),
            points,
            front: Vec::new(),
        });
    }
    pareto::fill_fronts(&mut groups);
    let recommendations = pareto::recommend(&groups);
    let info = ctx.info();
    let report = AccuracyReport {
        device: info.device.clone(),
        driver: info.driver.clone(),
        command: opt.command.clone(),
        quick: opt.quick,
        wall_s: start.elapsed().as_secs_f64(),
        mesh: format!(
            "{} ({} triangles)",
            rays.name,
            rays.scene.geometry.triangle_count()
        ),
        rays: RayCountsInfo {
            primary: rays.sets[0].rays.len(),
            shadow: rays.sets[1].rays.len(),
            secondary: rays.sets[2].rays.len(),
        },
        hard_cases: format!(
            "icospheres of {} subdivisions, {}² grids, {} rays per watertightness case, {} \
             self-intersection primitives × {} spawned rays, {} brute-force-checked rays per \
             case, {} builder-stress triangles",
            suite.sphere_subdivisions,
            suite.grid,
            suite.watertight_rays,
            suite.self_prims,
            suite.spawn_per_hit,
            suite.checked_rays,
            suite.builder_prims
        ),
        image_scenes: scenes.iter().map(|s| s.info.clone()).collect(),
        groups,
        recommendations,
        notes: trace_bench::driver_note(ctx).into_iter().collect(),
    };
    Ok((report, images))
}

/// A group's axes and the uses its knobs matter for.
struct Axes {
    time: &'static str,
    error: &'static str,
    preview_error_max: f64,
    uses: &'static [&'static str],
}

impl Axes {
    /// A preview tolerates one wrong answer in a thousand hard-case rays.
    fn structure(points: &[Point]) -> Self {
        let rays = points
            .iter()
            .filter_map(|p| p.accuracy.hard_cases.map(|h| h.rays))
            .max()
            .unwrap_or(0);
        Self {
            time: "build + trace of the bunny's primary, shadow and mirror rays (ms)",
            error: "wrong answers: hard-case failures + bunny rays differing from the reference",
            preview_error_max: rays as f64 * 1e-3,
            uses: &pareto::USES,
        }
    }

    /// A preview tolerates an RMSE of 0.05 (13 of 255 levels).
    fn image() -> Self {
        Self {
            time: "render GPU ms, all image scenes",
            error: "mean RMSE against the reference (display values, 0..1)",
            preview_error_max: 0.05,
            uses: &pareto::USES[..2],
        }
    }

    /// A preview tolerates a tree 25 % worse than a fresh build.
    fn motion() -> Self {
        Self {
            time: "update + render GPU ms per frame (the dynamic demo)",
            error: "SAH cost over a fresh build's, minus 1 (last frame)",
            preview_error_max: 0.25,
            uses: &pareto::USES[..2],
        }
    }
}

/// The bunny's rays and the reference setting's answers.
struct RayBench {
    name: String,
    scene: BenchScene,
    triangles: Vec<[glam::Vec3; 3]>,
    /// Primary, shadow, mirror.
    sets: Vec<RaySet>,
    /// A small mesh to warm pipelines up on.
    warm: vkrt::accel::primitives::TraceGeometry,
    reference: Vec<Vec<Hit>>,
}

impl RayBench {
    fn new(ctx: &Context, opt: &AccuracyOptions, sizes: &Sizes) -> Result<Self, BoxError> {
        let (name, triangles) = match opt.mesh.clone().or_else(scenes::default_mesh) {
            Some(path) => scenes::mesh_triangles(&path)?,
            None => {
                let (name, tris) = scenes::icosphere_triangles(STAND_IN_TRIANGLES)?;
                (format!("{name} (no mesh given)"), tris)
            }
        };
        let scene = BenchScene::from_triangles(name, &triangles);
        let g = &scene.geometry;
        let primary = RaySet {
            kind: RayKind::Primary,
            rays: scene.primary_rays(sizes.ray_image),
        };
        // The reference: the kd-tree with the watertight test and its fp64 fallback.
        let builder = Build::default_for(REFERENCE_ACCEL)
            .builder(ctx)?
            .expect("a device builder");
        let (geom, _) = trace_bench::build(ctx, &builder, g)?;
        let trace = |set: &RaySet| {
            best_trace(
                ctx,
                &geom,
                set,
                REFERENCE_ACCEL,
                &TraceOptions::default(),
                1,
            )
            .map(|t| t.hits)
        };
        let primary_hits = trace(&primary)?;
        let (shadow, mirror) = scene.secondary_rays(&primary.rays, &primary_hits);
        let reference = vec![primary_hits, trace(&shadow)?, trace(&mirror)?];
        Ok(Self {
            warm: scenes::icosphere(WARM_UP_TRIANGLES)?.geometry,
            name: scene.name.clone(),
            scene,
            triangles,
            sets: vec![primary, shadow, mirror],
            reference,
        })
    }
}

/// One ray set traced `reps` times: the last hits, the best kernel ms, the rays that ran out
/// of steps.
struct Traced {
    hits: Vec<Hit>,
    ms: f64,
    exhausted: u32,
}

fn best_trace(
    ctx: &Context,
    geom: &GpuGeometry,
    set: &RaySet,
    choice: AccelChoice,
    trace: &TraceOptions,
    reps: u32,
) -> Result<Traced, GpuError> {
    let o = TraceOptions {
        query: set.kind.query(),
        ..*trace
    };
    let tracer = Tracer::for_accel(ctx, &o, choice.traversal())?;
    let mut best = Traced {
        hits: Vec::new(),
        ms: f64::MAX,
        exhausted: 0,
    };
    for _ in 0..reps.max(1) {
        let b = tracer.trace_batched(ctx, geom, &set.rays, 0.0, None)?;
        best = Traced {
            ms: best.ms.min(b.profile.ms("trace").unwrap_or(0.0)),
            hits: b.hits,
            exhausted: b.exhausted,
        };
    }
    Ok(best)
}

/// lavapipe compiles a pipeline at its first dispatch, which must not be timed: builds with
/// `builder` over a small mesh and traces a few rays of each kind through it.
fn warm_up(
    ctx: &Context,
    rays: &RayBench,
    builder: &AccelBuilder,
    s: &StructureSetting,
) -> Result<(), BoxError> {
    let (geom, _) = trace_bench::build(ctx, builder, &rays.warm)?;
    for set in &rays.sets {
        let few = RaySet {
            kind: set.kind,
            rays: set.rays[..set.rays.len().min(64)].to_vec(),
        };
        best_trace(ctx, &geom, &few, s.build.choice(), &s.trace, 1)?;
    }
    Ok(())
}

/// Whether two answers to the same ray differ: hit or miss, and for closest-hit queries the
/// primitive or `t` beyond 1e-5 relative.
fn differs(a: &Hit, b: &Hit, query: Query) -> bool {
    if a.is_hit() != b.is_hit() {
        return true;
    }
    query == Query::Closest
        && a.is_hit()
        && (a.prim != b.prim || (a.t - b.t).abs() > 1e-5 * a.t.abs().max(b.t.abs()))
}

/// The failures of the hard cases, by kind.
fn hard_cases(cases: &[robust::CaseResult]) -> HardCases {
    let mut h = HardCases::default();
    for c in cases {
        h.rays += c.rays;
        h.errors += c.errors;
        let wrong = c.failures - c.errors.min(c.failures);
        match c.failure_kind {
            "misses" => h.misses += wrong,
            "re-hits" => h.self_hits += wrong,
            "errors" => h.errors += wrong,
            _ => h.wrong_hits += wrong,
        }
    }
    h
}

#[allow(clippy::too_many_arguments)]
fn measure_structure(
    ctx: &Context,
    rays: &RayBench,
    scenes: &[Compared],
    sizes: &Sizes,
    suite: &SuiteSize,
    s: &StructureSetting,
    group: &str,
    images: &mut Vec<ImageFile>,
) -> Result<Point, BoxError> {
    let g = &rays.scene.geometry;
    let choice = s.build.choice();
    let mut notes = Vec::new();
    // `None`: the host kd-tree with full clipping (the kd-tree walk the reference warmed up).
    let builder = s.build.builder(ctx)?;
    if let Some(b) = &builder {
        warm_up(ctx, rays, b, s)?;
    }
    // Build, best of `reps`; the last one is traced.
    let mut build_ms = f64::MAX;
    let mut built = None;
    let mut host = None;
    for _ in 0..sizes.reps.max(1) {
        drop(built.take());
        let (geom, ms) = match &builder {
            Some(b) => trace_bench::build(ctx, b, g)?,
            None => {
                let t = Instant::now();
                let tree = full_clip::build(&rays.triangles, &s.build.kd_params());
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let geom = GpuGeometry::upload(ctx, g, &tree)?;
                host = Some(HostStructure::KdTree(tree));
                (geom, ms)
            }
        };
        build_ms = build_ms.min(ms);
        built = Some(geom);
    }
    let geom = built.expect("at least one build");
    // Trace each set, best of `reps`.
    let mut trace_ms = [0.0f64; 3];
    let mut differing = 0u64;
    let mut exhausted = 0u32;
    for (k, set) in rays.sets.iter().enumerate() {
        let t = best_trace(ctx, &geom, set, choice, &s.trace, sizes.reps)?;
        trace_ms[k] = t.ms;
        exhausted += t.exhausted;
        differing += t
            .hits
            .iter()
            .zip(&rays.reference[k])
            .filter(|(a, b)| differs(a, b, set.kind.query()))
            .count() as u64;
    }
    if exhausted > 0 {
        notes.push(format!("{exhausted} bunny rays ran out of traversal steps"));
    }
    // Quality and size of the structure.
    let (sah_cost, bytes) = if choice.kind == AccelKind::Driver {
        notes.push("the driver's structure is opaque: no SAH cost".into());
        (None, geom.structure().driver_bytes())
    } else {
        let host = match host {
            Some(h) => h,
            None => geom.structure().download()?,
        };
        match host {
            HostStructure::KdTree(t) => (
                Some(stats::stats(&t, &s.build.kd_params()).sah_cost),
                Some(
                    (t.nodes.len() * std::mem::size_of::<KdNode>() + t.prim_refs.len() * 4) as u64,
                ),
            ),
            HostStructure::Bvh(b) => (
                Some(bvh::validate::sah_cost(&b, &BvhParams::default())),
                Some(
                    (b.nodes.len() * std::mem::size_of::<bvh::BvhNode>()
                        + (b.refs.len() + b.parents.len()) * 4) as u64,
                ),
            ),
        }
    };
    drop(geom);
    // The hard cases, with the setting's builder and trace options.
    let hard = match s.build {
        Build::KdFullClip(_) => {
            notes.push("hard cases: not run (a host reference builder; the device suite builds on the device)".into());
            None
        }
        Build::Builder { .. } => {
            let build = s.build;
            let config = SuiteConfig {
                builder: Some(Arc::new(move |ctx: &Context| {
                    Ok(build.builder(ctx)?.expect("a device builder"))
                })),
                kd_params: s.build.kd_params(),
                trace: s.trace,
                under_instance: false,
            };
            let cases = robust::run_all_with(ctx, suite, &[s.trace.intersector], choice, &config)?;
            Some(hard_cases(&cases))
        }
    };
    // Images, where a render can express the setting.
    let (image_errors, render_ms) = if s.render {
        let (e, ms) = render_all(
            ctx,
            scenes,
            sizes,
            (sizes.test_spp, sizes.reference_depth),
            choice,
            &s.trace,
            &format!("{group}-{}", slug(&s.label)),
            images,
        )?;
        (e, Some(ms))
    } else {
        (Vec::new(), None)
    };
    let trace = TraceMs {
        primary: trace_ms[0],
        shadow: trace_ms[1],
        secondary: trace_ms[2],
    };
    let error = hard.map_or(0, |h| h.failures()) + differing;
    Ok(Point {
        setting: s.label.clone(),
        time_ms: build_ms + trace.total(),
        error: error as f64,
        costs: Costs {
            build_ms: Some(build_ms),
            update_ms: None,
            trace_ms: Some(trace),
            render_ms,
            sah_cost,
            bytes,
        },
        accuracy: Accuracy {
            hard_cases: hard,
            hit_differences: Some(differing),
            images: image_errors,
            sah_ratio: None,
        },
        use_times: Some(UseTimes::new(build_ms, trace.total())),
        note: (!notes.is_empty()).then(|| notes.join("; ")),
    })
}

fn measure_motion(
    ctx: &Context,
    scene: &Scene,
    sizes: &Sizes,
    s: &MotionSetting,
) -> Result<Point, BoxError> {
    let step = sizes.frame_step;
    let frames = sizes
        .frames
        .min((scene.frame_count().saturating_sub(1)) / step.max(1) + 1)
        .max(1);
    let opt = AnimateOptions {
        render: RenderOptions {
            width: Some(sizes.motion_width),
            height: Some(sizes.motion_height),
            spp: Some(1),
            all_effects: false,
            accel: AccelChoice::new(s.kind, Default::default()),
            // the flat structure's update strategies are what this measures
            flatten: true,
            max_level_primitives: None,
        },
        update: s.update,
        frames: (0..frames).collect(),
        radiance: false,
        quality: true,
    };
    // Untimed first: two tiny frames compile the loop's pipelines.
    let warm = AnimateOptions {
        render: RenderOptions {
            width: Some(8),
            height: Some(6),
            ..opt.render
        },
        frames: (0..2.min(frames)).collect(),
        quality: false,
        ..opt.clone()
    };
    let frames_of = |o: &AnimateOptions| {
        animate::run(
            ctx,
            |k| (scene.frame_time(k * step), scene.at_frame(k * step)),
            o,
            &TraceOptions::default(),
            |_| Ok(()),
            |_| {},
        )
    };
    frames_of(&warm)?;
    let report = frames_of(&opt)?;
    // Frame 0 builds in both modes: the frames after it are what an update costs.
    let later: Vec<_> = report.frames.iter().skip(1).collect();
    let rows = if later.is_empty() {
        report.frames.iter().collect()
    } else {
        later
    };
    let n = rows.len().max(1) as f64;
    let update = rows.iter().map(|r| r.update_ms).sum::<f64>() / n;
    let render_ms = rows.iter().map(|r| r.render_ms).sum::<f64>() / n;
    let last = report.frames.last();
    let ratio = last.and_then(|r| Some(r.sah_cost? / r.rebuilt_sah_cost?));
    Ok(Point {
        setting: s.label.clone(),
        time_ms: update + render_ms,
        error: ratio.map_or(f64::NAN, |r| r - 1.0),
        costs: Costs {
            update_ms: Some(update),
            render_ms: Some(render_ms),
            sah_cost: last.and_then(|r| r.sah_cost),
            ..Costs::default()
        },
        accuracy: Accuracy {
            sah_ratio: ratio,
            ..Accuracy::default()
        },
        use_times: None,
        note: Some(format!(
            "{} frames, every {step}th of the animation, {}×{}, 1 spp",
            report.frames.len(),
            report.width,
            report.height
        )),
    })
}
