//! Output files: PNG/BMP images, the original's `.meta` file, animated GIFs.

use std::path::Path;

use image::RgbaImage;

use super::RenderError;
use super::view::BirdseyeView;

fn write_error(path: &Path, e: impl std::fmt::Display) -> RenderError {
    RenderError::Write { path: path.to_path_buf(), message: e.to_string() }
}

/// Write an image; the extension picks the format: `.png` (RGBA) or `.bmp` (24-bit RGB, the
/// original's bitmap format).
pub fn write_image(path: &Path, image: &RgbaImage) -> Result<(), RenderError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("png") => image.save_with_format(path, image::ImageFormat::Png).map_err(|e| write_error(path, e)),
        Some("bmp") => image::DynamicImage::ImageRgba8(image.clone())
            .to_rgb8()
            .save_with_format(path, image::ImageFormat::Bmp)
            .map_err(|e| write_error(path, e)),
        _ => Err(write_error(path, "unknown image format: use a .png or .bmp file name")),
    }
}

/// Write the original's metadata file beside an image: `FILE.meta` (the image's extension
/// replaced) containing `image_width=W;image_height=H;pixel_per_meter=P`, no trailing newline.
pub fn write_meta(image_path: &Path, view: &BirdseyeView) -> Result<std::path::PathBuf, RenderError> {
    let meta = image_path.with_extension("meta");
    std::fs::write(&meta, view.meta()).map_err(|e| write_error(&meta, e))?;
    Ok(meta)
}

/// Path of numbered frame `index` in `dir`: `DIR/frame_000042.png` (six digits, so file names sort
/// in frame order).
pub fn frame_path(dir: &Path, index: u64) -> std::path::PathBuf {
    dir.join(format!("frame_{index:06}.png"))
}

/// Write frames as an animated GIF that loops forever, shown at `frame_rate` [Hz].
pub fn write_gif(path: &Path, frames: &[RgbaImage], frame_rate: f64) -> Result<(), RenderError> {
    if !(frame_rate.is_finite() && frame_rate > 0.0) {
        return Err(write_error(path, format!("frame rate {frame_rate} Hz must be finite and > 0")));
    }
    let file = std::fs::File::create(path).map_err(|e| write_error(path, e))?;
    // Speed 10 of 1..30: good colours at a tolerable encoding time for 1080p frames.
    let mut encoder = image::codecs::gif::GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
    encoder.set_repeat(image::codecs::gif::Repeat::Infinite).map_err(|e| write_error(path, e))?;
    // GIF delays are in hundredths of a second.
    let delay = image::Delay::from_numer_denom_ms((1000.0 / frame_rate).round().max(10.0) as u32, 1);
    for f in frames {
        encoder.encode_frame(image::Frame::from_parts(f.clone(), 0, 0, delay)).map_err(|e| write_error(path, e))?;
    }
    Ok(())
}
