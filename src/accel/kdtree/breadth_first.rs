//! The breadth-first SAH kd-tree build of Kolodzey (2014), on the CPU, pass for pass as the GPU
//! kernels run it: the oracle the GPU build must equal bit for bit.
//!
//! Phase I: primitive boxes, the scene box, six events per primitive (START and END on
//! each axis) in SoA arrays, each axis list sorted once by the total order
//! (plane, END before START, primitive id). Phase II, one level per iteration, every node
//! of the level at once:
//! 1. `split_costs`: per event, the START count before it (a flag scan) gives the
//!    primitives below and above its plane; the SAH of that plane on all three axes, the
//!    cheapest axis kept per event;
//! 2. `best_split`: a segmented argmin over each node's events (lowest cost, then lowest
//!    event index);
//! 3. `decide`: leaf or split (size, depth, no candidate, SAH leaf test);
//! 4. `leaves`: leaf primitive lists, written once, in axis-0 START order;
//! 5. `classify`: a clip-mask per event — below, above or both — and a flag scan over the
//!    virtual `[below | above]` slots of every node;
//! 6. `scatter`: one compaction moves each event record once per side, clipping its box
//!    only on the split axis; the lists stay sorted because they are stable
//!    subsequences of sorted lists, so they are never re-sorted;
//! 7. `children`: child boxes, counts and event ranges from the scan.
//!
//! Deviations from the thesis, each for determinism or robustness:
//! - event planes are never snapped to the split: a clipped event keeps its sort key and
//!   only its box is clipped; candidates outside the open interval of the node box are
//!   skipped. Lists therefore stay sorted with ties in (END, START, id) order;
//! - child sizes come from the classification (the scan), not from the SAH counts, so an
//!   approximate count at tied planes can cost quality but never corrupt the tree;
//! - the SAH is evaluated without division — `C_trav·A + C_isect·(A_L·n_L + A_R·n_R)`,
//!   with A the half surface area of the node — so it uses only +, − and ×, which Vulkan
//!   rounds exactly (GLSL `precise`, no FMA), and the CPU and GPU costs agree bit for bit;
//! - the SAH leaf test of pbrt (leaf when splitting costs at least intersecting all),
//!   switchable to reproduce Kolodzey's build.

use glam::Vec3;

use super::{Aabb, KdNode, KdTree, SahParams};
// The totally ordered min/max and the triangle box are the primitives' own (every builder
// boxes triangles alike); kept here under their old path.
pub use crate::accel::primitives::{fmax, fmin, prim_box};

/// Event type, also its sort rank at equal planes (END first).
pub const END: u8 = 0;
/// Event type of a primitive's box start (its minimum on the axis); sorts after [`END`].
pub const START: u8 = 1;

/// One axis list of events (SoA, as on the GPU).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Events {
    /// The event's plane on this axis (its primitive's unclipped box minimum or maximum).
    pub plane: Vec<f32>,
    /// [`START`] or [`END`].
    pub kind: Vec<u8>,
    /// The primitive the event belongs to.
    pub prim: Vec<u32>,
    /// The event's node: its index within the level being built.
    pub node: Vec<u32>,
    /// Minimum corner of the primitive's box, clipped by its node's ancestors' split planes.
    pub box_min: [Vec<f32>; 3],
    /// Maximum corner of the primitive's box, clipped by its node's ancestors' split planes.
    pub box_max: [Vec<f32>; 3],
}

impl Events {
    fn len(&self) -> usize {
        self.plane.len()
    }

    fn with_capacity(n: usize) -> Self {
        let f = || Vec::with_capacity(n);
        Self {
            plane: f(),
            kind: Vec::with_capacity(n),
            prim: Vec::with_capacity(n),
            node: Vec::with_capacity(n),
            box_min: [f(), f(), f()],
            box_max: [f(), f(), f()],
        }
    }
}

