//! The gpu layer on the test device (lavapipe in CI), under validation with
//! synchronization validation: kernels against CPU twins, the subgroup size kernels see,
//! the barrier net, the embedding path and the profiler.

mod common;

use vkrt::gpu::{kernels, Buffer, Context, GpuError, Kernel, RawBuffer, Recorder, Spec};
use vkrt::verify;

const SAXPY_WG: u32 = 256;

/// Push constants of `glsl/gpu/saxpy.comp` (keep in sync).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SaxpyPush {
    a: f32,
    n: u32,
}

/// The CPU twin of `glsl/gpu/saxpy.comp`.
fn saxpy_cpu(a: f32, x: &[f32], y: &mut [f32]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

fn saxpy_gpu(ctx: &Context, wg: u32, a: f32, x: &[f32], y: &[f32]) -> Vec<f32> {
    let kernel = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(wg))
        .unwrap();
    let xb = Buffer::from_slice(ctx, "saxpy.x", x).unwrap();
    let yb = Buffer::from_slice(ctx, "saxpy.y", y).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    let n = x.len() as u32;
    let groups = rec.groups_1d(u64::from(n), kernel.invocations());
    rec.dispatch(&kernel, groups, &[&xb, &yb], &SaxpyPush { a, n });
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    yb.download().unwrap()
}

#[test]
fn saxpy_equals_cpu_twin_bit_for_bit_at_every_edge_size() {
    let Some(ctx) = common::context() else { return };
    let sg = ctx.info().subgroup_size as usize;
    let wg = SAXPY_WG as usize;
    let mut sizes = vec![
        0,
        1,
        7,
        8,
        9,
        sg - 1,
        sg,
        sg + 1,
        wg - 1,
        wg,
        wg + 1,
        1_000_003,
    ];
    sizes.dedup();
    let mut rng = common::Rng(7);
    for n in sizes {
        let x: Vec<f32> = (0..n).map(|_| rng.next_f32() * 1e3).collect();
        let y: Vec<f32> = (0..n).map(|_| rng.next_f32()).collect();
        let a = 1.0 + rng.next_f32();
        let gpu = saxpy_gpu(&ctx, SAXPY_WG, a, &x, &y);
        let mut cpu = y.clone();
        saxpy_cpu(a, &x, &mut cpu);
        assert_eq!(gpu.len(), n);
        let first_diff = gpu
            .iter()
            .zip(&cpu)
            .position(|(g, c)| g.to_bits() != c.to_bits());
        assert_eq!(
            first_diff, None,
            "n = {n}: GPU and CPU differ at {first_diff:?}"
        );
    }
    common::assert_silent(&ctx);
}

#[test]
fn large_dispatches_fold_into_a_2d_grid() {
    let Some(ctx) = common::context() else { return };
    // 64-wide groups over more than 65,535 groups (the least maxComputeWorkGroupCount[0]
    // Vulkan allows): the grid folds into y where the device's x limit requires it.
    let wg = 64u32;
    let n = 65_536 * wg as usize + 5;
    let rec = Recorder::new(&ctx).unwrap();
    let groups = rec.groups_1d(n as u64, wg);
    let needed = (n as u64).div_ceil(u64::from(wg));
    let max_x = ctx.info().max_workgroup_count[0];
    assert!(
        groups[0] <= max_x,
        "{groups:?} past the device's x limit {max_x}"
    );
    assert!(
        u64::from(groups[0]) * u64::from(groups[1]) >= needed,
        "{groups:?} too small"
    );
    assert_eq!(
        groups[1] > 1,
        needed > u64::from(max_x),
        "folded without need: {groups:?}"
    );
    let x: Vec<f32> = (0..n).map(|i| (i % 1000) as f32).collect();
    let y = vec![0.5f32; n];
    drop(rec);
    let gpu = saxpy_gpu(&ctx, wg, 2.0, &x, &y);
    let mut cpu = y.clone();
    saxpy_cpu(2.0, &x, &mut cpu);
    assert!(gpu == cpu, "folded grid missed or repeated elements");
    common::assert_silent(&ctx);
}

