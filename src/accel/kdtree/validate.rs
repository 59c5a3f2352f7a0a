//! Structural validator for kd-trees in the shared layout: the oracle every builder (the
//! full-clipping reference, Kolodzey's GPU build and its CPU twin) is checked against.
//!
//! Checks, in order (the first failure is returned, naming the node or primitive):
//!
//! 1. `tree.primitives` equals the number of triangles; there is a root.
//! 2. Layout: every `kind` is an axis or [`LEAF`]; inner nodes have `b = 0` and children
//!    `a`, `a + 1` in range and after the parent; every node except the root is the child of
//!    exactly one node; depths never decrease with the index (breadth-first order, as the
//!    level-by-level GPU build (Kolodzey 2014) and the GLSL traversal expect).
//! 3. Geometry of the splits: every plane is finite and inside its node's box (inclusive),
//!    the boxes being derived top-down from `tree.bounds`. The two children then partition
//!    the parent by construction of the layout.
//! 4. Leaves: `prim_refs[a .. a + b]` in range, every reference below `tree.primitives`, no
//!    primitive twice in one leaf.
//! 5. Coverage. `tree.bounds` contains every vertex (exactly). Then every triangle is pushed
//!    down the tree by Sutherland–Hodgman clipping (Sutherland & Hodgman 1974), starting
//!    from the whole triangle at the root: at an inner node the polygon goes to the side(s)
//!    where it has points more than `ε` from the plane, clipped to that side. Every leaf
//!    reached must reference the triangle. A polygon within `ε` of the
//!    plane (a flat triangle lying on it, or a sliver) must be covered entirely by **one**
//!    of the two sides — that is how Wald & Havran (2006) and Kolodzey (2014) place planar
//!    primitives. So every triangle whose clip against a leaf box leaves a polygon reaching
//!    more than `ε` into the box must be referenced there, flat and zero-area triangles
//!    included, and every triangle is referenced at least once.
//!
//! `ε = 2^-16 · max |coordinate of tree.bounds|` absorbs rounding: the builder clips the
//! original triangle against each box while this walk clips incrementally, and the two
//! cannot agree bit for bit near a plane. Overlaps thinner than `ε` are not required;
//! references a leaf does not need are allowed (they cost, they do not break traversal).
//! Triangles with a non-finite coordinate (which scene validation rejects) are not checked.
//!
//! Cost: O(nodes + references) for the layout, plus one descent per triangle that visits the
//! nodes its geometry overlaps — linear in the number of references times the depth. The
//! triangles are split across the available cores; the error reported is the one of the
//! lowest primitive index, so results are deterministic.

use glam::Vec3;

use super::full_clip::{clip_half, Polygon};
use super::{Aabb, KdNode, KdTree, LEAF};

