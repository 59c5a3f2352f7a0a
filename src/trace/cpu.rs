//! CPU twin of `vkrt_trace_ray` in `glsl/include/vkrt/traverse.glsl` (same decisions in the same
//! order), and brute force over every primitive: the oracle the traversal is tested against.

use glam::{Vec3, Vec4};

use super::intersect::{self, Shear, TriHit};
use super::{Hit, Intersector, Query, Ray, TraceOptions};
use crate::accel::kdtree::{KdTree, LEAF};
use crate::accel::primitives::TraceGeometry;
use crate::scene::Aabb;

/// Node visits + primitive tests per ray when [`TraceOptions::max_steps`] is `None`: the
/// default of `VKRT_MAX_TRAVERSAL_STEPS` in `vkrt/ray_query.glsl`, within lavapipe's loop
/// budget. A GPU tracer resolves `None` to the device's cap
/// ([`DeviceInfo::max_traversal_steps`](crate::gpu::DeviceInfo::max_traversal_steps)).
pub const DEFAULT_MAX_TRAVERSAL_STEPS: u32 = 60_000;
/// `PLANE_SLACK` in `traverse.glsl`.
pub const PLANE_SLACK: f32 = 4e-7;

/// Geometry plus its kd-tree: what a query runs against.
pub struct TraceScene<'a> {
    /// The primitives, by id.
    pub geometry: &'a TraceGeometry,
    /// The kd-tree built over `geometry`'s boxes.
    pub tree: &'a KdTree,
}

#[allow(
    clippy::too_many_arguments,
    reason = "the kernel's arguments, one by one"
)]
pub(crate) fn hit_primitive(
    g: &TraceGeometry,
    prim: u32,
    r: &Ray,
    sh: &Shear,
    time: f32,
    intersector: Intersector,
    exact: bool,
    tmin: f32,
    tmax: f32,
) -> Option<TriHit> {
    let n_tris = g.triangle_count();
    let (o, d) = (r.o(), r.d());
    if (prim as usize) < n_tris {
        let [p0, p1, p2] = g.triangle_at(prim as usize, time);
        match intersector {
            Intersector::Watertight => {
                intersect::triangle_watertight(exact, o, sh, p0, p1, p2, tmin, tmax)
            }
            Intersector::MollerTrumbore => intersect::triangle_moller(o, d, p0, p1, p2, tmin, tmax),
        }
    } else if (prim as usize) < n_tris + g.spheres.len() {
        let s: Vec4 = g.sphere_at(prim as usize - n_tris, time);
        intersect::sphere(o, d, s, tmin, tmax).map(|t| (t, 0.0, 0.0))
    } else {
        let b = &g.aabbs[prim as usize - n_tris - g.spheres.len()];
        intersect::aabb(o, d, b.min, b.max, tmin, tmax).map(|t| (t, 0.0, 0.0))
    }
}

/// `clip_to_box` in `traverse.glsl`: clips `[t0, t1]` to box `b`, false if the ray misses
/// it; parallel axes test only the origin, slabs are widened by [`PLANE_SLACK`]. `inv_d` is
/// `1 / d`. The kd-tree walk's scene box and every child box of the BVH walk.
pub(crate) fn clip_to_box(
    b: &Aabb,
    o: Vec3,
    d: Vec3,
    inv_d: Vec3,
    t0: &mut f32,
    t1: &mut f32,
) -> bool {
    for a in 0..3 {
        let (lo_b, hi_b) = (b.min[a], b.max[a]);
        if d[a] == 0.0 {
            if o[a] < lo_b || o[a] > hi_b {
                return false;
            }
            continue;
        }
        let ta = (lo_b - o[a]) * inv_d[a];
        let tb = (hi_b - o[a]) * inv_d[a];
        let (lo, hi) = (ta.min(tb), ta.max(tb));
        let lo_w = lo - lo.abs() * PLANE_SLACK;
        let hi_w = hi + hi.abs() * PLANE_SLACK;
        *t0 = t0.max(lo_w);
        *t1 = t1.min(hi_w);
    }
    *t0 <= *t1
}

fn clip_to_scene(r: &Ray, tree: &KdTree, t0: &mut f32, t1: &mut f32) -> bool {
    let d = r.d();
    clip_to_box(&tree.bounds, r.o(), d, Vec3::ONE / d, t0, t1)
}

struct Entry {
    node: u32,
    t0: f32,
    t1: f32,
}

