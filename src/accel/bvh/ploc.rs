//! PLOC (Meister & Bittner 2018): the BVH built bottom-up from the primitives in Morton
//! order. Every round, each cluster finds its nearest neighbour among the `radius` clusters
//! on either side (distance: the half area of their union, the SAH's measure); mutual
//! nearest neighbours merge into a new node; the survivors are compacted, in order; until
//! one cluster remains. This is the CPU twin of the GPU build (`glsl/accel/ploc_*.comp`,
//! [`super::ploc_gpu`]): the same rounds, the same node indices, bit for bit.
//!
//! Ties are broken by a hash of the pair, then by index: the pair that is least in that
//! strict order is always a mutual pair, so every round merges at least one; the hash keeps
//! runs of equal distances (primitives in one point) from merging one pair per round. Node
//! indices are handed out from the top, so the last merge is node 0, the root. After
//! `max_rounds` rounds (which real inputs never reach) the remaining clusters are paired
//! with their neighbours `2k, 2k + 1` until one is left: the build always ends.

use super::layout::{Bvh, BvhNode, Child, MAX_TRAVERSAL_DEPTH, NO_NODE};
use super::lbvh::{morton_codes, MortonBits};
use super::refit::union;
use crate::scene::Aabb;

/// The default search radius (the paper's 8–16 range).
pub const DEFAULT_RADIUS: u32 = 8;

/// PLOC's knobs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub struct PlocParams {
    /// Width of the Morton codes that order the initial clusters.
    pub bits: MortonBits,
    /// Clusters searched on each side.
    pub radius: u32,
    /// Nearest-neighbour rounds before the pairing fallback; `None`: [`max_rounds`] (tests
    /// set it low to exercise the fallback).
    pub max_rounds: Option<u32>,
}

impl Default for PlocParams {
    fn default() -> Self {
        Self {
            bits: MortonBits::default(),
            radius: DEFAULT_RADIUS,
            max_rounds: None,
        }
    }
}

impl PlocParams {
    /// The rounds recorded for `n` primitives before the fallback.
    pub fn rounds(&self, n: usize) -> u32 {
        self.max_rounds
            .unwrap_or_else(|| max_rounds(n))
            .min(max_rounds(usize::MAX))
    }
}

/// Rounds of nearest-neighbour merging recorded for `n` primitives before the pairing
/// fallback (the GPU build records this many; unused rounds are empty dispatches). A round
/// adds at most one level, so with the fallback's rounds the tree stays within
/// [`MAX_TRAVERSAL_DEPTH`] levels.
pub fn max_rounds(n: usize) -> u32 {
    let bits = usize::BITS - n.max(1).leading_zeros();
    (4 * bits + 16).min(MAX_TRAVERSAL_DEPTH - 1 - PAIRING_ROUNDS)
}

/// Rounds of the pairing fallback: each halves the clusters (2^32 > any primitive count).
pub const PAIRING_ROUNDS: u32 = 32;

/// A cluster: what it is as a child, and its box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cluster {
    /// A single-primitive leaf, or the node a merge made.
    pub child: Child,
    /// Box of everything under the cluster.
    pub bounds: Aabb,
}

/// Half the area of `a ∪ b`, evaluated as the kernel does (`(x*y + y*z) + z*x`).
pub fn merged_area(a: &Aabb, b: &Aabb) -> f32 {
    let u = union(a, b);
    let d = u.max - u.min;
    d.x * d.y + d.y * d.z + d.z * d.x
}

/// The tie-breaking hash of the pair `lo < hi`.
pub fn pair_hash(lo: u32, hi: u32) -> u32 {
    let mut h = lo
        .wrapping_mul(0x9E37_79B1)
        .wrapping_add(hi.wrapping_mul(0x85EB_CA77));
    h ^= h >> 16;
    h = h.wrapping_mul(0x7FEB_352D);
    h ^ (h >> 15)
}

/// The nearest neighbour of cluster `i` within `radius` (itself when alone).
pub fn nearest(clusters: &[Cluster], i: usize, radius: u32) -> usize {
    let lo = i.saturating_sub(radius as usize);
    let hi = (i + radius as usize).min(clusters.len() - 1);
    let mut best = (f32::INFINITY, u32::MAX, usize::MAX);
    for j in lo..=hi {
        if j == i {
            continue;
        }
        let d = merged_area(&clusters[i].bounds, &clusters[j].bounds);
        let h = pair_hash(i.min(j) as u32, i.max(j) as u32);
        let better = best.2 == usize::MAX
            || d < best.0
            || (d == best.0 && (h < best.1 || (h == best.1 && j < best.2)));
        if better {
            best = (d, h, j);
        }
    }
    if best.2 == usize::MAX {
        i
    } else {
        best.2
    }
}

