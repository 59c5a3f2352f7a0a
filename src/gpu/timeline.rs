//! One time axis for the host and the device: host spans on the process's monotonic clock
//! (`std::time::Instant`), and GPU timestamps mapped onto it — through
//! `VK_KHR_calibrated_timestamps` or `VK_EXT_calibrated_timestamps` where the device has them
//! (one device tick and one `CLOCK_MONOTONIC` reading taken together after each submission),
//! else by placing a submission's first tick at the host time of its submit.

use std::ffi::CStr;
use std::sync::OnceLock;
use std::time::Instant;

use ash::vk;
use serde::Serialize;

/// The method of a [`Calibration`] without calibrated timestamps: the submission's first
/// tick is placed at the host time of its submit.
pub const SUBMIT_ALIGNED: &str = "submit-aligned";

static EPOCH: OnceLock<Instant> = OnceLock::new();

/// The origin of host times: the first time anything in vkrt asked for one.
fn epoch() -> Instant {
    *EPOCH.get_or_init(Instant::now)
}

/// Nanoseconds of `t` after the process's timeline origin (0 for an earlier instant).
pub fn host_ns(t: Instant) -> u64 {
    t.checked_duration_since(epoch())
        .map_or(0, |d| d.as_nanos() as u64)
}

/// Nanoseconds after the process's timeline origin, now.
pub fn host_now_ns() -> u64 {
    host_ns(Instant::now())
}

/// A stretch of host time: recording, a submit, a wait, a read-back, an upload, a build
/// on the CPU.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HostSpan {
    /// What the host did (`vkrt.record`, `vkrt.submit`, `vkrt.wait`, `vkrt.read_back`, …).
    pub name: &'static str,
    /// Start, in nanoseconds after the process's timeline origin ([`host_ns`]).
    pub start_ns: u64,
    /// End, on the same clock.
    pub end_ns: u64,
}

/// How a submission's device ticks map onto host time: `host_ns(tick) = host_ns +
/// (tick - gpu_tick) × timestampPeriod`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Calibration {
    /// `VK_KHR_calibrated_timestamps` or `VK_EXT_calibrated_timestamps` (a device tick and
    /// `CLOCK_MONOTONIC` read together), or [`SUBMIT_ALIGNED`].
    pub method: &'static str,
    /// A device tick …
    pub gpu_tick: u64,
    /// … and the host time it corresponds to ([`host_ns`]'s clock).
    pub host_ns: u64,
    /// The calibration's error bound in nanoseconds (`maxDeviation` of
    /// `vkGetCalibratedTimestamps`, plus the spread of reading `CLOCK_MONOTONIC` against
    /// `Instant`); `None` when submit-aligned (no bound: the device may start later).
    pub max_deviation_ns: Option<u64>,
}

/// The device-tick ↔ host-clock samples a context takes after each submission.
pub(crate) struct Calibrator {
    fns: CalibrationFns,
    /// `CLOCK_MONOTONIC` nanoseconds at the timeline origin, and the uncertainty of that.
    monotonic_at_epoch: (u64, u64),
}

enum CalibrationFns {
    Khr(ash::khr::calibrated_timestamps::Device),
    Ext(ash::ext::calibrated_timestamps::Device),
}

impl Calibrator {
    /// The calibrated-timestamps extension to enable on `pd`, where it has one whose time
    /// domains include the device's and the host clock `Instant` reads.
    pub(crate) fn extension(
        entry: &ash::Entry,
        instance: &ash::Instance,
        pd: vk::PhysicalDevice,
    ) -> Option<&'static CStr> {
        monotonic_now()?;
        // SAFETY: a plain query of a valid physical device.
        let extensions =
            unsafe { instance.enumerate_device_extension_properties(pd) }.unwrap_or_default();
        let has = |name: &CStr| {
            extensions
                .iter()
                .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == name))
        };
        let khr = ash::khr::calibrated_timestamps::NAME;
        let ext = ash::ext::calibrated_timestamps::NAME;
        // SAFETY: instance-level queries of a valid physical device, each only where the
        // device lists its extension.
        let domains = unsafe {
            if has(khr) {
                ash::khr::calibrated_timestamps::Instance::new(entry, instance)
                    .get_physical_device_calibrateable_time_domains(pd)
                    .map(|d| (khr, d))
            } else if has(ext) {
                ash::ext::calibrated_timestamps::Instance::new(entry, instance)
                    .get_physical_device_calibrateable_time_domains(pd)
                    .map(|d| (ext, d))
            } else {
                return None;
            }
        };
        let (name, domains) = domains.ok()?;
        (domains.contains(&vk::TimeDomainKHR::DEVICE)
            && domains.contains(&vk::TimeDomainKHR::CLOCK_MONOTONIC))
        .then_some(name)
    }

    /// The sampler of a device created with `extension` enabled.
    pub(crate) fn new(
        instance: &ash::Instance,
        device: &ash::Device,
        extension: &'static CStr,
    ) -> Option<Self> {
        let fns = if extension == ash::khr::calibrated_timestamps::NAME {
            CalibrationFns::Khr(ash::khr::calibrated_timestamps::Device::new(
                instance, device,
            ))
        } else {
            CalibrationFns::Ext(ash::ext::calibrated_timestamps::Device::new(
                instance, device,
            ))
        };
        Some(Self {
            fns,
            monotonic_at_epoch: monotonic_at_epoch()?,
        })
    }

    /// The extension's name, as a calibration's method.
    fn method(&self) -> &'static str {
        match self.fns {
            CalibrationFns::Khr(_) => "VK_KHR_calibrated_timestamps",
            CalibrationFns::Ext(_) => "VK_EXT_calibrated_timestamps",
        }
    }

    /// A device tick and the host time it corresponds to, read now; `None` where the call
    /// fails (the profile then falls back to aligning with the submit).
    pub(crate) fn sample(&self) -> Option<Calibration> {
        let infos = [
            vk::CalibratedTimestampInfoKHR::default().time_domain(vk::TimeDomainKHR::DEVICE),
            vk::CalibratedTimestampInfoKHR::default()
                .time_domain(vk::TimeDomainKHR::CLOCK_MONOTONIC),
        ];
        // SAFETY: the device was created with this extension enabled and both domains are
        // among those it lists (`Calibrator::extension`).
        let got = unsafe {
            match &self.fns {
                CalibrationFns::Khr(d) => d.get_calibrated_timestamps(&infos),
                CalibrationFns::Ext(d) => d.get_calibrated_timestamps(&infos),
            }
        };
        let (ticks, deviation) = got.ok()?;
        let (at_epoch, spread) = self.monotonic_at_epoch;
        Some(Calibration {
            method: self.method(),
            gpu_tick: ticks[0],
            host_ns: ticks[1].saturating_sub(at_epoch),
            max_deviation_ns: Some(deviation + spread),
        })
    }
}

