//! The best GPU time of a profiler scope over repeated recordings: the benches that time a
//! build or a refit by its scope.

use vkrt::gpu::{Context, Recorder};

/// The best GPU milliseconds of `scope` over `runs` recordings of `record`, each submitted
/// and waited for (the first of them warms up like the rest; NaN where the scope is absent).
pub fn best_of(
    ctx: &Context,
    scope: &str,
    runs: u32,
    mut record: impl FnMut(&mut Recorder),
) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..runs {
        let mut rec = Recorder::new(ctx).expect("recorder");
        record(&mut rec);
        let p = rec.submit_and_wait().expect("submit");
        best = best.min(p.ms(scope).unwrap_or(f64::NAN));
    }
    best
}
