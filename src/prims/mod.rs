//! GPU parallel primitives on subgroup operations, each with a plain CPU twin that the
//! tests compare against bit for bit: scans (u32 and 0/1 flags packed four per u32),
//! reductions and argmin, segmented and hybrid segmented argmin, stream compaction and
//! key-value radix sort. They are the building blocks of the GPU builders (the kd-tree, the
//! LBVH and PLOC).
//!
//! Rules every kernel here follows:
//! - the subgroup size is read at run time (`gl_SubgroupSize`); nothing assumes 32 lanes,
//!   and every kernel is tested under subgroup sizes 4, 8, 16 and 32;
//! - no workgroup ever waits for another (lavapipe runs a thread's workgroups one after
//!   another): multi-pass reduce-then-scan, or a look-back that reduces a predecessor's
//!   input itself instead of waiting for it (the chained scan's decoupled fallback);
//! - results are deterministic: integer sums, and argmin ties broken by the lowest index.
#![forbid(unsafe_code)]

pub mod compact;
pub mod radix_sort;
pub mod reduce;
pub mod scan;
pub mod segmented;

use crate::gpu::Context;

/// Workgroup shape of a primitive. Tests run every primitive with a workgroup of one
/// subgroup (subgroup-local paths only) and with several subgroups (cross-subgroup paths).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PrimConfig {
    /// Invocations per workgroup: a power of two, a multiple of the subgroup size.
    pub workgroup_size: u32,
    /// Elements each invocation handles per tile ("algorithm cascading", Kolodzey 2014).
    pub items_per_invocation: u32,
}

impl PrimConfig {
    /// The measured default (see `vkrt bench prims`).
    pub fn default_for(ctx: &Context) -> Self {
        Self {
            workgroup_size: 256.min(ctx.info().max_workgroup_invocations),
            items_per_invocation: 16,
        }
        .with_subgroup(ctx)
    }

    /// One subgroup per workgroup: exercises only the subgroup-local paths.
    pub fn single_subgroup(ctx: &Context) -> Self {
        Self {
            workgroup_size: ctx.info().subgroup_size,
            items_per_invocation: 4,
        }
    }

    fn with_subgroup(mut self, ctx: &Context) -> Self {
        self.workgroup_size = self.workgroup_size.max(ctx.info().subgroup_size);
        self
    }

    /// Elements per workgroup tile.
    pub fn tile(&self) -> u32 {
        self.workgroup_size * self.items_per_invocation
    }
}
