//! Fine-grained profiling on the test device, under validation: per-dispatch timestamps
//! named after their kernels, the warm-up scope, query pools that grow or report running
//! out, the statistics the render table prints, the one CPU+GPU timeline of a trace, the
//! scope hook an embedder's profiler listens on, the invocation counts of pipeline
//! statistics, and the bytes each scope binds beside the copy baseline.

mod common;

use common::{assert_silent, context};
use glam::Vec3;
use std::sync::{Arc, Mutex};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;

use vkrt::gpu::{
    kernels, vk, Buffer, CompletedScope, Context, PassBytes, PassTime, Profile, QuerySlot,
    RecordedScope, Recorder, ScopeHook, ScopeKind, Spec, Spread, Submission,
};

/// Push constants of `glsl/gpu/saxpy.comp` (keep in sync).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SaxpyPush {
    a: f32,
    n: u32,
}

fn triangles(n: usize) -> TraceGeometry {
    let tris: Vec<[Vec3; 3]> = (0..n)
        .map(|i| {
            let c = Vec3::new((i % 17) as f32, (i / 17) as f32, (i % 5) as f32);
            [c, c + Vec3::X, c + Vec3::Y]
        })
        .collect();
    TraceGeometry::from_triangles_and_spheres(&tris, &[])
}

/// An LBVH build in one submission: its profile and how many dispatches it recorded.
fn lbvh_build(ctx: &Context, g: &TraceGeometry, per_dispatch: bool) -> (Profile, u64) {
    let builder = AccelBuilder::new(ctx, AccelKind::Lbvh).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    rec.set_dispatch_timestamps(per_dispatch);
    let _built = GpuGeometry::record_build(&mut rec, &builder, g, 0).unwrap();
    let dispatches = rec.counts().dispatches;
    (rec.submit_and_wait().unwrap(), dispatches)
}

#[test]
fn every_dispatch_of_a_build_is_a_timed_scope_named_after_its_kernel() {
    let Some(ctx) = context() else { return };
    if !ctx.info().timestamps {
        eprintln!("skipped: device has no timestamps");
        return;
    }
    let g = triangles(300);
    let (off, dispatches) = lbvh_build(&ctx, &g, false);
    let (on, dispatches_on) = lbvh_build(&ctx, &g, true);
    assert_eq!(dispatches, dispatches_on);
    assert!(dispatches > 0);
    let kernel_names: Vec<&str> = kernels::ALL.iter().map(|b| b.name).collect();
    // The timed build has the untimed build's scopes and one more per dispatch, named
    // after its kernel, each inside a pass scope with a time of its own.
    let mut extra: std::collections::HashMap<&str, i64> = Default::default();
    for p in &on.passes {
        *extra.entry(p.name.as_str()).or_default() += 1;
    }
    for p in &off.passes {
        *extra.entry(p.name.as_str()).or_default() -= 1;
    }
    assert!(extra.values().all(|&n| n >= 0), "a pass scope went missing");
    assert_eq!(
        extra.values().sum::<i64>() as u64,
        dispatches,
        "one scope per dispatch"
    );
    for (name, n) in &extra {
        if *n > 0 {
            assert!(kernel_names.contains(name), "`{name}` is no kernel's name");
        }
    }
    let dispatch_scopes = on
        .passes
        .iter()
        .filter(|p| kernel_names.contains(&p.name.as_str()) && extra[p.name.as_str()] > 0);
    for d in dispatch_scopes {
        assert!(d.ms.is_some(), "`{}` has no time", d.name);
        assert!(d.parent.is_some(), "`{}` is in no pass", d.name);
    }
    assert_eq!(on.untimed_scopes, 0);
    // A pass's total is its own time, however its dispatches are named.
    for name in ["build", "levels"] {
        if let (Some(a), Some(b)) = (on.ms(name), off.ms(name)) {
            assert!(a > 0.0 && b > 0.0);
        }
    }
    assert_silent(&ctx);
}

