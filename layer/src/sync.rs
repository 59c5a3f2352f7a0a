//! Synchronization: the extension's acceleration-structure stages and accesses become the
//! work vkrt's builds are (compute shaders, transfers, indirect dispatches) and the reads its
//! lowered shaders make (texel and device-address reads), in every barrier, event, submit
//! and subpass dependency. A mask without those bits passes unchanged.

use ash::vk;

use crate::commands::slice;
use crate::device::served;
use crate::{guard, pfn};

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkCmdPipelineBarrier" => pfn!(cmd_pipeline_barrier, vk::PFN_vkCmdPipelineBarrier),
        b"vkCmdPipelineBarrier2" | b"vkCmdPipelineBarrier2KHR" => {
            pfn!(cmd_pipeline_barrier2, vk::PFN_vkCmdPipelineBarrier2)
        }
        b"vkCmdWaitEvents" => pfn!(cmd_wait_events, vk::PFN_vkCmdWaitEvents),
        b"vkCmdWaitEvents2" | b"vkCmdWaitEvents2KHR" => {
            pfn!(cmd_wait_events2, vk::PFN_vkCmdWaitEvents2)
        }
        b"vkCmdSetEvent" => pfn!(cmd_set_event, vk::PFN_vkCmdSetEvent),
        b"vkCmdSetEvent2" | b"vkCmdSetEvent2KHR" => pfn!(cmd_set_event2, vk::PFN_vkCmdSetEvent2),
        b"vkCmdResetEvent" => pfn!(cmd_reset_event, vk::PFN_vkCmdResetEvent),
        b"vkCmdResetEvent2" | b"vkCmdResetEvent2KHR" => {
            pfn!(cmd_reset_event2, vk::PFN_vkCmdResetEvent2)
        }
        b"vkQueueSubmit" => pfn!(queue_submit, vk::PFN_vkQueueSubmit),
        b"vkQueueSubmit2" | b"vkQueueSubmit2KHR" => pfn!(queue_submit2, vk::PFN_vkQueueSubmit2),
        b"vkCreateRenderPass" => pfn!(create_render_pass, vk::PFN_vkCreateRenderPass),
        b"vkCreateRenderPass2" | b"vkCreateRenderPass2KHR" => {
            pfn!(create_render_pass2, vk::PFN_vkCreateRenderPass2)
        }
        _ => None,
    }
}

// Acceleration-structure stages and accesses, as vkrt's builds and lowered shaders are.
const AS_BUILD: u64 = vk::PipelineStageFlags2::ACCELERATION_STRUCTURE_BUILD_KHR.as_raw();
const AS_COPY: u64 = vk::PipelineStageFlags2::ACCELERATION_STRUCTURE_COPY_KHR.as_raw();
const AS_READ: u64 = vk::AccessFlags2::ACCELERATION_STRUCTURE_READ_KHR.as_raw();
const AS_WRITE: u64 = vk::AccessFlags2::ACCELERATION_STRUCTURE_WRITE_KHR.as_raw();
/// A build: compute kernels, fills and copies, indirect dispatches.
const BUILD_STAGES: u64 = vk::PipelineStageFlags2::COMPUTE_SHADER.as_raw()
    | vk::PipelineStageFlags2::TRANSFER.as_raw()
    | vk::PipelineStageFlags2::DRAW_INDIRECT.as_raw();

/// Stages that run shaders (a structure read there is a texel and device-address read).
const SHADER_STAGES: u64 = vk::PipelineStageFlags2::VERTEX_SHADER.as_raw()
    | vk::PipelineStageFlags2::TESSELLATION_CONTROL_SHADER.as_raw()
    | vk::PipelineStageFlags2::TESSELLATION_EVALUATION_SHADER.as_raw()
    | vk::PipelineStageFlags2::GEOMETRY_SHADER.as_raw()
    | vk::PipelineStageFlags2::FRAGMENT_SHADER.as_raw()
    | vk::PipelineStageFlags2::COMPUTE_SHADER.as_raw()
    | vk::PipelineStageFlags2::PRE_RASTERIZATION_SHADERS.as_raw()
    | vk::PipelineStageFlags2::ALL_GRAPHICS.as_raw()
    | vk::PipelineStageFlags2::ALL_COMMANDS.as_raw()
    | vk::PipelineStageFlags2::TASK_SHADER_EXT.as_raw()
    | vk::PipelineStageFlags2::MESH_SHADER_EXT.as_raw();
