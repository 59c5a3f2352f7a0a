//! Shared test setup: a context with validation and synchronization validation on (when
//! the Khronos layer is installed and VKRT_VALIDATION is not 0), and a check that the layer
//! stayed silent.
#![allow(dead_code, reason = "each test binary uses a different part")]

use std::sync::{Mutex, MutexGuard};

use vkrt::gpu::{Context, ContextOptions};

/// One Vulkan test at a time per test binary. The validation layer (1.3.239) looks every
/// call's dispatch key up in a global map that creating an instance or device writes to,
/// without a lock (Vulkan-ValidationLayers issue #4391): a test creating its context while
/// another test records crashed the suite with SIGSEGV in vkAllocateDescriptorSets, about
/// once in ten runs of kdtree_gpu. Serialising the tests that hold a context rules it out.
static VULKAN_TURN: Mutex<()> = Mutex::new(());

/// Waits for this test's turn to use Vulkan; hold the guard while any Vulkan object of the
/// test is alive. A test that panicked in its turn poisons nothing the next one needs.
pub fn vulkan_turn() -> MutexGuard<'static, ()> {
    VULKAN_TURN
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// A test's context, holding its Vulkan turn until the context is gone (fields drop in
/// order: the context first, then the turn).
pub struct TestContext {
    ctx: Context,
    _turn: MutexGuard<'static, ()>,
}

impl std::ops::Deref for TestContext {
    type Target = Context;
    fn deref(&self) -> &Context {
        &self.ctx
    }
}

/// A context on the test device, in this test's Vulkan turn. No device is a loud failure
/// unless VKRT_ALLOW_NO_GPU=1.
pub fn context() -> Option<TestContext> {
    let turn = vulkan_turn();
    match Context::new(&ContextOptions::for_tests()) {
        Ok(ctx) => {
            if !ctx.validation_enabled() {
                eprintln!(
                    "note: validation layer not enabled (not installed or VKRT_VALIDATION=0)"
                );
            }
            Some(TestContext { ctx, _turn: turn })
        }
        Err(e) if std::env::var("VKRT_ALLOW_NO_GPU").is_ok_and(|v| v == "1") => {
            eprintln!("skipped: no Vulkan device ({e}) and VKRT_ALLOW_NO_GPU=1");
            None
        }
        Err(e) => panic!(
            "no Vulkan device for the tests: {e} (run ./x setup, or VKRT_ALLOW_NO_GPU=1 to skip)"
        ),
    }
}

/// Fails the test if the validation layer said anything.
pub fn assert_silent(ctx: &Context) {
    let messages = ctx.take_validation_messages();
    assert!(
        messages.is_empty(),
        "validation reported {} message(s):\n{}",
        messages.len(),
        messages
            .iter()
            .map(|m| m.to_string())
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// Deterministic pseudo-random numbers (splitmix64), so failures reproduce.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
    }

    /// A point in [-1, 1)³ (x, then y, then z drawn).
    pub fn next_vec3(&mut self) -> glam::Vec3 {
        glam::Vec3::new(self.next_f32(), self.next_f32(), self.next_f32())
    }
}

#[cfg(feature = "verify")]
/// The sizes every primitive is tested at: empty, one, around the subgroup and the workgroup
/// size and the tile, several tiles, and large ones past every scan level (2^20+13 and
/// 2^24+3, unless VKRT_TEST_QUICK=1).
pub fn edge_sizes(subgroup: usize, workgroup: usize, tile: usize) -> Vec<usize> {
    // VKRT_TEST_QUICK=1 (while developing) leaves the large sizes out.
    let quick = std::env::var("VKRT_TEST_QUICK").is_ok_and(|v| v == "1");
    vkrt::verify::edge_sizes(subgroup, workgroup, tile, !quick)
}

/// World-space triangles of a mesh.
pub fn mesh_triangles(mesh: &vkrt::scene::Mesh) -> Vec<[glam::Vec3; 3]> {
    mesh.indices
        .iter()
        .map(|t| {
            [
                mesh.positions[t[0] as usize],
                mesh.positions[t[1] as usize],
                mesh.positions[t[2] as usize],
            ]
        })
        .collect()
}

/// The checkout's root: the nearest folder holding `Cargo.lock` above the manifest of the
/// crate under test (this file serves the library's tests and, from cli/, the command
/// line's).
pub fn checkout() -> &'static std::path::Path {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .find(|dir| dir.join("Cargo.lock").is_file())
        .expect("a Cargo.lock above the crate")
}

/// The bunny's OBJ in ../shared, or `None` (with a printed skip) when ../shared is absent.
pub fn bunny_path() -> Option<std::path::PathBuf> {
    let path = checkout().join("../shared/scenes/stanford-bunny.obj");
    if !path.exists() {
        eprintln!("skipped the bunny: {} not present", path.display());
        return None;
    }
    Some(path)
}

#[cfg(feature = "scene-files")]
/// The bunny's triangles, or `None` (with a printed skip) when ../shared is absent.
pub fn bunny() -> Option<Vec<[glam::Vec3; 3]>> {
    let path = bunny_path()?;
    Some(
        vkrt::scene::Scene::load(&path)
            .unwrap()
            .scene
            .triangles_world(0.0),
    )
}

