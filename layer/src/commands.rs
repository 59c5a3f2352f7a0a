//! The application's command buffers: what vkrt's builds in them use (released when the
//! command buffer is reset or freed: it cannot be pending then), the compute state the
//! application bound (put back after every build), and barriers whose
//! acceleration-structure stages and accesses become the compute and transfer work vkrt's
//! builds are.

use ash::vk;
use vkrt::gpu::RecordedWork;

use crate::device::{served, Served};
use crate::{guard, log, pfn, HandleMap};

/// The command buffers of a device.
#[derive(Default)]
pub struct CommandBuffers {
    buffers: HandleMap<vk::CommandBuffer, CommandBufferState>,
}

#[derive(Default)]
struct CommandBufferState {
    pool: vk::CommandPool,
    /// vkrt's recordings in it.
    work: Vec<RecordedWork>,
    compute: ComputeState,
}

/// What the application bound at the compute bind point.
#[derive(Default)]
struct ComputeState {
    pipeline: Option<vk::Pipeline>,
    /// Its descriptor-set binds, in order (layout, first set, sets, dynamic offsets).
    sets: Vec<(vk::PipelineLayout, u32, Vec<vk::DescriptorSet>, Vec<u32>)>,
    /// Its push constants, in order (layout, stages, offset, bytes).
    push: Vec<(vk::PipelineLayout, vk::ShaderStageFlags, u32, Vec<u8>)>,
    /// Its push descriptors, in order.
    push_descriptors: Vec<PushDescriptors>,
}

/// One push of descriptors at the compute bind point, its structures already texel views.
enum PushDescriptors {
    /// `vkCmdPushDescriptorSetKHR`: layout, set, writes.
    Writes(vk::PipelineLayout, u32, Vec<OwnedWrite>),
    /// `vkCmdPushDescriptorSetWithTemplateKHR`: template, layout, set, the data its entries
    /// read.
    Template(
        vk::DescriptorUpdateTemplate,
        vk::PipelineLayout,
        u32,
        Vec<u8>,
    ),
}

/// A descriptor write with the arrays it points to.
struct OwnedWrite {
    binding: u32,
    element: u32,
    ty: vk::DescriptorType,
    count: u32,
    images: Vec<vk::DescriptorImageInfo>,
    buffers: Vec<vk::DescriptorBufferInfo>,
    views: Vec<vk::BufferView>,
}

impl OwnedWrite {
    /// # Safety
    /// `w`'s arrays hold its count.
    unsafe fn of(w: &vk::WriteDescriptorSet<'_>) -> Self {
        let n = w.descriptor_count;
        // SAFETY: the caller's contract; each array is read only for the types that use it.
        unsafe {
            Self {
                binding: w.dst_binding,
                element: w.dst_array_element,
                ty: w.descriptor_type,
                count: n,
                images: match w.p_image_info.is_null() {
                    true => Vec::new(),
                    false => slice(w.p_image_info, n).to_vec(),
                },
                buffers: match w.p_buffer_info.is_null() {
                    true => Vec::new(),
                    false => slice(w.p_buffer_info, n).to_vec(),
                },
                views: match w.p_texel_buffer_view.is_null() {
                    true => Vec::new(),
                    false => slice(w.p_texel_buffer_view, n).to_vec(),
                },
            }
        }
    }

    fn write(&self) -> vk::WriteDescriptorSet<'_> {
        let mut w = vk::WriteDescriptorSet::default()
            .dst_binding(self.binding)
            .dst_array_element(self.element)
            .descriptor_type(self.ty);
        w.descriptor_count = self.count;
        w.p_image_info = self.images.as_ptr();
        w.p_buffer_info = self.buffers.as_ptr();
        w.p_texel_buffer_view = self.views.as_ptr();
        w
    }
}

