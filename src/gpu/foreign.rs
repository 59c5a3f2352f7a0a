//! A compute pipeline from SPIR-V that vkrt did not compile (a renderer's own shader), with
//! the descriptor set layout, push-constant range and specialization its caller states,
//! and one descriptor set of its own: storage buffers, uniform texel buffers and the
//! driver's acceleration structures. `vkrt shader-check` runs a renderer's ray-query shader
//! with it.
//!
//! The pipeline is created with `DISPATCH_BASE`, so that a grid larger than
//! `maxComputeWorkGroupCount` runs as several dispatches whose `gl_GlobalInvocationID`
//! continue where the previous one stopped ([`ForeignKernel::record_dispatch`]).

use ash::vk;

use super::accel_ext::AccelerationStructure;
use super::buffer::{BufferArg, TexelView};
use super::context::Context;
use super::error::{vk_err, GpuError, Result};
use super::pipeline::PipelineDesc;
use super::recorder::Recorder;

/// What one binding of the set holds.
#[derive(Clone, Copy)]
pub enum ForeignBinding<'a> {
    /// A storage buffer's range.
    Storage(&'a dyn BufferArg),
    /// An RGBA32UI view (`usamplerBuffer` / `utextureBuffer`).
    Texel(&'a TexelView),
    /// The driver's (top-level) acceleration structure (`accelerationStructureEXT`).
    Accel(&'a AccelerationStructure),
}

impl ForeignBinding<'_> {
    fn descriptor_type(&self) -> vk::DescriptorType {
        match self {
            ForeignBinding::Storage(_) => vk::DescriptorType::STORAGE_BUFFER,
            ForeignBinding::Texel(_) => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
            ForeignBinding::Accel(_) => vk::DescriptorType::ACCELERATION_STRUCTURE_KHR,
        }
    }
}

/// A pipeline over foreign SPIR-V, its layouts and its one descriptor set (bindings
/// `0..n` of set 0). Keep it until the work that dispatches it has executed.
pub struct ForeignKernel {
    ctx: crate::gpu::teardown::Held,
    pipeline: vk::Pipeline,
    layout: vk::PipelineLayout,
    set_layout: vk::DescriptorSetLayout,
    pool: vk::DescriptorPool,
    set: vk::DescriptorSet,
    /// The binding types, in binding order, the set was made for.
    types: Vec<vk::DescriptorType>,
    push_bytes: u32,
}

impl ForeignKernel {
    /// The pipeline of `spirv`'s `main` compute entry point, over set 0 with `bindings`
    /// (binding `k` is `bindings[k]`'s type), a push-constant range of `push_bytes` (a
    /// multiple of 4; 0: none) and the specialization constants `spec` (id, 32-bit value).
    /// A driver that refuses the module or pipeline is an error naming `name`.
    pub fn new(
        ctx: &Context,
        name: &str,
        spirv: &[u32],
        bindings: &[ForeignBinding<'_>],
        push_bytes: u32,
        spec: &[(u32, u32)],
    ) -> Result<Self> {
        let types: Vec<vk::DescriptorType> = bindings
            .iter()
            .map(ForeignBinding::descriptor_type)
            .collect();
        if push_bytes % 4 != 0 || push_bytes > ctx.info().max_push_constants_size {
            return Err(GpuError::Usage {
                call: "ForeignKernel::new",
                reason: format!(
                    "{push_bytes} push-constant bytes (a multiple of 4, at most the device's {})",
                    ctx.info().max_push_constants_size
                ),
            });
        }
        let kernel_err = |reason: String| GpuError::Kernel {
            kernel: "foreign shader",
            reason: format!("{name}: {reason}"),
        };
        let mut pool_sizes: Vec<vk::DescriptorPoolSize> = Vec::new();
        for &t in &types {
            match pool_sizes.iter_mut().find(|s| s.ty == t) {
                Some(s) => s.descriptor_count += 1,
                None => pool_sizes.push(vk::DescriptorPoolSize {
                    ty: t,
                    descriptor_count: 1,
                }),
            }
        }
        let layout_bindings: Vec<(u32, vk::DescriptorType)> = types
            .iter()
            .enumerate()
            .map(|(k, &t)| (k as u32, t))
            .collect();
        let device = &ctx.inner.device;
        let mut out = Self {
            ctx: crate::gpu::teardown::Held::new(ctx, crate::gpu::teardown::Holder::ForeignKernel),
            pipeline: vk::Pipeline::null(),
            layout: vk::PipelineLayout::null(),
            set_layout: vk::DescriptorSetLayout::null(),
            pool: vk::DescriptorPool::null(),
            set: vk::DescriptorSet::null(),
            types,
            push_bytes,
        };
        let desc = PipelineDesc {
            name,
            spirv,
            bindings: &layout_bindings,
            push_bytes,
            spec,
            flags: vk::PipelineCreateFlags::DISPATCH_BASE,
            pushed: false,
        };
        let made =
            ctx.create_compute_pipeline(&desc)
                .map_err(|f| match f.code {
                    vk::Result::ERROR_OUT_OF_HOST_MEMORY
                    | vk::Result::ERROR_OUT_OF_DEVICE_MEMORY => vk_err(f.call)(f.code),
                    code => kernel_err(format!("{} failed ({code:?})", f.call)),
                })?;
        out.set_layout = made.set_layout;
        out.layout = made.layout;
        out.pipeline = made.pipeline;
        let set_layouts = [out.set_layout];
        // SAFETY: valid device; the create-infos point at locals that outlive the calls;
        // each object is stored in `out` as soon as it exists, so that `Drop` destroys what
        // was made when a later call fails (null handles are skipped).
        unsafe {
            if !pool_sizes.is_empty() {
                out.pool = device
                    .create_descriptor_pool(
                        &vk::DescriptorPoolCreateInfo::default()
                            .max_sets(1)
                            .pool_sizes(&pool_sizes),
                        None,
                    )
                    .map_err(vk_err("vkCreateDescriptorPool"))?;
                out.set = device
                    .allocate_descriptor_sets(
                        &vk::DescriptorSetAllocateInfo::default()
                            .descriptor_pool(out.pool)
                            .set_layouts(&set_layouts),
                    )
                    .map_err(vk_err("vkAllocateDescriptorSets"))?[0];
            }
        }
        out.write(bindings)?;
        Ok(out)
    }

    /// Writes `bindings` (the types the kernel was made with) into its set.
    fn write(&self, bindings: &[ForeignBinding<'_>]) -> Result<()> {
        if bindings.len() != self.types.len()
            || bindings
                .iter()
                .zip(&self.types)
                .any(|(b, &t)| b.descriptor_type() != t)
        {
            return Err(GpuError::Usage {
                call: "ForeignKernel::write",
                reason: "the bindings differ from those the kernel was made for".into(),
            });
        }
        let buffer_infos: Vec<[vk::DescriptorBufferInfo; 1]> = bindings
            .iter()
            .map(|b| match b {
                ForeignBinding::Storage(b) => [vk::DescriptorBufferInfo {
                    buffer: b.raw(),
                    offset: b.offset(),
                    range: b.range(),
                }],
                _ => [vk::DescriptorBufferInfo::default()],
            })
            .collect();
        let views: Vec<[vk::BufferView; 1]> = bindings
            .iter()
            .map(|b| match b {
                ForeignBinding::Texel(v) => [v.raw()],
                _ => [vk::BufferView::null()],
            })
            .collect();
        let accels: Vec<[vk::AccelerationStructureKHR; 1]> = bindings
            .iter()
            .map(|b| match b {
                ForeignBinding::Accel(a) => [a.raw()],
                _ => [vk::AccelerationStructureKHR::null()],
            })
            .collect();
        let mut accel_writes: Vec<vk::WriteDescriptorSetAccelerationStructureKHR> = accels
            .iter()
            .map(|a| {
                vk::WriteDescriptorSetAccelerationStructureKHR::default().acceleration_structures(a)
            })
            .collect();
        let mut writes = Vec::with_capacity(bindings.len());
        for (k, (b, accel)) in bindings.iter().zip(accel_writes.iter_mut()).enumerate() {
            let w = vk::WriteDescriptorSet::default()
                .dst_set(self.set)
                .dst_binding(k as u32)
                .descriptor_type(b.descriptor_type());
            writes.push(match b {
                ForeignBinding::Storage(_) => w.buffer_info(&buffer_infos[k]),
                ForeignBinding::Texel(_) => w.texel_buffer_view(&views[k]),
                // The count of an acceleration-structure write comes from its chained
                // struct.
                ForeignBinding::Accel(_) => {
                    let mut w = w.push_next(accel);
                    w.descriptor_count = 1;
                    w
                }
            });
        }
        // SAFETY: the set was allocated for this layout, with these types (checked above),
        // and no recorded work uses it yet (it is written once, when the kernel is made);
        // the infos, views and chained structs outlive the call.
        unsafe { self.ctx.inner.device.update_descriptor_sets(&writes, &[]) };
        Ok(())
    }

    /// Records dispatches of `groups` one-dimensional workgroups (split where they exceed
    /// `maxComputeWorkGroupCount[0]`, each piece starting at its base so that
    /// `gl_WorkGroupID.x` runs on) with `push` (its range's bytes, or fewer) bound.
    pub fn record_dispatch(&self, rec: &mut Recorder, groups: u64, push: &[u8]) -> Result<()> {
        self.record_dispatch_grid(rec, [groups, 1], push)
    }

    /// [`Self::record_dispatch`] over a two-dimensional grid of workgroups: `groups[0]` in
    /// x (split as there), `groups[1]` in y (at most the device's `maxComputeWorkGroupCount`
    /// in y).
    pub fn record_dispatch_grid(
        &self,
        rec: &mut Recorder,
        groups: [u64; 2],
        push: &[u8],
    ) -> Result<()> {
        let [groups, rows] = groups;
        if rows > u64::from(self.ctx.info().max_workgroup_count[1]) {
            return Err(GpuError::Usage {
                call: "ForeignKernel::record_dispatch_grid",
                reason: format!(
                    "{rows} workgroups in y: more than the device's {}",
                    self.ctx.info().max_workgroup_count[1]
                ),
            });
        }
        if push.len() > self.push_bytes as usize {
            return Err(GpuError::Usage {
                call: "ForeignKernel::record_dispatch",
                reason: format!(
                    "{} push-constant bytes for a range of {}",
                    push.len(),
                    self.push_bytes
                ),
            });
        }
        let max = u64::from(self.ctx.info().max_workgroup_count[0]);
        if groups > u64::from(u32::MAX) {
            return Err(GpuError::Usage {
                call: "ForeignKernel::record_dispatch",
                reason: format!("{groups} workgroups: more than a base offset can name"),
            });
        }
        let device = &self.ctx.inner.device;
        let cmd = rec.command_buffer();
        // SAFETY: the command buffer is recording; the pipeline, layout and set belong to
        // this kernel and live until its work has executed (the caller's contract); `push`
        // fits the range (checked); the bases and counts stay within u32 and the device's
        // workgroup counts (checked), and the pipeline was made with DISPATCH_BASE.
        unsafe {
            device.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::COMPUTE, self.pipeline);
            if self.set != vk::DescriptorSet::null() {
                device.cmd_bind_descriptor_sets(
                    cmd,
                    vk::PipelineBindPoint::COMPUTE,
                    self.layout,
                    0,
                    &[self.set],
                    &[],
                );
            }
            if !push.is_empty() {
                device.cmd_push_constants(cmd, self.layout, vk::ShaderStageFlags::COMPUTE, 0, push);
            }
            let mut base = 0u64;
            while base < groups {
                let count = (groups - base).min(max);
                device.cmd_dispatch_base(cmd, base as u32, 0, 0, count as u32, rows as u32, 1);
                base += count;
            }
        }
        Ok(())
    }
}

impl Drop for ForeignKernel {
    fn drop(&mut self) {
        let device = &self.ctx.inner.device;
        // SAFETY: the objects were made on this device, null ones are skipped, and the
        // owner keeps the kernel until the work that used it has executed (the type's
        // contract); destroying the pool frees its set.
        unsafe {
            if self.pool != vk::DescriptorPool::null() {
                device.destroy_descriptor_pool(self.pool, None);
            }
            if self.pipeline != vk::Pipeline::null() {
                device.destroy_pipeline(self.pipeline, None);
            }
            if self.layout != vk::PipelineLayout::null() {
                device.destroy_pipeline_layout(self.layout, None);
            }
            if self.set_layout != vk::DescriptorSetLayout::null() {
                device.destroy_descriptor_set_layout(self.set_layout, None);
            }
        }
    }
}
