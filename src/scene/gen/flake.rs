//! Haines' sphere flake, as spheres and as a triangle mesh.

use glam::Vec3;

use super::{check_triangles, icosphere, icosphere_triangle_count, too_large};
use crate::scene::error::SceneError;
use crate::scene::limits::MAX_SPHERES;
use crate::scene::material::Material;
use crate::scene::model::{Light, Mesh, Sphere};
use crate::scene::Scene;

/// Spheres in a sphere flake of `depth`: `(9^(depth+1) − 1) / 8`.
pub fn sphere_flake_count(depth: u32) -> u64 {
    let mut total: u64 = 0;
    let mut level: u64 = 1;
    for _ in 0..=depth.min(40) {
        // 9^21 > u64::MAX: saturated long before 40 levels.
        total = total.saturating_add(level);
        level = level.saturating_mul(9);
    }
    total
}

/// Haines' sphere flake (SPD "balls"): a unit sphere at the origin carrying
/// 9 spheres of a third its radius (6 around its equator, 3 above),
/// recursively to `depth` levels; `(9^(d+1) − 1)/8` spheres, all using
/// material 0. Error above [`MAX_SPHERES`] (depth ≥ 7).
pub fn sphere_flake_spheres(depth: u32) -> Result<Vec<Sphere>, SceneError> {
    let count = sphere_flake_count(depth);
    if count > MAX_SPHERES {
        return Err(too_large("sphere", count, MAX_SPHERES, "sphere_flake"));
    }
    let mut out = Vec::with_capacity(count as usize);
    out.push(Sphere::new(Vec3::ZERO, 1.0, 0));
    flake_children(&mut out, Vec3::ZERO, 1.0, Vec3::Y, depth);
    Ok(out)
}

fn flake_children(out: &mut Vec<Sphere>, center: Vec3, radius: f32, axis: Vec3, depth: u32) {
    if depth == 0 {
        return;
    }
    let (t1, t2) = axis.any_orthonormal_pair();
    let r = radius / 3.0;
    let dist = radius + r;
    for k in 0..9 {
        let (elevation, azimuth) = if k < 6 {
            (0.0f32, k as f32 * 60.0)
        } else {
            (60.0f32, 30.0 + (k - 6) as f32 * 120.0)
        };
        let (el, az) = (elevation.to_radians(), azimuth.to_radians());
        let dir = (axis * el.sin() + (t1 * az.cos() + t2 * az.sin()) * el.cos()).normalize();
        let c = center + dir * dist;
        out.push(Sphere::new(c, r, 0));
        flake_children(out, c, r, dir, depth - 1);
    }
}

/// The sphere flake as a scene: reflective spheres, two point lights, a
/// framing camera.
pub fn sphere_flake(depth: u32) -> Result<Scene, SceneError> {
    let spheres = sphere_flake_spheres(depth)?;
    let material = Material {
        specular: Vec3::splat(0.5),
        shininess: 60.0,
        mirror: Vec3::splat(0.4),
        ..Material::diffuse("flake", Vec3::new(0.8, 0.6, 0.5))
    };
    let mut scene = Scene::from_geometry(Vec::new(), spheres, vec![material]);
    let b = scene.bounds();
    let r = b.diagonal();
    scene.lights.push(Light::Point {
        position: b.center() + Vec3::new(-r, r, 0.5 * r),
        color: Vec3::splat(0.6),
        intensity: r * r,
    });
    Ok(scene)
}

/// The sphere flake tessellated: every sphere replaced by an
/// [`icosphere`]`(subdivisions)`, merged into one mesh of
/// `count · 20·4^s` triangles — a large, clustered triangle scene.
pub fn sphere_flake_mesh(depth: u32, subdivisions: u32) -> Result<Mesh, SceneError> {
    let count = sphere_flake_count(depth);
    if count > MAX_SPHERES {
        return Err(too_large("sphere", count, MAX_SPHERES, "sphere_flake"));
    }
    let per = icosphere_triangle_count(subdivisions);
    check_triangles(count.saturating_mul(per), "sphere_flake_mesh")?;
    let spheres = sphere_flake_spheres(depth)?;
    let unit = icosphere(subdivisions)?;
    let nv = unit.positions.len();
    let mut positions = Vec::with_capacity(nv * spheres.len());
    let mut normals = Vec::with_capacity(nv * spheres.len());
    let mut indices = Vec::with_capacity(unit.indices.len() * spheres.len());
    for s in &spheres {
        let base = positions.len() as u32;
        positions.extend(unit.positions.iter().map(|&p| s.center + p * s.radius));
        normals.extend_from_slice(&unit.normals);
        indices.extend(
            unit.indices
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }
    let mut mesh = Mesh::new(
        &format!("sphere_flake_mesh({depth}, {subdivisions})"),
        positions,
        indices,
        0,
    );
    mesh.normals = normals.into();
    Ok(mesh)
}
