//! The embedding path: a renderer that owns its instance, device, queue, allocator and
//! command buffer hands them to vkrt, records vkrt's work into its own command buffer,
//! submits it itself — and everything it owns is still alive afterwards.

mod common;

use std::sync::{Arc, Mutex};

use ash::vk;
use glam::Vec3;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{kernels, Buffer, Context, DeviceFeatures, GpuError, RawParts, Recorder, Spec};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{cpu, Hit, Ray, TraceOptions};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SaxpyPush {
    a: f32,
    n: u32,
}

/// What "the renderer" owns.
struct Renderer {
    entry: ash::Entry,
    instance: ash::Instance,
    physical_device: vk::PhysicalDevice,
    device: ash::Device,
    family: u32,
    queue: vk::Queue,
    /// The features its device was created with.
    features: DeviceFeatures,
}

impl Renderer {
    /// The renderer's own command pool and a command buffer in the recording state.
    fn begin_commands(&self) -> (vk::CommandPool, vk::CommandBuffer) {
        // SAFETY: plain Vulkan on the renderer's valid device.
        unsafe {
            let pool = self
                .device
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default().queue_family_index(self.family),
                    None,
                )
                .unwrap();
            let cmd = self
                .device
                .allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(pool)
                        .command_buffer_count(1),
                )
                .unwrap()[0];
            self.device
                .begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default())
                .unwrap();
            (pool, cmd)
        }
    }

    /// What vkrt is given of the renderer's device, with the renderer's `allocator` if any.
    fn parts(&self, allocator: Option<Arc<Mutex<Allocator>>>) -> RawParts {
        RawParts {
            entry: self.entry.clone(),
            instance: self.instance.clone(),
            physical_device: self.physical_device,
            device: self.device.clone(),
            queue_family: self.family,
            queue: self.queue,
            enabled_features: self.features,
            debug_utils: false,
            allocator,
            pipeline_cache_dir: None,
        }
    }

    /// Ends `cmd`, submits it to the renderer's queue and waits for it.
    fn submit_and_wait(&self, cmd: vk::CommandBuffer) {
        // SAFETY: the renderer ends, submits and waits for its own command buffer.
        unsafe {
            self.device.end_command_buffer(cmd).unwrap();
            let fence = self
                .device
                .create_fence(&vk::FenceCreateInfo::default(), None)
                .unwrap();
            let cmds = [cmd];
            self.device
                .queue_submit(
                    self.queue,
                    &[vk::SubmitInfo::default().command_buffers(&cmds)],
                    fence,
                )
                .unwrap();
            self.device
                .wait_for_fences(&[fence], true, u64::MAX)
                .unwrap();
            self.device.destroy_fence(fence, None);
        }
    }
}

fn renderer() -> Option<Renderer> {
    renderer_with(false)
}

/// The renderer's device, with its calibrated-timestamps extension enabled where the device
/// lists one and `calibrated` asks for it.
fn renderer_with(calibrated: bool) -> Option<Renderer> {
    // SAFETY: test code standing in for an embedding application: plain Vulkan setup with
    // every create-info pointing at locals that outlive the calls.
    unsafe {
        let entry = ash::Entry::load().ok()?;
        let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_2);
        let instance = entry
            .create_instance(
                &vk::InstanceCreateInfo::default().application_info(&app),
                None,
            )
            .ok()?;
        let (physical_device, family) = instance
            .enumerate_physical_devices()
            .ok()?
            .into_iter()
            .find_map(|pd| {
                let families = instance.get_physical_device_queue_family_properties(pd);
                let family = families
                    .iter()
                    .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))?;
                Some((pd, family as u32))
            })?;
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(family)
            .queue_priorities(&priorities)];
        // The kd-tree builder's 1-byte flags need 8-bit storage (lavapipe has it).
        let mut f12 =
            vk::PhysicalDeviceVulkan12Features::default().storage_buffer8_bit_access(true);
        let listed = instance
            .enumerate_device_extension_properties(physical_device)
            .ok()?;
        let extensions: Vec<*const std::ffi::c_char> = [
            ash::khr::calibrated_timestamps::NAME,
            ash::ext::calibrated_timestamps::NAME,
        ]
        .into_iter()
        .filter(|&n| {
            calibrated
                && listed
                    .iter()
                    .any(|e| e.extension_name_as_c_str().is_ok_and(|x| x == n))
        })
        .take(1)
        .map(|n| n.as_ptr())
        .collect();
        let info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_extension_names(&extensions)
            .push_next(&mut f12);
        let device = instance.create_device(physical_device, &info, None).ok()?;
        // What vkrt is told the device has: read from the same create info.
        let features = DeviceFeatures::from_device_create_info(&info, vk::API_VERSION_1_2);
        let queue = device.get_device_queue(family, 0);
        Some(Renderer {
            entry,
            instance,
            physical_device,
            device,
            family,
            queue,
            features,
        })
    }
}