#[test]
fn kernels_see_the_subgroup_size_the_device_reports() {
    let Some(ctx) = common::context() else { return };
    let sg = ctx.info().subgroup_size;
    if let Ok(expected) = std::env::var("VKRT_EXPECT_SUBGROUP_SIZE") {
        assert_eq!(
            sg.to_string(),
            expected,
            "LP_NATIVE_VECTOR_WIDTH matrix: wrong subgroup size"
        );
    }
    for wg in [32u32, 64, 128] {
        let kernel = ctx
            .kernel(&kernels::GPU_SUBGROUP_PROBE, &Spec::new().workgroup(wg))
            .unwrap();
        let out = Buffer::<u32>::zeroed(&ctx, "probe.out", 2 + wg as usize).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.dispatch(&kernel, [1, 1, 1], &[&out], &());
        rec.compute_to_transfer();
        rec.submit_and_wait().unwrap();
        let got = out.download().unwrap();
        assert_eq!(
            got[0], sg,
            "gl_SubgroupSize differs from the device property"
        );
        // The lanes a subgroup really has: what subgroupAdd(1) counts, the same everywhere,
        // and consistent with gl_NumSubgroups.
        let lanes = got[2];
        assert!(
            got[2..].iter().all(|&l| l == lanes),
            "subgroups of different sizes: {got:?}"
        );
        assert_eq!(
            got[1] * lanes,
            wg,
            "gl_NumSubgroups x lanes must cover the workgroup: {got:?}"
        );
        if lanes != sg {
            // Known lavapipe quirk (Mesa 22.3, AVX2, LP_NATIVE_VECTOR_WIDTH=1024): reports 32,
            // runs 16. Kernels derive lanes from gl_NumSubgroups (glsl/common/subgroup_scan.glsl).
            let quirk = ctx.info().device.contains("llvmpipe") && sg == 32 && lanes == 16;
            assert!(
                quirk,
                "device reports subgroup size {sg} but subgroups have {lanes} lanes"
            );
            eprintln!("note: llvmpipe reports subgroup size {sg} but runs {lanes}-lane subgroups");
        }
    }
    common::assert_silent(&ctx);
}

/// subgroupBarrier() in subgroup-uniform but workgroup-divergent control flow, then a
/// workgroup barrier: every invocation must get past both (glsl/gpu/subgroup_barrier_probe.comp).
/// Mesa 25.0 and 26.1 lavapipe take the subgroup barrier for a workgroup barrier and lose
/// the subgroup that ran it (22.3 does not); the radix sort's `Match` ranking keeps its
/// subgroup barriers in workgroup-uniform trip counts because of it. This test documents
/// which drivers do so: it fails on any other driver that loses invocations, and says so when
/// llvmpipe does.
#[test]
fn subgroup_barriers_in_divergent_subgroups_keep_every_invocation() {
    let Some(ctx) = common::context() else { return };
    let info = ctx.info().clone();
    let lanes = info.max_subgroup_size.max(info.subgroup_size);
    let known = info.device.contains("llvmpipe")
        && vkrt::gpu::mesa_version(&info.driver).is_some_and(|v| v >= (25, 0));
    probe_keeps_every_invocation(
        &ctx,
        &kernels::GPU_SUBGROUP_BARRIER_PROBE,
        (4 * lanes).max(32),
        "subgroup barriers in one subgroup",
        known,
    );
}

/// Memory barriers in divergent control flow (legal anywhere): every invocation must still
/// reach the end of the kernel when one subgroup runs them and the others do not
/// (glsl/gpu/memory_barrier_probe.comp). Mesa 22.3's llvmpipe loses that subgroup after 3
/// barriers (the BVH refit met it; `glsl/accel/bvh/refit.comp` keeps its barriers in
/// uniform control flow); any other driver that does fails this test.
#[test]
fn memory_barriers_in_divergent_loops_keep_every_invocation() {
    let Some(ctx) = common::context() else { return };
    let info = ctx.info().clone();
    let known = info.device.contains("llvmpipe") && info.driver.contains("Mesa 22.");
    probe_keeps_every_invocation(
        &ctx,
        &kernels::GPU_MEMORY_BARRIER_PROBE,
        64,
        "memory barriers in one subgroup's loop",
        known,
    );
}

