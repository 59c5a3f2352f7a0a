//! An on-disk Vulkan pipeline cache, so kernels JIT-compiled by the driver (lavapipe runs
//! LLVM for every pipeline) are reused across runs.
//!
//! Location: `$VKRT_PIPELINE_CACHE` (a directory; `0` or `off` disables), else
//! `$XDG_CACHE_HOME/vkrt`, else `$HOME/.cache/vkrt`. One file per driver cache UUID, written
//! atomically (temporary file + rename) so concurrent processes and contexts never see a torn
//! file. The driver validates the header, so a stale or foreign file is ignored, not trusted.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

use ash::vk;

use super::error::{vk_err, Result};
use super::info::DeviceInfo;

/// The default cache file: see the module docs.
pub(crate) fn default_path(info: &DeviceInfo) -> Option<PathBuf> {
    let dir = match std::env::var("VKRT_PIPELINE_CACHE") {
        Ok(v) if v == "0" || v.eq_ignore_ascii_case("off") => return None,
        Ok(v) if !v.is_empty() => PathBuf::from(v),
        _ => match std::env::var_os("XDG_CACHE_HOME") {
            Some(x) if !x.is_empty() => PathBuf::from(x).join("vkrt"),
            _ => PathBuf::from(std::env::var_os("HOME")?)
                .join(".cache")
                .join("vkrt"),
        },
    };
    Some(path_in(&dir, info))
}

/// The cache file in directory `dir` for this driver.
pub(crate) fn path_in(dir: &std::path::Path, info: &DeviceInfo) -> PathBuf {
    let uuid: String = info
        .pipeline_cache_uuid
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    dir.join(format!("pipelines-{uuid}.bin"))
}

/// A pipeline cache primed from `path` (none: an empty cache that is never saved).
pub(crate) fn create(
    device: &ash::Device,
    path: Option<&std::path::Path>,
) -> Result<vk::PipelineCache> {
    let data = path.and_then(|p| std::fs::read(p).ok()).unwrap_or_default();
    let create = vk::PipelineCacheCreateInfo::default().initial_data(&data);
    // SAFETY: valid device; the driver checks the header of `data` and ignores a mismatch.
    match unsafe { device.create_pipeline_cache(&create, None) } {
        Ok(cache) => Ok(cache),
        Err(_) if !data.is_empty() => {
            let empty = vk::PipelineCacheCreateInfo::default();
            // SAFETY: as above, with no initial data.
            unsafe { device.create_pipeline_cache(&empty, None) }
                .map_err(vk_err("vkCreatePipelineCache"))
        }
        Err(e) => Err(vk_err("vkCreatePipelineCache")(e)),
    }
}

/// Writes the cache to disk (best effort: a cache is never worth failing for) and destroys it.
///
/// # Safety
/// `cache` was created on `device` and no pipeline creation using it is in flight.
pub(crate) unsafe fn save_and_destroy(
    device: &ash::Device,
    cache: vk::PipelineCache,
    path: Option<&std::path::Path>,
) {
    // SAFETY: guaranteed by the caller.
    let data = unsafe { device.get_pipeline_cache_data(cache) }.unwrap_or_default();
    if let (Some(path), false) = (path, data.is_empty()) {
        if let Some(dir) = path.parent() {
            let _ = std::fs::create_dir_all(dir);
        }
        // Unique per process and per save: two contexts of one process may save at once.
        static SAVES: AtomicU64 = AtomicU64::new(0);
        let save = SAVES.fetch_add(1, Ordering::Relaxed);
        let tmp = path.with_extension(format!("tmp{}-{save}", std::process::id()));
        if std::fs::write(&tmp, &data).is_ok() {
            let _ = std::fs::rename(&tmp, path);
        }
        let _ = std::fs::remove_file(&tmp);
    }
    // SAFETY: guaranteed by the caller.
    unsafe { device.destroy_pipeline_cache(cache, None) };
}
