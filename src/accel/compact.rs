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
//! 3. [`GpuGeometry::record_compact_into`]: the copy, recorded (copies only: no kernel, no
//!    scratch), ending with the barrier a build ends with.
//!
//! Which kinds: the kd-tree, whose output is sized for a capacity — 16 nodes and 8
//! references per primitive in the first budget — of which a build uses a fraction (the
//! bunny's compacts to 0.59 of its bytes, primitives included: `cargo bench --bench
//! compaction`). The LBVH's and PLOC's buffers are sized exactly
//! for `n` primitives; their only slack is the node slots the SAH leaf collapse removes,
//! which stay in place (a removed slot keeps its index, `bvh::collapse::DEAD`): compacting
//! them means renumbering the live nodes and their children on the device, a kernel vkrt
//! does not have, so they refuse compaction with an error rather than copy without saving.
//! The driver's structure is opaque to vkrt.

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
    /// Nodes of the built tree.
    pub nodes: u32,
    /// Primitive references of the built tree.
    pub refs: u32,
}

/// The recorded query of a structure's compacted size; read it once the work has executed.
#[must_use = "read() it once the work has executed"]
pub struct CompactedSizeQuery {
    report: Readback<u32>,
    ctx: Context,
    input: DeviceInput,
}

impl CompactedSizeQuery {
    /// The compacted size. Call only after the recording's work has completed. An error
    /// where the kd-tree's build ran out of capacity (there is no tree to compact: grow it
    /// and build again).
    pub fn read(self) -> Result<CompactedSize> {
        let built = KdBuilt::decode(&self.report.read()?);
        if built.overflow {
            return Err(usage(
                "CompactedSizeQuery::read",
                "the build ran out of capacity: build again with one more \
                 kd_capacity_doubling, then compact",
            ));
        }
        let (nodes, refs) = (built.nodes.max(1), built.refs);
        let ctx = &self.ctx;
        let (_, bytes) = place(ctx, "the compacted structure", Placement::Measure, || {
            compacted_buffers(ctx, &self.input, nodes as usize, refs as usize)
        })?;
        Ok(CompactedSize { bytes, nodes, refs })
    }
}

/// Where a structure's scene constants lie: which structure a compacted copy was made for.
fn identity(g: &GpuGeometry) -> (crate::gpu::vk::Buffer, u64) {
    let info = g.accel.info.as_raw();
    (info.raw, info.offset)
}