fn saxpy(ctx: &Context, rec: &mut Recorder, x: &Buffer<f32>, y: &Buffer<f32>) {
    let kernel = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(64))
        .unwrap();
    let n = x.len() as u32;
    let groups = rec.groups_1d(u64::from(n), kernel.invocations());
    rec.dispatch(&kernel, groups, &[x, y], &SaxpyPush { a: 1.0, n });
}

#[test]
fn a_warm_up_dispatches_empty_and_writes_nothing() {
    let Some(ctx) = context() else { return };
    let x = Buffer::from_slice(&ctx, "warm.x", &[1.0f32; 256]).unwrap();
    let y = Buffer::from_slice(&ctx, "warm.y", &[1.0f32; 256]).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.warm_up(|rec| {
        saxpy(&ctx, rec, &x, &y);
        rec.fill(&y, 7);
        rec.compute_to_compute();
    });
    assert_eq!(rec.counts().dispatches, 1);
    rec.scope("timed", |rec| saxpy(&ctx, rec, &x, &y));
    rec.compute_to_transfer();
    let profile = rec.submit_and_wait().unwrap();
    // Only the timed dispatch ran: y = 1 + 1.
    assert!(y.download().unwrap().iter().all(|&v| v == 2.0));
    let names: Vec<&str> = profile.passes.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["warm-up", "timed"]);
    assert_eq!(profile.without("warm-up").passes.len(), 1);
    assert_silent(&ctx);
}

#[test]
fn running_out_of_queries_is_reported_and_pools_grow_when_dispatches_are_timed() {
    let Some(ctx) = context() else { return };
    if !ctx.info().timestamps {
        eprintln!("skipped: device has no timestamps");
        return;
    }
    let x = Buffer::from_slice(&ctx, "q.x", &[1.0f32; 64]).unwrap();
    let y = Buffer::from_slice(&ctx, "q.y", &[0.0f32; 64]).unwrap();
    // Without per-dispatch timestamps a recorder keeps its one pool of 32,768 queries
    // (16,384 scopes): the scopes past it are counted untimed, never silently dropped.
    let scopes = vkrt::gpu::DEFAULT_QUERY_CAPACITY as usize / 2 + 16;
    let mut rec = Recorder::new(&ctx).unwrap();
    for _ in 0..scopes {
        rec.begin_scope("pass");
        rec.end_scope();
    }
    let profile = rec.submit_and_wait().unwrap();
    assert_eq!(profile.passes.len(), scopes);
    assert_eq!(profile.untimed_scopes, 16, "{:?}", profile.passes.last());
    assert_eq!(profile.passes.iter().filter(|p| p.ms.is_none()).count(), 16);

    // vkrt's own recorder with every dispatch timed adds pools past the first's 32,768
    // queries instead: 20,000 dispatches, 40,000 queries, all timed.
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.set_dispatch_timestamps(true);
    let kernel = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(64))
        .unwrap();
    for _ in 0..20_000 {
        rec.dispatch(&kernel, [0, 1, 1], &[&x, &y], &SaxpyPush { a: 1.0, n: 64 });
    }
    let profile = rec.submit_and_wait().unwrap();
    assert_eq!(profile.passes.len(), 20_000);
    assert_eq!(profile.untimed_scopes, 0);
    assert!(profile.passes.iter().all(|p| p.ms.is_some()));
    assert_silent(&ctx);
}

fn pass(name: &str, depth: u32, parent: Option<usize>, ms: f64) -> PassTime {
    PassTime {
        name: name.into(),
        depth,
        parent,
        start_ms: Some(0.0),
        ms: Some(ms),
        ..PassTime::default()
    }
}