/// Runs a probe (one workgroup of `wg` invocations, push constant `trips` = 0, 1, 3) whose
/// invocations each write the marker 1 at the end: every marker must be written, except on a
/// driver with the `known` bug, where the loss is printed.
fn probe_keeps_every_invocation(
    ctx: &Context,
    blob: &'static vkrt::gpu::ShaderBlob,
    wg: u32,
    what: &str,
    known: bool,
) {
    let info = ctx.info();
    let kernel = ctx.kernel(blob, &Spec::new().workgroup(wg)).unwrap();
    for trips in [0u32, 1, 3] {
        let out = Buffer::<u32>::zeroed(ctx, "probe.out", wg as usize).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        rec.dispatch(&kernel, [1, 1, 1], &[&out], &trips);
        rec.compute_to_transfer();
        rec.submit_and_wait().unwrap();
        let got = out.download().unwrap();
        let lost = got.iter().filter(|&&m| m != 1).count();
        if trips == 0 || lost == 0 {
            assert_eq!(lost, 0, "trips={trips}: {got:?}");
            continue;
        }
        assert!(
            known,
            "{} ({}) lost {lost} of {wg} invocations after {what} (trips={trips})",
            info.device, info.driver
        );
        eprintln!(
            "note: {} lost {lost} of {wg} invocations after {what} (trips={trips}): a known \
             driver bug",
            info.driver
        );
    }
    common::assert_silent(ctx);
}

/// Two dependent dispatches: saxpy writes `y`, then the copy kernel reads `y`.
fn dependent_dispatches(ctx: &Context, with_barrier: bool) {
    let n = 4096u32;
    let saxpy = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(64))
        .unwrap();
    let copy = ctx
        .kernel(&kernels::GPU_COPY_U32, &Spec::new().workgroup(64))
        .unwrap();
    let x = Buffer::from_slice(ctx, "hazard.x", &vec![1.0f32; n as usize]).unwrap();
    let y = Buffer::from_slice(ctx, "hazard.y", &vec![2.0f32; n as usize]).unwrap();
    let z = Buffer::<f32>::new(ctx, "hazard.z", n as usize).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    let groups = rec.groups_1d(u64::from(n), 64);
    rec.dispatch(&saxpy, groups, &[&x, &y], &SaxpyPush { a: 3.0, n });
    if with_barrier {
        rec.compute_to_compute();
    }
    rec.dispatch(&copy, groups, &[&y, &z], &n);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    // Without the barrier the data is undefined (lavapipe runs in order and gets it right
    // anyway, a GPU overlaps the dispatches): only the layer can tell, so only the
    // synchronised run's data is checked.
    if with_barrier {
        assert!(z.download().unwrap().iter().all(|&v| v == 5.0));
    }
}

#[test]
fn sync_validation_catches_a_missing_barrier_and_is_silent_with_it() {
    let Some(ctx) = common::context() else { return };
    if !ctx.validation_enabled() {
        eprintln!("skipped: needs the validation layer (apt vulkan-validationlayers; VKRT_VALIDATION not 0)");
        return;
    }
    dependent_dispatches(&ctx, true);
    common::assert_silent(&ctx);

    dependent_dispatches(&ctx, false);
    let messages = ctx.take_validation_messages();
    assert!(
        messages
            .iter()
            .any(|m| m.id.contains("SYNC-HAZARD-READ") || m.text.contains("SYNC-HAZARD-READ")),
        "the missing compute->compute barrier was not reported; got: {messages:?}"
    );
}

