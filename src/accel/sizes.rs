//! What a structure needs, in bytes, asked before it is created, and what a recorded build
//! knows when it returns.

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

/// What [`AccelBuilder::record_build`](crate::accel::device::AccelBuilder::record_build)
/// knows when it returns.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RecordedBuild {
    /// Host milliseconds spent building (a host builder; `None` for a device builder,
    /// whose GPU passes are in the recorder's profile).
    pub host_ms: Option<f64>,
}

impl RecordedBuild {
    /// The build's milliseconds: the host builder's, or the GPU passes in `profile` (the
    /// executed recorder's, whose scope `build` holds the build).
    pub fn ms(&self, profile: &crate::gpu::Profile) -> f64 {
        self.host_ms
            .unwrap_or_else(|| profile.ms("build").unwrap_or(0.0))
    }
}
