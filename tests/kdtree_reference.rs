//! The full-clipping SAH kd-tree (Wald & Havran 2006), its statistics and the structural
//! validator: every builder output is validated, traced against brute force, and the
//! validator is shown to fail on broken trees.

use std::path::Path;
use std::time::{Duration, Instant};

use glam::Vec3;
use vkrt::accel::kdtree::full_clip::{self, clipped_bounds};
use vkrt::accel::kdtree::stats::{stats, KdStats, HISTOGRAM_LAST};
use vkrt::accel::kdtree::validate::{leaves_of, node_boxes, validate, ValidationError};
use vkrt::accel::kdtree::{Aabb, KdNode, KdTree, SahParams, LEAF};
use vkrt::scene::gen::{self, Rng};
use vkrt::scene::{Mesh, Scene};

fn tris(mesh: &Mesh) -> Vec<[Vec3; 3]> {
    mesh.indices
        .iter()
        .map(|&[a, b, c]| {
            [
                mesh.positions[a as usize],
                mesh.positions[b as usize],
                mesh.positions[c as usize],
            ]
        })
        .collect()
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Build, validate and measure; checks the properties every tree must have.
#[track_caller]
fn check(name: &str, triangles: &[[Vec3; 3]], params: &SahParams) -> (KdTree, KdStats) {
    let t0 = Instant::now();
    let tree = full_clip::build(triangles, params);
    let build = t0.elapsed();
    let t1 = Instant::now();
    if let Err(e) = validate(&tree, triangles) {
        panic!("{name}: invalid tree: {e}");
    }
    let valid = t1.elapsed();
    let s = stats(&tree, params);
    let live = triangles
        .iter()
        .filter(|t| t.iter().all(|v| v.is_finite()))
        .count();
    // The tree is never worse than one leaf holding everything.
    let single_leaf = f64::from(params.intersection_cost) * live as f64;
    assert!(
        s.sah_cost <= single_leaf * (1.0 + 1e-9),
        "{name}: SAH {} above a single leaf's {single_leaf}",
        s.sah_cost
    );
    assert_eq!(s.nodes as usize, tree.nodes.len());
    assert_eq!(s.leaves + s.inner, s.nodes, "{name}: unreachable nodes");
    assert_eq!(s.inner + 1, s.leaves, "{name}: binary tree");
    assert_eq!(
        s.references,
        tree.prim_refs.len() as u64,
        "{name}: unused refs"
    );
    assert_eq!(
        s.leaf_size_histogram
            .iter()
            .map(|&c| u64::from(c))
            .sum::<u64>(),
        u64::from(s.leaves)
    );
    assert!(
        s.max_depth <= params.depth_limit(live),
        "{name}: depth limit"
    );
    eprintln!(
        "{name:<34} n={:>8} build {:>9.2} ms  validate {:>8.2} ms  nodes {:>8} leaves {:>8} \
         depth {:>2} refs/prim {:.3} SAH {:.3}",
        triangles.len(),
        ms(build),
        ms(valid),
        s.nodes,
        s.leaves,
        s.max_depth,
        s.refs_per_primitive,
        s.sah_cost
    );
    (tree, s)
}

// ---------------------------------------------------------------------------------------
// Ray traversal against brute force: an end-to-end check of builder and validator.

/// Möller–Trumbore in f64, edges inclusive.
fn hit(t: &[Vec3; 3], o: Vec3, d: Vec3) -> Option<f64> {
    let (o, d) = (o.as_dvec3(), d.as_dvec3());
    let (a, b, c) = (t[0].as_dvec3(), t[1].as_dvec3(), t[2].as_dvec3());
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-30 {
        return None;
    }
    let s = o - a;
    let u = s.dot(p) / det;
    let q = s.cross(e1);
    let v = d.dot(q) / det;
    let w = e2.dot(q) / det;
    (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && w > 0.0).then_some(w)
}

fn brute(tris: &[[Vec3; 3]], o: Vec3, d: Vec3) -> Option<f64> {
    tris.iter()
        .filter_map(|t| hit(t, o, d))
        .min_by(|a, b| a.total_cmp(b))
}

/// Recursive front-to-back traversal of `node` over the ray interval `[tmin, tmax]`; `slack`
/// widens every leaf's interval so hits on a boundary are found from either side.
#[allow(
    clippy::too_many_arguments,
    reason = "test helper: the traversal state"
)]
fn trace(
    tree: &KdTree,
    tris: &[[Vec3; 3]],
    o: Vec3,
    d: Vec3,
    slack: f64,
    node: usize,
    tmin: f64,
    tmax: f64,
) -> Option<f64> {
    let n = tree.nodes[node];
    if n.is_leaf() {
        return tree.prim_refs[n.a as usize..(n.a + n.b) as usize]
            .iter()
            .filter_map(|&p| hit(&tris[p as usize], o, d))
            .filter(|&t| t >= tmin - slack && t <= tmax + slack)
            .min_by(|a, b| a.total_cmp(b));
    }
    let k = n.kind as usize;
    let (ok, dk) = (f64::from(o[k]), f64::from(d[k]));
    let split = f64::from(n.split);
    let (near, far) = if ok < split || (ok == split && dk <= 0.0) {
        (n.a as usize, n.a as usize + 1)
    } else {
        (n.a as usize + 1, n.a as usize)
    };
    let t = (split - ok) / dk;
    if t.is_nan() || t <= 0.0 || t > tmax + slack {
        return trace(tree, tris, o, d, slack, near, tmin, tmax);
    }
    if t < tmin - slack {
        return trace(tree, tris, o, d, slack, far, tmin, tmax);
    }
    trace(tree, tris, o, d, slack, near, tmin, t.min(tmax))
        .or_else(|| trace(tree, tris, o, d, slack, far, t.max(tmin), tmax))
}

