//! Bird's-eye view: how world metres (x east, y north) map to image pixels (x right, y down).

use glam::DVec2;

use super::RenderError;

/// A bird's-eye camera: an image of `width` x `height` pixels looking straight down at `center`.
///
/// A world point `p` \[m\] lands at pixel
/// `x = W/2 + (p.x - center.x)·P`, `y = H/2 - (p.y - center.y)·P·aspect`
/// (y up in the world, down in the image). With `center = (0, 0)` this is the 2015 tool's
/// convention `x = W/2 + x·P`, `y = H/2 - y·P`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BirdseyeView {
    /// Image width \[px\].
    pub width: u32,
    /// Image height \[px\].
    pub height: u32,
    /// Horizontal scale [px/m]; larger zooms in.
    pub pixels_per_meter: f64,
    /// World point at the image centre \[m\].
    pub center: DVec2,
    /// Vertical scale divided by horizontal scale (1.0 = square metres stay square). Only a
    /// projector calibration whose floor rectangle does not match the image's aspect ratio needs
    /// anything else.
    pub aspect: f64,
}

/// Largest image side the renderer accepts \[px\] (wgpu's default 2D texture limit).
pub const MAX_IMAGE_SIDE: u32 = 8192;

impl BirdseyeView {
    /// A view of `width` x `height` px at `pixels_per_meter` [px/m] centred on `center` \[m\].
    pub fn new(width: u32, height: u32, pixels_per_meter: f64, center: DVec2) -> Result<Self, RenderError> {
        let view = BirdseyeView { width, height, pixels_per_meter, center, aspect: 1.0 };
        view.validate()?;
        Ok(view)
    }

    /// The 2015 tool's view: centred on the map's local origin (pixel x = W/2 + x·P, y = H/2 - y·P).
    pub fn centered_on_origin(width: u32, height: u32, pixels_per_meter: f64) -> Result<Self, RenderError> {
        BirdseyeView::new(width, height, pixels_per_meter, DVec2::ZERO)
    }

    /// The largest scale at which the world box `min`..`max` \[m\] fits the image with a margin of
    /// `margin` \[m\] on every side, centred on the box.
    pub fn fit(width: u32, height: u32, min: DVec2, max: DVec2, margin: f64) -> Result<Self, RenderError> {
        let size = (max - min).max(DVec2::ZERO) + DVec2::splat(2.0 * margin.max(0.0));
        if !(size.x.is_finite() && size.y.is_finite()) {
            return Err(RenderError::InvalidView(format!(
                "cannot fit the box {min}..{max} [m]: its size is not finite"
            )));
        }
        // A point-sized box (one node) still gets a sensible 10 px/m.
        let ppm = if size.x <= 0.0 && size.y <= 0.0 {
            10.0
        } else {
            let sx = if size.x > 0.0 { f64::from(width) / size.x } else { f64::INFINITY };
            let sy = if size.y > 0.0 { f64::from(height) / size.y } else { f64::INFINITY };
            sx.min(sy)
        };
        BirdseyeView::new(width, height, ppm, (min + max) * 0.5)
    }

    /// A view that shows the whole map (the bounding box of all its nodes plus 5 % margin).
    pub fn fit_map(width: u32, height: u32, map: &crate::map::LaneletMap) -> Result<Self, RenderError> {
        if map.nodes.is_empty() {
            return Err(RenderError::InvalidView(
                "cannot fit a view to a map without nodes; give --pixels-per-meter and --center".into(),
            ));
        }
        let (min, max) = map.bounding_box();
        let margin = 0.05 * (max - min).max_element();
        BirdseyeView::fit(width, height, min, max, margin)
    }

    /// A projector calibration: the floor rectangle `left..right` x `down..up` \[m\] fills the whole
    /// image exactly, so a ceiling projector showing this image lines up with the floor. When the
    /// rectangle's aspect ratio differs from the image's, the pixels are not square on the floor
    /// (`aspect != 1`).
    pub fn projector(width: u32, height: u32, left: f64, right: f64, down: f64, up: f64) -> Result<Self, RenderError> {
        if !(right > left && up > down && [left, right, down, up].iter().all(|v| v.is_finite())) {
            return Err(RenderError::InvalidView(format!(
                "projector rectangle left={left} right={right} down={down} up={up} [m] must have right > left and up > down"
            )));
        }
        let ppm = f64::from(width) / (right - left);
        let ppm_y = f64::from(height) / (up - down);
        let view = BirdseyeView {
            width,
            height,
            pixels_per_meter: ppm,
            center: DVec2::new(0.5 * (left + right), 0.5 * (down + up)),
            aspect: ppm_y / ppm,
        };
        view.validate()?;
        Ok(view)
    }

    /// Vertical scale [px/m].
    pub fn pixels_per_meter_y(&self) -> f64 {
        self.pixels_per_meter * self.aspect
    }

