//! Writing images, the format chosen by the file's extension: 8-bit sRGB PNG and JPEG, and
//! linear float radiance as OpenEXR or PFM (for reference comparisons). Every file is
//! encoded in memory, then written through a temporary file and a rename, so a failed write
//! leaves no partial file.

use std::io::Cursor;
use std::path::Path;

use crate::gpu::{write_atomically, GpuError};

/// `tonemap.comp`: linear radiance to an 8-bit sRGB channel.
pub fn srgb8(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5).floor() as u8
}

/// The extensions [`ImageFormat::from_path`] accepts, for error messages and help.
pub const SUPPORTED_EXTENSIONS: &str = ".png, .jpg, .jpeg, .exr, .pfm";

/// JPEG quality: visually lossless for renders, a fraction of the PNG's size.
const JPEG_QUALITY: u8 = 92;

/// An image file format, chosen by extension (case-insensitive).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// 8-bit sRGB, lossless.
    Png,
    /// 8-bit sRGB, lossy.
    Jpeg,
    /// Linear float radiance (RGB f32), OpenEXR.
    Exr,
    /// Linear float radiance (RGB f32), portable float map.
    Pfm,
}

impl ImageFormat {
    /// The format `path`'s extension names; an unknown or missing extension is an error
    /// listing the supported ones (never a silent fallback to another format).
    pub fn from_path(path: &Path) -> Result<Self, GpuError> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_deref() {
            Some("png") => Ok(Self::Png),
            Some("jpg" | "jpeg") => Ok(Self::Jpeg),
            Some("exr") => Ok(Self::Exr),
            Some("pfm") => Ok(Self::Pfm),
            other => Err(GpuError::Io {
                path: path.display().to_string(),
                reason: format!(
                    "{} (supported: {SUPPORTED_EXTENSIONS})",
                    match other {
                        Some(e) => format!("unsupported image extension `.{e}`"),
                        None => "no image extension".into(),
                    }
                ),
            }),
        }
    }
}

/// An `image` encoder's error as a write error of `what`.
fn encode_error(what: &str, e: image::ImageError) -> GpuError {
    GpuError::Io {
        path: format!("<{what}>"),
        reason: e.to_string(),
    }
}

/// Encodes RGBA8 pixels as PNG bytes.
pub fn png_bytes(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, GpuError> {
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut out);
    image::ImageEncoder::write_image(enc, rgba, width, height, image::ExtendedColorType::Rgba8)
        .map_err(|e| encode_error("png", e))?;
    Ok(out)
}

/// Encodes RGBA8 pixels as JPEG bytes (alpha dropped: JPEG has none).
pub fn jpeg_bytes(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, GpuError> {
    let rgb: Vec<u8> = rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    let mut out = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, JPEG_QUALITY);
    image::ImageEncoder::write_image(enc, &rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| encode_error("jpeg", e))?;
    Ok(out)
}

/// OpenEXR bytes of linear RGB (f32, top row first, lossless).
pub fn exr_bytes(width: u32, height: u32, rgb: &[[f32; 3]]) -> Result<Vec<u8>, GpuError> {
    let mut out = Cursor::new(Vec::new());
    let enc = image::codecs::openexr::OpenExrEncoder::new(&mut out);
    image::ImageEncoder::write_image(
        enc,
        bytemuck::cast_slice(rgb),
        width,
        height,
        image::ExtendedColorType::Rgb32F,
    )
    .map_err(|e| encode_error("exr", e))?;
    Ok(out.into_inner())
}

/// PFM (little-endian, bottom row first) bytes of linear RGB.
pub fn pfm_bytes(width: u32, height: u32, rgb: &[[f32; 3]]) -> Vec<u8> {
    let mut out = format!("PF\n{width} {height}\n-1.0\n").into_bytes();
    for row in (0..height as usize).rev() {
        for px in &rgb[row * width as usize..(row + 1) * width as usize] {
            for c in px {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    out
}

/// Writes the image to `path` in the format its extension names ([`ImageFormat`]): the
/// 8-bit formats from `rgba`, the float ones from the linear `rgb`.
pub fn write_image(
    path: &Path,
    width: u32,
    height: u32,
    rgba: &[u8],
    rgb: &[[f32; 3]],
) -> Result<(), GpuError> {
    let bytes = match ImageFormat::from_path(path)? {
        ImageFormat::Png => png_bytes(width, height, rgba)?,
        ImageFormat::Jpeg => jpeg_bytes(width, height, rgba)?,
        ImageFormat::Exr => exr_bytes(width, height, rgb)?,
        ImageFormat::Pfm => pfm_bytes(width, height, rgb),
    };
    write_atomically(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_by_extension_ignoring_case() {
        let f = |p: &str| ImageFormat::from_path(Path::new(p));
        assert_eq!(f("a.png").unwrap(), ImageFormat::Png);
        assert_eq!(f("dir/a.JPG").unwrap(), ImageFormat::Jpeg);
        assert_eq!(f("a.jpeg").unwrap(), ImageFormat::Jpeg);
        assert_eq!(f("a.Exr").unwrap(), ImageFormat::Exr);
        assert_eq!(f("a.PFM").unwrap(), ImageFormat::Pfm);
        for bad in ["a.bmp", "a", "a.png.tmp"] {
            let e = f(bad).unwrap_err().to_string();
            assert!(e.contains(SUPPORTED_EXTENSIONS) && e.contains(bad), "{e}");
        }
    }

    #[test]
    fn exr_holds_the_linear_floats() {
        let rgb: Vec<[f32; 3]> = (0..6).map(|i| [i as f32 * 0.25, 1e-7, 3.5e4]).collect();
        let bytes = exr_bytes(3, 2, &rgb).unwrap();
        let img = image::load_from_memory(&bytes).unwrap().into_rgb32f();
        assert_eq!((img.width(), img.height()), (3, 2));
        let back: Vec<[f32; 3]> = img.pixels().map(|p| p.0).collect();
        assert_eq!(back, rgb);
    }
}
