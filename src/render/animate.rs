//! What `vkrt animate` writes: frame files named by a printf-style pattern
//! (`out/frame_%04d.png`), encoded and written on a thread of their own while the device
//! renders the next frame (double-buffered: at most one finished frame waits), and an
//! animated PNG of every frame for a quick look. Each file is written atomically; on any
//! error the files this run wrote are removed, so a failed animation leaves no partial set.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::JoinHandle;

use super::gpu::{FrameLoop, Renderer, Update};
use super::output::{exr_bytes, jpeg_bytes, pfm_bytes, png_bytes, ImageFormat};
use super::{Plan, RenderOptions, RenderScene};
use crate::accel::device::AccelKind;
use crate::accel::host::HostStructure;
use crate::gpu::{write_atomically, Context, GpuError};
use crate::scene::Scene;
use crate::trace::TraceOptions;

/// A frame file name pattern: one `%d` or `%0Nd` in the file name, a `.png` or `.jpg`
/// extension.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FramePattern {
    dir: PathBuf,
    prefix: String,
    digits: usize,
    suffix: String,
    format: ImageFormat,
}

fn pattern_error(pattern: &Path, reason: &str) -> GpuError {
    GpuError::Io {
        path: pattern.display().to_string(),
        reason: reason.to_string(),
    }
}

impl FramePattern {
    /// Parses `pattern`; the directory need not exist yet ([`FramePattern::prepare`]).
    pub fn parse(pattern: &Path) -> Result<Self, GpuError> {
        let err = |r: &str| pattern_error(pattern, r);
        let name = pattern
            .file_name()
            .and_then(|n| n.to_str())
            .ok_or_else(|| err("not a file name pattern"))?;
        let format = ImageFormat::from_path(pattern)?;
        let Some(at) = name.find('%') else {
            return Err(err("the file name needs a frame number: %d or %04d"));
        };
        let (prefix, rest) = name.split_at(at);
        let rest = &rest[1..];
        let width_len = rest
            .find('d')
            .ok_or_else(|| err("`%` must be followed by d or 0Nd"))?;
        let width = &rest[..width_len];
        let digits = match width {
            "" => 0,
            w if w.starts_with('0') && w.len() > 1 => w[1..]
                .parse::<usize>()
                .ok()
                .filter(|&d| d <= 9)
                .ok_or_else(|| err("the frame number's width must be %01d .. %09d"))?,
            _ => return Err(err("`%` must be followed by d or 0Nd (e.g. %04d)")),
        };
        let suffix = &rest[width_len + 1..];
        if suffix.contains('%') || prefix.contains('%') {
            return Err(err("one frame number only"));
        }
        Ok(Self {
            dir: pattern.parent().map(Path::to_path_buf).unwrap_or_default(),
            prefix: prefix.to_string(),
            digits,
            suffix: suffix.to_string(),
            format,
        })
    }

    /// The file of frame `k`.
    pub fn path(&self, k: u32) -> PathBuf {
        let name = format!("{}{:0w$}{}", self.prefix, k, self.suffix, w = self.digits);
        self.dir.join(name)
    }

    /// Creates the directory and checks it takes files, before anything is rendered.
    pub fn prepare(&self) -> Result<(), GpuError> {
        let dir = if self.dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            &self.dir
        };
        let io = |e: std::io::Error| pattern_error(dir, &format!("cannot write frames: {e}"));
        std::fs::create_dir_all(dir).map_err(io)?;
        let probe = dir.join(format!(".vkrt-probe-{}", std::process::id()));
        std::fs::write(&probe, b"").map_err(io)?;
        std::fs::remove_file(&probe).map_err(io)
    }

    /// Whether frame `k`'s file exists and is a whole `width`×`height` image of this
    /// pattern's format (what `--skip-existing` leaves alone). Writes are atomic, so a file
    /// is either whole or absent unless something else wrote it.
    pub fn complete(&self, k: u32, width: u32, height: u32) -> bool {
        let path = self.path(k);
        match self.format {
            ImageFormat::Pfm => std::fs::read(&path).is_ok_and(|b| pfm_complete(&b, width, height)),
            _ => image::ImageReader::open(&path)
                .and_then(|r| r.with_guessed_format())
                .ok()
                .and_then(|r| r.decode().ok())
                .is_some_and(|img| img.width() == width && img.height() == height),
        }
    }

    /// Whether the frames hold linear radiance (EXR, PFM) rather than 8-bit sRGB.
    pub fn float(&self) -> bool {
        matches!(self.format, ImageFormat::Exr | ImageFormat::Pfm)
    }

    fn encode(&self, width: u32, height: u32, frame: &Frame) -> Result<Vec<u8>, GpuError> {
        let radiance = || {
            frame
                .radiance
                .as_deref()
                .ok_or_else(|| pattern_error(&self.path(frame.k), "no radiance was read back"))
        };
        match self.format {
            ImageFormat::Png => png_bytes(width, height, &frame.rgba),
            ImageFormat::Jpeg => jpeg_bytes(width, height, &frame.rgba),
            ImageFormat::Exr => exr_bytes(width, height, radiance()?),
            ImageFormat::Pfm => Ok(pfm_bytes(width, height, radiance()?)),
        }
    }
}

