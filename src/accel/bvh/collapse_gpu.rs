//! The SAH leaf collapse on the GPU (CPU twin: [`super::collapse`]), recorded after the
//! LBVH's or PLOC's tree is complete: the SAH costs bottom-up with visit counters
//! (`accel.bvh_collapse_cost`), which nodes live and how many references their leaves hold
//! (`accel.bvh_collapse_flags`), an exclusive scan of the latter (each live node's first
//! reference), and the references laid out anew with the leaf children pointed at them
//! (`accel.bvh_collapse_write`). Nodes stay in their slots: a removed node keeps its slot
//! with the parent link [`DEAD`](super::collapse::DEAD), which the refits and the schedule
//! skip and the host's copy drops (`AccelStructure::download` renumbers, giving the twin's
//! compacted tree); the last pass counts the live nodes into the structure, where
//! compaction's size query reads them. The builder writes its references into this scratch
//! ([`CollapseScratch::tree_refs`]). A tree whose references lie in depth-first order (the
//! LBVH's, [`RefLayout::InPlace`]) skips the flags, the scan and the write: one pass
//! (`accel.bvh_collapse_in_place`) copies the references as they are and points each
//! collapsed child at its run, and its scratch holds no flags and no scan.

use std::sync::Arc;

use super::collapse::RefLayout;
use super::sah::BvhParams;
use super::BvhNode;
use crate::gpu::{kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, Spec};
use crate::prims::scan::{Scan, ScanInput, ScanOp, ScanScratch};
use crate::prims::PrimConfig;

/// The largest leaf the collapse makes (the write kernel's gather stack holds 64 children).
pub const MAX_COLLAPSE_LEAF: u32 = 32;

const WORKGROUP: u32 = 64;

/// The kernels, compiled once.
pub struct CollapseKernels {
    cost: Arc<Kernel>,
    flags: Arc<Kernel>,
    write: Arc<Kernel>,
    in_place: Arc<Kernel>,
    scan: Scan,
}

/// Scratch of one collapse of a tree of up to `max_nodes` nodes.
pub struct CollapseScratch {
    max_nodes: usize,
    /// Count, SAH cost and decision of every node.
    costs: Buffer<u32>,
    /// The builder's references, then its parent links.
    words: Buffer<u32>,
    /// What only [`RefLayout::NodeOrder`] lays out with: absent for [`RefLayout::InPlace`].
    node_order: Option<NodeOrderScratch>,
}

/// The node-order layout's flags and scan.
struct NodeOrderScratch {
    live: Buffer<u32>,
    /// Each live node's leaf references, scanned in place into its first reference.
    first_ref: Buffer<u32>,
    scan: ScanScratch,
}

impl CollapseScratch {
    /// Where the builder writes its references and parent links (the structure's layout)
    /// for the collapse to lay them out in the structure.
    pub fn tree_refs(&self) -> &Buffer<u32> {
        &self.words
    }

    /// Every node's primitive count, SAH cost and collapse decision (three words each), for
    /// a pass that decides on its own climb (`LbvhBuilder::record_build`).
    pub fn costs(&self) -> &Buffer<u32> {
        &self.costs
    }
}

impl CollapseKernels {
    /// `climb_workgroup`: the cost pass climbs like the refit, in workgroups of one subgroup.
    pub fn new(ctx: &Context, climb_workgroup: u32) -> Result<Self> {
        let spec = Spec::new().workgroup(WORKGROUP);
        Ok(Self {
            cost: ctx.kernel(
                &kernels::ACCEL_BVH_COLLAPSE_COST,
                &Spec::new().workgroup(climb_workgroup),
            )?,
            flags: ctx.kernel(&kernels::ACCEL_BVH_COLLAPSE_FLAGS, &spec)?,
            write: ctx.kernel(&kernels::ACCEL_BVH_COLLAPSE_WRITE, &spec)?,
            in_place: ctx.kernel(&kernels::ACCEL_BVH_COLLAPSE_IN_PLACE, &spec)?,
            scan: Scan::new(ctx, PrimConfig::default_for(ctx), ScanInput::U32)?,
        })
    }

    /// Bytes of [`CollapseKernels::scratch`] for a tree of `n_prims` primitives.
    pub fn scratch_bytes(&self, n_prims: usize, layout: RefLayout) -> u64 {
        let nodes = n_prims.saturating_sub(1).max(1);
        // Costs (three words a node), then the builder's references and parent links.
        let shared = (4 * (3 * nodes + n_prims.max(1) + nodes)) as u64;
        match layout {
            RefLayout::InPlace => shared,
            RefLayout::NodeOrder => {
                shared + (4 * 2 * nodes) as u64 + self.scan.scratch_bytes(nodes)
            }
        }
    }

    /// Allocates the scratch of collapses of trees of up to `n_prims` primitives whose
    /// references are laid out as `layout` says.
    pub fn scratch(
        &self,
        ctx: &Context,
        n_prims: usize,
        layout: RefLayout,
    ) -> Result<CollapseScratch> {
        let nodes = n_prims.saturating_sub(1).max(1);
        let node_order = match layout {
            RefLayout::InPlace => None,
            RefLayout::NodeOrder => Some(NodeOrderScratch {
                live: Buffer::new(ctx, "accel.collapse.live", nodes)?,
                first_ref: Buffer::new(ctx, "accel.collapse.first_ref", nodes)?,
                scan: self.scan.scratch(ctx, nodes)?,
            }),
        };
        Ok(CollapseScratch {
            max_nodes: nodes,
            costs: Buffer::new(ctx, "accel.collapse.costs", 3 * nodes)?,
            words: Buffer::new(ctx, "accel.collapse.words", n_prims.max(1) + nodes)?,
            node_order,
        })
    }

