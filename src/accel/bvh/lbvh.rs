//! Karras's LBVH (2012), Novák's (2019) GPU builder: primitives ordered along a Morton curve of
//! their box centroids, every internal node's range and split found from the common prefixes
//! of the sorted codes, boxes computed bottom-up. This is the CPU twin of the GPU build
//! (`glsl/accel/lbvh_*.comp` + `accel.bvh_refit`, [`super::lbvh_gpu`]): the same codes, the
//! same stable order, the same topology and the same boxes, bit for bit.
//!
//! The Morton grid is cubic, `2^e` cells of the same size on every axis with `2^e` at least
//! the largest extent of the centroid box: cubic cells keep the curve's neighbourhoods the
//! same in every direction (on the bunny, SAH cost 41.46 → 40.79 for the LBVH and 37.86 →
//! 37.29 for PLOC against a grid stretched to each axis), and scaling by a power of two is
//! exact on every device, where a division is not (Vulkan allows 2.5 ulp for `a / b`), so
//! the codes do not depend on the driver. The power of two costs at most one bit.

use glam::Vec3;

use super::layout::{Bvh, BvhNode, Child, NO_NODE};
use super::refit::refit;
use crate::scene::Aabb;

/// Bits of the Morton codes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
pub enum MortonBits {
    /// 10 bits per axis in one 32-bit word (one radix sort of 30 bits).
    Bits30,
    /// 21 bits per axis in two words (two stable sorts: low word, then high word).
    #[default]
    Bits63,
}

impl MortonBits {
    /// Bits per axis.
    pub fn per_axis(self) -> u32 {
        match self {
            MortonBits::Bits30 => 10,
            MortonBits::Bits63 => 21,
        }
    }

    /// The `MORTON_BITS` specialization constant of `lbvh_morton`.
    pub fn spec(self) -> u32 {
        3 * self.per_axis()
    }
}

/// The centroid of a box (the midpoint, exactly as the kernel computes it).
pub fn centroid(b: &Aabb) -> Vec3 {
    (b.min + b.max) * 0.5
}

/// An f32 as a u32 whose unsigned order is the IEEE total order (-0 below +0).
pub fn ordered_key(x: f32) -> u32 {
    let bits = x.to_bits();
    if bits & 0x8000_0000 != 0 {
        !bits
    } else {
        bits | 0x8000_0000
    }
}

/// The inverse of [`ordered_key`].
pub fn from_ordered_key(key: u32) -> f32 {
    f32::from_bits(if key & 0x8000_0000 != 0 {
        key & 0x7fff_ffff
    } else {
        !key
    })
}

/// The box of the centroids (min and max in total order), as `lbvh_bounds` reduces it.
pub fn centroid_bounds(boxes: &[Aabb]) -> Aabb {
    let mut lo = [u32::MAX; 3];
    let mut hi = [0u32; 3];
    for b in boxes {
        let c = centroid(b).to_array();
        for k in 0..3 {
            lo[k] = lo[k].min(ordered_key(c[k]));
            hi[k] = hi[k].max(ordered_key(c[k]));
        }
    }
    Aabb {
        min: Vec3::from_array(lo.map(from_ordered_key)),
        max: Vec3::from_array(hi.map(from_ordered_key)),
    }
}

/// Extents below this quantize to 0 on that axis (no denormals reach the scaling).
const MIN_EXTENT: f32 = f32::from_bits(27 << 23); // 2^-100

/// `2^(per_axis - e)` where `2^(e-1) <= extent < 2^e`, the scale onto the integer grid;
/// 0 for a box too small to quantize (every centroid in one cell). Built from the exponent bits, as the kernel does.
fn grid_scale(extent: f32, per_axis: u32) -> f32 {
    // NaN too.
    if extent.partial_cmp(&MIN_EXTENT).is_none_or(|o| o.is_lt()) {
        return 0.0;
    }
    let e = ((extent.to_bits() >> 23) & 0xff) as i32 - 126;
    let k = per_axis as i32 - e;
    f32::from_bits(((k + 127) as u32) << 23)
}

/// Grid coordinate of `c` on one axis.
fn quantize(c: f32, lo: f32, scale: f32, per_axis: u32) -> u32 {
    let top = ((1u32 << per_axis) - 1) as f32;
    let u = (c - lo) * scale;
    u.clamp(0.0, top) as u32
}

/// The Morton code of each primitive's centroid: (high word, low word), x the most
/// significant axis of each bit triple.
pub fn morton_codes(boxes: &[Aabb], bits: MortonBits) -> Vec<(u32, u32)> {
    let cb = centroid_bounds(boxes);
    let per_axis = bits.per_axis();
    let ext = cb.max - cb.min;
    let scale = grid_scale(ext.max_element(), per_axis);
    boxes
        .iter()
        .map(|b| {
            let c = centroid(b);
            let q = [0, 1, 2].map(|k| quantize(c[k], cb.min[k], scale, per_axis));
            interleave(q, per_axis)
        })
        .collect()
}

