//! obvhs as a CPU peer: its PLOC BVH (`BvhBuildParams::medium_build`) over the scene's
//! triangles, traced on one thread with Möller–Trumbore, timed by the wall clock. obvhs has
//! no spheres: on a scene with spheres it answers for the triangles alone.

use std::time::{Duration, Instant};

use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use vkrt::trace::{Query, Ray};

use vkrt::accel::primitives::TraceGeometry;

/// obvhs builds its rays and triangles with glam 0.34 (vkrt uses 0.30).
fn v34(v: [f32; 3]) -> glam034::Vec3A {
    glam034::Vec3A::new(v[0], v[1], v[2])
}

/// obvhs's BVH over a scene's triangles, built and traced on the CPU (see the module docs).
pub struct ObvhsPeer {
    tris: Vec<Triangle>,
    bvh: Bvh2,
    /// Wall milliseconds of the build (one thread: obvhs without its `parallel` feature).
    pub build_ms: f64,
}

impl ObvhsPeer {
    /// The BVH over `g`'s triangles; `None` without any. Zero-area triangles (which
    /// `TraceGeometry` stores as NaN and nothing hits) are left out: a NaN box would poison
    /// obvhs's build.
    pub fn build(g: &TraceGeometry) -> Option<Self> {
        let tris: Vec<Triangle> = g
            .tri_verts
            .chunks_exact(9)
            .filter(|t| t.iter().all(|x| x.is_finite()))
            .map(|t| Triangle {
                v0: v34([t[0], t[1], t[2]]),
                v1: v34([t[3], t[4], t[5]]),
                v2: v34([t[6], t[7], t[8]]),
            })
            .collect();
        if tris.is_empty() {
            return None;
        }
        let start = Instant::now();
        let bvh = build_bvh2_from_tris(
            &tris,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let build_ms = start.elapsed().as_secs_f64() * 1e3;
        Some(Self {
            tris,
            bvh,
            build_ms,
        })
    }

    /// Traces `rays` (`query` as the GPU tracers do): the number of hits and the wall ms.
    pub fn trace(&self, rays: &[Ray], query: Query) -> (usize, f64) {
        let start = Instant::now();
        let intersect = |ray: &obvhs::ray::Ray, id: usize| {
            self.tris[self.bvh.primitive_indices[id] as usize].intersect(ray)
        };
        let mut hits = 0usize;
        for r in rays {
            let ray = obvhs::ray::Ray::new(v34(r.origin), v34(r.dir), r.tmin, r.tmax);
            let hit = match query {
                Query::Any => !self.bvh.ray_traverse_miss(ray, intersect),
                Query::Closest => {
                    let mut h = obvhs::ray::RayHit::none();
                    self.bvh.ray_traverse(ray, &mut h, intersect)
                }
            };
            hits += hit as usize;
        }
        (hits, start.elapsed().as_secs_f64() * 1e3)
    }
}
