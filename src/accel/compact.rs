//! Compaction, as `vkCmdCopyAccelerationStructureKHR` with
//! `VK_COPY_ACCELERATION_STRUCTURE_MODE_COMPACT_KHR` does it: after a build, the bytes the
//! built structure actually uses, read back from a recorded query
//! (`VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR`), then a recorded copy into a
//! smaller range of the caller's memory that traces the same, hit for hit.
//!
//! 1. [`GpuGeometry::record_compacted_size`]: the copy of the build's report into host
//!    memory; after the caller's fence, [`CompactedSizeQuery::read`] gives the
//!    [`CompactedSize`];
//! 2. [`GpuGeometry::create_compacted_in`]: the compacted structure placed in a range of at
//!    least [`CompactedSize::bytes`];
//! 3. [`GpuGeometry::record_compact_into`]: the copy, recorded, ending with the barrier a
//!    build ends with.
//!
//! Which kinds: the kd-tree, whose output is sized for a capacity — 16 nodes and 8
//! references per primitive in the first budget — of which a build uses a fraction (the
//! bunny's compacts to 0.59 of its bytes, primitives included: `cargo bench --bench
//! compaction`); its copy is copies only, with no scratch. And the LBVH and PLOC, whose
//! buffers are sized exactly for `n` primitives but whose SAH leaf collapse frees node slots
//! in place (a freed slot keeps its index, parent link `bvh::collapse::DEAD`): the collapse
//! counts the live nodes on the device, the query reads that count, and the copy renumbers
//! the live nodes densely on the device — their live flags, an exclusive scan (each one's
//! new index), and a scatter that renames every interior child and parent link
//! (`bvh::compact_gpu`, CPU twin `bvh::compact`) — with the references, the refit schedule
//! of a structure built to be updated (which a compacted BVH keeps: it can be updated) and
//! the wide nodes made anew. That renumbering needs scratch, which Vulkan's copy does not
//! take: [`CompactedSize::scratch_bytes`]. The bunny's LBVH and PLOC compact to 0.83 and
//! 0.79 of their bytes. The driver's structure is opaque to vkrt.

use crate::accel::bvh::device::{BvhStorage, CompactShape, LiveCount};
use crate::accel::device::handle_record;
use crate::accel::device::{AccelKind, Storage};
use crate::accel::device_input::DeviceInput;
use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::kdtree::device::{KdBuilt, KdStorage};
use crate::accel::primitives::SceneInfo;
use crate::gpu::placement::{place, Placement};
use crate::gpu::{Buffer, Context, GpuError, RawBuffer, Readback, Recorder, Result};

fn usage(call: &'static str, reason: impl Into<String>) -> GpuError {
    GpuError::Usage {
        call,
        reason: reason.into(),
    }
}

/// The bytes a built structure uses and the counts its compacted copy is made for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CompactedSize {
    /// Bytes of the compacted structure (what [`GpuGeometry::create_compacted_in`] places).
    pub bytes: u64,
    /// Bytes of the scratch [`GpuGeometry::record_compact_into`] needs: 0 for a kd-tree
    /// (copies only); a BVH's renumbering scans its node slots.
    pub scratch_bytes: u64,
    /// Nodes of the built tree (a BVH's live nodes, without the slots its collapse freed).
    pub nodes: u32,
    /// Primitive references of the built tree.
    pub refs: u32,
}

/// What a query reads back, by family.
enum Report {
    /// The kd-tree build's report.
    Kd(Readback<u32>),
    /// A BVH's live nodes, and what its compacted copy is made for.
    Bvh(LiveCount, CompactShape),
}

/// The recorded query of a structure's compacted size; read it once the work has executed.
#[must_use = "read() it once the work has executed"]
pub struct CompactedSizeQuery {
    report: Report,
    ctx: crate::gpu::teardown::Held,
    input: DeviceInput,
}

impl CompactedSizeQuery {
    /// The compacted size, once the recording's work is known complete (an error before,
    /// as [`crate::gpu::Readback::read`]). An error
    /// where the kd-tree's build ran out of capacity (there is no tree to compact: grow it
    /// and build again).
    pub fn read(self) -> Result<CompactedSize> {
        let ctx = &self.ctx;
        let (nodes, refs, scratch_bytes, shape) = match self.report {
            Report::Kd(report) => {
                let built = KdBuilt::decode(&report.read()?);
                if built.overflow {
                    return Err(usage(
                        "CompactedSizeQuery::read",
                        "the build ran out of capacity: build again with one more \
                         kd_capacity_doubling, then compact",
                    ));
                }
                (built.nodes.max(1), built.refs, 0, None)
            }
            Report::Bvh(live, shape) => {
                let live = live.read()?;
                if live > shape.slots {
                    return Err(usage(
                        "CompactedSizeQuery::read",
                        format!("{live} live nodes reported of {} slots", shape.slots),
                    ));
                }
                let scratch = BvhStorage::compact_scratch_bytes(ctx, &shape)?;
                (live as u32, shape.refs as u32, scratch, Some(shape))
            }
        };
        let (_, bytes) = place(ctx, "the compacted structure", Placement::Measure, || {
            compacted_buffers(ctx, &self.input, nodes as usize, refs as usize, shape)
        })?;
        Ok(CompactedSize {
            bytes,
            scratch_bytes,
            nodes,
            refs,
        })
    }
}

