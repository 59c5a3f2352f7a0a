//! A draw whose fragment shader traces with ray queries — an alpha-tested candidate loop,
//! generated spheres and a shadow ray — as a renderer writes it for `GL_EXT_ray_query`:
//! compiled with vkrt's include, compiled for the driver and lowered by the SPIR-V pass, and
//! (where the device has ray query) run by the driver itself. Every pixel's record is the
//! same through the include and the pass on every driver, and the driver's where it has ray
//! query (`shader_check::records_agree`).

mod common;
#[path = "common/graphics.rs"]
mod graphics;

use std::path::Path;

use vkrt::accel::device::{AccelChoice, AccelKind};
use vkrt::accel::walk::Traversal;
use vkrt::gpu::{vk, Buffer, Context, Recorder, TexelView};
use vkrt::scene::Scene;
use vkrt::shader_check::{mismatches, scene_levels};

const SQUARE_OBJ: &str = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n";

/// Two squares (the first not opaque, so its triangles come to the shader), the second
/// behind and above it, and two spheres as procedural boxes.
const SCENE: &str = r#"
[[meshes]]
path = "square.obj"
opaque = false

[[meshes]]
path = "square.obj"
translate = [0, 3, -1]

[[spheres]]
center = [-2, 0, 0]
radius = 0.5

[[spheres]]
center = [2, 0.5, -1]
radius = 0.75
"#;

const VERT: &str = r#"#version 460
void main() {
    vec2 p = vec2((gl_VertexIndex << 1) & 2, gl_VertexIndex & 2);
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"#;

/// Per pixel: a ray straight down -z; of the first square only primitive 0 is kept (the
/// alpha test), spheres are intersected and generated; then a shadow ray towards a light.
/// The record: (t bits, instance id, primitive index, committed type | shadowed << 4).
const FRAG: &str = r#"#version 460
#extension GL_EXT_ray_query : require
#include "vkrt/ext_ray_query.glsl"
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(location = 0) out uvec4 result;
layout(push_constant) uniform P { uint size; };

const vec4 SPHERES[2] = vec4[2](vec4(-2.0, 0.0, 0.0, 0.5), vec4(2.0, 0.5, -1.0, 0.75));

bool sphereHit(rayQueryEXT q, float tMin, float tMax, out float t) {
    vec4 s = SPHERES[rayQueryGetIntersectionPrimitiveIndexEXT(q, false)];
    vec3 oc = rayQueryGetIntersectionObjectRayOriginEXT(q, false) - s.xyz;
    vec3 d = rayQueryGetIntersectionObjectRayDirectionEXT(q, false);
    float a = dot(d, d);
    float b = dot(oc, d);
    float c = dot(oc, oc) - s.w * s.w;
    float disc = b * b - a * c;
    t = (-b - sqrt(max(disc, 0.0))) / a;
    return disc >= 0.0 && t >= tMin && t <= tMax;
}

void main() {
    uvec2 p = uvec2(gl_FragCoord.xy);
    vec2 xy = (vec2(p) + 0.5) / float(size) * 6.0 - vec2(3.0, 1.5);
    vec3 o = vec3(xy, 5.0);
    vec3 d = vec3(0.0, 0.0, -1.0);
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsNoneEXT, 0xFF, o, 0.0, d, 100.0);
    while (rayQueryProceedEXT(q)) {
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionTriangleEXT) {
            // The alpha test: the first square's second triangle is cut out.
            if (rayQueryGetIntersectionPrimitiveIndexEXT(q, false) == 0) {
                rayQueryConfirmIntersectionEXT(q);
            }
        } else {
            float best = rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionNoneEXT
                ? 100.0 : rayQueryGetIntersectionTEXT(q, true);
            float t;
            if (sphereHit(q, 0.0, best, t)) {
                rayQueryGenerateIntersectionEXT(q, t);
            }
        }
    }
    uint kind = rayQueryGetIntersectionTypeEXT(q, true);
    uvec4 record = uvec4(0u, ~0u, ~0u, 0u);
    if (kind != gl_RayQueryCommittedIntersectionNoneEXT) {
        float t = rayQueryGetIntersectionTEXT(q, true);
        vec3 hit = o + t * d;
        vec3 toLight = vec3(-6.0, 0.0, 0.5) - hit;
        rayQueryEXT s;
        rayQueryInitializeEXT(s, scene, gl_RayFlagsTerminateOnFirstHitEXT | gl_RayFlagsOpaqueEXT,
                              0xFF, hit, 1e-3, normalize(toLight), length(toLight));
        while (rayQueryProceedEXT(s)) {
            float ts;
            if (sphereHit(s, 1e-3, length(toLight), ts)) {
                rayQueryGenerateIntersectionEXT(s, ts);
            }
        }
        uint shadowed = rayQueryGetIntersectionTypeEXT(s, true) != gl_RayQueryCommittedIntersectionNoneEXT ? 1u : 0u;
        record = uvec4(floatBitsToUint(t), rayQueryGetIntersectionInstanceIdEXT(q, true),
                       rayQueryGetIntersectionPrimitiveIndexEXT(q, true), kind | (shadowed << 4u));
    }
    result = record;
}
"#;