#[test]
fn per_sample_statistics_of_a_synthetic_profile() {
    // warm-up { sample { camera 9 } }, then three samples: camera 1+1, 4, 3 (the first in
    // two waves, the last with a dispatch scope named like its pass inside).
    let profile = Profile {
        passes: vec![
            pass("warm-up", 0, None, 9.0),
            pass("render.sample", 1, Some(0), 9.0),
            pass("render.camera", 2, Some(1), 9.0),
            pass("render.sample", 0, None, 5.0),
            pass("render.camera", 1, Some(3), 1.0),
            pass("render.camera", 1, Some(3), 1.0),
            pass("render.sample", 0, None, 5.0),
            pass("render.camera", 1, Some(6), 4.0),
            pass("render.sample", 0, None, 5.0),
            pass("render.camera", 1, Some(8), 3.0),
            pass("render.camera", 2, Some(9), 2.5),
        ],
        ..Profile::default()
    };
    let timed = profile.without("warm-up");
    assert_eq!(timed.passes.len(), 8);
    assert_eq!(timed.passes[1].parent, Some(0));
    assert_eq!(timed.passes[7].parent, Some(6));
    assert_eq!(timed.ms("render.camera"), Some(9.0));
    assert_eq!(profile.ms("render.camera"), Some(18.0));
    let per = timed.ms_within("render.camera", "render.sample");
    assert_eq!(per, [2.0, 4.0, 3.0]);
    let s = Spread::of(&per);
    assert_eq!(
        s,
        Spread {
            count: 3,
            median: 3.0,
            min: 2.0,
            max: 4.0
        }
    );
    assert_eq!(Spread::of(&[4.0, 1.0, 3.0, 2.0]).median, 2.5);
    assert_eq!(Spread::of(&[]).count, 0);
}

/// The complete events of a trace on thread `tid`, as (name, start, end) in microseconds.
fn spans_on(trace: &serde_json::Value, tid: u64) -> Vec<(String, f64, f64)> {
    trace["traceEvents"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["ph"] == "X" && e["tid"] == tid)
        .map(|e| {
            let ts = e["ts"].as_f64().unwrap();
            let name = e["name"].as_str().unwrap().to_string();
            (name, ts, ts + e["dur"].as_f64().unwrap())
        })
        .collect()
}

