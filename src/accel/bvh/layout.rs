//! The BVH as the traversal reads it: binary nodes that hold both children's boxes (Aila &
//! Laine 2009: one node fetch decides both children), parent links for the stackless
//! bitstack traversal (Áfra & Szirmay-Kalos 2014), and the primitive references the leaves point into.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::scene::Aabb;

/// Index of no node: the root's parent, and the missing second child of a root that is a
/// single leaf.
pub const NO_NODE: u32 = u32::MAX;

/// The deepest tree the traversal walks (`VKRT_BVH_MAX_DEPTH` in `glsl/include/vkrt/bvh.glsl`: its
/// stack and its bit trail): the SAH builder stops at 64 levels, the LBVH's 63-bit codes and
/// index tie-breaks give at most 95, and PLOC adds at most one level per round.
pub const MAX_TRAVERSAL_DEPTH: u32 = 128;

/// The largest leaf the GPU walks take: a stack entry keeps a leaf's size in the low 8 bits
/// of its entry distance (`vkrt_stack_entry` in `glsl/include/vkrt/bvh.glsl`).
pub const MAX_WALK_LEAF: u32 = 255;

/// The distance a stack entry keeps: `t` with its low 8 bits cleared, so rounded down for
/// `t >= 0` (the GPU walks' `vkrt_stack_entry`). An entry is dropped at a pop only when this
/// lies beyond the closest hit, so the CPU twins visit what the GPU walks visit.
pub fn stack_entry_t(t: f32) -> f32 {
    f32::from_bits(t.to_bits() & !0xff)
}

/// One node, 64 bytes: child `a` and child `b`, each a box and either an interior node
/// (`count == 0`, `index` is its node) or a leaf (`count > 0` references from `index` on in
/// [`Bvh::refs`]). A missing child (`count == 0`, `index == NO_NODE`) has an empty box
/// (min = +inf, max = -inf), which no ray enters.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct BvhNode {
    /// Minimum corner of child `a`'s box.
    pub a_min: [f32; 3],
    /// Child `a`'s node (interior), first reference (leaf) or [`NO_NODE`] (missing).
    pub a_index: u32,
    /// Maximum corner of child `a`'s box.
    pub a_max: [f32; 3],
    /// Child `a`'s reference count: 0 for an interior or missing child.
    pub a_count: u32,
    /// Minimum corner of child `b`'s box.
    pub b_min: [f32; 3],
    /// Child `b`'s node (interior), first reference (leaf) or [`NO_NODE`] (missing).
    pub b_index: u32,
    /// Maximum corner of child `b`'s box.
    pub b_max: [f32; 3],
    /// Child `b`'s reference count: 0 for an interior or missing child.
    pub b_count: u32,
}

/// One child of a node, as the builder and the validators see it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Child {
    /// An interior node, by index into [`Bvh::nodes`].
    Node(u32),
    /// A leaf: `count` references from `first` on in [`Bvh::refs`].
    Leaf {
        /// Index of the leaf's first reference in [`Bvh::refs`].
        first: u32,
        /// Number of references (at least 1).
        count: u32,
    },
    /// A missing child (`count == 0`, `index == NO_NODE`, an empty box): the second child
    /// of a root that is a single leaf.
    None,
}

impl BvhNode {
    /// A node with two missing children (empty boxes).
    pub fn empty() -> Self {
        let (lo, hi) = (Aabb::EMPTY.min.to_array(), Aabb::EMPTY.max.to_array());
        Self {
            a_min: lo,
            a_index: NO_NODE,
            a_max: hi,
            a_count: 0,
            b_min: lo,
            b_index: NO_NODE,
            b_max: hi,
            b_count: 0,
        }
    }

    /// Child 0 (`a`) or 1 (`b`) with its box.
    pub fn child(&self, which: usize) -> (Aabb, Child) {
        let (min, max, index, count) = if which == 0 {
            (self.a_min, self.a_max, self.a_index, self.a_count)
        } else {
            (self.b_min, self.b_max, self.b_index, self.b_count)
        };
        let child = match (count, index) {
            (0, NO_NODE) => Child::None,
            (0, node) => Child::Node(node),
            (count, first) => Child::Leaf { first, count },
        };
        let bounds = Aabb {
            min: Vec3::from_array(min),
            max: Vec3::from_array(max),
        };
        (bounds, child)
    }

