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

/// Write frames as an animated GIF that loops forever, shown at `frame_rate` \[Hz\].
pub fn write_gif(path: &Path, frames: &[RgbaImage], frame_rate: f64) -> Result<(), RenderError> {
    let (w, h) = frames.first().map_or((1, 1), RgbaImage::dimensions);
    let mut gif = GifWriter::create(path, w, h, frame_rate)?;
    for f in frames {
        gif.push(f.clone())?;
    }
    gif.finish().map(|_| ())
}

/// An animated GIF written frame by frame, under a temporary name until [`GifWriter::finish`]
/// renames it into place (dropped unfinished, the temporary file is removed and an earlier GIF
/// of the same name stays).
///
/// One palette serves every frame (the GIF's global colour table, learnt from the first frame
/// plus the colours vehicles, rings, signals and the overlay are drawn in), and each pixel's
/// colour always maps to the same entry. Each frame after the first stores only the pixels
/// whose palette entry changed (the bounding box of the changes, unchanged pixels transparent,
/// `Keep` disposal), so a static ground costs nothing after the first frame, and what a viewer
/// shows is always the frame's own colours: with a palette per frame, a pixel a label had
/// passed over came back in the next frame's palette, not the ground's, and left grey trails
/// (issue 61), and a small legend swatch could take a neighbouring grey.
pub struct GifWriter {
    path: std::path::PathBuf,
    file: AtomicFile,
    /// The file until the first frame has given the palette.
    out: Option<std::io::BufWriter<std::fs::File>>,
    encoder: Option<gif::Encoder<std::io::BufWriter<std::fs::File>>>,
    size: (u16, u16),
    palette: Option<GifPalette>,
    /// The previous frame as pushed (to skip the palette lookup of unchanged pixels).
    previous: Option<RgbaImage>,
    /// Palette index of every pixel the viewer shows now.
    shown: Vec<u8>,
    /// Frame delay [1/100 s].
    delay: u16,
}

/// Palette index that stands for "unchanged" (transparent) in delta frames.
const TRANSPARENT: u8 = 255;

/// Colours the frames draw that a first frame may lack (vehicle classes, id labels, rings,
/// signals, indicator, overlay text and box), learnt into the palette with the first frame.
fn drawn_colours() -> Vec<[u8; 4]> {
    let mut colours = vec![
        [255, 255, 255, 255],
        [0, 0, 0, 255],
        [245, 245, 245, 255],
        [235, 20, 20, 255],
        super::SIGNAL_GREEN,
        super::SIGNAL_YELLOW,
        super::SIGNAL_RED,
        [255, 176, 0, 255],
    ];
    for class in ["Car", "Truck", "Bus", "Bicycle", "Emergency", "Tractor", "Pedestrian", "Van"] {
        colours.push(super::class_color(class));
    }
    colours.extend((0..12).map(super::vehicle_color));
    colours
}

/// The one palette of a GIF and the index of each colour seen so far.
struct GifPalette {
    quant: color_quant::NeuQuant,
    /// RGBA (as one `u32`) to palette index; a `HashMap` because only lookups are made.
    index: std::collections::HashMap<u32, u8>,
}

impl GifPalette {
    /// 255 colours learnt from `first` and [`drawn_colours`] (index 255 is [`TRANSPARENT`]).
    fn learn(first: &RgbaImage) -> GifPalette {
        let mut pixels: Vec<u8> = first.as_raw().clone();
        // Each drawn colour as a block big enough for the network to give it an entry.
        let block = (first.as_raw().len() / 4 / 200).max(64);
        for c in drawn_colours() {
            for _ in 0..block {
                pixels.extend_from_slice(&c);
            }
        }
        for p in pixels.chunks_exact_mut(4) {
            p[3] = 255;
        }
        GifPalette { quant: color_quant::NeuQuant::new(10, 255, &pixels), index: std::collections::HashMap::new() }
    }

    /// The global colour table: 256 RGB entries (the last one, transparent, black).
    fn table(&self) -> Vec<u8> {
        let mut rgb = self.quant.color_map_rgb();
        rgb.resize(256 * 3, 0);
        rgb
    }

    fn index_of(&mut self, p: [u8; 4]) -> u8 {
        let key = u32::from_le_bytes([p[0], p[1], p[2], 255]);
        let quant = &self.quant;
        *self.index.entry(key).or_insert_with(|| quant.index_of(&[p[0], p[1], p[2], 255]).min(254) as u8)
    }
}

