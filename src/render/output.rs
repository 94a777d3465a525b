//! Output files: PNG/BMP images, the original's `.meta` file, animated GIFs. Each is written
//! atomically ([`crate::files::AtomicFile`]): a failed write never replaces a good file.

use std::path::Path;

use crate::files::AtomicFile;

use image::RgbaImage;

use super::RenderError;
use super::view::BirdseyeView;

pub(super) fn write_error(path: &Path, e: impl std::fmt::Display) -> RenderError {
    RenderError::Write { path: path.to_path_buf(), message: e.to_string() }
}

/// Write an image; the extension picks the format: `.png` (RGBA) or `.bmp` (24-bit RGB, the
/// original's bitmap format).
/// Parent folders are created; the file is replaced only once the new one is complete.
pub fn write_image(path: &Path, image: &RgbaImage) -> Result<(), RenderError> {
    image_aside(path, image)?.commit().map_err(|e| write_error(path, e))
}

/// Write `image` beside `path` under a temporary name (format from the extension, see
/// [`write_image`]); committing the returned file puts it in place.
fn image_aside(path: &Path, image: &RgbaImage) -> Result<AtomicFile, RenderError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let format = match ext.as_deref() {
        Some("png") => image::ImageFormat::Png,
        Some("bmp") => image::ImageFormat::Bmp,
        _ => return Err(write_error(path, "unknown image format: use a .png or .bmp file name")),
    };
    let file = AtomicFile::new(path).map_err(|e| write_error(path, e))?;
    let saved = if format == image::ImageFormat::Bmp {
        image::DynamicImage::ImageRgba8(image.clone()).to_rgb8().save_with_format(file.path(), format)
    } else {
        image.save_with_format(file.path(), format)
    };
    saved.map_err(|e| write_error(path, e))?;
    Ok(file)
}

/// The `.meta` path beside an image: the image's extension replaced by `meta`.
fn meta_path(image_path: &Path) -> std::path::PathBuf {
    image_path.with_extension("meta")
}

/// Write the original's metadata file beside an image: `FILE.meta` (the image's extension
/// replaced) containing `image_width=W;image_height=H;pixel_per_meter=P`, no trailing newline.
pub fn write_meta(image_path: &Path, view: &BirdseyeView) -> Result<std::path::PathBuf, RenderError> {
    let meta = meta_path(image_path);
    crate::files::write_atomic(&meta, view.meta().as_bytes()).map_err(|e| write_error(&meta, e))?;
    Ok(meta)
}

/// Write an image and its `.meta` ([`write_image`], [`write_meta`]) as a pair: both are written
/// aside first, so when either cannot be written neither earlier file is replaced (the `.meta`
/// goes into place first: a `.meta` that cannot be renamed leaves the earlier image too).
/// Returns the `.meta` path.
pub fn write_image_with_meta(
    path: &Path,
    image: &RgbaImage,
    view: &BirdseyeView,
) -> Result<std::path::PathBuf, RenderError> {
    let image_file = image_aside(path, image)?;
    let meta = meta_path(path);
    let meta_file = AtomicFile::new(&meta).map_err(|e| write_error(&meta, e))?;
    std::fs::write(meta_file.path(), view.meta()).map_err(|e| write_error(&meta, e))?;
    meta_file.commit().map_err(|e| write_error(&meta, e))?;
    image_file.commit().map_err(|e| write_error(path, e))?;
    Ok(meta)
}

/// Path of numbered frame `index` in `dir`: `DIR/frame_000042.png` (six digits, so file names sort
/// in frame order).
pub fn frame_path(dir: &Path, index: u64) -> std::path::PathBuf {
    dir.join(format!("frame_{index:06}.png"))
}

/// Write frames as an animated GIF that loops forever, shown at `frame_rate` [Hz].
pub fn write_gif(path: &Path, frames: &[RgbaImage], frame_rate: f64) -> Result<(), RenderError> {
    let (w, h) = frames.first().map_or((1, 1), RgbaImage::dimensions);
    let mut gif = GifWriter::create(path, w, h, frame_rate)?;
    for f in frames {
        gif.push(f.clone())?;
    }
    gif.finish()
}