/// Closest hits of the tree equal brute force on seeded rays: random ones and ones aimed at
/// triangle centroids.
fn check_rays(name: &str, tree: &KdTree, tris: &[[Vec3; 3]], rays: usize, seed: u64) {
    if tris.is_empty() {
        return;
    }
    let b = tree.bounds;
    let size = (b.max - b.min).max_element().max(1e-3);
    let center = (b.min + b.max) * 0.5;
    let slack = 1e-6 * f64::from(size + b.min.abs().max(b.max.abs()).max_element());
    let mut rng = Rng::new(seed);
    let mut hits = 0;
    for r in 0..rays {
        let o = center + rng.vec3_signed() * size * 1.5;
        let d = if r % 2 == 0 {
            rng.vec3_signed()
        } else {
            let t = &tris[rng.below(tris.len() as u32) as usize];
            let w = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) + 0.05;
            (t[0] * w.x + t[1] * w.y + t[2] * w.z) / (w.x + w.y + w.z) - o
        };
        if d.length_squared() == 0.0 {
            continue;
        }
        let expect = brute(tris, o, d);
        let got = trace(tree, tris, o, d, slack, 0, 0.0, f64::INFINITY);
        match (expect, got) {
            (None, None) => {}
            (Some(e), Some(g)) => {
                hits += 1;
                // With the slack a hit a hair behind the true closest one may win.
                assert!(
                    (e - g).abs() <= 4.0 * slack + 1e-9 * e.abs(),
                    "{name}: ray {r} ({o}, {d}): tree t = {g}, brute force t = {e}"
                );
            }
            _ => panic!("{name}: ray {r} ({o}, {d}): tree {got:?}, brute force {expect:?}"),
        }
    }
    assert!(hits > rays / 4, "{name}: only {hits} of {rays} rays hit");
}

// ---------------------------------------------------------------------------------------
// An independent O(N²)-per-node implementation of the same rules: every candidate plane is
// counted from scratch from the primitives' clipped boxes, without events, sorting or
// merging. It must give the identical tree.

enum Naive {
    Inner(u32, f32, Box<Naive>, Box<Naive>),
    Leaf(Vec<u32>),
}

fn naive_build(tris: &[[Vec3; 3]], p: &SahParams) -> KdTree {
    let mut bounds = Aabb::EMPTY;
    let mut prims = Vec::new();
    for (i, t) in tris.iter().enumerate() {
        if t.iter().all(|v| v.is_finite()) {
            let b = vkrt::accel::kdtree::triangle_bounds(t);
            bounds.union(&b);
            prims.push((i as u32, b));
        }
    }
    let limit = p.depth_limit(prims.len());
    let root = naive_node(tris, p, limit, prims, bounds, 0);
    // Breadth-first layout.
    let (mut nodes, mut refs) = (Vec::new(), Vec::new());
    let mut queue = std::collections::VecDeque::from([&root]);
    while let Some(n) = queue.pop_front() {
        match n {
            Naive::Inner(axis, split, below, above) => {
                nodes.push(KdNode::inner(
                    *axis,
                    *split,
                    (nodes.len() + queue.len() + 1) as u32,
                ));
                queue.push_back(below);
                queue.push_back(above);
            }
            Naive::Leaf(ids) => {
                nodes.push(KdNode::leaf(refs.len() as u32, ids.len() as u32));
                refs.extend_from_slice(ids);
            }
        }
    }
    KdTree {
        nodes,
        prim_refs: refs,
        bounds,
        primitives: tris.len() as u32,
    }
}