#[test]
fn profiler_scopes_are_nested_ordered_and_non_empty() {
    let Some(ctx) = common::context() else { return };
    if !ctx.info().timestamps {
        eprintln!("skipped: device has no timestamps");
        return;
    }
    let n = 1 << 20;
    let kernel = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(256))
        .unwrap();
    let x = Buffer::from_slice(&ctx, "prof.x", &vec![1.0f32; n]).unwrap();
    let y = Buffer::from_slice(&ctx, "prof.y", &vec![1.0f32; n]).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let groups = rec.groups_1d(n as u64, 256);
    rec.scope("outer", |rec| {
        rec.scope("first", |rec| {
            rec.dispatch(
                &kernel,
                groups,
                &[&x, &y],
                &SaxpyPush {
                    a: 1.0,
                    n: n as u32,
                },
            )
        });
        rec.compute_to_compute();
        rec.scope("second", |rec| {
            rec.dispatch(
                &kernel,
                groups,
                &[&x, &y],
                &SaxpyPush {
                    a: 1.0,
                    n: n as u32,
                },
            )
        });
    });
    rec.compute_to_transfer();
    let profile = rec.submit_and_wait().unwrap();
    let names: Vec<_> = profile
        .passes
        .iter()
        .map(|p| (p.name.as_str(), p.depth, p.parent))
        .collect();
    assert_eq!(
        names,
        [
            ("outer", 0, None),
            ("first", 1, Some(0)),
            ("second", 1, Some(0))
        ]
    );
    let t = |i: usize| {
        (
            profile.passes[i].start_ms.unwrap(),
            profile.passes[i].ms.unwrap(),
        )
    };
    let (outer, first, second) = (t(0), t(1), t(2));
    assert!(first.1 > 0.0 && second.1 > 0.0, "empty scopes: {profile:?}");
    assert!(
        first.0 >= outer.0 && first.0 + first.1 <= second.0 + 1e-9,
        "order: {profile:?}"
    );
    assert!(
        second.0 + second.1 <= outer.0 + outer.1 + 1e-9,
        "nesting: {profile:?}"
    );

    let trace = profile.chrome_trace();
    let events: Vec<_> = trace["traceEvents"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["ph"] == "X")
        .collect();
    assert_eq!(events.len(), 3);
    assert!(events.iter().all(|e| e["dur"].as_f64().unwrap() > 0.0));
    assert_eq!(y.download().unwrap()[0], 3.0);
    common::assert_silent(&ctx);
}

#[test]
fn generated_kernel_table_matches_what_the_code_binds() {
    // Hand-written binding lists (what the Rust side passes) against the reflected table.
    let expect: [(&vkrt::gpu::ShaderBlob, &[u32], bool); 4] = [
        (&kernels::GPU_SAXPY, &[0, 1], true),
        (&kernels::GPU_COPY_U32, &[0, 1], true),
        (&kernels::GPU_COPY_UVEC4, &[0, 1], true),
        (&kernels::GPU_SUBGROUP_PROBE, &[0], false),
    ];
    for (blob, bindings, push) in expect {
        assert_eq!(blob.bindings, bindings, "{}", blob.name);
        assert_eq!(blob.push_constants, push, "{}", blob.name);
        assert_eq!(
            blob.local_size_spec_ids[0],
            Some(0),
            "{}: workgroup size by constant_id 0",
            blob.name
        );
        assert_eq!(blob.spirv[0], 0x0723_0203, "{}: SPIR-V magic", blob.name);
    }
    assert_eq!(kernels::GPU_COPY_UVEC4.defines, &[("ELEM", "uvec4")]);
    let mut names: Vec<_> = kernels::ALL.iter().map(|b| b.name).collect();
    let count = names.len();
    names.dedup();
    assert_eq!(names.len(), count, "kernel names must be unique");
    assert!(vkrt::gpu::find_kernel("gpu.saxpy").is_some());
}

/// The saxpy kernel and its two 8-element buffers (x = 1, y = 2) for the misuse tests.
fn saxpy_on_eight(ctx: &Context) -> (std::sync::Arc<Kernel>, Buffer<f32>, Buffer<f32>) {
    let kernel = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(64))
        .unwrap();
    let x = Buffer::from_slice(ctx, "x", &[1.0f32; 8]).unwrap();
    let y = Buffer::from_slice(ctx, "y", &[2.0f32; 8]).unwrap();
    (kernel, x, y)
}

