//! Traffic-signal stop lines over a frame: each signalised link's stop line (the start of its
//! lanelet) in its signal's colour, drawn on the CPU over the read-back frame like the collision
//! rings. The caller says what each link shows ([`SignalLine`]); nothing here reads the world.

use glam::DVec2;
use image::RgbaImage;

use super::BirdseyeView;
use crate::map::LaneletMap;
use crate::map::junctions::Junctions;

/// One link's part of a stop line and the signal it shows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignalLine {
    /// One end \[m\].
    pub a: DVec2,
    /// The other end \[m\].
    pub b: DVec2,
    /// Signal character: `G`/`g` green, `y` yellow, `r`/`s` red; any other draws nothing.
    pub signal: u8,
}

/// Green of a `G`/`g` stop line (sRGB).
pub const SIGNAL_GREEN: [u8; 4] = [40, 210, 60, 255];
/// Yellow of a `y` stop line (sRGB).
pub const SIGNAL_YELLOW: [u8; 4] = [250, 200, 20, 255];
/// Red of an `r`/`s` stop line (sRGB).
pub const SIGNAL_RED: [u8; 4] = [230, 30, 30, 255];

/// The colour a signal character is drawn in, `None` for no signal or off (`-`, `o`, `O`).
pub fn signal_color(signal: u8) -> Option<[u8; 4]> {
    match signal {
        b'G' | b'g' => Some(SIGNAL_GREEN),
        b'y' => Some(SIGNAL_YELLOW),
        b'r' | b's' => Some(SIGNAL_RED),
        _ => None,
    }
}

/// The stop-line segment of every link of every junction of `map`: `out[j][k]` for link `k` of
/// junction index `j` (id `j + 1`), in the order `smlworld map info` lists the links. A stop line
/// runs from the first point of the lanelet's left bound to the first of its right bound; links
/// that start on the same line (straight, left and right from one lane) share it side by side,
/// each drawing its own part, as SUMO draws them. A link whose lanelet is missing gets a
/// zero-length segment (drawn as nothing).
pub fn stop_lines(map: &LaneletMap, junctions: &Junctions) -> Vec<Vec<(DVec2, DVec2)>> {
    junctions
        .list
        .iter()
        .map(|junction| {
            let whole: Vec<(DVec2, DVec2)> = junction
                .links
                .iter()
                .map(|l| match map.lanelet(l.lanelet) {
                    Some(x) if !x.left.is_empty() && !x.right.is_empty() => (x.left[0], x.right[0]),
                    _ => (DVec2::ZERO, DVec2::ZERO),
                })
                .collect();
            // Links sharing a stop line (ends within 1 cm): the k-th of n draws the k-th n-th.
            let same = |p: &(DVec2, DVec2), q: &(DVec2, DVec2)| p.0.distance(q.0) < 0.01 && p.1.distance(q.1) < 0.01;
            whole
                .iter()
                .enumerate()
                .map(|(i, line)| {
                    let n = whole.iter().filter(|o| same(o, line)).count().max(1);
                    let k = whole[..i].iter().filter(|o| same(o, line)).count();
                    let d = line.1 - line.0;
                    (line.0 + d * (k as f64 / n as f64), line.0 + d * ((k + 1) as f64 / n as f64))
                })
                .collect()
        })
        .collect()
}

/// Blend colour `c` over pixel (x, y) with weight `w` in [0, 1].
fn blend(img: &mut RgbaImage, x: i64, y: i64, c: [u8; 4], w: f64) {
    if x < 0 || y < 0 || x >= i64::from(img.width()) || y >= i64::from(img.height()) || w <= 0.0 {
        return;
    }
    let w = w.min(1.0);
    let p = img.get_pixel_mut(x as u32, y as u32);
    for (channel, &over) in p.0.iter_mut().zip(&c).take(3) {
        *channel = (f64::from(*channel) * (1.0 - w) + f64::from(over) * w).round() as u8;
    }
    p.0[3] = 255;
}