/// The nodes of the level being built (SoA).
#[derive(Clone, Debug, Default)]
struct Level {
    box_min: Vec<Vec3>,
    box_max: Vec<Vec3>,
    /// First primitive reference: the node's events are `[2·first, 2·(first + count))`.
    first: Vec<u32>,
    count: Vec<u32>,
}

/// Per-phase work counters of one build (what the GPU profile times).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct BuildTrace {
    /// Levels built (iterations of Phase II).
    pub levels: u32,
    /// Primitive references per level (events per axis / 2).
    pub refs_per_level: Vec<u32>,
    /// Nodes per level.
    pub nodes_per_level: Vec<u32>,
}

/// `C_trav·A + C_isect·(A_L·n_L + A_R·n_R)` (times λ when a side is empty), where the A
/// are half surface areas: the SAH scaled by the node's area, free of division. `+∞`
/// when the plane is not strictly inside the node box. The GLSL twin is
/// `sah_scaled` in `glsl/accel/kdtree/level.glsl`: keep the operation order identical.
pub fn sah_scaled(
    min: Vec3,
    max: Vec3,
    axis: usize,
    plane: f32,
    below: u32,
    above: u32,
    p: &SahParams,
) -> f32 {
    if !(plane > min[axis] && plane < max[axis]) {
        return f32::INFINITY;
    }
    let d = max - min;
    let area = d.x * d.y + d.y * d.z + d.z * d.x;
    let mut dl = d;
    dl[axis] = plane - min[axis];
    let mut dr = d;
    dr[axis] = max[axis] - plane;
    let area_l = dl.x * dl.y + dl.y * dl.z + dl.z * dl.x;
    let area_r = dr.x * dr.y + dr.y * dr.z + dr.z * dr.x;
    let cost = p.traversal_cost * area
        + p.intersection_cost * (area_l * below as f32 + area_r * above as f32);
    if below == 0 || above == 0 {
        cost * p.empty_bonus
    } else {
        cost
    }
}

/// A sphere's box, `center ± radius`, exactly as `accel.kdtree_sphere_boxes` computes it
/// (one correctly rounded add or subtract per bound).
pub fn sphere_box(center: Vec3, radius: f32) -> Aabb {
    Aabb {
        min: Vec3::new(center.x - radius, center.y - radius, center.z - radius),
        max: Vec3::new(center.x + radius, center.y + radius, center.z + radius),
    }
}

/// The union of boxes, as the GPU min/max reductions compute it.
pub fn bounds_of(boxes: &[Aabb]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for x in boxes {
        for a in 0..3 {
            b.min[a] = fmin(b.min[a], x.min[a]);
            b.max[a] = fmax(b.max[a], x.max[a]);
        }
    }
    b
}

/// Phase I: the three sorted axis lists for `boxes`.
pub fn initial_events(boxes: &[Aabb]) -> [Events; 3] {
    std::array::from_fn(|axis| {
        let n = boxes.len();
        // Generated END-major (all ENDs by primitive id, then all STARTs), so a stable sort
        // by plane alone yields the total order (plane, END before START, id).
        let mut order: Vec<u32> = (0..2 * n as u32).collect();
        let plane_of = |i: u32| {
            let (kind, prim) = ((i as usize) / n.max(1), (i as usize) % n.max(1));
            if kind as u8 == START {
                boxes[prim].min[axis]
            } else {
                boxes[prim].max[axis]
            }
        };
        order.sort_by(|&a, &b| plane_of(a).total_cmp(&plane_of(b)));
        let mut ev = Events::with_capacity(2 * n);
        for i in order {
            let (kind, prim) = ((i as usize) / n, (i as usize) % n);
            ev.plane.push(plane_of(i));
            ev.kind.push(kind as u8);
            ev.prim.push(prim as u32);
            ev.node.push(0);
            for a in 0..3 {
                ev.box_min[a].push(boxes[prim].min[a]);
                ev.box_max[a].push(boxes[prim].max[a]);
            }
        }
        ev
    })
}