#[test]
fn a_trace_puts_host_spans_and_gpu_passes_on_one_calibrated_time_axis() {
    let Some(ctx) = context() else { return };
    if !ctx.info().timestamps {
        eprintln!("skipped: device has no timestamps");
        return;
    }
    ctx.set_dispatch_timestamps(true);
    let g = triangles(500);
    // Three submissions (an upload, a build, a read-back) under one capture.
    let ((), profile) = vkrt::gpu::capture_profiles(|| {
        let x = Buffer::from_slice(&ctx, "timeline.x", &[1.0f32; 4096]).unwrap();
        let y = Buffer::from_slice(&ctx, "timeline.y", &[2.0f32; 4096]).unwrap();
        lbvh_build(&ctx, &g, true);
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.scope("saxpy", |rec| saxpy(&ctx, rec, &x, &y));
        rec.submit_and_wait().unwrap();
        assert!(y.download().unwrap().iter().all(|&v| v == 3.0));
    });
    ctx.set_dispatch_timestamps(false);
    assert!(
        profile.submissions.len() >= 4,
        "{}",
        profile.submissions.len()
    );
    let names = |n: &str| profile.host_spans.iter().filter(|h| h.name == n).count();
    assert_eq!(names("vkrt.submit"), profile.submissions.len());
    assert_eq!(names("vkrt.wait"), profile.submissions.len());
    assert_eq!(names("vkrt.record"), profile.submissions.len());
    assert!(names("vkrt.upload") >= 2 && names("vkrt.read_back") >= 1);
    // Every timed scope's interval on the host's clock lies inside its submission's,
    // from just before vkQueueSubmit to the end of the fence wait, within the
    // calibration's error bound.
    let mut mapped = 0;
    for (i, p) in profile.passes.iter().enumerate() {
        let Some((b, e)) = profile.host_interval_ns(i) else {
            assert!(
                p.ms.is_none(),
                "`{}` timed but not on the host's clock",
                p.name
            );
            continue;
        };
        let s = &profile.submissions[p.submission.unwrap()];
        let slack = s.calibration.unwrap().max_deviation_ns.unwrap_or(0) as f64 + 1_000.0;
        assert!(
            s.submitted_ns as f64 - slack <= b && b <= e && e <= s.completed_ns as f64 + slack,
            "`{}` at {b}..{e} ns outside its submission {}..{} ns",
            p.name,
            s.submitted_ns,
            s.completed_ns
        );
        mapped += 1;
    }
    assert!(mapped > 10, "{mapped} scopes on the host's clock");
    // (Submissions without a timed scope, such as the uploads', have no calibration.)
    let method = profile
        .submissions
        .iter()
        .find_map(|s| s.calibration)
        .unwrap()
        .method;
    assert!(
        [
            "VK_KHR_calibrated_timestamps",
            "VK_EXT_calibrated_timestamps",
            vkrt::gpu::timeline::SUBMIT_ALIGNED
        ]
        .contains(&method),
        "{method}"
    );

    // The same in the written trace: a CPU track and a GPU track, every GPU span inside a
    // submit-to-wait interval of the CPU track, the device and calibration in its metadata.
    let trace = profile.chrome_trace();
    let tracks: Vec<&str> = trace["traceEvents"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["ph"] == "M" && e["name"] == "thread_name")
        .map(|e| e["args"]["name"].as_str().unwrap())
        .collect();
    let family = ctx.queue_family();
    assert_eq!(
        tracks,
        [
            "CPU (host thread)".to_string(),
            format!("GPU queue family {family}")
        ]
    );
    let host = spans_on(&trace, 1);
    let submits: Vec<(f64, f64)> = host
        .iter()
        .filter(|h| h.0 == "vkrt.submit")
        .zip(host.iter().filter(|h| h.0 == "vkrt.wait"))
        .map(|(s, w)| (s.1, w.2))
        .collect();
    let gpu = spans_on(&trace, 100 + u64::from(family));
    assert_eq!(gpu.len(), mapped);
    let slack_us = 2.0;
    for (name, b, e) in &gpu {
        assert!(
            submits
                .iter()
                .any(|&(s, w)| s - slack_us <= *b && *e <= w + slack_us),
            "`{name}` at {b}..{e} us in no submit-to-wait interval of {submits:?}"
        );
    }
    let meta = &trace["otherData"];
    assert_eq!(meta["device"], ctx.info().device.as_str());
    assert_eq!(meta["driver"], ctx.info().driver.as_str());
    assert_eq!(
        meta["timestamp_period_ns"].as_f64().unwrap() as f32,
        ctx.info().timestamp_period_ns
    );
    assert_eq!(meta["calibration"], method);
    if method != vkrt::gpu::timeline::SUBMIT_ALIGNED {
        assert!(meta["calibration_max_deviation_ns"].as_u64().is_some());
    }
    assert_silent(&ctx);
}

/// A scope begun: name, kind, begin query.
type Begun = (String, ScopeKind, Option<QuerySlot>);
/// A scope ended: name, begin and end queries.
type Ended = (String, Option<QuerySlot>, Option<QuerySlot>);
/// A scope completed: name, kind, depth, queries, ticks.
type Done = (String, ScopeKind, u32, [QuerySlot; 2], [u64; 2]);

/// What a test embedder's profiler hears from the scope hook.
#[derive(Default)]
struct Heard {
    begun: Mutex<Vec<Begun>>,
    ended: Mutex<Vec<Ended>>,
    completed: Mutex<Vec<Done>>,
}