/// Draw every line of `lines` seen through `view` in its signal's colour: a bar 0.6 m wide (at
/// least 3 px) with a dark 1 px edge, so it reads on asphalt and on markings. Lines without a
/// colour ([`signal_color`]) are skipped. O(pixels under the bars).
pub fn draw_signal_lines(img: &mut RgbaImage, view: &BirdseyeView, lines: &[SignalLine]) {
    let half = (0.3 * view.pixels_per_meter).max(1.5);
    let edge = 1.0;
    for line in lines {
        let Some(color) = signal_color(line.signal) else { continue };
        let (a, b) = (view.world_to_pixel(line.a), view.world_to_pixel(line.b));
        if !(a.is_finite() && b.is_finite()) || a.distance(b) < 1e-9 {
            continue;
        }
        let reach = half + edge + 1.0;
        let (lo, hi) = (a.min(b) - DVec2::splat(reach), a.max(b) + DVec2::splat(reach));
        // Skip lines far outside the image (and bound the loop for a huge zoom).
        let (w, h) = (f64::from(img.width()), f64::from(img.height()));
        if hi.x < 0.0 || hi.y < 0.0 || lo.x > w || lo.y > h {
            continue;
        }
        let (x0, x1) = (lo.x.max(0.0).floor() as i64, hi.x.min(w).ceil() as i64);
        let (y0, y1) = (lo.y.max(0.0).floor() as i64, hi.y.min(h).ceil() as i64);
        let ab = b - a;
        let len2 = ab.length_squared();
        for y in y0..=y1 {
            for x in x0..=x1 {
                let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                // Distance to the segment, the bar's ends cut square (no caps past the ends).
                let along = (p - a).dot(ab) / len2;
                if !(0.0..=1.0).contains(&along) {
                    continue;
                }
                let d = (p - (a + ab * along)).length();
                blend(img, x, y, [15, 15, 15, 255], (half + edge + 0.5 - d).clamp(0.0, 1.0) * 0.8);
                blend(img, x, y, color, (half + 0.5 - d).clamp(0.0, 1.0));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_is_drawn_in_its_signal_colour_and_nothing_else_is_touched() {
        let view = BirdseyeView::new(100, 100, 5.0, DVec2::ZERO).expect("a valid view");
        let grey = image::Rgba([90, 90, 90, 255]);
        let mut img = RgbaImage::from_pixel(100, 100, grey);
        let lines = [
            SignalLine { a: DVec2::new(-5.0, 5.0), b: DVec2::new(5.0, 5.0), signal: b'r' },
            SignalLine { a: DVec2::new(-5.0, -5.0), b: DVec2::new(5.0, -5.0), signal: b'G' },
            SignalLine { a: DVec2::new(-5.0, 0.0), b: DVec2::new(5.0, 0.0), signal: b'-' },
        ];
        draw_signal_lines(&mut img, &view, &lines);
        // (0, 5) m is pixel (50, 25); (0, -5) m is (50, 75).
        assert_eq!(img.get_pixel(50, 25).0, SIGNAL_RED);
        assert_eq!(img.get_pixel(50, 75).0, SIGNAL_GREEN);
        assert_eq!(img.get_pixel(50, 50).0, grey.0, "no signal: nothing drawn");
        assert_eq!(img.get_pixel(50, 40).0, grey.0, "the bar stays narrow");
        assert_eq!(img.get_pixel(10, 25).0, grey.0, "nothing past the line's end");
    }

    #[test]
    fn signal_characters_map_to_three_colours() {
        assert_eq!(signal_color(b'G'), Some(SIGNAL_GREEN));
        assert_eq!(signal_color(b'g'), Some(SIGNAL_GREEN));
        assert_eq!(signal_color(b'y'), Some(SIGNAL_YELLOW));
        assert_eq!(signal_color(b'r'), Some(SIGNAL_RED));
        assert_eq!(signal_color(b'-'), None);
    }
}
