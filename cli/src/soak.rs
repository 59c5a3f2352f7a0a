//! Long runs that show nothing grows and nothing goes wrong (`vkrt bench soak`).
//!
//! - **Frames**: an animation's frames, many more than it has (the loop wraps), through the
//!   per-frame loop `vkrt animate` uses ([`animate::run`]); every frame's radiance must be
//!   finite, and every `check_every`-th frame must equal, byte for byte, a fresh render of
//!   the same animation frame by a new renderer, and (flat scenes) agree with the CPU twin
//!   ([`cpu::render`]) within its tolerance.
//! - **Builds**: random scenes (a seeded generator: the same seed, the same run) of a random
//!   kind and size, each built by a random structure on the device and traced on the GPU
//!   with random rays, closest and any hit; every answer checked against brute force
//!   ([`robust::check_trace`]).
//!
//! Both record the device memory held through the allocator and the process's resident
//! host memory after every frame or build; the growth from the end of a warm-up (caches
//! and pools settle: pipelines, the allocator's blocks) to the end is the measure.

use std::time::Instant;

use glam::{Vec3, Vec4};
use serde::Serialize;

use vkrt::accel::device::{AccelChoice, AccelKind};
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{Context, GpuError};
use vkrt::host::host_rss_bytes;
use vkrt::render::animate::{self, AnimateOptions, FrameRow};
use vkrt::render::gpu::Update;
use vkrt::render::output::srgb8;
use vkrt::render::{cpu, Plan, RenderOptions, RenderScene};
use vkrt::scene::gen::{self, Rng};
use vkrt::scene::Scene;
use vkrt::trace::robust::{self, CheckedTrace};
use vkrt::trace::{Query, TraceOptions};

type Error = Box<dyn std::error::Error + Send + Sync>;

/// Growth above which a soak fails: 1 %.
pub const MAX_GROWTH: f64 = 0.01;

/// Memory at one point of a run.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Memory {
    /// Bytes of the live allocations through vkrt's allocator.
    pub device_bytes: u64,
    /// Live allocations through vkrt's allocator.
    pub device_allocations: u64,
    /// The process's resident host memory (Linux; absent elsewhere). On a device whose
    /// memory is host memory (lavapipe) it holds the device's allocations too.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub host_rss_bytes: Option<u64>,
}

impl Memory {
    /// Now.
    pub fn now(ctx: &Context) -> Self {
        let m = ctx.memory();
        Self {
            device_bytes: m.allocated_bytes,
            device_allocations: m.allocations,
            host_rss_bytes: host_rss_bytes(),
        }
    }

    fn of(f: &FrameRow) -> Self {
        Self {
            device_bytes: f.device_bytes,
            device_allocations: f.device_allocations,
            host_rss_bytes: f.host_rss_bytes,
        }
    }
}

/// Memory at the end of the warm-up and at the end, and the growth between.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Growth {
    /// Frames or builds of the warm-up.
    pub warm_up: u32,
    /// After the warm-up.
    pub warm: Memory,
    /// After the last frame or build.
    pub end: Memory,
    /// (end − warm) ÷ warm of the device bytes (0 when both are 0).
    pub device_growth: f64,
    /// (end − warm) ÷ warm of the resident host memory.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub host_rss_growth: Option<f64>,
}

impl Growth {
    fn new(warm_up: u32, warm: Memory, end: Memory) -> Self {
        let rel = |a: u64, b: u64| match a {
            0 => f64::from(u8::from(b > 0)),
            _ => (b as f64 - a as f64) / a as f64,
        };
        Self {
            warm_up,
            warm,
            end,
            device_growth: rel(warm.device_bytes, end.device_bytes),
            host_rss_growth: warm
                .host_rss_bytes
                .zip(end.host_rss_bytes)
                .map(|(a, b)| rel(a, b)),
        }
    }