/// `source` compiled by glslc for `stage`, with vkrt's include directory; `native` defines
/// VKRT_NATIVE_RAY_QUERY (the include then empty: the driver's ray query).
fn glslc(source: &str, stage: &str, native: bool) -> Vec<u32> {
    let dir = std::env::temp_dir().join(format!(
        "vkrt-spirv-fragment-{}-{stage}-{native}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let (src, out) = (dir.join(format!("s.{stage}")), dir.join("s.spv"));
    std::fs::write(&src, source).unwrap();
    let mut cmd = std::process::Command::new(vkrt::shader_check::compile::compiler());
    cmd.arg("--target-env=vulkan1.2")
        .arg("-I")
        .arg(vkrt::accel::shader_library::include_dir());
    if native {
        cmd.arg("-DVKRT_NATIVE_RAY_QUERY=1");
    }
    let o = cmd.arg(&src).arg("-o").arg(&out).output().expect("glslc");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let words = bytemuck::pod_collect_to_vec::<u8, u32>(&std::fs::read(&out).unwrap());
    let _ = std::fs::remove_dir_all(&dir);
    words
}

/// The target's format: a record of four words a pixel.
const FORMAT: vk::Format = vk::Format::R32G32B32A32_UINT;

/// What binding 0 holds.
enum Structure<'a> {
    Texel(&'a TexelView),
    Accel(vk::AccelerationStructureKHR),
}

/// Draws one full-screen triangle of `frag` into a `size`² target of RGBA32UI records and
/// copies them into `results`, with the structure at binding 0; records into `rec` (after
/// what it holds) and returns the Vulkan objects to destroy once the work has run.
fn draw(
    ctx: &Context,
    rec: &mut Recorder,
    frag: &[u32],
    structure: Structure<'_>,
    results: &Buffer<[u32; 4]>,
    size: u32,
) -> Objects {
    let d = ctx.device().clone();
    let vert = glslc(VERT, "vert", false);
    let steps = ctx.info().max_traversal_steps;
    let cmd = rec.command_buffer();
    let structure_type = match structure {
        Structure::Texel(_) => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
        Structure::Accel(_) => vk::DescriptorType::ACCELERATION_STRUCTURE_KHR,
    };
    let stage = vk::ShaderStageFlags::FRAGMENT;
    // SAFETY: test code standing in for a renderer: plain Vulkan on the context's device,
    // every create-info pointing at locals that outlive the call, `cmd` recording outside
    // a render pass; the objects are destroyed after the submission completed.
    unsafe {
        let attachment = [vk::AttachmentDescription::default()
            .format(FORMAT)
            .samples(vk::SampleCountFlags::TYPE_1)
            .load_op(vk::AttachmentLoadOp::CLEAR)
            .store_op(vk::AttachmentStoreOp::STORE)
            .initial_layout(vk::ImageLayout::UNDEFINED)
            .final_layout(vk::ImageLayout::TRANSFER_SRC_OPTIMAL)];
        let colour = [vk::AttachmentReference::default()
            .attachment(0)
            .layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)];
        let subpass = [vk::SubpassDescription::default()
            .pipeline_bind_point(vk::PipelineBindPoint::GRAPHICS)
            .color_attachments(&colour)];
        // The target's writes (and its layout change) before the copy out.
        let dependencies = [
            vk::SubpassDependency::default()
                .src_subpass(vk::SUBPASS_EXTERNAL)
                .dst_subpass(0)
                .src_stage_mask(vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT)
                .dst_stage_mask(vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT)
                .dst_access_mask(vk::AccessFlags::COLOR_ATTACHMENT_WRITE),
            vk::SubpassDependency::default()
                .src_subpass(0)
                .dst_subpass(vk::SUBPASS_EXTERNAL)
                .src_stage_mask(vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT)
                .dst_stage_mask(vk::PipelineStageFlags::TRANSFER)
                .src_access_mask(vk::AccessFlags::COLOR_ATTACHMENT_WRITE)
                .dst_access_mask(vk::AccessFlags::TRANSFER_READ),
        ];
        let render_pass = d
            .create_render_pass(
                &vk::RenderPassCreateInfo::default()
                    .attachments(&attachment)
                    .subpasses(&subpass)
                    .dependencies(&dependencies),
                None,
            )
            .unwrap();
        let image = d
            .create_image(
                &vk::ImageCreateInfo::default()
                    .image_type(vk::ImageType::TYPE_2D)
                    .format(FORMAT)
                    .extent(vk::Extent3D {
                        width: size,
                        height: size,
                        depth: 1,
                    })
                    .mip_levels(1)
                    .array_layers(1)
                    .samples(vk::SampleCountFlags::TYPE_1)
                    .tiling(vk::ImageTiling::OPTIMAL)
                    .usage(
                        vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
                    )
                    .initial_layout(vk::ImageLayout::UNDEFINED),
                None,
            )
            .unwrap();
        // Any memory type the image allows will do for a test's target.
        let requirements = d.get_image_memory_requirements(image);
        let memory = d
            .allocate_memory(
                &vk::MemoryAllocateInfo::default()
                    .allocation_size(requirements.size)
                    .memory_type_index(requirements.memory_type_bits.trailing_zeros()),
                None,
            )
            .unwrap();
        d.bind_image_memory(image, memory, 0).unwrap();
        let range = vk::ImageSubresourceRange {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: 1,
        };
        let view = d
            .create_image_view(
                &vk::ImageViewCreateInfo::default()
                    .image(image)
                    .view_type(vk::ImageViewType::TYPE_2D)
                    .format(FORMAT)
                    .subresource_range(range),
                None,
            )
            .unwrap();
        let framebuffer = d
            .create_framebuffer(
                &vk::FramebufferCreateInfo::default()
                    .render_pass(render_pass)
                    .attachments(std::slice::from_ref(&view))
                    .width(size)
                    .height(size)
                    .layers(1),
                None,
            )
            .unwrap();
        let bindings = [vk::DescriptorSetLayoutBinding::default()
            .binding(0)
            .descriptor_type(structure_type)
            .descriptor_count(1)
            .stage_flags(stage)];
        let set_layout = d
            .create_descriptor_set_layout(
                &vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings),
                None,
            )
            .unwrap();
        let push = [vk::PushConstantRange::default().stage_flags(stage).size(4)];
        let layout = d
            .create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default()
                    .set_layouts(std::slice::from_ref(&set_layout))
                    .push_constant_ranges(&push),
                None,
            )
            .unwrap();
        let (entries, data) = vkrt::accel::shader_library::steps_specialization(steps);
        let spec = vk::SpecializationInfo::default()
            .map_entries(&entries)
            .data(&data);
        let pipeline = graphics::fullscreen_pipeline(
            &d,
            &vert,
            frag,
            &spec,
            layout,
            render_pass,
            size,
            vk::ColorComponentFlags::RGBA,
        );

        let sizes = [vk::DescriptorPoolSize {
            ty: structure_type,
            descriptor_count: 1,
        }];
        let pool = d
            .create_descriptor_pool(
                &vk::DescriptorPoolCreateInfo::default()
                    .max_sets(1)
                    .pool_sizes(&sizes),
                None,
            )
            .unwrap();
        let set = d
            .allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(pool)
                    .set_layouts(std::slice::from_ref(&set_layout)),
            )
            .unwrap()[0];
        let views;
        let accels;
        let mut accel_write;
        let mut first = vk::WriteDescriptorSet::default()
            .dst_set(set)
            .dst_binding(0)
            .descriptor_type(structure_type)
            .descriptor_count(1);
        match structure {
            Structure::Texel(view) => {
                views = [view.raw()];
                first = first.texel_buffer_view(&views);
            }
            Structure::Accel(raw) => {
                accels = [raw];
                accel_write = vk::WriteDescriptorSetAccelerationStructureKHR::default()
                    .acceleration_structures(&accels);
                first = first.push_next(&mut accel_write);
            }
        }
        d.update_descriptor_sets(&[first], &[]);

        // Everything recorded before (the builds, the results' clear) before the draw's
        // reads and writes.
        let mut reads = vk::AccessFlags::SHADER_READ;
        if structure_type == vk::DescriptorType::ACCELERATION_STRUCTURE_KHR {
            reads |= vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR;
        }
        let before = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::MEMORY_WRITE)
            .dst_access_mask(reads)];
        d.cmd_pipeline_barrier(
            cmd,
            vk::PipelineStageFlags::ALL_COMMANDS,
            vk::PipelineStageFlags::FRAGMENT_SHADER,
            vk::DependencyFlags::empty(),
            &before,
            &[],
            &[],
        );
        let clear = [vk::ClearValue {
            color: vk::ClearColorValue { uint32: [7; 4] },
        }];
        let begin = vk::RenderPassBeginInfo::default()
            .render_pass(render_pass)
            .framebuffer(framebuffer)
            .render_area(vk::Rect2D {
                offset: vk::Offset2D::default(),
                extent: vk::Extent2D {
                    width: size,
                    height: size,
                },
            })
            .clear_values(&clear);
        d.cmd_begin_render_pass(cmd, &begin, vk::SubpassContents::INLINE);
        d.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipeline);
        d.cmd_bind_descriptor_sets(cmd, vk::PipelineBindPoint::GRAPHICS, layout, 0, &[set], &[]);
        d.cmd_push_constants(cmd, layout, stage, 0, &size.to_ne_bytes());
        d.cmd_draw(cmd, 3, 1, 0, 0);
        d.cmd_end_render_pass(cmd);
        let out = results.as_raw();
        let region = [vk::BufferImageCopy::default()
            .buffer_offset(out.offset())
            .image_subresource(vk::ImageSubresourceLayers {
                aspect_mask: vk::ImageAspectFlags::COLOR,
                mip_level: 0,
                base_array_layer: 0,
                layer_count: 1,
            })
            .image_extent(vk::Extent3D {
                width: size,
                height: size,
                depth: 1,
            })];
        d.cmd_copy_image_to_buffer(
            cmd,
            image,
            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
            out.buffer(),
            &region,
        );
        // The copy's writes before the read-back's copy.
        let after = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::TRANSFER_READ)];
        d.cmd_pipeline_barrier(
            cmd,
            vk::PipelineStageFlags::TRANSFER,
            vk::PipelineStageFlags::TRANSFER,
            vk::DependencyFlags::empty(),
            &after,
            &[],
            &[],
        );
        Objects {
            image,
            memory,
            view,
            device: d,
            render_pass,
            framebuffer,
            set_layout,
            layout,
            pipeline,
            pool,
        }
    }
}