/// Why a tree is invalid.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ValidationError {
    /// `tree.primitives` differs from the number of triangles given.
    #[error("the tree says {tree} primitives, but {triangles} triangles were given")]
    PrimitiveCount {
        /// `tree.primitives`.
        tree: u32,
        /// Triangles given.
        triangles: usize,
    },
    /// The tree has no root.
    #[error("the tree has no nodes (an empty tree is one empty leaf)")]
    NoNodes,
    /// A node's `kind` is neither an axis nor [`LEAF`].
    #[error("node {node}: kind {kind} is neither an axis (0..=2) nor LEAF ({LEAF})")]
    BadKind {
        /// The node's index.
        node: u32,
        /// Its `kind`.
        kind: u32,
    },
    /// An inner node's `b` is not 0.
    #[error("inner node {node}: `b` = {b}, must be 0")]
    InnerB {
        /// The node's index.
        node: u32,
        /// Its `b`.
        b: u32,
    },
    /// An inner node's children `a`, `a + 1` are not both nodes of the tree.
    #[error("inner node {node}: children {first} and {first} + 1 are out of range ({len} nodes)")]
    ChildOutOfRange {
        /// The node's index.
        node: u32,
        /// Its first child (`a`).
        first: u32,
        /// Nodes in the tree.
        len: usize,
    },
    /// An inner node's first child is stored at or before it.
    #[error("inner node {node}: child {child} is not stored after its parent")]
    ChildBeforeParent {
        /// The node's index.
        node: u32,
        /// Its first child (`a`).
        child: u32,
    },
    /// A node is the child of two inner nodes.
    #[error("node {node} is a child of both node {first_parent} and node {second_parent}")]
    SharedChild {
        /// The child's index.
        node: u32,
        /// The first parent found (the lower index).
        first_parent: u32,
        /// The second parent found.
        second_parent: u32,
    },
    /// A node other than the root is no node's child.
    #[error("node {node} is not the root and no node's child")]
    Orphan {
        /// The node's index.
        node: u32,
    },
    /// A node is shallower than the node stored before it: the order is not breadth-first.
    #[error("node {node} (depth {depth}) follows node {previous} (depth {previous_depth}): not breadth-first")]
    NotBreadthFirst {
        /// The node's index.
        node: u32,
        /// Its depth (root = 0).
        depth: u32,
        /// The node stored before it (`node - 1`).
        previous: u32,
        /// That node's depth.
        previous_depth: u32,
    },
    /// A split plane is not finite or lies outside its node's box (inclusive).
    #[error("inner node {node}: split {split} on axis {axis} is outside its box [{min}, {max}]")]
    SplitOutsideBox {
        /// The node's index.
        node: u32,
        /// The split axis.
        axis: u32,
        /// The split plane's position.
        split: f32,
        /// The node box's minimum on the axis.
        min: f32,
        /// The node box's maximum on the axis.
        max: f32,
    },
    /// A leaf's references run past the end of `prim_refs`.
    #[error("leaf {node}: references {first} .. {first} + {count} exceed prim_refs ({len})")]
    LeafRange {
        /// The leaf's index.
        node: u32,
        /// Its first reference (`a`).
        first: u32,
        /// Its reference count (`b`).
        count: u32,
        /// Entries in `prim_refs`.
        len: usize,
    },
    /// A leaf references a primitive that does not exist.
    #[error(
        "leaf {node}: prim_refs[{index}] = {prim} is not below the primitive count {primitives}"
    )]
    RefOutOfRange {
        /// The leaf's index.
        node: u32,
        /// The offending entry's index in `prim_refs`.
        index: usize,
        /// The primitive it names.
        prim: u32,
        /// `tree.primitives`.
        primitives: u32,
    },
    /// A leaf references one primitive twice.
    #[error("leaf {node}: primitive {prim} is referenced twice")]
    DuplicateRef {
        /// The leaf's index.
        node: u32,
        /// The primitive referenced twice.
        prim: u32,
    },
    /// `tree.bounds` is not finite with `min <= max`, though a triangle is finite.
    #[error("tree bounds {min:?} .. {max:?} are not a finite box")]
    BadBounds {
        /// `tree.bounds.min`.
        min: [f32; 3],
        /// `tree.bounds.max`.
        max: [f32; 3],
    },
    /// A triangle's vertex lies outside `tree.bounds`.
    #[error("primitive {prim}: vertex {vertex:?} lies outside the tree bounds")]
    OutsideBounds {
        /// The triangle's index.
        prim: u32,
        /// The vertex outside.
        vertex: [f32; 3],
    },
    /// A triangle reaches more than `ε` into a leaf's box, but the leaf does not reference it.
    #[error("primitive {prim} overlaps leaf {leaf} (box {min:?} .. {max:?}) but the leaf does not reference it")]
    MissingReference {
        /// The triangle's index.
        prim: u32,
        /// The leaf's index.
        leaf: u32,
        /// Minimum corner of the leaf's box.
        min: [f32; 3],
        /// Maximum corner of the leaf's box.
        max: [f32; 3],
    },
}

/// Validate `tree` against the `triangles` it was built from (module docs list the checks).
pub fn validate(tree: &KdTree, triangles: &[[Vec3; 3]]) -> Result<(), ValidationError> {
    if tree.primitives as usize != triangles.len() {
        return Err(ValidationError::PrimitiveCount {
            tree: tree.primitives,
            triangles: triangles.len(),
        });
    }
    if tree.nodes.is_empty() {
        return Err(ValidationError::NoNodes);
    }
    check_layout(tree)?;
    let boxes = node_boxes(tree);
    check_splits(tree, &boxes)?;
    let leaves_of_prim = check_leaves(tree)?;
    check_bounds(tree, triangles)?;

    let scale = [tree.bounds.min, tree.bounds.max]
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f32, |m, v| m.max(v.abs().max_element()));
    let walk = Walk {
        nodes: &tree.nodes,
        boxes: &boxes,
        leaves_of_prim: &leaves_of_prim,
        eps: scale * (1.0 / 65536.0),
    };
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, 8);
    let chunk = triangles.len().div_ceil(threads).max(4096);
    let first_error = std::thread::scope(|s| {
        let handles: Vec<_> = triangles
            .chunks(chunk)
            .enumerate()
            .map(|(c, tris)| {
                let walk = &walk;
                s.spawn(move || {
                    for (i, t) in tris.iter().enumerate() {
                        if t.iter().all(|v| v.is_finite()) {
                            let prim = (c * chunk + i) as u32;
                            walk.descend(prim, 0, Polygon::from_triangle(t))?;
                        }
                    }
                    Ok(())
                })
            })
            .collect();
        // Chunks are in primitive order: the first failing chunk has the lowest index.
        handles
            .into_iter()
            .map(|h| h.join().expect("validator thread panicked"))
            .find(|r| r.is_err())
    });
    first_error.unwrap_or(Ok(()))
}

