//! A tiny embedded 5x7 bitmap font for vehicle ids (digits and minus sign).

/// Glyph width [font px].
pub const GLYPH_W: u32 = 5;
/// Glyph height [font px].
pub const GLYPH_H: u32 = 7;

/// Atlas index of the minus sign; digits `0..=9` are at their own value.
pub const MINUS_GLYPH: u32 = 10;

/// Rows top to bottom; bit 4 is the leftmost column.
const GLYPHS: [[u8; 7]; 11] = [
    [0b01110, 0b10001, 0b10011, 0b10101, 0b11001, 0b10001, 0b01110], // 0
    [0b00100, 0b01100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110], // 1
    [0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b01000, 0b11111], // 2
    [0b11111, 0b00010, 0b00100, 0b00010, 0b00001, 0b10001, 0b01110], // 3
    [0b00010, 0b00110, 0b01010, 0b10010, 0b11111, 0b00010, 0b00010], // 4
    [0b11111, 0b10000, 0b11110, 0b00001, 0b00001, 0b10001, 0b01110], // 5
    [0b00110, 0b01000, 0b10000, 0b11110, 0b10001, 0b10001, 0b01110], // 6
    [0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b01000, 0b01000], // 7
    [0b01110, 0b10001, 0b10001, 0b01110, 0b10001, 0b10001, 0b01110], // 8
    [0b01110, 0b10001, 0b10001, 0b01111, 0b00001, 0b00010, 0b01100], // 9
    [0b00000, 0b00000, 0b00000, 0b11111, 0b00000, 0b00000, 0b00000], // -
];

/// Number of glyphs in the atlas.
pub fn glyph_count() -> u32 {
    GLYPHS.len() as u32
}

/// The atlas as an 8-bit coverage image: glyph `g` occupies columns `g*5 .. g*5+5`, rows 0..7.
pub fn atlas() -> (u32, u32, Vec<u8>) {
    let w = GLYPH_W * glyph_count();
    let mut data = vec![0u8; (w * GLYPH_H) as usize];
    for (g, rows) in GLYPHS.iter().enumerate() {
        for (y, row) in rows.iter().enumerate() {
            for x in 0..GLYPH_W {
                if row & (1 << (GLYPH_W - 1 - x)) != 0 {
                    data[y * w as usize + g * GLYPH_W as usize + x as usize] = 255;
                }
            }
        }
    }
    (w, GLYPH_H, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_glyph_has_ink() {
        for (g, rows) in GLYPHS.iter().enumerate() {
            assert!(rows.iter().any(|r| *r != 0), "glyph {g} is empty");
        }
        let (w, h, data) = atlas();
        assert_eq!((w, h), (55, 7));
        // '1' has its stem in the middle column on every row; the minus sign only in row 3.
        let one = GLYPH_W + 2;
        assert!((0..7).all(|y| data[(y * w + one) as usize] == 255));
        let minus = MINUS_GLYPH * GLYPH_W + 2;
        assert!((0..7).all(|y| (data[(y * w + minus) as usize] == 255) == (y == 3)));
    }
}
