//! Animated scenes: frames at a fixed rate, and keyframed mesh transforms.
//!
//! A scene with an [`Animation`] is a sequence of frames; frame `k` shows
//! the scene at time `k / fps` (frame 0 at `t = 0`). Everything that moves
//! is a function of time — velocities and orbits ([`Motion`](super::Motion))
//! and keyframed transforms ([`Keyframe`]) — so a frame is the scene with
//! its camera shutter shifted to the frame's time ([`Scene::at_frame`]).
//!
//! Keyframes are placements (translate, rotate, scale, written like a
//! mesh's [`Transform`]) at given times. Between two keys translation and
//! scale are interpolated linearly and rotation by slerp (the shorter arc);
//! before the first key and after the last the end keys hold. They animate
//! the placed mesh: at time `t` a mesh is placed by its `transform`, then
//! by its keyframed transform at `t`, then moved by its velocity and orbit.
//!
//! The renderer's motion model (`TraceGeometry::over_interval` and the GPU
//! `VkrtMotionRecord`) is rigid velocity + orbit, so within one exposure a
//! keyframed mesh is held at its keyed pose at the shutter-open time
//! ([`Scene::hold_keyframes`]); its velocity and orbit still blur.

use glam::{Affine3A, Mat3, Quat, Vec3};

use super::model::{Aabb, Transform};
use super::Scene;

/// Frame rate and length of an animated scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Animation {
    /// Frames per second, in (0, [`MAX_FPS`](super::MAX_FPS)].
    pub fps: f32,
    /// Number of frames, 1 ..= [`MAX_FRAMES`](super::MAX_FRAMES).
    pub frames: u32,
}

impl Animation {
    /// Time of frame `k` in seconds: `k / fps` (frame 0 at `t = 0`).
    /// Computed in `f64`, so late frames are the nearest `f32` to the
    /// exact time.
    pub fn frame_time(&self, k: u32) -> f32 {
        (f64::from(k) / f64::from(self.fps)) as f32
    }

    /// Length in seconds, `frames / fps`: the last frame shows time
    /// `duration − 1/fps`.
    pub fn duration(&self) -> f32 {
        self.frame_time(self.frames)
    }

    /// The frame count for an animation of `end_time` seconds:
    /// `⌈end_time · fps⌉`, so the frames cover `[0, end_time)`, and at least
    /// one. A product within 10⁻⁶ of an integer counts as that integer, so
    /// `end_time = 0.1` at 30 fps is 3 frames although `0.1f32 · 30` is
    /// slightly above 3. `None` when either input is not finite and
    /// positive; the count is not capped (the caller checks it against
    /// [`MAX_FRAMES`](super::MAX_FRAMES)).
    pub fn frames_for_end_time(end_time: f32, fps: f32) -> Option<u64> {
        if !(end_time.is_finite() && end_time > 0.0 && fps.is_finite() && fps > 0.0) {
            return None;
        }
        let exact = f64::from(end_time) * f64::from(fps);
        Some(((exact - 1e-6).ceil() as u64).max(1))
    }
}

/// A mesh placement at a time: the mesh's keyed transform at `time`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keyframe {
    /// Seconds; a mesh's keyframes have strictly increasing times.
    pub time: f32,
    /// Placement at `time` (no scale component zero).
    pub transform: Transform,
}

/// A placement in the form keyframes are interpolated in: scale, then
/// rotate, then translate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Translation.
    pub translate: Vec3,
    /// Rotation.
    pub rotation: Quat,
    /// Per-axis scale.
    pub scale: Vec3,
}

impl From<&Transform> for Pose {
    fn from(t: &Transform) -> Self {
        Self {
            translate: t.translate,
            rotation: t.rotation(),
            scale: t.scale,
        }
    }
}

impl Pose {
    /// Object-to-world matrix `T · R · S` (equal to [`Transform::matrix`]
    /// for a pose made from a transform).
    pub fn matrix(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(self.scale, self.rotation, self.translate)
    }

    /// The same placement written as a [`Transform`] (rotation as X, Y, Z
    /// degrees, Y in [−90°, 90°]), to `f32` rounding even near gimbal lock.
    pub fn to_transform(&self) -> Transform {
        // `Transform::rotate` is R = Rz(z)·Ry(y)·Rx(x), whose last row is
        // (−sin y, sin x·cos y, cos x·cos y). Solving for z after x, from
        // R·Rx(−x) = Rz(z)·Ry(y) (its middle column is (−sin z, cos z, 0)),
        // keeps the matrix accurate where y ≈ ±90° leaves x and z
        // ill-defined (M. Day, "Extracting Euler Angles from a Rotation
        // Matrix", Insomniac Games, 2014); asin-based formulas (glam's
        // `to_euler`) lose ~1e-4 there.
        let r = Mat3::from_quat(self.rotation);
        let (r01, r02, r11, r12) = (r.y_axis.x, r.z_axis.x, r.y_axis.y, r.z_axis.y);
        let (r20, r21, r22) = (r.x_axis.z, r.y_axis.z, r.z_axis.z);
        let x = r21.atan2(r22);
        let y = (-r20).atan2(r21.hypot(r22));
        let (sx, cx) = x.sin_cos();
        let z = (r02 * sx - r01 * cx).atan2(r11 * cx - r12 * sx);
        Transform {
            translate: self.translate,
            rotate: Vec3::new(x, y, z) * (180.0 / std::f32::consts::PI),
            scale: self.scale,
        }
    }
}

