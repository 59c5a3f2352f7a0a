//! The GPU build of Kolodzey (2014), recorded into one command buffer with no read-back between
//! levels (see [`super::breadth_first`] for the algorithm; it is this build's CPU twin and the
//! tests require both to give the same tree, bit for bit).
//!
//! Phase I: primitive boxes — from triangles (`accel.kdtree_boxes`) or from boxes the
//! caller computed, 6 floats each (`accel.kdtree_input_boxes`, for spheres, moving
//! primitives or a mix; `accel.kdtree_sphere_boxes` computes sphere boxes on the GPU) —,
//! then the scene box (min/max reductions), per
//! axis the event keys (`accel.kdtree_event_keys`), a stable f32 radix sort and the SoA
//! event records (`accel.kdtree_event_gather`), then the root (`accel.kdtree_init`).
//!
//! Phase II, recorded `depth_limit + 1` times (a level with no nodes dispatches nothing):
//! START flag scans per axis → `split_costs` → hybrid segmented argmin → `decide` → scans
//! of inner flags and leaf sizes → `write_nodes` + `leaves` → per axis `classify` → slot
//! scan → `scatter` (and `children` after axis 0) → `advance`. Every size lives in a state
//! buffer on the GPU: event- and node-parallel kernels are dispatched indirectly with
//! arguments `advance` computed; scans are recorded for their capacity and read their
//! length from the state (`Scan::record_counted`).
//!
//! Capacity: clipping duplicates references, so per-level buffers are sized from
//! [`BuildCapacity`]. When a level would exceed a capacity, `advance` raises a flag, records
//! how many references it needed and gives every later level zero work: the build stops
//! cleanly, never writes out of bounds, never hangs. [`KdTreeBuilder::build`] then retries
//! with larger buffers.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use super::breadth_first::Events;
use super::{Aabb, KdNode, KdTree, SahParams};
use crate::gpu::{
    kernels, Buffer, BufferArg, Context, GpuError, Kernel, Profile, Recorder, Result, Spec,
};
use crate::prims::radix_sort::{RadixScratch, RadixSort};
use crate::prims::reduce::{CostIndex, Reduce};
use crate::prims::scan::{GpuCount, Scan, ScanInput, ScanOp, ScanScratch};
use crate::prims::segmented::{SegmentedArgmin, SegmentedMode, WorkgroupReduction};
use crate::prims::PrimConfig;

const WORKGROUP: u32 = 256;
// Words of the state buffer (keep in sync with glsl/accel/kdtree/level.glsl).
const ST_REFS: u32 = 0;
const ST_NODES: u32 = 1;
const ST_NODE_BASE: usize = 2;
const ST_REF_BASE: usize = 3;
const ST_OVERFLOW: usize = 5;
const ST_NEED_REFS: usize = 6;
const ST_LEVELS: usize = 8;
const ST_EVENT_ARGS: u64 = 12;
const ST_NODE_ARGS: u64 = 16;
const ST_WORDS: usize = 32;

/// One axis list of events on the GPU (SoA, as [`Events`]).
pub struct GpuEvents {
    /// Each event's plane ([`Events::plane`]).
    pub plane: Buffer<f32>,
    /// END = 0 / START = 1, one byte each.
    pub kind: Buffer<u8>,
    /// Each event's primitive.
    pub prim: Buffer<u32>,
    /// Each event's node, by index within the level being built.
    pub node: Buffer<u32>,
    /// The (clipped) primitive box of every event: three arrays of `capacity` component
    /// pairs, (min x, min y), (min z, max x) and (max y, max z), one buffer each so that
    /// each stays within `maxStorageBufferRange` (16 bytes per reference of a level instead
    /// of 48). A kernel moves a pair as one 64-bit component where the device has
    /// `shaderInt64`: on lavapipe every load and store at a lane-varying address is a loop
    /// over lanes and components (`glsl/accel/kdtree/level.glsl`).
    pub boxes: [Buffer<f32>; 3],
    /// Events every array holds.
    pub capacity: usize,
}

impl GpuEvents {
    fn new(ctx: &Context, name: &str, len: usize) -> Result<Self> {
        let name = |f: &str| format!("kdtree.{name}.{f}");
        Ok(Self {
            plane: Buffer::new(ctx, &name("plane"), len)?,
            kind: Buffer::new(ctx, &name("kind"), len)?,
            prim: Buffer::new(ctx, &name("prim"), len)?,
            node: Buffer::new(ctx, &name("node"), len)?,
            boxes: [
                Buffer::new(ctx, &name("min_xy"), 2 * len)?,
                Buffer::new(ctx, &name("min_z_max_x"), 2 * len)?,
                Buffer::new(ctx, &name("max_yz"), 2 * len)?,
            ],
            capacity: len,
        })
    }

    /// The three box pair arrays, as kernel arguments.
    fn box_args(&self) -> [&dyn BufferArg; 3] {
        let b = &self.boxes;
        [&b[0], &b[1], &b[2]]
    }

    /// plane, kind, prim, node and the three box pair arrays, as kernel arguments.
    fn record_args(&self) -> Vec<&dyn BufferArg> {
        let mut v: Vec<&dyn BufferArg> = vec![&self.plane, &self.kind, &self.prim, &self.node];
        v.extend(self.box_args());
        v
    }

    /// Reads the first `len` events back (for tests and the twin comparison).
    pub fn download(&self, len: usize) -> Result<Events> {
        let pairs = [
            self.boxes[0].download()?,
            self.boxes[1].download()?,
            self.boxes[2].download()?,
        ];
        // Component k (min x, y, z, max x, y, z) is element 2·event + k % 2 of array k / 2.
        let arr = |k: usize| -> Result<Vec<f32>> {
            Ok(pairs[k / 2]
                .iter()
                .skip(k % 2)
                .step_by(2)
                .take(len)
                .copied()
                .collect())
        };
        let head = |mut v: Vec<u32>| {
            v.truncate(len);
            v
        };
        let mut plane = self.plane.download()?;
        plane.truncate(len);
        let mut kind = self.kind.download()?;
        kind.truncate(len);
        Ok(Events {
            plane,
            kind,
            prim: head(self.prim.download()?),
            node: head(self.node.download()?),
            box_min: [arr(0)?, arr(1)?, arr(2)?],
            box_max: [arr(3)?, arr(4)?, arr(5)?],
        })
    }
}

/// How large the build's buffers are. References per level grow by clipping; the
/// default allows 4 per primitive, and [`KdTreeBuilder::build`] doubles on overflow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct BuildCapacity {
    /// Primitive references (events per axis / 2) one level may hold.
    pub refs_per_level: usize,
    /// Nodes one level may hold (at most twice the references plus one).
    pub nodes_per_level: usize,
    /// Nodes of the output tree.
    pub nodes: usize,
    /// Leaf references of the output tree.
    pub refs: usize,
}

impl BuildCapacity {
    /// The default for `n` primitives.
    pub fn for_primitives(n: usize) -> Self {
        Self::with_refs(n, 4 * n.max(1) + 64)
    }