#[test]
fn an_adopted_device_with_calibrated_timestamps_gets_calibrated_profiles() {
    let Some(r) = renderer_with(true) else { return };
    let Some(which) = r.features.calibrated_timestamps else {
        eprintln!("skipped: the device has no calibrated timestamps");
        return;
    };
    let parts = r.parts(None);
    // SAFETY: as in the test above; the context is dropped before the device.
    let ctx = unsafe { Context::from_raw(parts) }.expect("adopt the renderer's device");
    let c = ctx.calibrate().unwrap().expect("a device with timestamps");
    assert_eq!(c.method, which.name().to_str().unwrap());
    assert!(c.max_deviation_ns.is_some(), "{c:?}");
    drop(ctx);
    // SAFETY: the context is gone; nothing of the device is in use.
    unsafe {
        r.device.destroy_device(None);
        r.instance.destroy_instance(None);
    }
}

#[test]
fn vkrt_runs_in_a_caller_owned_command_buffer_and_leaves_the_device_alive() {
    let Some(r) = renderer() else {
        assert!(
            std::env::var("VKRT_ALLOW_NO_GPU").is_ok_and(|v| v == "1"),
            "no Vulkan device"
        );
        return;
    };
    let allocator = Arc::new(Mutex::new(
        Allocator::new(&AllocatorCreateDesc {
            instance: r.instance.clone(),
            device: r.device.clone(),
            physical_device: r.physical_device,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        })
        .unwrap(),
    ));
    assert_eq!(
        r.features,
        DeviceFeatures {
            storage_buffer_8bit: true,
            ..DeviceFeatures::default()
        }
    );
    let parts = r.parts(Some(allocator.clone()));
    // SAFETY: the handles are valid and outlive the context (destroyed at the end of the
    // test, after the context is dropped); this thread is the only queue user.
    let ctx = unsafe { Context::from_raw(parts) }.expect("adopt the renderer's device");

    let n = 1000u32;
    let x = Buffer::from_slice(&ctx, "embed.x", &vec![2.0f32; n as usize]).unwrap();
    let y = Buffer::from_slice(&ctx, "embed.y", &vec![1.0f32; n as usize]).unwrap();
    // The renderer enabled no bufferDeviceAddress: an address is an error naming it.
    match x.device_address() {
        Err(GpuError::MissingCapability { what, .. }) => {
            assert!(what.contains("bufferDeviceAddress"))
        }
        other => panic!("{other:?}"),
    }
    let kernel = ctx
        .kernel(&kernels::GPU_SAXPY, &Spec::new().workgroup(64))
        .unwrap();

    // The renderer's own command pool and command buffer.
    let (pool, cmd) = r.begin_commands();
    // SAFETY: `cmd` is recording, of the context's family; the buffers outlive its execution;
    // `complete` is called after the fence wait below.
    let mut rec = unsafe { Recorder::from_raw(&ctx, cmd, 16) }.unwrap();
    rec.scope("embedded.saxpy", |rec| {
        let groups = rec.groups_1d(u64::from(n), 64);
        rec.dispatch(&kernel, groups, &[&x, &y], &SaxpyPush { a: 3.0, n });
    });
    rec.compute_to_transfer();
    let back = rec.read_back(&y).unwrap();
    rec.transfer_to_host();
    let work = rec.finish().unwrap();
    // Not yet: the work is not known complete, so the host may not read what it writes.
    let early = back.read().unwrap_err();
    assert!(matches!(early, GpuError::Usage { .. }), "{early}");
    r.submit_and_wait(cmd);
    // SAFETY: the command buffer has finished executing (fence waited above).
    let profile = unsafe { work.complete() }.unwrap();
    assert!(back.read().unwrap().iter().all(|&v| v == 7.0));
    assert_eq!(profile.passes.len(), 1);
    assert_eq!(profile.passes[0].name, "embedded.saxpy");
    if ctx.info().timestamps {
        assert!(profile.passes[0].ms.unwrap() > 0.0);
        // An adopted device has no calibrated timestamps of vkrt's: the first tick is put
        // at the host time the recording was finished.
        let s = &profile.submissions[0];
        let c = s.calibration.unwrap();
        assert_eq!(c.method, vkrt::gpu::timeline::SUBMIT_ALIGNED);
        assert_eq!(c.max_deviation_ns, None);
        assert_eq!(
            profile.host_interval_ns(0).unwrap().0,
            s.submitted_ns as f64
        );
        assert!(s.submitted_ns <= s.completed_ns);
    }
    assert!(y.download().unwrap().iter().all(|&v| v == 7.0));

    // vkrt never submits the renderer's command buffer: asked to, it says so.
    let (pool2, cmd2) = r.begin_commands();
    // SAFETY: as above; nothing is recorded and `cmd2` is submitted empty below.
    let rec = unsafe { Recorder::from_raw(&ctx, cmd2, 0) }.unwrap();
    let err = rec.submit_and_wait().unwrap_err();
    assert!(matches!(err, GpuError::Usage { .. }), "{err}");
    r.submit_and_wait(cmd2);
    // SAFETY: the empty command buffer has executed.
    unsafe { r.device.destroy_command_pool(pool2, None) };

    // A device-wide wait is the renderer's to make, not vkrt's.
    let err = ctx.wait_idle().unwrap_err();
    assert!(matches!(err, GpuError::Usage { .. }), "{err}");

    // A recording with a refused command (a kernel given one binding of two) is no
    // RecordedWork: finish() returns the refusal, and the renderer resets its command buffer.
    let (pool3, cmd3) = r.begin_commands();
    // SAFETY: as above; the command buffer is reset below and never submitted.
    let mut rec = unsafe { Recorder::from_raw(&ctx, cmd3, 4) }.unwrap();
    rec.dispatch(&kernel, [1, 1, 1], &[&x], &SaxpyPush { a: 1.0, n });
    match rec.finish() {
        Err(GpuError::Usage { call, .. }) => assert!(call.contains("dispatch"), "{call}"),
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("a failed recording finished"),
    }
    // SAFETY: never submitted; the pool goes with its command buffer.
    unsafe { r.device.destroy_command_pool(pool3, None) };

    // A convenience submission on the adopted queue works too.
    let z = Buffer::from_slice(&ctx, "embed.z", &[5u32; 17]).unwrap();
    assert_eq!(z.download().unwrap(), vec![5u32; 17]);

    for kind in AccelKind::ALL {
        embedded_build_and_trace(&r, &ctx, kind);
    }

    drop((x, y, z, kernel, back));
    drop(ctx);

    // The renderer's device, queue and allocator are still alive and usable.
    // SAFETY: plain Vulkan on the renderer's device, which vkrt must not have destroyed.
    unsafe {
        r.device.device_wait_idle().expect("device still alive");
        let buffer = r
            .device
            .create_buffer(
                &vk::BufferCreateInfo::default()
                    .size(256)
                    .usage(vk::BufferUsageFlags::STORAGE_BUFFER),
                None,
            )
            .expect("device still creates objects");
        let requirements = r.device.get_buffer_memory_requirements(buffer);
        let allocation = allocator
            .lock()
            .unwrap()
            .allocate(&gpu_allocator::vulkan::AllocationCreateDesc {
                name: "after-vkrt",
                requirements,
                location: gpu_allocator::MemoryLocation::GpuOnly,
                linear: true,
                allocation_scheme: gpu_allocator::vulkan::AllocationScheme::GpuAllocatorManaged,
            })
            .expect("the renderer's allocator still works");
        allocator.lock().unwrap().free(allocation).unwrap();
        r.device.destroy_buffer(buffer, None);
        r.device.destroy_command_pool(pool, None);
        drop(allocator);
        r.device.destroy_device(None);
        r.instance.destroy_instance(None);
    }
}

