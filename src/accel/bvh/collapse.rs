//! SAH leaf collapse of the GPU builders' trees (LBVH, PLOC): they end in one primitive per
//! leaf, which makes the walk visit a node where a leaf of a few primitives is cheaper.
//! Bottom-up, every node weighs the SAH cost of its subtree, `C_trav·A + cost(a) + cost(b)`,
//! against a leaf of its primitives, `C_isect·A·n`, and becomes a leaf when it holds at most
//! `max_leaf_prims` and the leaf is no dearer — the optimal collapse under the SAH, as PLOC's
//! paper (Meister & Bittner 2018, §4.3) and RADV's builder do it. The root stays a node.
//!
//! [`collapse`] lays the references of every node's leaves out contiguously in node order,
//! child `a` before `b` and a collapsed subtree's in depth-first order (PLOC's trees).
//! [`collapse_in_place`] serves trees whose references already lie in depth-first order,
//! every subtree a contiguous run (the LBVH's: its leaves are the Morton order): a
//! collapsed subtree's leaf points at its run, and no reference moves. On the device the
//! nodes keep their slots and a removed node's parent link becomes [`DEAD`]; the host tree
//! is compacted in index order (the root stays node 0; [`drop_removed`] renumbers a
//! downloaded one the same way). CPU twin of `glsl/accel/bvh_collapse_*.comp`, bit for bit.

use super::layout::{half_area, Bvh, BvhNode, Child, NO_NODE};
use super::refit::union;
use super::sah::BvhParams;

/// Parent link of a node slot the collapse freed (after every live node).
pub const DEAD: u32 = 0xffff_fffe;

/// What the bottom-up pass knows of one node.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NodeCost {
    /// Primitives below the node.
    pub count: u32,
    /// The SAH cost of the node as it will be (a leaf or a node), in half areas.
    pub cost: f32,
    /// The node becomes a leaf of its parent (never the root).
    pub collapse: bool,
}

/// Whether [`collapse`] changes anything: trees of fewer than three primitives have no node
/// to collapse (the root stays), and a leaf size of 1 keeps every node.
pub fn applies(n_prims: usize, p: &BvhParams) -> bool {
    n_prims >= 3 && p.max_leaf_prims > 1
}

/// The SAH costs and collapse decisions of every node (the cost kernel's result).
pub fn costs(bvh: &Bvh, p: &BvhParams) -> Vec<NodeCost> {
    let mut out = vec![NodeCost::default(); bvh.nodes.len()];
    for &i in bvh.top_down().iter().rev() {
        out[i as usize] = node_cost(&bvh.nodes[i as usize], &out, i == 0, p);
    }
    out
}

/// One node's decision from its children's (the kernel's `decide`, operation for operation).
fn node_cost(node: &BvhNode, done: &[NodeCost], root: bool, p: &BvhParams) -> NodeCost {
    let mut count = 0u32;
    let mut below = [0.0f32; 2];
    for (which, cost) in below.iter_mut().enumerate() {
        let (bounds, child) = node.child(which);
        match child {
            Child::Leaf { count: k, .. } => {
                count += k;
                *cost = p.intersection_cost * half_area(&bounds) * k as f32;
            }
            Child::Node(c) => {
                count += done[c as usize].count;
                *cost = done[c as usize].cost;
            }
            Child::None => {}
        }
    }
    let area = half_area(&union(&node.child(0).0, &node.child(1).0));
    let split = p.traversal_cost * area + below[0] + below[1];
    let leaf = p.intersection_cost * area * count as f32;
    let collapse = !root && count <= p.max_leaf_prims && leaf <= split;
    NodeCost {
        count,
        cost: if collapse { leaf } else { split },
        collapse,
    }
}

/// `bvh` with its subtrees collapsed into leaves where the SAH says so, the references laid
/// out in node order (see the module); `bvh` itself when [`applies`] says nothing would
/// change.
pub fn collapse(bvh: &Bvh, p: &BvhParams) -> Bvh {
    collapse_with(bvh, p, RefLayout::NodeOrder)
}

/// [`collapse`] of a tree whose references lie in depth-first order, `a` before `b`, every
/// subtree a contiguous run (the LBVH's): the references stay where they are, and a
/// collapsed subtree becomes a leaf over its run.
pub fn collapse_in_place(bvh: &Bvh, p: &BvhParams) -> Bvh {
    collapse_with(bvh, p, RefLayout::InPlace)
}

/// Where a collapse puts the references.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RefLayout {
    /// Laid out anew in node order ([`collapse`]).
    NodeOrder,
    /// Left where they are, for trees whose references lie in depth-first order
    /// ([`collapse_in_place`]).
    InPlace,
}

