//! Plots: the deviation histogram and the convergence of the chain's attempts. Drawn with the same
//! rasteriser and bitmap font as the maps, so their bytes do not depend on the machine's fonts.

use super::maps::Deviation;
use super::sheet::{INK, MUTED, num};
use crate::geometry::raster::{BACKGROUND, Image, text_width};
use crate::stages::quality::deviation_colour;

/// A plot's size.
pub const PLOT: (u32, u32) = (1024, 384);

/// The plotting area inside a plot: left, top, width, height.
const AREA: (i64, i64, i64, i64) = (88, 40, 900, 270);

/// Bins of the deviation histogram.
pub const HISTOGRAM_BINS: usize = 80;

/// The deviation histogram: the share of the seen surface's vertices per bin of signed deviation over the
/// map's symmetric range (beyond it, in the end bins), each bar in the map's colour; the tolerance band's
/// edges dashed.
pub fn histogram(dev: &Deviation) -> Image {
    let range = dev.range();
    let mut counts = [0usize; HISTOGRAM_BINS];
    let (mut n, mut within, mut sq) = (0usize, 0usize, 0.0);
    for (i, &d) in dev.signed.iter().enumerate() {
        if !d.is_finite() || dev.invented.is_some_and(|m| m.get(i).copied().unwrap_or(false)) {
            continue;
        }
        let b = (((d + range) / (2.0 * range)) * HISTOGRAM_BINS as f64).floor();
        counts[(b.max(0.0) as usize).min(HISTOGRAM_BINS - 1)] += 1;
        n += 1;
        within += usize::from(d.abs() <= dev.band);
        sq += d * d;
    }
    let mut img = Image::filled(PLOT.0, PLOT.1, BACKGROUND);
    let (x0, y0, w, h) = AREA;
    let top = counts.iter().copied().max().unwrap_or(0).max(1);
    let bw = w as f64 / HISTOGRAM_BINS as f64;
    for (k, &c) in counts.iter().enumerate() {
        let bh = (c as f64 / top as f64 * h as f64).round() as i64;
        let xa = x0 + (k as f64 * bw).round() as i64;
        let xb = x0 + ((k + 1) as f64 * bw).round() as i64;
        let centre = ((k as f64 + 0.5) / HISTOGRAM_BINS as f64 * 2.0 - 1.0) * range;
        img.fill_rect(xa, y0 + h - bh, (xb - xa - 1).max(1), bh, deviation_colour(centre, range, dev.band));
        img.stroke_rect(xa, y0 + h - bh, (xb - xa - 1).max(1), bh.max(1), MUTED);
    }
    for edge in [-dev.band, dev.band] {
        let x = x0 + (((edge + range) / (2.0 * range)) * w as f64).round() as i64;
        dashed_vertical(&mut img, x, y0, h, MUTED);
    }
    axes(&mut img, &format!("{:.1}%", 100.0 * top as f64 / n.max(1) as f64), "0%");
    let xl = |v: f64| x0 + (((v + range) / (2.0 * range)) * w as f64).round() as i64;
    for (v, label) in [(-range, dev.label(-range)), (0.0, "0".into()), (range, dev.label(range))] {
        let lw = text_width(&label, 1);
        img.text((xl(v) - lw / 2).clamp(2, i64::from(PLOT.0) - lw - 2), y0 + h + 10, &label, 1, INK);
    }
    let rms = (sq / n.max(1) as f64).sqrt();
    let title = format!(
        "deviation histogram: {n} vertices seen by the scan; RMS {}; {:.1} % within +-{}",
        dev.label(rms),
        100.0 * within as f64 / n.max(1) as f64,
        dev.label(dev.band)
    );
    img.text(x0, 12, &title, 1, INK);
    img.text(x0, y0 + h + 30, "signed distance solid - scan (negative: inside)", 1, MUTED);
    img
}

/// One attempt of the chain, as the convergence plot shows it.
pub struct AttemptPoint {
    /// Control vertices asked for.
    pub target_vertices: usize,
    /// Two-sided RMS of the solid to the input, % of the diagonal.
    pub rms_pct: f64,
    /// Whether the solid crossed itself or folded (the chain built it again).
    pub rejected: bool,
}

/// The convergence of the chain: each attempt's RMS (% of the diagonal) in order, a rejected one (crossed
/// or folded) hollow, and the RMS gate's bound dashed red.
pub fn convergence(attempts: &[AttemptPoint], bound_pct: f64) -> Image {
    let mut img = Image::filled(PLOT.0, PLOT.1, BACKGROUND);
    let (x0, y0, w, h) = AREA;
    let ymax = attempts.iter().map(|a| a.rms_pct).filter(|v| v.is_finite()).fold(bound_pct, f64::max).max(1e-12) * 1.15;
    let y = |v: f64| y0 + h - ((v / ymax).clamp(0.0, 1.0) * h as f64).round() as i64;
    let n = attempts.len().max(1);
    let x = |k: usize| x0 + ((k as f64 + 0.5) / n as f64 * w as f64).round() as i64;
    let by = y(bound_pct);
    for xx in (x0..x0 + w).step_by(12) {
        img.fill_rect(xx, by, 6, 2, [200, 30, 30]);
    }
    img.text(x0 + w - text_width("RMS gate", 1) - 4, by - 12, "RMS gate", 1, [200, 30, 30]);
    for (k, a) in attempts.iter().enumerate() {
        let p = (x(k), y(a.rms_pct));
        if k > 0 {
            img.line((x(k - 1), y(attempts[k - 1].rms_pct)), p, 2, MUTED);
        }
        img.disc(p.0, p.1, 6, if a.rejected { [200, 30, 30] } else { [30, 60, 150] });
        if a.rejected {
            img.disc(p.0, p.1, 3, BACKGROUND);
        }
        let label = format!("{} v", a.target_vertices);
        img.text(p.0 - text_width(&label, 1) / 2, y0 + h + 10, &label, 1, INK);
    }
    axes(&mut img, &format!("{}%", num(ymax)), "0%");
    let title = format!(
        "convergence: the solid's RMS (% of the diagonal) at each attempt; {} attempts; hollow: crossed or folded, built again",
        attempts.len()
    );
    img.text(x0, 12, &title, 1, INK);
    img.text(x0, y0 + h + 30, "control vertices asked for", 1, MUTED);
    img
}

/// The plotting area's axes, with the y axis' top and bottom labels.
fn axes(img: &mut Image, top: &str, bottom: &str) {
    let (x0, y0, w, h) = AREA;
    img.fill_rect(x0 - 2, y0, 1, h + 1, INK);
    img.fill_rect(x0 - 2, y0 + h, w + 2, 1, INK);
    img.text(x0 - 8 - text_width(top, 1), y0, top, 1, INK);
    img.text(x0 - 8 - text_width(bottom, 1), y0 + h - 8, bottom, 1, INK);
}

/// A dashed vertical line.
fn dashed_vertical(img: &mut Image, x: i64, y0: i64, h: i64, colour: [u8; 3]) {
    for y in (y0..y0 + h).step_by(8) {
        img.fill_rect(x, y, 1, 4, colour);
    }
}