/// `CLOCK_MONOTONIC` now, in nanoseconds: the clock `Instant` reads on Linux, and the host
/// domain of the calibrated-timestamps extensions.
#[cfg(all(target_os = "linux", target_pointer_width = "64"))]
fn monotonic_now() -> Option<u64> {
    #[repr(C)]
    struct Timespec {
        sec: i64,
        nsec: std::ffi::c_long,
    }
    extern "C" {
        fn clock_gettime(clock: i32, tp: *mut Timespec) -> i32;
    }
    const CLOCK_MONOTONIC: i32 = 1;
    let mut t = Timespec { sec: 0, nsec: 0 };
    // SAFETY: glibc's and musl's clock_gettime on a 64-bit Linux: `Timespec` is their
    // `struct timespec` (time_t and long are 64 bits), written only on success.
    let ok = unsafe { clock_gettime(CLOCK_MONOTONIC, &mut t) } == 0;
    ok.then(|| t.sec as u64 * 1_000_000_000 + t.nsec as u64)
}

/// Elsewhere `Instant`'s clock is not one of the extensions' domains: submissions are
/// aligned with their submit instead.
#[cfg(not(all(target_os = "linux", target_pointer_width = "64")))]
fn monotonic_now() -> Option<u64> {
    None
}

/// `CLOCK_MONOTONIC` at the timeline origin, from the closest of a few readings taken
/// between two `Instant`s, and half that gap (the reading's uncertainty).
fn monotonic_at_epoch() -> Option<(u64, u64)> {
    static AT_EPOCH: OnceLock<Option<(u64, u64)>> = OnceLock::new();
    *AT_EPOCH.get_or_init(|| {
        (0..5)
            .filter_map(|_| {
                let before = host_now_ns();
                let m = monotonic_now()?;
                let after = host_now_ns();
                let mid = before + (after - before) / 2;
                Some((m.checked_sub(mid)?, (after - before).div_ceil(2)))
            })
            .min_by_key(|&(_, spread)| spread)
    })
}

/// Runs `f` as a host span named `name` in the active profile capture
/// ([`super::capture_profiles`]); with the `profiling` feature also as a `profiling` scope
/// (Tracy, Puffin, Optick, Superluminal or `tracing`, as the application chose).
pub fn host_span<R>(name: &'static str, f: impl FnOnce() -> R) -> R {
    let start = Instant::now();
    let r = profiling_scope(name, f);
    record_host_span(name, start);
    r
}

/// Runs `f` inside a `profiling` scope named `name` (with the `profiling` feature; else
/// just runs it).
pub(crate) fn profiling_scope<R>(name: &'static str, f: impl FnOnce() -> R) -> R {
    #[cfg(feature = "profiling")]
    profiling::scope!(name);
    // (Unused where no profiler is on: `profiling`'s scopes are then empty.)
    let _ = name;
    f()
}

/// Records a host span named `name` from `start` until now in the active profile capture.
/// Without a capture it records nothing.
pub fn record_host_span(name: &'static str, start: Instant) {
    super::profiler::record_host_span(HostSpan {
        name,
        start_ns: host_ns(start),
        end_ns: host_now_ns(),
    });
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_monotonic_clock_agrees_with_instant() {
        let Some((at_epoch, spread)) = super::monotonic_at_epoch() else {
            return;
        };
        let now = super::monotonic_now().unwrap() - at_epoch;
        let host = super::host_now_ns();
        // Read one after the other: within the reading's spread and a millisecond.
        assert!(now.abs_diff(host) < spread + 1_000_000, "{now} vs {host}");
    }
}