/// A colour PFM of `width`×`height` with its whole raster.
fn pfm_complete(bytes: &[u8], width: u32, height: u32) -> bool {
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 && at < bytes.len() {
        while at < bytes.len() && bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        let start = at;
        while at < bytes.len() && !bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..at]).into_owned());
        at += 1;
    }
    fields.len() == 4
        && fields[0] == "PF"
        && fields[1] == width.to_string()
        && fields[2] == height.to_string()
        && bytes.len().saturating_sub(at) == width as usize * height as usize * 12
}

/// One finished frame: 8-bit sRGB, and the linear radiance where it was read back.
pub struct Frame {
    /// The frame's number in the animation.
    pub k: u32,
    /// 8-bit sRGB RGBA, row-major from the top-left.
    pub rgba: Vec<u8>,
    /// Mean linear radiance per pixel, where it was read back (EXR and PFM frames).
    pub radiance: Option<Vec<[f32; 3]>>,
}

/// Writes frames on its own thread; [`FrameWriter::finish`] waits for it.
pub struct FrameWriter {
    send: Option<SyncSender<Frame>>,
    thread: Option<JoinHandle<Result<(), GpuError>>>,
    written: std::sync::Arc<std::sync::Mutex<Vec<PathBuf>>>,
}

/// The animated PNG of the frames: its path, the frame rate, the frame count.
pub struct Preview {
    /// Where the animated PNG is written.
    pub path: PathBuf,
    /// Frames per second it plays at.
    pub fps: f32,
    /// Frames it holds.
    pub frames: u32,
}

impl FrameWriter {
    /// A writer of `width`×`height` frames named by `pattern`, and of `preview` if given.
    pub fn new(
        pattern: FramePattern,
        width: u32,
        height: u32,
        preview: Option<Preview>,
    ) -> Result<Self, GpuError> {
        // One frame may wait while the next renders: double buffering.
        let (send, recv) = sync_channel::<Frame>(1);
        let written = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let list = written.clone();
        let thread = std::thread::Builder::new()
            .name("vkrt-frames".into())
            .spawn(move || write_frames(recv, &pattern, (width, height), preview, &list))
            .map_err(|e| pattern_error(Path::new("<frame writer>"), &e.to_string()))?;
        Ok(Self {
            send: Some(send),
            thread: Some(thread),
            written,
        })
    }

    /// Hands frame `k` to the writer; blocks while the previous one is still waiting. An
    /// error is the writer's, which has stopped.
    pub fn write(&mut self, frame: Frame) -> Result<(), GpuError> {
        let sent = self.send.as_ref().map(|s| s.send(frame));
        match sent {
            Some(Ok(())) => Ok(()),
            _ => self.join().and(Err(pattern_error(
                Path::new("<frame writer>"),
                "the frame writer stopped",
            ))),
        }
    }

    /// Waits for every frame to be written.
    pub fn finish(mut self) -> Result<Vec<PathBuf>, GpuError> {
        self.join()?;
        Ok(std::mem::take(
            &mut *self.written.lock().expect("not poisoned"),
        ))
    }

    fn join(&mut self) -> Result<(), GpuError> {
        self.send = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(pattern_error(Path::new("<frame writer>"), "panicked")),
            None => Ok(()),
        }
    }

    /// Removes every file written so far (after an error elsewhere).
    pub fn abandon(mut self) {
        let _ = self.join();
        for p in self.written.lock().expect("not poisoned").drain(..) {
            let _ = std::fs::remove_file(p);
        }
    }
}

impl Drop for FrameWriter {
    fn drop(&mut self) {
        let _ = self.join();
    }
}

