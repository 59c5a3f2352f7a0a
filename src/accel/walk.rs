//! The structure kinds ([`AccelKind`]) and how kernels walk them: the BVH walks (stack,
//! bitstack, wide), the structure-and-walk pairs the tracing kernels specialise on
//! (`ACCEL_KIND` in `glsl/include/vkrt/traverse.glsl`), the pair `--accel` and `--traversal`
//! choose ([`AccelChoice`]), and how the walks read the nodes. Every conversion between them
//! is here: a kind's walk ([`AccelKind::walked`]), a walk's specialization constant
//! ([`AccelTraversal::spec`]) and the scene constants' walk word
//! ([`AccelTraversal::scene_walk`]).

use crate::accel::primitives::SceneInfo;
use crate::gpu::{vk, Context, Result, ShaderBlob, Spec};

/// How a BVH query walks the tree.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Traversal {
    /// Far children on a stack.
    #[default]
    Stack,
    /// No stack: parent links and a trail of one bit per level (Áfra & Szirmay-Kalos 2014).
    Bitstack,
    /// The 4-wide quantized nodes (Ylitie et al. 2017) with a stack: one node fetch decides
    /// four children ([`crate::accel::bvh::wide`]).
    Wide,
}

impl Traversal {
    /// `stack` or `bitstack` (the CLI's `--traversal`).
    pub fn name(self) -> &'static str {
        match self {
            Traversal::Stack => "stack",
            Traversal::Bitstack => "bitstack",
            Traversal::Wide => "wide",
        }
    }

    /// The nodes this walk reads, in words (`vkrt info`). The binary walks read the nodes
    /// every builder writes; the 4-wide walk reads nodes made from them after the build.
    /// Either way a leaf holds up to
    /// [`BvhParams::max_leaf_prims`](crate::accel::bvh::BvhParams::max_leaf_prims)
    /// references where the SAH says so: one triangle per leaf, the driver's shape, traced
    /// 1.16–1.39× slower than the 4-wide nodes on Mesa 26.1.6's lavapipe and 0.96–1.11×
    /// the binary walk's time on 25.0.7's (`cargo bench --bench leaf_layout`).
    pub fn node_layout(self) -> &'static str {
        match self {
            Traversal::Stack | Traversal::Bitstack => {
                "binary, both children's boxes as floats (Aila & Laine 2009), SAH-collapsed \
                 leaves of triangle references"
            }
            Traversal::Wide => {
                "4-wide, child boxes quantized to 8 bits per plane (Ylitie et al. 2017), made \
                 from the binary nodes after the build; SAH-collapsed leaves of triangle \
                 references"
            }
        }
    }

    /// Every walk, binary ones first.
    pub const ALL: [Traversal; 3] = [Traversal::Stack, Traversal::Bitstack, Traversal::Wide];

    /// The walk that traces fastest on `ctx`'s device, as measured: the 4-wide walk where
    /// [`DeviceInfo::wide_walks`](crate::gpu::DeviceInfo::wide_walks) says so, else the binary
    /// stack walk. Every walk finds the same hits bit for bit; the wide one costs a pass and
    /// a quarter of the nodes' memory after the build. `VKRT_TRAVERSAL=stack`, `bitstack` or
    /// `wide` overrides it.
    pub fn for_device(ctx: &Context) -> Self {
        match std::env::var("VKRT_TRAVERSAL").as_deref() {
            Ok("stack") => return Traversal::Stack,
            Ok("bitstack") => return Traversal::Bitstack,
            Ok("wide") => return Traversal::Wide,
            _ => {}
        }
        match ctx.info().wide_walks {
            true => Traversal::Wide,
            false => Traversal::Stack,
        }
    }
}

