//! The CPU SAH BVH builder of Sochora (2013): top-down, greedy, binary object splits.
//!
//! Each node keeps its primitives in three index arrays sorted by box centroid along x, y
//! and z (ties by primitive id), sorted once at the root and stably partitioned at every
//! split, so no node sorts again (O(n log n) in all). A split is "the first `i` primitives
//! of axis `k`'s order go left"; it is found either
//! - by the **full sweep** of Sochora (2013) over all n − 1 positions of every axis: areas of the
//!   right-hand boxes accumulated right to left, then a left-to-right sweep that grows the
//!   left box, or
//! - **binned** (Wald 2007): centroids into `bins` equal slabs of the node's centroid box
//!   per axis, splits only between bins. Bins are monotone in the centroid, so a binned split
//!   is again a prefix of the axis order and partitions the same way.
//!
//! Cost model (one for kd-tree and BVH, relative to the node's area so that no division
//! is needed): splitting costs `C_trav·A + C_isect·(A_L·n_L + A_R·n_R)`, a leaf
//! `C_isect·A·n`, with A half surface areas. A node of one primitive is a leaf; a node of
//! more than `max_leaf_prims` is always split; in between, the cheaper wins.
//!
//! Threading (Sochora 2013, Chapter 4): [`Threading::Uneven`] hands the bigger child of a split
//! to a new thread with one core fewer and builds the other child without threads;
//! [`Threading::Even`] halves the free cores per child; [`Threading::Queue`] processes nodes
//! breadth-first from a shared queue with as many workers as cores and switches a node to
//! plain recursion once the queue holds 2·T items, or, for scenes under 500 K primitives,
//! below depth 4 (the thesis's conditions 2 and 4); [`Threading::Rayon`] is today's
//! work-stealing baseline. Split decisions depend only on the node's primitives and the
//! final layout is a depth-first walk of the decided tree, so every scheme and thread count
//! gives the same BVH, bit for bit.

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex};

use glam::Vec3;

use super::layout::{half_area, Bvh, BvhNode, Child, NO_NODE};
use crate::scene::Aabb;

/// Parameters of the SAH build.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct BvhParams {
    /// Cost of visiting a node (C_trav).
    pub traversal_cost: f32,
    /// Cost of one primitive intersection (C_isect).
    pub intersection_cost: f32,
    /// Nodes with more primitives are always split; up to this many the SAH decides.
    pub max_leaf_prims: u32,
    /// `None`: the exact full sweep; `Some(b)`: binned SAH with `b` bins (8 to 256).
    pub bins: Option<u32>,
}

impl Default for BvhParams {
    fn default() -> Self {
        Self {
            traversal_cost: 1.0,
            intersection_cost: 1.5,
            max_leaf_prims: 4,
            bins: None,
        }
    }
}

/// How the build uses threads (Sochora's (2013) three schemes and a rayon baseline).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Threading {
    /// Plain recursion on the calling thread.
    Single,
    /// The bigger child gets the new thread and all cores but one; the other none.
    Uneven {
        /// Threads in all, the calling one included (it starts `threads - 1`).
        threads: usize,
    },
    /// Free cores halved between the children.
    Even {
        /// Threads in all, the calling one included (it starts `threads - 1`).
        threads: usize,
    },
    /// Shared node queue, switching to recursion (conditions 2 and 4 of the thesis).
    Queue {
        /// Workers on the queue, the calling thread included.
        threads: usize,
    },
    /// `rayon::join` on every split above a size threshold.
    Rayon,
}

impl Threading {
    /// Sochora's (2013) winner, the node queue, on every core of this machine: what the CLI and
    /// the renderer build with.
    pub fn all_cores() -> Self {
        Threading::Queue {
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        }
    }

    /// Every scheme at `threads` threads, for tests and benchmarks.
    pub fn all(threads: usize) -> [Threading; 5] {
        [
            Threading::Single,
            Threading::Uneven { threads },
            Threading::Even { threads },
            Threading::Queue { threads },
            Threading::Rayon,
        ]
    }
}