    /// Capacity for `refs_per_level` references per level, the rest derived.
    pub fn with_refs(n: usize, refs_per_level: usize) -> Self {
        Self {
            refs_per_level,
            nodes_per_level: 2 * refs_per_level + 1,
            nodes: 4 * refs_per_level + 1024,
            refs: (2 * refs_per_level).max(n) + 1024,
        }
    }

    /// This capacity with every buffer clamped to `max_range` bytes (the device's
    /// `maxStorageBufferRange`: 128 MiB on lavapipe). The largest buffers per unit are the
    /// scanned slot offsets (16 bytes per reference of a level: 4 virtual slots of a u32;
    /// the event boxes are three pair arrays of as much), the level's node boxes (24
    /// bytes per node) and the output nodes (16 bytes each, in two buffers). On lavapipe that
    /// is 8.4 M references per level, 5.6 M nodes per level and 16.8 M nodes. A build that
    /// needs more overflows and [`KdTreeBuilder::build_from`] reports it as an error naming
    /// the limit.
    pub fn fit(self, max_range: u64) -> Self {
        let most = |bytes_per_item: u64| (max_range / bytes_per_item) as usize;
        Self {
            refs_per_level: self.refs_per_level.min(most(16)),
            nodes_per_level: self.nodes_per_level.min(most(24)),
            nodes: self.nodes.min(2 * most(16)),
            refs: self.refs.min(most(4)),
        }
    }
}

/// Bytes a build needs, for an embedding renderer that allocates itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct BuildSizes {
    /// Device scratch of the build (events, per-event and per-node arrays, scans).
    pub scratch_bytes: u64,
    /// The output tree: 16 bytes per node and 4 per leaf reference of the capacity.
    pub tree_bytes: u64,
}

/// What [`KdTreeBuilder::build_from`] returns.
pub struct BuildResult {
    /// The built tree.
    pub tree: KdTree,
    /// GPU passes of the successful attempt.
    pub profile: Profile,
    /// 1 unless a capacity overflowed and the build was retried larger.
    pub attempts: u32,
    /// The capacity of the successful attempt.
    pub capacity: BuildCapacity,
    /// Levels that had nodes.
    pub levels: u32,
}