/// A query's answer and whether it ran out of steps (then it is reported as a miss).
pub fn trace(s: &TraceScene, r: &Ray, time: f32, opt: &TraceOptions) -> (Hit, bool) {
    let g = s.geometry;
    let mut best = Hit::MISS;
    if !r.is_valid() || g.primitive_count() == 0 || s.tree.nodes.is_empty() {
        return (best, false);
    }
    let tmin = r.tmin.max(0.0);
    let (mut t0, mut t1) = (tmin, r.tmax);
    if !clip_to_scene(r, s.tree, &mut t0, &mut t1) {
        return (best, false);
    }
    let scene_t1 = t1;
    let sh = Shear::new(r.d());
    let (o, d) = (r.o(), r.d());
    let inv_d = Vec3::ONE / d;
    let mut best_t = r.tmax;
    let cap = opt.stack_size.max(1) as usize;
    let mut stack: std::collections::VecDeque<Entry> = std::collections::VecDeque::new();
    let mut dropped = false;
    let push = |stack: &mut std::collections::VecDeque<Entry>, e: Entry, dropped: &mut bool| {
        if stack.len() == cap {
            stack.pop_front();
            *dropped = true;
        }
        stack.push_back(e);
    };
    let (mut node, mut n0, mut n1) = (0u32, t0, t1);
    let mut step = 0u32;
    let max_steps = opt.max_steps();
    while step < max_steps {
        step += 1;
        let nd = s.tree.nodes[node as usize];
        if nd.kind != LEAF {
            let axis = nd.kind as usize;
            let (oa, da) = (o[axis], d[axis]);
            let below_first = oa < nd.split || (oa == nd.split && da <= 0.0);
            let (first, second) = if below_first {
                (nd.a, nd.a + 1)
            } else {
                (nd.a + 1, nd.a)
            };
            if da == 0.0 {
                if oa == nd.split {
                    push(
                        &mut stack,
                        Entry {
                            node: second,
                            t0: n0,
                            t1: n1,
                        },
                        &mut dropped,
                    );
                }
                node = first;
                continue;
            }
            if oa == nd.split && n0 <= 0.0 {
                // Starting on the plane: the ray enters `first` at once and touches `second`
                // at t = 0 only (primitives lying in the plane): `second` over [n0, n0]
                // first, then `first` over the whole interval.
                push(
                    &mut stack,
                    Entry {
                        node: first,
                        t0: n0,
                        t1: n1,
                    },
                    &mut dropped,
                );
                node = second;
                n1 = n0;
                continue;
            }
            let tp = (nd.split - oa) * inv_d[axis];
            let tp_lo = tp - tp.abs() * PLANE_SLACK;
            let tp_hi = tp + tp.abs() * PLANE_SLACK;
            if tp <= 0.0 || tp_lo > n1 {
                node = first;
                continue;
            }
            if tp_hi < n0 {
                node = second;
                continue;
            }
            push(
                &mut stack,
                Entry {
                    node: second,
                    t0: tp_lo.max(n0),
                    t1: n1,
                },
                &mut dropped,
            );
            node = first;
            n1 = tp_hi.min(n1);
            continue;
        }
        for i in nd.a..nd.a + nd.b {
            let prim = s.tree.prim_refs[i as usize];
            if let Some((t, u, v)) = hit_primitive(
                g,
                prim,
                r,
                &sh,
                time,
                opt.intersector,
                opt.exact,
                tmin,
                best_t,
            ) {
                if !best.is_hit() || t < best_t || (t == best_t && prim < best.prim) {
                    best = Hit { t, prim, u, v };
                    best_t = t;
                }
                if opt.query == Query::Any {
                    return (best, false);
                }
            }
        }
        step += nd.b;
        // No early exit on `best_t <= n1`: entries pushed for rays lying in or starting on a
        // split plane cover the same interval as this cell, and ties at equal t go to the
        // lowest id; the pop below skips every cell that starts beyond the best hit.
        let mut found = false;
        while let Some(e) = stack.pop_back() {
            if !best.is_hit() || e.t0 <= best_t {
                (node, n0, n1) = (e.node, e.t0, e.t1);
                found = true;
                break;
            }
        }
        if !found {
            if !dropped || n1 >= scene_t1 || (best.is_hit() && best_t <= n1) {
                return (best, false);
            }
            dropped = false;
            (node, n0, n1) = (0, n1, scene_t1);
        }
    }
    (best, true)
}

/// Every primitive against the ray: the closest hit (lowest id among equal `t`), or for
/// `Query::Any` whether any primitive is hit (the lowest id that is).
pub fn brute_force(g: &TraceGeometry, r: &Ray, time: f32, opt: &TraceOptions) -> Hit {
    let mut best = Hit::MISS;
    if !r.is_valid() {
        return best;
    }
    let sh = Shear::new(r.d());
    let tmin = r.tmin.max(0.0);
    let mut best_t = r.tmax;
    for prim in 0..g.primitive_count() as u32 {
        if let Some((t, u, v)) = hit_primitive(
            g,
            prim,
            r,
            &sh,
            time,
            opt.intersector,
            opt.exact,
            tmin,
            best_t,
        ) {
            if !best.is_hit() || t < best_t {
                best = Hit { t, prim, u, v };
                best_t = t;
                if opt.query == Query::Any {
                    return best;
                }
            }
        }
    }
    best
}
