//! Ray queries against any vkrt structure: rays and hits shared byte for byte with GLSL
//! (`glsl/include/vkrt/ray.glsl`, `glsl/include/vkrt/traverse.glsl`), the GPU tracer
//! ([`gpu`]) and its CPU twins (the kd-tree walk in [`cpu`], the BVH walks in [`bvh_cpu`]),
//! scenes traced as two levels ([`instanced`]), ray files ([`files`]), the robustness suite
//! ([`robust`]), and brute force as the oracle.
//!
//! Contract of a query (GPU and CPU alike):
//! - `tmax = +inf` means unbounded, as in Embree, DXR and pbrt;
//! - a ray is valid when origin, direction and `tmin` are finite, `tmax` is not NaN, the
//!   direction is not zero and `tmin <= tmax`; any other ray is a miss (never a hang, never
//!   an error), and [`Ray::invalid_reason`] says why, so callers can report it;
//! - hits are searched in `[max(tmin, 0), tmax]` at the scene's time (moving geometry is
//!   placed at the ray's time; `vkrt trace` uses the shutter-open time);
//! - the closest hit wins; among hits at exactly equal `t`, the lowest primitive id;
//! - any-hit queries return some hit in the interval (the first found).
//! - with the watertight test, triangles of zero area (the cross product of their edges is
//!   exactly zero: collinear or repeated vertices) are never hit.

pub mod bvh_cpu;
pub mod cpu;
pub mod files;
pub mod gpu;
pub mod instanced;
pub mod intersect;
pub mod robust;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// A ray: 32 bytes, `Ray` in `glsl/include/vkrt/ray.glsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Ray {
    /// The ray's origin.
    pub origin: [f32; 3],
    /// Start of the hit interval, in units of `dir`'s length.
    pub tmin: f32,
    /// The direction; need not be normalized (`t` is measured in its length).
    pub dir: [f32; 3],
    /// End of the hit interval; `+inf` means unbounded.
    pub tmax: f32,
}

impl Ray {
    /// A ray from its origin, direction and `[tmin, tmax]` interval.
    pub fn new(origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Self {
        Self {
            origin: origin.to_array(),
            tmin,
            dir: dir.to_array(),
            tmax,
        }
    }

    /// The origin as a vector.
    pub fn o(&self) -> Vec3 {
        Vec3::from_array(self.origin)
    }

    /// The direction as a vector.
    pub fn d(&self) -> Vec3 {
        Vec3::from_array(self.dir)
    }

    /// See the module docs.
    pub fn is_valid(&self) -> bool {
        self.invalid_reason().is_none()
    }

    /// Why a query answers this ray with a miss without tracing it (`None`: a valid ray).
    pub fn invalid_reason(&self) -> Option<InvalidRay> {
        let values = self
            .origin
            .iter()
            .chain(&self.dir)
            .chain([&self.tmin, &self.tmax]);
        if values.clone().any(|x| x.is_nan()) {
            Some(InvalidRay::Nan)
        } else if !values.take(7).all(|x| x.is_finite()) {
            Some(InvalidRay::Infinite)
        } else if self.d() == Vec3::ZERO {
            Some(InvalidRay::ZeroDirection)
        } else if self.tmin > self.tmax {
            Some(InvalidRay::EmptyInterval)
        } else {
            None
        }
    }
}

/// The classes of rays a query answers with a miss without tracing them, checked in this
/// order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum InvalidRay {
    /// A NaN in any of the eight values.
    Nan,
    /// An infinite origin, direction or `tmin` (`tmax = +inf` is unbounded, not invalid).
    Infinite,
    /// A direction of (0, 0, 0) (signed zeros included).
    ZeroDirection,
    /// `tmin > tmax` (`tmax = -inf` included).
    EmptyInterval,
}

impl InvalidRay {
    /// Every class, in the order they are checked.
    pub const ALL: [InvalidRay; 4] = [
        InvalidRay::Nan,
        InvalidRay::Infinite,
        InvalidRay::ZeroDirection,
        InvalidRay::EmptyInterval,
    ];

    /// The class's snake_case name, as in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            InvalidRay::Nan => "nan",
            InvalidRay::Infinite => "infinite",
            InvalidRay::ZeroDirection => "zero_direction",
            InvalidRay::EmptyInterval => "empty_interval",
        }
    }
}

/// How many rays of a batch fall in each [`InvalidRay`] class (in `InvalidRay::ALL` order).
pub fn count_invalid(rays: &[Ray]) -> [usize; 4] {
    let mut counts = [0; 4];
    for reason in rays.iter().filter_map(Ray::invalid_reason) {
        counts[InvalidRay::ALL.iter().position(|&r| r == reason).unwrap()] += 1;
    }
    counts
}

/// Primitive id of a miss.
pub const NO_HIT: u32 = u32::MAX;

