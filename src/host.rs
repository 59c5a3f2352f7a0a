//! The process's own host memory, as the OS reports it (`/proc/self/status` on Linux;
//! `None` elsewhere). On a device whose memory is host memory (lavapipe) it includes the
//! device's allocations.

/// The resident set now (`VmRSS`).
pub fn host_rss_bytes() -> Option<u64> {
    status_kb("VmRSS:").map(|kb| kb * 1024)
}

/// The most the resident set has been since the process started (`VmHWM`, its high-water
/// mark).
pub fn host_peak_rss_bytes() -> Option<u64> {
    status_kb("VmHWM:").map(|kb| kb * 1024)
}

/// A `kB` field of `/proc/self/status`.
fn status_kb(field: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(field))?;
    line.split_whitespace().nth(1)?.parse().ok()
}