fn write_frames(
    recv: Receiver<Frame>,
    pattern: &FramePattern,
    (width, height): (u32, u32),
    preview: Option<Preview>,
    written: &std::sync::Mutex<Vec<PathBuf>>,
) -> Result<(), GpuError> {
    let mut apng = preview
        .as_ref()
        .map(|p| Apng::start(p, width, height))
        .transpose()?;
    let result = (|| {
        for job in recv {
            let path = pattern.path(job.k);
            write_atomically(&path, &pattern.encode(width, height, &job)?)?;
            written.lock().expect("not poisoned").push(path);
            if let Some(a) = apng.as_mut() {
                a.frame(&job.rgba)?;
            }
        }
        if let (Some(a), Some(p)) = (apng.take(), preview.as_ref()) {
            a.finish(&p.path)?;
            written.lock().expect("not poisoned").push(p.path.clone());
        }
        Ok(())
    })();
    if result.is_err() {
        for p in written.lock().expect("not poisoned").drain(..) {
            let _ = std::fs::remove_file(p);
        }
    }
    result
}

/// An animated PNG being encoded into a temporary file beside its path, renamed into place
/// when finished (removed on an error).
struct Apng {
    writer: Option<png::Writer<std::io::BufWriter<std::fs::File>>>,
    tmp: PathBuf,
}

fn apng_error(e: png::EncodingError) -> GpuError {
    pattern_error(Path::new("<animated png>"), &e.to_string())
}

impl Apng {
    fn start(p: &Preview, width: u32, height: u32) -> Result<Self, GpuError> {
        let name = p.path.file_name().unwrap_or_default().to_string_lossy();
        let tmp = p
            .path
            .with_file_name(format!(".{name}.tmp{}", std::process::id()));
        let file = std::fs::File::create(&tmp)
            .map_err(|e| pattern_error(&p.path, &format!("cannot write: {e}")))?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width, height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        let started = (|| {
            enc.set_animated(p.frames, 0)?;
            // Each frame shows for 1/fps s: 100 / (100·fps), within u16.
            let den = (p.fps * 100.0).round().clamp(1.0, 65535.0) as u16;
            enc.set_frame_delay(100, den)?;
            enc.write_header()
        })();
        match started {
            Ok(writer) => Ok(Self {
                writer: Some(writer),
                tmp,
            }),
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                Err(apng_error(e))
            }
        }
    }

    fn frame(&mut self, rgba: &[u8]) -> Result<(), GpuError> {
        let w = self.writer.as_mut().expect("started");
        w.write_image_data(rgba).map_err(apng_error)
    }

    fn finish(mut self, path: &Path) -> Result<(), GpuError> {
        let tmp = self.tmp.clone();
        let done = self
            .writer
            .take()
            .expect("started")
            .finish()
            .map_err(apng_error)
            .and_then(|()| {
                std::fs::rename(&tmp, path).map_err(|e| pattern_error(path, &e.to_string()))
            });
        if done.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        done
    }
}

impl Drop for Apng {
    fn drop(&mut self) {
        // Unfinished (an error stopped the frames): no partial file.
        let _ = std::fs::remove_file(&self.tmp);
    }
}

/// One frame's numbers.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FrameRow {
    /// The frame's number in the animation.
    pub frame: u32,
    /// Seconds from the animation's start.
    pub time: f32,
    /// Whether the frame built its structure (else it refit it).
    pub built: bool,
    /// GPU ms of the build or refit (a host builder's wall ms).
    pub update_ms: f64,
    /// GPU ms of the samples and the tone map.
    pub render_ms: f64,
    /// Rays traced (primary, secondary, shadow, ambient occlusion).
    pub rays: u64,
    /// Wall ms of the frame on the host: flattening, recording, the submission, handing the
    /// image to the writer.
    pub wall_ms: f64,
    /// Records made again (a wave overflowed, a kd-tree outgrew its budget).
    pub redone: u32,
    /// Queue submissions vkrt made for the frame (1 unless a record was redone), and the
    /// bytes it read back (the image) and uploaded (moved primitives): `Context::traffic`.
    pub submits: u64,
    /// Bytes read back for the frame.
    pub readback_bytes: u64,
    /// Bytes uploaded for the frame.
    pub upload_bytes: u64,
    /// After the frame: device memory held through vkrt's allocator, and the process's
    /// resident host memory (Linux; absent elsewhere). Flat over a long run: nothing leaks.
    pub device_bytes: u64,
    /// Live allocations through vkrt's allocator after the frame.
    pub device_allocations: u64,
    /// Resident host memory after the frame ([`host_rss_bytes`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub host_rss_bytes: Option<u64>,
    /// The SAH cost of the frame's structure, and of a structure of the same kind built anew
    /// over the frame (BVHs, with `quality`: a read-back outside the timed frame).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sah_cost: Option<f64>,
    /// The SAH cost of a structure of the same kind built anew over the frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rebuilt_sah_cost: Option<f64>,
}