/// A hit: 16 bytes, `Hit` in `glsl/include/vkrt/ray.glsl`. A miss has `t = +inf` and
/// `prim = NO_HIT`. `u`, `v` are the barycentric weights of a triangle's second and third
/// vertex (0 for spheres).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Hit {
    /// Ray parameter of the hit, in units of the ray direction's length (`+inf` for a miss).
    pub t: f32,
    /// Id of the primitive hit, or [`NO_HIT`].
    pub prim: u32,
    /// Barycentric weight of a triangle's second vertex.
    pub u: f32,
    /// Barycentric weight of a triangle's third vertex.
    pub v: f32,
}

impl Hit {
    /// The miss: `t = +inf`, `prim = NO_HIT`.
    pub const MISS: Hit = Hit {
        t: f32::INFINITY,
        prim: NO_HIT,
        u: 0.0,
        v: 0.0,
    };

    /// Whether this is a hit (`prim != NO_HIT`).
    pub fn is_hit(&self) -> bool {
        self.prim != NO_HIT
    }
}

/// Which ray/triangle test the traversal uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Intersector {
    /// Woop, Benthin & Wald 2013: no ray slips between triangles sharing an edge.
    #[default]
    Watertight,
    /// Möller & Trumbore 1997: faster, not watertight.
    MollerTrumbore,
}

impl Intersector {
    /// Both tests.
    pub const ALL: [Intersector; 2] = [Intersector::Watertight, Intersector::MollerTrumbore];

    /// The `INTERSECTOR` specialization constant.
    pub fn spec(self) -> u32 {
        match self {
            Intersector::Watertight => 0,
            Intersector::MollerTrumbore => 1,
        }
    }

    /// The test's snake_case name, as in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Intersector::Watertight => "watertight",
            Intersector::MollerTrumbore => "moller_trumbore",
        }
    }
}

/// Closest hit or any hit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Query {
    /// The closest hit in the interval (lowest primitive id among equal `t`).
    #[default]
    Closest,
    /// Some hit in the interval: the first found.
    Any,
}

/// How a query runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TraceOptions {
    /// The ray/triangle test.
    pub intersector: Intersector,
    /// Closest hit or any hit.
    pub query: Query,
    /// Entries of the traversal's short stack; deeper trees restart from the root.
    pub stack_size: u32,
    /// The watertight test's double-precision fallback for edge functions that round to
    /// zero. On by default; the GPU tracer turns it off on devices without shaderFloat64.
    pub exact: bool,
    /// Node visits + primitive tests per ray before the walk gives up and reports the ray
    /// as exhausted (never a silent miss). `None`: the device's cap on the GPU
    /// ([`DeviceInfo::max_traversal_steps`](crate::gpu::DeviceInfo::max_traversal_steps)),
    /// [`DEFAULT_MAX_TRAVERSAL_STEPS`](cpu::DEFAULT_MAX_TRAVERSAL_STEPS) on the CPU. A GPU
    /// tracer never goes past the device's cap ([`Tracer::options`](gpu::Tracer::options)
    /// says what it runs with): past a loop budget the driver would end the walk silently.
    pub max_steps: Option<u32>,
}

impl TraceOptions {
    /// The step cap the CPU twins run with.
    pub fn max_steps(&self) -> u32 {
        self.max_steps.unwrap_or(cpu::DEFAULT_MAX_TRAVERSAL_STEPS)
    }
}

impl Default for TraceOptions {
    fn default() -> Self {
        Self {
            intersector: Intersector::Watertight,
            query: Query::Closest,
            stack_size: DEFAULT_STACK_SIZE,
            exact: true,
            max_steps: None,
        }
    }
}

/// Short-stack entries by default: at least the kd-tree builders' depth limit for any
/// primitive count a `u32` holds (`SahParams::depth_limit`: 48 at 2^32 - 1), so with the
/// default limit the stack never overflows and the walk never restarts (pbrt's kd-tree
/// stack has 64 entries too). A power of two: the ring buffer wraps with a mask.
pub const DEFAULT_STACK_SIZE: u32 = 64;

#[cfg(test)]
mod tests {
    use super::DEFAULT_STACK_SIZE;
    use crate::accel::kdtree::SahParams;

    /// The kd-tree walk's stack holds a path of the deepest tree the builders make with
    /// their default depth limit, for any primitive count: it never overflows, so it never
    /// restarts (the restart can skip a cell for a ray lying in a split plane).
    #[test]
    fn the_default_stack_holds_every_default_kd_tree() {
        let deepest = SahParams::default().depth_limit(u32::MAX as usize);
        assert!(deepest <= DEFAULT_STACK_SIZE, "{deepest} levels");
        assert!(DEFAULT_STACK_SIZE.is_power_of_two());
    }
}
