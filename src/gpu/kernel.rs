//! Compute kernels: a pipeline made from an embedded [`ShaderBlob`], its descriptor-set
//! layout (storage buffers only) and a pipeline layout with one push-constant range.
//!
//! Kernels are cached per context by (blob, specialization), so asking for the same kernel
//! twice compiles it once; lavapipe JIT-compiles every pipeline with LLVM.

use std::sync::Arc;

use ash::vk;

use super::context::Context;
use super::error::{vk_err, GpuError, Result};
use super::pipeline::{PipelineDesc, PipelineFailure};
use super::shader::ShaderBlob;

/// Push-constant bytes every kernel layout reserves: the minimum every device supports.
pub const PUSH_CONSTANT_BYTES: u32 = 128;

/// Specialization constants for one kernel instance.
#[derive(Clone, Debug, Default, PartialEq, Eq, Hash)]
pub struct Spec {
    values: Vec<(u32, u32)>,
    workgroup: Option<[u32; 3]>,
}

impl Spec {
    /// No constants set: the kernel's defaults and declared workgroup size.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the workgroup size (the kernel must declare `local_size_x_id` etc.).
    pub fn workgroup(mut self, x: u32) -> Self {
        self.workgroup = Some([x, 1, 1]);
        self
    }

    /// Sets `layout(constant_id = id) const uint/int/bool`.
    pub fn u32(mut self, id: u32, value: u32) -> Self {
        self.values.retain(|(i, _)| *i != id);
        self.values.push((id, value));
        self.values.sort_unstable();
        self
    }

    /// Without the constants `blob` does not declare: for a variant compiled without some
    /// of its family's (the `query` variants of the tracing kernels walk no vkrt structure,
    /// so they have no stack size and no walk). Elsewhere an unknown id stays an error.
    pub fn declared_in(mut self, blob: &ShaderBlob) -> Self {
        self.values
            .retain(|(id, _)| blob.spec_constants.iter().any(|(i, _)| i == id));
        self
    }

    /// Sets `layout(constant_id = id) const float`.
    pub fn f32(self, id: u32, value: f32) -> Self {
        self.u32(id, value.to_bits())
    }
}

#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct KernelKey {
    name: &'static str,
    spec: Spec,
}

/// A compute pipeline ready to dispatch.
#[derive(Debug)]
pub struct Kernel {
    pub(crate) blob: &'static ShaderBlob,
    pub(crate) pipeline: vk::Pipeline,
    pub(crate) layout: vk::PipelineLayout,
    pub(crate) set_layout: vk::DescriptorSetLayout,
    /// Whether its buffers are pushed into the command buffer (`VK_KHR_push_descriptor`,
    /// for a kernel without texel bindings) rather than bound as a descriptor set.
    pub(crate) pushed: bool,
    /// The context it was made on ([`Context`]'s id): its pipeline is that device's.
    pub(crate) context: u64,
    /// The workgroup size after specialization.
    pub workgroup_size: [u32; 3],
}

