//! SAH kd-trees: one flat node layout in BFS order shared by every builder and by the GLSL
//! traversal, the SAH parameters, statistics and a structural validator.
//!
//! Builders take triangles (world space) or primitive boxes (spheres, moving primitives, a
//! mix: [`gpu::KdTreeBuilder::build_boxes`], [`breadth_first::build_boxes`]) and return a
//! [`KdTree`] whose primitive `i` is input `i`; they do not know what a material or a mesh
//! is.
//!
//! Node layout (16 bytes, std430; keep in sync with `glsl/include/vkrt/kdtree.glsl`):
//! - inner node: `kind` = split axis (0, 1, 2), `split` = plane position, children are
//!   `a` (below the plane) and `a + 1` (above), both stored after their parent (BFS order:
//!   all nodes of depth d come before those of depth d + 1);
//! - leaf: `kind` = [`LEAF`], primitives `prim_refs[a .. a + b]` (b may be 0: empty leaf).

pub mod breadth_first;
pub(crate) mod device;
pub mod full_clip;
pub mod gpu;
pub mod report;
pub mod stats;
pub mod validate;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

pub use crate::scene::Aabb;

/// `KdNode::kind` of a leaf.
pub const LEAF: u32 = 3;

/// One node. See the module docs for the layout.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct KdNode {
    /// Split plane position (inner nodes); 0 for leaves.
    pub split: f32,
    /// Split axis 0..=2, or [`LEAF`].
    pub kind: u32,
    /// Inner: index of the child below the plane (the other is `a + 1`). Leaf: first index
    /// into `prim_refs`.
    pub a: u32,
    /// Inner: 0. Leaf: number of primitive references.
    pub b: u32,
}

impl KdNode {
    /// An inner node splitting at `split` on `axis`; its children are `first_child` (below)
    /// and `first_child + 1` (above).
    pub fn inner(axis: u32, split: f32, first_child: u32) -> Self {
        Self {
            split,
            kind: axis,
            a: first_child,
            b: 0,
        }
    }

    /// A leaf of the `count` references from `first_ref` on in `prim_refs`.
    pub fn leaf(first_ref: u32, count: u32) -> Self {
        Self {
            split: 0.0,
            kind: LEAF,
            a: first_ref,
            b: count,
        }
    }

    /// Whether this is a leaf (`kind == LEAF`).
    pub fn is_leaf(&self) -> bool {
        self.kind == LEAF
    }
}

/// A built kd-tree: nodes in BFS order (root at 0), the leaves' primitive references, and
/// the root box.
#[derive(Clone, Debug, PartialEq)]
pub struct KdTree {
    /// The nodes in BFS order, root at 0.
    pub nodes: Vec<KdNode>,
    /// Primitive ids; each leaf's references are contiguous.
    pub prim_refs: Vec<u32>,
    /// Box of every primitive (empty when there are none).
    pub bounds: Aabb,
    /// Number of input primitives.
    pub primitives: u32,
}

/// SAH parameters and termination rules (pbrt's and Kolodzey's defaults).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SahParams {
    /// Cost of one traversal step (C_trav).
    pub traversal_cost: f32,
    /// Cost of one primitive intersection (c_obj).
    pub intersection_cost: f32,
    /// Factor on the SAH when one side of a split is empty (Kolodzey 2014: λ = 0.8).
    pub empty_bonus: f32,
    /// Maximum depth; `None` = `8 + 1.3·log2(N)` (pbrt).
    pub max_depth: Option<u32>,
    /// A node with at most this many primitives becomes a leaf.
    pub max_leaf_prims: u32,
    /// Make a leaf when the best split costs more than intersecting everything
    /// (Kolodzey 2014 lacked this test; switch it off to reproduce that build).
    pub sah_leaf_test: bool,
}

impl Default for SahParams {
    fn default() -> Self {
        Self {
            traversal_cost: 1.0,
            intersection_cost: 1.5,
            empty_bonus: 0.8,
            max_depth: None,
            max_leaf_prims: 2,
            sah_leaf_test: true,
        }
    }
}

impl SahParams {
    /// The depth limit for `n` primitives: `max_depth`, else `round(8 + 1.3·floor(log2 n))`.
    pub fn depth_limit(&self, n: usize) -> u32 {
        self.max_depth.unwrap_or_else(|| {
            let log = if n <= 1 {
                0
            } else {
                usize::BITS - 1 - n.leading_zeros()
            };
            (8.0 + 1.3 * log as f32).round() as u32
        })
    }
}

/// The box of a triangle.
pub fn triangle_bounds(t: &[Vec3; 3]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for p in t {
        b.grow(*p);
    }
    b
}

/// The surface area of a box (0 for an empty box).
pub fn surface_area(b: &Aabb) -> f32 {
    if b.is_empty() {
        return 0.0;
    }
    let d = b.max - b.min;
    2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
}