/// Keeps a compute push-descriptor write (its structures already texel views) to replay
/// after vkrt's dispatches.
pub fn note_push_descriptors(
    s: &Served,
    cb: vk::CommandBuffer,
    layout: vk::PipelineLayout,
    set: u32,
    writes: &[vk::WriteDescriptorSet<'_>],
) {
    // SAFETY: writes the layer has just translated from the application's valid ones.
    let owned: Vec<OwnedWrite> = writes
        .iter()
        .map(|w| unsafe { OwnedWrite::of(w) })
        .collect();
    note_push(s, cb, PushDescriptors::Writes(layout, set, owned));
}

/// Keeps a compute push through a template (`data`: what its entries read, structures
/// already texel views) to replay after vkrt's dispatches.
pub fn note_push_template(
    s: &Served,
    cb: vk::CommandBuffer,
    template: vk::DescriptorUpdateTemplate,
    layout: vk::PipelineLayout,
    set: u32,
    data: Vec<u8>,
) {
    note_push(
        s,
        cb,
        PushDescriptors::Template(template, layout, set, data),
    );
}

fn note_push(s: &Served, cb: vk::CommandBuffer, push: PushDescriptors) {
    if let Ok(mut c) = s.commands.lock() {
        c.buffers
            .entry(cb)
            .or_default()
            .compute
            .push_descriptors
            .push(push);
    }
}

impl CommandBuffers {
    /// Completes every recording (the device is idle).
    pub fn clear(&mut self) {
        for (_, s) in self.buffers.drain() {
            complete(s.work);
        }
    }

    fn reset(&mut self, cb: vk::CommandBuffer) {
        if let Some(s) = self.buffers.get_mut(&cb) {
            complete(std::mem::take(&mut s.work));
            s.compute = ComputeState::default();
        }
    }
}

/// Releases what finished recordings used.
fn complete(work: Vec<RecordedWork>) {
    for w in work {
        // SAFETY: the command buffer is being reset, freed or begun again, or its device
        // destroyed: none of which the application may do while it is pending.
        if let Err(e) = unsafe { w.complete() } {
            log(&format!("a build recorded earlier failed: {e}"));
        }
    }
}

/// Keeps a build's recording until its command buffer is reset or freed.
pub fn keep(s: &Served, cb: vk::CommandBuffer, work: RecordedWork) {
    if let Ok(mut c) = s.commands.lock() {
        c.buffers.entry(cb).or_default().work.push(work);
    }
}

/// Binds the application's compute pipeline, descriptor sets and push constants again
/// after vkrt's dispatches.
pub fn restore(s: &Served, cb: vk::CommandBuffer) {
    let Ok(c) = s.commands.lock() else { return };
    let Some(state) = c.buffers.get(&cb) else {
        return;
    };
    let st = &state.compute;
    let d = &s.fns;
    // SAFETY: the application's own binds, replayed in its command buffer in their order;
    // every handle was valid when it bound it, and the application keeps what it bound
    // alive while recording.
    unsafe {
        if let Some(p) = st.pipeline {
            d.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, p);
        }
        for (layout, first, sets, offsets) in &st.sets {
            d.cmd_bind_descriptor_sets(
                cb,
                vk::PipelineBindPoint::COMPUTE,
                *layout,
                *first,
                sets,
                offsets,
            );
        }
        for (layout, stages, offset, bytes) in &st.push {
            d.cmd_push_constants(cb, *layout, *stages, *offset, bytes);
        }
        for push in &st.push_descriptors {
            match push {
                PushDescriptors::Writes(layout, set, writes) => {
                    let Some(f) = s.descriptor_fns.push_descriptor_set else {
                        continue;
                    };
                    let w: Vec<vk::WriteDescriptorSet<'_>> =
                        writes.iter().map(OwnedWrite::write).collect();
                    f(
                        cb,
                        vk::PipelineBindPoint::COMPUTE,
                        *layout,
                        *set,
                        w.len() as u32,
                        w.as_ptr(),
                    );
                }
                PushDescriptors::Template(template, layout, set, data) => {
                    let Some(f) = s.descriptor_fns.push_descriptor_set_with_template else {
                        continue;
                    };
                    // A template destroyed since its push cannot be replayed.
                    if !crate::descriptors::template_alive(*template) {
                        log(
                            "a push descriptor template was destroyed before a build in \
                             the same command buffer: its push is not restored",
                        );
                        continue;
                    }
                    f(cb, *template, *layout, *set, data.as_ptr().cast());
                }
            }
        }
    }
}

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkAllocateCommandBuffers" => {
            pfn!(allocate_command_buffers, vk::PFN_vkAllocateCommandBuffers)
        }
        b"vkFreeCommandBuffers" => pfn!(free_command_buffers, vk::PFN_vkFreeCommandBuffers),
        b"vkBeginCommandBuffer" => pfn!(begin_command_buffer, vk::PFN_vkBeginCommandBuffer),
        b"vkResetCommandBuffer" => pfn!(reset_command_buffer, vk::PFN_vkResetCommandBuffer),
        b"vkResetCommandPool" => pfn!(reset_command_pool, vk::PFN_vkResetCommandPool),
        b"vkDestroyCommandPool" => pfn!(destroy_command_pool, vk::PFN_vkDestroyCommandPool),
        b"vkCmdBindPipeline" => pfn!(cmd_bind_pipeline, vk::PFN_vkCmdBindPipeline),
        b"vkCmdBindDescriptorSets" => {
            pfn!(cmd_bind_descriptor_sets, vk::PFN_vkCmdBindDescriptorSets)
        }
        b"vkCmdPushConstants" => pfn!(cmd_push_constants, vk::PFN_vkCmdPushConstants),
        _ => None,
    }
}