fn naive_node(
    tris: &[[Vec3; 3]],
    p: &SahParams,
    limit: u32,
    mut prims: Vec<(u32, Aabb)>,
    bx: Aabb,
    depth: u32,
) -> Naive {
    let n = prims.len();
    let d = (bx.max - bx.min).as_dvec3();
    let half = d.x * d.y + d.y * d.z + d.z * d.x;
    let (ct, ci) = (f64::from(p.traversal_cost), f64::from(p.intersection_cost));
    // (cost, axis, pos, planar_left)
    let mut best: Option<(f64, usize, f32, bool)> = None;
    if n > p.max_leaf_prims as usize && depth < limit && half > 0.0 {
        for axis in 0..3 {
            let (lo, hi) = (bx.min[axis], bx.max[axis]);
            let mut cands: Vec<f32> = prims
                .iter()
                .flat_map(|(_, b)| [b.min[axis] + 0.0, b.max[axis] + 0.0])
                .filter(|&x| lo < x && x < hi)
                .collect();
            cands.sort_by(f32::total_cmp);
            cands.dedup();
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for pos in cands {
                let (mut l, mut r, mut pl) = (0, 0, 0);
                for (_, b) in &prims {
                    let (a, z) = (b.min[axis], b.max[axis]);
                    if a == z {
                        match a.partial_cmp(&pos).unwrap() {
                            std::cmp::Ordering::Less => l += 1,
                            std::cmp::Ordering::Greater => r += 1,
                            std::cmp::Ordering::Equal => pl += 1,
                        }
                    } else if z <= pos {
                        l += 1;
                    } else if a >= pos {
                        r += 1;
                    } else {
                        l += 1;
                        r += 1;
                    }
                }
                let x = f64::from(pos);
                // Half areas, and costs scaled by half the node's area, like the builder.
                let half_l = d[u] * d[v] + (x - f64::from(lo)) * (d[u] + d[v]);
                let half_r = d[u] * d[v] + (f64::from(hi) - x) * (d[u] + d[v]);
                let sides: &[(usize, usize, bool)] = if pl > 0 {
                    &[(l + pl, r, true), (l, r + pl, false)]
                } else {
                    &[(l, r, true)]
                };
                for &(cl, cr, left) in sides {
                    if cl == n && cr == n {
                        continue;
                    }
                    let mut cost = ct * half + ci * (half_l * cl as f64 + half_r * cr as f64);
                    if cl == 0 || cr == 0 {
                        cost *= f64::from(p.empty_bonus);
                    }
                    if best.is_none_or(|b| cost < b.0) {
                        best = Some((cost, axis, pos, left));
                    }
                }
            }
        }
    }
    let best = best.filter(|b| !p.sah_leaf_test || b.0 / half < ci * n as f64);
    let Some((_, axis, pos, planar_left)) = best else {
        prims.sort_by_key(|&(i, _)| i);
        return Naive::Leaf(prims.iter().map(|&(i, _)| i).collect());
    };
    let (mut lbox, mut rbox) = (bx, bx);
    lbox.max[axis] = pos;
    rbox.min[axis] = pos;
    let (mut left, mut right) = (Vec::new(), Vec::new());
    for (i, b) in prims {
        let (a, z) = (b.min[axis], b.max[axis]);
        if a == z {
            if a < pos || (a == pos && planar_left) {
                left.push((i, b));
            } else {
                right.push((i, b));
            }
        } else if z <= pos {
            left.push((i, b));
        } else if a >= pos {
            right.push((i, b));
        } else {
            let t = &tris[i as usize];
            let (cl, cr) = (naive_clip(t, &lbox), naive_clip(t, &rbox));
            let inside = |c: &Option<(Aabb, bool)>| matches!(c, Some((_, false)));
            let touches = |c: &Option<(Aabb, bool)>| matches!(c, Some((_, true)));
            let keep_l = !(touches(&cl) && inside(&cr));
            let keep_r = !(touches(&cr) && inside(&cl));
            for (keep, c, cbox, side) in [
                (keep_l, cl, lbox, &mut left),
                (keep_r, cr, rbox, &mut right),
            ] {
                if !keep {
                    continue;
                }
                let b = c.map(|(b, _)| b).or_else(|| {
                    let mut b = vkrt::accel::kdtree::triangle_bounds(t);
                    b.min = b.min.max(cbox.min);
                    b.max = b.max.min(cbox.max);
                    (!b.is_empty()).then_some(b)
                });
                if let Some(b) = b {
                    side.push((i, b));
                }
            }
        }
    }
    Naive::Inner(
        axis as u32,
        pos,
        Box::new(naive_node(tris, p, limit, left, lbox, depth + 1)),
        Box::new(naive_node(tris, p, limit, right, rbox, depth + 1)),
    )
}

/// Clipped box and whether the polygon only touches a face the triangle is not parallel to.
fn naive_clip(t: &[Vec3; 3], b: &Aabb) -> Option<(Aabb, bool)> {
    let c = clipped_bounds(t, b)?;
    let tb = vkrt::accel::kdtree::triangle_bounds(t);
    let touches = (0..3).any(|k| {
        c.min[k] == c.max[k]
            && (c.min[k] == b.min[k] || c.max[k] == b.max[k])
            && tb.min[k] < tb.max[k]
    });
    Some((c, touches))
}

// ---------------------------------------------------------------------------------------
// Scenes

fn params() -> SahParams {
    SahParams::default()
}

/// Axis-aligned squares on integer planes spanning a 4³ lattice, two triangles each: their
/// PLANAR events coincide with the START/END events of the squares across them.
fn lattice_quads() -> Vec<[Vec3; 3]> {
    let mut out = Vec::new();
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for c in 0..=4 {
            let p = |a: f32, b: f32| {
                let mut x = Vec3::ZERO;
                x[axis] = c as f32;
                x[u] = a;
                x[v] = b;
                x
            };
            out.push([p(0.0, 0.0), p(4.0, 0.0), p(4.0, 4.0)]);
            out.push([p(0.0, 0.0), p(4.0, 4.0), p(0.0, 4.0)]);
        }
    }
    out
}

/// Unit cubes on a 3³ grid, 12 triangles each; neighbouring cubes give identical,
/// axis-aligned triangles on shared integer planes.
fn cube_grid(n: u32) -> Vec<[Vec3; 3]> {
    let mut out = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let o = Vec3::new(i as f32, j as f32, k as f32);
                for axis in 0..3 {
                    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                    for side in [0.0, 1.0] {
                        let p = |a: f32, b: f32| {
                            let mut x = o;
                            x[axis] += side;
                            x[u] += a;
                            x[v] += b;
                            x
                        };
                        out.push([p(0.0, 0.0), p(1.0, 0.0), p(1.0, 1.0)]);
                        out.push([p(0.0, 0.0), p(1.0, 1.0), p(0.0, 1.0)]);
                    }
                }
            }
        }
    }
    out
}