    /// Pixel coordinates (x right, y down, continuous; pixel (i, j) covers i..i+1, j..j+1) of a world point \[m\].
    pub fn world_to_pixel(&self, p: DVec2) -> DVec2 {
        DVec2::new(
            0.5 * f64::from(self.width) + (p.x - self.center.x) * self.pixels_per_meter,
            0.5 * f64::from(self.height) - (p.y - self.center.y) * self.pixels_per_meter_y(),
        )
    }

    /// World point \[m\] under pixel coordinates (inverse of [`BirdseyeView::world_to_pixel`]).
    pub fn pixel_to_world(&self, px: DVec2) -> DVec2 {
        DVec2::new(
            self.center.x + (px.x - 0.5 * f64::from(self.width)) / self.pixels_per_meter,
            self.center.y - (px.y - 0.5 * f64::from(self.height)) / self.pixels_per_meter_y(),
        )
    }

    /// World rectangle seen by the view: (min, max) corners \[m\].
    pub fn world_rect(&self) -> (DVec2, DVec2) {
        let half = DVec2::new(
            0.5 * f64::from(self.width) / self.pixels_per_meter,
            0.5 * f64::from(self.height) / self.pixels_per_meter_y(),
        );
        (self.center - half, self.center + half)
    }

    /// The original's metadata line: `image_width=W;image_height=H;pixel_per_meter=P`, numbers
    /// written as Python wrote floats (`1920.0`), no trailing newline.
    pub fn meta(&self) -> String {
        format!(
            "image_width={:?};image_height={:?};pixel_per_meter={:?}",
            f64::from(self.width),
            f64::from(self.height),
            self.pixels_per_meter
        )
    }

    fn validate(&self) -> Result<(), RenderError> {
        if self.width == 0 || self.height == 0 || self.width > MAX_IMAGE_SIDE || self.height > MAX_IMAGE_SIDE {
            return Err(RenderError::InvalidView(format!(
                "image size {}x{} px: each side must be 1..={MAX_IMAGE_SIDE}",
                self.width, self.height
            )));
        }
        let scale_ok = |s: f64| s.is_finite() && s > 0.0;
        if !scale_ok(self.pixels_per_meter) || !scale_ok(self.aspect) {
            return Err(RenderError::InvalidView(format!(
                "pixels per metre {} (aspect {}) must be finite and > 0",
                self.pixels_per_meter, self.aspect
            )));
        }
        if !(self.center.x.is_finite() && self.center.y.is_finite()) {
            return Err(RenderError::InvalidView(format!("view centre {} [m] is not finite", self.center)));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origin_view_matches_the_2015_convention() {
        let v = BirdseyeView::centered_on_origin(1920, 1080, 5.0).expect("a valid view");
        // x = 960 + 10·5, y = 540 - (-4)·5
        assert_eq!(v.world_to_pixel(DVec2::new(10.0, -4.0)), DVec2::new(1010.0, 560.0));
        assert_eq!(v.pixel_to_world(DVec2::new(1010.0, 560.0)), DVec2::new(10.0, -4.0));
    }

    #[test]
    fn meta_matches_the_original_file_format() {
        let v = BirdseyeView::centered_on_origin(1920, 1080, 5.0).expect("a valid view");
        assert_eq!(v.meta(), "image_width=1920.0;image_height=1080.0;pixel_per_meter=5.0");
    }

    #[test]
    fn fit_keeps_the_whole_box_inside() {
        let v =
            BirdseyeView::fit(800, 600, DVec2::new(-100.0, -20.0), DVec2::new(300.0, 80.0), 0.0).expect("a valid view");
        // Width limits: 800 px / 400 m = 2 px/m; the box spans 400x100 m -> 800x200 px.
        assert_eq!(v.pixels_per_meter, 2.0);
        assert_eq!(v.world_to_pixel(DVec2::new(-100.0, 80.0)), DVec2::new(0.0, 200.0));
        assert_eq!(v.world_to_pixel(DVec2::new(300.0, -20.0)), DVec2::new(800.0, 400.0));
    }

    #[test]
    fn projector_rectangle_fills_the_image() {
        let v = BirdseyeView::projector(1920, 1080, -3.0, 4.0, -2.0, 2.0).expect("a valid view");
        assert_eq!(v.world_to_pixel(DVec2::new(-3.0, 2.0)), DVec2::new(0.0, 0.0));
        let br = v.world_to_pixel(DVec2::new(4.0, -2.0));
        assert!((br - DVec2::new(1920.0, 1080.0)).length() < 1e-9, "{br}");
    }

    #[test]
    fn bad_views_are_errors() {
        assert!(BirdseyeView::new(0, 10, 1.0, DVec2::ZERO).is_err());
        assert!(BirdseyeView::new(10, 10, -1.0, DVec2::ZERO).is_err());
        assert!(BirdseyeView::new(10, 10, f64::NAN, DVec2::ZERO).is_err());
        assert!(BirdseyeView::projector(10, 10, 1.0, 1.0, 0.0, 1.0).is_err());
    }
}
