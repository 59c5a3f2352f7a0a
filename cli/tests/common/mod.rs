//! Shared setup of the command line's tests: the library's test setup (tests/common in the
//! checkout's root), and running the `vkrt` binary of this build.
#![allow(dead_code, reason = "each test binary uses a different part")]

#[path = "../../../tests/common/mod.rs"]
mod library;
#[allow(unused_imports, reason = "each test binary uses a different part")]
pub use library::*;

/// Runs the `vkrt` binary of this build in the checkout's root, where `./x vkrt` runs it
/// (its defaults name `scenes/...` there).
pub fn vkrt(args: &[&str]) -> std::process::Output {
    vkrt_command()
        .current_dir(checkout())
        .args(args)
        .output()
        .expect("run vkrt")
}

/// A command starting the `vkrt` binary of this build, through the runner the tests run
/// under, if any (a driver that needs another glibc needs it in the child too).
pub fn vkrt_command() -> std::process::Command {
    let exe = env!("CARGO_BIN_EXE_vkrt");
    match std::env::var("CARGO_TARGET_X86_64_UNKNOWN_LINUX_GNU_RUNNER") {
        Ok(runner) if !runner.is_empty() => {
            let mut c = std::process::Command::new(runner);
            c.arg(exe);
            c
        }
        _ => std::process::Command::new(exe),
    }
}

/// Runs `vkrt` and expects success: `None` (skip) when it failed and no device is allowed,
/// otherwise a failure shows its stderr.
pub fn vkrt_ok(args: &[&str]) -> Option<std::process::Output> {
    let out = vkrt(args);
    if !out.status.success() && no_gpu_allowed() {
        return None;
    }
    assert!(
        out.status.success(),
        "vkrt {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    Some(out)
}