fn flat_soup(n: u32, axis: usize, at: f32, seed: u64) -> Vec<[Vec3; 3]> {
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let c = rng.vec3_signed();
            let mut t = [c, c + rng.vec3_signed() * 0.2, c + rng.vec3_signed() * 0.2];
            for v in &mut t {
                v[axis] = at;
            }
            t
        })
        .collect()
}

fn huge_and_tiny(n: u32, seed: u64) -> Vec<[Vec3; 3]> {
    let mut rng = Rng::new(seed);
    let mut out = vec![[
        Vec3::new(-10.0, -10.0, -3.0),
        Vec3::new(10.0, -9.0, 2.0),
        Vec3::new(-2.0, 10.0, 4.0),
    ]];
    for _ in 0..n {
        let c = rng.vec3_signed();
        out.push([
            c,
            c + rng.vec3_signed() * 1e-3,
            c + rng.vec3_signed() * 1e-3,
        ]);
    }
    out
}

// ---------------------------------------------------------------------------------------
// Tests

#[test]
fn icospheres() {
    for s in [0, 1, 3, 5] {
        let t = tris(&gen::icosphere(s).unwrap());
        let (tree, st) = check(&format!("icosphere({s})"), &t, &params());
        check_rays(&format!("icosphere({s})"), &tree, &t, 400, s as u64);
        if s == 5 {
            // A closed sphere of 20 480 triangles: far below one leaf (30 720). The cheap
            // intersection cost (1.5 vs 1 per step) still gives deep trees with leaves of 2–3
            // around the mesh vertices.
            assert!(
                st.sah_cost > 5.0 && st.sah_cost < 150.0,
                "SAH {}",
                st.sah_cost
            );
            assert!(st.refs_per_primitive < 8.0, "{}", st.refs_per_primitive);
        }
    }
}

#[test]
fn random_soups() {
    for (n, seed) in [
        (1, 1),
        (2, 2),
        (3, 3),
        (10, 4),
        (100, 5),
        (1000, 6),
        (20_000, 7),
    ] {
        let t = tris(&gen::random_soup(n, seed).unwrap());
        let name = format!("random_soup({n}, {seed})");
        let (tree, _) = check(&name, &t, &params());
        check_rays(&name, &tree, &t, 300, seed);
    }
}

#[test]
fn integer_grid_lies_on_candidate_planes() {
    let t = tris(&gen::integer_grid(32, 32).unwrap());
    let (tree, s) = check("integer_grid(32, 32)", &t, &params());
    check_rays("integer_grid", &tree, &t, 400, 11);
    // A flat grid: splits only in x and y, and no triangle is clipped into a sliver.
    assert!(tree.nodes.iter().all(|n| n.is_leaf() || n.kind < 2));
    assert!(s.refs_per_primitive < 3.0, "{}", s.refs_per_primitive);
}

#[test]
fn identical_triangles_make_one_leaf() {
    let one = [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.2, 0.3),
        Vec3::new(0.4, 1.0, 0.7),
    ];
    let t = vec![one; 500];
    let (_, s) = check("500 identical", &t, &params());
    assert_eq!((s.nodes, s.references), (1, 500));
    // Without the SAH leaf test (Kolodzey's rules) no split separates anything either.
    let kolodzey_rules = SahParams {
        sah_leaf_test: false,
        ..params()
    };
    let (_, s) = check("500 identical, no SAH leaf test", &t, &kolodzey_rules);
    assert_eq!((s.nodes, s.references), (1, 500));
    // Identical axis-aligned (flat) triangles too.
    let flat = vec![[Vec3::ZERO, Vec3::X, Vec3::Y]; 300];
    let (_, s) = check("300 identical flat", &flat, &kolodzey_rules);
    assert_eq!((s.nodes, s.references), (1, 300));
}

#[test]
fn triangles_in_one_plane() {
    for axis in 0..3 {
        let t = flat_soup(1000, axis, 0.25, axis as u64);
        let name = format!("1000 in plane axis {axis} = 0.25");
        let (tree, _) = check(&name, &t, &params());
        assert!(tree
            .nodes
            .iter()
            .all(|n| n.is_leaf() || n.kind as usize != axis));
        check_rays(&name, &tree, &t, 300, 20 + axis as u64);
    }
}

#[test]
fn one_huge_and_many_tiny() {
    let t = huge_and_tiny(5000, 9);
    let (tree, s) = check("1 huge + 5000 tiny", &t, &params());
    check_rays("huge_and_tiny", &tree, &t, 400, 9);
    // The huge triangle is clipped into many leaves; the tiny ones are rarely split.
    let huge_refs = tree.prim_refs.iter().filter(|&&p| p == 0).count();
    assert!(huge_refs >= 2, "huge triangle in {huge_refs} leaves");
    assert!(s.refs_per_primitive < 2.0);
}