    /// Whether the device bytes, or with `rss` the resident host memory, grew more than
    /// [`MAX_GROWTH`]. (Under the validation layer RSS is no measure: the layer's own
    /// tracking grows by tens of KB a frame.)
    pub fn grew(&self, rss: bool) -> bool {
        self.device_growth > MAX_GROWTH
            || rss && self.host_rss_growth.is_some_and(|g| g > MAX_GROWTH)
    }
}

/// How the frame soak runs.
#[derive(Clone, Debug)]
pub struct FrameSoakOptions {
    /// Frames rendered; frame `k` shows the animation's frame `k mod` its frame count.
    pub frames: u32,
    /// Every this many frames (and the last), the frame is checked against a fresh render
    /// and the CPU twin.
    pub check_every: u32,
    /// Image size, samples, structure.
    pub render: RenderOptions,
    /// How the structure follows the primitives.
    pub update: Update,
}

/// One checked frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameCheck {
    /// The frame's number in the soak.
    pub frame: u32,
    /// The animation's frame it showed.
    pub animation_frame: u32,
    /// Whether a fresh render of the same animation frame is the same image, byte for byte
    /// (8-bit and linear radiance).
    pub fresh_equal: bool,
    /// 8-bit channels differing by more than 1/255 from the CPU twin, of `channels`
    /// (flat scenes only: the twin walks one level).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub twin_off: Option<u64>,
    /// Channels compared with the twin.
    pub channels: u64,
}

impl FrameCheck {
    /// The twin may differ where a transcendental's last bit or a traversal tie flips a
    /// sample: at most 1 channel in 200 by more than 1/255 (as the renderer's tests allow).
    pub fn ok(&self) -> bool {
        self.fresh_equal && self.twin_off.is_none_or(|off| off * 200 <= self.channels)
    }
}

/// What the frame soak found.
#[derive(Clone, Debug, Serialize)]
pub struct FrameSoak {
    /// Frames rendered.
    pub frames: u32,
    /// The animation's frame count (the soak wraps around it).
    pub animation_frames: u32,
    /// The structure and its walk.
    pub accel: String,
    /// How it followed the primitives.
    pub update: Update,
    /// 2: two levels, 1: flat.
    pub levels: u32,
    /// Image width, height and samples per pixel.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Frames with a non-finite radiance value.
    pub non_finite_frames: u64,
    /// Frames whose structure was redone (a wave overflowed, a kd-tree outgrew its budget).
    pub redone_frames: u64,
    /// The checked frames.
    pub checks: Vec<FrameCheck>,
    /// Non-finite frames plus failed checks.
    pub mismatches: u64,
    /// Device memory and RSS growth from the warm-up to the end.
    pub memory: Growth,
    /// Mean wall ms per frame of the soak loop.
    pub mean_frame_ms: f64,
    /// Wall seconds of the whole soak, checks included.
    pub wall_s: f64,
}

/// A frame kept for its check.
struct Kept {
    frame: u32,
    rgba: Vec<u8>,
    radiance: Vec<[f32; 3]>,
}