/// Builds the tree of `triangles` with the breadth-first algorithm.
pub fn build(triangles: &[[Vec3; 3]], params: &SahParams) -> (KdTree, BuildTrace) {
    let boxes: Vec<Aabb> = triangles.iter().map(prim_box).collect();
    build_boxes(&boxes, params)
}

/// Builds the tree over primitive boxes.
#[allow(
    clippy::needless_range_loop,
    reason = "one event per iteration, as one per invocation in the kernel"
)]
pub fn build_boxes(boxes: &[Aabb], params: &SahParams) -> (KdTree, BuildTrace) {
    let n = boxes.len();
    let bounds = bounds_of(boxes);
    let mut tree = KdTree {
        nodes: Vec::new(),
        prim_refs: Vec::new(),
        bounds,
        primitives: n as u32,
    };
    let mut trace = BuildTrace::default();
    if n == 0 {
        tree.nodes.push(KdNode::leaf(0, 0));
        return (tree, trace);
    }
    let depth_limit = params.depth_limit(n);
    let mut events = initial_events(boxes);
    let mut level = Level {
        box_min: vec![bounds.min],
        box_max: vec![bounds.max],
        first: vec![0],
        count: vec![n as u32],
    };
    let mut depth = 0;
    while !level.count.is_empty() {
        let m = level.count.len();
        trace.levels += 1;
        trace.refs_per_level.push((events[0].len() / 2) as u32);
        trace.nodes_per_level.push(m as u32);
        let level_base = tree.nodes.len() as u32;
        let next_base = level_base + m as u32;

        // 1. split_costs
        let starts_before: [Vec<u32>; 3] =
            std::array::from_fn(|a| exclusive_scan_u8(&events[a].kind));
        let (cost, axis_of) = split_costs(&events, &starts_before, &level, params);
        // 2. best_split (segmented argmin)
        let best: Vec<(f32, u32)> = (0..m)
            .map(|i| {
                let lo = 2 * level.first[i] as usize;
                let hi = lo + 2 * level.count[i] as usize;
                argmin(&cost[lo..hi], lo as u32)
            })
            .collect();
        // 3. decide
        let is_leaf: Vec<bool> = (0..m)
            .map(|i| {
                let c = level.count[i];
                let d = level.box_max[i] - level.box_min[i];
                let area = d.x * d.y + d.y * d.z + d.z * d.x;
                c <= params.max_leaf_prims
                    || depth >= depth_limit
                    || best[i].0 == f32::INFINITY
                    || (params.sah_leaf_test
                        && best[i].0 >= params.intersection_cost * c as f32 * area)
            })
            .collect();
        // (Leaves may be empty: their argmin index points past their events.)
        let split_axis: Vec<usize> = (0..m)
            .map(|i| {
                if is_leaf[i] {
                    0
                } else {
                    axis_of[best[i].1 as usize] as usize
                }
            })
            .collect();
        let split_plane: Vec<f32> = (0..m)
            .map(|i| {
                if is_leaf[i] {
                    0.0
                } else {
                    events[split_axis[i]].plane[best[i].1 as usize]
                }
            })
            .collect();
        // Node records: inner children at 2·(inner nodes before); leaves' refs after all
        // earlier leaves.
        let inner_before =
            exclusive_scan_u32(&is_leaf.iter().map(|&l| u32::from(!l)).collect::<Vec<_>>());
        let leaf_refs_before = exclusive_scan_u32(
            &(0..m)
                .map(|i| if is_leaf[i] { level.count[i] } else { 0 })
                .collect::<Vec<_>>(),
        );
        let leaf_ref_base = tree.prim_refs.len() as u32;
        let total_leaf_refs = leaf_refs_before.last().copied().unwrap_or(0)
            + if is_leaf[m - 1] {
                level.count[m - 1]
            } else {
                0
            };
        for i in 0..m {
            tree.nodes.push(if is_leaf[i] {
                KdNode::leaf(leaf_ref_base + leaf_refs_before[i], level.count[i])
            } else {
                KdNode::inner(
                    split_axis[i] as u32,
                    split_plane[i],
                    next_base + 2 * inner_before[i],
                )
            });
        }
        // 4. leaves: axis-0 STARTs of leaf nodes, in list order.
        tree.prim_refs
            .resize((leaf_ref_base + total_leaf_refs) as usize, u32::MAX);
        let ev0 = &events[0];
        for id in 0..ev0.len() {
            let node = ev0.node[id] as usize;
            if is_leaf[node] && ev0.kind[id] == START {
                let rank = starts_before[0][id] - level.first[node];
                tree.prim_refs[(leaf_ref_base + leaf_refs_before[node] + rank) as usize] =
                    ev0.prim[id];
            }
        }
        // 5–6. classify and scatter, per axis list.
        let mut next_events: [Events; 3] = Default::default();
        let mut side_offsets = Vec::new();
        for a in 0..3 {
            let ev = &events[a];
            let mask = classify(ev, &is_leaf, &split_axis, &split_plane);
            let slots = virtual_slots(ev, &mask, &level);
            let offsets = exclusive_scan_u8(&slots);
            let total = offsets.last().copied().unwrap_or(0)
                + u32::from(slots.last().copied().unwrap_or(0));
            next_events[a] = scatter(
                ev,
                &mask,
                &offsets,
                total as usize,
                &level,
                &inner_before,
                &split_axis,
                &split_plane,
            );
            if a == 0 {
                side_offsets = offsets;
                side_offsets.push(total);
            }
        }
        // 7. children
        let mut next = Level::default();
        for i in 0..m {
            if is_leaf[i] {
                continue;
            }
            let base = 4 * level.first[i] as usize;
            let c2 = 2 * level.count[i] as usize;
            let (lo, mid, hi) = (
                side_offsets[base],
                side_offsets[base + c2],
                side_offsets[base + 2 * c2],
            );
            let (a, p) = (split_axis[i], split_plane[i]);
            let mut left_max = level.box_max[i];
            left_max[a] = p;
            let mut right_min = level.box_min[i];
            right_min[a] = p;
            next.box_min.extend([level.box_min[i], right_min]);
            next.box_max.extend([left_max, level.box_max[i]]);
            next.first.extend([lo / 2, mid / 2]);
            next.count.extend([(mid - lo) / 2, (hi - mid) / 2]);
        }
        events = next_events;
        level = next;
        depth += 1;
    }
    (tree, trace)
}