/// What the frames of one animation cost.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AnimationReport {
    /// The structure and its walk (`kdtree`, `sah-bvh/stack`, ...).
    pub accel: String,
    /// 2: traced as two levels (each frame updates the top level only), 1: flat.
    pub levels: u32,
    /// How the structure followed the primitives from frame to frame.
    pub update: Update,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel, as planned.
    pub spp: u32,
    /// Each rendered frame's numbers, in order.
    pub frames: Vec<FrameRow>,
    /// Frames left alone because their files were already complete (`--skip-existing`).
    pub skipped: Vec<u32>,
}

impl AnimationReport {
    fn mean(&self, f: impl Fn(&FrameRow) -> f64) -> f64 {
        self.frames.iter().map(f).sum::<f64>() / self.frames.len().max(1) as f64
    }

    /// Mean build or refit ms over the frames after the first (which always builds).
    pub fn mean_update_ms(&self) -> f64 {
        let later: Vec<&FrameRow> = self.frames.iter().skip(1).collect();
        match later.len() {
            0 => self.frames.first().map_or(0.0, |f| f.update_ms),
            n => later.iter().map(|f| f.update_ms).sum::<f64>() / n as f64,
        }
    }

    /// Mean GPU ms per frame of the samples and the tone map.
    pub fn mean_render_ms(&self) -> f64 {
        self.mean(|f| f.render_ms)
    }

    /// Frames per second of wall time.
    pub fn fps(&self) -> f64 {
        1e3 / self.mean(|f| f.wall_ms).max(1e-9)
    }

    /// Submissions, bytes read back and bytes uploaded over every frame.
    pub fn traffic_totals(&self) -> (u64, u64, u64) {
        self.frames.iter().fold((0, 0, 0), |(s, r, u), f| {
            (s + f.submits, r + f.readback_bytes, u + f.upload_bytes)
        })
    }

    /// Rays per second over the frames' GPU render time, in millions.
    pub fn mrays_per_s(&self) -> f64 {
        let rays: u64 = self.frames.iter().map(|f| f.rays).sum();
        let ms: f64 = self.frames.iter().map(|f| f.render_ms).sum();
        rays as f64 / (ms.max(1e-9) * 1e3)
    }
}

pub use crate::host::host_rss_bytes;

/// Growth of a per-frame quantity from frame `from` to the last frame, relative to its value
/// at `from` (`None` with fewer frames or no values): the soak measure.
pub fn growth(
    frames: &[FrameRow],
    from: usize,
    value: impl Fn(&FrameRow) -> Option<u64>,
) -> Option<f64> {
    let first = value(frames.get(from)?)? as f64;
    let last = value(frames.last()?)? as f64;
    (first > 0.0).then(|| (last - first) / first)
}

/// How to render an animation.
#[derive(Clone, Debug)]
pub struct AnimateOptions {
    /// Image size, samples and structure, as for a still render.
    pub render: RenderOptions,
    /// How the structure follows the primitives from frame to frame.
    pub update: Update,
    /// The frames to render, by their number in the animation, in increasing order.
    pub frames: Vec<u32>,
    /// Also read back each frame's linear radiance (for EXR and PFM frames).
    pub radiance: bool,
    /// Also the SAH cost of every frame's structure and of one built anew (BVHs only; a
    /// read-back after each frame, outside its timing).
    pub quality: bool,
}

