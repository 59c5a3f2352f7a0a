//! The benchmark's scenes and rays: a pinhole camera's primary rays (one through each
//! pixel's centre), and from their hits shadow rays towards one light (any hit) and mirror
//! reflections (closest hit), spawned as the renderer spawns them.

use glam::Vec3;
use serde::Serialize;

use vkrt::accel::primitives::TraceGeometry;
use vkrt::scene::{Camera, Light, Scene};
use vkrt::trace::intersect::{offset_ray_origin_bounded, sphere_hit_point, triangle_hit_point};
use vkrt::trace::{Hit, Query, Ray};

/// Where secondary rays start, as a fraction of the scene's diagonal. vkrt's kernels need
/// none (the spawn offset clears their watertight test's error), but lavapipe's ray query
/// (Mesa 25) re-hits the surface a ray leaves at t ≈ 1e-8 on a quarter to nearly half of the
/// mirror rays of the example scenes without it, and obvhs's Möller–Trumbore test does too;
/// 1e-6 of the diagonal is enough for both, and changes no hit of vkrt's. Every backend then
/// traces the same work.
pub const SPAWN_TMIN: f32 = 1e-6;

/// Where shadow rays go.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ShadowTarget {
    /// To a point (a point light, or the centre of an area light), bounded by its distance.
    Point(Vec3),
    /// Along a direction, unbounded (a directional light: towards where it comes from).
    Direction(Vec3),
}

/// One scene of the benchmark: static geometry, a camera and where shadow rays go.
#[derive(Clone, Debug)]
pub struct BenchScene {
    /// The scene's name in the report.
    pub name: String,
    /// The static geometry every structure is built over.
    pub geometry: TraceGeometry,
    /// The camera the primary rays leave.
    pub camera: Camera,
    /// Image height over width (the primary rays are `size` × `size · aspect`).
    pub aspect: f32,
    /// Where the shadow rays go.
    pub shadow: ShadowTarget,
    /// Where `shadow` comes from ("point light", "no light: above the scene", ...).
    pub light: String,
}

/// The three kinds of rays traced on every scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RayKind {
    /// From the camera through each pixel's centre (closest hit).
    Primary,
    /// From each primary hit towards the light (any hit).
    Shadow,
    /// The mirror reflection at each primary hit (closest hit).
    Mirror,
}

impl RayKind {
    /// Every kind, in the order traced (the others start from the primary hits).
    pub const ALL: [RayKind; 3] = [RayKind::Primary, RayKind::Shadow, RayKind::Mirror];

    /// `primary`, `shadow` or `mirror`, as reports print it.
    pub fn name(self) -> &'static str {
        match self {
            RayKind::Primary => "primary",
            RayKind::Shadow => "shadow",
            RayKind::Mirror => "mirror",
        }
    }

    /// Shadow rays ask whether anything is in the way; the others want the closest hit.
    pub fn query(self) -> Query {
        match self {
            RayKind::Shadow => Query::Any,
            RayKind::Primary | RayKind::Mirror => Query::Closest,
        }
    }
}

/// The rays of one kind on one scene (kept so a caller can give the same rays to a peer).
#[derive(Clone, Debug)]
pub struct RaySet {
    /// Which rays.
    pub kind: RayKind,
    /// The rays, in the order traced.
    pub rays: Vec<Ray>,
}

impl BenchScene {
    /// A scene as its file sets it up: static at the shutter-open time, its own camera and
    /// image aspect, shadow rays to its first light (above the scene where it has none).
    pub fn from_scene(name: impl Into<String>, scene: &Scene) -> Self {
        let geometry = TraceGeometry::at_time(scene, scene.camera.shutter_open);
        let s = &scene.settings;
        let (shadow, light) = match scene.lights.first() {
            Some(&Light::Point { position, .. }) => (ShadowTarget::Point(position), "point light"),
            Some(&Light::Sphere { center, .. }) => {
                (ShadowTarget::Point(center), "sphere light's centre")
            }
            Some(&Light::Quad {
                corner,
                edge_u,
                edge_v,
                ..
            }) => (
                ShadowTarget::Point(corner + (edge_u + edge_v) * 0.5),
                "quad light's centre",
            ),
            Some(&Light::Directional { direction, .. }) => (
                ShadowTarget::Direction(-direction.normalize()),
                "directional light",
            ),
            None => (
                above(&geometry),
                "point above the scene, which has no light",
            ),
        };
        Self {
            name: name.into(),
            geometry,
            camera: scene.camera,
            aspect: s.height as f32 / s.width.max(1) as f32,
            shadow,
            light: light.to_string(),
        }
    }