const TRANSFER_STAGES: u64 = vk::PipelineStageFlags2::TRANSFER.as_raw()
    | vk::PipelineStageFlags2::ALL_TRANSFER.as_raw()
    | vk::PipelineStageFlags2::COPY.as_raw()
    | vk::PipelineStageFlags2::CLEAR.as_raw()
    | vk::PipelineStageFlags2::ALL_COMMANDS.as_raw();
const INDIRECT_STAGES: u64 = vk::PipelineStageFlags2::DRAW_INDIRECT.as_raw()
    | vk::PipelineStageFlags2::ALL_COMMANDS.as_raw();

fn stages(s: u64) -> u64 {
    if s & (AS_BUILD | AS_COPY) == 0 {
        return s;
    }
    (s & !(AS_BUILD | AS_COPY)) | BUILD_STAGES
}

/// An access mask for translated `stages` (each access one of those stages supports).
fn access(a: u64, stages: u64) -> u64 {
    if a & (AS_READ | AS_WRITE) == 0 {
        return a;
    }
    let mut out = a & !(AS_READ | AS_WRITE);
    let (shader, transfer, indirect) = (
        stages & SHADER_STAGES != 0,
        stages & TRANSFER_STAGES != 0,
        stages & INDIRECT_STAGES != 0,
    );
    if a & AS_READ != 0 {
        if shader {
            out |= vk::AccessFlags2::SHADER_READ.as_raw();
        }
        if transfer {
            out |= vk::AccessFlags2::TRANSFER_READ.as_raw();
        }
        if indirect {
            out |= vk::AccessFlags2::INDIRECT_COMMAND_READ.as_raw();
        }
    }
    if a & AS_WRITE != 0 {
        if shader {
            out |= vk::AccessFlags2::SHADER_WRITE.as_raw();
        }
        if transfer {
            out |= vk::AccessFlags2::TRANSFER_WRITE.as_raw();
        }
    }
    out
}

fn stages1(s: vk::PipelineStageFlags) -> vk::PipelineStageFlags {
    vk::PipelineStageFlags::from_raw(stages(u64::from(s.as_raw())) as u32)
}

fn access1(a: vk::AccessFlags, s: vk::PipelineStageFlags) -> vk::AccessFlags {
    vk::AccessFlags::from_raw(access(u64::from(a.as_raw()), u64::from(s.as_raw())) as u32)
}

fn stages2(s: vk::PipelineStageFlags2) -> vk::PipelineStageFlags2 {
    vk::PipelineStageFlags2::from_raw(stages(s.as_raw()))
}

fn access2(a: vk::AccessFlags2, s: vk::PipelineStageFlags2) -> vk::AccessFlags2 {
    vk::AccessFlags2::from_raw(access(a.as_raw(), s.as_raw()))
}

/// A dependency of synchronization2, translated, with the arrays it points to.
struct Dependency<'a> {
    info: vk::DependencyInfo<'a>,
    _memory: Vec<vk::MemoryBarrier2<'a>>,
    _buffers: Vec<vk::BufferMemoryBarrier2<'a>>,
    _images: Vec<vk::ImageMemoryBarrier2<'a>>,
}

macro_rules! translate2 {
    ($b:expr) => {{
        $b.src_stage_mask = stages2($b.src_stage_mask);
        $b.dst_stage_mask = stages2($b.dst_stage_mask);
        $b.src_access_mask = access2($b.src_access_mask, $b.src_stage_mask);
        $b.dst_access_mask = access2($b.dst_access_mask, $b.dst_stage_mask);
    }};
}

/// # Safety
/// `info` is valid.
unsafe fn dependency<'a>(info: &vk::DependencyInfo<'a>) -> Dependency<'a> {
    let mut ours = *info;
    // SAFETY: the caller's arrays of their counts.
    let (mut memory, mut buffers, mut images) = unsafe {
        (
            slice(ours.p_memory_barriers, ours.memory_barrier_count).to_vec(),
            slice(
                ours.p_buffer_memory_barriers,
                ours.buffer_memory_barrier_count,
            )
            .to_vec(),
            slice(
                ours.p_image_memory_barriers,
                ours.image_memory_barrier_count,
            )
            .to_vec(),
        )
    };
    memory.iter_mut().for_each(|b| translate2!(b));
    buffers.iter_mut().for_each(|b| translate2!(b));
    images.iter_mut().for_each(|b| translate2!(b));
    ours.p_memory_barriers = memory.as_ptr();
    ours.p_buffer_memory_barriers = buffers.as_ptr();
    ours.p_image_memory_barriers = images.as_ptr();
    Dependency {
        info: ours,
        _memory: memory,
        _buffers: buffers,
        _images: images,
    }
}