/// [`collapse`] or [`collapse_in_place`] by `layout`.
pub fn collapse_with(bvh: &Bvh, p: &BvhParams, layout: RefLayout) -> Bvh {
    if !applies(bvh.refs.len(), p) {
        return bvh.clone();
    }
    let costs = costs(bvh, p);
    let n_nodes = bvh.nodes.len();
    // A node lives when neither it nor an ancestor collapsed.
    let live: Vec<bool> = (0..n_nodes)
        .map(|i| {
            let mut x = i as u32;
            while x != NO_NODE && costs[x as usize].count <= p.max_leaf_prims {
                if costs[x as usize].collapse {
                    return false;
                }
                x = bvh.parents[x as usize];
            }
            true
        })
        .collect();
    let leaf_prims = |i: usize| -> u32 {
        (0..2)
            .map(|which| match bvh.nodes[i].child(which).1 {
                Child::Leaf { count, .. } => count,
                Child::Node(c) if costs[c as usize].collapse => costs[c as usize].count,
                _ => 0,
            })
            .sum()
    };
    let mut index = vec![NO_NODE; n_nodes];
    let mut offset = vec![0u32; n_nodes];
    let (mut next_node, mut next_ref) = (0u32, 0u32);
    for i in 0..n_nodes {
        if live[i] {
            index[i] = next_node;
            offset[i] = next_ref;
            next_node += 1;
            // References left in place need no offsets of their own.
            if layout == RefLayout::NodeOrder {
                next_ref += leaf_prims(i);
            }
        }
    }
    let mut out = Bvh {
        nodes: vec![BvhNode::empty(); next_node as usize],
        parents: vec![NO_NODE; next_node as usize],
        refs: match layout {
            RefLayout::NodeOrder => vec![0; bvh.refs.len()],
            RefLayout::InPlace => bvh.refs.clone(),
        },
        bounds: bvh.bounds,
        wide: Default::default(),
    };
    for i in (0..n_nodes).filter(|&i| live[i]) {
        let j = index[i] as usize;
        let mut at = offset[i];
        let mut node = bvh.nodes[i];
        for which in 0..2 {
            let (bounds, child) = bvh.nodes[i].child(which);
            let child = match (child, layout) {
                (Child::Node(c), _) if !costs[c as usize].collapse => {
                    Child::Node(index[c as usize])
                }
                (Child::Node(c), RefLayout::InPlace) => Child::Leaf {
                    first: first_ref(bvh, c),
                    count: costs[c as usize].count,
                },
                (Child::Node(c), RefLayout::NodeOrder) => {
                    let first = at;
                    gather(bvh, c, &mut out.refs, &mut at);
                    Child::Leaf {
                        first,
                        count: at - first,
                    }
                }
                (Child::Leaf { .. }, RefLayout::InPlace) => child,
                (Child::Leaf { first, count }, RefLayout::NodeOrder) => {
                    let refs = &bvh.refs[first as usize..(first + count) as usize];
                    out.refs[at as usize..(at + count) as usize].copy_from_slice(refs);
                    at += count;
                    Child::Leaf {
                        first: at - count,
                        count,
                    }
                }
                (Child::None, _) => Child::None,
            };
            node.set_child(which, bounds, child);
        }
        out.nodes[j] = node;
        let parent = bvh.parents[i];
        out.parents[j] = if parent == NO_NODE {
            NO_NODE
        } else {
            index[parent as usize]
        };
    }
    out
}

/// The first reference below `node` in depth-first order: its leftmost leaf's (child `a`
/// first, `b` where `a` is missing).
fn first_ref(bvh: &Bvh, mut node: u32) -> u32 {
    loop {
        let n = &bvh.nodes[node as usize];
        let child = match n.child(0).1 {
            Child::None => n.child(1).1,
            a => a,
        };
        match child {
            Child::Leaf { first, .. } => return first,
            Child::Node(c) => node = c,
            Child::None => return 0,
        }
    }
}

/// The nodes and parent links of a device tree without the slots a collapse removed (parent
/// [`DEAD`]), the rest renumbered in index order: the host form [`collapse`] returns (and
/// what compaction makes on the device, [`super::compact::renumber`]).
pub fn drop_removed(nodes: Vec<BvhNode>, parents: &[u32]) -> (Vec<BvhNode>, Vec<u32>) {
    if !parents.contains(&DEAD) {
        return (nodes, parents.to_vec());
    }
    super::compact::renumber(&nodes, parents)
}