/// One round given each cluster's partner: merges the mutual pairs into nodes
/// `nodes_left - merges ..` (in cluster order), writes their parent links, and returns the
/// compacted clusters.
fn merge_round(
    clusters: &[Cluster],
    nn: &[usize],
    nodes: &mut [BvhNode],
    parents: &mut [u32],
    nodes_left: &mut usize,
) -> Vec<Cluster> {
    let merges = (0..clusters.len())
        .filter(|&i| nn[nn[i]] == i && i < nn[i])
        .count();
    let base = *nodes_left - merges;
    let mut rank = 0;
    let mut out = Vec::with_capacity(clusters.len() - merges);
    for (i, c) in clusters.iter().enumerate() {
        let j = nn[i];
        let mutual = nn[j] == i && j != i;
        if !mutual {
            out.push(*c);
        } else if i < j {
            let idx = base + rank;
            rank += 1;
            let other = &clusters[j];
            let mut node = BvhNode::empty();
            node.set_child(0, c.bounds, c.child);
            node.set_child(1, other.bounds, other.child);
            nodes[idx] = node;
            for child in [c.child, other.child] {
                if let Child::Node(k) = child {
                    parents[k as usize] = idx as u32;
                }
            }
            out.push(Cluster {
                child: Child::Node(idx as u32),
                bounds: union(&c.bounds, &other.bounds),
            });
        }
    }
    *nodes_left = base;
    out
}

/// What a build did besides the tree.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct PlocStats {
    /// Nearest-neighbour rounds that merged something.
    pub rounds: u32,
    /// Pairing rounds the fallback needed (0 for every real input).
    pub pairing_rounds: u32,
}

/// PLOC over `boxes` in the order of their Morton codes.
pub fn build(boxes: &[Aabb], params: &PlocParams) -> (Bvh, PlocStats) {
    let n = boxes.len();
    let radius = params.radius;
    let codes = morton_codes(boxes, params.bits);
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by_key(|&p| codes[p as usize]);
    let mut stats = PlocStats::default();
    if n <= 1 {
        let (nodes, parents) = super::lbvh::topology(&vec![(0, 0); n]);
        let mut bvh = Bvh {
            nodes,
            parents,
            refs: order,
            bounds: Aabb::EMPTY,
            wide: Default::default(),
        };
        super::refit::refit(&mut bvh, boxes);
        return (bvh, stats);
    }
    let mut nodes = vec![BvhNode::empty(); n - 1];
    let mut parents = vec![NO_NODE; n - 1];
    let mut clusters: Vec<Cluster> = order
        .iter()
        .enumerate()
        .map(|(pos, &p)| Cluster {
            child: Child::Leaf {
                first: pos as u32,
                count: 1,
            },
            bounds: boxes[p as usize],
        })
        .collect();
    let mut nodes_left = n - 1;
    for _ in 0..params.rounds(n) {
        if clusters.len() <= 1 {
            break;
        }
        let nn: Vec<usize> = (0..clusters.len())
            .map(|i| nearest(&clusters, i, radius))
            .collect();
        clusters = merge_round(&clusters, &nn, &mut nodes, &mut parents, &mut nodes_left);
        stats.rounds += 1;
    }
    for _ in 0..PAIRING_ROUNDS {
        if clusters.len() <= 1 {
            break;
        }
        let len = clusters.len();
        let nn: Vec<usize> = (0..len)
            .map(|i| if (i ^ 1) < len { i ^ 1 } else { i })
            .collect();
        clusters = merge_round(&clusters, &nn, &mut nodes, &mut parents, &mut nodes_left);
        stats.pairing_rounds += 1;
    }
    debug_assert_eq!(nodes_left, 0);
    let root = &nodes[0];
    let bounds = union(&root.child(0).0, &root.child(1).0);
    parents[0] = NO_NODE;
    (
        Bvh {
            nodes,
            parents,
            refs: order,
            bounds,
            wide: Default::default(),
        },
        stats,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::validate::validate;
    use glam::Vec3;

    fn boxes(n: usize) -> Vec<Aabb> {
        (0..n)
            .map(|i| {
                let p = Vec3::new((i * 37 % 101) as f32, (i * 11 % 13) as f32, i as f32 * 0.1);
                Aabb {
                    min: p,
                    max: p + Vec3::ONE,
                }
            })
            .collect()
    }

    #[test]
    fn valid_trees_at_every_small_size_and_radius() {
        for n in [0usize, 1, 2, 3, 5, 8, 9, 17, 100, 1000] {
            for r in [1, 4, 8, 16] {
                let b = boxes(n);
                let params = PlocParams {
                    radius: r,
                    ..PlocParams::default()
                };
                let (bvh, stats) = build(&b, &params);
                validate(&bvh, &b).unwrap_or_else(|e| panic!("{n}, r {r}: {e}"));
                assert_eq!(stats.pairing_rounds, 0, "{n}, r {r}");
            }
        }
    }

    #[test]
    fn one_point_converges_in_few_rounds() {
        let p = Aabb {
            min: Vec3::ONE,
            max: Vec3::ONE,
        };
        let b = vec![p; 5000];
        let (bvh, stats) = build(&b, &PlocParams::default());
        validate(&bvh, &b).unwrap();
        assert_eq!(stats.pairing_rounds, 0);
        assert!(stats.rounds < 40, "{} rounds", stats.rounds);
    }

    #[test]
    fn the_pairing_fallback_ends_every_build() {
        let b = boxes(1000);
        let params = PlocParams {
            max_rounds: Some(2),
            ..PlocParams::default()
        };
        let (bvh, stats) = build(&b, &params);
        validate(&bvh, &b).unwrap();
        assert_eq!(stats.rounds, 2);
        assert!(stats.pairing_rounds > 0);
    }

    #[test]
    fn pair_hash_is_a_mix() {
        assert_ne!(pair_hash(0, 1), pair_hash(1, 2));
        assert_ne!(pair_hash(0, 2), pair_hash(2, 0));
    }
}