/// The hard cases every kd-tree builder must terminate on and stay valid: identical,
/// single, two, all in one plane, flat axis-aligned quads on candidate planes, one huge over
/// many tiny, zero-area and signed-zero triangles.
pub fn kdtree_hard_cases() -> Vec<(&'static str, Vec<[glam::Vec3; 3]>)> {
    use glam::Vec3;
    let t = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let mut rng = Rng(3);
    let planar = (0..2000)
        .map(|_| {
            let o = Vec3::new(rng.next_f32() * 10.0, rng.next_f32() * 10.0, 0.0);
            [
                o,
                o + Vec3::new(0.3, 0.0, 0.0),
                o + Vec3::new(0.0, 0.3, 0.0),
            ]
        })
        .collect();
    let mut flats = Vec::new();
    for i in 0..40 {
        let x = i as f32;
        flats.push([
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x, 1.0, 0.0),
            Vec3::new(x, 0.0, 1.0),
        ]);
        flats.push([
            Vec3::new(0.0, x, 0.0),
            Vec3::new(1.0, x, 0.0),
            Vec3::new(0.0, x, 1.0),
        ]);
        flats.push([
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x + 1.0, 1.0, 0.0),
            Vec3::new(x, 1.0, 0.0),
        ]);
    }
    let mut mixed: Vec<[Vec3; 3]> = (0..5000)
        .map(|_| {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            [o, o + Vec3::splat(1e-3), o + Vec3::new(1e-3, 0.0, 0.0)]
        })
        .collect();
    mixed.push([
        Vec3::splat(-100.0),
        Vec3::new(100.0, -100.0, 0.0),
        Vec3::new(0.0, 100.0, 100.0),
    ]);
    let degenerate = vec![
        [Vec3::ONE; 3],
        [Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
        t,
        [Vec3::new(-0.0, 0.0, -0.0), Vec3::X, Vec3::Z],
    ];
    vec![
        ("identical", vec![t; 500]),
        ("single", vec![t]),
        ("two", vec![t, [t[0] + 3.0, t[1] + 3.0, t[2] + 3.0]]),
        ("planar", planar),
        ("flat-quads", flats),
        ("huge+tiny", mixed),
        ("degenerate", degenerate),
    ]
}

/// VKRT_TEST_QUICK=1, while developing: tests trim what does not depend on the lane count.
pub fn quick() -> bool {
    std::env::var("VKRT_TEST_QUICK").is_ok_and(|v| v == "1")
}

/// Same hit or miss; the same primitive with `t` within 1e-5 relative, or another one at a
/// tie (`t` equal within 1e-6 relative).
pub fn same_answer(a: &vkrt::trace::Hit, b: &vkrt::trace::Hit) -> bool {
    if a.is_hit() != b.is_hit() {
        return false;
    }
    if !a.is_hit() {
        return true;
    }
    let scale = a.t.abs().max(b.t.abs()).max(1e-30);
    if a.prim == b.prim {
        (a.t - b.t).abs() <= 1e-5 * scale
    } else {
        // a different primitive only in a tie (equal t up to rounding)
        (a.t - b.t).abs() <= 1e-6 * scale
    }
}

/// Whether a missing Vulkan device is allowed (VKRT_ALLOW_NO_GPU=1): tests then skip.
pub fn no_gpu_allowed() -> bool {
    std::env::var("VKRT_ALLOW_NO_GPU").is_ok_and(|v| v == "1")
}

/// Compiles a compute shader with glslc (a renderer's own compiler) against the library's
/// include files, with `-D` `defines`; the SPIR-V, or glslc's message.
pub fn compile_glsl(source: &str, defines: &[&str]) -> Result<Vec<u32>, String> {
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("vkrt-glslc-{}-{n}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let src = dir.join("shader.comp");
    let out = dir.join("shader.spv");
    std::fs::write(&src, source).map_err(|e| e.to_string())?;
    let mut glslc = std::process::Command::new("glslc");
    for d in defines {
        glslc.arg(format!("-D{d}"));
    }
    let result = glslc
        .arg("--target-env=vulkan1.2")
        .arg("-I")
        .arg(vkrt::accel::shader_library::include_dir())
        .arg(&src)
        .arg("-o")
        .arg(&out)
        .output();
    let spirv = match result {
        Err(e) => Err(format!(
            "cannot run glslc ({e}): install it (Debian: glslc)"
        )),
        Ok(o) if !o.status.success() => Err(String::from_utf8_lossy(&o.stderr).into_owned()),
        Ok(_) => std::fs::read(&out)
            .map(|b| bytemuck::pod_collect_to_vec::<u8, u32>(&b))
            .map_err(|e| e.to_string()),
    };
    let _ = std::fs::remove_dir_all(&dir);
    spirv
}

/// vkrtTrace's closest hits through the structure whose handle lies at device address
/// `handle` (`gpu.handle_probe`), every ray at `time`; `mode` as the probe reads it. Per ray:
/// t bits (all ones for a miss), geometry, primitive, instance.
pub fn probe_handle(
    ctx: &Context,
    handle: u64,
    rays: &[vkrt::trace::Ray],
    mode: u32,
    time: f32,
) -> Vec<[u32; 4]> {
    use vkrt::gpu::{Buffer, BufferArg, Recorder, Spec};
    let kernel = ctx
        .kernel(
            &vkrt::gpu::kernels::GPU_HANDLE_PROBE_ADDRESS,
            &Spec::new().workgroup(64),
        )
        .unwrap();
    let ray_buf = Buffer::from_slice(ctx, "probe.rays", rays).unwrap();
    let out = Buffer::<[u32; 4]>::zeroed(ctx, "probe.hits", rays.len()).unwrap();
    let push = [
        rays.len() as u32,
        mode,
        handle as u32,
        (handle >> 32) as u32,
        time.to_bits(),
        0,
    ];
    let mut rec = Recorder::new(ctx).unwrap();
    let groups = rec.groups_1d(rays.len() as u64, 64);
    let b: [&dyn BufferArg; 2] = [&ray_buf, &out];
    rec.dispatch(&kernel, groups, &b, &push);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    out.download().unwrap()
}