/// The structures vkrt builds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum AccelKind {
    /// Kolodzey's (2014) SAH kd-tree, built on the GPU.
    KdTree,
    /// Sochora's (2013) SAH BVH, built on the host's cores and uploaded.
    SahBvh,
    /// Karras's LBVH (2012), built on the GPU: the default (see
    /// [`AccelKind::EMBEDDING_DEFAULT`]).
    #[default]
    Lbvh,
    /// PLOC (Meister & Bittner 2018), built on the GPU.
    Ploc,
    /// The driver's own (`VK_KHR_acceleration_structure`), queried with `VK_KHR_ray_query`:
    /// the peer vkrt's structures are measured against, where the device has it.
    Driver,
}

impl AccelKind {
    /// The structures vkrt itself builds (every device runs them).
    pub const ALL: [AccelKind; 4] = [
        AccelKind::KdTree,
        AccelKind::SahBvh,
        AccelKind::Lbvh,
        AccelKind::Ploc,
    ];

    /// The kind a renderer embedding vkrt starts from: the LBVH, built on the device from the
    /// caller's buffers in a fixed number of passes, with no capacity to run out of (the
    /// kd-tree's reference budget may, and asks the caller to grow it) and a fraction of the
    /// kd-tree's memory per primitive. `AccelKind::default()` is the same. (The command line's
    /// default is the SAH BVH built on the host's cores, which a renderer's frame cannot
    /// wait for.)
    pub const EMBEDDING_DEFAULT: AccelKind = AccelKind::Lbvh;

    /// The CLI name (`--accel`).
    pub fn name(self) -> &'static str {
        match self {
            AccelKind::KdTree => "kdtree",
            AccelKind::SahBvh => "sah-bvh",
            AccelKind::Lbvh => "lbvh",
            AccelKind::Ploc => "ploc",
            AccelKind::Driver => "driver",
        }
    }

    /// How kernels walk this kind (`traversal` applies to vkrt's BVHs).
    pub fn walked(self, traversal: Traversal) -> AccelTraversal {
        match self {
            AccelKind::KdTree => AccelTraversal::KdTree,
            AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc => AccelTraversal::Bvh(traversal),
            AccelKind::Driver => AccelTraversal::RayQuery,
        }
    }

    /// [`AccelKind::ALL`], and the driver's where `ctx`'s device has ray query.
    pub fn available(ctx: &Context) -> Vec<AccelKind> {
        let mut kinds = Self::ALL.to_vec();
        if ctx.info().features.ray_query {
            kinds.push(AccelKind::Driver);
        }
        kinds
    }

    /// Whether one walk serves it (no `--traversal` choice).
    fn single_walk(self) -> bool {
        matches!(self, AccelKind::KdTree | AccelKind::Driver)
    }
}

/// What `--accel` and `--traversal` choose: a structure and how kernels walk it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
pub struct AccelChoice {
    /// The structure built.
    pub kind: AccelKind,
    /// How a BVH is walked (ignored for a kd-tree and the driver's structure).
    pub walk: Traversal,
    /// What the driver's builder optimises for (the driver's structure only).
    pub prefer: Prefer,
}

impl AccelChoice {
    /// `kind` walked by `walk` (the default walk for kinds with one walk: the kd-tree and
    /// the driver's), with the driver's default preference.
    pub fn new(kind: AccelKind, walk: Traversal) -> Self {
        let walk = if kind.single_walk() {
            Traversal::default()
        } else {
            walk
        };
        Self {
            kind,
            walk,
            prefer: Prefer::default(),
        }
    }

    /// The driver's structure built with `prefer`.
    pub fn driver(prefer: Prefer) -> Self {
        Self {
            prefer,
            ..Self::new(AccelKind::Driver, Traversal::default())
        }
    }

    /// The walk the kernels compile in (`ACCEL_KIND`).
    pub fn traversal(self) -> AccelTraversal {
        self.kind.walked(self.walk)
    }

    /// Every structure vkrt builds with every walk, for suites and benchmarks.
    pub fn all() -> Vec<Self> {
        Self::every(AccelKind::ALL.to_vec())
    }