/// Per event: the cheapest of its three axes' split costs, and that axis.
#[allow(
    clippy::needless_range_loop,
    reason = "mirrors the GLSL kernel, one event per invocation"
)]
fn split_costs(
    events: &[Events; 3],
    starts_before: &[Vec<u32>; 3],
    level: &Level,
    p: &SahParams,
) -> (Vec<f32>, Vec<u8>) {
    let len = events[0].len();
    let mut cost = vec![f32::INFINITY; len];
    let mut axis_of = vec![0u8; len];
    for id in 0..len {
        let node = events[0].node[id] as usize;
        let (first, count) = (level.first[node], level.count[node]);
        for a in 0..3 {
            let ev = &events[a];
            let below = starts_before[a][id] - first;
            let ends_before = id as u32 - first - starts_before[a][id];
            let above = count - ends_before - u32::from(ev.kind[id] == END);
            let c = sah_scaled(
                level.box_min[node],
                level.box_max[node],
                a,
                ev.plane[id],
                below,
                above,
                p,
            );
            if c < cost[id] {
                cost[id] = c;
                axis_of[id] = a as u8;
            }
        }
    }
    (cost, axis_of)
}

/// Lowest cost, then lowest index; `(+∞, first)` when every cost is infinite.
fn argmin(costs: &[f32], first: u32) -> (f32, u32) {
    let mut best = (f32::INFINITY, first);
    for (i, &c) in costs.iter().enumerate() {
        if c < best.0 {
            best = (c, first + i as u32);
        }
    }
    best
}

