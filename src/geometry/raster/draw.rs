//! 2-D drawing on an [`Image`]: what legends, histograms and overlays need. Integer pixel coordinates (x
//! right, y down), everything clipped to the image.

use super::Image;

/// Width and height of a glyph of the bitmap font at scale 1, pixels.
pub const GLYPH: i64 = 8;

impl Image {
    /// Fill the rectangle of top left (x, y) and size w × h.
    pub fn fill_rect(&mut self, x: i64, y: i64, w: i64, h: i64, colour: [u8; 3]) {
        let (x0, y0) = (x.max(0), y.max(0));
        let (x1, y1) = ((x + w).min(i64::from(self.width)), (y + h).min(i64::from(self.height)));
        for r in y0..y1 {
            for c in x0..x1 {
                self.put(c, r, colour);
            }
        }
    }

    /// The outline (one pixel wide) of the rectangle of top left (x, y) and size w × h.
    pub fn stroke_rect(&mut self, x: i64, y: i64, w: i64, h: i64, colour: [u8; 3]) {
        self.fill_rect(x, y, w, 1, colour);
        self.fill_rect(x, y + h - 1, w, 1, colour);
        self.fill_rect(x, y, 1, h, colour);
        self.fill_rect(x + w - 1, y, 1, h, colour);
    }

    /// A line from (x0, y0) to (x1, y1), `width` pixels wide (a square pen), Bresenham's steps.
    pub fn line(&mut self, (x0, y0): (i64, i64), (x1, y1): (i64, i64), width: i64, colour: [u8; 3]) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        let off = (width - 1) / 2;
        // Bounded: a line longer than the image's perimeter squared is clipped by its pixels anyway.
        for _ in 0..=(dx - dy).min(4 * i64::from(self.width + self.height)) {
            self.fill_rect(x - off, y - off, width, width, colour);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// A filled disc of radius `r` pixels centred on (x, y).
    pub fn disc(&mut self, x: i64, y: i64, r: i64, colour: [u8; 3]) {
        for dy in -r..=r {
            for dx in -r..=r {
                if dx * dx + dy * dy <= r * r {
                    self.put(x + dx, y + dy, colour);
                }
            }
        }
    }

    /// `text` (ASCII; other characters as `?`) with its top left at (x, y), each glyph `scale` × 8 pixels.
    /// Returns the x just past the last glyph.
    pub fn text(&mut self, x: i64, y: i64, text: &str, scale: i64, colour: [u8; 3]) -> i64 {
        let mut cx = x;
        for ch in text.chars() {
            let code = if ch.is_ascii() { ch as usize } else { '?' as usize };
            let glyph = font8x8::legacy::BASIC_LEGACY[code];
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits >> col & 1 == 1 {
                        self.fill_rect(cx + col * scale, y + row as i64 * scale, scale, scale, colour);
                    }
                }
            }
            cx += GLYPH * scale;
        }
        cx
    }
}

/// Width in pixels of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: i64) -> i64 {
    text.chars().count() as i64 * GLYPH * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_lines_and_rects_land_where_asked() {
        let mut img = Image::filled(64, 32, [255; 3]);
        let end = img.text(2, 3, "I", 1, [0; 3]);
        assert_eq!(end, 10);
        // font8x8's "I" is a vertical bar in columns 2-3 of its cell (0x1E row bits at the top, 0x0C below).
        let dark: Vec<(u32, u32)> = (0..8)
            .flat_map(|r| (0..8).map(move |c| (c, r)))
            .filter(|&(c, r)| img.pixel(2 + c, 3 + r) == [0; 3])
            .collect();
        assert!(dark.len() >= 10, "the glyph has pixels: {dark:?}");
        assert!(dark.iter().all(|&(c, _)| (1..=4).contains(&c)), "a narrow bar: {dark:?}");
        img.line((0, 31), (63, 31), 1, [9, 9, 9]);
        assert!((0..64).all(|x| img.pixel(x, 31) == [9, 9, 9]));
        img.stroke_rect(40, 5, 10, 10, [1, 2, 3]);
        assert_eq!(img.pixel(40, 5), [1, 2, 3]);
        assert_eq!(img.pixel(49, 14), [1, 2, 3]);
        assert_eq!(img.pixel(45, 10), [255; 3]);
        img.fill_rect(-5, -5, 3, 3, [0; 3]); // clipped away entirely
        assert_eq!(text_width("abc", 2), 48);
    }
}
