//! Which structure a kernel walks and how: the BVH walks (stack, bitstack, wide), the
//! structure-and-walk pairs the tracing kernels specialise on (`ACCEL_KIND` in
//! `glsl/include/vkrt/traverse.glsl`), and how they read the nodes. The choice belongs with
//! the structures: a structure's kind says which walks serve it.

use crate::gpu::{Context, Result, ShaderBlob, Spec};

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

    /// Every walk, binary ones first.
    pub const ALL: [Traversal; 3] = [Traversal::Stack, Traversal::Bitstack, Traversal::Wide];
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