/// The barriers of synchronization 1, translated for `src` and `dst`.
///
/// # Safety
/// The arrays hold their counts.
#[allow(clippy::type_complexity)]
unsafe fn barriers1<'a>(
    src: vk::PipelineStageFlags,
    dst: vk::PipelineStageFlags,
    memory: &[vk::MemoryBarrier<'a>],
    buffers: &[vk::BufferMemoryBarrier<'a>],
    images: &[vk::ImageMemoryBarrier<'a>],
) -> (
    Vec<vk::MemoryBarrier<'a>>,
    Vec<vk::BufferMemoryBarrier<'a>>,
    Vec<vk::ImageMemoryBarrier<'a>>,
) {
    macro_rules! t {
        ($v:expr) => {
            $v.iter()
                .map(|b| {
                    let mut b = *b;
                    b.src_access_mask = access1(b.src_access_mask, src);
                    b.dst_access_mask = access1(b.dst_access_mask, dst);
                    b
                })
                .collect()
        };
    }
    (t!(memory), t!(buffers), t!(images))
}

#[allow(clippy::too_many_arguments)]
unsafe extern "system" fn cmd_pipeline_barrier(
    cb: vk::CommandBuffer,
    src: vk::PipelineStageFlags,
    dst: vk::PipelineStageFlags,
    dependency: vk::DependencyFlags,
    memory_count: u32,
    memory: *const vk::MemoryBarrier<'_>,
    buffer_count: u32,
    buffers: *const vk::BufferMemoryBarrier<'_>,
    image_count: u32,
    images: *const vk::ImageMemoryBarrier<'_>,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let (src, dst) = (stages1(src), stages1(dst));
        // SAFETY: the application's arrays of their counts.
        let (m, b, i) = unsafe {
            barriers1(
                src,
                dst,
                slice(memory, memory_count),
                slice(buffers, buffer_count),
                slice(images, image_count),
            )
        };
        // SAFETY: the application's barrier, its acceleration-structure bits translated.
        unsafe {
            (s.fns.fp_v1_0().cmd_pipeline_barrier)(
                cb,
                src,
                dst,
                dependency,
                memory_count,
                m.as_ptr(),
                buffer_count,
                b.as_ptr(),
                image_count,
                i.as_ptr(),
            )
        };
    })
}

unsafe extern "system" fn cmd_pipeline_barrier2(
    cb: vk::CommandBuffer,
    info: *const vk::DependencyInfo<'_>,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let Some(f) = s.sync2.pipeline_barrier2 else {
            return;
        };
        // SAFETY: the application's valid struct.
        let d = unsafe { dependency(&*info) };
        // SAFETY: the application's barrier, its acceleration-structure bits translated.
        unsafe { f(cb, &d.info) };
    })
}

#[allow(clippy::too_many_arguments)]
unsafe extern "system" fn cmd_wait_events(
    cb: vk::CommandBuffer,
    event_count: u32,
    events: *const vk::Event,
    src: vk::PipelineStageFlags,
    dst: vk::PipelineStageFlags,
    memory_count: u32,
    memory: *const vk::MemoryBarrier<'_>,
    buffer_count: u32,
    buffers: *const vk::BufferMemoryBarrier<'_>,
    image_count: u32,
    images: *const vk::ImageMemoryBarrier<'_>,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let (src, dst) = (stages1(src), stages1(dst));
        // SAFETY: the application's arrays of their counts.
        let (m, b, i) = unsafe {
            barriers1(
                src,
                dst,
                slice(memory, memory_count),
                slice(buffers, buffer_count),
                slice(images, image_count),
            )
        };
        // SAFETY: the application's wait, its acceleration-structure bits translated.
        unsafe {
            (s.fns.fp_v1_0().cmd_wait_events)(
                cb,
                event_count,
                events,
                src,
                dst,
                memory_count,
                m.as_ptr(),
                buffer_count,
                b.as_ptr(),
                image_count,
                i.as_ptr(),
            )
        };
    })
}

unsafe extern "system" fn cmd_wait_events2(
    cb: vk::CommandBuffer,
    count: u32,
    events: *const vk::Event,
    infos: *const vk::DependencyInfo<'_>,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let Some(f) = s.sync2.wait_events2 else {
            return;
        };
        // SAFETY: the application's `count` dependencies.
        let deps: Vec<Dependency<'_>> = unsafe { slice(infos, count) }
            .iter()
            // SAFETY: each valid.
            .map(|d| unsafe { dependency(d) })
            .collect();
        let infos: Vec<vk::DependencyInfo<'_>> = deps.iter().map(|d| d.info).collect();
        // SAFETY: the application's wait, translated.
        unsafe { f(cb, count, events, infos.as_ptr()) };
    })
}