#[test]
fn axis_aligned_quads_on_candidate_planes() {
    // Squares spanning the whole box: no split pays off under the SAH...
    let t = lattice_quads();
    let (tree, s) = check("lattice quads", &t, &params());
    assert_eq!(s.nodes, 1);
    check_rays("lattice quads", &tree, &t, 400, 31);
    // ...so force splits: every plane then holds planar squares.
    let forced = SahParams {
        sah_leaf_test: false,
        max_leaf_prims: 1,
        ..params()
    };
    let (tree, s) = check("lattice quads, forced splits", &t, &forced);
    assert!(s.inner > 10);
    check_rays("lattice quads, forced splits", &tree, &t, 400, 33);
    let t = cube_grid(3);
    let (tree, _) = check("3³ unit cubes (shared faces)", &t, &params());
    check_rays("cube grid", &tree, &t, 400, 32);
    // Planar primitives lie on split planes: each must be on (at least) one side, and the
    // validator checks exactly that.
    let kolodzey_rules = SahParams {
        sah_leaf_test: false,
        max_leaf_prims: 1,
        ..params()
    };
    check("3³ unit cubes, Kolodzey rules", &t, &kolodzey_rules);
}

#[test]
fn tiny_inputs() {
    let p = params();
    // Zero triangles: one empty leaf with EMPTY bounds.
    let tree = full_clip::build(&[], &p);
    assert_eq!(tree.nodes, vec![KdNode::leaf(0, 0)]);
    assert!(tree.prim_refs.is_empty() && tree.bounds == Aabb::EMPTY && tree.primitives == 0);
    validate(&tree, &[]).unwrap();
    let s = stats(&tree, &p);
    assert_eq!(
        (s.nodes, s.leaves, s.empty_leaves, s.sah_cost),
        (1, 1, 1, 0.0)
    );
    assert_eq!(s.leaf_size_histogram.len(), HISTOGRAM_LAST + 1);
    assert_eq!(s.leaf_size_histogram[0], 1);

    let a = [
        Vec3::ZERO,
        Vec3::new(1.0, 0.0, 0.5),
        Vec3::new(0.0, 1.0, 0.25),
    ];
    let (tree, s) = check("single triangle", &[a], &p);
    assert_eq!(
        (tree.nodes.len(), tree.prim_refs.as_slice()),
        (1, &[0u32][..])
    );
    assert!((s.sah_cost - 1.5).abs() < 1e-12);

    let b = a.map(|v| v + Vec3::new(3.0, 0.0, 0.0));
    let (tree, _) = check("two triangles", &[a, b], &p);
    assert_eq!(tree.nodes.len(), 1, "two ≤ max_leaf_prims");
    let one_each = SahParams {
        max_leaf_prims: 1,
        ..p
    };
    let (tree, s) = check("two triangles, leaves of 1", &[a, b], &one_each);
    assert_eq!(s.references, 2, "disjoint triangles are not duplicated");
    assert!(s.leaves >= 2);
    check_rays("two triangles", &tree, &[a, b], 200, 5);
}

#[test]
fn degenerate_and_non_finite_triangles() {
    let mut t = tris(&gen::random_soup(2000, 77).unwrap());
    let mut rng = Rng::new(78);
    for i in 0..400 {
        let a = rng.vec3_signed();
        let b = rng.vec3_signed();
        t.push(match i % 4 {
            0 => [a, a, a],                                 // a point
            1 => [a, b, (a + b) * 0.5],                     // collinear
            2 => [a, b, a],                                 // repeated vertex
            _ => [a, a + Vec3::X * 0.3, a + Vec3::X * 0.6], // axis-parallel segment
        });
    }
    let (_, s) = check("soup + 400 zero-area", &t, &params());
    assert_eq!(s.primitives, 2400);
    let kolodzey_rules = SahParams {
        sah_leaf_test: false,
        max_leaf_prims: 1,
        ..params()
    };
    check("soup + 400 zero-area, Kolodzey rules", &t, &kolodzey_rules);
    // Everything degenerate at one point: a single leaf.
    let points = vec![[Vec3::splat(0.5); 3]; 50];
    let (_, s) = check("50 identical points", &points, &params());
    assert_eq!(s.nodes, 1);

    // Non-finite triangles (scene validation rejects them) are skipped, not a panic.
    let mut bad = t[..100].to_vec();
    bad.insert(7, [Vec3::splat(f32::NAN), Vec3::ZERO, Vec3::ONE]);
    bad.push([Vec3::ZERO, Vec3::splat(f32::INFINITY), Vec3::ONE]);
    let tree = full_clip::build(&bad, &params());
    validate(&tree, &bad).unwrap();
    assert!(!tree.prim_refs.contains(&7) && !tree.prim_refs.contains(&101));
}

#[test]
fn builds_are_deterministic() {
    let mut t = tris(&gen::random_soup(5000, 3).unwrap());
    t.extend(cube_grid(3));
    t.extend(flat_soup(500, 1, 0.0, 4));
    for p in [
        params(),
        SahParams {
            sah_leaf_test: false,
            max_leaf_prims: 8,
            ..params()
        },
    ] {
        let a = full_clip::build(&t, &p);
        let b = full_clip::build(&t, &p);
        assert_eq!(a, b);
        let bits = |t: &KdTree| {
            t.nodes
                .iter()
                .map(|n| n.split.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&a), bits(&b));
    }
}

