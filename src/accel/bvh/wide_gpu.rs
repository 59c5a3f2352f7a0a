//! The 4-wide nodes on the device: `accel.bvh_widen` (CPU twin [`super::wide::widen`], bit
//! for bit), one invocation per binary slot, recorded after a BVH's build and after every
//! refit of a structure walked wide.

use std::sync::Arc;

use super::wide::WideNode;
use super::BvhNode;
use crate::gpu::{kernels, Buffer, BufferArg, Context, Kernel, Recorder, Result, Spec};

const WORKGROUP: u32 = 64;

/// The kernel, compiled once.
pub struct Widen {
    kernel: Arc<Kernel>,
}

impl Widen {
    /// Compiles `accel.bvh_widen`.
    pub fn new(ctx: &Context) -> Result<Self> {
        Ok(Self {
            kernel: ctx.kernel(&kernels::ACCEL_BVH_WIDEN, &Spec::new().workgroup(WORKGROUP))?,
        })
    }

    /// Records wide node `i` of `wide` from binary slot `i` of `nodes` for every `i <
    /// n_slots`, in a scope `widen`, ending with a compute → compute barrier. The caller
    /// orders the writes of `nodes` before.
    pub fn record(
        &self,
        rec: &mut Recorder,
        nodes: &Buffer<BvhNode>,
        wide: &Buffer<WideNode>,
        n_slots: usize,
    ) {
        let n = n_slots.min(nodes.len()).min(wide.len());
        if n == 0 {
            return;
        }
        rec.scope("widen", |rec| {
            let groups = rec.groups_1d(n as u64, WORKGROUP);
            let b: [&dyn BufferArg; 2] = [nodes, wide];
            rec.dispatch(&self.kernel, groups, &b, &(n as u32));
        });
        rec.compute_to_compute();
    }

    /// The wide nodes of `nodes` (all slots), computed on the device (tests and tools).
    pub fn run(&self, ctx: &Context, nodes: &[BvhNode]) -> Result<Vec<WideNode>> {
        if nodes.is_empty() {
            return Ok(Vec::new());
        }
        let input = Buffer::from_slice(ctx, "accel.bvh_nodes", nodes)?;
        let wide = Buffer::new(ctx, "accel.bvh_wide", nodes.len())?;
        let mut rec = Recorder::new(ctx)?;
        self.record(&mut rec, &input, &wide, nodes.len());
        rec.compute_to_transfer();
        let back = rec.read_back(&wide)?;
        rec.transfer_to_host();
        rec.submit_and_wait()?;
        back.read()
    }
}
