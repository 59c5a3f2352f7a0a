//! A scene's two levels on the driver's own structures ([`DriverAccel::record_instanced`])
//! as a structure the `query` kernels trace, and its levels for a later move of the
//! instances: the bridge from the driver's family to [`AccelStructure`], above both.

use crate::accel::device::{AccelKind, AccelStructure, Storage};
use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::driver::storage::DriverStorage;
use crate::accel::driver::{DriverAccel, InstancedIds, Prefer};
use crate::accel::instance::Instance;
use crate::accel::primitives::SceneInfo;
use crate::gpu::{Buffer, Recorder, Result};
use crate::scene::Aabb;

/// The driver's two levels over `instances` of `levels` (their primitives uploaded before,
/// into `rec` or earlier), recorded into `rec`: a structure the `query` kernels trace with
/// level `bound`'s primitives bound (see [`DriverAccel::record_instanced`]).
pub(crate) fn record_instanced(
    rec: &mut Recorder,
    levels: &[&DevicePrimitives],
    instances: &[Instance],
    bound: usize,
    prefer: Prefer,
) -> Result<(AccelStructure, InstancedIds)> {
    let ctx = rec.context().clone();
    let (accel, ids) = DriverAccel::record_instanced(rec, levels, instances, bound, prefer)?;
    let info = Buffer::new(&ctx, "accel.info", 1)?;
    let address = Buffer::new(&ctx, "accel.driver.address", 1)?;
    let bases = Buffer::new(&ctx, "accel.driver.bases", ids.bases.len())?;
    let constants = match levels.get(bound) {
        Some(p) => p.info(&Aabb::EMPTY, 0),
        None => SceneInfo::new(&Aabb::EMPTY, [0, 0, 0], false, 0),
    };
    rec.update(&info, 0, &[constants.walked(SceneInfo::WALK_RAY_QUERY)])?;
    rec.update(&address, 0, &[accel.tlas_address()])?;
    for (k, chunk) in ids.bases.chunks(8192).enumerate() {
        rec.update(&bases, 8192 * k, chunk)?;
    }
    rec.transfer_to_compute();
    let storage = DriverStorage {
        levels: Some(Box::new(accel)),
        address,
        bases,
    };
    let out = AccelStructure::from_parts(AccelKind::Driver, Storage::Driver(storage), info);
    Ok((out, ids))
}

/// The driver's levels of `accel`, where it is the driver's structure and they exist.
pub(crate) fn levels(accel: &AccelStructure) -> Option<&DriverAccel> {
    match accel.storage() {
        Storage::Driver(d) => d.levels.as_deref(),
        _ => None,
    }
}

/// [`levels`], to move the instances (the renderer's animation does).
#[cfg(feature = "render")]
pub(crate) fn levels_mut(accel: &mut AccelStructure) -> Option<&mut DriverAccel> {
    match accel.storage_mut() {
        Storage::Driver(d) => d.levels.as_deref_mut(),
        _ => None,
    }
}

/// The driver's buffers of `accel`, where it is the driver's structure.
pub(crate) fn storage_mut(accel: &mut AccelStructure) -> Option<&mut DriverStorage> {
    match accel.storage_mut() {
        Storage::Driver(d) => Some(d),
        _ => None,
    }
}
