//! `[animation]` and `[[meshes.keyframes]]` of the TOML format, both ways.
//!
//! Reading checks what only the file can get wrong (`frames` and `end_time`
//! both or neither, a bad `end_time`); everything the model can express is
//! left to [`validate`](super::validate), so hand-built scenes get the same
//! checks and messages.

use glam::Vec3;

use super::animation::{Animation, Keyframe};
use super::error::{Origin, SceneError};
use super::limits::{MAX_FRAMES, MAX_TIME};
use super::model::Transform;
use super::toml_defs::{AnimationDef, KeyframeDef, Vec3OrScalar};
use super::validate;

/// The model's animation; `end_time` becomes a frame count
/// ([`Animation::frames_for_end_time`]).
pub(super) fn animation_from_def(a: &AnimationDef) -> Result<Animation, SceneError> {
    let frames = match (a.frames, a.end_time) {
        (Some(frames), None) => frames,
        (None, Some(end_time)) => frames_for(end_time, a.fps)?,
        (Some(_), Some(_)) => {
            return Err(SceneError::invalid(
                Origin::key("animation.end_time"),
                "give either `frames` or `end_time`, not both",
            ))
        }
        (None, None) => {
            return Err(SceneError::invalid(
                Origin::key("animation"),
                "[animation] needs `frames` (a count) or `end_time` (seconds)",
            ))
        }
    };
    Ok(Animation { fps: a.fps, frames })
}

fn frames_for(end_time: f32, fps: f32) -> Result<u32, SceneError> {
    const K: &str = "animation.end_time";
    validate::fps(fps, "animation.fps")?;
    if !end_time.is_finite() {
        return Err(SceneError::NonFinite {
            origin: Origin::key(K),
            value: end_time.to_string(),
        });
    }
    if !(end_time > 0.0 && end_time <= MAX_TIME) {
        return Err(SceneError::out_of_range(
            Origin::key(K),
            end_time,
            format!("the animation's length must be in (0, {MAX_TIME:e}] s"),
        ));
    }
    let frames = Animation::frames_for_end_time(end_time, fps).unwrap_or(0);
    u32::try_from(frames)
        .ok()
        .filter(|&n| n <= MAX_FRAMES)
        .ok_or_else(|| {
            SceneError::out_of_range(
                Origin::key(K),
                format!("{end_time} s at {fps} fps = {frames} frames"),
                format!("the frame count must be 1 ..= {MAX_FRAMES}"),
            )
        })
}

/// Keys as written; omitted fields are the identity.
pub(super) fn keyframes_from_defs(defs: &[KeyframeDef]) -> Vec<Keyframe> {
    defs.iter()
        .map(|d| Keyframe {
            time: d.time,
            transform: Transform {
                translate: d.translate.map_or(Vec3::ZERO, Vec3::from_array),
                rotate: d.rotate.map_or(Vec3::ZERO, Vec3::from_array),
                scale: d.scale.map_or(Vec3::ONE, |s| Vec3::from_array(s.0)),
            },
        })
        .collect()
}

/// `[animation]` as the writer puts it: always as a frame count, which is
/// what the model keeps.
pub(super) fn animation_def(a: &Animation) -> AnimationDef {
    AnimationDef {
        fps: a.fps,
        frames: Some(a.frames),
        end_time: None,
    }
}

/// Keys with every field written.
pub(super) fn keyframe_defs(keys: &[Keyframe]) -> Vec<KeyframeDef> {
    keys.iter()
        .map(|k| KeyframeDef {
            time: k.time,
            translate: Some(k.transform.translate.to_array()),
            rotate: Some(k.transform.rotate.to_array()),
            scale: Some(Vec3OrScalar(k.transform.scale.to_array())),
        })
        .collect()
}
