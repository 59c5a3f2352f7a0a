//! Compaction of a collapsed BVH: the node slots the SAH leaf collapse freed (parent link
//! [`DEAD`]) removed and the live nodes renumbered densely in index order, each interior
//! child and parent link renamed (the root stays node 0, the references stay as they are).
//! The rank of a live node — its new index — is the exclusive scan of the live flags. CPU
//! twin of `glsl/accel/bvh/compact_*.comp`, bit for bit.

use super::collapse::DEAD;
use super::layout::{BvhNode, Child, NO_NODE};

/// A BVH's node slots as they lie on the device ([`AccelStructure::download_slots`]).
///
/// [`AccelStructure::download_slots`]: crate::accel::device::AccelStructure::download_slots
#[derive(Clone, Debug, PartialEq)]
pub struct BvhSlots {
    /// The node slots of the built tree, those its leaf collapse freed included.
    pub nodes: Vec<BvhNode>,
    /// A parent link per slot ([`DEAD`] for a freed one).
    pub parents: Vec<u32>,
    /// The references.
    pub refs: Vec<u32>,
    /// The live nodes (the collapse's count where it counted them).
    pub live: usize,
}

/// Every slot's rank: how many live slots come before it (the new index of a live one).
pub fn ranks(parents: &[u32]) -> Vec<u32> {
    let mut next = 0;
    parents
        .iter()
        .map(|&p| {
            let rank = next;
            next += u32::from(p != DEAD);
            rank
        })
        .collect()
}

/// The live slots of `nodes` (parent links `parents`, one per slot) in index order, their
/// interior children and parent links renamed to their ranks.
pub fn renumber(nodes: &[BvhNode], parents: &[u32]) -> (Vec<BvhNode>, Vec<u32>) {
    let rank = ranks(parents);
    let rename = |i: u32| match i {
        NO_NODE => NO_NODE,
        i => rank[i as usize],
    };
    nodes
        .iter()
        .zip(parents)
        .filter(|(_, &p)| p != DEAD)
        .map(|(node, &parent)| {
            let mut node = *node;
            for which in 0..2 {
                let (bounds, child) = node.child(which);
                if let Child::Node(c) = child {
                    node.set_child(which, bounds, Child::Node(rename(c)));
                }
            }
            (node, rename(parent))
        })
        .unzip()
}

/// A refit schedule's first `live` node ids (sorted by depth, the freed slots after them)
/// renamed to their ranks: the schedule of the renumbered tree.
pub fn renumber_order(order: &[u32], parents: &[u32], live: usize) -> Vec<u32> {
    let rank = ranks(parents);
    order[..live].iter().map(|&i| rank[i as usize]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranks_count_the_live_slots_before() {
        assert_eq!(
            ranks(&[NO_NODE, DEAD, 0, DEAD, DEAD, 2]),
            [0, 1, 1, 2, 2, 2]
        );
        assert!(ranks(&[]).is_empty());
    }

    #[test]
    fn renumbering_is_the_host_copy_without_the_freed_slots() {
        // Slots: 0 root (children 2 and 4), 1 freed, 2 (children: leaf, 5), 3 freed, 4 a
        // node of two leaves, 5 a node of two leaves.
        let mut nodes = vec![BvhNode::empty(); 6];
        let leaf = |first| Child::Leaf { first, count: 1 };
        let b = crate::scene::Aabb::EMPTY;
        nodes[0].set_child(0, b, Child::Node(2));
        nodes[0].set_child(1, b, Child::Node(4));
        nodes[2].set_child(0, b, leaf(0));
        nodes[2].set_child(1, b, Child::Node(5));
        for i in [4, 5] {
            nodes[i].set_child(0, b, leaf(i as u32));
            nodes[i].set_child(1, b, leaf(i as u32 + 1));
        }
        let parents = [NO_NODE, DEAD, 0, DEAD, 0, 2];
        let (out, out_parents) = renumber(&nodes, &parents);
        assert_eq!(out_parents, [NO_NODE, 0, 0, 1]);
        assert_eq!(out[0].child(0).1, Child::Node(1));
        assert_eq!(out[0].child(1).1, Child::Node(2));
        assert_eq!(out[1].child(1).1, Child::Node(3));
        assert_eq!(out[1].child(0).1, leaf(0));
        assert_eq!(
            renumber_order(&[0, 2, 4, 5, 1, 3], &parents, 4),
            [0, 1, 2, 3]
        );
    }
}