impl ScopeHook for Heard {
    fn scope_begun(&self, s: &RecordedScope<'_>) {
        assert!(s.end.is_none());
        let entry = (s.name.to_string(), s.kind, s.begin);
        self.begun.lock().unwrap().push(entry);
    }
    fn scope_ended(&self, s: &RecordedScope<'_>) {
        let entry = (s.name.to_string(), s.begin, s.end);
        self.ended.lock().unwrap().push(entry);
    }
    fn completed(&self, scopes: &[CompletedScope<'_>], submission: &Submission) {
        assert!(submission.calibration.is_some());
        let mut heard = self.completed.lock().unwrap();
        for s in scopes {
            heard.push((s.name.to_string(), s.kind, s.depth, s.queries, s.ticks));
        }
    }
}

#[test]
fn a_scope_hook_hears_every_pass_and_dispatch_with_its_queries_and_ticks() {
    let Some(ctx) = context() else { return };
    if !ctx.info().timestamps {
        eprintln!("skipped: device has no timestamps");
        return;
    }
    let heard = Arc::new(Heard::default());
    ctx.set_scope_hook(Some(heard.clone()));
    let x = Buffer::from_slice(&ctx, "hook.x", &[1.0f32; 256]).unwrap();
    let y = Buffer::from_slice(&ctx, "hook.y", &[1.0f32; 256]).unwrap();
    let narrow = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(32))
        .unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.set_dispatch_timestamps(true);
    rec.scope("outer", |rec| {
        saxpy(&ctx, rec, &x, &y);
        rec.compute_to_compute();
        rec.scope("inner", |rec| {
            rec.dispatch(&narrow, [8, 1, 1], &[&x, &y], &SaxpyPush { a: 1.0, n: 256 })
        });
    });
    // Untimed dispatches are told too, without queries.
    rec.set_dispatch_timestamps(false);
    rec.compute_to_compute();
    saxpy(&ctx, &mut rec, &x, &y);
    let profile = rec.submit_and_wait().unwrap();
    let wide = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(64))
        .unwrap();
    let (w, n) = (wide.name().to_string(), narrow.name().to_string());

    let begun = heard.begun.lock().unwrap().clone();
    let names: Vec<&str> = begun.iter().map(|b| b.0.as_str()).collect();
    assert_eq!(names, ["outer", &w, "inner", &n, &w]);
    let kinds: Vec<ScopeKind> = begun.iter().map(|b| b.1).collect();
    use ScopeKind::{Dispatch, Pass};
    assert_eq!(kinds, [Pass, Dispatch, Pass, Dispatch, Dispatch]);
    assert!(begun[..4].iter().all(|b| b.2.is_some()) && begun[4].2.is_none());
    let ended = heard.ended.lock().unwrap().clone();
    let ended_names: Vec<&str> = ended.iter().map(|e| e.0.as_str()).collect();
    assert_eq!(ended_names, [&w, &n, "inner", "outer", &w]);

    // At completion: the four timed scopes in opening order, with the queries told at
    // record time, ticks that nest as the scopes do, and the profile's own ticks.
    let done = heard.completed.lock().unwrap().clone();
    let done_names: Vec<&str> = done.iter().map(|d| d.0.as_str()).collect();
    assert_eq!(done_names, ["outer", &w, "inner", &n]);
    assert_eq!(done.iter().map(|d| d.2).collect::<Vec<_>>(), [0, 1, 1, 2]);
    // Scope i of the completed ones was begun i-th and ended as ended[closed[i]].
    let closed = [3, 0, 2, 1];
    for (i, d) in done.iter().enumerate() {
        let (b, e) = (&begun[i], &ended[closed[i]]);
        assert_eq!((b.2, e.1, e.2), (Some(d.3[0]), Some(d.3[0]), Some(d.3[1])));
        assert_eq!(profile.passes[i].ticks, Some(d.4));
    }
    let t = |i: usize| done[i].4;
    let order = [
        t(0)[0],
        t(1)[0],
        t(1)[1],
        t(2)[0],
        t(3)[0],
        t(3)[1],
        t(2)[1],
        t(0)[1],
    ];
    assert!(order.windows(2).all(|p| p[0] <= p[1]), "{order:?}");

    // A build's dispatches are all heard, each named after its kernel.
    heard.completed.lock().unwrap().clear();
    let (_, dispatches) = lbvh_build(&ctx, &triangles(300), true);
    let done = heard.completed.lock().unwrap().clone();
    let kernel_names: Vec<&str> = kernels::ALL.iter().map(|b| b.name).collect();
    let heard_dispatches: Vec<&str> = done
        .iter()
        .filter(|d| d.1 == Dispatch)
        .map(|d| d.0.as_str())
        .collect();
    assert_eq!(heard_dispatches.len() as u64, dispatches);
    assert!(heard_dispatches.iter().all(|n| kernel_names.contains(n)));
    ctx.set_scope_hook(None);
    assert_silent(&ctx);
}