/// Why a build was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BvhError {
    /// [`BvhParams::bins`] is outside 8 to 256.
    #[error("bins = {0}: binned SAH takes 8 to 256 bins")]
    Bins(u32),
    /// [`BvhParams::max_leaf_prims`] is 0.
    #[error("max_leaf_prims = 0: a leaf holds at least one primitive")]
    LeafSize,
    /// A cost is not finite and positive (the traversal and intersection costs given).
    #[error("SAH costs must be finite and positive (traversal {0}, intersection {1})")]
    Costs(f32, f32),
    /// A primitive's box (index, min, max) has a non-finite corner or `min > max` on an axis.
    #[error("primitive {0} has a box that is not finite (min {1}, max {2})")]
    BadBox(usize, Vec3, Vec3),
    /// More than 2^31 primitives (the count).
    #[error("{0} primitives: the layout indexes at most 2^31")]
    TooMany(usize),
}

/// Builds the BVH over primitive boxes (every box finite, `min <= max`).
pub fn build(boxes: &[Aabb], params: &BvhParams, threading: Threading) -> Result<Bvh, BvhError> {
    check(boxes, params)?;
    let n = boxes.len();
    let centroids: Vec<Vec3> = boxes.iter().map(|b| (b.min + b.max) * 0.5).collect();
    let mut order: [Vec<u32>; 3] = std::array::from_fn(|k| {
        let mut ids: Vec<u32> = (0..n as u32).collect();
        ids.sort_unstable_by(|&a, &b| key(&centroids, k, a).total_cmp_key(key(&centroids, k, b)));
        ids
    });
    let ctx = Ctx {
        boxes,
        centroids: &centroids,
        params: *params,
        threads: threading,
        queue_switch_depth: n < 500_000,
    };
    let bounds = boxes.iter().fold(Aabb::EMPTY, |mut acc, b| {
        acc.union(b);
        acc
    });
    if n == 0 {
        return Ok(Bvh {
            nodes: Vec::new(),
            parents: Vec::new(),
            refs: Vec::new(),
            bounds,
            wide: Default::default(),
        });
    }
    let [x, y, z] = &mut order;
    let root = Slices {
        axes: [x.as_mut_slice(), y.as_mut_slice(), z.as_mut_slice()],
        offset: 0,
        depth: 0,
    };
    let tree = match threading {
        Threading::Single => ctx.recurse(root),
        Threading::Uneven { threads } | Threading::Even { threads } => {
            ctx.spawning(root, threads.max(1) - 1)
        }
        Threading::Queue { threads } => ctx.queue(root, threads.max(1)),
        Threading::Rayon => ctx.rayon(root),
    };
    Ok(flatten(&tree, bounds, std::mem::take(&mut order[0])))
}

/// [`build`] and its wall time in milliseconds.
pub fn build_timed(
    boxes: &[Aabb],
    params: &BvhParams,
    threading: Threading,
) -> Result<(Bvh, f64), BvhError> {
    let start = std::time::Instant::now();
    let bvh = build(boxes, params, threading)?;
    Ok((bvh, start.elapsed().as_secs_f64() * 1e3))
}

fn check(boxes: &[Aabb], p: &BvhParams) -> Result<(), BvhError> {
    if let Some(b) = p.bins {
        if !(8..=256).contains(&b) {
            return Err(BvhError::Bins(b));
        }
    }
    if p.max_leaf_prims == 0 {
        return Err(BvhError::LeafSize);
    }
    let positive = |c: f32| c.is_finite() && c > 0.0;
    if !positive(p.traversal_cost) || !positive(p.intersection_cost) {
        return Err(BvhError::Costs(p.traversal_cost, p.intersection_cost));
    }
    if boxes.len() > 1 << 31 {
        return Err(BvhError::TooMany(boxes.len()));
    }
    for (i, b) in boxes.iter().enumerate() {
        if !(b.min.is_finite() && b.max.is_finite() && b.min.cmple(b.max).all()) {
            return Err(BvhError::BadBox(i, b.min, b.max));
        }
    }
    Ok(())
}