/// A draw's Vulkan objects, destroyed on drop (after its submission completed).
struct Objects {
    image: vk::Image,
    memory: vk::DeviceMemory,
    view: vk::ImageView,
    device: ash::Device,
    render_pass: vk::RenderPass,
    framebuffer: vk::Framebuffer,
    set_layout: vk::DescriptorSetLayout,
    layout: vk::PipelineLayout,
    pipeline: vk::Pipeline,
    pool: vk::DescriptorPool,
}

impl Drop for Objects {
    fn drop(&mut self) {
        // SAFETY: the submission that used these objects has completed (submit_and_wait).
        unsafe {
            let d = &self.device;
            d.destroy_pipeline(self.pipeline, None);
            d.destroy_descriptor_pool(self.pool, None);
            d.destroy_pipeline_layout(self.layout, None);
            d.destroy_descriptor_set_layout(self.set_layout, None);
            d.destroy_framebuffer(self.framebuffer, None);
            d.destroy_render_pass(self.render_pass, None);
            d.destroy_image_view(self.view, None);
            d.destroy_image(self.image, None);
            d.free_memory(self.memory, None);
        }
    }
}

/// Runs `frag` through vkrt's levels (binding 0 the top level's texel buffer) or the
/// driver's: every pixel's record.
fn render(ctx: &Context, dir: &Path, frag: &[u32], driver: bool, size: u32) -> Vec<[u32; 4]> {
    let scene = Scene::load(&dir.join("scene.toml")).unwrap().scene;
    let levels = scene_levels(&scene);
    let pixels = (size * size) as usize;
    let results = Buffer::<[u32; 4]>::new(ctx, "fragment.results", pixels).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    let out = if driver {
        let built = levels.record_driver(&mut rec).unwrap();
        let objects = draw(
            ctx,
            &mut rec,
            frag,
            Structure::Accel(built.accel.tlas().raw()),
            &results,
            size,
        );
        let back = rec.read_back(&results).unwrap();
        rec.transfer_to_host();
        rec.submit_and_wait().unwrap();
        drop((objects, built));
        back.read().unwrap()
    } else {
        let choice = AccelChoice::new(AccelKind::Lbvh, Traversal::Stack);
        let built = levels.record_vkrt(&mut rec, choice).unwrap();
        let address = built.top.handle_address();
        let handle = Buffer::<[u32; 4]>::new(ctx, "fragment.handle", 1).unwrap();
        rec.upload(&handle, &[[address as u32, (address >> 32) as u32, 0, 0]])
            .unwrap();
        let view = TexelView::new(ctx, &handle).unwrap();
        let objects = draw(ctx, &mut rec, frag, Structure::Texel(&view), &results, size);
        let back = rec.read_back(&results).unwrap();
        rec.transfer_to_host();
        rec.submit_and_wait().unwrap();
        drop((objects, built, view));
        back.read().unwrap()
    };
    out
}