#[test]
fn commands_given_wrong_arguments_fail_the_recording_instead_of_panicking() {
    let Some(ctx) = common::context() else { return };
    let (kernel, x, y) = saxpy_on_eight(&ctx);
    let small = Buffer::<f32>::new(&ctx, "small", 4).unwrap();
    let push = SaxpyPush { a: 3.0, n: 8 };
    let raw = |offset: u64, size: u64| unsafe { RawBuffer::new(y.as_raw().buffer(), offset, size) };
    let past_limit = raw(0, ctx.info().max_storage_buffer_range + 4);
    let align = ctx.info().min_storage_buffer_offset_alignment;
    let misaligned = raw(align / 2, 16);
    let empty = raw(0, 0);
    let other = Context::new(&vkrt::gpu::ContextOptions::for_tests()).unwrap();
    let (foreign, _, _) = saxpy_on_eight(&other);
    type Case<'a> = (&'a str, Box<dyn Fn(&mut Recorder) + 'a>);
    let mut cases: Vec<Case> = vec![
        (
            "one buffer of two",
            Box::new(|rec| rec.dispatch(&kernel, [1, 1, 1], &[&x], &push)),
        ),
        (
            "a grid past the device's",
            Box::new(|rec| rec.dispatch(&kernel, [u32::MAX, 1, 1], &[&x, &y], &push)),
        ),
        (
            "a copy past a buffer",
            Box::new(|rec| rec.copy(&x, &small, 8)),
        ),
        (
            "a fill past a buffer",
            Box::new(|rec| rec.fill_first(&small, 5, 0)),
        ),
        // The ranges a kernel trusts, checked at record time.
        (
            "a binding past the device's maxStorageBufferRange",
            Box::new(|rec| rec.dispatch(&kernel, [1, 1, 1], &[&x, &past_limit], &push)),
        ),
        (
            "an empty binding",
            Box::new(|rec| rec.dispatch(&kernel, [1, 1, 1], &[&x, &empty], &push)),
        ),
    ];
    // A kernel of another context: its pipeline is another device's object.
    cases.push((
        "a kernel made on another context",
        Box::new(|rec| rec.dispatch(&foreign, [1, 1, 1], &[&x, &y], &push)),
    ));
    if align > 1 {
        cases.push((
            "a binding at an offset the device does not allow",
            Box::new(|rec| rec.dispatch(&kernel, [1, 1, 1], &[&x, &misaligned], &push)),
        ));
    }
    for (what, record) in cases {
        let before = ctx.traffic();
        let mut rec = Recorder::new(&ctx).unwrap();
        record(&mut rec);
        // Later commands are left out; nothing is submitted.
        rec.dispatch(&kernel, [1, 1, 1], &[&x, &y], &push);
        assert!(matches!(rec.check(), Err(GpuError::Usage { .. })), "{what}");
        let err = rec.submit_and_wait().unwrap_err();
        assert!(matches!(err, GpuError::Usage { .. }), "{what}: {err}");
        assert_eq!((ctx.traffic() - before).submits, 0, "{what}");
    }
    // y untouched by every refused recording.
    assert_eq!(y.download().unwrap(), vec![2.0; 8]);
    common::assert_silent(&ctx);
}

#[test]
fn a_recorder_used_the_wrong_way_is_an_error_not_a_panic() {
    let Some(ctx) = common::context() else { return };
    let (kernel, x, y) = saxpy_on_eight(&ctx);
    let push = SaxpyPush { a: 3.0, n: 8 };
    let usage = |r: Result<vkrt::gpu::Profile, GpuError>, what: &str| match r {
        Err(GpuError::Usage { .. }) => {}
        other => panic!("{what}: {other:?}"),
    };
    // finish() is for the caller's command buffers.
    let rec = Recorder::new(&ctx).unwrap();
    assert!(matches!(rec.finish(), Err(GpuError::Usage { .. })));
    // A scope left open, and one closed that was never opened.
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.begin_scope("left.open");
    usage(rec.submit_and_wait(), "a scope left open");
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.end_scope();
    rec.dispatch(&kernel, [1, 1, 1], &[&x, &y], &push);
    usage(rec.submit_and_wait(), "a scope closed twice");
    // More workgroups than the device's grid holds: refused at dispatch.
    let mut rec = Recorder::new(&ctx).unwrap();
    let max = ctx.info().max_workgroup_count;
    let items = u64::from(max[0]) * (u64::from(max[1]) + 1);
    let groups = rec.groups_1d(items, 1);
    rec.dispatch(&kernel, groups, &[&x, &y], &push);
    usage(rec.submit_and_wait(), "a grid beyond the device's");
    // y untouched; the recorder still works the right way.
    assert_eq!(y.download().unwrap(), vec![2.0; 8]);
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.scope("right", |rec| {
        rec.dispatch(&kernel, [1, 1, 1], &[&x, &y], &push)
    });
    rec.submit_and_wait().unwrap();
    assert_eq!(y.download().unwrap(), vec![5.0; 8]);
    common::assert_silent(&ctx);
}