impl Kernel {
    /// The name of the blob it was made from ([`ShaderBlob::name`]).
    pub fn name(&self) -> &'static str {
        self.blob.name
    }

    /// Invocations per workgroup.
    pub fn invocations(&self) -> u32 {
        self.workgroup_size.iter().product()
    }

    /// # Safety
    /// No command buffer using this kernel is pending, and `device` created it.
    pub(crate) unsafe fn destroy(&self, device: &ash::Device) {
        // SAFETY: guaranteed by the caller.
        unsafe {
            device.destroy_pipeline(self.pipeline, None);
            device.destroy_pipeline_layout(self.layout, None);
            device.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

impl Context {
    /// The kernel for `blob` specialised by `spec`, compiled on first use.
    pub fn kernel(&self, blob: &'static ShaderBlob, spec: &Spec) -> Result<Arc<Kernel>> {
        let key = KernelKey {
            name: blob.name,
            spec: spec.clone(),
        };
        if let Some(k) = super::error::lock(&self.inner.kernels).get(&key) {
            return Ok(k.clone());
        }
        let kernel = Arc::new(self.create_kernel(blob, spec)?);
        let mut cache = super::error::lock(&self.inner.kernels);
        match cache.get(&key) {
            // Another thread won the race: keep its kernel and destroy ours.
            Some(k) => {
                // SAFETY: ours was never used in a command buffer.
                unsafe { kernel.destroy(&self.inner.device) };
                Ok(k.clone())
            }
            None => {
                cache.insert(key, kernel.clone());
                Ok(kernel)
            }
        }
    }

    fn create_kernel(&self, blob: &'static ShaderBlob, spec: &Spec) -> Result<Kernel> {
        let err = |reason: String| GpuError::Kernel {
            kernel: blob.name,
            reason,
        };
        let mut entries: Vec<(u32, u32)> = spec.values.clone();
        let mut workgroup_size = blob.local_size;
        if let Some(wg) = spec.workgroup {
            for axis in 0..3 {
                match blob.local_size_spec_ids[axis] {
                    Some(id) => {
                        entries.retain(|(i, _)| *i != id);
                        entries.push((id, wg[axis]));
                        workgroup_size[axis] = wg[axis];
                    }
                    None if wg[axis] != blob.local_size[axis] => {
                        return Err(err(format!(
                            "workgroup size axis {axis} is fixed at {} in the source (use local_size_x_id)",
                            blob.local_size[axis]
                        )))
                    }
                    None => {}
                }
            }
        }
        for (id, _) in &entries {
            if !blob.spec_constants.iter().any(|(i, _)| i == id) {
                return Err(err(format!("has no specialization constant with id {id}")));
            }
        }
        let limits = &self.inner.info;
        let invocations: u32 = workgroup_size.iter().product();
        if invocations == 0
            || invocations > limits.max_workgroup_invocations
            || (0..3).any(|a| workgroup_size[a] > limits.max_workgroup_size[a])
        {
            return Err(err(format!(
                "workgroup size {workgroup_size:?} exceeds the device limits ({} invocations, {:?})",
                limits.max_workgroup_invocations, limits.max_workgroup_size
            )));
        }
        // A texel binding needs a view object, which a push would not spare; the extension
        // guarantees 32 pushed descriptors.
        let pushed = self.inner.push_descriptor.is_some()
            && blob.texel_bindings.is_empty()
            && blob.bindings.len() <= 32;
        let bindings: Vec<(u32, vk::DescriptorType)> = blob
            .bindings
            .iter()
            .map(|&b| (b, descriptor_type(blob, b)))
            .collect();
        let desc = PipelineDesc {
            name: blob.name,
            spirv: blob.spirv,
            bindings: &bindings,
            push_bytes: if blob.push_constants {
                PUSH_CONSTANT_BYTES
            } else {
                0
            },
            spec: &entries,
            flags: vk::PipelineCreateFlags::empty(),
            pushed,
        };
        match self.create_compute_pipeline(&desc) {
            Ok(p) => Ok(Kernel {
                blob,
                pipeline: p.pipeline,
                layout: p.layout,
                set_layout: p.set_layout,
                pushed,
                context: self.inner.id,
                workgroup_size,
            }),
            Err(PipelineFailure {
                call: "vkCreateComputePipelines",
                code,
            }) if !matches!(
                code,
                vk::Result::ERROR_OUT_OF_HOST_MEMORY | vk::Result::ERROR_OUT_OF_DEVICE_MEMORY
            ) =>
            {
                // The driver's compiler refused this kernel: say which, and how it was
                // specialised, so that the failure can be reproduced.
                Err(err(format!(
                    "vkCreateComputePipelines failed ({code:?}) for workgroup size \
                     {workgroup_size:?} and specialization {entries:?}"
                )))
            }
            Err(f) => Err(vk_err(f.call)(f.code)),
        }
    }
}

/// How binding `b` of `blob` is bound: a storage buffer, or a uniform texel buffer.
pub(crate) fn descriptor_type(blob: &ShaderBlob, b: u32) -> vk::DescriptorType {
    if blob.texel_bindings.contains(&b) {
        vk::DescriptorType::UNIFORM_TEXEL_BUFFER
    } else {
        vk::DescriptorType::STORAGE_BUFFER
    }
}