/// Sort key of a primitive along an axis: centroid, then id.
#[derive(Clone, Copy)]
struct Key(f32, u32);

impl Key {
    fn total_cmp_key(self, other: Key) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0).then(self.1.cmp(&other.1))
    }
}

fn key(centroids: &[Vec3], axis: usize, id: u32) -> Key {
    Key(centroids[id as usize][axis], id)
}

/// The decided tree before layout: leaves are ranges of the final x order.
enum Tmp {
    Leaf {
        bounds: Aabb,
        start: u32,
        count: u32,
    },
    Inner {
        bounds: Aabb,
        kids: Box<[Tmp; 2]>,
    },
}

impl Tmp {
    fn bounds(&self) -> Aabb {
        match self {
            Tmp::Leaf { bounds, .. } | Tmp::Inner { bounds, .. } => *bounds,
        }
    }
}

/// A node's primitives: its ranges of the three axis orders, where they start in the whole
/// order, and its depth.
struct Slices<'a> {
    axes: [&'a mut [u32]; 3],
    offset: u32,
    depth: u32,
}

enum Decision<'a> {
    Leaf(Tmp),
    Split(Aabb, Slices<'a>, Slices<'a>),
}

struct Ctx<'a> {
    boxes: &'a [Aabb],
    centroids: &'a [Vec3],
    params: BvhParams,
    threads: Threading,
    /// Sochora's (2013) condition 4 (depth) for scenes under 500 K primitives, else condition 2.
    queue_switch_depth: bool,
}

/// Deepest leaf (root children have depth 1): the bitstack traversal keeps one bit per
/// level in 64 bits. Nodes that could otherwise end deeper split at the object median.
pub const MAX_DEPTH: usize = 64;

fn ceil_log2(n: usize) -> usize {
    n.next_power_of_two().trailing_zeros() as usize
}

/// Below this many primitives rayon builds a subtree on one thread.
const RAYON_SEQUENTIAL_BELOW: usize = 4096;

impl<'a> Ctx<'a> {
    fn union_of(&self, ids: &[u32]) -> Aabb {
        ids.iter().fold(Aabb::EMPTY, |mut acc, &i| {
            acc.union(&self.boxes[i as usize]);
            acc
        })
    }

