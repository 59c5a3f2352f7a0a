//! Ray queries in any SPIR-V: a pass that rewrites a module's `SPV_KHR_ray_query`
//! instructions into calls of vkrt's walk, so that a shader written for the standard's ray
//! query (from GLSL, HLSL, Slang or WGSL, compiled by anyone) runs on a device without
//! `VK_KHR_ray_query`, with no change to its source.
//!
//! ```no_run
//! # fn load() -> Vec<u32> { Vec::new() }
//! let words: Vec<u32> = load(); // the shader's SPIR-V
//! let lowered = vkrt::spirv::lower_ray_queries(&words, &vkrt::spirv::LowerOptions::default())?;
//! // lowered.words: the module to create the shader module from
//! # Ok::<(), vkrt::spirv::LowerError>(())
//! ```
//!
//! What the pass does:
//!
//! - Every ray-query instruction (initialize, proceed, confirm, generate, terminate, every
//!   getter, position fetch) becomes a call into a SPIR-V library compiled from the same GLSL walk that
//!   `vkrt/ext_ray_query.glsl`, `vkrtTrace` and vkrt's kernels run
//!   (`glsl/spirv/ray_query_library.comp`, checked in with the kernels). Only the
//!   functions the module needs are linked.
//! - A query (`OpTypeRayQueryKHR`) becomes a 32-bit handle: the index of one of the
//!   invocation's query states. Every query variable is given its handles as an
//!   initializer, numbered from the entry point's static count (a function's queries come
//!   after those of every function that calls it), so no handle is undefined, a query
//!   value loaded and stored elsewhere still names the same query, and arrays of queries,
//!   queries passed to functions and queries initialized again in a loop all work.
//! - An acceleration-structure variable (single, array or runtime array) keeps its set and
//!   binding and becomes a **uniform texel buffer** (`VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER`,
//!   a view in `VK_FORMAT_R32G32B32A32_UINT`) whose first texel holds, in `.x` (low word)
//!   and `.y`, the device address of the structure's handle: the descriptor
//!   `vkrt/ext_ray_query.glsl` takes, so one host path serves both. One view per structure,
//!   made with it, serves every descriptor write. `OpConvertUToAccelerationStructureKHR`
//!   takes such an address (`uint64_t` or `uvec2`).
//! - Capabilities and extensions: `RayQueryKHR`, `RayTraversalPrimitiveCullingKHR` and
//!   `SPV_KHR_ray_query` go; `Int64`, `PhysicalStorageBufferAddresses`, `SampledBuffer`
//!   (where a structure is bound) and `SPV_KHR_physical_storage_buffer` come, and the
//!   addressing model becomes `PhysicalStorageBuffer64`. Specialization constants stay; the
//!   walk's step cap is the specialization constant [`LowerOptions::steps_constant_id`].
//!
//! Input: SPIR-V 1.3 to 1.6 (at 1.4 and above the library's globals join every entry
//! point's interface), either memory model. Stages: compute, fragment, vertex,
//! tessellation, geometry, task and mesh; ray-tracing pipeline stages and instructions are
//! refused, as are hit objects and opacity micromaps. A module without the `RayQueryKHR`
//! capability comes back unchanged, found by a scan of its leading capabilities. Bad input is a [`LowerError`] naming the instruction
//! and its word offset, never a panic.

mod library;
mod link;
mod queries;
mod rewrite;
mod types;
mod words;

use rspirv::binary::Assemble;

pub use words::has_ray_queries;

/// How [`lower_ray_queries`] lowers a module.
#[derive(Clone, Debug)]
pub struct LowerOptions {
    /// The specialization constant id of the walk's step cap (node visits and primitive
    /// tests per query before it ends, exhausted). Set it to the device's
    /// `DeviceInfo::max_traversal_steps` when creating the pipeline; unset, the cap is
    /// 60,000. The module must not use this id itself.
    pub steps_constant_id: u32,
    /// The walk for a device with a loop budget (`DeviceInfo::loop_budget`, Mesa 22.3's
    /// lavapipe), whose loop reaches no other loop: there it spends about a quarter of the
    /// budget the nested walk does. The same answers either way; default false.
    pub loop_budget: bool,
}