unsafe extern "system" fn cmd_set_event(
    cb: vk::CommandBuffer,
    event: vk::Event,
    stage: vk::PipelineStageFlags,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        // SAFETY: the application's call, its stage translated.
        unsafe { (s.fns.fp_v1_0().cmd_set_event)(cb, event, stages1(stage)) };
    })
}

unsafe extern "system" fn cmd_reset_event(
    cb: vk::CommandBuffer,
    event: vk::Event,
    stage: vk::PipelineStageFlags,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        // SAFETY: the application's call, its stage translated.
        unsafe { (s.fns.fp_v1_0().cmd_reset_event)(cb, event, stages1(stage)) };
    })
}

unsafe extern "system" fn cmd_set_event2(
    cb: vk::CommandBuffer,
    event: vk::Event,
    info: *const vk::DependencyInfo<'_>,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let Some(f) = s.sync2.set_event2 else { return };
        // SAFETY: the application's valid struct.
        let d = unsafe { dependency(&*info) };
        // SAFETY: the application's call, translated.
        unsafe { f(cb, event, &d.info) };
    })
}

unsafe extern "system" fn cmd_reset_event2(
    cb: vk::CommandBuffer,
    event: vk::Event,
    stage: vk::PipelineStageFlags2,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let Some(f) = s.sync2.reset_event2 else {
            return;
        };
        // SAFETY: the application's call, its stage translated.
        unsafe { f(cb, event, stages2(stage)) };
    })
}

unsafe extern "system" fn queue_submit(
    queue: vk::Queue,
    count: u32,
    submits: *const vk::SubmitInfo<'_>,
    fence: vk::Fence,
) -> vk::Result {
    guard(vk::Result::ERROR_DEVICE_LOST, || {
        let Some(s) = served(queue) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's `count` submits.
        let submits_v = unsafe { slice(submits, count) };
        let mut masks: Vec<Vec<vk::PipelineStageFlags>> = Vec::new();
        let mut ours: Vec<vk::SubmitInfo<'_>> = Vec::with_capacity(submits_v.len());
        for sub in submits_v {
            let mut sub = *sub;
            // SAFETY: one stage mask per wait semaphore.
            let m: Vec<_> = unsafe { slice(sub.p_wait_dst_stage_mask, sub.wait_semaphore_count) }
                .iter()
                .map(|&m| stages1(m))
                .collect();
            sub.p_wait_dst_stage_mask = m.as_ptr();
            masks.push(m);
            ours.push(sub);
        }
        // SAFETY: the application's submit, its wait stages translated.
        unsafe { (s.fns.fp_v1_0().queue_submit)(queue, count, ours.as_ptr(), fence) }
    })
}

unsafe extern "system" fn queue_submit2(
    queue: vk::Queue,
    count: u32,
    submits: *const vk::SubmitInfo2<'_>,
    fence: vk::Fence,
) -> vk::Result {
    guard(vk::Result::ERROR_DEVICE_LOST, || {
        let Some(s) = served(queue) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        let Some(f) = s.sync2.queue_submit2 else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's `count` submits.
        let submits_v = unsafe { slice(submits, count) };
        let mut semaphores: Vec<Vec<vk::SemaphoreSubmitInfo<'_>>> = Vec::new();
        let mut ours: Vec<vk::SubmitInfo2<'_>> = Vec::with_capacity(submits_v.len());
        for sub in submits_v {
            let mut sub = *sub;
            let translate = |p, n| -> Vec<vk::SemaphoreSubmitInfo<'_>> {
                // SAFETY: the application's array of its count.
                unsafe { slice(p, n) }
                    .iter()
                    .map(|w: &vk::SemaphoreSubmitInfo<'_>| vk::SemaphoreSubmitInfo {
                        stage_mask: stages2(w.stage_mask),
                        ..*w
                    })
                    .collect()
            };
            let waits = translate(sub.p_wait_semaphore_infos, sub.wait_semaphore_info_count);
            let signals = translate(
                sub.p_signal_semaphore_infos,
                sub.signal_semaphore_info_count,
            );
            sub.p_wait_semaphore_infos = waits.as_ptr();
            sub.p_signal_semaphore_infos = signals.as_ptr();
            semaphores.push(waits);
            semaphores.push(signals);
            ours.push(sub);
        }
        // SAFETY: the application's submit, its stages translated.
        unsafe { f(queue, count, ours.as_ptr(), fence) }
    })
}

