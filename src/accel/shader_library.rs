//! The GLSL library a renderer's own shaders include to trace vkrt's structures
//! (`vkrt/ray_query.glsl`): the same walk vkrt's kernels run.
//!
//! Give your compiler the include directory ([`include_dir`]) or serve the files from
//! [`FILES`] through its includer (shaderc's `set_include_callback`, glslang's includer),
//! bind a structure's seven buffers ([`GpuGeometry::descriptor_buffer_infos`]) at the
//! bindings of [`descriptor_set_layout_bindings`], and call `vkrtTraceClosest` /
//! `vkrtTraceAny`. One descriptor set layout serves every kind of structure vkrt builds:
//! the walk is chosen from the structure itself.
//!
//! ```
//! use vkrt::accel::shader_library::{file, include_dir, write_to, ENTRY};
//!
//! // The entry point and everything it includes, for a compiler's includer...
//! assert!(file(ENTRY).unwrap().contains("vkrtTraceClosest"));
//! // ...or as a directory for `glslc -I`: this crate's own, or the files written out.
//! assert!(include_dir().join(ENTRY).is_file());
//! let dir = std::env::temp_dir().join(format!("vkrt-include-{}", std::process::id()));
//! write_to(&dir)?;
//! assert!(dir.join(ENTRY).is_file());
//! # std::fs::remove_dir_all(&dir)?;
//! # Ok::<(), std::io::Error>(())
//! ```

use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::walk::NodeAccess;
use crate::gpu::{vk, TexelView};

/// The library's files, by the name an `#include` gives them (relative to
/// [`include_dir`]).
pub const FILES: &[(&str, &str)] = &[
    (
        "vkrt/ext_ray_query.glsl",
        include_str!("../../glsl/include/vkrt/ext_ray_query.glsl"),
    ),
    (
        "vkrt/ext_ray_query_step.glsl",
        include_str!("../../glsl/include/vkrt/ext_ray_query_step.glsl"),
    ),
    (
        "vkrt/affine.glsl",
        include_str!("../../glsl/include/vkrt/affine.glsl"),
    ),
    (
        "vkrt/ray_query.glsl",
        include_str!("../../glsl/include/vkrt/ray_query.glsl"),
    ),
    (
        "vkrt/instances.glsl",
        include_str!("../../glsl/include/vkrt/instances.glsl"),
    ),
    (
        "vkrt/traverse.glsl",
        include_str!("../../glsl/include/vkrt/traverse.glsl"),
    ),
    (
        "vkrt/bvh.glsl",
        include_str!("../../glsl/include/vkrt/bvh.glsl"),
    ),
    (
        "vkrt/bvh_node.glsl",
        include_str!("../../glsl/include/vkrt/bvh_node.glsl"),
    ),
    (
        "vkrt/bvh_wide_node.glsl",
        include_str!("../../glsl/include/vkrt/bvh_wide_node.glsl"),
    ),
    (
        "vkrt/kdtree.glsl",
        include_str!("../../glsl/include/vkrt/kdtree.glsl"),
    ),
    (
        "vkrt/ray.glsl",
        include_str!("../../glsl/include/vkrt/ray.glsl"),
    ),
];

/// The entry point to `#include`.
pub const ENTRY: &str = "vkrt/ray_query.glsl";

/// The entry point for a shader written against `GL_EXT_ray_query`: its queries, getters
/// and `accelerationStructureEXT` over vkrt's structures (docs/ray-queries.md).
pub const EXT_RAY_QUERY: &str = "vkrt/ext_ray_query.glsl";

/// Storage buffers a structure binds, from the first binding on.
pub const BINDINGS: u32 = 7;

/// The specialization constant that holds the walks' step cap (node visits + primitive
/// tests per ray before a query reports `vkrtExhausted`) where the shader does not define
/// `VKRT_MAX_TRAVERSAL_STEPS`; `VKRT_STEPS_CONSTANT_ID` moves it where the shader's own
/// constants need this id. Unset, the cap is 60,000 (within lavapipe's loop budget); set
/// it to the device's [`DeviceInfo::max_traversal_steps`](crate::gpu::DeviceInfo) with
/// [`steps_specialization`].
pub const STEPS_CONSTANT_ID: u32 = 1900;

/// The specialization constant (a `bool`) that gives `vkrt/ext_ray_query.glsl`'s queries the
/// walk for a device with a loop budget ([`DeviceInfo::loop_budget`](crate::gpu::DeviceInfo),
/// Mesa 22.3's lavapipe): set it to `loop_budget.is_some()`. Unset, it is false: the nested
/// walk, which spends about four times the budget there. `VKRT_LOOP_BUDGET_CONSTANT_ID`
/// moves it. The same answers either way.
pub const LOOP_BUDGET_CONSTANT_ID: u32 = 1901;