/// The renderer records vkrt's upload, structure build and trace between its own commands
/// into its own command buffer and submits it once: vkrt submits nothing, and the hits
/// equal brute force.
fn embedded_build_and_trace(r: &Renderer, ctx: &Context, kind: AccelKind) {
    let sphere = vkrt::scene::gen::icosphere(3).unwrap();
    let tris = common::mesh_triangles(&sphere);
    let g = TraceGeometry::from_triangles(&tris);
    let rays: Vec<Ray> = (0..500)
        .map(|i| {
            let a = i as f32 * 0.37;
            let o = Vec3::new(a.cos(), a.sin(), (i as f32 * 0.11).sin()) * 3.0;
            Ray::new(
                o,
                -o + Vec3::splat(0.01 * (i % 7) as f32),
                0.0,
                f32::INFINITY,
            )
        })
        .collect();
    let opt = TraceOptions::default();
    let builder = AccelBuilder::new(ctx, kind).unwrap();
    let tracer = Tracer::for_accel(ctx, &opt, kind.walked(Default::default())).unwrap();
    let sizes = builder.sizes(ctx, g.primitive_count(), 0).unwrap();
    assert!(sizes.structure_bytes > 0);
    let ray_buf = Buffer::<Ray>::new(ctx, "embed.rays", rays.len()).unwrap();
    let hits = Buffer::<Hit>::new(ctx, "embed.hits", rays.len()).unwrap();
    let errors = Buffer::<u32>::new(ctx, "embed.errors", 1).unwrap();
    let before = ctx.traffic();
    let (pool, cmd) = r.begin_commands();
    // SAFETY: `cmd` is recording, of the context's family; everything bound outlives its
    // execution (the geometry below is dropped after the fence wait); `complete` follows it.
    let mut rec = unsafe { Recorder::from_raw(ctx, cmd, 4096) }.unwrap();
    rec.upload(&ray_buf, &rays).unwrap();
    rec.fill(&errors, 0);
    let (geom, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
    rec.scope("embedded.trace", |rec| {
        tracer.record(rec, &geom, &ray_buf, &hits, &errors, rays.len(), 0.0)
    })
    .unwrap();
    rec.compute_to_transfer();
    let work = rec.finish().unwrap();
    assert_eq!(
        (ctx.traffic() - before).submits,
        0,
        "vkrt submitted on its own"
    );
    r.submit_and_wait(cmd);
    // SAFETY: the command buffer has finished executing.
    let profile = unsafe { work.complete() }.unwrap();
    assert!(profile.passes.iter().any(|p| p.name == "embedded.trace"));
    if kind == AccelKind::KdTree {
        assert!(profile.passes.iter().any(|p| p.name == "kdtree.phase2"));
    }
    let got = hits.download().unwrap();
    assert_eq!(errors.download().unwrap(), [0]);
    let mut n_hits = 0;
    for (ray, h) in rays.iter().zip(&got) {
        let b = cpu::brute_force(&g, ray, 0.0, &opt);
        assert_eq!(h.is_hit(), b.is_hit(), "{kind:?} {ray:?}");
        if h.is_hit() {
            n_hits += 1;
            assert!(
                (h.t - b.t).abs() <= 1e-5 * b.t,
                "{kind:?}: t {} vs {}",
                h.t,
                b.t
            );
        }
    }
    assert!(n_hits > 400, "{kind:?}: {n_hits} hits");
    drop(geom);
    // SAFETY: the pool's command buffer has executed.
    unsafe { r.device.destroy_command_pool(pool, None) };
}

/// `Tracer::record` over ranges of one buffer of the caller's (rays, hits and the counter at
/// aligned offsets in it, as a renderer suballocates): the hits of the same rays through
/// vkrt's own buffers, bit for bit; a range at an offset the device does not allow is an
/// error before anything is recorded.
#[test]
fn tracer_records_over_ranges_of_the_callers_buffer() {
    let Some(ctx) = common::context() else { return };
    let sphere = vkrt::scene::gen::icosphere(3).unwrap();
    let g = TraceGeometry::from_triangles(&common::mesh_triangles(&sphere));
    let rays: Vec<Ray> = (0..300)
        .map(|i| {
            let a = i as f32 * 0.41;
            let o = Vec3::new(a.cos(), (i as f32 * 0.07).sin(), a.sin()) * 3.0;
            Ray::new(
                o,
                -o + Vec3::splat(0.02 * (i % 5) as f32),
                0.0,
                f32::INFINITY,
            )
        })
        .collect();
    let builder = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let tracer = Tracer::for_accel(
        &ctx,
        &TraceOptions::default(),
        AccelKind::Lbvh.walked(Default::default()),
    )
    .unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let (geom, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
    rec.submit_and_wait().unwrap();
    let want = tracer.trace(&ctx, &geom, &rays, 0.0).unwrap().hits;

    // One buffer of the caller's: rays, then hits, then the counter, each range starting
    // at a multiple of the device's storage offset alignment.
    let align = ctx.info().min_storage_buffer_offset_alignment.max(4);
    let up = |x: u64| x.div_ceil(align) * align;
    let ray_bytes = std::mem::size_of_val(rays.as_slice()) as u64;
    let hit_bytes = (rays.len() * std::mem::size_of::<Hit>()) as u64;
    let (hits_at, errors_at) = (up(ray_bytes), up(up(ray_bytes) + hit_bytes));
    let words = Buffer::<u32>::new(&ctx, "renderer.arena", ((errors_at + 4) / 4) as usize).unwrap();
    let range = |offset: u64, size: u64| unsafe {
        vkrt::gpu::RawBuffer::new(
            words.as_raw().buffer(),
            words.as_raw().offset() + offset,
            size,
        )
    };
    let mut rec = Recorder::new(&ctx).unwrap();
    for (k, chunk) in bytemuck::cast_slice::<Ray, u32>(&rays)
        .chunks(4096)
        .enumerate()
    {
        rec.update(&words, k * 4096, chunk).unwrap();
    }
    rec.update(&words, (errors_at / 4) as usize, &[0]).unwrap();
    rec.transfer_to_compute();
    let misaligned = tracer.record(
        &mut rec,
        &geom,
        &range(4, ray_bytes),
        &range(hits_at, hit_bytes),
        &range(errors_at, 4),
        rays.len(),
        0.0,
    );
    assert!(
        misaligned.is_err() || align == 4,
        "a misaligned ray range was recorded"
    );
    let short = tracer.record(
        &mut rec,
        &geom,
        &range(0, ray_bytes - 32),
        &range(hits_at, hit_bytes),
        &range(errors_at, 4),
        rays.len(),
        0.0,
    );
    assert!(
        matches!(short, Err(GpuError::Usage { .. })),
        "{short:?}: a ray range one ray short"
    );
    tracer
        .record(
            &mut rec,
            &geom,
            &range(0, ray_bytes),
            &range(hits_at, hit_bytes),
            &range(errors_at, 4),
            rays.len(),
            0.0,
        )
        .unwrap();
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    let back = words.download().unwrap();
    let bytes: &[u8] = bytemuck::cast_slice(&back);
    let got: &[Hit] =
        bytemuck::cast_slice(&bytes[hits_at as usize..(hits_at + hit_bytes) as usize]);
    assert_eq!(
        bytemuck::cast_slice::<Hit, u32>(got),
        bytemuck::cast_slice::<Hit, u32>(&want)
    );
    assert_eq!(back[(errors_at / 4) as usize], 0);
    assert!(want.iter().filter(|h| h.is_hit()).count() > 100);
    common::assert_silent(&ctx);
}