#[test]
fn kolodzey_rules_without_sah_leaf_test() {
    // Kolodzey's build splits until the leaf size or depth limit; the references stay bounded.
    let t = tris(&gen::random_soup(3000, 12).unwrap());
    let p = SahParams {
        sah_leaf_test: false,
        max_leaf_prims: 1,
        ..params()
    };
    let (tree, s) = check("soup 3000, Kolodzey rules", &t, &p);
    check_rays("soup 3000, Kolodzey rules", &tree, &t, 300, 12);
    assert!(s.refs_per_primitive < 20.0, "{}", s.refs_per_primitive);
    let with_test = stats(&full_clip::build(&t, &params()), &params());
    eprintln!(
        "SAH with leaf test {:.3}, without {:.3}",
        with_test.sah_cost, s.sah_cost
    );
}

#[test]
fn clipping_is_exact() {
    let t = [
        Vec3::ZERO,
        Vec3::new(2.0, 0.0, 0.0),
        Vec3::new(0.0, 2.0, 0.0),
    ];
    // The corner box [1,2]×[1,2] touches the hypotenuse only at (1, 1).
    let corner = Aabb {
        min: Vec3::new(1.0, 1.0, -1.0),
        max: Vec3::new(2.0, 2.0, 1.0),
    };
    let b = clipped_bounds(&t, &corner).unwrap();
    assert_eq!(
        (b.min, b.max),
        (Vec3::new(1.0, 1.0, 0.0), Vec3::new(1.0, 1.0, 0.0))
    );
    // Half the triangle: x ≥ 1 leaves the small triangle (1,0), (2,0), (1,1).
    let right = Aabb {
        min: Vec3::new(1.0, -1.0, -1.0),
        max: Vec3::new(3.0, 3.0, 1.0),
    };
    let b = clipped_bounds(&t, &right).unwrap();
    assert_eq!(
        (b.min, b.max),
        (Vec3::new(1.0, 0.0, 0.0), Vec3::new(2.0, 1.0, 0.0))
    );
    // Its bounding box overlaps [1.5,2]×[0.6,2], the triangle does not.
    let miss = Aabb {
        min: Vec3::new(1.5, 0.6, -1.0),
        max: Vec3::new(2.0, 2.0, 1.0),
    };
    assert_eq!(clipped_bounds(&t, &miss), None);
    // A tilted triangle: the clip is tighter than box ∩ triangle bounds on every axis.
    let tilted = [
        Vec3::ZERO,
        Vec3::new(4.0, 0.0, 4.0),
        Vec3::new(0.0, 4.0, 4.0),
    ];
    let slab = Aabb {
        min: Vec3::new(-1.0, -1.0, 0.0),
        max: Vec3::new(5.0, 5.0, 1.0),
    };
    let b = clipped_bounds(&tilted, &slab).unwrap();
    assert_eq!((b.min, b.max), (Vec3::ZERO, Vec3::new(1.0, 1.0, 1.0)));
}

#[test]
fn stats_match_a_hand_built_tree() {
    // Unit cube split at x = 0.25; below: 1 reference, above: split at y = 0.5 into an
    // empty leaf and a leaf with 3 references.
    let tree = KdTree {
        nodes: vec![
            KdNode::inner(0, 0.25, 1),
            KdNode::leaf(0, 1),
            KdNode::inner(1, 0.5, 3),
            KdNode::leaf(1, 0),
            KdNode::leaf(1, 3),
        ],
        prim_refs: vec![0, 0, 1, 2],
        bounds: Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        },
        primitives: 3,
    };
    let p = params();
    let s = stats(&tree, &p);
    // Areas: root 6; x-slab 0.25: 2(0.25 + 1 + 0.25) = 3; x-slab 0.75: 2(0.75+1+0.75) = 5;
    // its halves in y: 2(0.375 + 0.5 + 0.75) = 3.25 each.
    let expect = (1.0 * 6.0 + 1.5 * 1.0 * 3.0 + 1.0 * 5.0 + 0.0 + 1.5 * 3.0 * 3.25) / 6.0;
    assert!(
        (s.sah_cost - expect).abs() < 1e-12,
        "{} vs {expect}",
        s.sah_cost
    );
    assert_eq!(
        (s.nodes, s.leaves, s.empty_leaves, s.inner, s.max_depth),
        (5, 3, 1, 2, 2)
    );
    assert_eq!(
        (s.references, s.max_leaf_size, s.bytes),
        (4, 3, 5 * 16 + 4 * 4)
    );
    assert!((s.avg_leaf_depth - 5.0 / 3.0).abs() < 1e-12);
    assert!((s.refs_per_primitive - 4.0 / 3.0).abs() < 1e-12);
    assert_eq!(&s.leaf_size_histogram[..4], &[1, 1, 0, 1]);
    let json = serde_json::to_string(&s).unwrap();
    assert!(json.contains("\"sah_cost\""));
    assert_eq!(node_boxes(&tree)[4].min, Vec3::new(0.25, 0.5, 0.0));
    assert_eq!(leaves_of(&tree, Vec3::new(0.25, 0.5, 0.5)), vec![1, 3, 4]);
}