/// The box of every node, derived top-down from `tree.bounds` and the splits. Assumes
/// children are stored after their parents (out-of-range children are ignored); nodes no
/// parent reaches keep [`Aabb::EMPTY`].
pub fn node_boxes(tree: &KdTree) -> Vec<Aabb> {
    let mut boxes = vec![Aabb::EMPTY; tree.nodes.len()];
    if let Some(b) = boxes.first_mut() {
        *b = tree.bounds;
    }
    for (i, n) in tree.nodes.iter().enumerate() {
        if n.is_leaf() || n.kind > 2 {
            continue;
        }
        let (a, axis) = (n.a as usize, n.kind as usize);
        if a <= i || a + 1 >= tree.nodes.len() {
            continue;
        }
        let mut below = boxes[i];
        below.max[axis] = n.split;
        let mut above = boxes[i];
        above.min[axis] = n.split;
        boxes[a] = below;
        boxes[a + 1] = above;
    }
    boxes
}

/// The leaves whose closed box contains `point`, in increasing index order (a point on a
/// split plane lies in both sides). Assumes a structurally valid tree.
pub fn leaves_of(tree: &KdTree, point: Vec3) -> Vec<u32> {
    let mut out = Vec::new();
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let Some(n) = tree.nodes.get(i) else {
            continue;
        };
        if n.is_leaf() {
            out.push(i as u32);
            continue;
        }
        let (a, x) = (n.a as usize, point[(n.kind as usize).min(2)]);
        if x <= n.split && a > i {
            stack.push(a);
        }
        if x >= n.split && a > i {
            stack.push(a + 1);
        }
    }
    out.sort_unstable();
    out
}

fn check_layout(tree: &KdTree) -> Result<(), ValidationError> {
    let len = tree.nodes.len();
    let mut parent = vec![u32::MAX; len];
    let mut depth = vec![0u32; len];
    for (i, n) in tree.nodes.iter().enumerate() {
        let node = i as u32;
        if i > 0 {
            if parent[i] == u32::MAX {
                return Err(ValidationError::Orphan { node });
            }
            if depth[i] < depth[i - 1] {
                return Err(ValidationError::NotBreadthFirst {
                    node,
                    depth: depth[i],
                    previous: node - 1,
                    previous_depth: depth[i - 1],
                });
            }
        }
        if n.is_leaf() {
            continue;
        }
        if n.kind > 2 {
            return Err(ValidationError::BadKind { node, kind: n.kind });
        }
        if n.b != 0 {
            return Err(ValidationError::InnerB { node, b: n.b });
        }
        if n.a as usize + 1 >= len {
            return Err(ValidationError::ChildOutOfRange {
                node,
                first: n.a,
                len,
            });
        }
        if n.a <= node {
            return Err(ValidationError::ChildBeforeParent { node, child: n.a });
        }
        for child in [n.a, n.a + 1] {
            let c = child as usize;
            if parent[c] != u32::MAX {
                return Err(ValidationError::SharedChild {
                    node: child,
                    first_parent: parent[c],
                    second_parent: node,
                });
            }
            parent[c] = node;
            depth[c] = depth[i] + 1;
        }
    }
    Ok(())
}

fn check_splits(tree: &KdTree, boxes: &[Aabb]) -> Result<(), ValidationError> {
    for (i, n) in tree.nodes.iter().enumerate() {
        if n.is_leaf() {
            continue;
        }
        let axis = n.kind as usize;
        let (min, max) = (boxes[i].min[axis], boxes[i].max[axis]);
        if !(n.split.is_finite() && min <= n.split && n.split <= max) {
            return Err(ValidationError::SplitOutsideBox {
                node: i as u32,
                axis: n.kind,
                split: n.split,
                min,
                max,
            });
        }
    }
    Ok(())
}

