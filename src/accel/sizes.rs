//! What a structure needs, in bytes, asked before it is created.

/// What a structure over a primitive count needs, in bytes
/// (`VkAccelerationStructureBuildSizesInfoKHR`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct AccelSizes {
    /// The structure: nodes, references, parent links, scene constants.
    pub structure_bytes: u64,
    /// Device scratch of a build (0: the builder works in host memory).
    pub build_scratch_bytes: u64,
    /// Device scratch of an update; `None`: the kind cannot be refit.
    pub update_scratch_bytes: Option<u64>,
}