    /// A bare mesh: a square image of its box seen from the front, slightly from above and
    /// the right (45° vertical field of view), and a point light above the scene.
    pub fn from_triangles(name: impl Into<String>, tris: &[[Vec3; 3]]) -> Self {
        let geometry = TraceGeometry::from_triangles(tris);
        let (lo, hi) = bounds(&geometry);
        let c = (lo + hi) * 0.5;
        let radius = (hi - lo).length() * 0.5;
        let eye = c + Vec3::new(0.3, 0.25, 1.0).normalize() * radius * 2.0;
        Self {
            name: name.into(),
            camera: Camera::look_at(eye, c, Vec3::Y, 45.0),
            aspect: 1.0,
            shadow: above(&geometry),
            light: "point light above the scene".into(),
            geometry,
        }
    }

    /// The image `size` pixels wide, at the scene's aspect (at least one pixel high).
    pub fn image(&self, size: u32) -> (u32, u32) {
        let h = (size as f32 * self.aspect).round().max(1.0) as u32;
        (size, h)
    }

    /// One ray through the centre of each pixel, row by row from the top (the renderer's
    /// `camera_ray` without jitter, lens or shutter).
    pub fn primary_rays(&self, size: u32) -> Vec<Ray> {
        let (w, h) = self.image(size);
        let cam = &self.camera;
        let (forward, right, up) = cam.basis();
        let tan = (cam.fov.to_radians() * 0.5).tan();
        let (right, up) = (right * tan * w as f32 / h as f32, up * tan);
        let mut rays = Vec::with_capacity(w as usize * h as usize);
        for y in 0..h {
            for x in 0..w {
                let sx = 2.0 * (x as f32 + 0.5) / w as f32 - 1.0;
                let sy = 1.0 - 2.0 * (y as f32 + 0.5) / h as f32;
                let d = (forward + sx * right + sy * up).normalize();
                rays.push(Ray::new(cam.position, d, 0.0, f32::MAX));
            }
        }
        rays
    }

    /// From every hit of `primary`: a shadow ray towards [`BenchScene::shadow`] and a mirror
    /// reflection, both leaving the side the primary ray came from: spawned off the surface
    /// as the renderer spawns them, and starting at `SPAWN_TMIN` × the scene's diagonal.
    pub fn secondary_rays(&self, primary: &[Ray], hits: &[Hit]) -> (RaySet, RaySet) {
        let g = &self.geometry;
        let (lo, hi) = bounds(g);
        let tmin = SPAWN_TMIN * (hi - lo).length();
        let (mut shadow, mut mirror) = (Vec::new(), Vec::new());
        for (r, h) in primary.iter().zip(hits).filter(|(_, h)| h.is_hit()) {
            let prim = h.prim as usize;
            let (p, err, mut n) = if prim < g.triangle_count() {
                let [p0, p1, p2] = g.triangle_at(prim, 0.0);
                let (p, err) = triangle_hit_point(p0, p1, p2, h.u, h.v);
                (p, err, (p1 - p0).cross(p2 - p0).normalize())
            } else if prim >= g.triangle_count() + g.spheres.len() {
                let b = &g.aabbs[prim - g.triangle_count() - g.spheres.len()];
                let p = r.o() + r.d() * h.t;
                // o + t·d: two roundings of each term, a few ulps of its magnitudes.
                let err = (r.o().abs() + (r.d() * h.t).abs()) * (4.0 * f32::EPSILON);
                (p, err, vkrt::trace::intersect::aabb_normal(b.min, b.max, p))
            } else {
                let s = g.sphere_at(prim - g.triangle_count(), 0.0);
                let c = s.truncate();
                let (p, err) = sphere_hit_point(c, s.w, r.o() + r.d() * h.t);
                (p, err, (p - c).normalize())
            };
            if n.dot(r.d()) > 0.0 {
                n = -n;
            }
            let o = offset_ray_origin_bounded(p, n, err);
            shadow.push(match self.shadow {
                ShadowTarget::Point(light) => {
                    let to = light - o;
                    let dist = to.length();
                    Ray::new(o, to / dist, tmin, dist)
                }
                ShadowTarget::Direction(d) => Ray::new(o, d, tmin, f32::MAX),
            });
            let d = r.d() - 2.0 * r.d().dot(n) * n;
            mirror.push(Ray::new(o, d.normalize(), tmin, f32::MAX));
        }
        let set = |kind, rays| RaySet { kind, rays };
        (set(RayKind::Shadow, shadow), set(RayKind::Mirror, mirror))
    }
}

/// The box of every primitive.
fn bounds(g: &TraceGeometry) -> (Vec3, Vec3) {
    g.boxes.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), b| (lo.min(b.min), hi.max(b.max)),
    )
}

/// A point light above and in front of the scene, as far out again as its diagonal.
fn above(g: &TraceGeometry) -> ShadowTarget {
    let (lo, hi) = bounds(g);
    ShadowTarget::Point((lo + hi) * 0.5 + Vec3::new(1.0, 2.0, 1.5) * (hi - lo).length())
}