#[test]
fn oversized_buffers_are_a_clear_error() {
    let Some(ctx) = common::context() else { return };
    let limit = ctx.info().max_storage_buffer_range;
    let err = Buffer::<u32>::new(&ctx, "too.big", (limit / 4 + 1) as usize).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, GpuError::BufferTooLarge { .. }), "{err:?}");
    assert!(
        text.contains("too.big") && text.contains(&limit.to_string()),
        "{text}"
    );
    let err = Buffer::<[u32; 4]>::new(&ctx, "overflow", usize::MAX).unwrap_err();
    assert!(matches!(err, GpuError::BufferTooLarge { .. }), "{err:?}");
    common::assert_silent(&ctx);
}

#[test]
fn a_device_that_does_not_exist_is_named_in_the_error() {
    let options = vkrt::gpu::ContextOptions {
        device_name: Some("no-such-gpu".into()),
        ..Default::default()
    };
    let _turn = common::vulkan_turn();
    let err = Context::new(&options)
        .err()
        .expect("no device is called no-such-gpu");
    let text = err.to_string();
    assert!(text.contains("no-such-gpu"), "{text}");
}

#[test]
fn empty_buffers_and_dispatches_are_fine() {
    let Some(ctx) = common::context() else { return };
    let empty = Buffer::<u32>::from_slice(&ctx, "empty", &[]).unwrap();
    assert!(empty.is_empty());
    assert_eq!(empty.download().unwrap(), Vec::<u32>::new());
    let gpu = saxpy_gpu(&ctx, 64, 2.0, &[], &[]);
    assert!(gpu.is_empty());
    common::assert_silent(&ctx);
}

/// The driver's own ray tracing (`AccelKind::Driver`) is found where it exists and enabled:
/// Mesa 25's lavapipe has `VK_KHR_acceleration_structure` and `VK_KHR_ray_query`, 22.3's
/// has neither. Creating the context with them (and buffer device addresses in the
/// allocator) keeps the validation layer silent.
#[test]
fn the_drivers_ray_query_is_found_and_enabled_where_it_exists() {
    let Some(ctx) = common::context() else { return };
    let info = ctx.info();
    eprintln!("{}: ray query {}", info.driver, info.features.ray_query);
    if info.driver.contains("Mesa 25.") {
        assert!(info.features.ray_query, "{}", info.driver);
    }
    if info.driver.contains("Mesa 22.") {
        assert!(!info.features.ray_query, "{}", info.driver);
    }
    let b = Buffer::<u32>::from_slice(&ctx, "probe", &[1, 2, 3]).unwrap();
    assert_eq!(b.download().unwrap(), [1, 2, 3]);
    common::assert_silent(&ctx);
}

/// `div_rn` and `sqrt_rn` of `vkrt/ray.glsl` round correctly, as the CPU twins' IEEE
/// arithmetic does, both from the device's own division and square root and from ones up to
/// 3 ulps off (Vulkan allows 2.5 and 3): the walks' hits then equal the twins' on any device
/// with doubles. Compared where the results are normal floats well inside the range.
/// Where the device is known to divide correctly, its unrefined answers must be exact too.
#[test]
fn division_and_square_root_round_correctly_from_an_inexact_driver() {
    let Some(ctx) = common::context() else { return };
    let f = &ctx.info().features;
    if !(f.shader_float64 && f.shader_int64) {
        eprintln!("skipped: the exact variants need shaderFloat64 and shaderInt64");
        return;
    }
    let pairs = verify::rounding_pairs(1 << 18);
    // The refinement from the driver's answers and from sloppy ones; and where the device
    // is said to divide correctly (DeviceInfo::ieee_division, which turns the refinement
    // off), the driver's own answers unrefined.
    let mut runs = vec![
        (&kernels::GPU_ROUNDING_PROBE_EXACT, true),
        (&kernels::GPU_ROUNDING_PROBE_SLOPPY, true),
    ];
    if ctx.info().ieee_division {
        runs.push((&kernels::GPU_ROUNDING_PROBE_EXACT, false));
    }
    for (variant, refine) in runs {
        let got = verify::run_rounding_probe(&ctx, variant, refine, &pairs).unwrap();
        match verify::rounding_mismatch(&pairs, &got) {
            Ok(compared) => assert!(compared > pairs.len() / 2, "only {compared} compared"),
            Err(e) => panic!("rounding probe (refine {refine}): {e}"),
        }
    }
    common::assert_silent(&ctx);
}