/// The map entry and data of a `VkSpecializationInfo` that set the library's step cap
/// ([`STEPS_CONSTANT_ID`]) to `max_traversal_steps`:
///
/// ```
/// use vkrt::accel::shader_library::steps_specialization;
/// use vkrt::gpu::vk;
/// let (entries, data) = steps_specialization(1 << 24);
/// let info = vk::SpecializationInfo::default().map_entries(&entries).data(&data);
/// assert_eq!(info.data_size, 4);
/// ```
pub fn steps_specialization(
    max_traversal_steps: u32,
) -> ([vk::SpecializationMapEntry; 1], [u8; 4]) {
    let entry = vk::SpecializationMapEntry {
        constant_id: STEPS_CONSTANT_ID,
        offset: 0,
        size: 4,
    };
    ([entry], max_traversal_steps.to_ne_bytes())
}

/// The directory holding `vkrt/` in this crate's sources (for `-I` of `glslc` or
/// `glslangValidator`). Where the crate's sources are not at hand, write [`FILES`] out with
/// [`write_to`].
pub fn include_dir() -> &'static std::path::Path {
    std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/glsl/include"))
}

/// The contents of library file `name` (`"vkrt/ray_query.glsl"`, ...).
pub fn file(name: &str) -> Option<&'static str> {
    FILES.iter().find(|(n, _)| *n == name).map(|(_, c)| *c)
}

/// Writes [`FILES`] under `dir` (as `dir/vkrt/...`), for compilers that take a directory.
pub fn write_to(dir: &std::path::Path) -> std::io::Result<()> {
    for (name, contents) in FILES {
        let path = dir.join(name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(path, contents)?;
    }
    Ok(())
}

/// The layout bindings of a structure at `first`..`first + 7` for `stages` (the
/// `VKRT_BINDING` the shader defines), read-only storage buffers.
pub fn descriptor_set_layout_bindings(
    first: u32,
    stages: vk::ShaderStageFlags,
) -> [vk::DescriptorSetLayoutBinding<'static>; BINDINGS as usize] {
    descriptor_set_layout_bindings_for(first, stages, NodeAccess::Storage)
}

/// Bindings through texel buffers (`VKRT_TEXEL_BUFFERS`): the first three (nodes,
/// references, triangle vertices).
pub const TEXEL_BINDINGS: u32 = 3;

/// [`descriptor_set_layout_bindings`] for a shader that reads the structure as `access`
/// says: [`NodeAccess::Texel`] (`VKRT_TEXEL_BUFFERS`) makes the first
/// [`TEXEL_BINDINGS`] uniform texel buffers, written from [`GpuGeometry::texel_views`].
pub fn descriptor_set_layout_bindings_for(
    first: u32,
    stages: vk::ShaderStageFlags,
    access: NodeAccess,
) -> [vk::DescriptorSetLayoutBinding<'static>; BINDINGS as usize] {
    std::array::from_fn(|k| {
        let texel = access == NodeAccess::Texel && (k as u32) < TEXEL_BINDINGS;
        vk::DescriptorSetLayoutBinding::default()
            .binding(first + k as u32)
            .descriptor_type(if texel {
                vk::DescriptorType::UNIFORM_TEXEL_BUFFER
            } else {
                vk::DescriptorType::STORAGE_BUFFER
            })
            .descriptor_count(1)
            .stage_flags(stages)
    })
}

impl GpuGeometry {
    /// RGBA32UI views of the first [`TEXEL_BINDINGS`] ranges (nodes, references, triangle
    /// vertices), for a shader compiled with `VKRT_TEXEL_BUFFERS`: write them as uniform
    /// texel buffers, and the other bindings from [`GpuGeometry::descriptor_buffer_infos`].
    /// Keep the views until the work that reads them has executed.
    pub fn texel_views(&self) -> crate::gpu::Result<[TexelView; TEXEL_BINDINGS as usize]> {
        let ctx = self.prims.tri_verts.context();
        let [nodes, refs, verts, ..] = self.bindings();
        Ok([
            TexelView::new(ctx, nodes)?,
            TexelView::new(ctx, refs)?,
            TexelView::new(ctx, verts)?,
        ])
    }

    /// The seven buffer ranges to write into the descriptor set of a shader that includes
    /// `vkrt/ray_query.glsl`, in binding order.
    pub fn descriptor_buffer_infos(&self) -> [vk::DescriptorBufferInfo; BINDINGS as usize] {
        let b = self.bindings();
        std::array::from_fn(|k| vk::DescriptorBufferInfo {
            buffer: b[k].raw(),
            offset: b[k].offset(),
            range: b[k].range(),
        })
    }
}