    /// Sets child `which` (0: `a`, 1: `b`) to `child` with box `bounds`.
    pub fn set_child(&mut self, which: usize, bounds: Aabb, child: Child) {
        let (index, count) = match child {
            Child::Node(n) => (n, 0),
            Child::Leaf { first, count } => (first, count),
            Child::None => (NO_NODE, 0),
        };
        let (min, max) = (bounds.min.to_array(), bounds.max.to_array());
        if which == 0 {
            (self.a_min, self.a_max, self.a_index, self.a_count) = (min, max, index, count);
        } else {
            (self.b_min, self.b_max, self.b_index, self.b_count) = (min, max, index, count);
        }
    }
}

/// A built BVH on the host: what uploads to the device, and what the CPU twins traverse.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh {
    /// Node 0 is the root; empty for an empty input.
    pub nodes: Vec<BvhNode>,
    /// `parents[i]`: the node whose child node `i` is ([`NO_NODE`] for the root).
    pub parents: Vec<u32>,
    /// Primitive ids; each leaf's references are contiguous.
    pub refs: Vec<u32>,
    /// Box of every primitive.
    pub bounds: Aabb,
    /// The 4-wide nodes of [`Bvh::wide`], made when first asked for.
    pub wide: WideCache,
}

/// [`Bvh::wide`]'s nodes, derived from the binary ones (equal whether made or not).
#[derive(Clone, Debug, Default)]
pub struct WideCache(pub(super) std::sync::OnceLock<Vec<WideNode>>);

impl PartialEq for WideCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl Bvh {
    /// Forgets the wide nodes made from the old `nodes`.
    pub fn nodes_changed(&mut self) {
        self.wide = WideCache::default();
    }

    /// Device bytes of the layout: nodes, parent links and references.
    pub fn bytes(&self) -> usize {
        std::mem::size_of_val(self.nodes.as_slice())
            + std::mem::size_of_val(self.parents.as_slice())
            + std::mem::size_of_val(self.refs.as_slice())
    }

    /// Leaves (a child with references).
    pub fn leaf_count(&self) -> usize {
        self.nodes
            .iter()
            .flat_map(|n| [n.child(0).1, n.child(1).1])
            .filter(|c| matches!(c, Child::Leaf { .. }))
            .count()
    }

    /// The nodes reachable from the root, each before its children (depth first); reversed,
    /// every node comes after its children (the order of bottom-up passes).
    pub fn top_down(&self) -> Vec<u32> {
        let mut order = Vec::with_capacity(self.nodes.len());
        let mut stack = if self.nodes.is_empty() {
            vec![]
        } else {
            vec![0u32]
        };
        while let Some(i) = stack.pop() {
            order.push(i);
            for which in 0..2 {
                if let Child::Node(c) = self.nodes[i as usize].child(which).1 {
                    stack.push(c);
                }
            }
        }
        order
    }

    /// Depth of the deepest leaf (a leaf child of the root has depth 1).
    pub fn depth(&self) -> u32 {
        let mut deepest = 0;
        let mut stack = vec![(0u32, 1u32)];
        while let Some((node, depth)) = stack.pop() {
            let Some(n) = self.nodes.get(node as usize) else {
                break;
            };
            for which in 0..2 {
                match n.child(which).1 {
                    Child::Node(c) => stack.push((c, depth + 1)),
                    Child::Leaf { .. } => deepest = deepest.max(depth),
                    Child::None => {}
                }
            }
        }
        deepest
    }
}

/// Half the surface area of a box (0 for an empty one): the SAH's measure.
pub fn half_area(b: &Aabb) -> f32 {
    if b.is_empty() {
        return 0.0;
    }
    let d = b.max - b.min;
    d.x * d.y + d.y * d.z + d.z * d.x
}

/// One node, 64 bytes (16 words, four RGBA32UI texels; `glsl/include/vkrt/bvh_wide.glsl`).
/// Child `k`'s planes are byte `k` of the `lo` and `hi` words.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct WideNode {
    /// The frame's origin (bits of three floats).
    pub origin: [u32; 3],
    /// Biased exponents of the three scales: x in bits 0..8, y 8..16, z 16..24.
    pub exponents: u32,
    /// Low planes, one word per axis.
    pub lo: [u32; 3],
    /// High planes, one word per axis.
    pub hi: [u32; 3],
    /// Leaf sizes, 16 bits per child (children 0, 1 in the first word): 0 for an interior
    /// node or a missing child.
    pub counts: [u32; 2],
    /// Per child: its wide node (count 0), its first reference (count > 0), or [`NO_NODE`].
    pub index: [u32; 4],
}