/// An animated GIF written frame by frame, under a temporary name until [`GifWriter::finish`]
/// renames it into place (dropped unfinished, the temporary file is removed and an earlier GIF
/// of the same name stays). Each frame after the first stores only what changed
/// since the previous one (the bounding box of the changed pixels, unchanged pixels transparent,
/// `Keep` disposal), so a static ground costs nothing after the first frame: GIFs of a run are
/// tens of times smaller and faster to write than with full frames.
pub struct GifWriter {
    path: std::path::PathBuf,
    file: AtomicFile,
    encoder: gif::Encoder<std::io::BufWriter<std::fs::File>>,
    previous: Option<RgbaImage>,
    /// Frame delay [1/100 s].
    delay: u16,
}

impl GifWriter {
    /// Create `path` for frames of `width` x `height` px shown at `frame_rate` [Hz], looping forever.
    pub fn create(path: &Path, width: u32, height: u32, frame_rate: f64) -> Result<GifWriter, RenderError> {
        if !(frame_rate.is_finite() && frame_rate > 0.0) {
            return Err(write_error(path, format!("frame rate {frame_rate} Hz must be finite and > 0")));
        }
        let side = |px: u32| {
            u16::try_from(px).map_err(|_| write_error(path, format!("{px} px is too large for a GIF (at most 65535)")))
        };
        let (w, h) = (side(width)?, side(height)?);
        let file = AtomicFile::new(path).map_err(|e| write_error(path, e))?;
        let out = std::fs::File::create(file.path()).map_err(|e| write_error(path, e))?;
        let mut encoder =
            gif::Encoder::new(std::io::BufWriter::new(out), w, h, &[]).map_err(|e| write_error(path, e))?;
        encoder.set_repeat(gif::Repeat::Infinite).map_err(|e| write_error(path, e))?;
        // GIF delays are in hundredths of a second; 2 is the shortest most viewers honour.
        let delay = (100.0 / frame_rate).round().clamp(2.0, f64::from(u16::MAX)) as u16;
        Ok(GifWriter { path: path.to_path_buf(), file, encoder, previous: None, delay })
    }

    /// Append a frame (of the size given to [`GifWriter::create`]).
    pub fn push(&mut self, image: RgbaImage) -> Result<(), RenderError> {
        let frame = delta_frame(self.previous.as_ref(), &image, self.delay);
        self.encoder.write_frame(&frame).map_err(|e| write_error(&self.path, e))?;
        self.previous = Some(image);
        Ok(())
    }

    /// End the GIF (its trailer written, the file flushed) and rename it into place.
    pub fn finish(self) -> Result<(), RenderError> {
        let GifWriter { path, file, encoder, .. } = self;
        let out = encoder.into_inner().map_err(|e| write_error(&path, e))?;
        out.into_inner().map_err(|e| write_error(&path, e.error().to_string()))?;
        file.commit().map_err(|e| write_error(&path, e))
    }
}

/// A GIF frame holding only what changed since `prev` (the whole image when there is none).
fn delta_frame(prev: Option<&RgbaImage>, next: &RgbaImage, delay: u16) -> gif::Frame<'static> {
    let (w, h) = next.dimensions();
    let (mut x0, mut y0, mut x1, mut y1) = (0, 0, w - 1, h - 1);
    if let Some(prev) = prev {
        (x0, y0, x1, y1) = (w, h, 0, 0);
        for (x, y, p) in next.enumerate_pixels() {
            if prev.get_pixel(x, y) != p {
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
            }
        }
        if x0 > x1 {
            // Nothing changed: one transparent pixel keeps the frame's place in time.
            (x0, y0, x1, y1) = (0, 0, 0, 0);
        }
    }
    let mut sub: Vec<u8> = Vec::with_capacity(((x1 - x0 + 1) * (y1 - y0 + 1) * 4) as usize);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = next.get_pixel(x, y);
            let same = prev.is_some_and(|prev| prev.get_pixel(x, y) == p);
            sub.extend_from_slice(if same { &[0, 0, 0, 0] } else { &p.0 });
        }
    }
    // Speed 10 of 1..30: good colours at a tolerable encoding time.
    let mut frame = gif::Frame::from_rgba_speed((x1 - x0 + 1) as u16, (y1 - y0 + 1) as u16, &mut sub, 10);
    frame.left = x0 as u16;
    frame.top = y0 as u16;
    frame.delay = delay;
    frame.dispose = gif::DisposalMethod::Keep;
    frame
}
