//! Shader modules: every module with ray queries goes through vkrt's SPIR-V pass, which
//! rewrites them into calls of vkrt's walk (`vkrt::spirv::lower_ray_queries`).

use ash::vk;

use crate::device::served;
use crate::{guard, log, pfn};

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkCreateShaderModule" => pfn!(create_shader_module, vk::PFN_vkCreateShaderModule),
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
        let lowered = match vkrt::spirv::lower_ray_queries(words, &Default::default()) {
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
