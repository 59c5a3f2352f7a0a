//! Graphics-pipeline plumbing for the tests that draw (a renderer's fragment shaders):
//! kept apart from `common` because the command line's tests, which share `common`, do not
//! depend on ash.

/// A graphics pipeline that draws one full-screen triangle (`vert` makes it from
/// `gl_VertexIndex`) over a `size`² viewport with `frag`, its fragment stage specialized by
/// `spec`, into subpass 0 of `render_pass`, whose one colour attachment takes `write_mask`.
/// The shader modules are made and destroyed here.
///
/// # Safety
/// `device` is live, `layout` and `render_pass` are its, and `vert` and `frag` are valid
/// SPIR-V for `layout`.
#[allow(clippy::too_many_arguments, reason = "a pipeline's few choices, named")]
pub unsafe fn fullscreen_pipeline(
    device: &ash::Device,
    vert: &[u32],
    frag: &[u32],
    spec: &vkrt::gpu::vk::SpecializationInfo<'_>,
    layout: vkrt::gpu::vk::PipelineLayout,
    render_pass: vkrt::gpu::vk::RenderPass,
    size: u32,
    write_mask: vkrt::gpu::vk::ColorComponentFlags,
) -> vkrt::gpu::vk::Pipeline {
    use vkrt::gpu::vk;
    // SAFETY: the caller's contract; every create-info points at locals that outlive the
    // calls, and the modules are destroyed after the pipeline holds what it needs.
    unsafe {
        let module = |code: &[u32]| {
            device
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(code), None)
                .unwrap()
        };
        let (vert, frag) = (module(vert), module(frag));
        let stages = [
            vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::VERTEX)
                .module(vert)
                .name(c"main"),
            vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::FRAGMENT)
                .module(frag)
                .name(c"main")
                .specialization_info(spec),
        ];
        let viewports = [vk::Viewport {
            x: 0.0,
            y: 0.0,
            width: size as f32,
            height: size as f32,
            min_depth: 0.0,
            max_depth: 1.0,
        }];
        let scissors = [vk::Rect2D {
            offset: vk::Offset2D::default(),
            extent: vk::Extent2D {
                width: size,
                height: size,
            },
        }];
        let vertex_input = vk::PipelineVertexInputStateCreateInfo::default();
        let assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
            .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
        let viewport = vk::PipelineViewportStateCreateInfo::default()
            .viewports(&viewports)
            .scissors(&scissors);
        let raster = vk::PipelineRasterizationStateCreateInfo::default()
            .polygon_mode(vk::PolygonMode::FILL)
            .cull_mode(vk::CullModeFlags::NONE)
            .line_width(1.0);
        let multisample = vk::PipelineMultisampleStateCreateInfo::default()
            .rasterization_samples(vk::SampleCountFlags::TYPE_1);
        let blend_attachment =
            [vk::PipelineColorBlendAttachmentState::default().color_write_mask(write_mask)];
        let blend = vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend_attachment);
        let create = [vk::GraphicsPipelineCreateInfo::default()
            .stages(&stages)
            .vertex_input_state(&vertex_input)
            .input_assembly_state(&assembly)
            .viewport_state(&viewport)
            .rasterization_state(&raster)
            .multisample_state(&multisample)
            .color_blend_state(&blend)
            .layout(layout)
            .render_pass(render_pass)
            .subpass(0)];
        let pipeline = device
            .create_graphics_pipelines(vk::PipelineCache::null(), &create, None)
            .map_err(|(_, e)| e)
            .unwrap()[0];
        device.destroy_shader_module(vert, None);
        device.destroy_shader_module(frag, None);
        pipeline
    }
}
