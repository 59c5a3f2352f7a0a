//! Quality statistics of a kd-tree: shape, references, memory and its SAH cost.
//!
//! The SAH cost of a whole tree is the expected cost of a random ray through the root box
//! under the surface-area model (Goldsmith & Salmon 1987, MacDonald & Booth 1990; the same
//! model the builders minimise locally, Wald & Havran 2006):
//!
//! `C = Σ_inner C_trav·SA(node)/SA(root) + Σ_leaf c_obj·count·SA(leaf)/SA(root)`
//!
//! Node boxes are derived top-down from `tree.bounds` and the split planes, so the number
//! measures the tree as traversal sees it (a leaf's box is its region, not the box of its
//! primitives). The empty bonus λ is a build-time bias, not a cost, and does not appear.
//! Areas and sums are accumulated in f64. It is the number Kolodzey's GPU builder (split-
//! axis clipping) and the full-clipping reference are compared by; a single leaf holding all
//! N primitives costs `c_obj·N`.
//!
//! When the root box has zero area (no primitives, or everything on a line or a point),
//! probabilities are undefined; every node then counts with weight 1.

use serde::Serialize;

use super::{Aabb, KdTree, SahParams};

/// Leaves with at least this many references share the last histogram bucket.
pub const HISTOGRAM_LAST: usize = 16;

/// Statistics of one tree; see [`stats`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KdStats {
    /// All nodes (`tree.nodes.len()`).
    pub nodes: u32,
    /// Leaves reachable from the root (including empty ones).
    pub leaves: u32,
    /// Leaves with no reference.
    pub empty_leaves: u32,
    /// Inner nodes reachable from the root.
    pub inner: u32,
    /// Depth of the deepest node (root = 0).
    pub max_depth: u32,
    /// Mean depth of the leaves.
    pub avg_leaf_depth: f64,
    /// `leaf_size_histogram[i]` = leaves with `i` references, for `i < 16`; the last bucket
    /// (index [`HISTOGRAM_LAST`] = 16) counts leaves with 16 or more.
    pub leaf_size_histogram: Vec<u32>,
    /// Largest leaf.
    pub max_leaf_size: u32,
    /// Sum of the leaves' reference counts.
    pub references: u64,
    /// Input primitives (`tree.primitives`).
    pub primitives: u32,
    /// `references / primitives` (0 without primitives): the duplication that splitting
    /// straddlers causes.
    pub refs_per_primitive: f64,
    /// SAH cost of the whole tree (module docs).
    pub sah_cost: f64,
    /// Memory of the layout: 16 bytes per node plus 4 per `prim_refs` entry.
    pub bytes: u64,
}

/// Compute [`KdStats`] with the costs of `params`. Walks the tree from the root; on a tree
/// that [`validate`](super::validate::validate) rejects the numbers are meaningless, but
/// this does not panic (out-of-range children and leaf ranges are ignored, and every node
/// is visited at most once).
pub fn stats(tree: &KdTree, params: &SahParams) -> KdStats {
    let ct = f64::from(params.traversal_cost);
    let ci = f64::from(params.intersection_cost);
    let root_area = area(&tree.bounds);
    let weight = |b: &Aabb| {
        if root_area > 0.0 {
            area(b) / root_area
        } else {
            1.0
        }
    };

    let mut s = KdStats {
        nodes: tree.nodes.len() as u32,
        leaves: 0,
        empty_leaves: 0,
        inner: 0,
        max_depth: 0,
        avg_leaf_depth: 0.0,
        leaf_size_histogram: vec![0; HISTOGRAM_LAST + 1],
        max_leaf_size: 0,
        references: 0,
        primitives: tree.primitives,
        refs_per_primitive: 0.0,
        sah_cost: 0.0,
        bytes: 16 * tree.nodes.len() as u64 + 4 * tree.prim_refs.len() as u64,
    };
    let mut visited = vec![false; tree.nodes.len()];
    let mut depth_sum = 0u64;
    let mut stack = vec![(0usize, tree.bounds, 0u32)];
    while let Some((i, bx, depth)) = stack.pop() {
        let Some(node) = tree.nodes.get(i) else {
            continue;
        };
        if std::mem::replace(&mut visited[i], true) {
            continue;
        }
        s.max_depth = s.max_depth.max(depth);
        if node.is_leaf() {
            let count = node.b;
            s.leaves += 1;
            s.empty_leaves += u32::from(count == 0);
            s.leaf_size_histogram[(count as usize).min(HISTOGRAM_LAST)] += 1;
            s.max_leaf_size = s.max_leaf_size.max(count);
            s.references += u64::from(count);
            depth_sum += u64::from(depth);
            s.sah_cost += ci * f64::from(count) * weight(&bx);
        } else {
            s.inner += 1;
            s.sah_cost += ct * weight(&bx);
            let axis = (node.kind as usize).min(2);
            let (mut below, mut above) = (bx, bx);
            below.max[axis] = node.split;
            above.min[axis] = node.split;
            let a = node.a as usize;
            stack.push((a.saturating_add(1), above, depth + 1));
            stack.push((a, below, depth + 1));
        }
    }
    if s.leaves > 0 {
        s.avg_leaf_depth = depth_sum as f64 / f64::from(s.leaves);
    }
    if s.primitives > 0 {
        s.refs_per_primitive = s.references as f64 / f64::from(s.primitives);
    }
    s
}

/// Surface area in f64; 0 for an empty or inverted box.
pub(crate) fn area(b: &Aabb) -> f64 {
    if b.is_empty() {
        return 0.0;
    }
    let d = (b.max - b.min).as_dvec3();
    2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
}
