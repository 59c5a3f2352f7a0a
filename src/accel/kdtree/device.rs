//! The kd-tree on the device: Kolodzey's (2014) GPU build into the buffers the walks bind,
//! finished on the device (`accel.kdtree_finish` writes the scene constants, and an empty
//! root if the build ran out of capacity), and the upload of a tree built on the host.

use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::kdtree::gpu::{BuildCapacity, BuildOutput, BuildScratch, KdTreeBuilder};
use crate::accel::kdtree::{KdNode, KdTree, SahParams};
use crate::accel::primitives::SceneInfo;
use crate::accel::sizes::AccelSizes;
use crate::gpu::{Buffer, BufferArg, Context, GpuError, Readback, Recorder, Result};
use crate::scene::Aabb;

/// What a kd-tree build recorded on the device reports once it has executed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KdBuilt {
    /// Nodes written (1, the empty root, when the build overflowed or had no primitives).
    pub nodes: u32,
    /// Primitive references written (0 when the build overflowed or had no primitives).
    pub refs: u32,
    /// The build ran out of capacity: the structure is an empty leaf (every ray misses).
    pub overflow: bool,
    /// References the level that overflowed needed (what to grow the budget to).
    pub needed_refs: u32,
}

impl KdBuilt {
    /// Decodes the report `accel.kdtree_finish` wrote (4 words).
    pub(crate) fn decode(words: &[u32]) -> Self {
        KdBuilt {
            nodes: words[0],
            refs: words[1],
            overflow: words[2] != 0,
            needed_refs: words[3],
        }
    }
}

/// The kd-tree family's builder.
pub(crate) struct KdFamily {
    builder: KdTreeBuilder,
}

/// A kd-tree in device memory.
pub(crate) struct KdStorage {
    out: Box<BuildOutput>,
    /// Written by `accel.kdtree_finish`: nodes, references, overflow flag, references the
    /// overflowing level needed.
    built: Buffer<u32>,
}

impl KdFamily {
    pub(crate) fn new(ctx: &Context) -> Result<Self> {
        Ok(Self {
            builder: KdTreeBuilder::new(ctx)?,
        })
    }

    /// The build's capacity for `n` primitives: the first reference budget per level
    /// (`first`, else 4 per primitive, [`BuildCapacity::for_primitives`]) doubled `grow`
    /// times, fitted to the device with all nodes in the one buffer the traversal binds.
    fn capacity(&self, ctx: &Context, n: usize, grow: u32, first: Option<usize>) -> BuildCapacity {
        let first = first.unwrap_or(BuildCapacity::for_primitives(n).refs_per_level);
        let c = BuildCapacity::with_refs(n, first << grow.min(8));
        let c = self.builder.fit_capacity(ctx, c);
        BuildCapacity {
            nodes: c
                .nodes
                .min((ctx.info().max_storage_buffer_range / 16) as usize),
            ..c
        }
    }

    pub(crate) fn sizes(
        &self,
        ctx: &Context,
        n: usize,
        grow: u32,
        first: Option<usize>,
    ) -> AccelSizes {
        let info = std::mem::size_of::<SceneInfo>() as u64;
        let c = self.capacity(ctx, n, grow, first);
        let s = self.builder.build_sizes(n, &c);
        AccelSizes {
            structure_bytes: s.tree_bytes + info + 16,
            build_scratch_bytes: s.scratch_bytes,
            update_scratch_bytes: None,
        }
    }

    pub(crate) fn create_storage(
        &self,
        ctx: &Context,
        n: usize,
        grow: u32,
        first: Option<usize>,
    ) -> Result<KdStorage> {
        let c = self.capacity(ctx, n, grow, first);
        Ok(KdStorage {
            out: Box::new(self.builder.output(ctx, &c)?),
            built: Buffer::new(ctx, "accel.kdtree_built", 4)?,
        })
    }

    pub(crate) fn create_scratch(
        &self,
        ctx: &Context,
        n: usize,
        grow: u32,
        first: Option<usize>,
    ) -> Result<Box<BuildScratch>> {
        let c = self.capacity(ctx, n, grow, first);
        Ok(Box::new(self.builder.scratch(ctx, n.max(1), c)?))
    }

    /// Records the build over `prims.boxes`; `from_host`: the primitives were uploaded from
    /// the host (no gather wrote the scene constants: they start from zeros).
    #[allow(clippy::too_many_arguments, reason = "the build's inputs and outputs")]
    pub(crate) fn record_build(
        &self,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        from_host: bool,
        params: &SahParams,
        scratch: &BuildScratch,
        out: &KdStorage,
        info: &Buffer<SceneInfo>,
    ) -> Result<()> {
        let n = prims.count();
        if from_host {
            // The finish writes the constants the walk needs; the rest (the shader library's
            // walk, no geometry table) are zeros.
            rec.fill(info, 0);
            rec.transfer_to_compute();
        }
        if n > 0 {
            let o = &out.out;
            self.builder
                .record_build_boxes(rec, &prims.boxes, n, params, scratch, o)?;
            rec.compute_to_compute();
        }
        self.builder.record_finish(
            rec,
            scratch,
            &out.out.nodes[0],
            info,
            &out.built,
            [
                n as u32,
                prims.n_tris as u32,
                prims.n_spheres as u32,
                prims.has_motion as u32,
                prims.n_aabbs as u32,
            ],
        );
        rec.compute_to_compute();
        Ok(())
    }
}