/// Where a structure's scene constants lie: which structure a compacted copy was made for.
fn identity(g: &GpuGeometry) -> (crate::gpu::vk::Buffer, u64) {
    let info = g.accel.info.own_range();
    (info.raw, info.offset)
}

/// The primitives, scene constants and tree buffers of a compacted structure (in placement
/// order): a kd-tree's, or a BVH's of `bvh`'s shape.
fn compacted_buffers(
    ctx: &Context,
    input: &DeviceInput,
    nodes: usize,
    refs: usize,
    bvh: Option<CompactShape>,
) -> Result<(DevicePrimitives, Buffer<SceneInfo>, Storage)> {
    let prims = DevicePrimitives::for_layout(ctx, &input.layout)?;
    // (and one more element, where a top level's reference finds the structure's handle)
    let info = Buffer::new(ctx, "accel.info", input.layout.info_len() + 1)?;
    let tree = match bvh {
        Some(shape) => Storage::Bvh(BvhStorage::compacted(ctx, &shape, nodes)?),
        None => Storage::KdTree(KdStorage::compacted(ctx, nodes, refs)?),
    };
    Ok((prims, info, tree))
}

impl GpuGeometry {
    /// The description of a built structure over device geometry that compaction reads;
    /// `Err` for anything else.
    fn compactable(&self, call: &'static str) -> Result<&DeviceInput> {
        let input = self.device_input.as_ref().ok_or_else(|| {
            usage(
                call,
                "compaction copies structures over device geometry (AccelBuilder::create_in)",
            )
        })?;
        if let AccelKind::Driver = self.accel.kind() {
            return Err(usage(
                call,
                "the driver's structure is opaque to vkrt: compact it with the driver's own \
                 vkCmdCopyAccelerationStructureKHR",
            ));
        }
        if !input.built {
            return Err(GpuError::NotBuilt { call });
        }
        Ok(input)
    }

    /// Records the query of the bytes this built structure uses, read with
    /// [`CompactedSizeQuery::read`] after the work has executed: the copy into host memory
    /// of a kd-tree's build report (16 bytes), or of the live-node count an LBVH's or PLOC's
    /// leaf collapse wrote (4 bytes; no copy where nothing was collapsed: the host knows the
    /// count then). Synchronized as [`GpuGeometry::record_read_status`]
    /// ([`RecordSync::READ_STATUS`]): a `compute_to_transfer` barrier before, a
    /// `transfer_to_host` after, then the caller's fence. The driver's structure is an
    /// error ([module docs](crate::accel::compact)).
    ///
    /// [`RecordSync::READ_STATUS`]: crate::accel::sync::RecordSync::READ_STATUS
    pub fn record_compacted_size(&self, rec: &mut Recorder) -> Result<CompactedSizeQuery> {
        let call = "GpuGeometry::record_compacted_size";
        let input = self.compactable(call)?;
        let report = match self.accel.storage() {
            Storage::Bvh(b) => Report::Bvh(b.record_live_count(rec)?, b.compact_shape()),
            _ => Report::Kd(
                self.accel
                    .record_read_built(rec)?
                    .ok_or_else(|| usage(call, "no build report"))?,
            ),
        };
        Ok(CompactedSizeQuery {
            report,
            ctx: crate::gpu::teardown::Held::new(
                rec.context(),
                crate::gpu::teardown::Holder::CompactedSizeQuery,
            ),
            input: input.clone(),
        })
    }