unsafe extern "system" fn allocate_command_buffers(
    device: vk::Device,
    info: *const vk::CommandBufferAllocateInfo<'_>,
    out: *mut vk::CommandBuffer,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's call, passed on.
        let r = unsafe { (s.fns.fp_v1_0().allocate_command_buffers)(device, info, out) };
        if r == vk::Result::SUCCESS {
            // SAFETY: the application's valid info; `out` holds its count.
            let (info, made) = unsafe {
                let info = &*info;
                (
                    info,
                    std::slice::from_raw_parts(out, info.command_buffer_count as usize),
                )
            };
            if let Ok(mut c) = s.commands.lock() {
                for &cb in made {
                    c.buffers.insert(
                        cb,
                        CommandBufferState {
                            pool: info.command_pool,
                            ..Default::default()
                        },
                    );
                }
            }
        }
        r
    })
}

unsafe extern "system" fn free_command_buffers(
    device: vk::Device,
    pool: vk::CommandPool,
    count: u32,
    buffers: *const vk::CommandBuffer,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        if let Ok(mut c) = s.commands.lock() {
            // SAFETY: the application's array of `count`.
            for cb in unsafe { std::slice::from_raw_parts(buffers, count as usize) } {
                if let Some(state) = c.buffers.remove(cb) {
                    complete(state.work);
                }
            }
        }
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().free_command_buffers)(device, pool, count, buffers) };
    })
}

unsafe extern "system" fn begin_command_buffer(
    cb: vk::CommandBuffer,
    info: *const vk::CommandBufferBeginInfo<'_>,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(cb) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // Beginning resets it implicitly.
        if let Ok(mut c) = s.commands.lock() {
            c.reset(cb);
        }
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().begin_command_buffer)(cb, info) }
    })
}

unsafe extern "system" fn reset_command_buffer(
    cb: vk::CommandBuffer,
    flags: vk::CommandBufferResetFlags,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(cb) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        if let Ok(mut c) = s.commands.lock() {
            c.reset(cb);
        }
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().reset_command_buffer)(cb, flags) }
    })
}

unsafe extern "system" fn reset_command_pool(
    device: vk::Device,
    pool: vk::CommandPool,
    flags: vk::CommandPoolResetFlags,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        if let Ok(mut c) = s.commands.lock() {
            let of_pool: Vec<_> = c
                .buffers
                .iter()
                .filter(|(_, st)| st.pool == pool)
                .map(|(&cb, _)| cb)
                .collect();
            for cb in of_pool {
                c.reset(cb);
            }
        }
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().reset_command_pool)(device, pool, flags) }
    })
}