impl KdStorage {
    /// A tree built on the host (or downloaded), uploaded.
    pub(crate) fn from_host(ctx: &Context, tree: &KdTree) -> Result<Self> {
        let nodes: &[KdNode] = if tree.nodes.is_empty() {
            &[KdNode::leaf(0, 0)]
        } else {
            &tree.nodes
        };
        let out = BuildOutput {
            nodes: [
                Buffer::from_slice(ctx, "accel.kdtree_nodes", nodes)?,
                Buffer::new(ctx, "accel.kdtree_nodes1", 1)?,
            ],
            prim_refs: Buffer::from_slice(ctx, "accel.kdtree_refs", &tree.prim_refs)?,
        };
        let built = [nodes.len() as u32, tree.prim_refs.len() as u32, 0, 0];
        Ok(Self {
            out: Box::new(out),
            built: Buffer::from_slice(ctx, "accel.kdtree_built", &built)?,
        })
    }

    /// Buffers for a built tree of `nodes` nodes and `refs` references exactly (a
    /// compacted copy, [`KdStorage::record_copy_into`]).
    pub(crate) fn compacted(ctx: &Context, nodes: usize, refs: usize) -> Result<Self> {
        Ok(Self {
            out: Box::new(BuildOutput {
                nodes: [
                    Buffer::new(ctx, "accel.kdtree_nodes", nodes.max(1))?,
                    Buffer::new(ctx, "accel.kdtree_nodes1", 1)?,
                ],
                prim_refs: Buffer::new(ctx, "accel.kdtree_refs", refs.max(1))?,
            }),
            built: Buffer::new(ctx, "accel.kdtree_built", 4)?,
        })
    }

    /// Nodes and references `dst` holds.
    pub(crate) fn capacity(&self) -> (usize, usize) {
        (self.out.nodes[0].len(), self.out.prim_refs.len())
    }

    /// Records the copy of the built tree into `dst` ([`KdStorage::compacted`] for its
    /// counts): its nodes, references and report. The tree lies in the first node buffer
    /// (the one the walk binds).
    pub(crate) fn record_copy_into(&self, rec: &mut Recorder, dst: &KdStorage) -> Result<()> {
        let (nodes, refs) = dst.capacity();
        if nodes > self.out.nodes[0].len() || refs > self.out.prim_refs.len() {
            return Err(GpuError::Usage {
                call: "GpuGeometry::record_compact_into",
                reason: format!(
                    "the destination holds {nodes} nodes and {refs} references, more than \
                     the structure has room for"
                ),
            });
        }
        rec.copy(&self.out.nodes[0], &dst.out.nodes[0], nodes);
        rec.copy(&self.out.prim_refs, &dst.out.prim_refs, refs);
        rec.copy(&self.built, &dst.built, 4);
        Ok(())
    }

    /// The `nodes` and `prim_refs` bindings.
    pub(crate) fn node_bindings(&self) -> [&dyn BufferArg; 2] {
        [&self.out.nodes[0], &self.out.prim_refs]
    }

    /// Records the copy of the build's report to the host.
    pub(crate) fn record_read_built(&self, rec: &mut Recorder) -> Result<Readback<u32>> {
        rec.read_back(&self.built)
    }

    /// Records the copy of the build's report into the start of `dst`.
    pub(crate) fn record_copy_built_into(&self, rec: &mut Recorder, dst: &dyn BufferArg) {
        rec.copy_into(&self.built, dst);
    }

    /// The tree as the host sees it, with scene constants `info` (an error where the build
    /// ran out of capacity).
    pub(crate) fn download(&self, info: &SceneInfo, bounds: Aabb) -> Result<KdTree> {
        let b = KdBuilt::decode(&self.built.download()?);
        if b.overflow {
            return Err(GpuError::Kernel {
                kernel: "accel.kdtree",
                reason: format!(
                    "the build ran out of capacity (a level needed {} references)",
                    b.needed_refs
                ),
            });
        }
        let primitives = info.n_tris + info.n_spheres + info.n_aabbs;
        let nodes: Vec<KdNode> = self.out.download_nodes(b.nodes.max(1) as usize)?;
        let mut prim_refs = self.out.prim_refs.download()?;
        prim_refs.truncate(b.refs as usize);
        Ok(KdTree {
            nodes,
            prim_refs,
            bounds: if primitives == 0 { Aabb::EMPTY } else { bounds },
            primitives,
        })
    }
}
