//! Software rendering for the job pictures (issue 45): a mesh seen from a view ([`Snapshot`]: an
//! orthographic z-buffer that remembers which triangle covers each pixel, painted afterwards by any colour
//! rule), and the 2-D drawing legends and plots need ([`Image`]: rectangles, lines, discs, text in an 8 × 8
//! bitmap font). On the CPU, with no display and no GPU, and deterministic: the same input gives the same
//! pixels whatever the thread count.

mod draw;
mod snapshot;

pub use draw::{GLYPH, text_width};
pub use snapshot::{BACKGROUND, MARGIN, Snapshot, View, render};

/// An RGB image, 8 bits a channel, rows top to bottom.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `width × height` pixels, 3 bytes each, row-major from the top left.
    pub rgb: Vec<u8>,
}

impl Image {
    /// A `width × height` image filled with `colour`.
    pub fn filled(width: u32, height: u32, colour: [u8; 3]) -> Image {
        Image { width, height, rgb: colour.repeat(width as usize * height as usize) }
    }

    /// The pixel at column `x`, row `y` (from the top left).
    ///
    /// # Panics
    /// When (x, y) lies outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Set the pixel at (x, y); nothing outside the image.
    pub fn put(&mut self, x: i64, y: i64, colour: [u8; 3]) {
        if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
            return;
        }
        let i = 3 * (y as usize * self.width as usize + x as usize);
        self.rgb[i..i + 3].copy_from_slice(&colour);
    }

    /// Copy `other` into this image with its top left corner at (x, y), clipped.
    pub fn blit(&mut self, other: &Image, x: i64, y: i64) {
        for r in 0..i64::from(other.height) {
            for c in 0..i64::from(other.width) {
                self.put(x + c, y + r, other.pixel(c as u32, r as u32));
            }
        }
    }
}