/// Clip-mask bits.
pub const BELOW: u8 = 1;
/// Clip-mask bit of an event that goes to the child above the plane.
pub const ABOVE: u8 = 2;

/// Which child (or both) each event goes to; 0 for events of leaves.
fn classify(ev: &Events, is_leaf: &[bool], split_axis: &[usize], split_plane: &[f32]) -> Vec<u8> {
    (0..ev.len())
        .map(|id| {
            let node = ev.node[id] as usize;
            if is_leaf[node] {
                return 0;
            }
            let (s, p) = (split_axis[node], split_plane[node]);
            if ev.box_max[s][id] <= p {
                BELOW
            } else if ev.box_min[s][id] >= p {
                ABOVE
            } else {
                BELOW | ABOVE
            }
        })
        .collect()
}

/// The 0/1 flags of the virtual slots: node i owns `[4·first, 4·first + 2·count)` for its
/// below copies and the next `2·count` for its above copies, each at the event's local
/// index, so one exclusive scan gives every copy its place and keeps each list sorted.
#[allow(
    clippy::needless_range_loop,
    reason = "one event per iteration, as one per invocation in the kernel"
)]
fn virtual_slots(ev: &Events, mask: &[u8], level: &Level) -> Vec<u8> {
    let mut slots = vec![0u8; 2 * ev.len()];
    for id in 0..ev.len() {
        let node = ev.node[id] as usize;
        let (first, count) = (level.first[node] as usize, level.count[node] as usize);
        let local = id - 2 * first;
        slots[4 * first + local] = u8::from(mask[id] & BELOW != 0);
        slots[4 * first + 2 * count + local] = u8::from(mask[id] & ABOVE != 0);
    }
    slots
}

#[allow(
    clippy::too_many_arguments,
    reason = "named like the kernel's bindings"
)]
#[allow(
    clippy::needless_range_loop,
    reason = "one event per iteration, as one per invocation in the kernel"
)]
fn scatter(
    ev: &Events,
    mask: &[u8],
    offsets: &[u32],
    total: usize,
    level: &Level,
    inner_before: &[u32],
    split_axis: &[usize],
    split_plane: &[f32],
) -> Events {
    let mut out = Events {
        plane: vec![0.0; total],
        kind: vec![0; total],
        prim: vec![0; total],
        node: vec![0; total],
        box_min: std::array::from_fn(|_| vec![0.0; total]),
        box_max: std::array::from_fn(|_| vec![0.0; total]),
    };
    for id in 0..ev.len() {
        let node = ev.node[id] as usize;
        let (first, count) = (level.first[node] as usize, level.count[node] as usize);
        let local = id - 2 * first;
        for (side, bit) in [(0usize, BELOW), (1, ABOVE)] {
            if mask[id] & bit == 0 {
                continue;
            }
            let o = offsets[4 * first + side * 2 * count + local] as usize;
            out.plane[o] = ev.plane[id];
            out.kind[o] = ev.kind[id];
            out.prim[o] = ev.prim[id];
            out.node[o] = 2 * inner_before[node] + side as u32;
            for a in 0..3 {
                out.box_min[a][o] = ev.box_min[a][id];
                out.box_max[a][o] = ev.box_max[a][id];
            }
            let s = split_axis[node];
            if side == 0 {
                out.box_max[s][o] = fmin(out.box_max[s][o], split_plane[node]);
            } else {
                out.box_min[s][o] = fmax(out.box_min[s][o], split_plane[node]);
            }
        }
    }
    out
}

fn exclusive_scan_u8(flags: &[u8]) -> Vec<u32> {
    let mut sum = 0u32;
    flags
        .iter()
        .map(|&f| {
            let before = sum;
            sum += u32::from(f);
            before
        })
        .collect()
}

fn exclusive_scan_u32(values: &[u32]) -> Vec<u32> {
    let mut sum = 0u32;
    values
        .iter()
        .map(|&v| {
            let before = sum;
            sum += v;
            before
        })
        .collect()
}
