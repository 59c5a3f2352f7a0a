//! What `vkrt bench` and the benches measure with a device: the copy baselines every kernel
//! is set against ([`copy`]), the GPU primitives ([`prims`]), Kolodzey's kd-tree build
//! ([`kdtree`]) and the fixed set whose history guards against regressions ([`history`]).

use vkrt::gpu::Profile;

pub mod copy;
pub mod history;
pub mod kdtree;
pub mod prims;

/// The scope name of repetition `rep` of the variant `name`: repetition 0 is the untimed
/// warm-up (`warmup.NAME`: the first touch of fresh memory costs page faults on lavapipe),
/// the timed ones share `name` for [`best_ms`].
pub fn rep_scope(rep: u32, name: &str) -> String {
    if rep == 0 {
        format!("warmup.{name}")
    } else {
        name.to_string()
    }
}

/// The fastest of the timed scopes called `name` in `profile` (infinity where none was
/// timed): a variant's figure when a submission ran it several times.
pub fn best_ms(profile: &Profile, name: &str) -> f64 {
    profile
        .passes
        .iter()
        .filter(|p| p.name == name)
        .filter_map(|p| p.ms)
        .fold(f64::INFINITY, f64::min)
}

/// The exponent `k` of the power law `ms ≈ c·n^k` through `(n, ms)` points: the
/// least-squares slope of log(ms) over log(n); `None` for fewer than two points.
pub fn power_law_exponent(points: &[(f64, f64)]) -> Option<f64> {
    (points.len() >= 2).then(|| {
        let logs: Vec<(f64, f64)> = points.iter().map(|p| (p.0.ln(), p.1.ln())).collect();
        let n = logs.len() as f64;
        let (sx, sy) = logs.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        let (mx, my) = (sx / n, sy / n);
        let num: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let den: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
        num / den
    })
}

#[cfg(test)]
mod tests {
    use super::power_law_exponent;

    #[test]
    fn the_power_law_exponent_of_exact_points_is_their_power() {
        let pts: Vec<(f64, f64)> = [1e3, 1e4, 2e5, 3e6]
            .iter()
            .map(|&n: &f64| (n, 0.25 * n.powf(1.37)))
            .collect();
        let k = power_law_exponent(&pts).unwrap();
        assert!((k - 1.37).abs() < 1e-9, "{k}");
        assert_eq!(power_law_exponent(&pts[..1]), None);
    }
}
