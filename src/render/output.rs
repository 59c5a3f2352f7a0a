//! Writing images: 8-bit sRGB PNG (the `image` crate) and 32-bit float PFM (linear
//! radiance, for reference comparisons). Both are written through a temporary file and a
//! rename, so a failed write leaves no partial file.

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

/// Encodes RGBA8 pixels as PNG bytes.
pub fn png_bytes(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, GpuError> {
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut out);
    image::ImageEncoder::write_image(enc, rgba, width, height, image::ExtendedColorType::Rgba8)
        .map_err(|e| GpuError::Io {
            path: "<png>".into(),
            reason: e.to_string(),
        })?;
    Ok(out)
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

/// Writes the image to `path`: PFM for a `.pfm` extension, PNG otherwise.
pub fn write_image(
    path: &Path,
    width: u32,
    height: u32,
    rgba: &[u8],
    rgb: &[[f32; 3]],
) -> Result<(), GpuError> {
    let pfm = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("pfm"));
    let bytes = if pfm {
        pfm_bytes(width, height, rgb)
    } else {
        png_bytes(width, height, rgba)?
    };
    write_atomically(path, &bytes)
}
