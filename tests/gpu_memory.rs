//! Memory the gpu layer leaves behind, under validation (the layer's bookkeeping is part
//! of it). A binary of its own: no other test allocates while resident memory is measured.

mod common;

use vkrt::gpu::Recorder;

/// Resident memory of this process in MiB (Linux).
fn resident_mib() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split(' ').nth(1)?.parse().ok()?;
    Some((pages * 4096) >> 20)
}

/// Recorders are made per submission, hundreds per test: one must not leave memory behind.
/// A whole-pool reset of the 32,768 timestamp queries left 4.6 MB per recorder in the
/// validation layer (1.3.239), 1.9 GB over 400 recorders, until queries were reset one by
/// one as they are used.
#[test]
fn recorders_leave_no_memory_behind() {
    let Some(ctx) = common::context() else { return };
    let cycle = |scopes: usize| {
        let mut rec = Recorder::new(&ctx).unwrap();
        for i in 0..scopes {
            rec.scope(&format!("scope{i}"), |_| {});
        }
        rec.submit_and_wait().unwrap();
    };
    for _ in 0..20 {
        cycle(4); // warm-up: allocator pools, layer tables
    }
    let Some(before) = resident_mib() else {
        eprintln!("skipped: no /proc/self/statm");
        return;
    };
    for _ in 0..400 {
        cycle(4);
    }
    let grown = resident_mib().unwrap().saturating_sub(before);
    assert!(grown < 64, "400 recorders grew the process by {grown} MiB");
    common::assert_silent(&ctx);
}
