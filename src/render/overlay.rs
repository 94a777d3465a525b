//! The frame overlay: a time stamp and a legend (vehicle classes by colour; real vs virtual) in
//! the top-left corner, drawn on the CPU over a read-back frame with DejaVu Sans (shipped in
//! `assets/fonts`, so frames look the same everywhere).

use std::sync::OnceLock;

use ab_glyph::{Font, FontRef, PxScale, ScaleFont, point};
use image::RgbaImage;

use super::{VehicleSprite, class_color};

/// DejaVu Sans (TrueType; licence in `assets/fonts/DejaVuSans.LICENSE`), for overlays and plots.
pub static FONT_TTF: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

fn font() -> Option<&'static FontRef<'static>> {
    static FONT: OnceLock<Option<FontRef<'static>>> = OnceLock::new();
    FONT.get_or_init(|| FontRef::try_from_slice(FONT_TTF).ok()).as_ref()
}

/// Text height of the overlay [px].
pub const OVERLAY_TEXT_PX: f32 = 16.0;
/// Background of the overlay box (sRGB with alpha).
pub const OVERLAY_BACKGROUND: [u8; 4] = [16, 16, 24, 200];

fn blend(img: &mut RgbaImage, x: i64, y: i64, c: [u8; 4], coverage: f32) {
    if x < 0 || y < 0 || x >= i64::from(img.width()) || y >= i64::from(img.height()) {
        return;
    }
    let a = (f32::from(c[3]) / 255.0) * coverage.clamp(0.0, 1.0);
    let p = img.get_pixel_mut(x as u32, y as u32);
    for k in 0..3 {
        p.0[k] = (f32::from(p.0[k]) * (1.0 - a) + f32::from(c[k]) * a).round() as u8;
    }
    p.0[3] = 255;
}

fn fill(img: &mut RgbaImage, x0: i64, y0: i64, w: i64, h: i64, c: [u8; 4]) {
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            blend(img, x, y, c, 1.0);
        }
    }
}

/// Width of `text` [px] at the overlay size.
fn text_width(text: &str) -> f32 {
    let Some(f) = font() else { return 0.0 };
    let f = f.as_scaled(PxScale::from(OVERLAY_TEXT_PX));
    text.chars().map(|c| f.h_advance(f.glyph_id(c))).sum()
}

/// Draw `text` with its baseline at `y` from `x` [px].
fn draw_text(img: &mut RgbaImage, x: f32, y: f32, text: &str, color: [u8; 4]) {
    let Some(f) = font() else { return };
    let scaled = f.as_scaled(PxScale::from(OVERLAY_TEXT_PX));
    let mut pen = x;
    for c in text.chars() {
        let id = scaled.glyph_id(c);
        let glyph = id.with_scale_and_position(PxScale::from(OVERLAY_TEXT_PX), point(pen, y));
        pen += scaled.h_advance(id);
        if let Some(outline) = f.outline_glyph(glyph) {
            let b = outline.px_bounds();
            outline.draw(|gx, gy, cov| {
                blend(img, b.min.x as i64 + i64::from(gx), b.min.y as i64 + i64::from(gy), color, cov);
            });
        }
    }
}

/// Draw the time stamp `t` [s] and the legend of the classes in `sprites` (sorted by name), and
/// "real"/"virtual" entries for the kinds present, into the top-left corner of `img`.
pub fn draw_overlay(img: &mut RgbaImage, t: f64, sprites: &[VehicleSprite]) {
    let mut classes: Vec<&str> = sprites.iter().map(|s| s.class.as_str()).collect();
    classes.sort_unstable();
    classes.dedup();
    let mut lines: Vec<(Option<[u8; 4]>, String)> = vec![(None, format!("t = {t:.1} s"))];
    lines.extend(classes.iter().map(|c| (Some(class_color(c)), (*c).to_string())));
    if sprites.iter().any(|s| s.id >= 0) {
        lines.push((None, "solid: real (id >= 0)".into()));
    }
    if sprites.iter().any(|s| s.id < 0) {
        lines.push((None, "hatched: virtual (id < 0)".into()));
    }
    let line_h = (OVERLAY_TEXT_PX * 1.35).ceil() as i64;
    let (pad, swatch) = (8i64, 14i64);
    let width = lines.iter().map(|(_, s)| text_width(s)).fold(0.0f32, f32::max).ceil() as i64 + 3 * pad + swatch;
    let height = line_h * lines.len() as i64 + pad;
    fill(img, pad, pad, width, height, OVERLAY_BACKGROUND);
    for (i, (color, text)) in lines.iter().enumerate() {
        let top = pad + pad / 2 + line_h * i as i64;
        let mut x = 2 * pad;
        if let Some(c) = color {
            fill(img, x, top + (line_h - swatch) / 2, swatch, swatch, *c);
            x += swatch + pad / 2;
        }
        draw_text(img, x as f32, top as f32 + OVERLAY_TEXT_PX, text, [245, 245, 245, 255]);
    }
}