/// The state read back after a build.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct BuildOutcome {
    /// Nodes written (clamped to the capacity).
    pub nodes: u32,
    /// Leaf references written (clamped to the capacity).
    pub refs: u32,
    /// Levels that had nodes.
    pub levels: u32,
    /// A capacity was too small; the tree is incomplete.
    pub overflow: bool,
    /// References the overflowing level needed.
    pub needed_refs: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct SahPush {
    trav: f32,
    isect: f32,
    bonus: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DecidePush {
    isect: f32,
    max_leaf_prims: u32,
    depth_limit: u32,
    sah_leaf_test: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct AdvancePush {
    ref_capacity: u32,
    level_node_capacity: u32,
    node_capacity: u32,
    out_ref_capacity: u32,
}

struct Kernels {
    boxes: Arc<Kernel>,
    input_boxes: Arc<Kernel>,
    sphere_boxes: Arc<Kernel>,
    widen_flags: Arc<Kernel>,
    event_keys: Arc<Kernel>,
    event_gather: Arc<Kernel>,
    init: Arc<Kernel>,
    split_costs: Arc<Kernel>,
    decide: Arc<Kernel>,
    write_nodes: Arc<Kernel>,
    leaves: Arc<Kernel>,
    classify: Arc<Kernel>,
    scatter: Arc<Kernel>,
    children: Arc<Kernel>,
    advance: Arc<Kernel>,
    finish: Arc<Kernel>,
}

/// The GPU kd-tree builder: kernels and primitives, compiled once.
pub struct KdTreeBuilder {
    k: Kernels,
    sort: RadixSort,
    reduce: Reduce,
    flag_scan: Scan,
    scan: Scan,
    segmented: SegmentedArgmin,
    /// How the best split of every node is found (hybrid by default; the others are for
    /// the ablation benchmark).
    pub segmented_mode: SegmentedMode,
    /// Nodes of the first output buffer ([`BuildOutput::nodes`]); `None`: as many as fit
    /// `maxStorageBufferRange`. Tests set it small to exercise the second buffer.
    pub max_nodes_per_buffer: Option<usize>,
    ablation: Ablation,
}

/// The baselines of Kolodzey's Table 6.2 ablation that the build can switch back to. Every
/// combination gives the same tree, bit for bit (tests/kdtree_gpu.rs); only speed differs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Ablation {
    /// The best split's workgroup reduction through shared memory (one barrier per halving
    /// step) instead of subgroup shuffles (Kolodzey 2014, Listing 6.7 vs its Fig. 6.12 baseline).
    pub shared_memory_argmin: bool,
    /// START counts by the plain u32 scan over event types widened to u32 (an extra pass)
    /// instead of the byte-flag scan that reads 4 types per u32 (Kolodzey 2014, Listing 6.6).
    pub u32_event_scan: bool,
    /// Clipping and partitioning by scattering full event records instead of the 1-byte
    /// clip-mask (Kolodzey 2014, Alg. 10 / Table 6.1 vs its baseline, "Clip-Mask" in Table 6.2).
    /// Default: `classify` writes one flag byte per event and side, one flag scan, and
    /// `scatter` reads each record once and writes it, clipped, to its place (≈ 37 bytes
    /// written per kept copy). Baseline: `classify.records` also writes each event's complete
    /// clipped record (plane, type, primitive, child node, 6 box floats) into its valid
    /// [below | above] slots of a temporary list twice the event list's length, the same
    /// flag scan, and `scatter.records` moves every valid slot's complete record a second
    /// time to its scanned place: every record is written twice and read twice (≈ 74 bytes
    /// written per kept copy), with the temporary list as extra memory (74 bytes per
    /// event; its box pair arrays hold 32 bytes per reference, twice the slot offsets, so
    /// [`KdTreeBuilder::fit_capacity`] halves the per-level limit).
    pub full_record_scatter: bool,
    /// The classify, scatter and split-cost passes move the event boxes' component pairs and
    /// read the node's field pairs as two 32-bit components each (the path of devices without
    /// `shaderInt64`) instead of one 64-bit component (not in Kolodzey 2014: on lavapipe
    /// every load or store at a lane-varying address is a loop over lanes and components).
    pub narrow_moves: bool,
}

/// The level's node arrays (ping-ponged between levels).
struct LevelBuffers {
    node_box: Buffer<f32>,
    node_range: Buffer<u32>,
    offsets: Buffer<u32>,
}

/// Everything a build needs besides its input and output.
pub struct BuildScratch {
    capacity: BuildCapacity,
    max_prims: usize,
    prim_min: [Buffer<f32>; 3],
    prim_max: [Buffer<f32>; 3],
    bounds: [Buffer<f32>; 6],
    keys: Buffer<f32>,
    values: Buffer<u32>,
    sort: RadixScratch,
    reduce: Buffer<u32>,
    events: [[GpuEvents; 3]; 2],
    levels: [LevelBuffers; 2],
    state: Buffer<u32>,
    seg_count: Buffer<u32>,
    node_split: Buffer<u32>,
    inner_flag: Buffer<u32>,
    leaf_count: Buffer<u32>,
    inner_before: Buffer<u32>,
    leaf_before: Buffer<u32>,
    best: Buffer<CostIndex>,
    cost: Buffer<f32>,
    axis: Buffer<u32>,
    starts: [Buffer<u32>; 3],
    slots: Buffer<u8>,
    slot_offsets: Buffer<u32>,
    flag_scratch: ScanScratch,
    inner_scratch: ScanScratch,
    leaf_scratch: ScanScratch,
    slot_scratch: ScanScratch,
    seg_scratch: Buffer<u32>,
    /// Ablation `u32_event_scan` only: widened event types and the u32 scan's scratch.
    wide_flags: Option<(Buffer<u32>, ScanScratch)>,
    /// Ablation `full_record_scatter` only: the temporary list of full records, one per
    /// virtual slot (twice the event list).
    slot_records: Option<GpuEvents>,
}

/// The build's output: nodes and leaf references (valid up to the outcome's counts).
pub struct BuildOutput {
    /// The nodes in BFS order, in two buffers so that a tree may hold twice as many nodes
    /// as one buffer within `maxStorageBufferRange` (16.8 M on lavapipe): node `g` is
    /// `nodes[0][g]` below `nodes[0].len()` and `nodes[1][g - nodes[0].len()]` from there on
    /// (`nodes[1]` is a one-node buffer when the first holds the whole capacity).
    /// [`BuildOutput::download_nodes`] reads them back as one list.
    pub nodes: [Buffer<KdNode>; 2],
    /// The leaves' primitive references.
    pub prim_refs: Buffer<u32>,
}

impl BuildOutput {
    /// Nodes the output holds.
    pub fn node_capacity(&self) -> usize {
        self.nodes[0].len() + self.nodes[1].len()
    }

    /// The first `len` nodes as one list.
    pub fn download_nodes(&self, len: usize) -> Result<Vec<KdNode>> {
        let mut nodes = self.nodes[0].download()?;
        if len > nodes.len() {
            nodes.extend(self.nodes[1].download()?);
        }
        nodes.truncate(len);
        Ok(nodes)
    }
}

impl KdTreeBuilder {
    /// The builder with every optimisation on; errors where the device lacks
    /// `storageBuffer8BitAccess` ([`KdTreeBuilder::require`]).
    pub fn new(ctx: &Context) -> Result<Self> {
        Self::with_ablation(ctx, Ablation::default())
    }

    /// `Ok` where the device can run the builder: its classification writes one byte per
    /// event (`storageBuffer8BitAccess`, a Vulkan 1.2 feature).
    pub fn require(ctx: &Context) -> Result<()> {
        if ctx.info().features.storage_buffer_8bit {
            return Ok(());
        }
        Err(crate::gpu::GpuError::MissingCapability {
            device: ctx.info().device.clone(),
            what: "storageBuffer8BitAccess (the kd-tree builder's 1-byte flags): enable it \
                   when creating the device"
                .into(),
        })
    }

    /// A builder with some of Kolodzey's optimisations switched back to their baselines
    /// (for the ablation benchmark; [`KdTreeBuilder::new`] is the default, all on).
    pub fn with_ablation(ctx: &Context, ablation: Ablation) -> Result<Self> {
        Self::require(ctx)?;
        let spec = Spec::new().workgroup(WORKGROUP);
        let k = |blob| ctx.kernel(blob, &spec);
        let one = |blob| ctx.kernel(blob, &Spec::new());
        let cfg = PrimConfig::default_for(ctx);
        // Box pairs and node fields as 64-bit components where the device has them.
        let wide = ctx.info().features.shader_int64 && !ablation.narrow_moves;
        Ok(Self {
            k: Kernels {
                boxes: k(&kernels::ACCEL_KDTREE_BOXES)?,
                input_boxes: k(&kernels::ACCEL_KDTREE_INPUT_BOXES)?,
                sphere_boxes: k(&kernels::ACCEL_KDTREE_SPHERE_BOXES)?,
                widen_flags: k(&kernels::ACCEL_KDTREE_WIDEN_FLAGS)?,
                event_keys: k(&kernels::ACCEL_KDTREE_EVENT_KEYS)?,
                event_gather: k(&kernels::ACCEL_KDTREE_EVENT_GATHER)?,
                init: one(&kernels::ACCEL_KDTREE_INIT)?,
                split_costs: k(if wide {
                    &kernels::ACCEL_KDTREE_SPLIT_COSTS_WIDE
                } else {
                    &kernels::ACCEL_KDTREE_SPLIT_COSTS_NARROW
                })?,
                decide: k(&kernels::ACCEL_KDTREE_DECIDE)?,
                write_nodes: k(&kernels::ACCEL_KDTREE_WRITE_NODES)?,
                leaves: k(&kernels::ACCEL_KDTREE_LEAVES)?,
                classify: k(match (ablation.full_record_scatter, wide) {
                    (true, true) => &kernels::ACCEL_KDTREE_CLASSIFY_RECORDS64,
                    (true, false) => &kernels::ACCEL_KDTREE_CLASSIFY_RECORDS,
                    (false, true) => &kernels::ACCEL_KDTREE_CLASSIFY_MASK64,
                    (false, false) => &kernels::ACCEL_KDTREE_CLASSIFY_MASK,
                })?,
                scatter: k(match (ablation.full_record_scatter, wide) {
                    (true, true) => &kernels::ACCEL_KDTREE_SCATTER_RECORDS64,
                    (true, false) => &kernels::ACCEL_KDTREE_SCATTER_RECORDS,
                    (false, true) => &kernels::ACCEL_KDTREE_SCATTER_ONCE64,
                    (false, false) => &kernels::ACCEL_KDTREE_SCATTER_ONCE,
                })?,
                children: k(&kernels::ACCEL_KDTREE_CHILDREN)?,
                advance: one(&kernels::ACCEL_KDTREE_ADVANCE)?,
                finish: one(&kernels::ACCEL_KDTREE_FINISH)?,
            },
            sort: RadixSort::new(ctx, cfg, 8)?,
            reduce: Reduce::new(ctx, cfg)?,
            flag_scan: Scan::new(ctx, cfg, ScanInput::Flags)?,
            scan: Scan::new(ctx, cfg, ScanInput::U32)?,
            // Nodes of the deep levels hold a few events each: small workgroups per segment.
            segmented: SegmentedArgmin::with_reduction(
                ctx,
                cfg,
                ctx.info().subgroup_size.max(32),
                if ablation.shared_memory_argmin {
                    WorkgroupReduction::SharedMemory
                } else {
                    WorkgroupReduction::Shuffle
                },
            )?,
            // Tiles for the few long segments of the first levels, decided on the GPU.
            segmented_mode: SegmentedMode::hybrid_for(ctx),
            max_nodes_per_buffer: None,
            ablation,
        })
    }

    /// The optimisations switched off (none by default).
    pub fn ablation(&self) -> Ablation {
        self.ablation
    }

    /// `capacity` clamped to what this device and the builder's primitives take: every
    /// buffer within `maxStorageBufferRange` ([`BuildCapacity::fit`]), a level's nodes
    /// within the segmented argmin's segment limit, its events within its cost limit.
    pub fn fit_capacity(&self, ctx: &Context, capacity: BuildCapacity) -> BuildCapacity {
        let c = capacity.fit(ctx.info().max_storage_buffer_range);
        // The ablation's temporary slot list (twice the events) holds 32 bytes per reference
        // in each box pair array.
        let slot_list_refs = if self.ablation.full_record_scatter {
            (ctx.info().max_storage_buffer_range / 32) as usize
        } else {
            usize::MAX
        };
        BuildCapacity {
            refs_per_level: c
                .refs_per_level
                .min(self.segmented.max_costs() / 2)
                .min(slot_list_refs),
            nodes_per_level: c.nodes_per_level.min(self.segmented.max_segments()),
            ..c
        }
    }

    /// Bytes of scratch and output for `n` primitives at `capacity`.
    pub fn build_sizes(&self, n: usize, capacity: &BuildCapacity) -> BuildSizes {
        let e = 2 * capacity.refs_per_level as u64;
        let m = capacity.nodes_per_level as u64;
        let events = 2 * 3 * e * (4 + 1 + 4 + 4 + 24);
        let per_event = e * (4 + 4 + 3 * 4) + 2 * 2 * e * 4;
        let per_node = 2 * m * (24 + 8 + 4) + m * (8 + 4 * 4 + 8);
        let phase_one = n as u64 * (24 + 2 * 8);
        let scans = 3 * (2 * e * 4 / 1000 + 64); // tile sums: a small fraction
        let ablation = if self.ablation.full_record_scatter {
            2 * e * (4 + 1 + 4 + 4 + 24)
        } else {
            0
        } + if self.ablation.u32_event_scan {
            e * 4
        } else {
            0
        };
        BuildSizes {
            scratch_bytes: events + per_event + per_node + phase_one + scans + ablation,
            tree_bytes: capacity.nodes as u64 * 16 + capacity.refs as u64 * 4,
        }
    }

    /// Allocates scratch for up to `max_prims` primitives at `capacity`.
    pub fn scratch(
        &self,
        ctx: &Context,
        max_prims: usize,
        capacity: BuildCapacity,
    ) -> Result<BuildScratch> {
        let e = 2 * capacity.refs_per_level.max(max_prims);
        let m = capacity.nodes_per_level;
        let f = |name: &str, len: usize| Buffer::<f32>::new(ctx, name, len);
        let u = |name: &str, len: usize| Buffer::<u32>::new(ctx, name, len);
        let level = |i: usize| -> Result<LevelBuffers> {
            Ok(LevelBuffers {
                node_box: f(&format!("kdtree.level{i}.box"), 6 * m)?,
                node_range: u(&format!("kdtree.level{i}.range"), 2 * m)?,
                offsets: u(&format!("kdtree.level{i}.offsets"), m + 1)?,
            })
        };
        let events = |p: usize| -> Result<[GpuEvents; 3]> {
            Ok([
                GpuEvents::new(ctx, &format!("events{p}.x"), e)?,
                GpuEvents::new(ctx, &format!("events{p}.y"), e)?,
                GpuEvents::new(ctx, &format!("events{p}.z"), e)?,
            ])
        };
        Ok(BuildScratch {
            capacity: BuildCapacity {
                refs_per_level: e / 2,
                ..capacity
            },
            max_prims,
            prim_min: [
                f("kdtree.prim_min_x", max_prims)?,
                f("kdtree.prim_min_y", max_prims)?,
                f("kdtree.prim_min_z", max_prims)?,
            ],
            prim_max: [
                f("kdtree.prim_max_x", max_prims)?,
                f("kdtree.prim_max_y", max_prims)?,
                f("kdtree.prim_max_z", max_prims)?,
            ],
            bounds: std::array::from_fn(|i| {
                f(&format!("kdtree.bounds{i}"), 1).expect("4-byte buffer")
            }),
            keys: f("kdtree.sort_keys", 2 * max_prims)?,
            values: u("kdtree.sort_values", 2 * max_prims)?,
            sort: self.sort.scratch(ctx, 2 * max_prims)?,
            reduce: u(
                "kdtree.reduce_scratch",
                self.reduce.scratch_len(max_prims).max(1),
            )?,
            events: [events(0)?, events(1)?],
            levels: [level(0)?, level(1)?],
            state: u("kdtree.state", ST_WORDS)?,
            seg_count: u("kdtree.seg_count", 1)?,
            node_split: u("kdtree.node_split", 2 * m)?,
            inner_flag: u("kdtree.inner_flag", m)?,
            leaf_count: u("kdtree.leaf_count", m)?,
            inner_before: u("kdtree.inner_before", m)?,
            leaf_before: u("kdtree.leaf_before", m)?,
            best: Buffer::new(ctx, "kdtree.best", m)?,
            cost: f("kdtree.cost", e)?,
            axis: u("kdtree.axis", e)?,
            starts: [
                u("kdtree.starts0", e)?,
                u("kdtree.starts1", e)?,
                u("kdtree.starts2", e)?,
            ],
            slots: Buffer::new(ctx, "kdtree.slots", 2 * e)?,
            slot_offsets: u("kdtree.slot_offsets", 2 * e)?,
            flag_scratch: self.flag_scan.scratch(ctx, e)?,
            inner_scratch: self.scan.scratch(ctx, m)?,
            leaf_scratch: self.scan.scratch(ctx, m)?,
            slot_scratch: self.flag_scan.scratch(ctx, 2 * e)?,
            seg_scratch: u("kdtree.seg_scratch", self.segmented.scratch_len(e, m))?,
            wide_flags: if self.ablation.u32_event_scan {
                Some((u("kdtree.wide_flags", e)?, self.scan.scratch(ctx, e)?))
            } else {
                None
            },
            slot_records: if self.ablation.full_record_scatter {
                Some(GpuEvents::new(ctx, "slot_records", 2 * e)?)
            } else {
                None
            },
        })
    }

    /// Allocates the output of a build at `capacity` (nodes split over two buffers).
    pub fn output(&self, ctx: &Context, capacity: &BuildCapacity) -> Result<BuildOutput> {
        let per_buffer = self
            .max_nodes_per_buffer
            .unwrap_or((ctx.info().max_storage_buffer_range / 16) as usize)
            .max(1);
        let first = capacity.nodes.min(per_buffer);
        let second = (capacity.nodes - first).max(1);
        Ok(BuildOutput {
            nodes: [
                Buffer::new(ctx, "kdtree.nodes0", first)?,
                Buffer::new(ctx, "kdtree.nodes1", second)?,
            ],
            prim_refs: Buffer::new(ctx, "kdtree.prim_refs", capacity.refs)?,
        })
    }

    /// Records the whole build of the `n` triangles in `triangles` (9 floats each) into
    /// `rec`: no read-back, a finite number of passes. The caller orders the upload of
    /// `triangles` before and a `compute_to_*` barrier before reading `out`;
    /// [`KdTreeBuilder::read_outcome`] then tells how many nodes and references are valid.
    pub fn record_build(
        &self,
        rec: &mut Recorder,
        triangles: &Buffer<f32>,
        n: usize,
        params: &SahParams,
        s: &BuildScratch,
        out: &BuildOutput,
    ) -> Result<()> {
        self.record_source(rec, Source::Triangles(triangles), n, params, s, out)
    }

    /// [`KdTreeBuilder::record_build`] over `n` primitive boxes, 6 floats each (min x, y,
    /// z, max x, y, z; e.g. [`crate::scene::Aabb`]s, or boxes a kernel such as
    /// [`KdTreeBuilder::record_sphere_boxes`] wrote): spheres, moving primitives, any mix.
    /// Every box must be finite with min ≤ max (the host entry points check it).
    pub fn record_build_boxes(
        &self,
        rec: &mut Recorder,
        boxes: &Buffer<f32>,
        n: usize,
        params: &SahParams,
        s: &BuildScratch,
        out: &BuildOutput,
    ) -> Result<()> {
        self.record_source(rec, Source::Boxes(boxes), n, params, s, out)
    }

    /// Records the boxes of `n` spheres (4 floats each: center x, y, z, radius) into
    /// `boxes` as primitives `first .. first + n` of the box input of
    /// [`KdTreeBuilder::record_build_boxes`]: `center ± radius`, exactly as
    /// [`super::breadth_first::sphere_box`]. The caller orders the writes of `spheres` before and
    /// a `compute_to_compute` barrier before the build reads `boxes`.
    pub fn record_sphere_boxes(
        &self,
        rec: &mut Recorder,
        spheres: &Buffer<f32>,
        n: usize,
        boxes: &Buffer<f32>,
        first: usize,
    ) -> Result<()> {
        if !(4 * n <= spheres.len() && 6 * (first + n) <= boxes.len()) {
            return Err(GpuError::Usage {
                call: "KdTreeBuilder::record_sphere_boxes",
                reason: format!(
                    "sphere boxes {first}..{} into {} floats",
                    first + n,
                    boxes.len()
                ),
            });
        }
        if n == 0 {
            return Ok(());
        }
        rec.scope("kdtree.sphere_boxes", |rec| {
            let groups = rec.groups_1d(n as u64, WORKGROUP);
            rec.dispatch(
                &self.k.sphere_boxes,
                groups,
                &[spheres, boxes],
                &[n as u32, first as u32],
            );
        });
        Ok(())
    }

    fn record_source(
        &self,
        rec: &mut Recorder,
        input: Source,
        n: usize,
        params: &SahParams,
        s: &BuildScratch,
        out: &BuildOutput,
    ) -> Result<()> {
        if !(n >= 1 && n <= s.max_prims && input.floats_per_prim() * n <= input.buffer().len()) {
            return Err(GpuError::Usage {
                call: "KdTreeBuilder::record_build",
                reason: format!("build of {n} {}", input.what()),
            });
        }
        self.record_phase_one(rec, input, n, s);
        let depth_limit = params.depth_limit(n);
        rec.scope("kdtree.phase2", |rec| {
            for depth in 0..=depth_limit {
                let (cur, next) = ((depth % 2) as usize, ((depth + 1) % 2) as usize);
                rec.scope("kdtree.level", |rec| {
                    self.record_level(rec, params, depth_limit, s, cur, next, out)
                });
            }
        });
        Ok(())
    }

    fn record_phase_one(&self, rec: &mut Recorder, input: Source, n: usize, s: &BuildScratch) {
        let k = &self.k;
        rec.scope("kdtree.phase1", |rec| {
            rec.scope("kdtree.boxes", |rec| {
                let groups = rec.groups_1d(n as u64, WORKGROUP);
                let kernel = match input {
                    Source::Triangles(_) => &k.boxes,
                    Source::Boxes(_) => &k.input_boxes,
                };
                let b: [&dyn BufferArg; 7] = [
                    input.buffer(),
                    &s.prim_min[0],
                    &s.prim_min[1],
                    &s.prim_min[2],
                    &s.prim_max[0],
                    &s.prim_max[1],
                    &s.prim_max[2],
                ];
                rec.dispatch(kernel, groups, &b, &(n as u32));
            });
            rec.compute_to_compute();
            rec.scope("kdtree.bounds", |rec| {
                for a in 0..3 {
                    self.reduce.record_min_f32(
                        rec,
                        &s.prim_min[a],
                        n as u32,
                        &s.reduce,
                        &s.bounds[a],
                    );
                    rec.compute_to_compute();
                    self.reduce.record_max_f32(
                        rec,
                        &s.prim_max[a],
                        n as u32,
                        &s.reduce,
                        &s.bounds[3 + a],
                    );
                    rec.compute_to_compute();
                }
            });
            for (a, ev) in s.events[0].iter().enumerate() {
                rec.scope("kdtree.events", |rec| {
                    let groups = rec.groups_1d(2 * n as u64, WORKGROUP);
                    rec.dispatch(
                        &k.event_keys,
                        groups,
                        &[&s.prim_min[a], &s.prim_max[a], &s.keys, &s.values],
                        &(n as u32),
                    );
                    rec.compute_to_compute();
                    self.sort
                        .record_f32(rec, &s.keys, &s.values, 2 * n, &s.sort);
                    rec.compute_to_compute();
                    let groups = rec.groups_1d((2 * n).div_ceil(4) as u64, WORKGROUP);
                    let mut b: Vec<&dyn BufferArg> = vec![
                        &s.keys,
                        &s.values,
                        &s.prim_min[0],
                        &s.prim_min[1],
                        &s.prim_min[2],
                        &s.prim_max[0],
                        &s.prim_max[1],
                        &s.prim_max[2],
                    ];
                    b.extend(ev.record_args());
                    rec.dispatch(&k.event_gather, groups, &b, &(n as u32));
                    // The next axis reuses keys and values.
                    rec.compute_to_compute();
                });
            }
            let l = &s.levels[0];
            let b: [&dyn BufferArg; 11] = [
                &s.state,
                &s.bounds[0],
                &s.bounds[1],
                &s.bounds[2],
                &s.bounds[3],
                &s.bounds[4],
                &s.bounds[5],
                &l.node_box,
                &l.node_range,
                &l.offsets,
                &s.seg_count,
            ];
            rec.dispatch(&k.init, [1, 1, 1], &b, &(n as u32));
            rec.compute_to_indirect();
        });
    }

    #[allow(clippy::too_many_arguments, reason = "one level of the recorded loop")]
    #[allow(
        clippy::needless_range_loop,
        reason = "the axis indexes several parallel lists"
    )]
    fn record_level(
        &self,
        rec: &mut Recorder,
        params: &SahParams,
        depth_limit: u32,
        s: &BuildScratch,
        cur: usize,
        next: usize,
        out: &BuildOutput,
    ) {
        let k = &self.k;
        let (ev, nev) = (&s.events[cur], &s.events[next]);
        let (lv, nlv) = (&s.levels[cur], &s.levels[next]);
        let e = ev[0].capacity;
        let m = s.capacity.nodes_per_level;
        let refs = GpuCount {
            counts: &s.state,
            index: ST_REFS,
            mul: 2,
            div: 1,
        };
        let nodes = GpuCount {
            counts: &s.state,
            index: ST_NODES,
            mul: 1,
            div: 1,
        };
        let ev_args = 4 * ST_EVENT_ARGS;
        let node_args = 4 * ST_NODE_ARGS;

        rec.scope("kdtree.split_costs", |rec| {
            for a in 0..3 {
                if let Some((wide, scratch)) = &s.wide_flags {
                    let b: [&dyn BufferArg; 3] = [&s.state, &ev[a].kind, wide];
                    rec.dispatch_indirect(&k.widen_flags, &s.state, ev_args, &b, &());
                    rec.compute_to_compute();
                    self.scan.record_counted(
                        rec,
                        wide,
                        &s.starts[a],
                        e,
                        refs,
                        ScanOp::Exclusive,
                        scratch,
                    );
                } else {
                    self.flag_scan.record_counted(
                        rec,
                        &ev[a].kind,
                        &s.starts[a],
                        e,
                        refs,
                        ScanOp::Exclusive,
                        &s.flag_scratch,
                    );
                }
                rec.compute_to_compute();
            }
            let push = SahPush {
                trav: params.traversal_cost,
                isect: params.intersection_cost,
                bonus: params.empty_bonus,
            };
            let b: [&dyn BufferArg; 15] = [
                &s.state,
                &lv.node_box,
                &lv.node_range,
                &ev[0].plane,
                &ev[1].plane,
                &ev[2].plane,
                &ev[0].kind,
                &ev[1].kind,
                &ev[2].kind,
                &ev[0].node,
                &s.starts[0],
                &s.starts[1],
                &s.starts[2],
                &s.cost,
                &s.axis,
            ];
            rec.dispatch_indirect(&k.split_costs, &s.state, ev_args, &b, &push);
            rec.compute_to_compute();
        });
        rec.scope("kdtree.best_split", |rec| {
            self.segmented.record(
                rec,
                self.segmented_mode,
                &s.cost,
                &lv.offsets,
                &s.seg_count,
                m as u32,
                &s.seg_scratch,
                &s.best,
            );
            rec.compute_to_compute();
        });
        rec.scope("kdtree.nodes", |rec| {
            let push = DecidePush {
                isect: params.intersection_cost,
                max_leaf_prims: params.max_leaf_prims,
                depth_limit,
                sah_leaf_test: u32::from(params.sah_leaf_test),
            };
            let b: [&dyn BufferArg; 11] = [
                &s.state,
                &lv.node_box,
                &lv.node_range,
                &s.best,
                &s.axis,
                &ev[0].plane,
                &ev[1].plane,
                &ev[2].plane,
                &s.node_split,
                &s.inner_flag,
                &s.leaf_count,
            ];
            rec.dispatch_indirect(&k.decide, &s.state, node_args, &b, &push);
            rec.compute_to_compute();
            self.scan.record_counted(
                rec,
                &s.inner_flag,
                &s.inner_before,
                m,
                nodes,
                ScanOp::Exclusive,
                &s.inner_scratch,
            );
            self.scan.record_counted(
                rec,
                &s.leaf_count,
                &s.leaf_before,
                m,
                nodes,
                ScanOp::Exclusive,
                &s.leaf_scratch,
            );
            rec.compute_to_compute();
            let b: [&dyn BufferArg; 7] = [
                &s.state,
                &lv.node_range,
                &s.node_split,
                &s.inner_before,
                &s.leaf_before,
                &out.nodes[0],
                &out.nodes[1],
            ];
            let push = [out.node_capacity() as u32, out.nodes[0].len() as u32];
            rec.dispatch_indirect(&k.write_nodes, &s.state, node_args, &b, &push);
            let b: [&dyn BufferArg; 9] = [
                &s.state,
                &lv.node_range,
                &s.node_split,
                &s.leaf_before,
                &ev[0].kind,
                &ev[0].node,
                &ev[0].prim,
                &s.starts[0],
                &out.prim_refs,
            ];
            rec.dispatch_indirect(
                &k.leaves,
                &s.state,
                ev_args,
                &b,
                &(out.prim_refs.len() as u32),
            );
        });
        rec.scope("kdtree.clip_partition", |rec| {
            let slots = GpuCount {
                counts: &s.state,
                index: ST_REFS,
                mul: 4,
                div: 1,
            };
            for a in 0..3 {
                let mut b: Vec<&dyn BufferArg> =
                    vec![&s.state, &lv.node_range, &s.node_split, &ev[a].node];
                b.extend(ev[a].box_args());
                b.push(&s.slots);
                if let Some(t) = &s.slot_records {
                    b.extend([
                        &s.inner_before as &dyn BufferArg,
                        &ev[a].plane,
                        &ev[a].kind,
                        &ev[a].prim,
                    ]);
                    b.extend(t.record_args());
                }
                rec.scope("kdtree.classify", |rec| {
                    rec.dispatch_indirect(&k.classify, &s.state, ev_args, &b, &())
                });
                rec.compute_to_compute();
                self.flag_scan.record_counted(
                    rec,
                    &s.slots,
                    &s.slot_offsets,
                    2 * e,
                    slots,
                    ScanOp::Exclusive,
                    &s.slot_scratch,
                );
                rec.compute_to_compute();
                let mut b: Vec<&dyn BufferArg> = match &s.slot_records {
                    None => {
                        let mut b: Vec<&dyn BufferArg> = vec![
                            &s.state,
                            &lv.node_range,
                            &s.node_split,
                            &s.inner_before,
                            &s.slot_offsets,
                        ];
                        b.extend(ev[a].record_args());
                        b
                    }
                    Some(t) => {
                        let mut b: Vec<&dyn BufferArg> = vec![
                            &s.state,
                            &lv.node_range,
                            &s.node_split,
                            &ev[a].node,
                            &s.slot_offsets,
                            &s.slots,
                        ];
                        b.extend(t.record_args());
                        b
                    }
                };
                b.extend(nev[a].record_args());
                rec.scope("kdtree.scatter", |rec| {
                    rec.dispatch_indirect(&k.scatter, &s.state, ev_args, &b, &(e as u32))
                });
                if a == 0 {
                    let b: [&dyn BufferArg; 10] = [
                        &s.state,
                        &lv.node_box,
                        &lv.node_range,
                        &s.node_split,
                        &s.inner_before,
                        &s.slot_offsets,
                        &s.slot_scratch.total,
                        &nlv.node_box,
                        &nlv.node_range,
                        &nlv.offsets,
                    ];
                    rec.scope("kdtree.children", |rec| {
                        rec.dispatch_indirect(&k.children, &s.state, node_args, &b, &(m as u32))
                    });
                }
                // The next axis rewrites the slots and their offsets.
                rec.compute_to_compute();
            }
        });
        let push = AdvancePush {
            ref_capacity: s.capacity.refs_per_level as u32,
            level_node_capacity: m as u32,
            node_capacity: out.node_capacity() as u32,
            out_ref_capacity: out.prim_refs.len() as u32,
        };
        let b: [&dyn BufferArg; 6] = [
            &s.state,
            &s.slot_scratch.total,
            &s.inner_scratch.total,
            &s.leaf_scratch.total,
            &s.seg_count,
            &nlv.offsets,
        ];
        rec.dispatch(&k.advance, [1, 1, 1], &b, &push);
        rec.compute_to_indirect();
    }

    /// Records `accel.kdtree_finish` after a recorded build of `counts[0]` primitives (or
    /// none): the scene constants (`SceneInfo`: root box and `counts` = primitives,
    /// triangles, spheres, has-motion, box primitives) into `info`, the build's report (nodes, references,
    /// overflow, references needed) into `built`, and an empty root leaf into `nodes` when
    /// the build overflowed or had no primitives. The caller orders the build before.
    pub fn record_finish(
        &self,
        rec: &mut Recorder,
        s: &BuildScratch,
        nodes: &Buffer<KdNode>,
        info: &dyn BufferArg,
        built: &Buffer<u32>,
        counts: [u32; 5],
    ) {
        let b: [&dyn BufferArg; 10] = [
            &s.state,
            &s.bounds[0],
            &s.bounds[1],
            &s.bounds[2],
            &s.bounds[3],
            &s.bounds[4],
            &s.bounds[5],
            nodes,
            info,
            built,
        ];
        rec.scope("kdtree.finish", |rec| {
            rec.dispatch(&self.k.finish, [1, 1, 1], &b, &counts)
        });
    }

    /// The state after a recorded build has executed.
    pub fn read_outcome(&self, s: &BuildScratch) -> Result<BuildOutcome> {
        let st = s.state.download()?;
        Ok(BuildOutcome {
            nodes: st[ST_NODE_BASE],
            refs: st[ST_REF_BASE],
            levels: st[ST_LEVELS],
            overflow: st[ST_OVERFLOW] != 0,
            needed_refs: st[ST_NEED_REFS],
        })
    }

    /// Convenience: uploads `triangles`, builds (retrying with larger buffers on overflow),
    /// waits and reads the tree back, with the GPU profile of the successful attempt.
    pub fn build(
        &self,
        ctx: &Context,
        triangles: &[[Vec3; 3]],
        params: &SahParams,
    ) -> Result<(KdTree, Profile)> {
        self.build_input(ctx, BuildInput::Triangles(triangles), params)
    }

    /// [`KdTreeBuilder::build`] over primitive boxes (spheres, moving primitives, a mix:
    /// e.g. [`super::breadth_first::prim_box`] of every triangle followed by
    /// [`super::breadth_first::sphere_box`] of every sphere). Primitive `i` of the tree is
    /// `boxes[i]`; the tree equals [`super::breadth_first::build_boxes`] bit for bit. A box that is
    /// not finite or has min > max on an axis is an error.
    pub fn build_boxes(
        &self,
        ctx: &Context,
        boxes: &[Aabb],
        params: &SahParams,
    ) -> Result<(KdTree, Profile)> {
        self.build_input(ctx, BuildInput::Boxes(boxes), params)
    }

    /// [`KdTreeBuilder::build`] or [`KdTreeBuilder::build_boxes`], by input.
    pub fn build_input(
        &self,
        ctx: &Context,
        input: BuildInput,
        params: &SahParams,
    ) -> Result<(KdTree, Profile)> {
        let capacity = BuildCapacity::for_primitives(input.len());
        let r = self.build_input_from(ctx, input, params, capacity)?;
        Ok((r.tree, r.profile))
    }

    /// [`KdTreeBuilder::build`] starting from `capacity` (tests force a tiny one to exercise
    /// the overflow path).
    pub fn build_from(
        &self,
        ctx: &Context,
        triangles: &[[Vec3; 3]],
        params: &SahParams,
        capacity: BuildCapacity,
    ) -> Result<BuildResult> {
        self.build_input_from(ctx, BuildInput::Triangles(triangles), params, capacity)
    }

    /// [`KdTreeBuilder::build_input`] starting from `capacity`.
    pub fn build_input_from(
        &self,
        ctx: &Context,
        input: BuildInput,
        params: &SahParams,
        mut capacity: BuildCapacity,
    ) -> Result<BuildResult> {
        input.check()?;
        let n = input.len();
        let bounds = super::breadth_first::bounds_of(&input.boxes());
        if n == 0 {
            let tree = KdTree {
                nodes: vec![KdNode::leaf(0, 0)],
                prim_refs: Vec::new(),
                bounds: Aabb::EMPTY,
                primitives: 0,
            };
            return Ok(BuildResult {
                tree,
                profile: Profile::default(),
                attempts: 0,
                capacity,
                levels: 1,
            });
        }
        let limit = ctx.info().max_storage_buffer_range;
        // The most this device and builder take: the first level alone holds every primitive
        // once, so an input past it is refused before any GPU work.
        let most = self.fit_capacity(ctx, BuildCapacity::with_refs(n, usize::MAX / 8));
        let out_of_capacity = |needed: usize| GpuError::Kernel {
            kernel: "accel.kdtree",
            reason: format!(
                "the kd-tree of {n} primitives needs {needed} references in one level, more \
                 than this device takes ({} per level: its maxStorageBufferRange of {limit} \
                 bytes per buffer and the segmented argmin's limits); build fewer primitives \
                 per tree (e.g. a scene in pieces) or allow larger leaves \
                 (SahParams::max_leaf_prims)",
                most.refs_per_level
            ),
        };
        if n > most.refs_per_level {
            return Err(out_of_capacity(n));
        }
        capacity = self.fit_capacity(ctx, capacity);
        let uploaded = Uploaded::new(ctx, input)?;
        for attempt in 1..=8 {
            let scratch = self.scratch(ctx, n, capacity)?;
            let out = self.output(ctx, &capacity)?;
            let mut rec = Recorder::new(ctx)?;
            self.record_source(&mut rec, uploaded.source(), n, params, &scratch, &out)?;
            rec.compute_to_transfer();
            let profile = rec.submit_and_wait()?;
            let outcome = self.read_outcome(&scratch)?;
            if outcome.overflow {
                // A level past the device's most is final: no larger attempt can hold it.
                let needed = outcome.needed_refs as usize;
                if needed > most.refs_per_level || capacity == most {
                    return Err(out_of_capacity(needed));
                }
                let refs = needed.max(2 * capacity.refs_per_level);
                capacity = self.fit_capacity(ctx, BuildCapacity::with_refs(n, refs));
                continue;
            }
            let nodes = out.download_nodes(outcome.nodes as usize)?;
            let mut prim_refs = out.prim_refs.download()?;
            prim_refs.truncate(outcome.refs as usize);
            let tree = KdTree {
                nodes,
                prim_refs,
                bounds,
                primitives: n as u32,
            };
            return Ok(BuildResult {
                tree,
                profile,
                attempts: attempt,
                capacity,
                levels: outcome.levels,
            });
        }
        Err(GpuError::Kernel {
            kernel: "accel.kdtree",
            reason: format!("still out of capacity after 8 attempts ({capacity:?})"),
        })
    }

    /// Times a build at `capacity` (which must suffice: take it from a
    /// [`KdTreeBuilder::build_from`] result) the way a renderer rebuilding every frame sees
    /// it: buffers allocated once and touched by a first, untimed build. Returns the
    /// profile of the second build only (lavapipe's first touch of fresh memory costs page
    /// faults that are not the builder's).
    pub fn timed_build(
        &self,
        ctx: &Context,
        triangles: &[[Vec3; 3]],
        params: &SahParams,
        capacity: BuildCapacity,
    ) -> Result<Profile> {
        self.timed_build_input(ctx, BuildInput::Triangles(triangles), params, capacity)
    }

    /// [`KdTreeBuilder::timed_build`] for any input (at least one primitive).
    pub fn timed_build_input(
        &self,
        ctx: &Context,
        input: BuildInput,
        params: &SahParams,
        capacity: BuildCapacity,
    ) -> Result<Profile> {
        input.check()?;
        let n = input.len();
        if n == 0 {
            return Ok(Profile::default());
        }
        let capacity = self.fit_capacity(ctx, capacity);
        let uploaded = Uploaded::new(ctx, input)?;
        let scratch = self.scratch(ctx, n, capacity)?;
        let out = self.output(ctx, &capacity)?;
        let mut rec = Recorder::new(ctx)?;
        rec.scope("kdtree.warmup", |rec| {
            self.record_source(rec, uploaded.source(), n, params, &scratch, &out)
        })?;
        rec.compute_to_compute();
        rec.scope("kdtree.timed", |rec| {
            self.record_source(rec, uploaded.source(), n, params, &scratch, &out)
        })?;
        rec.compute_to_transfer();
        Ok(rec.submit_and_wait()?.subtree("kdtree.timed"))
    }

    /// Phase I alone, for the twin comparison: the scene box and the sorted event lists.
    pub fn phase_one(&self, ctx: &Context, triangles: &[[Vec3; 3]]) -> Result<(Aabb, [Events; 3])> {
        self.phase_one_input(ctx, BuildInput::Triangles(triangles))
    }

    /// [`KdTreeBuilder::phase_one`] for any input (at least one primitive).
    pub fn phase_one_input(&self, ctx: &Context, input: BuildInput) -> Result<(Aabb, [Events; 3])> {
        input.check()?;
        let n = input.len();
        if n == 0 {
            return Err(GpuError::Kernel {
                kernel: "accel.kdtree",
                reason: "phase one of zero primitives".into(),
            });
        }
        let uploaded = Uploaded::new(ctx, input)?;
        let capacity = self.fit_capacity(ctx, BuildCapacity::for_primitives(n));
        let scratch = self.scratch(ctx, n, capacity)?;
        let mut rec = Recorder::new(ctx)?;
        self.record_phase_one(&mut rec, uploaded.source(), n, &scratch);
        rec.compute_to_transfer();
        rec.submit_and_wait()?;
        let v = |i: usize| scratch.bounds[i].download().map(|b| b[0]);
        let bounds = Aabb {
            min: Vec3::new(v(0)?, v(1)?, v(2)?),
            max: Vec3::new(v(3)?, v(4)?, v(5)?),
        };
        let ev = &scratch.events[0];
        Ok((
            bounds,
            [
                ev[0].download(2 * n)?,
                ev[1].download(2 * n)?,
                ev[2].download(2 * n)?,
            ],
        ))
    }
}

