//! Structural checks of a built BVH and its SAH cost.

use super::layout::{half_area, Bvh, Child, MAX_TRAVERSAL_DEPTH, NO_NODE};
use super::sah::BvhParams;
use crate::scene::Aabb;

/// Checks that every primitive is referenced exactly once, every node but the root is the
/// child of exactly one node and names it as its parent, every child box is exactly the
/// union of what lies below it (tight and containing), interior nodes have two children and
/// leaves at least one primitive. `boxes` are the primitive boxes the tree was built over.
pub fn validate(bvh: &Bvh, boxes: &[Aabb]) -> Result<(), String> {
    if boxes.is_empty() {
        return if bvh.nodes.is_empty() && bvh.refs.is_empty() {
            Ok(())
        } else {
            Err("an empty input must give an empty tree".into())
        };
    }
    if bvh.nodes.is_empty() || bvh.parents.len() != bvh.nodes.len() {
        return Err(format!(
            "{} nodes and {} parent links",
            bvh.nodes.len(),
            bvh.parents.len()
        ));
    }
    let mut seen = vec![false; boxes.len()];
    for &r in &bvh.refs {
        let slot = seen
            .get_mut(r as usize)
            .ok_or(format!("reference {r} out of range"))?;
        if std::mem::replace(slot, true) {
            return Err(format!("primitive {r} referenced twice"));
        }
    }
    if let Some(missing) = seen.iter().position(|s| !s) {
        return Err(format!("primitive {missing} not referenced"));
    }
    if bvh.parents[0] != NO_NODE {
        return Err("the root has a parent".into());
    }
    let mut visited = vec![false; bvh.nodes.len()];
    let mut covered = 0usize;
    let root = subtree(bvh, boxes, 0, &mut visited, &mut covered)?;
    if let Some(n) = visited.iter().position(|v| !v) {
        return Err(format!("node {n} is not reachable from the root"));
    }
    if covered != bvh.refs.len() {
        return Err(format!(
            "leaves cover {covered} of {} references",
            bvh.refs.len()
        ));
    }
    if root != bvh.bounds {
        return Err(format!("root box {root:?} vs bounds {:?}", bvh.bounds));
    }
    if bvh.depth() > MAX_TRAVERSAL_DEPTH {
        return Err(format!(
            "{} levels: the traversal walks at most {MAX_TRAVERSAL_DEPTH}",
            bvh.depth()
        ));
    }
    Ok(())
}

/// The union of everything below `node`, checking its children on the way.
fn subtree(
    bvh: &Bvh,
    boxes: &[Aabb],
    node: u32,
    visited: &mut [bool],
    covered: &mut usize,
) -> Result<Aabb, String> {
    let seen = visited
        .get_mut(node as usize)
        .ok_or(format!("child node {node} out of range"))?;
    if std::mem::replace(seen, true) {
        return Err(format!("node {node} is reached twice"));
    }
    let n = bvh.nodes[node as usize];
    let mut all = Aabb::EMPTY;
    for which in 0..2 {
        let (b, child) = n.child(which);
        let below = match child {
            Child::Node(c) => {
                if bvh.parents.get(c as usize) != Some(&node) {
                    return Err(format!("node {c} does not name {node} as its parent"));
                }
                subtree(bvh, boxes, c, visited, covered)?
            }
            Child::Leaf { first, count } => {
                let refs = bvh
                    .refs
                    .get(first as usize..(first + count) as usize)
                    .ok_or(format!("leaf {first}+{count} out of range"))?;
                *covered += refs.len();
                refs.iter().fold(Aabb::EMPTY, |mut acc, &r| {
                    acc.union(&boxes[r as usize]);
                    acc
                })
            }
            Child::None => {
                if node != 0 || which != 1 || bvh.nodes.len() != 1 {
                    return Err(format!("node {node} lacks child {which}"));
                }
                Aabb::EMPTY
            }
        };
        if child != Child::None && b != below {
            return Err(format!(
                "node {node} child {which}: box {b:?}, content {below:?}"
            ));
        }
        all.union(&below);
    }
    Ok(all)
}

/// SAH cost of the tree relative to its root box: `C_trav` per interior node and `C_isect`
/// per primitive of each leaf, each weighted by its box's area over the root's.
pub fn sah_cost(bvh: &Bvh, params: &BvhParams) -> f64 {
    let root = half_area(&bvh.bounds) as f64;
    if bvh.nodes.is_empty() || root <= 0.0 {
        return 0.0;
    }
    let mut cost = params.traversal_cost as f64; // the root
    for n in &bvh.nodes {
        for which in 0..2 {
            let (b, child) = n.child(which);
            let a = half_area(&b) as f64 / root;
            match child {
                Child::Node(_) => cost += params.traversal_cost as f64 * a,
                Child::Leaf { count, .. } => {
                    cost += params.intersection_cost as f64 * count as f64 * a
                }
                Child::None => {}
            }
        }
    }
    cost
}
