//! The 4-wide BVH: every binary node with its grandchildren pulled up, child boxes quantized
//! to 8 bits per plane in a power-of-two frame (Ylitie, Karras & Laine 2017, "Efficient
//! incoherent ray traversal on GPUs through compressed wide BVHs"). A node is 64 bytes, as a
//! binary node is, but decides four children: one fetch where the binary walk needs two or
//! three, the trade for boxes that are up to one 255th of the node's extent looser.
//!
//! Wide node `i` is made from binary node `i`: each interior child is replaced by its own two
//! children, leaves stay, so a wide level spans two binary levels and the wide tree is at
//! most half as deep (64 levels: the walk's stack holds 3 entries per level). Every binary
//! slot gets its wide node (the walk reaches those at even depth), so no pass has to find
//! the depths first: one parallel pass over the nodes (`accel.bvh_widen`, this module its
//! CPU twin, bit for bit) after every build and refit.
//!
//! Quantization: per axis, the origin `p` is the low corner of the children's union and the
//! scale `s = 2^(e − 127)` the smallest power of two with `p + 255·s ≥` the high corner; a
//! child's planes are the integers `q` whose decoded value `p + q·s` (one rounding: `q·s` is
//! exact) lies at or below its low plane and at or above its high plane. The encoder checks
//! the decoded values with the walk's own arithmetic, so the decoded box always contains the
//! child's box and no ray that enters the child misses it.

pub use super::layout::WideNode;
use super::layout::{Bvh, BvhNode, Child, NO_NODE};
use crate::scene::Aabb;

/// Children per node.
pub const WIDTH: usize = 4;

/// The largest leaf a wide node can name (16 bits per child).
pub const MAX_WIDE_LEAF: u32 = 0xffff;

impl WideNode {
    /// Child `k` and its decoded box.
    pub fn child(&self, k: usize) -> (Aabb, Child) {
        let count = (self.counts[k / 2] >> (16 * (k % 2))) & 0xffff;
        let child = match (count, self.index[k]) {
            (0, NO_NODE) => Child::None,
            (0, node) => Child::Node(node),
            (count, first) => Child::Leaf { first, count },
        };
        let mut b = Aabb::EMPTY;
        for a in 0..3 {
            let p = f32::from_bits(self.origin[a]);
            let s = scale((self.exponents >> (8 * a)) & 0xff);
            b.min[a] = decode(p, s, byte(self.lo[a], k));
            b.max[a] = decode(p, s, byte(self.hi[a], k));
        }
        (b, child)
    }
}

fn byte(word: u32, k: usize) -> u32 {
    (word >> (8 * k)) & 0xff
}

/// `2^(e − 127)` for a biased exponent `e` in 1..=254.
fn scale(e: u32) -> f32 {
    f32::from_bits(e << 23)
}

/// The plane `q` of a frame: `p + q·s`, one rounding (`q·s` is exact, so a fused
/// multiply-add gives the same bits).
fn decode(p: f32, s: f32, q: u32) -> f32 {
    p + q as f32 * s
}

/// Wide node `i` for every binary slot `i < n_slots` (children past `n_slots` count as
/// missing: slots a leaf collapse freed may hold stale links).
pub fn widen(nodes: &[BvhNode], n_slots: usize) -> Vec<WideNode> {
    (0..n_slots.min(nodes.len()))
        .map(|i| widen_node(nodes, n_slots, i))
        .collect()
}

/// The up to four children of binary node `i`: leaves of it, and the children of its
/// interior children, in order (a's before b's).
fn gather(nodes: &[BvhNode], n_slots: usize, i: usize) -> Vec<(Aabb, Child)> {
    let mut out = Vec::with_capacity(WIDTH);
    for which in 0..2 {
        match nodes[i].child(which) {
            (_, Child::None) => {}
            (b, leaf @ Child::Leaf { .. }) => out.push((b, leaf)),
            (_, Child::Node(c)) if c as usize >= n_slots => {}
            (_, Child::Node(c)) => {
                for grand in 0..2 {
                    let g = nodes[c as usize].child(grand);
                    let stale = matches!(g.1, Child::Node(x) if x as usize >= n_slots);
                    if g.1 != Child::None && !stale {
                        out.push(g);
                    }
                }
            }
        }
    }
    out
}