/// Interleaves three `per_axis`-bit coordinates: bit `3k + 2 - axis` is bit `k` of `axis`.
pub fn interleave(q: [u32; 3], per_axis: u32) -> (u32, u32) {
    let mut code = 0u64;
    for k in 0..per_axis {
        for (axis, &v) in q.iter().enumerate() {
            code |= u64::from((v >> k) & 1) << (3 * k + 2 - axis as u32);
        }
    }
    ((code >> 32) as u32, code as u32)
}

/// Karras's δ: the common prefix of sorted codes `i` and `j`, the indices breaking ties
/// between equal codes; -1 outside `0..n`.
fn delta(codes: &[(u32, u32)], i: i64, j: i64) -> i32 {
    if j < 0 || j >= codes.len() as i64 {
        return -1;
    }
    let (a, b) = (codes[i as usize], codes[j as usize]);
    if a == b {
        return 64 + ((i ^ j) as u32).leading_zeros() as i32;
    }
    let x = ((u64::from(a.0) << 32) | u64::from(a.1)) ^ ((u64::from(b.0) << 32) | u64::from(b.1));
    x.leading_zeros() as i32
}

/// The children of internal node `i` over sorted `codes` (Karras 2012, Figure 4): child `a`
/// is position γ, child `b` is γ + 1, each a leaf when its range is one primitive.
pub fn karras_children(codes: &[(u32, u32)], i: usize) -> (Child, Child) {
    let i = i as i64;
    let d: i64 = if delta(codes, i, i + 1) - delta(codes, i, i - 1) >= 0 {
        1
    } else {
        -1
    };
    let d_min = delta(codes, i, i - d);
    let mut l_max = 2i64;
    while delta(codes, i, i + l_max * d) > d_min {
        l_max *= 2;
    }
    let mut l = 0i64;
    let mut t = l_max / 2;
    while t >= 1 {
        if delta(codes, i, i + (l + t) * d) > d_min {
            l += t;
        }
        t /= 2;
    }
    let j = i + l * d;
    let d_node = delta(codes, i, j);
    let mut s = 0i64;
    let mut t = l;
    loop {
        t = (t + 1) / 2;
        if delta(codes, i, i + (s + t) * d) > d_node {
            s += t;
        }
        if t <= 1 {
            break;
        }
    }
    let gamma = i + s * d + d.min(0);
    let a = if i.min(j) == gamma {
        Child::Leaf {
            first: gamma as u32,
            count: 1,
        }
    } else {
        Child::Node(gamma as u32)
    };
    let b = if i.max(j) == gamma + 1 {
        Child::Leaf {
            first: gamma as u32 + 1,
            count: 1,
        }
    } else {
        Child::Node(gamma as u32 + 1)
    };
    (a, b)
}

/// The topology over sorted codes: nodes with empty boxes and parent links (the boxes are
/// the refit's to compute).
pub fn topology(codes: &[(u32, u32)]) -> (Vec<BvhNode>, Vec<u32>) {
    let n = codes.len();
    if n == 0 {
        return (Vec::new(), Vec::new());
    }
    let empty = BvhNode::empty();
    if n == 1 {
        let mut root = empty;
        root.set_child(0, Aabb::EMPTY, Child::Leaf { first: 0, count: 1 });
        return (vec![root], vec![NO_NODE]);
    }
    let mut nodes = vec![empty; n - 1];
    let mut parents = vec![NO_NODE; n - 1];
    for (i, node) in nodes.iter_mut().enumerate() {
        let (a, b) = karras_children(codes, i);
        for (which, c) in [a, b].into_iter().enumerate() {
            node.set_child(which, Aabb::EMPTY, c);
            if let Child::Node(k) = c {
                parents[k as usize] = i as u32;
            }
        }
    }
    (nodes, parents)
}

