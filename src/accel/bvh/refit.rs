//! Refit: every box of a built BVH recomputed bottom-up from moved primitive boxes, the
//! topology kept (for dynamic scenes where objects move but stay close together). The CPU
//! twin of `glsl/accel/bvh/refit.comp`; both take the union with Kolodzey's total order on
//! ±0 (`fmin_total`/`fmax_total`), so they agree bit for bit.

use glam::Vec3;

use super::layout::{Bvh, Child};
use crate::accel::kdtree::breadth_first::{fmax, fmin};
use crate::scene::Aabb;

/// `a ∪ b`, -0 below +0.
pub fn union(a: &Aabb, b: &Aabb) -> Aabb {
    let lo = |x: Vec3, y: Vec3| Vec3::new(fmin(x.x, y.x), fmin(x.y, y.y), fmin(x.z, y.z));
    let hi = |x: Vec3, y: Vec3| Vec3::new(fmax(x.x, y.x), fmax(x.y, y.y), fmax(x.z, y.z));
    Aabb {
        min: lo(a.min, b.min),
        max: hi(a.max, b.max),
    }
}

/// Recomputes every child box of `bvh` (and its bounds) over `boxes`, the primitives' boxes
/// after they moved; the topology is unchanged.
pub fn refit(bvh: &mut Bvh, boxes: &[Aabb]) {
    bvh.nodes_changed();
    if bvh.nodes.is_empty() {
        bvh.bounds = Aabb::EMPTY;
        return;
    }
    for &i in bvh.top_down().iter().rev() {
        let node = bvh.nodes[i as usize];
        for which in 0..2 {
            let (old, child) = node.child(which);
            let b = match child {
                Child::Leaf { first, count } => bvh.refs[first as usize..(first + count) as usize]
                    .iter()
                    .fold(Aabb::EMPTY, |acc, &p| union(&acc, &boxes[p as usize])),
                Child::Node(c) => {
                    let n = &bvh.nodes[c as usize];
                    union(&n.child(0).0, &n.child(1).0)
                }
                Child::None => old,
            };
            bvh.nodes[i as usize].set_child(which, b, child);
        }
    }
    let root = &bvh.nodes[0];
    bvh.bounds = union(&root.child(0).0, &root.child(1).0);
}
