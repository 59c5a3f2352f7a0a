//! BVH queries on the CPU: closest or any hit with a short stack, or with the stackless
//! bitstack traversal of Áfra & Szirmay-Kalos (2014) as Novák (2019, Algorithm 3) writes it:
//! parent links and one bit per level of the path from the root, "the other child is still
//! to visit". Same contract as the kd-tree
//! query (`super` module docs); the twin of the GLSL BVH traversal.

use glam::Vec3;

use super::cpu::{clip_to_box, hit_primitive};
use super::intersect::Shear;
use super::{Hit, Query, Ray, TraceOptions};
use crate::accel::bvh::layout::stack_entry_t;
use crate::accel::bvh::{Bvh, Child};
use crate::accel::primitives::TraceGeometry;
use crate::accel::walk::Traversal;
use crate::scene::Aabb;

/// Where the ray enters `b` within `[t0, t1]` (the kd-tree walk's slab test); `None` when
/// it misses.
fn enter(b: &Aabb, o: Vec3, d: Vec3, inv_d: Vec3, t0: f32, t1: f32) -> Option<f32> {
    let (mut lo_t, mut hi_t) = (t0, t1);
    clip_to_box(b, o, d, inv_d, &mut lo_t, &mut hi_t).then_some(lo_t)
}

struct Query1<'a> {
    g: &'a TraceGeometry,
    bvh: &'a Bvh,
    r: &'a Ray,
    sh: Shear,
    o: Vec3,
    d: Vec3,
    inv_d: Vec3,
    time: f32,
    opt: &'a TraceOptions,
    tmin: f32,
    best: Hit,
    steps: u32,
}

impl Query1<'_> {
    fn best_t(&self) -> f32 {
        if self.best.is_hit() {
            self.best.t
        } else {
            self.r.tmax
        }
    }

    /// Tests a leaf's primitives; true when an any-hit query is answered.
    fn leaf(&mut self, first: u32, count: u32) -> bool {
        self.steps += count;
        for &prim in &self.bvh.refs[first as usize..(first + count) as usize] {
            let o = self.opt;
            let hit = hit_primitive(
                self.g,
                prim,
                self.r,
                &self.sh,
                self.time,
                o.intersector,
                o.exact,
                self.tmin,
                self.best_t(),
            );
            if let Some((t, u, v)) = hit {
                let b = &self.best;
                // Deterministic winner among equal t: the lowest primitive id.
                if !b.is_hit() || t < b.t || (t == b.t && prim < b.prim) {
                    self.best = Hit { t, prim, u, v };
                }
                if o.query == Query::Any {
                    return true;
                }
            }
        }
        false
    }

    /// Visits node `n`'s children: leaves now, and returns the interior children the ray
    /// enters, nearer first (ties: child a first).
    fn children(&mut self, n: u32) -> Option<[Option<u32>; 2]> {
        self.steps += 1;
        let node = self.bvh.nodes[n as usize];
        let mut inner: [Option<(f32, u32)>; 2] = [None, None];
        for (which, slot) in inner.iter_mut().enumerate() {
            let (b, child) = node.child(which);
            let Some(t) = enter(&b, self.o, self.d, self.inv_d, self.tmin, self.best_t()) else {
                continue;
            };
            match child {
                Child::Leaf { first, count } => {
                    if self.leaf(first, count) {
                        return None;
                    }
                }
                Child::Node(c) => *slot = Some((t, c)),
                Child::None => {}
            }
        }
        Some(match inner {
            [Some(a), Some(b)] if b.0 < a.0 => [Some(b.1), Some(a.1)],
            [a, b] => {
                let a = a.map(|x| x.1);
                let b = b.map(|x| x.1);
                if a.is_some() {
                    [a, b]
                } else {
                    [b, None]
                }
            }
        })
    }

    /// Whether the ray still enters node `n`'s box, which is a child box of its parent.
    fn still_enters(&self, n: u32) -> bool {
        let p = self.bvh.parents[n as usize];
        let node = self.bvh.nodes[p as usize];
        let which = if node.child(0).1 == Child::Node(n) {
            0
        } else {
            1
        };
        let b = node.child(which).0;
        enter(&b, self.o, self.d, self.inv_d, self.tmin, self.best_t()).is_some()
    }
}

/// The query's answer and whether it ran out of steps (then it is reported as a miss).
pub fn trace(
    g: &TraceGeometry,
    bvh: &Bvh,
    r: &Ray,
    time: f32,
    opt: &TraceOptions,
    traversal: Traversal,
) -> (Hit, bool) {
    if !r.is_valid() || bvh.nodes.is_empty() {
        return (Hit::MISS, false);
    }
    let d = r.d();
    let mut q = Query1 {
        g,
        bvh,
        r,
        sh: Shear::new(d),
        o: r.o(),
        d,
        inv_d: Vec3::ONE / d,
        time,
        opt,
        tmin: r.tmin.max(0.0),
        best: Hit::MISS,
        steps: 0,
    };
    let done = match traversal {
        Traversal::Stack => stack(&mut q),
        Traversal::Bitstack => bitstack(&mut q),
        Traversal::Wide => wide_stack(&mut q),
    };
    if done {
        (q.best, false)
    } else {
        (Hit::MISS, true)
    }
}

