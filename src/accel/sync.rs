//! The synchronization contract of vkrt's record calls, declared for the caller's barriers
//! (a render graph's, say): for each call, the pipeline stages and accesses it touches
//! first and those it leaves last. vkrt records no barrier against the caller's work: the
//! caller orders its own accesses before a call with a barrier whose destination is
//! [`RecordSync::first`], and its consumers after with one whose source is
//! [`RecordSync::last`] — as it does around `vkCmdBuildAccelerationStructuresKHR`, whose
//! stage (`ACCELERATION_STRUCTURE_BUILD`) and accesses are fixed by the specification.
//!
//! The masks are declared rather than taken as arguments: a render graph computes each
//! barrier from the passes on both sides of it (and merges them); a call that took the
//! caller's stages would record barriers the graph cannot see, and would need to know its
//! consumer when it is recorded (which a graph may record later, in another command buffer).
//!
//! - **Builds, updates and refits** (`AccelBuilder::record_build_from`,
//!   `record_builds_from` (a batch: one barrier at its end, for all its structures),
//!   `record_update_from`, `record_build`, `record_refit`; `TopLevelBuilder::record_build_from`,
//!   `record_update_from` and the calls over them): [`RecordSync::build`]. They read the
//!   geometry (or instances) as compute-shader reads and copies, and write the structure
//!   and the scratch with compute shaders, fills, copies and `vkCmdUpdateBuffer`, read
//!   dispatch arguments from the scratch (indirect reads), and for the driver's structure
//!   build with `ACCELERATION_STRUCTURE_BUILD`. Each ends with one barrier from all of that
//!   to compute-shader reads and writes, so what it leaves last is compute-shader work: a
//!   caller's compute shader recorded next needs no barrier; any other consumer (a fragment
//!   shader, a copy) needs one from [`RecordSync::last`].
//! - **Traces** (`Tracer::record`): [`RecordSync::TRACE`], compute-shader reads of the
//!   structure and rays and writes of the hits, with no barrier at the end.
//! - **Compaction** (`GpuGeometry::record_compact_into`): [`RecordSync::COMPACT`], copies
//!   (transfer reads of the built structure, transfer writes of the compacted one) and, for
//!   an LBVH or PLOC, kernels (compute-shader reads of the built structure and writes of the
//!   compacted one and of the scratch), ending with the barrier a build ends with; its size
//!   query (`record_compacted_size`) is a status read-back.
//! - **The status read-back** (`GpuGeometry::record_read_status`,
//!   `TopLevel::record_read_status`): [`RecordSync::READ_STATUS`], a copy. Before it, a
//!   barrier from the build's last (`Recorder::compute_to_transfer`); after it, one from
//!   transfer writes to host reads (`Recorder::transfer_to_host`), then the caller's fence.
//!
//! **A rebuild (or update) in place** writes memory the previous frame's shaders read: before
//! recording it, the caller records a barrier whose source stages include every stage that
//! read the structure (`FRAGMENT_SHADER`, say; an execution dependency is what a
//! write-after-read needs, so the source access may be empty) and whose destination is
//! [`RecordSync::first`] of the build. Frames in flight that read a structure while the next
//! frame rebuilds it need one structure each.
//!
//! **What stays bound.** Every dispatch binds a compute pipeline of vkrt's, its descriptor
//! set 0 and push constants at `VK_PIPELINE_BIND_POINT_COMPUTE`: after a vkrt call the
//! caller binds its own compute pipeline, sets and push constants again before dispatching
//! (Vulkan has no way to read the state back, and a dispatch cannot run without them).
//! Nothing is bound at the graphics bind point, no dynamic state is set, and nothing is
//! recorded inside a render pass.

use crate::accel::device::AccelKind;
use crate::gpu::vk;

/// Pipeline stages and the accesses made in them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StageAccess {
    /// `VkPipelineStageFlags`.
    pub stages: vk::PipelineStageFlags,
    /// `VkAccessFlags` made in those stages.
    pub access: vk::AccessFlags,
}

/// What a record call touches first and leaves last ([module docs](self)).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RecordSync {
    /// The destination of the caller's barrier before the call.
    pub first: StageAccess,
    /// The source of the caller's barrier before the next consumer of what it wrote.
    pub last: StageAccess,
}

const COMPUTE_WRITE: StageAccess = StageAccess {
    stages: vk::PipelineStageFlags::COMPUTE_SHADER,
    access: vk::AccessFlags::SHADER_WRITE,
};

impl RecordSync {
    /// A build, update or refit of a structure of `kind` (a top level's too).
    pub fn build(kind: AccelKind) -> Self {
        let mut stages = vk::PipelineStageFlags::COMPUTE_SHADER
            | vk::PipelineStageFlags::TRANSFER
            | vk::PipelineStageFlags::DRAW_INDIRECT;
        let mut access = vk::AccessFlags::SHADER_READ
            | vk::AccessFlags::SHADER_WRITE
            | vk::AccessFlags::TRANSFER_READ
            | vk::AccessFlags::TRANSFER_WRITE
            | vk::AccessFlags::INDIRECT_COMMAND_READ;
        if kind == AccelKind::Driver {
            stages |= vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR;
            access |= vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR
                | vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR;
        }
        Self {
            first: StageAccess { stages, access },
            last: COMPUTE_WRITE,
        }
    }

    /// A trace of vkrt's kernel (`Tracer::record`).
    pub const TRACE: Self = Self {
        first: StageAccess {
            stages: vk::PipelineStageFlags::COMPUTE_SHADER,
            access: vk::AccessFlags::from_raw(
                vk::AccessFlags::SHADER_READ.as_raw() | vk::AccessFlags::SHADER_WRITE.as_raw(),
            ),
        },
        last: COMPUTE_WRITE,
    };

    /// The copy of a built structure into its compacted one
    /// (`GpuGeometry::record_compact_into`): copies, and a BVH's renumbering kernels, then
    /// the barrier a build ends with, so what it leaves last is what a build leaves.
    pub const COMPACT: Self = Self {
        first: StageAccess {
            stages: vk::PipelineStageFlags::from_raw(
                vk::PipelineStageFlags::TRANSFER.as_raw()
                    | vk::PipelineStageFlags::COMPUTE_SHADER.as_raw(),
            ),
            access: vk::AccessFlags::from_raw(
                vk::AccessFlags::TRANSFER_READ.as_raw()
                    | vk::AccessFlags::TRANSFER_WRITE.as_raw()
                    | vk::AccessFlags::SHADER_READ.as_raw()
                    | vk::AccessFlags::SHADER_WRITE.as_raw(),
            ),
        },
        last: COMPUTE_WRITE,
    };

    /// The copy of a build's report into host memory (`record_read_status`).
    pub const READ_STATUS: Self = Self {
        first: StageAccess {
            stages: vk::PipelineStageFlags::TRANSFER,
            access: vk::AccessFlags::from_raw(
                vk::AccessFlags::TRANSFER_READ.as_raw() | vk::AccessFlags::TRANSFER_WRITE.as_raw(),
            ),
        },
        last: StageAccess {
            stages: vk::PipelineStageFlags::TRANSFER,
            access: vk::AccessFlags::TRANSFER_WRITE,
        },
    };
}
