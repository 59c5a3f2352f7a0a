//! Documented limits on scene size and render settings.
//!
//! Every limit is a named constant so that the CLI, the docs
//! (`docs/scene-format.md`) and the error messages agree. The size limits
//! are generous for a host-side model (a 16 M-triangle scene is ~600 MB of
//! positions once flattened); the renderer may impose tighter, device-specific
//! ones (lavapipe's 128 MiB `maxStorageBufferRange`) and must say so itself.
//! [`Limits`] bundles the size limits so that tests and fuzzers can lower them.

/// Largest image side, in pixels.
pub const MAX_RESOLUTION: u32 = 16_384;
/// Largest image area, in pixels (e.g. 8192 × 8192).
pub const MAX_PIXELS: u64 = 1 << 26;
/// Most samples per pixel.
pub const MAX_SPP: u32 = 65_536;
/// Deepest recursion (reflection/refraction bounces after the primary hit).
pub const MAX_DEPTH: u32 = 64;
/// Most ambient-occlusion rays per shading point.
pub const MAX_AO_SAMPLES: u32 = 1_024;
/// Largest Phong exponent.
pub const MAX_SHININESS: f32 = 1.0e6;
/// Largest index of refraction (diamond is 2.42; 10 leaves room for
/// exotic test scenes without admitting nonsense).
pub const MAX_IOR: f32 = 10.0;
/// Largest absolute world coordinate. Beyond this, products in ray–triangle
/// tests lose all precision or overflow `f32`.
pub const MAX_COORDINATE: f32 = 1.0e9;
/// Largest absolute shutter time, in seconds.
pub const MAX_TIME: f32 = 1.0e6;
/// Highest animation frame rate, frames per second (high-speed cameras
/// reach about 1000; anything above is a unit mistake).
pub const MAX_FPS: f32 = 1_000.0;
/// Most frames in an animation (about 69 minutes at 24 fps).
pub const MAX_FRAMES: u32 = 100_000;

/// Most triangles a scene holds: a mesh file or generator named more than once is held
/// once (its entries share it, as the instances they become) and counts once.
pub const MAX_TRIANGLES: u64 = 1 << 24;
/// Most triangles a scene places, every entry of a repeated mesh counted (what a flat
/// trace would hold; its primitive ids are 32-bit, with `u32::MAX` the miss).
pub const MAX_INSTANCED_TRIANGLES: u64 = 1 << 31;
/// Most vertices a scene holds, summed over its distinct meshes.
pub const MAX_VERTICES: u64 = 1 << 25;
/// Most analytic spheres.
pub const MAX_SPHERES: u64 = 1 << 20;
/// Most meshes.
pub const MAX_MESHES: u64 = 1 << 16;
/// Most materials (ids fit in 16 bits for the renderer's packed hit records).
pub const MAX_MATERIALS: u64 = 1 << 16;
/// Most lights.
pub const MAX_LIGHTS: u64 = 4_096;
/// Largest input file, in bytes (a 16 M-triangle OBJ is about 1 GiB).
pub const MAX_FILE_BYTES: u64 = 2 << 30;

/// Size limits applied while loading and validating. `Default` gives the
/// documented constants; fuzzers and tests lower them to stay fast.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// See [`MAX_TRIANGLES`].
    pub max_triangles: u64,
    /// See [`MAX_INSTANCED_TRIANGLES`].
    pub max_instanced_triangles: u64,
    /// See [`MAX_VERTICES`].
    pub max_vertices: u64,
    /// See [`MAX_SPHERES`].
    pub max_spheres: u64,
    /// See [`MAX_MESHES`].
    pub max_meshes: u64,
    /// See [`MAX_MATERIALS`].
    pub max_materials: u64,
    /// See [`MAX_LIGHTS`].
    pub max_lights: u64,
    /// See [`MAX_FILE_BYTES`].
    pub max_file_bytes: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_triangles: MAX_TRIANGLES,
            max_instanced_triangles: MAX_INSTANCED_TRIANGLES,
            max_vertices: MAX_VERTICES,
            max_spheres: MAX_SPHERES,
            max_meshes: MAX_MESHES,
            max_materials: MAX_MATERIALS,
            max_lights: MAX_LIGHTS,
            max_file_bytes: MAX_FILE_BYTES,
        }
    }
}
