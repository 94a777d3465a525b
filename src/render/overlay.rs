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

/// Text height of the overlay on a 720 px high image and above \[px\]; smaller images scale it
/// down with their height (never below 9 px), so the legend keeps to a corner (at 640x360 it is
/// at most a quarter of the width).
pub const OVERLAY_TEXT_PX: f32 = 16.0;

/// Text height of the overlay on an image `height` px high [px].
fn text_px(height: u32) -> f32 {
    (OVERLAY_TEXT_PX * height as f32 / 720.0).clamp(9.0, OVERLAY_TEXT_PX)
}
/// Background of the overlay box (sRGB with alpha).
pub const OVERLAY_BACKGROUND: [u8; 4] = [16, 16, 24, 200];

fn blend(img: &mut RgbaImage, x: i64, y: i64, c: [u8; 4], coverage: f32) {
    if x < 0 || y < 0 || x >= i64::from(img.width()) || y >= i64::from(img.height()) {
        return;
    }
    let a = (f32::from(c[3]) / 255.0) * coverage.clamp(0.0, 1.0);
    let p = img.get_pixel_mut(x as u32, y as u32);
    for (channel, &over) in p.0.iter_mut().zip(&c).take(3) {
        *channel = (f32::from(*channel) * (1.0 - a) + f32::from(over) * a).round() as u8;
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

/// Width of `text` [px] at text height `px`.
fn text_width(text: &str, px: f32) -> f32 {
    let Some(f) = font() else { return 0.0 };
    let f = f.as_scaled(PxScale::from(px));
    text.chars().map(|c| f.h_advance(f.glyph_id(c))).sum()
}

/// Draw `text` of height `px` with its baseline at `y` from `x` [px].
fn draw_text(img: &mut RgbaImage, x: f32, y: f32, px: f32, text: &str, color: [u8; 4]) {
    let Some(f) = font() else { return };
    let scaled = f.as_scaled(PxScale::from(px));
    let mut pen = x;
    for c in text.chars() {
        let id = scaled.glyph_id(c);
        let glyph = id.with_scale_and_position(PxScale::from(px), point(pen, y));
        pen += scaled.h_advance(id);
        if let Some(outline) = f.outline_glyph(glyph) {
            let b = outline.px_bounds();
            outline.draw(|gx, gy, cov| {
                blend(img, b.min.x as i64 + i64::from(gx), b.min.y as i64 + i64::from(gy), color, cov);
            });
        }
    }
}

/// Draw the time stamp `t` \[s\] and the legend of the classes in `sprites` (sorted by name), and
/// "real"/"virtual" entries for the kinds present, into the top-left corner of `img`; the text
/// scales with the image's height. Returns the legend's box: x, y, width, height \[px\].
pub fn draw_overlay(img: &mut RgbaImage, t: f64, sprites: &[VehicleSprite]) -> [i64; 4] {
    let mut classes: Vec<&str> = sprites.iter().map(|s| s.class.as_str()).collect();
    classes.sort_unstable();
    classes.dedup();
    let mut lines: Vec<(Option<[u8; 4]>, String)> = vec![(None, format!("t = {t:.1} s"))];
    lines.extend(classes.iter().map(|c| (Some(class_color(c)), (*c).to_string())));
    if sprites.iter().any(|s| s.real) {
        lines.push((None, "solid: real".into()));
    }
    if sprites.iter().any(|s| !s.real) {
        lines.push((None, "hatched: virtual".into()));
    }
    let px = text_px(img.height());
    let line_h = (px * 1.35).ceil() as i64;
    let (pad, swatch) = ((px / 2.0).round() as i64, (px * 0.85).round() as i64);
    let width = lines.iter().map(|(_, s)| text_width(s, px)).fold(0.0f32, f32::max).ceil() as i64 + 3 * pad + swatch;
    let height = line_h * lines.len() as i64 + pad;
    fill(img, pad, pad, width, height, OVERLAY_BACKGROUND);
    for (i, (color, text)) in lines.iter().enumerate() {
        let top = pad + pad / 2 + line_h * i as i64;
        let mut x = 2 * pad;
        if let Some(c) = color {
            fill(img, x, top + (line_h - swatch) / 2, swatch, swatch, *c);
            x += swatch + pad / 2;
        }
        draw_text(img, x as f32, top as f32 + px, px, text, [245, 245, 245, 255]);
    }
    [pad, pad, width, height]
}

/// Colour of a collision ring (sRGB).
const RING_COLOR: [u8; 4] = [235, 20, 20, 255];

/// A red ring around `place` \[m\] seen through `view`, marking a collision: radius 3 m but at
/// least 10 px, 3 px wide with a dark edge inside and out, so it reads on any ground.
pub fn draw_collision_ring(img: &mut RgbaImage, view: &super::BirdseyeView, place: glam::DVec2) {
    let c = view.world_to_pixel(place);
    let r = (3.0 * view.pixels_per_meter).max(10.0);
    let (half, edge) = (1.5, 1.0);
    let reach = r + half + edge + 1.0;
    let (x0, x1) = ((c.x - reach).floor() as i64, (c.x + reach).ceil() as i64);
    let (y0, y1) = ((c.y - reach).floor() as i64, (c.y + reach).ceil() as i64);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let d = ((x as f64 + 0.5 - c.x).hypot(y as f64 + 0.5 - c.y) - r).abs();
            let outer = (half + edge + 0.5 - d).clamp(0.0, 1.0) as f32;
            if outer > 0.0 {
                blend(img, x, y, [20, 0, 0, 255], outer * 0.8);
                blend(img, x, y, RING_COLOR, (half + 0.5 - d).clamp(0.0, 1.0) as f32);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_legend_keeps_to_a_quarter_of_a_small_image() {
        let sprites: Vec<VehicleSprite> = ["Truck", "Car", "Bus", "Emergency", "Bicycle"]
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let mut s = VehicleSprite::new(i as i32 - 2, glam::DVec2::ZERO, 0.0, 4.0, 2.0, c);
                s.real = i % 2 == 0;
                s
            })
            .collect();
        let mut small = RgbaImage::new(640, 360);
        let [x, _, w, _] = draw_overlay(&mut small, 1234.5, &sprites);
        assert!(x + w <= 160, "legend {w} px wide at 640x360");
        let mut big = RgbaImage::new(1920, 1080);
        let [_, _, w_big, _] = draw_overlay(&mut big, 1234.5, &sprites);
        assert!(w_big > w, "scales up on a big image");
    }

    #[test]
    fn a_collision_ring_is_red_on_its_circle_and_leaves_the_centre() {
        let view = super::super::BirdseyeView::new(200, 100, 5.0, glam::DVec2::ZERO).expect("a valid view");
        let mut img = RgbaImage::from_pixel(200, 100, image::Rgba([90, 90, 90, 255]));
        draw_collision_ring(&mut img, &view, glam::DVec2::new(2.0, 0.0));
        // Centre pixel (110, 50); radius 15 px.
        assert_eq!(img.get_pixel(110, 50).0, [90, 90, 90, 255]);
        let on = img.get_pixel(125, 50).0;
        assert!(on[0] > 200 && on[1] < 60, "{on:?}");
    }
}
