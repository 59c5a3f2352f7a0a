//! A compute pipeline with its one set layout and pipeline layout: what vkrt's kernels
//! ([`Kernel`](super::Kernel)) and a renderer's own shaders
//! ([`ForeignKernel`](super::ForeignKernel)) are made of. Each caller keeps its own policy
//! (its descriptors, its error wording); the creation, the clean-up on failure, the object
//! count and the debug names are here once.

use ash::vk;

use super::context::Context;

/// What a compute pipeline is made from.
pub(crate) struct PipelineDesc<'a> {
    /// The name its objects carry in debuggers (`.layout`, `.set_layout` appended).
    pub name: &'a str,
    pub spirv: &'a [u32],
    /// Binding number and descriptor type of each binding of set 0, compute stage only.
    pub bindings: &'a [(u32, vk::DescriptorType)],
    /// Push-constant bytes (0: none).
    pub push_bytes: u32,
    /// Specialization constants: `(constant id, 32-bit value)`.
    pub spec: &'a [(u32, u32)],
    pub flags: vk::PipelineCreateFlags,
    /// Whether set 0 is pushed (`VK_KHR_push_descriptor`) rather than bound.
    pub pushed: bool,
}

/// The three objects of a compute pipeline; the owner destroys them.
pub(crate) struct ComputePipeline {
    pub set_layout: vk::DescriptorSetLayout,
    pub layout: vk::PipelineLayout,
    pub pipeline: vk::Pipeline,
}

/// The Vulkan call that failed while making a pipeline, and its result.
pub(crate) struct PipelineFailure {
    pub call: &'static str,
    pub code: vk::Result,
}

impl Context {
    /// Makes a compute pipeline from `desc`; on failure nothing is left behind.
    pub(crate) fn create_compute_pipeline(
        &self,
        desc: &PipelineDesc<'_>,
    ) -> Result<ComputePipeline, PipelineFailure> {
        let bindings: Vec<vk::DescriptorSetLayoutBinding> = desc
            .bindings
            .iter()
            .map(|&(b, ty)| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b)
                    .descriptor_type(ty)
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let push = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .size(desc.push_bytes)];
        let push_ranges: &[vk::PushConstantRange] = if desc.push_bytes > 0 { &push } else { &[] };
        let map: Vec<vk::SpecializationMapEntry> = desc
            .spec
            .iter()
            .enumerate()
            .map(|(i, (id, _))| vk::SpecializationMapEntry {
                constant_id: *id,
                offset: 4 * i as u32,
                size: 4,
            })
            .collect();
        let data: Vec<u8> = desc
            .spec
            .iter()
            .flat_map(|(_, v)| v.to_ne_bytes())
            .collect();
        let specialization = vk::SpecializationInfo::default()
            .map_entries(&map)
            .data(&data);
        let fail = |call| move |code| PipelineFailure { call, code };
        let device = &self.inner.device;
        // SAFETY: valid device; every create-info points at locals that outlive the calls;
        // on failure every object created so far is destroyed before returning. The module
        // is destroyed right after pipeline creation, which Vulkan allows.
        unsafe {
            let set_flags = match desc.pushed {
                true => vk::DescriptorSetLayoutCreateFlags::PUSH_DESCRIPTOR_KHR,
                false => vk::DescriptorSetLayoutCreateFlags::empty(),
            };
            let set_layout = device
                .create_descriptor_set_layout(
                    &vk::DescriptorSetLayoutCreateInfo::default()
                        .flags(set_flags)
                        .bindings(&bindings),
                    None,
                )
                .map_err(fail("vkCreateDescriptorSetLayout"))?;
            let set_layouts = [set_layout];
            let layout = match device.create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default()
                    .set_layouts(&set_layouts)
                    .push_constant_ranges(push_ranges),
                None,
            ) {
                Ok(l) => l,
                Err(e) => {
                    device.destroy_descriptor_set_layout(set_layout, None);
                    return Err(fail("vkCreatePipelineLayout")(e));
                }
            };
            let module = match device.create_shader_module(
                &vk::ShaderModuleCreateInfo::default().code(desc.spirv),
                None,
            ) {
                Ok(m) => m,
                Err(e) => {
                    device.destroy_pipeline_layout(layout, None);
                    device.destroy_descriptor_set_layout(set_layout, None);
                    return Err(fail("vkCreateShaderModule")(e));
                }
            };
            let stage = vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::COMPUTE)
                .module(module)
                .name(c"main")
                .specialization_info(&specialization);
            let create = [vk::ComputePipelineCreateInfo::default()
                .flags(desc.flags)
                .stage(stage)
                .layout(layout)];
            let result = device.create_compute_pipelines(self.inner.pipeline_cache, &create, None);
            device.destroy_shader_module(module, None);
            // The set layout, pipeline layout and shader module, and the pipeline.
            self.inner.created(3 + result.is_ok() as u64);
            match result {
                Ok(p) => {
                    // Named for RenderDoc, Nsight and RGP, and in validation messages.
                    self.set_object_name(p[0], desc.name);
                    self.set_object_name(layout, &format!("{}.layout", desc.name));
                    self.set_object_name(set_layout, &format!("{}.set_layout", desc.name));
                    Ok(ComputePipeline {
                        set_layout,
                        layout,
                        pipeline: p[0],
                    })
                }
                Err((_, e)) => {
                    device.destroy_pipeline_layout(layout, None);
                    device.destroy_descriptor_set_layout(set_layout, None);
                    Err(fail("vkCreateComputePipelines")(e))
                }
            }
        }
    }
}