/// saxpy over 1,024 floats (`x` = 1, `y` = 0) in workgroups of 64, and workgroup counts the
/// device reads when an indirect dispatch runs: 5 x 1 x 1.
struct SaxpyRig {
    x: Buffer<f32>,
    y: Buffer<f32>,
    kernel: std::sync::Arc<vkrt::gpu::Kernel>,
    push: SaxpyPush,
    indirect: Buffer<u32>,
}

fn saxpy_rig(ctx: &Context, name: &str) -> SaxpyRig {
    SaxpyRig {
        x: Buffer::from_slice(ctx, &format!("{name}.x"), &[1.0f32; 1024]).unwrap(),
        y: Buffer::from_slice(ctx, &format!("{name}.y"), &[0.0f32; 1024]).unwrap(),
        kernel: ctx
            .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(64))
            .unwrap(),
        push: SaxpyPush { a: 1.0, n: 1024 },
        indirect: Buffer::from_slice(ctx, &format!("{name}.indirect"), &[5u32, 1, 1]).unwrap(),
    }
}

#[test]
fn pipeline_statistics_count_the_invocations_an_indirect_pass_really_ran() {
    let Some(ctx) = context() else { return };
    if !ctx.set_pipeline_statistics(true) {
        eprintln!("skipped: device has no pipelineStatisticsQuery");
        return;
    }
    let SaxpyRig {
        x,
        y,
        kernel,
        push,
        indirect,
    } = saxpy_rig(&ctx, "stats");
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.scope("direct", |rec| {
        rec.dispatch(&kernel, [3, 1, 1], &[&x, &y], &push)
    });
    rec.compute_to_compute();
    rec.scope("indirect", |rec| {
        rec.dispatch_indirect(&kernel, &indirect, 0, &[&x, &y], &push)
    });
    rec.compute_to_compute();
    rec.scope("both", |rec| {
        rec.scope("inner", |rec| {
            rec.dispatch(&kernel, [2, 1, 1], &[&x, &y], &push)
        });
        rec.compute_to_compute();
        rec.dispatch(&kernel, [1, 1, 1], &[&x, &y], &push);
    });
    rec.scope("empty", |_| ());
    let profile = rec.submit_and_wait().unwrap();
    assert_eq!(profile.invocations("direct"), Some(3 * 64));
    assert_eq!(profile.invocations("indirect"), Some(5 * 64));
    assert_eq!(profile.invocations("inner"), Some(2 * 64));
    assert_eq!(profile.invocations("both"), Some(3 * 64));
    assert_eq!(profile.invocations("empty"), Some(0));
    let trace = profile.chrome_trace();
    let indirect_event = trace["traceEvents"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "indirect" && e["ph"] == "X");
    if let Some(e) = indirect_event {
        assert_eq!(e["args"]["compute_invocations"], 5 * 64);
    }

    // Off, nothing is counted.
    ctx.set_pipeline_statistics(false);
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.scope("direct", |rec| {
        rec.dispatch(&kernel, [3, 1, 1], &[&x, &y], &push)
    });
    let profile = rec.submit_and_wait().unwrap();
    assert_eq!(profile.invocations("direct"), None);
    assert_silent(&ctx);
}