    /// [`AccelChoice::all`], and the driver's structure where `ctx`'s device has it.
    pub fn all_on(ctx: &Context) -> Vec<Self> {
        Self::every(AccelKind::available(ctx))
    }

    fn every(kinds: Vec<AccelKind>) -> Vec<Self> {
        kinds
            .into_iter()
            .flat_map(|kind| {
                let walks: &[Traversal] = if kind.single_walk() {
                    &[Traversal::Stack]
                } else {
                    &Traversal::ALL
                };
                walks.iter().map(move |&w| Self::new(kind, w))
            })
            .collect()
    }

    /// `kdtree`, `sah-bvh/stack`, `lbvh/bitstack`, ...
    pub fn label(self) -> String {
        match (self.kind, self.prefer) {
            (AccelKind::Driver, Prefer::FastBuild) => format!("driver/{}", self.prefer.name()),
            (AccelKind::KdTree | AccelKind::Driver, _) => self.kind.name().to_string(),
            _ => format!("{}/{}", self.kind.name(), self.walk.name()),
        }
    }
}

/// Which structure a [`GpuGeometry`](crate::accel::gpu_geometry::GpuGeometry) holds, and how
/// a kernel walks it (the `ACCEL_KIND` specialization constant of `traverse.glsl`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum AccelTraversal {
    /// A kd-tree (`ACCEL_KIND` 0).
    #[default]
    KdTree,
    /// A BVH, walked as the [`Traversal`] says.
    Bvh(Traversal),
    /// The driver's structure, through its ray query (the `query` kernel variants).
    RayQuery,
}

impl AccelTraversal {
    /// The `ACCEL_KIND` specialization constant (id 20) of kernels that trace.
    pub fn spec(self) -> u32 {
        match self {
            AccelTraversal::KdTree => 0,
            AccelTraversal::Bvh(Traversal::Stack) => 1,
            AccelTraversal::Bvh(Traversal::Bitstack) => 2,
            AccelTraversal::RayQuery => 3,
            AccelTraversal::Bvh(Traversal::Wide) => 4,
        }
    }

    /// The walk word of the scene constants (`SceneInfo::walk`): how the shader library
    /// walks a structure this walk serves (a BVH's binary walks read the same nodes).
    pub fn scene_walk(self) -> u32 {
        match self {
            AccelTraversal::KdTree => SceneInfo::WALK_KDTREE,
            AccelTraversal::Bvh(Traversal::Wide) => SceneInfo::WALK_BVH_WIDE,
            AccelTraversal::Bvh(_) => SceneInfo::WALK_BVH,
            AccelTraversal::RayQuery => SceneInfo::WALK_RAY_QUERY,
        }
    }

    /// Every structure and walk, for suites and benchmarks.
    pub const ALL: [AccelTraversal; 4] = [
        AccelTraversal::KdTree,
        AccelTraversal::Bvh(Traversal::Stack),
        AccelTraversal::Bvh(Traversal::Bitstack),
        AccelTraversal::Bvh(Traversal::Wide),
    ];

