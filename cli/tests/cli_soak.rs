//! `vkrt bench soak --quick` as a user runs it: every frame finite and the checked ones
//! equal to a fresh render, every random build's answers equal to brute force's, the memory
//! measures present and flat, and the validation layer silent.

mod common;

use common::vkrt_ok;
use serde_json::Value;

#[test]
fn quick_soak_finds_no_mismatch_and_no_growth() {
    let mut args = vec!["bench", "soak", "--quick", "--json"];
    if !std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "0") {
        args.push("--validate");
    }
    let Some(out) = vkrt_ok(&args) else { return };
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("validation:"), "validation messages:\n{err}");
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["passed"], true, "{v}");
    assert_eq!(v["mismatches"], 0, "{v}");
    let f = &v["frames"];
    assert_eq!(f["frames"], 100);
    assert_eq!(f["non_finite_frames"], 0);
    let checks = f["checks"].as_array().unwrap();
    assert!(checks.len() >= 4, "{f}");
    for c in checks {
        assert_eq!(c["fresh_equal"], true, "{c}");
    }
    let b = &v["builds"];
    assert_eq!(b["builds"], 40);
    assert!(b["rays"].as_u64().unwrap() > 0);
    for k in ["mismatches", "exhausted", "invalid"] {
        assert_eq!(b[k], 0, "{k}: {b}");
    }
    for m in [&f["memory"], &b["memory"]] {
        let g = m["device_growth"].as_f64().unwrap();
        assert!(g.is_finite() && g <= 0.01, "{m}");
        assert!(m["warm"]["device_bytes"].is_u64(), "{m}");
        assert!(m["end"]["device_bytes"].is_u64(), "{m}");
        if cfg!(target_os = "linux") {
            let r = m["host_rss_growth"].as_f64().unwrap();
            assert!(r.is_finite(), "{m}");
            // (under the validation layer its own tracking grows: RSS is not judged)
            if v["host_rss_judged"] == true {
                assert!(r <= 0.01, "{m}");
            }
        }
    }
    assert!(v["wall_s"].as_f64().unwrap() > 0.0);
}