unsafe extern "system" fn create_render_pass(
    device: vk::Device,
    info: *const vk::RenderPassCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::RenderPass,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info.
        let mut ours = unsafe { *info };
        // SAFETY: its dependencies, of their count.
        let deps: Vec<vk::SubpassDependency> =
            unsafe { slice(ours.p_dependencies, ours.dependency_count) }
                .iter()
                .map(|d| {
                    let (src, dst) = (stages1(d.src_stage_mask), stages1(d.dst_stage_mask));
                    vk::SubpassDependency {
                        src_stage_mask: src,
                        dst_stage_mask: dst,
                        src_access_mask: access1(d.src_access_mask, src),
                        dst_access_mask: access1(d.dst_access_mask, dst),
                        ..*d
                    }
                })
                .collect();
        ours.p_dependencies = deps.as_ptr();
        // SAFETY: the application's call, its dependencies translated.
        unsafe { (s.fns.fp_v1_0().create_render_pass)(device, &ours, allocator, out) }
    })
}

unsafe extern "system" fn create_render_pass2(
    device: vk::Device,
    info: *const vk::RenderPassCreateInfo2<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::RenderPass,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        let Some(f) = s.sync2.create_render_pass2 else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info.
        let mut ours = unsafe { *info };
        // SAFETY: its dependencies, of their count. (A VkMemoryBarrier2 chained to one, which
        // synchronization2 allows, passes as the application wrote it.)
        let deps: Vec<vk::SubpassDependency2<'_>> =
            unsafe { slice(ours.p_dependencies, ours.dependency_count) }
                .iter()
                .map(|d| {
                    let (src, dst) = (stages1(d.src_stage_mask), stages1(d.dst_stage_mask));
                    vk::SubpassDependency2 {
                        src_stage_mask: src,
                        dst_stage_mask: dst,
                        src_access_mask: access1(d.src_access_mask, src),
                        dst_access_mask: access1(d.dst_access_mask, dst),
                        ..*d
                    }
                })
                .collect();
        ours.p_dependencies = deps.as_ptr();
        // SAFETY: the application's call, its dependencies translated.
        unsafe { f(device, &ours, allocator, out) }
    })
}

/// The synchronization-2 and render-pass-2 entry points, core or by their extension's name,
/// where the device has them.
#[derive(Default)]
pub struct Sync2Fns {
    pub pipeline_barrier2: Option<vk::PFN_vkCmdPipelineBarrier2>,
    pub wait_events2: Option<vk::PFN_vkCmdWaitEvents2>,
    pub set_event2: Option<vk::PFN_vkCmdSetEvent2>,
    pub reset_event2: Option<vk::PFN_vkCmdResetEvent2>,
    pub queue_submit2: Option<vk::PFN_vkQueueSubmit2>,
    pub create_render_pass2: Option<vk::PFN_vkCreateRenderPass2>,
}

impl Sync2Fns {
    /// # Safety
    /// `gdpa` is the next layer's `vkGetDeviceProcAddr`, `device` live.
    pub unsafe fn load(gdpa: vk::PFN_vkGetDeviceProcAddr, device: vk::Device) -> Self {
        macro_rules! load {
            ($core:literal, $khr:literal, $t:ty) => {
                [$core, $khr]
                    .iter()
                    // SAFETY: the next layer's entry point, by name.
                    .find_map(|n: &&std::ffi::CStr| unsafe { gdpa(device, n.as_ptr()) })
                    // SAFETY: the loader's pointer is the function of that name.
                    .map(|f| unsafe { std::mem::transmute::<unsafe extern "system" fn(), $t>(f) })
            };
        }
        Self {
            pipeline_barrier2: load!(
                c"vkCmdPipelineBarrier2",
                c"vkCmdPipelineBarrier2KHR",
                vk::PFN_vkCmdPipelineBarrier2
            ),
            wait_events2: load!(
                c"vkCmdWaitEvents2",
                c"vkCmdWaitEvents2KHR",
                vk::PFN_vkCmdWaitEvents2
            ),
            set_event2: load!(
                c"vkCmdSetEvent2",
                c"vkCmdSetEvent2KHR",
                vk::PFN_vkCmdSetEvent2
            ),
            reset_event2: load!(
                c"vkCmdResetEvent2",
                c"vkCmdResetEvent2KHR",
                vk::PFN_vkCmdResetEvent2
            ),
            queue_submit2: load!(
                c"vkQueueSubmit2",
                c"vkQueueSubmit2KHR",
                vk::PFN_vkQueueSubmit2
            ),
            create_render_pass2: load!(
                c"vkCreateRenderPass2",
                c"vkCreateRenderPass2KHR",
                vk::PFN_vkCreateRenderPass2
            ),
        }
    }
}