/// Renders frames `opt.frames` of the scenes `frame_scene(k)` gives (the same primitives,
/// moved), one submission each, handing each [`Frame`] to `sink` (a [`FrameWriter`], or
/// nothing) while the next renders. `progress(done)` after each frame.
///
/// Any split of an animation into ranges gives the same frames: a rebuilt frame's tree
/// depends on that frame alone, and a refit frame's tree is always frame 0's refit to it
/// (a run whose first frame is past frame 0 first builds over frame 0, one submission
/// more).
pub fn run(
    ctx: &Context,
    frame_scene: impl Fn(u32) -> (f32, Scene),
    opt: &AnimateOptions,
    trace: &TraceOptions,
    mut sink: impl FnMut(Frame) -> Result<(), GpuError>,
    mut progress: impl FnMut(u32),
) -> Result<AnimationReport, Box<dyn std::error::Error + Send + Sync>> {
    let (_, first) = frame_scene(0);
    let plan = Plan::new(&first, &opt.render.for_device(ctx))?;
    if plan.levels != 2 {
        crate::accel::primitives::TraceGeometry::check_flat_fits(ctx, &first)?;
    }
    let accel = opt.render.accel;
    let renderer = Renderer::new(ctx, &plan, trace)?;
    let mut frames =
        FrameLoop::new(ctx, &renderer, &plan, accel, opt.update)?.with_radiance(opt.radiance);
    // One scene moved from frame to frame (over two levels only its instances change).
    let mut rs: Option<RenderScene> = None;
    if opt.update == Update::Refit && opt.frames.first().is_some_and(|&k| k > 0) {
        let r = RenderScene::on_device(&first, &plan);
        frames.prepare(ctx, &r, &plan)?;
        rs = Some(r);
    }
    let mut rows = Vec::with_capacity(opt.frames.len());
    for (done, &k) in opt.frames.iter().enumerate() {
        let start = std::time::Instant::now();
        let traffic = ctx.traffic();
        let (time, scene) = if k == 0 {
            (0.0, first.clone())
        } else {
            frame_scene(k)
        };
        let rs = match &mut rs {
            Some(r) if r.levels.is_some() => {
                r.move_to(&scene, &plan);
                &*r
            }
            _ => {
                rs = None; // (the last frame's flat scene goes before the next is made)
                rs.insert(RenderScene::on_device(&scene, &plan))
            }
        };
        let image = frames.render(ctx, rs, &plan)?;
        sink(Frame {
            k,
            rgba: image.rgba,
            radiance: image.radiance,
        })?;
        let wall_ms = start.elapsed().as_secs_f64() * 1e3;
        let traffic = ctx.traffic() - traffic;
        let memory = ctx.memory();
        let (sah_cost, rebuilt_sah_cost) = match opt.quality {
            true => frame_quality(&frames, rs, accel.kind)?,
            false => (None, None),
        };
        rows.push(FrameRow {
            frame: k,
            time,
            built: image.built,
            update_ms: image.update_ms,
            render_ms: image.render_ms,
            rays: image.counts.total(),
            wall_ms,
            redone: image.redone,
            submits: traffic.submits,
            readback_bytes: traffic.readback_bytes,
            upload_bytes: traffic.upload_bytes,
            device_bytes: memory.allocated_bytes,
            device_allocations: memory.allocations,
            host_rss_bytes: host_rss_bytes(),
            sah_cost,
            rebuilt_sah_cost,
        });
        progress(done as u32 + 1);
    }
    Ok(AnimationReport {
        accel: accel.label(),
        levels: plan.levels,
        update: opt.update,
        width: plan.width,
        height: plan.height,
        spp: plan.spp,
        frames: rows,
        skipped: Vec::new(),
    })
}

/// The SAH cost of the loop's BVH as it is now, and of the same kind built anew over the
/// frame's boxes on the host (the GPU builders' twins build the same trees).
fn frame_quality(
    frames: &FrameLoop,
    rs: &RenderScene,
    kind: AccelKind,
) -> Result<(Option<f64>, Option<f64>), GpuError> {
    use crate::accel::bvh::{self, validate::sah_cost};
    if matches!(kind, AccelKind::KdTree | AccelKind::Driver) {
        return Ok((None, None));
    }
    let Some(HostStructure::Bvh(now)) = frames.download()? else {
        return Ok((None, None));
    };
    let params = bvh::BvhParams::default();
    let twin = crate::accel::host::host_twin(kind, &rs.geometry, &Default::default())?;
    let HostStructure::Bvh(fresh) = twin else {
        return Ok((None, None));
    };
    Ok((
        Some(sah_cost(&now, &params)),
        Some(sah_cost(&fresh, &params)),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_name_frames_or_say_why_not() {
        let p = FramePattern::parse(Path::new("out/frame_%04d.png")).unwrap();
        assert_eq!(p.path(7), Path::new("out/frame_0007.png"));
        assert_eq!(p.path(12345), Path::new("out/frame_12345.png"));
        let p = FramePattern::parse(Path::new("f%d-x.JPG")).unwrap();
        assert_eq!(p.path(3), Path::new("f3-x.JPG"));
        for (bad, why) in [
            ("out/frame.png", "frame number"),
            ("out/frame_%04d.bmp", "unsupported"),
            ("out/frame_%4d.png", "0Nd"),
            ("out/frame_%s.png", "followed by d"),
            ("out/f%d_%d.png", "one frame number"),
            ("out/frame_%012d.png", "width"),
        ] {
            let e = FramePattern::parse(Path::new(bad)).unwrap_err().to_string();
            assert!(e.contains(why) && e.contains(bad), "{bad}: {e}");
        }
        for float in ["out/frame_%04d.exr", "out/f_%d.PFM"] {
            assert!(
                FramePattern::parse(Path::new(float)).unwrap().float(),
                "{float}"
            );
        }
        assert!(!FramePattern::parse(Path::new("out/f_%d.jpg"))
            .unwrap()
            .float());
    }
}
