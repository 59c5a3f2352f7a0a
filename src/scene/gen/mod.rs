//! Procedural scenes and meshes, for tests, benchmarks and the embedded
//! default scene.
//!
//! Everything is deterministic: the random soup uses an in-crate SplitMix64
//! generator ([`Rng`]) so a seed gives the same triangles on every machine
//! and every version, which the accel tests and benchmark tables rely on.
//! Generators whose size depends on a parameter check the predicted count
//! against the documented limits *before* allocating and return
//! [`SceneError::TooLarge`] instead.
//!
//! The icosphere is built as a geodesic grid: every icosahedron face is
//! split into `f²` triangles in one pass, with the points on the 30 shared
//! edges created once per edge, so the mesh is closed (every edge shared by
//! exactly two triangles) by construction and needs no hash map — 2 M
//! triangles take a few tens of milliseconds. Frequency `2^s` gives the same
//! counts as `s` rounds of midpoint subdivision (`20·4^s` triangles,
//! `10·4^s + 2` vertices); other frequencies reach counts in between, e.g.
//! Sochora's (2013) 1.8 M-triangle "Icosahedron" is frequency 300.

mod flake;
mod meshes;
mod rooms;
mod sphere;

pub use flake::{sphere_flake, sphere_flake_count, sphere_flake_mesh, sphere_flake_spheres};
pub use meshes::{integer_grid, random_soup};
pub use rooms::{cornell_box, dynamic_ring};
pub use sphere::{
    geodesic_sphere, geodesic_triangle_count, icosphere, icosphere_triangle_count,
    icosphere_with_at_least,
};

use glam::Vec3;

use super::error::{Origin, SceneError};
use super::limits::MAX_TRIANGLES;

/// SplitMix64 (Steele, Lea & Flood 2014): tiny, fast, and passes BigCrush
/// when used as here (one 64-bit state, one output per step).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator for `seed` (any value, including 0).
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)` with 24 random bits.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next_f32()
    }

    /// Uniform in the cube `[-1, 1)³`.
    pub fn vec3_signed(&mut self) -> Vec3 {
        Vec3::new(
            self.range(-1.0, 1.0),
            self.range(-1.0, 1.0),
            self.range(-1.0, 1.0),
        )
    }

    /// Uniform in `0..n` (n > 0), by Lemire's multiply-shift.
    pub fn below(&mut self, n: u32) -> u32 {
        (((self.next_u64() >> 32) * u64::from(n)) >> 32) as u32
    }
}

pub(super) fn too_large(what: &'static str, count: u64, limit: u64, name: &str) -> SceneError {
    SceneError::TooLarge {
        origin: Origin::key(name),
        what,
        count,
        limit,
    }
}

pub(super) fn check_triangles(count: u64, name: &str) -> Result<(), SceneError> {
    if count > MAX_TRIANGLES {
        return Err(too_large("triangle", count, MAX_TRIANGLES, name));
    }
    Ok(())
}
