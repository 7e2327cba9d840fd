//! One picture sheet: the solid from four views (front, side, top, isometric) in a 2 × 2 grid, and a
//! legend band under them. The mesh is rasterised once per view ([`Scene`]); each picture paints it.

use rayon::prelude::*;

use crate::geometry::mesh::TriMesh;
use crate::geometry::raster::{BACKGROUND, Image, Snapshot, View, text_width};
use crate::geometry::vec3::V3;

/// A sheet's size: readable at 1024 × 768.
pub const SHEET: (u32, u32) = (1024, 768);

/// Height of the legend band at the bottom of a sheet, pixels.
pub const LEGEND_HEIGHT: u32 = 96;

/// Dark text and rules.
pub const INK: [u8; 3] = [40, 40, 40];

/// Secondary text (panel names, tick labels).
pub const MUTED: [u8; 3] = [110, 110, 110];

/// A mesh rasterised from the four views of a sheet, each a quarter of the area above the legend.
pub struct Scene<'a> {
    /// The mesh seen.
    pub mesh: &'a TriMesh,
    /// (view name, its snapshot), in sheet order.
    pub panels: Vec<(&'static str, Snapshot)>,
}

impl<'a> Scene<'a> {
    /// Rasterise `mesh` from the four views of an object whose up is `up`, one view per thread (each view's
    /// pixels do not depend on the others, so the result does not depend on the thread count).
    ///
    /// Cost: four [`Snapshot::take`]s of 512 × 336 pixels; about 2.7 MB each.
    pub fn new(mesh: &'a TriMesh, up: V3) -> Scene<'a> {
        let (pw, ph) = panel_size();
        let panels = View::four(up).into_par_iter().map(|(name, v)| (name, Snapshot::take(mesh, &v, pw, ph))).collect();
        Scene { mesh, panels }
    }

    /// A sheet: each panel painted by `paint` (then given its view's name), the legend band left empty for
    /// the caller.
    pub fn sheet(&self, paint: impl Fn(&Snapshot) -> Image + Sync) -> Image {
        let (pw, ph) = panel_size();
        let painted: Vec<Image> = self.panels.par_iter().map(|(_, s)| paint(s)).collect();
        let mut sheet = Image::filled(SHEET.0, SHEET.1, BACKGROUND);
        for (k, (img, (name, _))) in painted.iter().zip(&self.panels).enumerate() {
            let (x, y) = (i64::from(pw) * (k as i64 % 2), i64::from(ph) * (k as i64 / 2));
            sheet.blit(img, x, y);
            sheet.text(x + 8, y + 8, name, 2, MUTED);
        }
        // Rules between the panels and above the legend.
        sheet.fill_rect(i64::from(pw), 0, 1, 2 * i64::from(ph), [225; 3]);
        sheet.fill_rect(0, i64::from(ph), i64::from(SHEET.0), 1, [225; 3]);
        sheet.fill_rect(0, legend_top(), i64::from(SHEET.0), 1, [200; 3]);
        sheet
    }

    /// The isometric panel painted by `paint`, cropped square and scaled to `size` × `size` (the job's
    /// thumbnail).
    pub fn thumbnail(&self, size: u32, paint: impl Fn(&Snapshot) -> Image) -> Image {
        let iso = &self.panels.last().expect("four panels").1;
        let img = paint(iso);
        let side = img.width.min(img.height);
        let (x0, y0) = ((img.width - side) / 2, (img.height - side) / 2);
        let mut out = Image::filled(size, size, BACKGROUND);
        for y in 0..size {
            for x in 0..size {
                // Box filter over the source pixels this one covers.
                let (sx0, sx1) = (x * side / size, ((x + 1) * side / size).max(x * side / size + 1));
                let (sy0, sy1) = (y * side / size, ((y + 1) * side / size).max(y * side / size + 1));
                let mut acc = [0u32; 3];
                for sy in sy0..sy1 {
                    for sx in sx0..sx1 {
                        let p = img.pixel(x0 + sx, y0 + sy);
                        (0..3).for_each(|k| acc[k] += u32::from(p[k]));
                    }
                }
                let n = (sx1 - sx0) * (sy1 - sy0);
                out.put(i64::from(x), i64::from(y), acc.map(|a| ((a + n / 2) / n) as u8));
            }
        }
        out
    }
}

/// A panel's size: half the sheet's width, half the height above the legend.
pub fn panel_size() -> (u32, u32) {
    (SHEET.0 / 2, (SHEET.1 - LEGEND_HEIGHT) / 2)
}

/// The first row of the legend band.
pub fn legend_top() -> i64 {
    i64::from(SHEET.1 - LEGEND_HEIGHT)
}

/// Where a legend draws: its colour bar's box and the caption line under it.
pub struct LegendBox {
    /// Colour bar left, top, width, height.
    pub bar: (i64, i64, i64, i64),
    /// Tick labels' top row.
    pub ticks_y: i64,
    /// Caption's top row.
    pub caption_y: i64,
    /// Where swatches start (x), right of the bar.
    pub swatch_x: i64,
}

/// The legend band's layout on a sheet.
pub fn legend_box() -> LegendBox {
    let top = legend_top();
    LegendBox { bar: (24, top + 10, 520, 18), ticks_y: top + 32, caption_y: top + 56, swatch_x: 680 }
}

/// A horizontal colour bar: `colour(t)` for t from 0 (left) to 1 (right), outlined.
pub fn colour_bar(img: &mut Image, (x, y, w, h): (i64, i64, i64, i64), colour: impl Fn(f64) -> [u8; 3]) {
    for c in 0..w {
        let col = colour((c as f64 + 0.5) / w as f64);
        img.fill_rect(x + c, y, 1, h, col);
    }
    img.stroke_rect(x - 1, y - 1, w + 2, h + 2, INK);
}

/// Tick marks under a bar of box `bar` at fractions `t` along it, each labelled (centred, kept inside the
/// sheet) at row `y`.
pub fn ticks(img: &mut Image, bar: (i64, i64, i64, i64), y: i64, labels: &[(f64, String)]) {
    let (x, by, w, h) = bar;
    for (t, label) in labels {
        let cx = x + (t * w as f64).round() as i64;
        img.fill_rect(cx, by + h, 1, 4, INK);
        let lw = text_width(label, 1);
        let lx = (cx - lw / 2).clamp(2, i64::from(img.width) - lw - 2);
        img.text(lx, y, label, 1, INK);
    }
}

/// A legend swatch at (x, y): a 16 × 16 square filled by `fill(x, y)` (hatches work), and its label;
/// returns the y of the next line.
pub fn swatch(img: &mut Image, (x, y): (i64, i64), fill: impl Fn(u32, u32) -> [u8; 3], label: &str) -> i64 {
    for r in 0..16 {
        for c in 0..16 {
            img.put(x + c, y + r, fill((x + c) as u32, (y + r) as u32));
        }
    }
    img.stroke_rect(x - 1, y - 1, 18, 18, INK);
    img.text(x + 24, y + 4, label, 1, INK);
    y + 22
}

/// A diagonal hatch: `ink` on every fourth diagonal, `base` elsewhere (for invented surface, supports).
pub fn hatch(x: u32, y: u32, base: [u8; 3], ink: [u8; 3]) -> [u8; 3] {
    if (x + y) % 6 < 2 { ink } else { base }
}

/// A number in a legend: 3 significant digits, exponent form outside 1e-3 … 1e5.
pub fn num(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.2e}")
    } else {
        let decimals = (2 - a.log10().floor() as i32).clamp(0, 6) as usize;
        format!("{v:.decimals$}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::icosphere;

    #[test]
    fn a_sheet_has_four_panels_and_a_square_thumbnail() {
        let s = icosphere(1.0, 3, [0.0; 3]);
        let scene = Scene::new(&s, [0.0, 1.0, 0.0]);
        let sheet = scene.sheet(|snap| snap.paint(|_, _, _, _| [200, 0, 0]));
        assert_eq!((sheet.width, sheet.height), SHEET);
        let (pw, ph) = panel_size();
        for (px, py) in [(pw / 2, ph / 2), (pw + pw / 2, ph / 2), (pw / 2, ph + ph / 2), (pw + pw / 2, ph + ph / 2)] {
            let c = sheet.pixel(px, py);
            assert!(c[0] > 100 && c[1] == 0, "the sphere at the centre of every panel: {c:?} at ({px}, {py})");
        }
        let thumb = scene.thumbnail(256, |snap| snap.paint(|_, _, _, _| [200, 0, 0]));
        assert_eq!((thumb.width, thumb.height), (256, 256));
        assert!(thumb.pixel(128, 128)[0] > 100);
        assert_eq!(thumb.pixel(1, 1), BACKGROUND);
    }

    #[test]
    fn legend_numbers_keep_three_digits() {
        assert_eq!(num(0.012345), "0.0123");
        assert_eq!(num(-1.5), "-1.50");
        assert_eq!(num(123.4), "123");
        assert_eq!(num(2.5e-5), "2.50e-5");
        assert_eq!(num(0.0), "0");
    }
}