    /// `kdtree`, `sah-bvh/stack`, `sah-bvh/bitstack` or `sah-bvh/wide`.
    pub fn label(self) -> &'static str {
        match self {
            AccelTraversal::KdTree => "kdtree",
            AccelTraversal::Bvh(Traversal::Stack) => "sah-bvh/stack",
            AccelTraversal::Bvh(Traversal::Bitstack) => "sah-bvh/bitstack",
            AccelTraversal::Bvh(Traversal::Wide) => "sah-bvh/wide",
            AccelTraversal::RayQuery => "driver",
        }
    }

    /// `Ok` where the device can run this walk: the driver's needs its ray query (else the
    /// error naming the extensions; its kernels cannot even be created without it).
    pub fn require(self, ctx: &Context) -> Result<()> {
        match self {
            AccelTraversal::RayQuery => crate::gpu::require_ray_query(ctx),
            _ => Ok(()),
        }
    }

    /// The structure family this walk serves (kd-tree, BVH, the driver's).
    pub(crate) fn family(self) -> u32 {
        match self {
            AccelTraversal::KdTree => 0,
            AccelTraversal::Bvh(_) => 1,
            AccelTraversal::RayQuery => 2,
        }
    }

    /// The kernel variant (of `render.trace`, `render.extend`, `render.shadow`: `[exact,
    /// float, query, exact_texel, float_texel]`) this walk runs: `query` for the driver's,
    /// else `exact` or `float`, reading nodes as `nodes` says.
    pub fn variant(
        self,
        exact: bool,
        nodes: NodeAccess,
        [exact_blob, float, query, exact_texel, float_texel]: [&'static ShaderBlob; 5],
    ) -> &'static ShaderBlob {
        match (self, exact, nodes) {
            (AccelTraversal::RayQuery, _, _) => query,
            (_, true, NodeAccess::Storage) => exact_blob,
            (_, false, NodeAccess::Storage) => float,
            (_, true, NodeAccess::Texel) => exact_texel,
            (_, false, NodeAccess::Texel) => float_texel,
        }
    }

    /// `spec` for `blob`, this walk's variant: the `query` variants take fewer constants.
    pub fn spec_for(self, spec: Spec, blob: &ShaderBlob) -> Spec {
        match self {
            AccelTraversal::RayQuery => spec.declared_in(blob),
            _ => spec,
        }
    }
}

/// How the walks read the structure's nodes: both give the same hits bit for bit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum NodeAccess {
    /// As a storage buffer (on Mesa < 25.1's lavapipe: a loop over the lanes with a bounds
    /// check each, for every load at a divergent offset).
    Storage,
    /// Through a uniform texel buffer (RGBA32UI texels), the sampler path: on lavapipe a
    /// branch-free gather.
    Texel,
}

impl NodeAccess {
    /// The device's: texel buffers where they measured faster
    /// ([`DeviceInfo::texel_walks`](crate::gpu::DeviceInfo::texel_walks)) and a view holds
    /// as many bytes as a storage binding (`maxTexelBufferElements` × 16 ≥
    /// `maxStorageBufferRange`, so every structure that can be bound can be viewed), else
    /// storage buffers. `VKRT_NODE_ACCESS=storage` or `texel` overrides it (for measuring
    /// one against the other).
    pub fn for_device(ctx: &Context) -> Self {
        match std::env::var("VKRT_NODE_ACCESS").as_deref() {
            Ok("storage") => return NodeAccess::Storage,
            Ok("texel") => return NodeAccess::Texel,
            _ => {}
        }
        let info = ctx.info();
        if info.texel_walks
            && u64::from(info.max_texel_buffer_elements) * 16 >= info.max_storage_buffer_range
        {
            NodeAccess::Texel
        } else {
            NodeAccess::Storage
        }
    }

    /// `storage` or `texel`.
    pub fn name(self) -> &'static str {
        match self {
            NodeAccess::Storage => "storage",
            NodeAccess::Texel => "texel",
        }
    }
}

/// What the driver's builder optimises for (`VkBuildAccelerationStructureFlagsKHR`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Prefer {
    /// A slower build of a structure that traces faster.
    #[default]
    FastTrace,
    /// A quicker build, for structures rebuilt often.
    FastBuild,
}

impl Prefer {
    /// The build flags, with `ALLOW_UPDATE` where the structure will be refit.
    pub(crate) fn flags(self, allow_update: bool) -> vk::BuildAccelerationStructureFlagsKHR {
        let prefer = match self {
            Prefer::FastTrace => vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
            Prefer::FastBuild => vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD,
        };
        if allow_update {
            prefer | vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE
        } else {
            prefer
        }
    }

    /// `fast-trace` or `fast-build`.
    pub fn name(self) -> &'static str {
        match self {
            Prefer::FastTrace => "fast-trace",
            Prefer::FastBuild => "fast-build",
        }
    }
}
