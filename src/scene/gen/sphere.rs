//! Icosphere as a geodesic grid (see the module docs of `gen`).

use glam::Vec3;

use super::check_triangles;
use crate::scene::error::{Origin, SceneError};
use crate::scene::model::Mesh;

const ICO_FACES: [[u32; 3]; 20] = [
    [0, 11, 5],
    [0, 5, 1],
    [0, 1, 7],
    [0, 7, 10],
    [0, 10, 11],
    [1, 5, 9],
    [5, 11, 4],
    [11, 10, 2],
    [10, 7, 6],
    [7, 1, 8],
    [3, 9, 4],
    [3, 4, 2],
    [3, 2, 6],
    [3, 6, 8],
    [3, 8, 9],
    [4, 9, 5],
    [2, 4, 11],
    [6, 2, 10],
    [8, 6, 7],
    [9, 8, 1],
];

fn ico_corners() -> [Vec3; 12] {
    let t = (1.0 + 5.0f32.sqrt()) * 0.5;
    [
        Vec3::new(-1.0, t, 0.0),
        Vec3::new(1.0, t, 0.0),
        Vec3::new(-1.0, -t, 0.0),
        Vec3::new(1.0, -t, 0.0),
        Vec3::new(0.0, -1.0, t),
        Vec3::new(0.0, 1.0, t),
        Vec3::new(0.0, -1.0, -t),
        Vec3::new(0.0, 1.0, -t),
        Vec3::new(t, 0.0, -1.0),
        Vec3::new(t, 0.0, 1.0),
        Vec3::new(-t, 0.0, -1.0),
        Vec3::new(-t, 0.0, 1.0),
    ]
    .map(Vec3::normalize)
}

/// Triangles of a geodesic sphere of frequency `f`: `20·f²`.
pub fn geodesic_triangle_count(frequency: u32) -> u64 {
    20 * u64::from(frequency) * u64::from(frequency)
}

/// Triangles of [`icosphere`]`(subdivisions)`: `20·4^s` (saturating).
pub fn icosphere_triangle_count(subdivisions: u32) -> u64 {
    if subdivisions >= 30 {
        u64::MAX
    } else {
        20u64 << (2 * subdivisions)
    }
}

/// Unit sphere from an icosahedron subdivided `subdivisions` times
/// (frequency `2^s`): `20·4^s` triangles, `10·4^s + 2` vertices, closed,
/// outward-facing, with unit normals. Error if above [`MAX_TRIANGLES`](crate::scene::limits::MAX_TRIANGLES)
/// (`s ≥ 10`).
pub fn icosphere(subdivisions: u32) -> Result<Mesh, SceneError> {
    let count = icosphere_triangle_count(subdivisions);
    check_triangles(count, "icosphere")?;
    let mut mesh = geodesic_sphere(1 << subdivisions)?;
    mesh.name = format!("icosphere({subdivisions})");
    Ok(mesh)
}

/// The smallest geodesic sphere with at least `n_tris` triangles
/// (frequency `⌈√(n/20)⌉`, so within a few per cent of `n` for large `n`).
pub fn icosphere_with_at_least(n_tris: u64) -> Result<Mesh, SceneError> {
    check_triangles(n_tris, "icosphere")?;
    let mut f = ((n_tris as f64 / 20.0).sqrt().ceil() as u32).max(1);
    while geodesic_triangle_count(f) < n_tris {
        f += 1;
    }
    while f > 1 && geodesic_triangle_count(f - 1) >= n_tris {
        f -= 1;
    }
    geodesic_sphere(f)
}

/// Unit geodesic sphere of frequency `f ≥ 1`: each icosahedron face split
/// into `f²` triangles, points projected to the sphere. `20·f²` triangles,
/// `10·f² + 2` vertices.
pub fn geodesic_sphere(frequency: u32) -> Result<Mesh, SceneError> {
    let f = frequency;
    if f == 0 {
        return Err(SceneError::out_of_range(
            Origin::key("geodesic_sphere.frequency"),
            0,
            "must be ≥ 1",
        ));
    }
    check_triangles(geodesic_triangle_count(f), "icosphere")?;
    let corners = ico_corners();
    let fu = f as usize;
    let n_vertices = 10 * fu * fu + 2;
    let mut positions: Vec<Vec3> = Vec::with_capacity(n_vertices);
    positions.extend_from_slice(&corners);

    // The 30 edges, each with f − 1 interior points from the lower corner
    // index to the higher.
    let mut edges: Vec<(u32, u32, u32)> = Vec::with_capacity(30); // (lo, hi, first vertex)
    for face in &ICO_FACES {
        for k in 0..3 {
            let (a, b) = (face[k], face[(k + 1) % 3]);
            let (lo, hi) = (a.min(b), a.max(b));
            if !edges.iter().any(|e| e.0 == lo && e.1 == hi) {
                let first = positions.len() as u32;
                let (pa, pb) = (corners[lo as usize], corners[hi as usize]);
                for i in 1..f {
                    let t = i as f32 / f as f32;
                    positions.push(pa.lerp(pb, t).normalize());
                }
                edges.push((lo, hi, first));
            }
        }
    }
    let edge_point = |u: u32, v: u32, k: u32| -> u32 {
        // k-th point (1..f-1) from u towards v.
        let (lo, hi) = (u.min(v), u.max(v));
        let e = edges
            .iter()
            .find(|e| e.0 == lo && e.1 == hi)
            .map_or(0, |e| e.2);
        if u < v {
            e + k - 1
        } else {
            e + (f - k) - 1
        }
    };

    let mut indices: Vec<[u32; 3]> = Vec::with_capacity(20 * fu * fu);
    // Per-face vertex index of grid point (i, j), i + j ≤ f, point =
    // A·(f−i−j)/f + B·i/f + C·j/f. Rows of constant j.
    let row_start = |j: u32| -> usize {
        // number of grid points in rows 0..j: sum_{r<j} (f + 1 − r)
        let j = j as usize;
        j * (fu + 1) - j * j.saturating_sub(1) / 2
    };
    let mut grid: Vec<u32> = vec![0; (fu + 1) * (fu + 2) / 2];
    for face in &ICO_FACES {
        let [a, b, c] = *face;
        let (pa, pb, pc) = (
            corners[a as usize],
            corners[b as usize],
            corners[c as usize],
        );
        for j in 0..=f {
            for i in 0..=(f - j) {
                let idx = if i == 0 && j == 0 {
                    a
                } else if i == f {
                    b
                } else if j == f {
                    c
                } else if j == 0 {
                    edge_point(a, b, i)
                } else if i == 0 {
                    edge_point(a, c, j)
                } else if i + j == f {
                    edge_point(b, c, j)
                } else {
                    let (fi, fj, ff) = (i as f32, j as f32, f as f32);
                    let p = (pa * (ff - fi - fj) + pb * fi + pc * fj) / ff;
                    positions.push(p.normalize());
                    (positions.len() - 1) as u32
                };
                grid[row_start(j) + i as usize] = idx;
            }
        }
        let at = |i: u32, j: u32| grid[row_start(j) + i as usize];
        for j in 0..f {
            for i in 0..(f - j) {
                indices.push([at(i, j), at(i + 1, j), at(i, j + 1)]);
                if i + j + 1 < f {
                    indices.push([at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
                }
            }
        }
    }
    debug_assert_eq!(positions.len(), n_vertices);
    let mut mesh = Mesh::new(&format!("geodesic_sphere({f})"), positions, indices, 0);
    mesh.normals = mesh.positions.clone();
    Ok(mesh)
}