/// Appends the references below `node` to `refs` from `*at` on, depth first, `a` before `b`.
fn gather(bvh: &Bvh, node: u32, refs: &mut [u32], at: &mut u32) {
    for which in 0..2 {
        match bvh.nodes[node as usize].child(which).1 {
            Child::Node(c) => gather(bvh, c, refs, at),
            Child::Leaf { first, count } => {
                for k in first..first + count {
                    refs[*at as usize] = bvh.refs[k as usize];
                    *at += 1;
                }
            }
            Child::None => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::validate::{sah_cost, validate};
    use crate::accel::bvh::{lbvh, ploc};
    use crate::scene::Aabb;
    use glam::Vec3;

    /// The boxes of the first `n` triangles of a fine icosphere (neighbours overlap, as in
    /// a real mesh, so the SAH collapses).
    fn boxes(n: usize) -> Vec<Aabb> {
        let sphere = crate::scene::gen::icosphere(4).unwrap();
        let tris: Vec<[Vec3; 3]> = sphere.indices[..n]
            .iter()
            .map(|t| t.map(|i| sphere.positions[i as usize]))
            .collect();
        crate::accel::primitives::TraceGeometry::from_triangles(&tris).boxes
    }

    #[test]
    fn collapsed_trees_are_valid_cheaper_and_hold_small_leaves() {
        let p = BvhParams::default();
        for n in [0, 1, 2, 3, 4, 5, 17, 64, 65, 1000] {
            let b = boxes(n);
            for tree in [
                lbvh::build(&b, Default::default()),
                ploc::build(&b, &Default::default()).0,
            ] {
                let c = collapse(&tree, &p);
                validate(&c, &b).unwrap_or_else(|e| panic!("n = {n}: {e}"));
                assert!(sah_cost(&c, &p) <= sah_cost(&tree, &p), "n = {n}");
                for node in &c.nodes {
                    for which in 0..2 {
                        if let Child::Leaf { count, .. } = node.child(which).1 {
                            assert!(count <= p.max_leaf_prims);
                        }
                    }
                }
                if n >= 64 {
                    assert!(
                        c.nodes.len() < tree.nodes.len(),
                        "n = {n}: nothing collapsed"
                    );
                }
            }
        }
    }

    /// The leaves' references in depth-first order, `a` before `b`.
    fn leaf_refs(t: &Bvh) -> Vec<Vec<u32>> {
        let mut out = Vec::new();
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            for which in [1, 0] {
                match t.nodes[i as usize].child(which).1 {
                    Child::Node(c) => stack.push(c),
                    Child::Leaf { first, count } => {
                        out.push(t.refs[first as usize..(first + count) as usize].to_vec())
                    }
                    Child::None => {}
                }
            }
        }
        out
    }

    #[test]
    fn in_place_collapse_is_the_same_tree_without_moving_a_reference() {
        let p = BvhParams::default();
        for n in [0, 1, 2, 3, 4, 5, 17, 64, 65, 1000] {
            let b = boxes(n);
            let tree = lbvh::build(&b, Default::default());
            let moved = collapse(&tree, &p);
            let kept = collapse_in_place(&tree, &p);
            validate(&kept, &b).unwrap_or_else(|e| panic!("n = {n}: {e}"));
            assert_eq!(kept.refs, tree.refs, "n = {n}");
            assert_eq!(kept.parents, moved.parents, "n = {n}");
            assert_eq!(kept.nodes.len(), moved.nodes.len(), "n = {n}");
            assert_eq!(sah_cost(&kept, &p), sah_cost(&moved, &p), "n = {n}");
            if n > 0 {
                // The hits need the leaves to hold the same primitives in the same order.
                assert_eq!(leaf_refs(&kept), leaf_refs(&moved), "n = {n}");
            }
            for (k, m) in kept.nodes.iter().zip(&moved.nodes) {
                for which in 0..2 {
                    let ((kb, kc), (mb, mc)) = (k.child(which), m.child(which));
                    assert_eq!(kb, mb);
                    match (kc, mc) {
                        (Child::Leaf { count: a, .. }, Child::Leaf { count: b, .. }) => {
                            assert_eq!(a, b)
                        }
                        _ => assert_eq!(kc, mc),
                    }
                }
            }
        }
    }

    #[test]
    fn leaf_size_one_keeps_the_tree() {
        let b = boxes(300);
        let tree = lbvh::build(&b, Default::default());
        let p = BvhParams {
            max_leaf_prims: 1,
            ..Default::default()
        };
        assert_eq!(collapse(&tree, &p), tree);
    }

    #[test]
    fn the_root_stays_a_node() {
        // Three primitives in one point: a leaf of all three is cheapest, but the root
        // stays a node so the traversal's layout holds.
        let b = vec![
            Aabb {
                min: Vec3::ONE,
                max: Vec3::ONE
            };
            3
        ];
        let c = collapse(&lbvh::build(&b, Default::default()), &BvhParams::default());
        validate(&c, &b).unwrap();
        assert!(!c.nodes.is_empty());
    }
}