#[test]
fn sweep_matches_a_naive_build() {
    let mut scenes: Vec<(String, Vec<[Vec3; 3]>)> = vec![
        ("soup 300".into(), tris(&gen::random_soup(300, 41).unwrap())),
        ("icosphere(2)".into(), tris(&gen::icosphere(2).unwrap())),
        (
            "integer grid 8×8".into(),
            tris(&gen::integer_grid(8, 8).unwrap()),
        ),
        ("lattice quads".into(), lattice_quads()),
        ("2³ cubes".into(), cube_grid(2)),
        ("flat soup".into(), flat_soup(150, 2, -0.5, 42)),
        ("huge + tiny".into(), huge_and_tiny(200, 43)),
    ];
    let mut mixed = tris(&gen::random_soup(150, 44).unwrap());
    mixed.extend(lattice_quads());
    mixed.push([Vec3::splat(0.5); 3]);
    mixed.push([Vec3::ZERO, Vec3::ONE, Vec3::splat(0.5)]);
    mixed.push([Vec3::splat(-0.0), Vec3::new(-0.0, 1.0, 0.0), Vec3::X]);
    scenes.push(("mixed".into(), mixed));
    let rules = [
        params(),
        SahParams {
            sah_leaf_test: false,
            max_leaf_prims: 1,
            ..params()
        },
        SahParams {
            empty_bonus: 1.0,
            intersection_cost: 4.0,
            max_depth: Some(6),
            ..params()
        },
    ];
    for (name, t) in &scenes {
        for p in &rules {
            let fast = full_clip::build(t, p);
            let naive = naive_build(t, p);
            assert!(
                fast == naive,
                "{name}, {p:?}: sweep and naive builds differ ({} vs {} nodes)",
                fast.nodes.len(),
                naive.nodes.len()
            );
            validate(&fast, t).unwrap();
        }
    }
}

// ---------------------------------------------------------------------------------------
// The validator must be able to fail.

/// A valid tree over a random soup, with its triangles.
fn soup_tree() -> (KdTree, Vec<[Vec3; 3]>) {
    let t = tris(&gen::random_soup(400, 21).unwrap());
    let tree = full_clip::build(&t, &params());
    validate(&tree, &t).unwrap();
    assert!(tree.nodes.len() > 20);
    (tree, t)
}

/// Remove entry `index` of `prim_refs` from its leaf, keeping the layout consistent.
fn without_ref(tree: &KdTree, index: usize) -> KdTree {
    let mut broken = tree.clone();
    broken.prim_refs.remove(index);
    for n in &mut broken.nodes {
        if n.is_leaf() {
            if (n.a as usize) <= index && index < (n.a + n.b) as usize {
                n.b -= 1;
            } else if n.a as usize > index {
                n.a -= 1;
            }
        }
    }
    broken
}

#[test]
fn validator_catches_a_missing_reference() {
    let (tree, t) = soup_tree();
    // Triangle 0's centroid lies strictly inside a leaf that must reference it.
    let c = (t[0][0] + t[0][1] + t[0][2]) / 3.0;
    let leaf = leaves_of(&tree, c)[0] as usize;
    let n = tree.nodes[leaf];
    let index = (n.a..n.a + n.b)
        .find(|&i| tree.prim_refs[i as usize] == 0)
        .expect("leaf of the centroid references the triangle") as usize;
    match validate(&without_ref(&tree, index), &t) {
        Err(ValidationError::MissingReference { prim: 0, .. }) => {}
        other => panic!("expected a missing reference to primitive 0, got {other:?}"),
    }

    // Removing any single reference is caught unless the triangle only grazes that leaf
    // (thinner than the validator's ε) — count both.
    let (mut caught, mut total) = (0, 0);
    for index in (0..tree.prim_refs.len()).step_by(3) {
        total += 1;
        if validate(&without_ref(&tree, index), &t).is_err() {
            caught += 1;
        }
    }
    eprintln!("validator caught {caught} of {total} removed references");
    assert!(caught * 100 >= total * 95, "caught {caught} of {total}");
}