/// The primitives, scene constants and tree buffers of a compacted kd-tree (in placement
/// order).
fn compacted_buffers(
    ctx: &Context,
    input: &DeviceInput,
    nodes: usize,
    refs: usize,
) -> Result<(DevicePrimitives, Buffer<SceneInfo>, KdStorage)> {
    let prims = DevicePrimitives::for_layout(ctx, &input.layout)?;
    // (and one more element, where a top level's reference finds the structure's handle)
    let info = Buffer::new(ctx, "accel.info", input.layout.info_len() + 1)?;
    let tree = KdStorage::compacted(ctx, nodes, refs)?;
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
        match self.accel.kind() {
            AccelKind::KdTree => {}
            kind => {
                return Err(usage(
                    call,
                    format!(
                        "a {} structure cannot be compacted: its buffers are sized for its \
                         primitives, and the node slots its leaf collapse frees stay in place \
                         (only the kd-tree, sized for a capacity, is compacted)",
                        kind.name()
                    ),
                ))
            }
        }
        if !input.built {
            return Err(usage(
                call,
                "the structure has not been built: record its build first",
            ));
        }
        Ok(input)
    }

    /// Records the query of the bytes this built structure uses (the copy of its build's
    /// report, 16 bytes, into host memory), read with [`CompactedSizeQuery::read`] after the
    /// work has executed. Synchronized as [`GpuGeometry::record_read_status`]
    /// ([`RecordSync::READ_STATUS`]): a `compute_to_transfer` barrier before, a
    /// `transfer_to_host` after, then the caller's fence. Only kd-trees are compacted
    /// ([module docs](crate::accel::compact)); other kinds are an error.
    ///
    /// [`RecordSync::READ_STATUS`]: crate::accel::sync::RecordSync::READ_STATUS
    pub fn record_compacted_size(&self, rec: &mut Recorder) -> Result<CompactedSizeQuery> {
        let input = self.compactable("GpuGeometry::record_compacted_size")?;
        let report = self
            .accel
            .record_read_built(rec)?
            .ok_or_else(|| usage("GpuGeometry::record_compacted_size", "no build report"))?;
        Ok(CompactedSizeQuery {
            report,
            ctx: rec.context().clone(),
            input: input.clone(),
        })
    }

    /// The compacted copy of this structure, placed at the start of `memory`, a range of
    /// the caller's buffer of at least `size.bytes` ([`REQUIRED_BUFFER_USAGE`]). It holds
    /// no data until [`GpuGeometry::record_compact_into`] has executed; it is traced as
    /// the original is, and cannot be built or updated into (build the original again and
    /// compact it again).
    ///
    /// [`REQUIRED_BUFFER_USAGE`]: crate::accel::embedded::REQUIRED_BUFFER_USAGE
    pub fn create_compacted_in(
        &self,
        ctx: &Context,
        size: &CompactedSize,
        memory: RawBuffer,
    ) -> Result<GpuGeometry> {
        let input = self.compactable("GpuGeometry::create_compacted_in")?;
        let (nodes, refs) = (size.nodes as usize, size.refs as usize);
        let ((prims, info, tree), _) = place(
            ctx,
            "the compacted structure",
            Placement::Into(memory),
            || compacted_buffers(ctx, input, nodes, refs),
        )?;
        Ok(GpuGeometry {
            prims,
            accel: self.accel.like(Storage::KdTree(tree), info),
            device_input: Some(DeviceInput {
                built: false,
                compacted: Some(identity(self)),
                ..input.clone()
            }),
        })
    }

    /// Records the copy of this built structure into `dst`, made for it by
    /// [`GpuGeometry::create_compacted_in`] from the size its last build reported: its
    /// primitives, scene constants and tree, with copies only. Ends with one barrier from
    /// the copies to compute-shader reads and writes, as a build does.
    ///
    /// Synchronization ([`crate::accel::sync`]): the caller's barrier before it has
    /// [`RecordSync::COMPACT`]`.first` as its destination (from the build's last, and for a
    /// copy into a structure traced before, from the stages that read it); consumers other
    /// than compute shaders wait on [`RecordSync::COMPACT`]`.last`.
    ///
    /// [`RecordSync::COMPACT`]: crate::accel::sync::RecordSync::COMPACT
    pub fn record_compact_into(&self, rec: &mut Recorder, dst: &mut GpuGeometry) -> Result<()> {
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
        let (Storage::KdTree(src_tree), Storage::KdTree(dst_tree)) =
            (self.accel.storage(), dst.accel.storage())
        else {
            return Err(usage(call, "compaction copies kd-trees only"));
        };
        rec.scope("compact", |rec| -> Result<()> {
            let (s, d) = (&self.prims, &dst.prims);
            rec.copy(&s.tri_verts, &d.tri_verts, d.tri_verts.len());
            rec.copy(&s.spheres, &d.spheres, d.spheres.len());
            rec.copy(&s.boxes, &d.boxes, d.boxes.len());
            // The constants; the handle after them is the copy's own (its arrays' addresses).
            rec.copy(&self.accel.info, &dst.accel.info, dst.accel.info.len() - 1);
            if let Some(record) = handle_record(rec.context(), &dst.prims, &dst.accel)? {
                rec.update(&dst.accel.info, dst.accel.info.len() - 1, &[record])?;
            }
            src_tree.record_copy_into(rec, dst_tree)
        })?;
        rec.end_of_build();
        rec.check()?;
        if let Some(d) = dst.device_input.as_mut() {
            d.built = true;
        }
        Ok(())
    }
}