/// What a host-side build reads: triangles (world space) or primitive boxes.
#[derive(Clone, Copy, Debug)]
pub enum BuildInput<'a> {
    /// Triangles, three world-space vertices each.
    Triangles(&'a [[Vec3; 3]]),
    /// One box per primitive (spheres, moving primitives, any mix).
    Boxes(&'a [Aabb]),
}

impl BuildInput<'_> {
    /// Number of primitives.
    pub fn len(&self) -> usize {
        match self {
            Self::Triangles(t) => t.len(),
            Self::Boxes(b) => b.len(),
        }
    }

    /// Whether there are no primitives.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The primitive boxes, as Phase I computes them.
    pub fn boxes(&self) -> Vec<Aabb> {
        match self {
            Self::Triangles(t) => t.iter().map(super::breadth_first::prim_box).collect(),
            Self::Boxes(b) => b.to_vec(),
        }
    }

    /// Boxes must be finite with min ≤ max (triangles are checked by scene validation).
    fn check(&self) -> Result<()> {
        if let Self::Boxes(boxes) = self {
            if let Some((i, b)) = boxes.iter().enumerate().find(|(_, b)| {
                !(b.min.is_finite() && b.max.is_finite() && b.min.cmple(b.max).all())
            }) {
                return Err(GpuError::Kernel {
                    kernel: "accel.kdtree",
                    reason: format!(
                        "primitive box {i} is not a finite box with min <= max: min {:?}, max {:?}",
                        b.min, b.max
                    ),
                });
            }
        }
        Ok(())
    }
}