#[test]
fn validator_catches_layout_errors() {
    let (tree, t) = soup_tree();
    let inner = tree
        .nodes
        .iter()
        .position(|n| !n.is_leaf() && n.a > 2)
        .unwrap();

    // Split plane outside its node's box.
    let mut bad = tree.clone();
    let axis = bad.nodes[inner].kind as usize;
    bad.nodes[inner].split = node_boxes(&tree)[inner].max[axis] + 0.5;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::SplitOutsideBox { node, .. }) if node as usize == inner
    ));
    let mut bad = tree.clone();
    bad.nodes[0].split = f32::NAN;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::SplitOutsideBox { node: 0, .. })
    ));

    // A split moved to the boundary of its box (still inside, inclusive) breaks coverage.
    let twig = (0..tree.nodes.len())
        .find(|&i| {
            let n = tree.nodes[i];
            !n.is_leaf()
                && tree.nodes[n.a as usize].is_leaf()
                && tree.nodes[n.a as usize].b > 0
                && tree.nodes[n.a as usize + 1].is_leaf()
        })
        .unwrap();
    let mut bad = tree.clone();
    let axis = bad.nodes[twig].kind as usize;
    bad.nodes[twig].split = node_boxes(&tree)[twig].max[axis];
    assert!(
        matches!(validate(&bad, &t), Err(ValidationError::MissingReference { leaf, .. }) if leaf == tree.nodes[twig].a),
        "{:?}",
        validate(&bad, &t)
    );

    // Dangling child index.
    let mut bad = tree.clone();
    bad.nodes[inner].a = tree.nodes.len() as u32 + 5;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::ChildOutOfRange { .. })
    ));
    // Child before its parent, and a node that is two nodes' child.
    let mut bad = tree.clone();
    bad.nodes[inner].a = 0;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::ChildBeforeParent { .. })
    ));
    let mut bad = tree.clone();
    let other = tree.nodes[inner + 1..]
        .iter()
        .position(|n| !n.is_leaf())
        .unwrap()
        + inner
        + 1;
    bad.nodes[other].a = tree.nodes[inner].a;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::SharedChild { .. } | ValidationError::Orphan { .. })
    ));
    // Not breadth-first: a depth-3 node stored before a depth-2 node (depth-first order).
    let unit = Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    };
    let dfs = KdTree {
        nodes: vec![
            KdNode::inner(0, 0.5, 1),
            KdNode::inner(0, 0.25, 3),
            KdNode::inner(0, 0.75, 7),
            KdNode::inner(0, 0.125, 5),
            KdNode::leaf(0, 0),
            KdNode::leaf(0, 0),
            KdNode::leaf(0, 0),
            KdNode::leaf(0, 0),
            KdNode::leaf(0, 0),
        ],
        prim_refs: vec![],
        bounds: unit,
        primitives: 0,
    };
    assert!(matches!(
        validate(&dfs, &[]),
        Err(ValidationError::NotBreadthFirst { node: 7, .. })
    ));
    // The same tree in breadth-first order is fine.
    let mut bfs = dfs.clone();
    bfs.nodes[2].a = 5;
    bfs.nodes[3].a = 7;
    validate(&bfs, &[]).unwrap();

    // Leaf range, reference out of range, duplicate reference, wrong count, bad kind.
    let leaf = tree
        .nodes
        .iter()
        .position(|n| n.is_leaf() && n.b > 1)
        .unwrap();
    let mut bad = tree.clone();
    bad.nodes[leaf].b = tree.prim_refs.len() as u32 + 1;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::LeafRange { .. })
    ));
    let mut bad = tree.clone();
    bad.prim_refs[tree.nodes[leaf].a as usize] = 400;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::RefOutOfRange { prim: 400, .. })
    ));
    let mut bad = tree.clone();
    let first = tree.nodes[leaf].a as usize;
    bad.prim_refs[first + 1] = bad.prim_refs[first];
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::DuplicateRef { .. })
    ));
    assert!(matches!(
        validate(&tree, &t[..399]),
        Err(ValidationError::PrimitiveCount { .. })
    ));
    let mut bad = tree.clone();
    bad.nodes[inner].kind = LEAF + 1;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::BadKind { .. })
    ));
    // Bounds that miss a vertex.
    let mut bad = tree.clone();
    bad.bounds.max.x -= 0.01;
    assert!(matches!(
        validate(&bad, &t),
        Err(ValidationError::OutsideBounds { .. } | ValidationError::SplitOutsideBox { .. })
    ));
    // Every message names the culprit.
    let e = validate(&without_ref(&tree, 0), &t)
        .unwrap_err()
        .to_string();
    assert!(e.contains("primitive") && e.contains("leaf"), "{e}");
}

// ---------------------------------------------------------------------------------------
// Reference scenes

#[test]
fn stanford_bunny() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/stanford-bunny.obj");
    if !path.exists() {
        eprintln!("skipped: {} not found", path.display());
        return;
    }
    let scene = Scene::load(&path).unwrap().scene;
    let t = scene.triangles_world(scene.camera.shutter_open);
    assert_eq!(t.len(), 69_451);
    let p = params();
    let _ = full_clip::build(&t, &p); // warm up caches and the allocator
    let (tree, s) = check("stanford bunny", &t, &p);
    check_rays("stanford bunny", &tree, &t, 200, 69);
    let best = (0..3)
        .map(|_| {
            let t0 = Instant::now();
            std::hint::black_box(full_clip::build(&t, &p));
            t0.elapsed()
        })
        .min()
        .unwrap();
    eprintln!(
        "bunny: build {:.1} ms (best of 3), SAH {:.3}, nodes {}, leaves {} ({} empty), \
         max depth {}, avg leaf depth {:.2}, refs/prim {:.3}, {} KiB\n{}",
        ms(best),
        s.sah_cost,
        s.nodes,
        s.leaves,
        s.empty_leaves,
        s.max_depth,
        s.avg_leaf_depth,
        s.refs_per_primitive,
        s.bytes / 1024,
        serde_json::to_string(&s).unwrap()
    );
    assert!(s.sah_cost > 5.0 && s.sah_cost < 200.0, "SAH {}", s.sah_cost);
}

/// Sochora's (2013) "Icosahedron" scale: the build and the validator stay practical at 1 M.
#[test]
fn one_million_triangle_icosphere() {
    let t = tris(&gen::icosphere_with_at_least(1_000_000).unwrap());
    let (_, s) = check("icosphere ≥ 1M", &t, &params());
    eprintln!("{}", serde_json::to_string(&s).unwrap());
    assert!(s.sah_cost < 200.0 && s.refs_per_primitive < 8.0);
}

#[test]
#[ignore = "1 M-triangle random soup: ~25 s build + validate on 2 shared cores; run with --ignored"]
fn one_million_triangle_soup() {
    let t = tris(&gen::random_soup(1_000_000, 1).unwrap());
    check("random_soup(1M)", &t, &params());
}