/// The LBVH of `boxes` with `bits`-bit Morton codes.
pub fn build(boxes: &[Aabb], bits: MortonBits) -> Bvh {
    let codes = morton_codes(boxes, bits);
    // A stable sort by code: equal codes keep the primitive order (the radix sort's order).
    let mut order: Vec<u32> = (0..boxes.len() as u32).collect();
    order.sort_by_key(|&p| codes[p as usize]);
    let sorted: Vec<(u32, u32)> = order.iter().map(|&p| codes[p as usize]).collect();
    let (nodes, parents) = topology(&sorted);
    let mut bvh = Bvh {
        nodes,
        parents,
        refs: order,
        bounds: Aabb::EMPTY,
        wide: Default::default(),
    };
    refit(&mut bvh, boxes);
    bvh
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(p: Vec3) -> Aabb {
        Aabb { min: p, max: p }
    }

    #[test]
    fn keys_order_floats_totally() {
        let xs = [
            f32::NEG_INFINITY,
            -2.0,
            -0.0,
            0.0,
            1e-40,
            3.0,
            f32::INFINITY,
        ];
        for w in xs.windows(2) {
            assert!(ordered_key(w[0]) < ordered_key(w[1]), "{w:?}");
        }
        for x in xs {
            assert_eq!(from_ordered_key(ordered_key(x)).to_bits(), x.to_bits());
        }
    }

    #[test]
    fn grid_scale_is_a_power_of_two_covering_the_extent() {
        for ext in [1e-20f32, 0.3, 1.0, 1.5, 2.0, 1000.0, 3e30] {
            let s = grid_scale(ext, 21);
            assert_eq!(s.to_bits() & 0x007f_ffff, 0, "{ext}: a power of two");
            assert!(ext * s < (1u32 << 21) as f32 && ext * s >= (1u32 << 20) as f32);
        }
        assert_eq!(grid_scale(0.0, 21), 0.0);
        assert_eq!(grid_scale(1e-35, 21), 0.0);
    }

    #[test]
    fn interleave_puts_x_highest() {
        assert_eq!(interleave([1, 0, 0], 21), (0, 4));
        assert_eq!(interleave([0, 1, 0], 21), (0, 2));
        assert_eq!(interleave([0, 0, 1], 21), (0, 1));
        let top = (1 << 21) - 1;
        assert_eq!(interleave([top, top, top], 21), (0x7fff_ffff, u32::MAX));
        assert_eq!(interleave([1023, 1023, 1023], 10), (0, (1 << 30) - 1));
    }

    #[test]
    fn every_primitive_in_one_leaf_and_boxes_contain_children() {
        for n in [0usize, 1, 2, 3, 7, 8, 9, 100, 1000] {
            let boxes: Vec<Aabb> = (0..n)
                .map(|i| {
                    let p = Vec3::new((i * 37 % 101) as f32, (i * 11 % 13) as f32, i as f32);
                    Aabb {
                        min: p,
                        max: p + Vec3::ONE,
                    }
                })
                .collect();
            for bits in [MortonBits::Bits30, MortonBits::Bits63] {
                let bvh = build(&boxes, bits);
                super::super::validate::validate(&bvh, &boxes).unwrap();
            }
        }
    }

    #[test]
    fn sixty_three_bit_codes_keep_a_cluster_ordered_beside_a_far_primitive() {
        // 4,096 unit boxes on a 16³ lattice, in scrambled order, and one box 10⁴ away: the
        // grid spans the centroids' bounds, so 30-bit codes (1,024 cells an axis) put the
        // lattice in a few cells and split it by index, where 63-bit codes (2²¹) still see its
        // order. So 63 bits are the default, though on a mesh alone both build trees of the
        // same SAH cost. Measure: the child boxes inside the lattice, their areas summed over
        // the lattice's (the SAH's node tests per ray that enters the lattice).
        use super::super::layout::half_area;
        let cell = |i: usize| {
            let j = i * 2731 % 4096;
            Vec3::new((j % 16) as f32, (j / 16 % 16) as f32, (j / 256) as f32) * 2.0
        };
        let mut boxes: Vec<Aabb> = (0..4096)
            .map(|i| Aabb {
                min: cell(i),
                max: cell(i) + Vec3::ONE,
            })
            .collect();
        boxes.push(point(Vec3::splat(1.0e4)));
        let lattice = Aabb {
            min: Vec3::ZERO,
            max: Vec3::splat(31.0),
        };
        let inside = |lo: [f32; 3], hi: [f32; 3]| {
            Vec3::from(lo).cmpge(lattice.min).all() && Vec3::from(hi).cmple(lattice.max).all()
        };
        let tests = |bits| {
            let bvh = build(&boxes, bits);
            let mut area = 0.0f64;
            for n in &bvh.nodes {
                for (lo, hi, index) in
                    [(n.a_min, n.a_max, n.a_index), (n.b_min, n.b_max, n.b_index)]
                {
                    if index != NO_NODE && inside(lo, hi) {
                        let b = Aabb {
                            min: Vec3::from(lo),
                            max: Vec3::from(hi),
                        };
                        area += half_area(&b) as f64;
                    }
                }
            }
            area / half_area(&lattice) as f64
        };
        let (t30, t63) = (tests(MortonBits::Bits30), tests(MortonBits::Bits63));
        println!("node tests per ray into the lattice: 30-bit {t30:.1}, 63-bit {t63:.1}");
        assert!(t30 > 2.0 * t63, "30-bit {t30}, 63-bit {t63}");
    }

    #[test]
    fn equal_codes_split_by_index() {
        // Every centroid in one point: all codes equal, the tree is balanced by index.
        let boxes = vec![point(Vec3::splat(2.0)); 33];
        let bvh = build(&boxes, MortonBits::Bits63);
        super::super::validate::validate(&bvh, &boxes).unwrap();
        assert!(bvh.depth() <= 7, "depth {}", bvh.depth());
    }
}
