//! Random triangle soup and the integer grid.

use glam::Vec3;

use super::{check_triangles, too_large, Rng};
use crate::scene::error::{Origin, SceneError};
use crate::scene::limits::MAX_VERTICES;
use crate::scene::model::Mesh;

/// `n` independent random triangles (3n vertices, nothing shared) in about
/// `[-1, 1]³`, deterministic for a `seed`. Each triangle's vertices lie
/// within `±2/∛n` of a uniformly random centre, so triangles are about
/// twice the mean spacing and overlap heavily — a hard case for SAH
/// builders. No triangle has zero area.
pub fn random_soup(n: u32, seed: u64) -> Result<Mesh, SceneError> {
    check_triangles(u64::from(n), "random_soup")?;
    let vertex_count = 3 * u64::from(n);
    if vertex_count > MAX_VERTICES {
        return Err(too_large(
            "vertex",
            vertex_count,
            MAX_VERTICES,
            "random_soup",
        ));
    }
    let mut rng = Rng::new(seed);
    let size = 2.0 / (n.max(1) as f32).cbrt();
    let mut positions = Vec::with_capacity(3 * n as usize);
    let mut indices = Vec::with_capacity(n as usize);
    for t in 0..n {
        let center = rng.vec3_signed();
        loop {
            let a = center + rng.vec3_signed() * size;
            let b = center + rng.vec3_signed() * size;
            let c = center + rng.vec3_signed() * size;
            if (b - a).cross(c - a) != Vec3::ZERO {
                positions.extend_from_slice(&[a, b, c]);
                break;
            }
        }
        indices.push([3 * t, 3 * t + 1, 3 * t + 2]);
    }
    Ok(Mesh::new(
        &format!("random_soup({n}, {seed})"),
        positions,
        indices,
        0,
    ))
}

/// A flat grid of `nx × ny` unit squares in the plane z = 0, every vertex on
/// integer coordinates `(i, j, 0)`, `0 ≤ i ≤ nx`, `0 ≤ j ≤ ny`: `2·nx·ny`
/// triangles facing +Z, the diagonal alternating like a checkerboard. Rays
/// aimed at integer points hit shared edges and vertices exactly — the
/// classic watertightness trap.
pub fn integer_grid(nx: u32, ny: u32) -> Result<Mesh, SceneError> {
    if nx == 0 || ny == 0 {
        return Err(SceneError::out_of_range(
            Origin::key("integer_grid"),
            format!("{nx} × {ny}"),
            "both sizes must be ≥ 1",
        ));
    }
    check_triangles(2 * u64::from(nx) * u64::from(ny), "integer_grid")?;
    let w = nx + 1;
    let mut positions = Vec::with_capacity(((nx + 1) * (ny + 1)) as usize);
    for j in 0..=ny {
        for i in 0..=nx {
            positions.push(Vec3::new(i as f32, j as f32, 0.0));
        }
    }
    let mut indices = Vec::with_capacity(2 * (nx * ny) as usize);
    for j in 0..ny {
        for i in 0..nx {
            let v00 = j * w + i;
            let v10 = v00 + 1;
            let v01 = v00 + w;
            let v11 = v01 + 1;
            if (i + j) % 2 == 0 {
                indices.push([v00, v10, v11]);
                indices.push([v00, v11, v01]);
            } else {
                indices.push([v00, v10, v01]);
                indices.push([v10, v11, v01]);
            }
        }
    }
    Ok(Mesh::new(
        &format!("integer_grid({nx}, {ny})"),
        positions,
        indices,
        0,
    ))
}
