//! Ground patterns: the built-in tiles (made by `examples/make_patterns.rs`), user overrides, scales.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use image::RgbaImage;

use super::RenderError;

/// Side of every pattern tile on the GPU \[px\]; user images of another size are resized to it.
pub const PATTERN_SIZE: u32 = 256;

/// The ground materials the environment layer knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum PatternKind {
    /// Background everywhere outside roads and areas.
    Forest,
    /// Inside every lanelet.
    Road,
    /// Closed ways tagged `mud` or `pile_stuff`.
    Mud,
    /// Closed ways tagged `iron`.
    Iron,
    /// Closed ways tagged `parking_lot`.
    ParkingLot,
    /// Closed ways tagged `free_space`.
    FreeSpace,
}

impl PatternKind {
    /// All kinds, in texture-layer order.
    pub const ALL: [PatternKind; 6] = [
        PatternKind::Forest,
        PatternKind::Road,
        PatternKind::Mud,
        PatternKind::Iron,
        PatternKind::ParkingLot,
        PatternKind::FreeSpace,
    ];

    /// File name of the pattern in a pattern directory (`forest.png`, `road.png`, ...).
    pub fn file_name(self) -> &'static str {
        match self {
            PatternKind::Forest => "forest.png",
            PatternKind::Road => "road.png",
            PatternKind::Mud => "mud.png",
            PatternKind::Iron => "iron.png",
            PatternKind::ParkingLot => "parking_lot.png",
            PatternKind::FreeSpace => "free_space.png",
        }
    }

    /// The pattern for a closed way's `line_type`/`region` value, if it names an area.
    pub fn from_area_tag(value: &str) -> Option<PatternKind> {
        match value {
            "mud" | "pile_stuff" => Some(PatternKind::Mud),
            "iron" => Some(PatternKind::Iron),
            "parking_lot" => Some(PatternKind::ParkingLot),
            "free_space" => Some(PatternKind::FreeSpace),
            _ => None,
        }
    }

    /// Default ground size of one tile \[m\]: a larger value stretches the pattern.
    pub fn default_tile_meters(self) -> f64 {
        match self {
            PatternKind::Forest => 24.0,
            PatternKind::Road => 8.0,
            PatternKind::Mud => 10.0,
            PatternKind::Iron => 4.0,
            PatternKind::ParkingLot => 12.0,
            PatternKind::FreeSpace => 10.0,
        }
    }

    /// Texture-array layer of this pattern.
    pub(crate) fn layer(self) -> u32 {
        match self {
            PatternKind::Forest => 0,
            PatternKind::Road => 1,
            PatternKind::Mud => 2,
            PatternKind::Iron => 3,
            PatternKind::ParkingLot => 4,
            PatternKind::FreeSpace => 5,
        }
    }

    fn builtin_png(self) -> &'static [u8] {
        match self {
            PatternKind::Forest => include_bytes!("../../assets/patterns/forest.png"),
            PatternKind::Road => include_bytes!("../../assets/patterns/road.png"),
            PatternKind::Mud => include_bytes!("../../assets/patterns/mud.png"),
            PatternKind::Iron => include_bytes!("../../assets/patterns/iron.png"),
            PatternKind::ParkingLot => include_bytes!("../../assets/patterns/parking_lot.png"),
            PatternKind::FreeSpace => include_bytes!("../../assets/patterns/free_space.png"),
        }
    }
}

/// One pattern: its tile image and the ground size of one tile \[m\].
#[derive(Debug, Clone)]
pub struct Pattern {
    /// Tile image, [`PATTERN_SIZE`] square, repeated over the ground.
    pub image: RgbaImage,
    /// Ground size of one tile \[m\].
    pub tile_meters: f64,
}

/// The patterns the environment is painted with: built in, or a user's directory.
#[derive(Debug, Clone)]
pub struct PatternSet {
    patterns: BTreeMap<PatternKind, Pattern>,
}

impl PatternSet {
    /// The built-in patterns (procedural tiles in `assets/patterns/`, compiled into the binary).
    pub fn builtin() -> PatternSet {
        let patterns = PatternKind::ALL
            .iter()
            .map(|&kind| {
                // The built-in PNGs are generated and checked by tests/render_patterns.rs.
                let image = image::load_from_memory(kind.builtin_png())
                    .expect("built-in pattern PNGs are valid (tests/render_patterns.rs checks them)")
                    .to_rgba8();
                (kind, Pattern { image: fit_tile(image), tile_meters: kind.default_tile_meters() })
            })
            .collect();
        PatternSet { patterns }
    }

    /// The built-in patterns, each replaced by `DIR/<kind>.png` (`forest.png`, `road.png`, `mud.png`,
    /// `iron.png`, `parking_lot.png`, `free_space.png`) when that file exists. Any readable image
    /// works; it is resized to [`PATTERN_SIZE`] square and should tile seamlessly.
    pub fn from_dir(dir: &Path) -> Result<PatternSet, RenderError> {
        if !dir.is_dir() {
            return Err(RenderError::PatternDir(dir.to_path_buf()));
        }
        let mut set = PatternSet::builtin();
        for kind in PatternKind::ALL {
            let path: PathBuf = dir.join(kind.file_name());
            if path.exists() {
                let image = image::open(&path)
                    .map_err(|source| RenderError::Pattern { path: path.clone(), source })?
                    .to_rgba8();
                tracing::debug!(pattern = %path.display(), "using user pattern");
                set.set_image(kind, image);
            }
        }
        Ok(set)
    }

    /// The pattern of one kind.
    pub fn get(&self, kind: PatternKind) -> &Pattern {
        &self.patterns[&kind]
    }

    /// Replace a pattern's tile image (resized to [`PATTERN_SIZE`] square).
    pub fn set_image(&mut self, kind: PatternKind, image: RgbaImage) {
        if let Some(p) = self.patterns.get_mut(&kind) {
            p.image = fit_tile(image);
        }
    }

    /// Set the ground size of one tile of a pattern \[m\] (ignored unless finite and > 0).
    pub fn set_tile_meters(&mut self, kind: PatternKind, meters: f64) {
        if let Some(p) = self.patterns.get_mut(&kind)
            && meters.is_finite()
            && meters > 0.0
        {
            p.tile_meters = meters;
        }
    }
}

fn fit_tile(image: RgbaImage) -> RgbaImage {
    if image.width() == PATTERN_SIZE && image.height() == PATTERN_SIZE {
        image
    } else {
        image::imageops::resize(&image, PATTERN_SIZE, PATTERN_SIZE, image::imageops::FilterType::Triangle)
    }
}

/// Mip chain of a tile, full size first, down to 1x1 (box-filtered in linear light would be
/// better; a triangle filter in sRGB is close enough for ground textures).
pub(crate) fn mip_chain(image: &RgbaImage) -> Vec<RgbaImage> {
    let mut levels = Vec::new();
    let mut current = image.clone();
    while current.width() > 1 {
        let size = current.width() / 2;
        let next = image::imageops::resize(&current, size, size, image::imageops::FilterType::Triangle);
        levels.push(std::mem::replace(&mut current, next));
    }
    levels.push(current);
    levels
}