/// Renders `opt.frames` frames of `scene` (wrapping its animation) through the animation
/// loop, then checks the kept frames; the warm-up is the first tenth of the frames.
pub fn soak_frames(
    ctx: &Context,
    scene: &Scene,
    opt: &FrameSoakOptions,
    mut progress: impl FnMut(u32),
) -> Result<FrameSoak, Error> {
    let start = Instant::now();
    let count = scene.frame_count().max(1);
    if opt.frames < 2 {
        return Err("a frame soak needs at least 2 frames".into());
    }
    let every = opt.check_every.max(1);
    let last = opt.frames - 1;
    let checked = |k: u32| k % every == 0 || k == last;
    let at = |k: u32| (scene.frame_time(k % count), scene.at_frame(k % count));
    let animate = AnimateOptions {
        render: opt.render,
        update: opt.update,
        frames: (0..opt.frames).collect(),
        radiance: true,
        quality: false,
    };
    let mut kept: Vec<Kept> = Vec::new();
    let mut non_finite = 0u64;
    let report = animate::run(
        ctx,
        at,
        &animate,
        &TraceOptions::default(),
        |f| {
            let radiance = f.radiance.unwrap_or_default();
            if radiance.is_empty() || radiance.iter().flatten().any(|c| !c.is_finite()) {
                non_finite += 1;
            }
            if checked(f.k) {
                kept.push(Kept {
                    frame: f.k,
                    rgba: f.rgba,
                    radiance,
                });
            }
            Ok(())
        },
        &mut progress,
    )?;
    let rows = &report.frames;
    let warm_up = (opt.frames / 10).max(1);
    let memory = Growth::new(
        warm_up,
        Memory::of(&rows[warm_up as usize - 1]),
        Memory::of(rows.last().expect("frames ≥ 2")),
    );
    let mean_frame_ms = rows.iter().map(|r| r.wall_ms).sum::<f64>() / rows.len() as f64;
    let redone_frames = rows.iter().filter(|r| r.redone > 0).count() as u64;

    // The checks, after the soak (their renderers' memory is not the loop's).
    let mut checks = Vec::with_capacity(kept.len());
    for k in kept {
        let j = k.frame % count;
        let fresh = AnimateOptions {
            frames: vec![j],
            ..animate.clone()
        };
        let mut image = None;
        animate::run(
            ctx,
            |i| (scene.frame_time(i), scene.at_frame(i)),
            &fresh,
            &TraceOptions::default(),
            |f| {
                image = Some(f);
                Ok(())
            },
            |_| {},
        )?;
        let image = image.ok_or("the fresh render gave no frame")?;
        let fresh_equal = image.rgba == k.rgba
            && image.radiance.as_deref().is_some_and(|r| {
                r.len() == k.radiance.len()
                    && r.iter()
                        .flatten()
                        .zip(k.radiance.iter().flatten())
                        .all(|(a, b)| a.to_bits() == b.to_bits())
            });
        let (_, frame_scene) = at(j);
        let plan = Plan::new(&frame_scene, &opt.render.for_device(ctx))?;
        let (twin_off, channels) = match plan.levels {
            1 => {
                let rs = RenderScene::on_device(&frame_scene, &plan);
                let twin = cpu::render(&rs, &plan, &TraceOptions::default());
                let off = twin
                    .radiance
                    .iter()
                    .flatten()
                    .zip(k.radiance.iter().flatten())
                    .filter(|(a, b)| (i32::from(srgb8(**a)) - i32::from(srgb8(**b))).abs() > 1)
                    .count() as u64;
                (Some(off), 3 * twin.radiance.len() as u64)
            }
            _ => (None, 0),
        };
        checks.push(FrameCheck {
            frame: k.frame,
            animation_frame: j,
            fresh_equal,
            twin_off,
            channels,
        });
    }
    let mismatches = non_finite + checks.iter().filter(|c| !c.ok()).count() as u64;
    Ok(FrameSoak {
        frames: opt.frames,
        animation_frames: count,
        accel: report.accel,
        update: report.update,
        levels: report.levels,
        width: report.width,
        height: report.height,
        spp: report.spp,
        non_finite_frames: non_finite,
        redone_frames,
        checks,
        mismatches,
        memory,
        mean_frame_ms,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

/// How the build soak runs.
#[derive(Clone, Debug)]
pub struct BuildSoakOptions {
    /// Scenes built and traced.
    pub builds: u32,
    /// The generator's seed: the same seed, the same scenes, structures and rays.
    pub seed: u64,
    /// The largest scene, in primitives (sizes are log-uniform from 1).
    pub max_primitives: u32,
    /// Rays per scene (traced once per query: closest and any hit).
    pub rays: usize,
}

/// The kinds of random scene.
pub const SCENE_KINDS: [&str; 6] = [
    "soup",
    "icosphere",
    "grid",
    "heightfield",
    "spheres",
    "soup+spheres",
];

/// Scene `kind` of about `n` primitives (at least 1), from `rng`.
pub fn random_scene(kind: &str, n: u32, rng: &mut Rng) -> Result<TraceGeometry, Error> {
    let n = n.max(1);
    let tris = |m: &vkrt::scene::Mesh| -> Vec<[Vec3; 3]> {
        m.indices
            .iter()
            .map(|t| t.map(|i| m.positions[i as usize]))
            .collect()
    };
    let spheres = |n: u32, rng: &mut Rng| -> Vec<Vec4> {
        let r = 0.5 / (n as f32).cbrt();
        (0..n)
            .map(|_| (rng.vec3_signed()).extend(r * rng.range(0.1, 1.0)))
            .collect()
    };
    let grid = |n: u32| -> (u32, u32) {
        let nx = ((n as f32 / 2.0).sqrt() as u32).max(1);
        (nx, (n / (2 * nx)).max(1))
    };
    Ok(match kind {
        "soup" => TraceGeometry::from_triangles(&tris(&gen::random_soup(n, rng.next_u64())?)),
        "icosphere" => {
            let f = ((n as f32 / 20.0).sqrt().round() as u32).max(1);
            TraceGeometry::from_triangles(&tris(&gen::geodesic_sphere(f)?))
        }
        "grid" => {
            let (nx, ny) = grid(n);
            TraceGeometry::from_triangles(&tris(&gen::integer_grid(nx, ny)?))
        }
        "heightfield" => {
            let (nx, ny) = grid(n);
            let mut m = gen::integer_grid(nx, ny)?;
            let heights: Vec<Vec3> = m
                .positions
                .iter()
                .map(|p| Vec3::new(p.x, p.y, rng.range(-1.0, 1.0)))
                .collect();
            m.positions = std::sync::Arc::new(heights);
            TraceGeometry::from_triangles(&tris(&m))
        }
        "spheres" => TraceGeometry::from_triangles_and_spheres(&[], &spheres(n, rng)),
        "soup+spheres" => {
            let t = (n / 2).max(1);
            let soup = tris(&gen::random_soup(t, rng.next_u64())?);
            TraceGeometry::from_triangles_and_spheres(&soup, &spheres((n - t).max(1), rng))
        }
        _ => return Err(format!("unknown scene kind {kind}").into()),
    })
}

/// One build of the soak that went wrong (the first few are kept).
#[derive(Clone, Debug, Serialize)]
pub struct BuildCase {
    /// Its number in the soak.
    pub build: u32,
    /// The scene's kind.
    pub kind: &'static str,
    /// Its primitives.
    pub primitives: u64,
    /// The structure and walk.
    pub accel: String,
    /// What the check found.
    pub result: CheckedTrace,
}

/// What the build soak found.
#[derive(Clone, Debug, Serialize)]
pub struct BuildSoak {
    /// Scenes built and traced.
    pub builds: u32,
    /// The generator's seed.
    pub seed: u64,
    /// Primitives over every build.
    pub primitives: u64,
    /// Builds per structure label.
    pub per_accel: std::collections::BTreeMap<String, u32>,
    /// Builds per scene kind.
    pub per_kind: std::collections::BTreeMap<&'static str, u32>,
    /// Rays traced (both queries) and checked against brute force.
    pub rays: u64,
    /// Answers unlike brute force's, on vkrt's structures (watertight: none expected).
    pub mismatches: u64,
    /// Answers unlike brute force's on the driver's structure: reported, not a failure
    /// (Vulkan promises no watertightness; rays aimed at shared edges may slip through).
    pub driver_mismatches: u64,
    /// Rays that ran out of traversal steps.
    pub exhausted: u64,
    /// Structures that did not validate.
    pub invalid: u64,
    /// The first builds with a mismatch, an exhausted ray or an invalid structure.
    pub failed: Vec<BuildCase>,
    /// Device memory and RSS growth from the warm-up to the end.
    pub memory: Growth,
    /// Wall seconds.
    pub wall_s: f64,
}

/// Runs `opt.builds` random builds and traces. The first builds cover every structure
/// (`AccelChoice::all_on`) over triangles, then over triangles and spheres, at the largest
/// size, so every pipeline exists and the
/// allocators have seen the largest scene; the warm-up is those or the first tenth of the
/// builds, whichever is more.
pub fn soak_builds(
    ctx: &Context,
    opt: &BuildSoakOptions,
    mut progress: impl FnMut(u32),
) -> Result<BuildSoak, Error> {
    let start = Instant::now();
    let choices = AccelChoice::all_on(ctx);
    // The warm-up's first builds: every structure over triangles, then over triangles and
    // spheres, at the largest size.
    let cover: Vec<(AccelChoice, &'static str)> = ["soup", "soup+spheres"]
        .into_iter()
        .flat_map(|kind| choices.iter().map(move |&c| (c, kind)))
        .collect();
    if opt.builds as usize <= cover.len() {
        return Err(format!(
            "a build soak needs more than {} builds (its warm-up covers every structure \
             over triangles, and over triangles and spheres)",
            cover.len()
        )
        .into());
    }
    let warm_up = (opt.builds / 10).max(cover.len() as u32);
    let mut rng = Rng::new(opt.seed);
    let mut out = BuildSoak {
        builds: opt.builds,
        seed: opt.seed,
        primitives: 0,
        per_accel: Default::default(),
        per_kind: Default::default(),
        rays: 0,
        mismatches: 0,
        driver_mismatches: 0,
        exhausted: 0,
        invalid: 0,
        failed: Vec::new(),
        memory: Growth::new(0, Memory::default(), Memory::default()),
        wall_s: 0.0,
    };
    let mut warm = Memory::default();
    let max_log = (opt.max_primitives.max(1) as f32).ln();
    for b in 0..opt.builds {
        let (accel, kind, n) = match cover.get(b as usize) {
            Some(&(c, kind)) => (c, kind, opt.max_primitives),
            None => (
                choices[rng.below(choices.len() as u32) as usize],
                SCENE_KINDS[rng.below(SCENE_KINDS.len() as u32) as usize],
                rng.range(0.0, max_log).exp() as u32,
            ),
        };
        let geometry = random_scene(kind, n, &mut rng)?;
        let primitives = geometry.primitive_count() as u64;
        let rays = robust::random_rays(&geometry, opt.rays, rng.next_u64());
        let result =
            robust::check_trace(ctx, geometry, accel, &rays, &[Query::Closest, Query::Any])
                .map_err(|e: GpuError| {
                    format!("build {b} ({kind}, {n}, {}): {e}", accel.label())
                })?;
        drop(rays);
        out.primitives += primitives;
        *out.per_accel.entry(accel.label()).or_default() += 1;
        *out.per_kind.entry(kind).or_default() += 1;
        out.rays += result.rays;
        let driver = accel.kind == AccelKind::Driver;
        match driver {
            true => out.driver_mismatches += result.mismatches,
            false => out.mismatches += result.mismatches,
        }
        out.exhausted += result.exhausted;
        out.invalid += result.invalid;
        let failed = !driver && result.mismatches > 0 || result.exhausted + result.invalid > 0;
        if failed && out.failed.len() < 16 {
            out.failed.push(BuildCase {
                build: b,
                kind,
                primitives,
                accel: accel.label(),
                result,
            });
        }
        log::debug!(
            "build {b}: {kind}, {primitives} primitives, {}: {result:?}; host RSS {:?}",
            accel.label(),
            host_rss_bytes()
        );
        if b + 1 == warm_up {
            warm = Memory::now(ctx);
        }
        progress(b + 1);
    }
    out.memory = Growth::new(warm_up, warm, Memory::now(ctx));
    out.wall_s = start.elapsed().as_secs_f64();
    Ok(out)
}
