//! Shader modules: every module with ray queries goes through vkrt's SPIR-V pass, which
//! rewrites them into calls of vkrt's walk (`vkrt::spirv::lower_ray_queries`) — made with
//! vkCreateShaderModule, or given inline to a pipeline (a `VkShaderModuleCreateInfo` chained
//! to a stage without a module, as maintenance5 and pipeline libraries allow).

use ash::vk;

use crate::device::served;
use crate::{guard, log, pfn};

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkCreateShaderModule" => pfn!(create_shader_module, vk::PFN_vkCreateShaderModule),
        b"vkCreateComputePipelines" => {
            pfn!(create_compute_pipelines, vk::PFN_vkCreateComputePipelines)
        }
        b"vkCreateGraphicsPipelines" => {
            pfn!(create_graphics_pipelines, vk::PFN_vkCreateGraphicsPipelines)
        }
        _ => None,
    }
}

unsafe extern "system" fn create_shader_module(
    device: vk::Device,
    info: *const vk::ShaderModuleCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::ShaderModule,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info and its code.
        let mut ours = unsafe { *info };
        // SAFETY: as above: codeSize bytes, 4-aligned.
        let words = unsafe { std::slice::from_raw_parts(ours.p_code, ours.code_size / 4) };
        let options = vkrt::spirv::LowerOptions::for_device(s.ctx.info());
        let lowered = match vkrt::spirv::lower_ray_queries(words, &options) {
            Ok(l) => l,
            Err(e) => {
                log(&format!(
                    "vkCreateShaderModule: the module's ray queries cannot be lowered: {e}"
                ));
                return vk::Result::ERROR_INVALID_SHADER_NV;
            }
        };
        if lowered.changed {
            ours.code_size = lowered.words.len() * 4;
            ours.p_code = lowered.words.as_ptr();
        }
        // SAFETY: the application's arguments, its code lowered.
        unsafe { (s.fns.fp_v1_0().create_shader_module)(device, &ours, allocator, out) }
    })
}

/// Stages' inline modules, lowered; their code pointers put back when dropped.
struct Inline {
    edits: Vec<(*mut vk::ShaderModuleCreateInfo<'static>, usize, *const u32)>,
    _code: Vec<Vec<u32>>,
}

impl Drop for Inline {
    fn drop(&mut self) {
        for &(info, size, code) in &self.edits {
            // SAFETY: the application's struct, alive for the call that edited it.
            unsafe {
                (*info).code_size = size;
                (*info).p_code = code;
            }
        }
    }
}

/// Lowers every inline module of `stages`.
///
/// # Safety
/// The stages and their chains are valid and outlive the result.
unsafe fn lower_inline(
    stages: &[vk::PipelineShaderStageCreateInfo<'_>],
    options: &vkrt::spirv::LowerOptions,
) -> Result<Inline, String> {
    let mut inline = Inline {
        edits: Vec::new(),
        _code: Vec::new(),
    };
    for stage in stages {
        if stage.module != vk::ShaderModule::null() {
            continue;
        }
        let mut next = stage.p_next as *mut vk::BaseOutStructure<'static>;
        // SAFETY: a valid chain.
        while let Some(n) = unsafe { next.as_mut() } {
            if n.s_type == vk::StructureType::SHADER_MODULE_CREATE_INFO {
                let info = next.cast::<vk::ShaderModuleCreateInfo<'static>>();
                // SAFETY: the sType says which struct it is; its code is codeSize bytes.
                let (size, code) = unsafe { ((*info).code_size, (*info).p_code) };
                // SAFETY: as above.
                let words = unsafe { std::slice::from_raw_parts(code, size / 4) };
                let lowered =
                    vkrt::spirv::lower_ray_queries(words, options).map_err(|e| e.to_string())?;
                if lowered.changed {
                    inline.edits.push((info, size, code));
                    // SAFETY: as above; put back by Drop.
                    unsafe {
                        (*info).code_size = lowered.words.len() * 4;
                        (*info).p_code = lowered.words.as_ptr();
                    }
                    inline._code.push(lowered.words);
                }
            }
            next = n.p_next;
        }
    }
    Ok(inline)
}

unsafe extern "system" fn create_compute_pipelines(
    device: vk::Device,
    cache: vk::PipelineCache,
    count: u32,
    infos: *const vk::ComputePipelineCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::Pipeline,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's `count` infos.
        let stages: Vec<vk::PipelineShaderStageCreateInfo<'_>> =
            unsafe { crate::commands::slice(infos, count) }
                .iter()
                .map(|i| i.stage)
                .collect();
        // SAFETY: the application's stages, alive for this call.
        let _inline = match unsafe {
            lower_inline(
                &stages,
                &vkrt::spirv::LowerOptions::for_device(s.ctx.info()),
            )
        } {
            Ok(i) => i,
            Err(e) => {
                log(&format!("vkCreateComputePipelines: an inline module's ray queries cannot be lowered: {e}"));
                return vk::Result::ERROR_INVALID_SHADER_NV;
            }
        };
        // SAFETY: the application's call, its inline modules lowered.
        unsafe {
            (s.fns.fp_v1_0().create_compute_pipelines)(device, cache, count, infos, allocator, out)
        }
    })
}

unsafe extern "system" fn create_graphics_pipelines(
    device: vk::Device,
    cache: vk::PipelineCache,
    count: u32,
    infos: *const vk::GraphicsPipelineCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::Pipeline,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's `count` infos and their stages.
        let stages: Vec<vk::PipelineShaderStageCreateInfo<'_>> =
            unsafe { crate::commands::slice(infos, count) }
                .iter()
                .flat_map(|i| unsafe { crate::commands::slice(i.p_stages, i.stage_count) })
                .copied()
                .collect();
        // SAFETY: the application's stages, alive for this call.
        let _inline = match unsafe {
            lower_inline(
                &stages,
                &vkrt::spirv::LowerOptions::for_device(s.ctx.info()),
            )
        } {
            Ok(i) => i,
            Err(e) => {
                log(&format!("vkCreateGraphicsPipelines: an inline module's ray queries cannot be lowered: {e}"));
                return vk::Result::ERROR_INVALID_SHADER_NV;
            }
        };
        // SAFETY: the application's call, its inline modules lowered.
        unsafe {
            (s.fns.fp_v1_0().create_graphics_pipelines)(device, cache, count, infos, allocator, out)
        }
    })
}