    /// Leaf or split, and the split's two halves (the three orders stably partitioned).
    fn decide<'s>(&self, s: Slices<'s>) -> Decision<'s> {
        let n = s.axes[0].len();
        let bounds = self.union_of(s.axes[0]);
        let leaf = |s: &Slices<'_>| Tmp::Leaf {
            bounds,
            start: s.offset,
            count: n as u32,
        };
        if n <= 1 {
            return Decision::Leaf(leaf(&s));
        }
        let p = &self.params;
        let (axis, at, cost) = if s.depth as usize + ceil_log2(n) + 1 >= MAX_DEPTH {
            self.median(&s)
        } else {
            match p.bins {
                None => self.sweep(&s),
                Some(bins) => self.binned(&s, bins),
            }
        };
        let area = half_area(&bounds);
        let split_cost = p.traversal_cost * area + p.intersection_cost * cost;
        let leaf_cost = p.intersection_cost * area * n as f32;
        if n <= p.max_leaf_prims as usize && leaf_cost <= split_cost {
            return Decision::Leaf(leaf(&s));
        }
        let (l, r) = self.partition(s, axis, at);
        Decision::Split(bounds, l, r)
    }

    /// Object median along the axis of the widest centroid spread: what keeps the tree
    /// within [`MAX_DEPTH`] when the SAH would split off few primitives at a time.
    fn median(&self, s: &Slices<'_>) -> (usize, usize, f32) {
        let n = s.axes[0].len();
        let cb = s.axes[0].iter().fold(Aabb::EMPTY, |mut acc, &i| {
            acc.grow(self.centroids[i as usize]);
            acc
        });
        let spread = cb.max - cb.min;
        let axis = (0..3).fold(0, |a, k| if spread[k] > spread[a] { k } else { a });
        let (l, r) = s.axes[axis].split_at(n / 2);
        let cost = half_area(&self.union_of(l)) * l.len() as f32
            + half_area(&self.union_of(r)) * r.len() as f32;
        (axis, n / 2, cost)
    }

    /// The full sweep: the best `(axis, i, A_L·n_L + A_R·n_R)` over every position.
    fn sweep(&self, s: &Slices<'_>) -> (usize, usize, f32) {
        let n = s.axes[0].len();
        let mut best = (0, n / 2, f32::INFINITY);
        let mut right_area = vec![0.0f32; n];
        for (axis, ids) in s.axes.iter().enumerate() {
            let mut acc = Aabb::EMPTY;
            for i in (1..n).rev() {
                acc.union(&self.boxes[ids[i] as usize]);
                right_area[i] = half_area(&acc);
            }
            let mut left = Aabb::EMPTY;
            for i in 1..n {
                left.union(&self.boxes[ids[i - 1] as usize]);
                let cost = half_area(&left) * i as f32 + right_area[i] * (n - i) as f32;
                if cost < best.2 {
                    best = (axis, i, cost);
                }
            }
        }
        best
    }

    /// Binned SAH: splits between `bins` slabs of the centroid box per axis; a degenerate
    /// centroid box (every centroid alike) splits at the median of the x order.
    fn binned(&self, s: &Slices<'_>, bins: u32) -> (usize, usize, f32) {
        let n = s.axes[0].len();
        let cb = s.axes[0].iter().fold(Aabb::EMPTY, |mut acc, &i| {
            acc.grow(self.centroids[i as usize]);
            acc
        });
        let mut best = (0, n / 2, f32::INFINITY);
        let b = bins as usize;
        let mut count = vec![0usize; b];
        let mut boxes = vec![Aabb::EMPTY; b];
        let mut right_area = vec![0.0f32; b];
        for (axis, ids) in s.axes.iter().enumerate() {
            let (lo, extent) = (cb.min[axis], cb.max[axis] - cb.min[axis]);
            if extent <= 0.0 || extent.is_nan() {
                continue;
            }
            count.fill(0);
            boxes.fill(Aabb::EMPTY);
            let scale = bins as f32 / extent;
            let bin =
                |i: u32| (((self.centroids[i as usize][axis] - lo) * scale) as usize).min(b - 1);
            for &i in ids.iter() {
                let k = bin(i);
                count[k] += 1;
                boxes[k].union(&self.boxes[i as usize]);
            }
            let mut acc = Aabb::EMPTY;
            for k in (1..b).rev() {
                acc.union(&boxes[k]);
                right_area[k] = half_area(&acc);
            }
            let (mut left, mut n_left) = (Aabb::EMPTY, 0);
            for k in 1..b {
                left.union(&boxes[k - 1]);
                n_left += count[k - 1];
                if n_left == 0 || n_left == n {
                    continue;
                }
                let cost = half_area(&left) * n_left as f32 + right_area[k] * (n - n_left) as f32;
                if cost < best.2 {
                    best = (axis, n_left, cost);
                }
            }
        }
        if best.2.is_infinite() {
            // Every centroid in one point: the median, costed like any split.
            let (l, r) = s.axes[0].split_at(n / 2);
            let cost = half_area(&self.union_of(l)) * l.len() as f32
                + half_area(&self.union_of(r)) * r.len() as f32;
            best = (0, n / 2, cost);
        }
        best
    }

    /// The first `at` of axis `axis`'s order go left; the other two orders are stably
    /// partitioned by comparing with the last left key.
    fn partition<'s>(&self, s: Slices<'s>, axis: usize, at: usize) -> (Slices<'s>, Slices<'s>) {
        let pivot = key(self.centroids, axis, s.axes[axis][at - 1]);
        let goes_left = |id: u32| key(self.centroids, axis, id).total_cmp_key(pivot).is_le();
        let mut spill = Vec::new();
        let [a0, a1, a2] = s.axes;
        let (l0, r0) = split_at(a0, at, &goes_left, &mut spill);
        let (l1, r1) = split_at(a1, at, &goes_left, &mut spill);
        let (l2, r2) = split_at(a2, at, &goes_left, &mut spill);
        let left = Slices {
            axes: [l0, l1, l2],
            offset: s.offset,
            depth: s.depth + 1,
        };
        let right = Slices {
            axes: [r0, r1, r2],
            offset: s.offset + at as u32,
            depth: s.depth + 1,
        };
        (left, right)
    }

    fn recurse(&self, s: Slices<'_>) -> Tmp {
        match self.decide(s) {
            Decision::Leaf(t) => t,
            Decision::Split(bounds, l, r) => Tmp::Inner {
                bounds,
                kids: Box::new([self.recurse(l), self.recurse(r)]),
            },
        }
    }

    /// Sochora's (2013) uneven and even thread assignment; `cores` = threads this call may start.
    fn spawning(&self, s: Slices<'_>, cores: usize) -> Tmp {
        if cores == 0 {
            return self.recurse(s);
        }
        match self.decide(s) {
            Decision::Leaf(t) => t,
            Decision::Split(bounds, l, r) => {
                let kids = std::thread::scope(|scope| match self.threads {
                    Threading::Uneven { .. } => {
                        // The bigger child takes the new thread and the cores left.
                        let left_bigger = l.axes[0].len() >= r.axes[0].len();
                        let (big, small) = if left_bigger { (l, r) } else { (r, l) };
                        let spawned = scope.spawn(move || self.spawning(big, cores - 1));
                        let here = self.recurse(small);
                        let big = spawned.join().expect("BVH build thread panicked");
                        if left_bigger {
                            [big, here]
                        } else {
                            [here, big]
                        }
                    }
                    _ => {
                        // Even: odd -> both get cores / 2; even -> the new thread's child one
                        // fewer.
                        let (to_left, to_right) = if cores % 2 == 1 {
                            (cores / 2, cores / 2)
                        } else {
                            (cores / 2 - 1, cores / 2)
                        };
                        let spawned = scope.spawn(move || self.spawning(l, to_left));
                        let right = self.spawning(r, to_right);
                        [spawned.join().expect("BVH build thread panicked"), right]
                    }
                });
                Tmp::Inner {
                    bounds,
                    kids: Box::new(kids),
                }
            }
        }
    }

    fn rayon(&self, s: Slices<'_>) -> Tmp {
        if s.axes[0].len() < RAYON_SEQUENTIAL_BELOW {
            return self.recurse(s);
        }
        match self.decide(s) {
            Decision::Leaf(t) => t,
            Decision::Split(bounds, l, r) => {
                let (a, b) = rayon::join(|| self.rayon(l), || self.rayon(r));
                Tmp::Inner {
                    bounds,
                    kids: Box::new([a, b]),
                }
            }
        }
    }

    /// Sochora's (2013) node queue: breadth-first from a shared queue, subtrees recursive once
    /// the switch condition holds.
    fn queue(&self, root: Slices<'_>, threads: usize) -> Tmp {
        struct State<'s> {
            items: VecDeque<(usize, Slices<'s>)>,
            busy: usize,
        }
        enum Slot {
            Pending,
            Done(Tmp),
            Inner(Aabb, usize, usize),
        }
        let state = Mutex::new(State {
            items: VecDeque::from([(0, root)]),
            busy: 0,
        });
        let wake = Condvar::new();
        let slots = Mutex::new(vec![Slot::Pending]);
        let worker = || loop {
            let (slot, item, queued) = {
                let mut st = state.lock().unwrap();
                loop {
                    if let Some((slot, item)) = st.items.pop_front() {
                        st.busy += 1;
                        let queued = st.items.len();
                        break (slot, item, queued);
                    }
                    if st.busy == 0 {
                        return;
                    }
                    st = wake.wait(st).unwrap();
                }
            };
            let switch = if self.queue_switch_depth {
                item.depth > 4
            } else {
                queued >= 2 * threads
            };
            let result = if switch {
                Slot::Done(self.recurse(item))
            } else {
                match self.decide(item) {
                    Decision::Leaf(t) => Slot::Done(t),
                    Decision::Split(bounds, l, r) => {
                        let (a, b) = {
                            let mut s = slots.lock().unwrap();
                            s.push(Slot::Pending);
                            s.push(Slot::Pending);
                            (s.len() - 2, s.len() - 1)
                        };
                        let mut st = state.lock().unwrap();
                        st.items.push_back((a, l));
                        st.items.push_back((b, r));
                        wake.notify_all();
                        Slot::Inner(bounds, a, b)
                    }
                }
            };
            slots.lock().unwrap()[slot] = result;
            let mut st = state.lock().unwrap();
            st.busy -= 1;
            if st.busy == 0 && st.items.is_empty() {
                wake.notify_all();
            }
        };
        std::thread::scope(|scope| {
            for _ in 1..threads {
                scope.spawn(worker);
            }
            worker();
        });
        let mut slots: Vec<Option<Slot>> =
            slots.into_inner().unwrap().into_iter().map(Some).collect();
        fn assemble(slots: &mut [Option<Slot>], i: usize) -> Tmp {
            match slots[i].take().expect("each slot is assembled once") {
                Slot::Done(t) => t,
                Slot::Inner(bounds, a, b) => Tmp::Inner {
                    bounds,
                    kids: Box::new([assemble(slots, a), assemble(slots, b)]),
                },
                Slot::Pending => unreachable!("the queue ran dry with a node unbuilt"),
            }
        }
        assemble(&mut slots, 0)
    }
}