    /// Checks that the device can collapse with `params` (the leaf size the gather holds).
    pub fn check(params: &BvhParams) -> Result<()> {
        if params.max_leaf_prims > MAX_COLLAPSE_LEAF {
            return Err(GpuError::Usage {
                call: "BvhParams::max_leaf_prims",
                reason: format!(
                    "max_leaf_prims = {}: the GPU builders' leaves hold at most {MAX_COLLAPSE_LEAF}",
                    params.max_leaf_prims
                ),
            });
        }
        Ok(())
    }

    /// Records the collapse of the complete tree in `nodes` and `scratch.tree_refs()`
    /// (`n_prims` references, then `n_prims - 1` parent links) with `params`' costs and leaf
    /// size: `nodes` in place, the structure's `refs` written as `layout` says, and the live
    /// nodes counted into the word after its parent links, which the caller zeroes before
    /// (ordered by a transfer → compute barrier). `visits`
    /// holds a zeroed-here counter per node; `decided`: the build decided already (the
    /// LBVH's climb, `LbvhBuilder::record_build`). Only where [`super::collapse::applies`]:
    /// elsewhere the builder writes the structure itself. Ends with a compute → compute
    /// barrier.
    #[allow(
        clippy::too_many_arguments,
        reason = "the tree's buffers and the knobs"
    )]
    pub fn record(
        &self,
        rec: &mut Recorder,
        n_prims: usize,
        visits: &Buffer<u32>,
        scratch: &CollapseScratch,
        params: &BvhParams,
        nodes: &Buffer<BvhNode>,
        refs: &Buffer<u32>,
        decided: bool,
        layout: RefLayout,
    ) -> Result<()> {
        if !(super::collapse::applies(n_prims, params)) {
            return Err(GpuError::Usage {
                call: "CollapseKernels::record",
                reason: "a collapse that changes nothing".into(),
            });
        }
        let n_nodes = n_prims - 1;
        if n_nodes > scratch.max_nodes {
            return Err(GpuError::Usage {
                call: "CollapseKernels::record",
                reason: format!(
                    "collapse of {n_nodes} nodes, scratch for {}",
                    scratch.max_nodes
                ),
            });
        }
        if refs.len() <= n_prims + n_nodes {
            return Err(GpuError::Usage {
                call: "CollapseKernels::record",
                reason: format!(
                    "the structure's words hold {}: {n_prims} references, {n_nodes} parent \
                     links and the live-node count do not fit",
                    refs.len()
                ),
            });
        }
        let s = scratch;
        // The node-order layout's flags and scan; none for references left in place.
        let node_order = match layout {
            RefLayout::InPlace => None,
            RefLayout::NodeOrder => Some(s.node_order.as_ref().ok_or_else(|| GpuError::Usage {
                call: "CollapseKernels::record",
                reason: "a node-order collapse with scratch made for references in place".into(),
            })?),
        };
        let parents_at = n_prims as u32;
        let max_leaf = params.max_leaf_prims.min(MAX_COLLAPSE_LEAF);
        rec.scope("collapse", |rec| {
            let tree: [&dyn BufferArg; 2] = [nodes, &s.words];
            if !decided {
                // The builder's last kernels read the counters.
                rec.compute_to_transfer();
                rec.fill_first(visits, n_nodes, 0);
                rec.transfer_to_compute();
                let groups = rec.groups_1d(n_nodes as u64, self.cost.invocations());
                let b: [&dyn BufferArg; 4] = [tree[0], tree[1], visits, &s.costs];
                let push = [
                    n_nodes as u32,
                    parents_at,
                    max_leaf,
                    params.traversal_cost.to_bits(),
                    params.intersection_cost.to_bits(),
                ];
                rec.scope("collapse.cost", |rec| {
                    rec.dispatch(&self.cost, groups, &b, &push)
                });
                rec.compute_to_compute();
            }
            let Some(o) = node_order else {
                let groups = rec.groups_1d(n_prims as u64, WORKGROUP);
                let b: [&dyn BufferArg; 4] = [nodes, &s.words, &s.costs, refs];
                let push = [n_nodes as u32, parents_at, max_leaf];
                rec.scope("collapse.in_place", |rec| {
                    rec.dispatch(&self.in_place, groups, &b, &push)
                });
                return;
            };
            let groups = rec.groups_1d(n_nodes as u64, WORKGROUP);
            let b: [&dyn BufferArg; 5] = [tree[0], tree[1], &s.costs, &o.live, &o.first_ref];
            rec.dispatch(
                &self.flags,
                groups,
                &b,
                &[n_nodes as u32, parents_at, max_leaf],
            );
            rec.compute_to_compute();
            let op = ScanOp::Exclusive;
            self.scan
                .record(rec, &o.first_ref, &o.first_ref, n_nodes, op, &o.scan);
            rec.compute_to_compute();
            let b: [&dyn BufferArg; 6] = [nodes, &s.words, &s.costs, &o.live, &o.first_ref, refs];
            rec.scope("collapse.write", |rec| {
                rec.dispatch(&self.write, groups, &b, &[n_nodes as u32, parents_at])
            });
        });
        rec.compute_to_compute();
        Ok(())
    }
}
