//! The breadth-first kd-tree build (CPU twin of the GPU build): structure, coverage of every
//! triangle by point location, determinism and termination on the hard cases.

mod common;

use glam::Vec3;
use vkrt::accel::kdtree::{breadth_first, KdNode, KdTree, SahParams};
use vkrt::scene::gen;

/// Depth of every node, checking the BFS layout on the way.
fn depths(tree: &KdTree) -> Vec<u32> {
    let mut depth = vec![u32::MAX; tree.nodes.len()];
    depth[0] = 0;
    for (i, node) in tree.nodes.iter().enumerate() {
        assert_ne!(
            depth[i],
            u32::MAX,
            "node {i} is not reachable from the root"
        );
        if node.is_leaf() {
            assert!(
                (node.a + node.b) as usize <= tree.prim_refs.len(),
                "leaf {i} range out of prim_refs"
            );
        } else {
            let c = node.a as usize;
            assert!(
                c > i && c + 1 < tree.nodes.len(),
                "children of {i} must follow it: {node:?}"
            );
            assert!(node.kind < 3);
            for child in [c, c + 1] {
                assert_eq!(depth[child], u32::MAX, "node {child} has two parents");
                depth[child] = depth[i] + 1;
            }
        }
    }
    assert!(
        depth.windows(2).all(|w| w[0] <= w[1]),
        "not in breadth-first order"
    );
    depth
}

/// Leaves whose closed box contains `p` (both sides when `p` lies on a split plane).
fn leaves_containing(tree: &KdTree, p: Vec3, out: &mut Vec<usize>) {
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let KdNode { split, kind, a, .. } = tree.nodes[i];
        if kind == vkrt::accel::kdtree::LEAF {
            out.push(i);
            continue;
        }
        let v = p[kind as usize];
        if v <= split {
            stack.push(a as usize);
        }
        if v >= split {
            stack.push(a as usize + 1);
        }
    }
}

/// Every triangle is found in every leaf that contains a point of it (sampled points and
/// the vertices) — the property traversal relies on.
fn assert_covers(tree: &KdTree, tris: &[[Vec3; 3]]) {
    let mut rng = common::Rng(99);
    let mut leaves = Vec::new();
    for (id, t) in tris.iter().enumerate() {
        let mut points = vec![t[0], t[1], t[2], (t[0] + t[1] + t[2]) / 3.0];
        for _ in 0..4 {
            let (mut u, mut v) = ((rng.next_f32() + 1.0) / 2.0, (rng.next_f32() + 1.0) / 2.0);
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            points.push(t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v);
        }
        for p in points {
            leaves.clear();
            leaves_containing(tree, p, &mut leaves);
            // A sampled point may round just outside the closed leaf boxes of its triangle;
            // it must still be covered by at least one leaf that references it.
            let referenced = leaves.iter().any(|&l| {
                let n = tree.nodes[l];
                tree.prim_refs[n.a as usize..(n.a + n.b) as usize].contains(&(id as u32))
            });
            assert!(
                referenced || leaves.is_empty(),
                "triangle {id} at {p} is in none of the leaves {leaves:?}"
            );
        }
    }
}

fn check(name: &str, tris: &[[Vec3; 3]], params: &SahParams) -> KdTree {
    let start = std::time::Instant::now();
    let (tree, trace) = breadth_first::build(tris, params);
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let d = depths(&tree);
    let max_depth = d.iter().copied().max().unwrap_or(0);
    assert!(
        max_depth <= params.depth_limit(tris.len()),
        "{name}: depth {max_depth} over the limit"
    );
    assert!(
        tree.prim_refs.iter().all(|&r| (r as usize) < tris.len()),
        "{name}: reference out of range"
    );
    let mut seen = vec![false; tris.len()];
    for &r in &tree.prim_refs {
        seen[r as usize] = true;
    }
    assert!(seen.iter().all(|&s| s), "{name}: a triangle is in no leaf");
    assert_covers(&tree, tris);
    let (again, _) = breadth_first::build(tris, params);
    assert!(again == tree, "{name}: two builds differ");
    eprintln!(
        "{name}: {} tris, {} nodes, {} refs, depth {max_depth}, {} levels, {ms:.1} ms",
        tris.len(),
        tree.nodes.len(),
        tree.prim_refs.len(),
        trace.levels
    );
    tree
}

#[test]
fn meshes_build_valid_deterministic_trees() {
    let p = SahParams::default();
    check(
        "icosphere",
        &common::mesh_triangles(&gen::icosphere(4).unwrap()),
        &p,
    );
    check(
        "soup",
        &common::mesh_triangles(&gen::random_soup(20_000, 5).unwrap()),
        &p,
    );
    check(
        "grid",
        &common::mesh_triangles(&gen::integer_grid(40, 40).unwrap()),
        &p,
    );
    // Kolodzey's (2014) termination: no SAH leaf test, leaves below 64 primitives... reproduced
    // with max_leaf_prims and the switch.
    let seed = SahParams {
        sah_leaf_test: false,
        max_leaf_prims: 63,
        ..p
    };
    check(
        "icosphere.kolodzey-termination",
        &common::mesh_triangles(&gen::icosphere(4).unwrap()),
        &seed,
    );
}

#[test]
fn hard_cases_terminate_and_stay_valid() {
    for (name, tris) in common::kdtree_hard_cases() {
        check(name, &tris, &SahParams::default());
    }
}

#[test]
fn empty_input_is_one_empty_leaf() {
    let (tree, _) = breadth_first::build(&[], &SahParams::default());
    assert_eq!(tree.nodes, vec![KdNode::leaf(0, 0)]);
    assert!(tree.prim_refs.is_empty());
}

#[test]
fn the_bunny_builds() {
    let Some(tris) = common::bunny() else { return };
    assert_eq!(tris.len(), 69_451);
    check("bunny", &tris, &SahParams::default());
}
