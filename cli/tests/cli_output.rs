//! `vkrt render -o FILE`: the image format by extension, errors before any rendering for
//! an unsupported one, no file left by a failed write; and the log flags `-q` / `-v`.

mod common;

use std::path::{Path, PathBuf};

use common::{no_gpu_allowed, vkrt, vkrt_ok};
use vkrt::render::output::{srgb8, SUPPORTED_EXTENSIONS};

const W: u32 = 32;
const H: u32 = 24;

/// A fresh, empty folder for one test.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vkrt-cli-output-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn entries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect()
}

/// Renders the default scene, small, to `out` (`None` without a GPU when that is allowed).
fn render_to(out: &Path) -> Option<()> {
    let (w, h) = (W.to_string(), H.to_string());
    vkrt_ok(&[
        "render",
        "-o",
        s(out),
        "--width",
        &w,
        "--height",
        &h,
        "--spp",
        "1",
    ])
    .map(|_| ())
}

/// A PFM's linear RGB, top row first.
fn read_pfm(path: &Path) -> Vec<[f32; 3]> {
    let bytes = std::fs::read(path).unwrap();
    let header = format!("PF\n{W} {H}\n-1.0\n");
    assert!(bytes.starts_with(header.as_bytes()), "{}", path.display());
    let floats: Vec<f32> = bytes[header.len()..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(floats.len(), (W * H * 3) as usize);
    let rows: Vec<&[f32]> = floats.chunks_exact(W as usize * 3).collect();
    rows.iter()
        .rev()
        .flat_map(|row| row.chunks_exact(3).map(|p| [p[0], p[1], p[2]]))
        .collect()
}

#[test]
fn each_format_is_written_by_its_extension() {
    let dir = temp_dir("formats");
    let magic: [(&str, &[u8]); 6] = [
        ("out.png", b"\x89PNG"),
        ("out.jpg", b"\xFF\xD8\xFF"),
        ("out.JPG", b"\xFF\xD8\xFF"),
        ("out.jpeg", b"\xFF\xD8\xFF"),
        ("out.exr", b"\x76\x2F\x31\x01"),
        ("out.pfm", b"PF"),
    ];
    for (name, magic) in magic {
        let path = dir.join(name);
        if render_to(&path).is_none() {
            return;
        }
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.starts_with(magic), "{name}: {:02x?}", &bytes[..8]);
        if !name.ends_with(".pfm") {
            let img = image::load_from_memory(&bytes).unwrap();
            assert_eq!((img.width(), img.height()), (W, H), "{name}");
        }
    }
    // The EXR holds the PFM's linear radiance (the same render: the renderer is
    // deterministic), and the PNG is its sRGB tonemap (the GPU's pow may round one level
    // differently).
    let pfm = read_pfm(&dir.join("out.pfm"));
    let exr = image::open(dir.join("out.exr")).unwrap().into_rgb32f();
    assert!(pfm.iter().flatten().any(|&c| c > 0.0), "a black render");
    let pfm_flat = pfm.iter().flatten();
    for (i, (&e, &p)) in exr.as_raw().iter().zip(pfm_flat.clone()).enumerate() {
        assert!(
            (e - p).abs() <= 1e-6 * p.abs().max(1.0),
            "channel {i}: {e} vs {p}"
        );
    }
    let png = image::open(dir.join("out.png")).unwrap().into_rgb8();
    for (i, (&q, &p)) in png.as_raw().iter().zip(pfm_flat).enumerate() {
        assert!(q.abs_diff(srgb8(p)) <= 1, "channel {i}: {q} vs {p}");
    }
    // The JPEG is the same picture, lossily.
    let jpg = image::open(dir.join("out.jpg")).unwrap().into_rgb8();
    let diff: u64 = jpg
        .as_raw()
        .iter()
        .zip(png.as_raw())
        .map(|(a, b)| a.abs_diff(*b) as u64)
        .sum();
    let mean = diff as f64 / png.as_raw().len() as f64;
    assert!(
        mean < 8.0,
        "JPEG differs from the PNG by {mean} levels on average"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_unsupported_extension_fails_before_rendering_and_writes_nothing() {
    let dir = temp_dir("bad-ext");
    for name in ["out.bmp", "out", "out.png.tmp"] {
        let out = dir.join(name);
        // A scene that does not exist: the extension is reported first, so it is checked
        // before the scene is read or a device is opened (this needs no GPU).
        let run = vkrt(&["render", "/no/such/scene.toml", "-o", s(&out)]);
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains("vkrt: error:"), "{err}");
        assert!(err.contains(SUPPORTED_EXTENSIONS), "{err}");
        assert!(err.contains(name), "{err}");
        assert!(!err.contains("/no/such/scene.toml"), "{err}");
    }
    assert!(entries(&dir).is_empty(), "{:?}", entries(&dir));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_unwritable_output_is_an_error_and_leaves_nothing() {
    let dir = temp_dir("unwritable");
    // A missing folder: caught before rendering.
    let missing = dir.join("no").join("out.png");
    let run = vkrt(&["render", "-o", s(&missing), "--width", "8", "--height", "8"]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(err.contains("no such directory"), "{err}");
    assert!(entries(&dir).is_empty(), "{:?}", entries(&dir));
    // A folder in the way: the write itself fails after the render; no temporary is left.
    let blocked = dir.join("blocked.exr");
    std::fs::create_dir(&blocked).unwrap();
    let run = vkrt(&["render", "-o", s(&blocked), "--width", "8", "--height", "8"]);
    let err = String::from_utf8_lossy(&run.stderr);
    if no_gpu_allowed() && !run.status.success() && err.contains("Vulkan") {
        return;
    }
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains("blocked.exr") && !err.contains("panicked"),
        "{err}"
    );
    assert!(blocked.is_dir() && entries(&blocked).is_empty());
    assert_eq!(entries(&dir), ["blocked.exr"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn quiet_silences_warnings_and_verbose_keeps_json_on_stdout_clean() {
    let dir = temp_dir("log");
    // No camera and no lights: two warnings by default (and no GPU needed).
    let scene = dir.join("bare.toml");
    std::fs::write(&scene, "[[spheres]]\ncenter = [0, 0, 0]\nradius = 1\n").unwrap();
    let run = vkrt(&["scene", s(&scene)]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    assert!(
        err.contains("vkrt: warning:") && err.contains("no [camera]"),
        "{err}"
    );
    for args in [["-q", "scene", s(&scene)], ["scene", s(&scene), "--quiet"]] {
        let run = vkrt(&args);
        assert!(run.status.success());
        assert!(
            run.stderr.is_empty(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        assert!(!run.stdout.is_empty());
    }
    let run = vkrt(&["-vvv", "scene", s(&scene), "--json"]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("no [camera]"), "{err}");
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert!(v.get("spheres").is_some(), "{v}");
    let run = vkrt(&["-q", "-v", "scene", s(&scene)]);
    assert!(!run.status.success());
    // With a device: -v logs it on stderr, the render's JSON stays alone on stdout.
    let out = dir.join("v.png");
    let Some(run) = vkrt_ok(&[
        "-v",
        "render",
        "-o",
        s(&out),
        "--width",
        "8",
        "--height",
        "8",
        "--json",
    ]) else {
        return;
    };
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("vkrt: info: device"), "{err}");
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(v["width"], 8, "{v}");
    std::fs::remove_dir_all(&dir).unwrap();
}
