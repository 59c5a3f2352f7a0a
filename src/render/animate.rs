//! What `vkrt animate` writes: frame files named by a printf-style pattern
//! (`out/frame_%04d.png`), encoded and written on a thread of their own while the device
//! renders the next frame (double-buffered: at most one finished frame waits), and an
//! animated PNG of every frame for a quick look. Each file is written atomically; on any
//! error the files this run wrote are removed, so a failed animation leaves no partial set.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::JoinHandle;

use super::output::{jpeg_bytes, png_bytes, ImageFormat};
use crate::gpu::{write_atomically, GpuError};

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
        if !matches!(format, ImageFormat::Png | ImageFormat::Jpeg) {
            return Err(err("frames are 8-bit images: use .png or .jpg"));
        }
        let Some(at) = name.find('%') else {
            return Err(err("the file name needs a frame number: %d or %04d"));
        };
        let (prefix, rest) = name.split_at(at);
        let rest = &rest[1..];
        let width_len = rest.find('d').ok_or_else(|| err("`%` must be followed by d or 0Nd"))?;
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

    fn encode(&self, width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, GpuError> {
        match self.format {
            ImageFormat::Jpeg => jpeg_bytes(width, height, rgba),
            _ => png_bytes(width, height, rgba),
        }
    }
}

/// One finished frame for the writer.
struct Job {
    k: u32,
    rgba: Vec<u8>,
}

/// Writes frames on its own thread; [`FrameWriter::finish`] waits for it.
pub struct FrameWriter {
    send: Option<SyncSender<Job>>,
    thread: Option<JoinHandle<Result<(), GpuError>>>,
    written: std::sync::Arc<std::sync::Mutex<Vec<PathBuf>>>,
}

/// The animated PNG of the frames: its path, the frame rate, the frame count.
pub struct Preview {
    pub path: PathBuf,
    pub fps: f32,
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
        let (send, recv) = sync_channel::<Job>(1);
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
    pub fn write(&mut self, k: u32, rgba: Vec<u8>) -> Result<(), GpuError> {
        let sent = self.send.as_ref().map(|s| s.send(Job { k, rgba }));
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
        Ok(std::mem::take(&mut *self.written.lock().expect("not poisoned")))
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
    recv: Receiver<Job>,
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
            write_atomically(&path, &pattern.encode(width, height, &job.rgba)?)?;
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
            ("out/frame_%04d.exr", "8-bit"),
            ("out/frame_%04d.bmp", "unsupported"),
            ("out/frame_%4d.png", "0Nd"),
            ("out/frame_%s.png", "followed by d"),
            ("out/f%d_%d.png", "one frame number"),
            ("out/frame_%012d.png", "width"),
        ] {
            let e = FramePattern::parse(Path::new(bad)).unwrap_err().to_string();
            assert!(e.contains(why) && e.contains(bad), "{bad}: {e}");
        }
    }
}