impl GifWriter {
    /// Create `path` for frames of `width` x `height` px shown at `frame_rate` \[Hz\], looping forever.
    pub fn create(path: &Path, width: u32, height: u32, frame_rate: f64) -> Result<GifWriter, RenderError> {
        if !(frame_rate.is_finite() && frame_rate > 0.0) {
            return Err(write_error(path, format!("frame rate {frame_rate} Hz must be finite and > 0")));
        }
        let side = |px: u32| {
            u16::try_from(px).map_err(|_| write_error(path, format!("{px} px is too large for a GIF (at most 65535)")))
        };
        let size = (side(width)?, side(height)?);
        let file = AtomicFile::new(path).map_err(|e| write_error(path, e))?;
        let out = std::fs::File::create(file.path()).map_err(|e| write_error(path, e))?;
        // GIF delays are in hundredths of a second; 2 is the shortest most viewers honour.
        let delay = (100.0 / frame_rate).round().clamp(2.0, f64::from(u16::MAX)) as u16;
        Ok(GifWriter {
            path: path.to_path_buf(),
            file,
            out: Some(std::io::BufWriter::new(out)),
            encoder: None,
            size,
            palette: None,
            previous: None,
            shown: Vec::new(),
            delay,
        })
    }

    /// Append a frame (of the size given to [`GifWriter::create`]).
    pub fn push(&mut self, image: RgbaImage) -> Result<(), RenderError> {
        let (w, h) = (u32::from(self.size.0), u32::from(self.size.1));
        if image.dimensions() != (w, h) {
            return Err(write_error(
                &self.path,
                format!("a {}x{} px frame in a {w}x{h} px GIF", image.width(), image.height()),
            ));
        }
        if self.palette.is_none() {
            let palette = GifPalette::learn(&image);
            let out = self.out.take().ok_or_else(|| write_error(&self.path, "GIF already finished"))?;
            let mut encoder = gif::Encoder::new(out, self.size.0, self.size.1, &palette.table())
                .map_err(|e| write_error(&self.path, e))?;
            encoder.set_repeat(gif::Repeat::Infinite).map_err(|e| write_error(&self.path, e))?;
            self.encoder = Some(encoder);
            self.palette = Some(palette);
            self.shown = vec![TRANSPARENT; (w * h) as usize];
        }
        let (Some(palette), Some(encoder)) = (self.palette.as_mut(), self.encoder.as_mut()) else {
            return Err(write_error(&self.path, "GIF encoder missing"));
        };
        // The palette index of every pixel; those equal to the previous frame's keep theirs.
        let mut next = self.shown.clone();
        let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
        for (i, (p, shown)) in image.pixels().zip(next.iter_mut()).enumerate() {
            let same = *shown != TRANSPARENT
                && self.previous.as_ref().is_some_and(|prev| prev.as_raw()[i * 4..i * 4 + 4] == p.0);
            if same {
                continue;
            }
            let k = palette.index_of(p.0);
            if k != *shown {
                *shown = k;
                let (x, y) = (i as u32 % w, i as u32 / w);
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
            }
        }
        if x0 > x1 {
            // Nothing changed: one transparent pixel keeps the frame's place in time.
            (x0, y0, x1, y1) = (0, 0, 0, 0);
        }
        let mut sub: Vec<u8> = Vec::with_capacity(((x1 - x0 + 1) * (y1 - y0 + 1)) as usize);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let i = (y * w + x) as usize;
                sub.push(if next[i] == self.shown[i] { TRANSPARENT } else { next[i] });
            }
        }
        let frame = gif::Frame {
            left: x0 as u16,
            top: y0 as u16,
            width: (x1 - x0 + 1) as u16,
            height: (y1 - y0 + 1) as u16,
            buffer: std::borrow::Cow::Owned(sub),
            transparent: Some(TRANSPARENT),
            delay: self.delay,
            dispose: gif::DisposalMethod::Keep,
            ..gif::Frame::default()
        };
        encoder.write_frame(&frame).map_err(|e| write_error(&self.path, e))?;
        self.shown = next;
        self.previous = Some(image);
        Ok(())
    }

    /// End the GIF (its trailer written, the file flushed) and rename it into place; returns
    /// the size written \[bytes\].
    pub fn finish(self) -> Result<u64, RenderError> {
        let GifWriter { path, file, encoder, out, size, .. } = self;
        let out = match (encoder, out) {
            (Some(encoder), _) => encoder.into_inner().map_err(|e| write_error(&path, e))?,
            // No frame: an empty GIF of the size asked for.
            (None, Some(out)) => {
                let mut encoder = gif::Encoder::new(out, size.0, size.1, &[]).map_err(|e| write_error(&path, e))?;
                encoder.set_repeat(gif::Repeat::Infinite).map_err(|e| write_error(&path, e))?;
                encoder.into_inner().map_err(|e| write_error(&path, e))?
            }
            (None, None) => return Err(write_error(&path, "GIF output missing")),
        };
        let out = out.into_inner().map_err(|e| write_error(&path, e.error().to_string()))?;
        let bytes = out.metadata().map_or(0, |m| m.len());
        drop(out);
        file.commit().map_err(|e| write_error(&path, e))?;
        Ok(bytes)
    }
}
