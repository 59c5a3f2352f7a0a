#[allow(dead_code)] // the bench uses what the tests do not
pub mod app;

/// How the layer's `VKRT_LAYER_STATS` lines start.
pub const STATS: &str = "vkrt layer: stats: ";

/// The layer's `VKRT_LAYER_STATS` lines in `stderr`: each recorded command and the Vulkan
/// objects vkrt created while recording it.
#[allow(dead_code)] // each test binary uses part of this module
pub fn objects_created_while_recording(stderr: &str) -> Vec<(String, u64)> {
    stderr
        .lines()
        .filter_map(|l| l.strip_prefix(STATS))
        .map(|l| {
            let (call, rest) = l.split_once(": ").unwrap();
            (
                call.to_string(),
                rest.split(' ').next().unwrap().parse().unwrap(),
            )
        })
        .collect()
}

/// Ray-triangle (Möller–Trumbore, f64): t, u, v where the ray meets the triangle's plane
/// (inside where u, v ≥ 0 and u + v ≤ 1).
pub fn intersect(o: [f64; 3], d: [f64; 3], t: &[[f64; 3]; 3]) -> Option<(f64, f64, f64)> {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (e1, e2) = (sub(t[1], t[0]), sub(t[2], t[0]));
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det.abs() < 1e-12 {
        return None;
    }
    let s = sub(o, t[0]);
    let u = dot(s, p) / det;
    let q = cross(s, e1);
    let v = dot(d, q) / det;
    let tt = dot(e2, q) / det;
    (u >= 0.0 && v >= 0.0 && u + v <= 1.0).then_some((tt, u, v))
}

/// Runs the child `cmd`, which writes its answer to `out`: that answer and its standard
/// error. A child that fails fails the test, naming `what` with its output.
pub fn run_to_file(
    mut cmd: std::process::Command,
    out: &std::path::Path,
    what: &str,
) -> (String, String) {
    let o = cmd.output().expect("the test binary, again");
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(
        o.status.success(),
        "{what} failed: {}\n{stderr}",
        String::from_utf8_lossy(&o.stdout)
    );
    let text = std::fs::read_to_string(out).unwrap();
    let _ = std::fs::remove_file(out);
    (text, stderr)
}