#[test]
fn each_scope_knows_the_bytes_its_direct_dispatches_and_copies_bind() {
    // What the kernels declare, as reflected from their SPIR-V.
    assert_eq!(kernels::GPU_SAXPY.read_only_bindings, &[0]);
    assert!(kernels::GPU_SAXPY.write_only_bindings.is_empty());
    assert_eq!(kernels::GPU_COPY_U32.read_only_bindings, &[0]);
    assert_eq!(kernels::GPU_COPY_U32.write_only_bindings, &[1]);

    let Some(ctx) = context() else { return };
    let SaxpyRig {
        x,
        y,
        kernel,
        push,
        indirect,
    } = saxpy_rig(&ctx, "bytes");
    let z = Buffer::from_slice(&ctx, "bytes.z", &[0.0f32; 256]).unwrap();
    ctx.set_copy_baseline(10.0);
    let mut rec = Recorder::new(&ctx).unwrap();
    // saxpy reads x and y and writes y.
    rec.scope("saxpy", |rec| {
        rec.dispatch(&kernel, [16, 1, 1], &[&x, &y], &push)
    });
    rec.compute_to_transfer();
    rec.scope("copy", |rec| rec.copy(&x, &z, 200));
    rec.transfer_to_transfer();
    rec.scope("fill", |rec| rec.fill(&y, 0));
    rec.transfer_to_compute();
    rec.scope("indirect", |rec| {
        rec.dispatch_indirect(&kernel, &indirect, 0, &[&x, &y], &push)
    });
    rec.compute_to_compute();
    rec.scope("outer", |rec| {
        rec.scope("inner", |rec| {
            rec.dispatch(&kernel, [16, 1, 1], &[&x, &y], &push)
        });
        rec.compute_to_transfer();
        rec.copy(&x, &z, 256);
    });
    rec.transfer_to_compute();
    rec.scope("mixed", |rec| {
        rec.dispatch(&kernel, [16, 1, 1], &[&x, &y], &push);
        rec.compute_to_compute();
        rec.dispatch_indirect(&kernel, &indirect, 0, &[&x, &y], &push);
    });
    rec.scope("empty", |_| ());
    let profile = rec.submit_and_wait().unwrap();
    let b = |read, written| Some(PassBytes { read, written });
    assert_eq!(profile.bytes("saxpy"), b(8192, 4096));
    assert_eq!(profile.bytes("copy"), b(800, 800));
    assert_eq!(profile.bytes("fill"), b(0, 4096));
    assert_eq!(profile.bytes("indirect"), None, "its grid is the device's");
    assert_eq!(profile.bytes("inner"), b(8192, 4096));
    assert_eq!(profile.bytes("outer"), b(8192 + 1024, 4096 + 1024));
    assert_eq!(profile.bytes("mixed"), None);
    assert_eq!(profile.bytes("empty"), b(0, 0));

    // The trace carries them, the bandwidth and its ratio to the copy baseline.
    let device = profile.device.clone().unwrap();
    assert_eq!(device.copy_gib_per_s, Some(10.0));
    let trace = profile.chrome_trace();
    assert_eq!(trace["otherData"]["copy_gib_per_s"], 10.0);
    let saxpy = trace["traceEvents"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "saxpy" && e["ph"] == "X");
    if let Some(e) = saxpy {
        assert_eq!(e["args"]["read_bytes"], 8192);
        assert_eq!(e["args"]["written_bytes"], 4096);
        let gib = e["args"]["gib_per_s"].as_f64().unwrap();
        let ms = profile.ms("saxpy").unwrap();
        assert!((gib - 12288.0 / (ms / 1e3) / f64::from(1u32 << 30)).abs() <= 1e-9 * gib);
        let of_copy = e["args"]["of_copy_bandwidth"].as_f64().unwrap();
        assert!((of_copy - gib / 10.0).abs() <= 1e-9 * of_copy);
    }
    let indirect_event = trace["traceEvents"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "indirect" && e["ph"] == "X");
    if let Some(e) = indirect_event {
        assert!(e["args"].get("read_bytes").is_none());
    }
    // A value that is no bandwidth clears the baseline.
    ctx.set_copy_baseline(f64::NAN);
    assert_eq!(ctx.copy_baseline(), None);
    assert_silent(&ctx);
}