/// The stack walk, "while-while" (Aila & Laine 2009), as the GPU runs it: descend through
/// interior nodes, the nearer child first (ties: child a) and the other one on the stack,
/// until a leaf is in hand; test it; pop. Entries keep the distance at which the ray enters
/// them, and one beyond the closest hit so far is dropped when popped. True when finished
/// within the step cap.
fn stack(q: &mut Query1<'_>) -> bool {
    walk_with_stack(q, |q, n, stack| {
        let node = q.bvh.nodes[n as usize];
        let best_t = q.best_t();
        let hit = |which: usize| {
            let (b, child) = node.child(which);
            if child == Child::None {
                return None;
            }
            enter(&b, q.o, q.d, q.inv_d, q.tmin, best_t).map(|t| (child, t))
        };
        match (hit(0), hit(1)) {
            (Some(a), Some(b)) => {
                let (near, far) = if b.1 < a.1 { (b, a) } else { (a, b) };
                stack.push(far);
                Some(near.0)
            }
            (Some(one), None) | (None, Some(one)) => Some(one.0),
            (None, None) => None,
        }
    })
}

/// The stack walk over the 4-wide nodes, as the GPU runs it (`trace_bvh_wide` in
/// `glsl/include/vkrt/bvh.glsl`): at a node the four children's decoded boxes are tested,
/// sorted by entry distance with the same five compare-exchanges (ties keep their order), the
/// ones entered pushed farthest first and the nearest taken; leaves are tested when in hand.
fn wide_stack(q: &mut Query1<'_>) -> bool {
    let wide = q.bvh.wide();
    walk_with_stack(q, |q, n, stack| {
        let node = &wide[n as usize];
        let best_t = q.best_t();
        let mut kids: [(f32, Child); 4] = std::array::from_fn(|k| {
            let (b, child) = node.child(k);
            match enter(&b, q.o, q.d, q.inv_d, q.tmin, best_t) {
                Some(t) if child != Child::None => (t, child),
                _ => (f32::INFINITY, Child::None),
            }
        });
        for (a, b) in [(0, 1), (2, 3), (0, 2), (1, 3), (1, 2)] {
            if kids[b].0 < kids[a].0 {
                kids.swap(a, b);
            }
        }
        for &(t, child) in kids[1..].iter().rev() {
            if child != Child::None {
                stack.push((child, t));
            }
        }
        match kids[0].1 {
            Child::None => None,
            near => Some(near),
        }
    })
}

/// The while-while loop both stack walks share: `expand(q, node, stack)` visits an interior
/// node, pushes the children that wait and returns the one to take next (`None`: pop).
fn walk_with_stack<'a>(
    q: &mut Query1<'a>,
    mut expand: impl FnMut(&Query1<'a>, u32, &mut Vec<(Child, f32)>) -> Option<Child>,
) -> bool {
    let mut stack: Vec<(Child, f32)> = Vec::new();
    let mut cur = Some(Child::Node(0));
    while let Some(c) = cur {
        match c {
            Child::Node(n) => {
                if q.steps > q.opt.max_steps() {
                    return false;
                }
                q.steps += 1;
                cur = match expand(q, n, &mut stack) {
                    Some(next) => Some(next),
                    None => pop(&mut stack, q.best_t()),
                };
            }
            Child::Leaf { first, count } => {
                if q.leaf(first, count) {
                    return true;
                }
                cur = pop(&mut stack, q.best_t());
            }
            Child::None => unreachable!("missing children are never visited"),
        }
    }
    true
}

/// The nearest stack entry the ray enters before `best_t`, its distance rounded down as the
/// GPU walks keep it ([`stack_entry_t`]).
fn pop(stack: &mut Vec<(Child, f32)>, best_t: f32) -> Option<Child> {
    while let Some((c, t)) = stack.pop() {
        if stack_entry_t(t) <= best_t {
            return Some(c);
        }
    }
    None
}

/// Novák's (2019) Algorithm 3 (the bitstack of Áfra & Szirmay-Kalos 2014): descend to the nearer child pushing a 1 bit when the farther one
/// waits, 0 otherwise; on a dead end climb the parent links to the deepest 1 bit and take
/// that level's other child (its box tested again against the best hit so far).
fn bitstack(q: &mut Query1<'_>) -> bool {
    // One bit per level: trees are at most MAX_TRAVERSAL_DEPTH (128) levels deep.
    let (mut node, mut trail) = (0u32, 0u128);
    loop {
        if q.steps > q.opt.max_steps() {
            return false;
        }
        let Some([near, far]) = q.children(node) else {
            return true;
        };
        if let Some(near) = near {
            trail = (trail << 1) | u128::from(far.is_some());
            node = near;
            continue;
        }
        // Dead end: back to the deepest level whose other child waits.
        loop {
            if trail == 0 {
                return true;
            }
            while trail & 1 == 0 {
                q.steps += 1;
                node = q.bvh.parents[node as usize];
                trail >>= 1;
            }
            trail ^= 1;
            let parent = q.bvh.nodes[q.bvh.parents[node as usize] as usize];
            let sibling = match (parent.child(0).1, parent.child(1).1) {
                (Child::Node(a), Child::Node(b)) => {
                    if a == node {
                        b
                    } else {
                        a
                    }
                }
                _ => unreachable!("a 1 bit marks a node with two interior children"),
            };
            q.steps += 1;
            if q.still_enters(sibling) {
                node = sibling;
                break;
            }
            node = sibling; // climb on from this level
        }
    }
}