#[test]
fn a_fragment_shader_s_queries_give_the_driver_s_image_through_the_pass() {
    let Some(ctx) = common::context() else { return };
    let f = &ctx.info().features;
    if !(f.buffer_device_address && f.shader_int64) {
        eprintln!("note: no bufferDeviceAddress and shaderInt64: vkrt's queries cannot run");
        return;
    }
    let dir = std::env::temp_dir().join(format!("vkrt-spirv-fragment-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("square.obj"), SQUARE_OBJ).unwrap();
    std::fs::write(dir.join("scene.toml"), SCENE).unwrap();
    let size = 48;

    let include = glslc(FRAG, "frag", false);
    let native = glslc(FRAG, "frag", true);
    let lowered =
        vkrt::spirv::lower_ray_queries(&native, &vkrt::spirv::LowerOptions::default()).unwrap();
    assert!(lowered.changed);
    assert_eq!(lowered.query_states, 2);

    let through_include = render(&ctx, &dir, &include, false, size);
    let through_pass = render(&ctx, &dir, &lowered.words, false, size);
    let differ = mismatches(&through_include, &through_pass);
    assert!(
        differ.is_empty(),
        "{} pixels differ between the include and the pass, first {:x?}",
        differ.len(),
        &differ[..differ.len().min(3)]
    );
    // The picture has what the scene puts in it: the first square's kept triangle, the
    // second square, both spheres, shadows, and the cut-out triangle missing.
    let count = |f: &dyn Fn(&[u32; 4]) -> bool| through_pass.iter().filter(|r| f(r)).count();
    let pixels = through_pass.len();
    assert!(
        count(&|r| r[1] == 0 && r[2] == 0) > pixels / 50,
        "the first square"
    );
    assert_eq!(
        count(&|r| r[1] == 0 && r[2] == 1),
        0,
        "the cut-out triangle"
    );
    assert!(count(&|r| r[1] == 1) > pixels / 50, "the second square");
    assert!(
        count(&|r| r[1] == 2 && r[3] & 0xf == 2) > pixels / 200,
        "the spheres"
    );
    assert!(count(&|r| r[3] >> 4 == 1) > pixels / 200, "shadows");
    assert!(count(&|r| r[3] == 0) > pixels / 10, "misses");

    if vkrt::gpu::require_ray_query(&ctx).is_ok() {
        let driver = render(&ctx, &dir, &native, true, size);
        let differ = mismatches(&driver, &through_pass);
        assert!(
            differ.is_empty(),
            "{} pixels differ from the driver's, first {:x?}",
            differ.len(),
            &differ[..differ.len().min(3)]
        );
    }
    common::assert_silent(&ctx);
    let _ = std::fs::remove_dir_all(&dir);
}