/// Vulkan objects a caller's recording of six timed, counted-or-not dispatches creates
/// while recording (after `Recorder::from_raw`), on a command buffer never submitted.
fn objects_made_while_recording(ctx: &Context, x: &Buffer<f32>, y: &Buffer<f32>) -> u64 {
    let kernel = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(64))
        .unwrap();
    let device = ctx.device();
    let info = vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family());
    // SAFETY: a command pool and one primary buffer of the context's own device, begun
    // once, never submitted, freed after the recording is dropped.
    let (pool, cmd) = unsafe {
        let pool = device.create_command_pool(&info, None).unwrap();
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        let cmd = device.allocate_command_buffers(&alloc).unwrap()[0];
        device
            .begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())
            .unwrap();
        (pool, cmd)
    };
    // SAFETY: `cmd` is recording, of the context's family; never submitted; the work is
    // dropped (not completed) before the pool goes.
    let mut rec = unsafe { Recorder::from_raw(ctx, cmd, 8) }.unwrap();
    rec.set_dispatch_timestamps(true);
    let before = ctx.traffic().objects_created;
    // Counting has four queries here (half the capacity): the dispatches past them are
    // left uncounted, never given a new pool.
    for _ in 0..6 {
        rec.scope("pass", |rec| {
            rec.dispatch(&kernel, [1, 1, 1], &[x, y], &SaxpyPush { a: 1.0, n: 64 })
        });
    }
    let made = ctx.traffic().objects_created - before;
    drop(rec.finish().unwrap());
    // SAFETY: the recording is gone and the buffer was never submitted.
    unsafe { device.destroy_command_pool(pool, None) };
    made
}

#[test]
fn counting_makes_no_object_while_a_callers_command_buffer_records() {
    let Some(ctx) = context() else { return };
    let x = Buffer::from_slice(&ctx, "raw.x", &[1.0f32; 64]).unwrap();
    let y = Buffer::from_slice(&ctx, "raw.y", &[0.0f32; 64]).unwrap();
    let uncounted = objects_made_while_recording(&ctx, &x, &y);
    if !ctx.set_pipeline_statistics(true) {
        eprintln!("skipped: device has no pipelineStatisticsQuery");
        return;
    }
    // What the recording itself binds (descriptor sets) and nothing more.
    assert_eq!(objects_made_while_recording(&ctx, &x, &y), uncounted);
    assert_silent(&ctx);
}

/// With the `tracy` feature: every timed scope of a build becomes a Tracy GPU zone, none
/// left out, each given its ticks at completion (recorded where the application's
/// tracy-client has `enable`; `--features tracy,tracy-client/enable` runs Tracy's client).
#[cfg(feature = "tracy")]
#[test]
fn the_tracy_hook_turns_every_timed_scope_into_a_zone() {
    let Some(ctx) = context() else { return };
    if !ctx.info().timestamps {
        eprintln!("skipped: device has no timestamps");
        return;
    }
    let client = tracy_client::Client::start();
    let tracy = vkrt::gpu::tracy::TracyScopes::new(&ctx, client, "vkrt test").unwrap();
    ctx.set_scope_hook(Some(tracy.clone()));
    let (profile, dispatches) = lbvh_build(&ctx, &triangles(300), true);
    assert!(dispatches > 0 && profile.passes.iter().all(|p| p.ticks.is_some()));
    assert_eq!(tracy.dropped_scopes(), 0);
    ctx.set_scope_hook(None);
    assert_silent(&ctx);
}