/// The keyed pose at time `t`: linear in translation and scale, slerp in
/// rotation between the keys around `t`, the end keys outside them (and
/// the first key for a NaN time). `None` when there are no keys. At a
/// key's time the result is that key exactly. Expects strictly increasing
/// times (validation's job); other input gives some key or blend, never a
/// panic.
pub fn pose_at(keys: &[Keyframe], t: f32) -> Option<Pose> {
    let (first, last) = (keys.first()?, keys.last()?);
    if t.is_nan() || t <= first.time {
        return Some(Pose::from(&first.transform));
    }
    if t >= last.time {
        return Some(Pose::from(&last.transform));
    }
    // Here `keys.len() ≥ 2`: `b` is the first key after `t`.
    let i = keys
        .partition_point(|k| k.time <= t)
        .clamp(1, keys.len() - 1);
    let (a, b) = (&keys[i - 1], &keys[i]);
    if t == a.time {
        return Some(Pose::from(&a.transform));
    }
    let u = ((t - a.time) / (b.time - a.time)).clamp(0.0, 1.0);
    let u = if u.is_nan() { 0.0 } else { u };
    let (pa, pb) = (Pose::from(&a.transform), Pose::from(&b.transform));
    Some(Pose {
        translate: pa.translate.lerp(pb.translate, u),
        rotation: pa.rotation.slerp(pb.rotation, u),
        scale: pa.scale.lerp(pb.scale, u),
    })
}

/// Where keyed placements can put a point at distance ≤ `reach` from the
/// origin, over all times: the box of the key translations grown by the
/// largest key scale times `reach` (rotation and slerp keep lengths;
/// interpolated translations and scales stay between the keys'). Empty
/// when there are no keys.
pub fn keyed_bounds(keys: &[Keyframe], reach: f32) -> Aabb {
    let mut b = Aabb::EMPTY;
    let mut max_scale = 0.0f32;
    for k in keys {
        b.grow(k.transform.translate);
        max_scale = max_scale.max(k.transform.scale.abs().max_element());
    }
    if !b.is_empty() {
        let r = Vec3::splat(max_scale * reach);
        b.min -= r;
        b.max += r;
    }
    b
}

impl Scene {
    /// Number of frames: the animation's, or 1 for a still scene.
    pub fn frame_count(&self) -> u32 {
        self.animation.map_or(1, |a| a.frames)
    }

    /// Time of frame `k` (0 for a still scene).
    pub fn frame_time(&self, k: u32) -> f32 {
        self.animation.map_or(0.0, |a| a.frame_time(k))
    }

    /// The still scene to render for frame `k`: the camera shutter shifted
    /// by the frame's time (so motion blur inside the frame still works),
    /// keyframed meshes held at their pose at the shifted shutter-open
    /// time ([`Scene::hold_keyframes`]), and no animation. Frame 0 of a
    /// scene without keyframes is the scene itself, less its animation.
    ///
    /// # Panics
    ///
    /// If `k ≥` [`Scene::frame_count`].
    pub fn at_frame(&self, k: u32) -> Scene {
        assert!(
            k < self.frame_count(),
            "frame {k} of a scene with {} frames",
            self.frame_count()
        );
        let t = self.frame_time(k);
        let mut s = self.clone();
        s.animation = None;
        s.camera.shutter_open += t;
        s.camera.shutter_close += t;
        s.hold_keyframes(s.camera.shutter_open);
        s
    }

    /// Whether some mesh has keyframes that change its placement over time
    /// (two or more keys).
    pub fn has_keyframe_motion(&self) -> bool {
        self.meshes.iter().any(|m| m.keyframes.len() > 1)
    }

    /// Freeze every keyframed mesh at its pose at time `t`: its keys become
    /// one key at `t`. This is what a renderer traces for an exposure that
    /// opens at `t`, since its motion model is rigid velocity + orbit.
    pub fn hold_keyframes(&mut self, t: f32) {
        for mesh in &mut self.meshes {
            if mesh.keyframes.len() > 1 {
                if let Some(pose) = pose_at(&mesh.keyframes, t) {
                    mesh.keyframes = vec![Keyframe {
                        time: t,
                        transform: pose.to_transform(),
                    }];
                }
            }
        }
    }
}