/// Checks the leaves and returns, per primitive, the sorted leaves that reference it, as
/// CSR (`offsets`, `leaves`).
fn check_leaves(tree: &KdTree) -> Result<Csr, ValidationError> {
    let primitives = tree.primitives as usize;
    let mut counts = vec![0u32; primitives + 1];
    for (i, n) in tree.nodes.iter().enumerate().filter(|(_, n)| n.is_leaf()) {
        let range = leaf_range(i, n, tree.prim_refs.len())?;
        for (index, &prim) in tree.prim_refs[range.clone()].iter().enumerate() {
            if prim as usize >= primitives {
                return Err(ValidationError::RefOutOfRange {
                    node: i as u32,
                    index: range.start + index,
                    prim,
                    primitives: tree.primitives,
                });
            }
            counts[prim as usize + 1] += 1;
        }
    }
    let mut sum = 0;
    for c in &mut counts {
        sum += *c;
        *c = sum;
    }
    let offsets = counts;
    let mut fill = offsets.clone();
    let mut leaves = vec![0u32; offsets[primitives] as usize];
    for (i, n) in tree.nodes.iter().enumerate().filter(|(_, n)| n.is_leaf()) {
        let range = leaf_range(i, n, tree.prim_refs.len())?;
        for &prim in &tree.prim_refs[range] {
            let slot = &mut fill[prim as usize];
            // Leaves are visited in index order, so each list is sorted: a repeat is the
            // previous entry.
            if *slot > offsets[prim as usize] && leaves[*slot as usize - 1] == i as u32 {
                return Err(ValidationError::DuplicateRef {
                    node: i as u32,
                    prim,
                });
            }
            leaves[*slot as usize] = i as u32;
            *slot += 1;
        }
    }
    Ok(Csr { offsets, leaves })
}

fn leaf_range(i: usize, n: &KdNode, len: usize) -> Result<std::ops::Range<usize>, ValidationError> {
    let (first, count) = (n.a as usize, n.b as usize);
    if first + count > len {
        return Err(ValidationError::LeafRange {
            node: i as u32,
            first: n.a,
            count: n.b,
            len,
        });
    }
    Ok(first..first + count)
}

fn check_bounds(tree: &KdTree, triangles: &[[Vec3; 3]]) -> Result<(), ValidationError> {
    let b = &tree.bounds;
    let any_finite = triangles.iter().any(|t| t.iter().all(|v| v.is_finite()));
    if any_finite && !(b.min.is_finite() && b.max.is_finite() && b.min.cmple(b.max).all()) {
        return Err(ValidationError::BadBounds {
            min: b.min.to_array(),
            max: b.max.to_array(),
        });
    }
    for (prim, t) in triangles.iter().enumerate() {
        if !t.iter().all(|v| v.is_finite()) {
            continue;
        }
        if let Some(v) = t
            .iter()
            .find(|v| !(v.cmpge(b.min).all() && v.cmple(b.max).all()))
        {
            return Err(ValidationError::OutsideBounds {
                prim: prim as u32,
                vertex: v.to_array(),
            });
        }
    }
    Ok(())
}

struct Csr {
    offsets: Vec<u32>,
    leaves: Vec<u32>,
}

struct Walk<'a> {
    nodes: &'a [KdNode],
    boxes: &'a [Aabb],
    leaves_of_prim: &'a Csr,
    eps: f32,
}

impl Walk<'_> {
    /// Push `poly` (part of primitive `prim`) down from `node`; every leaf it must reach has
    /// to reference `prim`.
    fn descend(&self, prim: u32, node: usize, poly: Polygon) -> Result<(), ValidationError> {
        let n = &self.nodes[node];
        if n.is_leaf() {
            let csr = self.leaves_of_prim;
            let (s, e) = (
                csr.offsets[prim as usize] as usize,
                csr.offsets[prim as usize + 1] as usize,
            );
            if csr.leaves[s..e].binary_search(&(node as u32)).is_ok() {
                return Ok(());
            }
            return Err(ValidationError::MissingReference {
                prim,
                leaf: node as u32,
                min: self.boxes[node].min.to_array(),
                max: self.boxes[node].max.to_array(),
            });
        }
        let (axis, p, below) = (n.kind as usize, n.split, n.a as usize);
        let (lo, hi) = poly.extent(axis);
        let need_below = lo < p - self.eps;
        let need_above = hi > p + self.eps;
        match (need_below, need_above) {
            // On the plane: one side must hold all of it.
            (false, false) => self
                .descend(prim, below, poly)
                .or_else(|e| self.descend(prim, below + 1, poly).map_err(|_| e)),
            // Clip even when the other side is not needed: a sub-ε overhang past this plane
            // must not count as overlap on a later axis.
            (true, false) => self.descend(prim, below, clip_half(&poly, axis, p, true)),
            (false, true) => self.descend(prim, below + 1, clip_half(&poly, axis, p, false)),
            (true, true) => {
                self.descend(prim, below, clip_half(&poly, axis, p, true))?;
                self.descend(prim, below + 1, clip_half(&poly, axis, p, false))
            }
        }
    }
}