/// An input on the GPU, in the layout its Phase I kernel reads.
enum Uploaded {
    Triangles(Buffer<f32>),
    Boxes(Buffer<f32>),
}

impl Uploaded {
    fn new(ctx: &Context, input: BuildInput) -> Result<Self> {
        Ok(match input {
            BuildInput::Triangles(t) => {
                let flat: Vec<f32> = t
                    .iter()
                    .flat_map(|t| t.iter().flat_map(|p| p.to_array()))
                    .collect();
                Self::Triangles(Buffer::from_slice(ctx, "kdtree.triangles", &flat)?)
            }
            BuildInput::Boxes(b) => {
                let flat: Vec<f32> = b
                    .iter()
                    .flat_map(|b| b.min.to_array().into_iter().chain(b.max.to_array()))
                    .collect();
                Self::Boxes(Buffer::from_slice(ctx, "kdtree.boxes", &flat)?)
            }
        })
    }

    fn source(&self) -> Source<'_> {
        match self {
            Self::Triangles(b) => Source::Triangles(b),
            Self::Boxes(b) => Source::Boxes(b),
        }
    }
}

/// A recorded build's input buffer.
#[derive(Clone, Copy)]
enum Source<'a> {
    /// 9 floats per triangle.
    Triangles(&'a Buffer<f32>),
    /// 6 floats per box.
    Boxes(&'a Buffer<f32>),
}

impl<'a> Source<'a> {
    fn buffer(self) -> &'a Buffer<f32> {
        match self {
            Self::Triangles(b) | Self::Boxes(b) => b,
        }
    }

    fn floats_per_prim(self) -> usize {
        match self {
            Self::Triangles(_) => 9,
            Self::Boxes(_) => 6,
        }
    }

    fn what(self) -> &'static str {
        match self {
            Self::Triangles(_) => "triangles",
            Self::Boxes(_) => "boxes",
        }
    }
}