    /// The compacted copy of this structure, placed at the start of `memory`, a range of
    /// the caller's buffer of at least `size.bytes` ([`REQUIRED_BUFFER_USAGE`]). It holds
    /// no data until [`GpuGeometry::record_compact_into`] has executed; it is traced as
    /// the original is, and cannot be built into (build the original again and compact it
    /// again); a BVH built with `allow_update` can be updated
    /// ([`AccelBuilder::record_update_from`](crate::accel::device::AccelBuilder::record_update_from)).
    /// The kernels a BVH's copy records are compiled here, not while recording.
    ///
    /// [`REQUIRED_BUFFER_USAGE`]: crate::accel::embedded::REQUIRED_BUFFER_USAGE
    pub fn create_compacted_in(
        &self,
        ctx: &Context,
        size: &CompactedSize,
        memory: RawBuffer,
    ) -> Result<GpuGeometry> {
        let call = "GpuGeometry::create_compacted_in";
        let input = self.compactable(call)?;
        let (nodes, refs) = (size.nodes as usize, size.refs as usize);
        let shape = match self.accel.storage() {
            Storage::Bvh(b) => {
                let shape = b.compact_shape();
                if refs != shape.refs || nodes > shape.slots {
                    return Err(usage(
                        call,
                        format!(
                            "the size is for {nodes} nodes over {refs} references; this \
                             structure was built with {} node slots over {}",
                            shape.slots, shape.refs
                        ),
                    ));
                }
                Some(shape)
            }
            _ => None,
        };
        let ((prims, info, tree), _) = place(
            ctx,
            "the compacted structure",
            Placement::Into(memory),
            || compacted_buffers(ctx, input, nodes, refs, shape),
        )?;
        Ok(GpuGeometry {
            prims,
            accel: self.accel.like(tree, info),
            device_input: Some(DeviceInput {
                built: false,
                compacted: Some(identity(self)),
                ..input.clone()
            }),
            life: Default::default(),
        })
    }

    /// Records the copy of this built structure into `dst`, made for it by
    /// [`GpuGeometry::create_compacted_in`] from the size its last build reported: its
    /// primitives and scene constants copied, and its tree — a kd-tree's copied; an LBVH's
    /// or PLOC's live nodes renumbered by kernels (see the [module docs](crate::accel::compact)),
    /// with `scratch`, a range of the caller's buffer of at least
    /// [`CompactedSize::scratch_bytes`] (`None` where that is 0). Ends with one barrier from
    /// the copies and kernels to compute-shader reads and writes, as a build does.
    ///
    /// Synchronization ([`crate::accel::sync`]): the caller's barrier before it has
    /// [`RecordSync::COMPACT`]`.first` as its destination (from the build's last, and for a
    /// copy into a structure traced before, from the stages that read it); consumers other
    /// than compute shaders wait on [`RecordSync::COMPACT`]`.last`.
    ///
    /// [`RecordSync::COMPACT`]: crate::accel::sync::RecordSync::COMPACT
    pub fn record_compact_into(
        &self,
        rec: &mut Recorder,
        dst: &mut GpuGeometry,
        scratch: Option<RawBuffer>,
    ) -> Result<()> {
        let call = "GpuGeometry::record_compact_into";
        self.compactable(call)?;
        let made_for_this = dst
            .device_input
            .as_ref()
            .is_some_and(|d| d.compacted == Some(identity(self)));
        if !made_for_this || dst.accel.kind() != self.accel.kind() {
            return Err(usage(
                call,
                "the destination was not made for this structure (its create_compacted_in)",
            ));
        }
        rec.scope("compact", |rec| -> Result<()> {
            match (self.accel.storage(), dst.accel.storage()) {
                (Storage::Bvh(src_tree), Storage::Bvh(dst_tree)) => {
                    src_tree.record_compact_into(rec, dst_tree, scratch)?
                }
                (Storage::KdTree(_), Storage::KdTree(_)) => {}
                _ => return Err(usage(call, "the destination is of another family")),
            }
            let (s, d) = (&self.prims, &dst.prims);
            rec.copy(&s.tri_verts, &d.tri_verts, d.tri_verts.len());
            rec.copy(&s.spheres, &d.spheres, d.spheres.len());
            rec.copy(&s.boxes, &d.boxes, d.boxes.len());
            // The constants; the handle after them is the copy's own (its arrays' addresses).
            rec.copy(&self.accel.info, &dst.accel.info, dst.accel.info.len() - 1);
            if let Some(record) = handle_record(rec.context(), &dst.prims, &dst.accel)? {
                rec.update(&dst.accel.info, dst.accel.info.len() - 1, &[record])?;
            }
            match (self.accel.storage(), dst.accel.storage()) {
                (Storage::KdTree(src_tree), Storage::KdTree(dst_tree)) => {
                    src_tree.record_copy_into(rec, dst_tree)
                }
                _ => Ok(()),
            }
        })?;
        rec.end_of_build();
        rec.check()?;
        if let Some(d) = dst.device_input.as_mut() {
            d.built = true;
        }
        Ok(())
    }
}