/// `ids` stably partitioned by `goes_left` (exactly `at` go left), split there.
fn split_at<'s>(
    ids: &'s mut [u32],
    at: usize,
    goes_left: &impl Fn(u32) -> bool,
    spill: &mut Vec<u32>,
) -> (&'s mut [u32], &'s mut [u32]) {
    stable_partition(ids, goes_left, spill);
    ids.split_at_mut(at)
}

/// Stable in-place partition of `ids` by `goes_left`, with `spill` as scratch.
fn stable_partition(ids: &mut [u32], goes_left: &impl Fn(u32) -> bool, spill: &mut Vec<u32>) {
    spill.clear();
    let mut w = 0;
    for r in 0..ids.len() {
        let id = ids[r];
        if goes_left(id) {
            ids[w] = id;
            w += 1;
        } else {
            spill.push(id);
        }
    }
    ids[w..].copy_from_slice(spill);
}

/// Depth-first layout: a node, then its first child's subtree, then its second's.
fn flatten(tree: &Tmp, bounds: Aabb, refs: Vec<u32>) -> Bvh {
    let mut bvh = Bvh {
        nodes: Vec::new(),
        parents: Vec::new(),
        refs,
        bounds,
        wide: Default::default(),
    };
    match tree {
        Tmp::Leaf { .. } => {
            let mut root = BvhNode::zeroed_node();
            root.set_child(0, tree.bounds(), child_of(tree, 0));
            root.set_child(1, Aabb::EMPTY, Child::None);
            bvh.nodes.push(root);
            bvh.parents.push(NO_NODE);
        }
        Tmp::Inner { .. } => {
            place(tree, NO_NODE, &mut bvh);
        }
    }
    bvh
}

fn child_of(t: &Tmp, node: u32) -> Child {
    match t {
        Tmp::Leaf { start, count, .. } => Child::Leaf {
            first: *start,
            count: *count,
        },
        Tmp::Inner { .. } => Child::Node(node),
    }
}

/// Places an interior node and its subtrees; returns its index.
fn place(t: &Tmp, parent: u32, bvh: &mut Bvh) -> u32 {
    let Tmp::Inner { kids, .. } = t else {
        unreachable!("only interior nodes are placed")
    };
    let me = bvh.nodes.len() as u32;
    bvh.nodes.push(BvhNode::zeroed_node());
    bvh.parents.push(parent);
    for (which, kid) in kids.iter().enumerate() {
        let index = match kid {
            Tmp::Inner { .. } => place(kid, me, bvh),
            Tmp::Leaf { .. } => 0,
        };
        bvh.nodes[me as usize].set_child(which, kid.bounds(), child_of(kid, index));
    }
    me
}

impl BvhNode {
    fn zeroed_node() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}