impl Default for LowerOptions {
    fn default() -> Self {
        LowerOptions {
            steps_constant_id: crate::accel::shader_library::STEPS_CONSTANT_ID,
            loop_budget: false,
        }
    }
}

impl LowerOptions {
    /// The options for `device`: its loop budget decides the walk.
    pub fn for_device(device: &crate::gpu::DeviceInfo) -> Self {
        LowerOptions {
            loop_budget: device.loop_budget.is_some(),
            ..Self::default()
        }
    }
}

/// A lowered module and what the pass did to it.
#[derive(Clone, Debug)]
pub struct Lowered {
    /// The module: the input itself where it has no ray query.
    pub words: Vec<u32>,
    /// Whether the module had ray queries and was rewritten.
    pub changed: bool,
    /// Query states per invocation (the entry points' largest static count).
    pub query_states: u32,
    /// Ray-query instructions rewritten (acceleration-structure conversions included).
    pub instructions: usize,
    /// Acceleration-structure variables turned into texel-buffer descriptors.
    pub structures: usize,
    /// Functions of the library linked in.
    pub functions_linked: usize,
}

/// Why a module could not be lowered.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum LowerError {
    /// Not a SPIR-V module (no magic number, a header cut short).
    #[error("not SPIR-V: {0}")]
    NotSpirv(String),
    /// A SPIR-V version the pass does not take.
    #[error("SPIR-V {major}.{minor}: the pass takes SPIR-V 1.3 to 1.6")]
    Version {
        /// Major version.
        major: u32,
        /// Minor version.
        minor: u32,
    },
    /// An instruction that runs past the module's end or has no words.
    #[error("malformed SPIR-V at word {offset}: {reason}")]
    Malformed {
        /// Word offset of the instruction.
        offset: usize,
        /// What is wrong.
        reason: String,
    },
    /// An id out of the module's bound, undefined, or defined twice.
    #[error("{instruction} at word {offset}: {reason} (id %{id})")]
    BadId {
        /// The instruction's name (`OpLoad`, ...).
        instruction: String,
        /// Its word offset, where known (0 otherwise).
        offset: usize,
        /// The id.
        id: u32,
        /// What is wrong with it.
        reason: String,
    },
    /// An instruction, capability or stage the pass does not serve.
    #[error("{instruction} at word {offset}: {reason}")]
    Unsupported {
        /// The instruction (with its operand where that names what is refused).
        instruction: String,
        /// Its word offset.
        offset: usize,
        /// Why it is refused.
        reason: String,
    },
    /// The module uses the specialization constant id the walk's step cap would take.
    #[error(
        "the module uses specialization constant id {0}, which LowerOptions::steps_constant_id \
         gives the walk's step cap: choose another"
    )]
    SpecIdTaken(u32),
}

/// Rewrites the ray queries of the SPIR-V module `words` into calls of vkrt's walk.
///
/// A module without the `RayQueryKHR` capability comes back unchanged (`changed` false).
pub fn lower_ray_queries(words: &[u32], options: &LowerOptions) -> Result<Lowered, LowerError> {
    let scan = words::scan(words)?;
    if !scan.ray_queries {
        return Ok(Lowered {
            words: words.to_vec(),
            changed: false,
            query_states: 0,
            instructions: 0,
            structures: 0,
            functions_linked: 0,
        });
    }
    let scan = words::scan_all(words, scan)?;
    // rspirv's loader places no OpExecutionModeId: those are read apart and put back.
    let (rest, mode_ids) = words::split_execution_mode_ids(words, &scan)?;
    let mut module = rspirv::dr::load_words(&rest).map_err(|e| LowerError::Malformed {
        offset: 0,
        reason: e.to_string(),
    })?;
    module.execution_modes.extend(mode_ids);
    words::check_ids(&module, &scan)?;
    let library = library::load();
    let (stats, library) = rewrite::Rewriter::new(&mut module, &scan, &library, options)?.run()?;
    let linked = link::link(&mut module, library, &stats, options, &scan);
    let out = module.assemble();
    Ok(Lowered {
        words: out,
        changed: true,
        query_states: stats.query_states,
        instructions: stats.instructions,
        structures: stats.structures,
        functions_linked: linked,
    })
}
