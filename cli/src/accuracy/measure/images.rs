//! The image groups' side of `vkrt bench accuracy`: the scenes images are compared on,
//! their converged references, and renders of a setting against them (see the parent
//! module's docs for what is compared and how).

use super::{AccuracyOptions, BoxError, Sizes};
use crate::accuracy::knobs::ImageSetting;
use crate::accuracy::{Accuracy, Costs, ImageError, ImageFile, ImageScene, Point};
use crate::trace_bench::scenes;
use vkrt::accel::device::AccelChoice;
use vkrt::gpu::Context;
use vkrt::render::{render_scene, RenderOptions};
use vkrt::scene::Scene;
use vkrt::trace::TraceOptions;

/// A scene images are compared on, its reference rendered.
pub(super) struct Compared {
    pub(super) info: ImageScene,
    scene: Scene,
    /// Display values of the reference, RGB in [0, 1].
    reference: Vec<[f32; 3]>,
}

/// The default scene and the effect scenes (every static `*.toml` in `scenes_dir`), with
/// their references rendered.
pub(super) fn image_scenes(
    ctx: &Context,
    opt: &AccuracyOptions,
    sizes: &Sizes,
    images: &mut Vec<ImageFile>,
    progress: &mut impl FnMut(&str),
) -> Result<Vec<Compared>, BoxError> {
    let mut list = vec![("default".to_string(), Scene::default_scene())];
    let paths = scenes::scene_files(&opt.scenes_dir)?;
    for p in paths {
        let scene = Scene::load(&p)?.scene;
        if scene.frame_count() > 1 {
            continue; // animated: the motion group's
        }
        let name = p
            .file_stem()
            .map_or("scene".into(), |s| s.to_string_lossy().into_owned());
        list.push((name, scene));
    }
    let mut out = Vec::new();
    for (name, mut scene) in list {
        scene.settings.max_depth = sizes.reference_depth;
        let r = render(
            ctx,
            &scene,
            sizes,
            sizes.reference_spp,
            super::REFERENCE_ACCEL,
            &TraceOptions::default(),
        )?;
        let file = format!("images/{name}/reference.png");
        progress(&format!("reference {name}: {} spp, {:.0} ms", r.spp, r.ms));
        images.push(ImageFile {
            file: file.clone(),
            width: sizes.width,
            height: sizes.height,
            rgba: r.rgba.clone(),
        });
        out.push(Compared {
            info: ImageScene {
                name,
                width: sizes.width,
                height: sizes.height,
                reference_spp: r.spp,
                reference_depth: sizes.reference_depth,
                reference_file: file,
            },
            scene,
            reference: display(&r.rgba),
        });
    }
    Ok(out)
}

/// One render's image and GPU time.
struct Render {
    rgba: Vec<u8>,
    ms: f64,
    /// The samples the plan used (a scene without sampled effects needs one).
    spp: u32,
}

fn render(
    ctx: &Context,
    scene: &Scene,
    sizes: &Sizes,
    spp: u32,
    accel: AccelChoice,
    trace: &TraceOptions,
) -> Result<Render, BoxError> {
    let opt = RenderOptions {
        width: Some(sizes.width),
        height: Some(sizes.height),
        spp: Some(spp),
        all_effects: false,
        accel,
        flatten: false,
        max_level_primitives: None,
    };
    // lavapipe compiles a pipeline at its first dispatch: a tiny render first, untimed.
    let warm = RenderOptions {
        width: Some(8),
        height: Some(6),
        spp: Some(1),
        ..opt
    };
    render_scene(ctx, scene, &warm, trace, |_, _| {})?;
    let r = render_scene(ctx, scene, &opt, trace, |_, _| {})?;
    Ok(Render {
        spp: r.plan.spp,
        ms: r.render_ms,
        rgba: r.image.rgba,
    })
}

/// RGB display values in [0, 1] of 8-bit RGBA.
fn display(rgba: &[u8]) -> Vec<[f32; 3]> {
    rgba.chunks_exact(4)
        .map(|p| [0, 1, 2].map(|c| f32::from(p[c]) / 255.0))
        .collect()
}

/// RMSE over every channel and the largest channel difference.
fn image_error(a: &[[f32; 3]], b: &[[f32; 3]]) -> (f64, f64) {
    let (mut sum, mut worst) = (0.0f64, 0.0f64);
    for (p, q) in a.iter().zip(b) {
        for c in 0..3 {
            let d = f64::from(p[c] - q[c]).abs();
            sum += d * d;
            worst = worst.max(d);
        }
    }
    let n = (a.len() * 3).max(1) as f64;
    ((sum / n).sqrt(), worst)
}

/// A file-name-safe form of a label.
pub(super) fn slug(s: &str) -> String {
    let mut out = String::new();
    for c in s.chars() {
        match c {
            'a'..='z' | 'A'..='Z' | '0'..='9' => out.push(c.to_ascii_lowercase()),
            _ if !out.ends_with('-') && !out.is_empty() => out.push('-'),
            _ => {}
        }
    }
    out.trim_end_matches('-').to_string()
}

/// Renders every image scene with `accel` and `trace` at `spp` and `depth`; the errors and
/// the summed GPU ms.
#[allow(clippy::too_many_arguments)]
pub(super) fn render_all(
    ctx: &Context,
    scenes: &[Compared],
    sizes: &Sizes,
    (spp, depth): (u32, u32),
    accel: AccelChoice,
    trace: &TraceOptions,
    file_stem: &str,
    images: &mut Vec<ImageFile>,
) -> Result<(Vec<ImageError>, f64), BoxError> {
    let (mut errors, mut ms) = (Vec::new(), 0.0);
    for s in scenes {
        let mut scene = s.scene.clone();
        scene.settings.max_depth = depth;
        let r = render(ctx, &scene, sizes, spp, accel, trace)?;
        let (rmse, worst) = image_error(&display(&r.rgba), &s.reference);
        let file = format!("images/{}/{file_stem}.png", s.info.name);
        images.push(ImageFile {
            file: file.clone(),
            width: sizes.width,
            height: sizes.height,
            rgba: r.rgba,
        });
        ms += r.ms;
        errors.push(ImageError {
            scene: s.info.name.clone(),
            rmse,
            worst,
            file,
        });
    }
    Ok((errors, ms))
}

pub(super) fn measure_image(
    ctx: &Context,
    scenes: &[Compared],
    sizes: &Sizes,
    s: &ImageSetting,
    group: &str,
    images: &mut Vec<ImageFile>,
) -> Result<Point, BoxError> {
    let (errors, ms) = render_all(
        ctx,
        scenes,
        sizes,
        (s.spp, s.depth),
        super::REFERENCE_ACCEL,
        &TraceOptions::default(),
        &format!("{group}-{}", slug(&s.label)),
        images,
    )?;
    let mean = errors.iter().map(|e| e.rmse).sum::<f64>() / errors.len().max(1) as f64;
    Ok(Point {
        setting: s.label.clone(),
        time_ms: ms,
        error: mean,
        costs: Costs {
            render_ms: Some(ms),
            ..Costs::default()
        },
        accuracy: Accuracy {
            images: errors,
            ..Accuracy::default()
        },
        use_times: None,
        note: None,
    })
}