fn widen_node(nodes: &[BvhNode], n_slots: usize, i: usize) -> WideNode {
    let children = gather(nodes, n_slots, i);
    let mut union = Aabb::EMPTY;
    for (b, _) in &children {
        union = super::refit::union(&union, b);
    }
    let mut w = WideNode {
        index: [NO_NODE; 4],
        ..WideNode::default()
    };
    for a in 0..3 {
        let (p, e) = frame(union.min[a], union.max[a]);
        // The reciprocal scale exactly, from its exponent (no division).
        let (s, inv_s) = (scale(e), scale(254 - e));
        w.origin[a] = p.to_bits();
        w.exponents |= e << (8 * a);
        for (k, (b, _)) in children.iter().enumerate() {
            w.lo[a] |= quantize_lo(p, s, inv_s, b.min[a]) << (8 * k);
            w.hi[a] |= quantize_hi(p, s, inv_s, b.max[a]) << (8 * k);
        }
    }
    for (k, (_, c)) in children.iter().enumerate() {
        let (index, count) = match *c {
            Child::Node(n) => (n, 0),
            // Builders for the wide layout refuse larger leaves (`MAX_WIDE_LEAF`).
            Child::Leaf { first, count } => (first, count & MAX_WIDE_LEAF),
            Child::None => (NO_NODE, 0),
        };
        w.index[k] = index;
        w.counts[k / 2] |= count << (16 * (k % 2));
    }
    w
}

/// The frame of one axis spanning `[lo, hi]`: origin and biased exponent. No extent (an
/// empty or flat union, or one with a non-finite plane) gets the smallest scale at the
/// origin `lo` (0 where `lo` is not finite).
fn frame(lo: f32, hi: f32) -> (f32, u32) {
    if !lo.is_finite() || hi.is_nan() || lo > hi {
        return (0.0, 1);
    }
    let extent = hi - lo;
    // 255·2^(E−7) ≥ extent for extent's exponent E; rounding of `hi − lo` may leave one or
    // two steps to go, which the decoded check takes.
    let mut e = (((extent.to_bits() >> 23) & 0xff) as i32 - 7).max(1) as u32;
    while e < 254 && decode(lo, scale(e), 255) < hi {
        e += 1;
    }
    (lo, e)
}

/// The largest plane at or below `v` (0 at least: the origin is the union's low corner).
fn quantize_lo(p: f32, s: f32, inv_s: f32, v: f32) -> u32 {
    let mut q = first_guess(((v - p) * inv_s).floor());
    while q > 0 && decode(p, s, q) > v {
        q -= 1;
    }
    q
}

/// The smallest plane at or above `v` (255 at most: the frame's scale reaches the union's
/// high corner there).
fn quantize_hi(p: f32, s: f32, inv_s: f32, v: f32) -> u32 {
    let mut q = first_guess(((v - p) * inv_s).ceil());
    while q < 255 && decode(p, s, q) < v {
        q += 1;
    }
    q
}

/// A plane estimate clamped to 0..=255 (NaN: 0).
fn first_guess(f: f32) -> u32 {
    if f >= 0.0 {
        f.min(255.0) as u32
    } else {
        0
    }
}

impl Bvh {
    /// The 4-wide nodes ([this module](self)): wide node `i` from binary node `i`, the root 0.
    /// Made from the nodes when first asked for; code that edits `nodes` after that calls
    /// [`Bvh::nodes_changed`].
    pub fn wide(&self) -> &[WideNode] {
        self.wide
            .0
            .get_or_init(|| widen(&self.nodes, self.nodes.len()))
    }
}