unsafe extern "system" fn destroy_command_pool(
    device: vk::Device,
    pool: vk::CommandPool,
    allocator: *const vk::AllocationCallbacks<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        if let Ok(mut c) = s.commands.lock() {
            let of_pool: Vec<_> = c
                .buffers
                .iter()
                .filter(|(_, st)| st.pool == pool)
                .map(|(&cb, _)| cb)
                .collect();
            for cb in of_pool {
                if let Some(st) = c.buffers.remove(&cb) {
                    complete(st.work);
                }
            }
        }
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().destroy_command_pool)(device, pool, allocator) };
    })
}

unsafe extern "system" fn cmd_bind_pipeline(
    cb: vk::CommandBuffer,
    point: vk::PipelineBindPoint,
    pipeline: vk::Pipeline,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        if point == vk::PipelineBindPoint::COMPUTE {
            if let Ok(mut c) = s.commands.lock() {
                c.buffers.entry(cb).or_default().compute.pipeline = Some(pipeline);
            }
        }
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().cmd_bind_pipeline)(cb, point, pipeline) };
    })
}

#[allow(clippy::too_many_arguments)]
unsafe extern "system" fn cmd_bind_descriptor_sets(
    cb: vk::CommandBuffer,
    point: vk::PipelineBindPoint,
    layout: vk::PipelineLayout,
    first: u32,
    count: u32,
    sets: *const vk::DescriptorSet,
    offsets_count: u32,
    offsets: *const u32,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        if point == vk::PipelineBindPoint::COMPUTE {
            // SAFETY: the application's arrays of their counts.
            let (sets_v, offsets_v) = unsafe {
                (
                    slice(sets, count).to_vec(),
                    slice(offsets, offsets_count).to_vec(),
                )
            };
            if let Ok(mut c) = s.commands.lock() {
                let binds = &mut c.buffers.entry(cb).or_default().compute.sets;
                // A bind that covers an earlier one's sets replaces it.
                let end = first + count;
                binds.retain(|(_, f, s, _)| !(first <= *f && *f + s.len() as u32 <= end));
                binds.push((layout, first, sets_v, offsets_v));
            }
        }
        // SAFETY: the application's call, passed on.
        unsafe {
            (s.fns.fp_v1_0().cmd_bind_descriptor_sets)(
                cb,
                point,
                layout,
                first,
                count,
                sets,
                offsets_count,
                offsets,
            )
        };
    })
}

/// # Safety
/// `p` is null with `n` 0, or holds `n` elements.
pub(crate) unsafe fn slice<'a, T>(p: *const T, n: u32) -> &'a [T] {
    match n {
        0 => &[],
        // SAFETY: the caller's contract.
        n => unsafe { std::slice::from_raw_parts(p, n as usize) },
    }
}

unsafe extern "system" fn cmd_push_constants(
    cb: vk::CommandBuffer,
    layout: vk::PipelineLayout,
    stages: vk::ShaderStageFlags,
    offset: u32,
    size: u32,
    values: *const std::ffi::c_void,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        if stages.contains(vk::ShaderStageFlags::COMPUTE) {
            // SAFETY: the application's `size` bytes.
            let bytes = unsafe { slice(values.cast::<u8>(), size) };
            if let Ok(mut c) = s.commands.lock() {
                let push = &mut c.buffers.entry(cb).or_default().compute.push;
                // The same range pushed again replaces the earlier bytes (kept last).
                match push.iter().position(|(_, st, o, b)| {
                    *st == stages && *o == offset && b.len() == bytes.len()
                }) {
                    Some(k) if k + 1 == push.len() => {
                        let last = &mut push[k];
                        last.0 = layout;
                        last.3.copy_from_slice(bytes);
                    }
                    Some(k) => {
                        push.remove(k);
                        push.push((layout, stages, offset, bytes.to_vec()));
                    }
                    None => push.push((layout, stages, offset, bytes.to_vec())),
                }
            }
        }
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().cmd_push_constants)(cb, layout, stages, offset, size, values) };
    })
}
