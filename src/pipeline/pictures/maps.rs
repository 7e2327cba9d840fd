//! The solid painted five ways, each as a sheet with its legend: deviation from the scan, the quad net,
//! the B-rep faces, von Mises stress, and a scan's coverage.

use super::sheet::{INK, Scene, colour_bar, hatch, legend_box, num, swatch, ticks};
use crate::geometry::mesh::PolyMesh;
use crate::geometry::raster::Image;
use crate::geometry::stats::percentile;
use crate::geometry::vec3::V3;
use crate::stages::quality::{DEVIATION_BAND, INVENTED_GREY, deviation_colour};

/// The shaded solid's own colour under overlays (net, faces' boundaries).
pub const SOLID_GREY: [u8; 3] = [215, 215, 215];

/// Hatch ink over invented surface.
const INVENTED_INK: [u8; 3] = [95, 95, 95];

/// What a deviation map shows: each vertex's signed distance to the scan (positive outside), in model
/// units, and which vertices are invented surface (caps and fills no scan saw).
pub struct Deviation<'a> {
    /// Signed distance per vertex of the scene's mesh.
    pub signed: &'a [f64],
    /// Invented surface, per vertex.
    pub invented: Option<&'a [bool]>,
    /// Half width of the neutral tolerance band, model units.
    pub band: f64,
    /// The input's bounding-box diagonal, model units.
    pub diag: f64,
    /// The model unit's name (`mm`).
    pub unit: &'a str,
    /// Places where the scan lies farther from the solid than the far-tail goal (model points: a tip cut
    /// short, a crease rounded off): each is ringed in every view ([`crate::pipeline::far_tail::FarTail::places`]).
    pub far: &'a [V3],
}

/// Ring colour of a far place on the deviation map.
pub const FAR_RING: [u8; 3] = [150, 0, 170];

/// Ring radius of a far place, pixels.
const FAR_RING_RADIUS: f64 = 11.0;

/// Ring `p` on `img` (the snapshot's panel), two pixels wide, whether or not the surface hides it (a part the
/// solid lost lies outside it).
fn ring(img: &mut Image, snap: &crate::geometry::raster::Snapshot, p: V3) {
    if let Some(c) = snap.screen(p) {
        ring_at(img, (c[0], c[1]), FAR_RING_RADIUS);
    }
}

/// A ring of radius `r` pixels about `c`, two pixels wide.
fn ring_at(img: &mut Image, c: (f64, f64), r: f64) {
    let at = |k: usize| {
        let a = std::f64::consts::TAU * k as f64 / 24.0;
        ((c.0 + r * a.cos()).round() as i64, (c.1 + r * a.sin()).round() as i64)
    };
    for k in 0..24 {
        img.line(at(k), at(k + 1), 2, FAR_RING);
    }
}

impl Deviation<'_> {
    fn is_invented(&self, i: usize) -> bool {
        self.invented.is_some_and(|m| m.get(i).copied().unwrap_or(false))
    }

    /// The scale's symmetric range: the 99th percentile of |d| over the surface a scan saw, at least twice
    /// the band (so the band is never the whole scale) and never zero.
    pub fn range(&self) -> f64 {
        let mut a: Vec<f64> = (0..self.signed.len())
            .filter(|&i| !self.is_invented(i) && self.signed[i].is_finite())
            .map(|i| self.signed[i].abs())
            .collect();
        let p = if a.is_empty() { 0.0 } else { percentile(&mut a, 0.99) };
        p.max(2.0 * self.band).max(1e-12 * self.diag.max(1e-300))
    }

    /// Each vertex's colour on the map's scale ([`Deviation::range`], the band).
    pub fn colours(&self) -> Vec<[u8; 3]> {
        let range = self.range();
        self.signed.iter().map(|&d| deviation_colour(d, range, self.band)).collect()
    }

    /// `v` model units as the legend writes it: in the unit and in % of the diagonal.
    pub fn label(&self, v: f64) -> String {
        format!("{} {} ({}%)", num(v), self.unit, num(100.0 * v / self.diag.max(1e-300)))
    }
}

/// The deviation map: blue inside, red outside, grey within the band, invented surface hatched.
/// The deviation map, its vertices coloured by `colours` ([`Deviation::colours`]).
pub fn deviation_sheet(scene: &Scene, dev: &Deviation, colours: &[[u8; 3]]) -> Image {
    let range = dev.range();
    let mut sheet = scene.sheet(|snap| {
        let mut img = paint_deviation(snap, scene, dev, colours);
        dev.far.iter().for_each(|&p| ring(&mut img, snap, p));
        img
    });
    let lb = legend_box();
    colour_bar(&mut sheet, lb.bar, |t| deviation_colour((2.0 * t - 1.0) * range, range, dev.band));
    ticks(&mut sheet, lb.bar, lb.ticks_y, &[(0.0, dev.label(-range)), (0.5, "0".into()), (1.0, dev.label(range))]);
    let caption = format!("solid - scan, signed: blue inside, red outside; grey within +-{}", dev.label(dev.band));
    sheet.text(lb.bar.0, lb.caption_y, &caption, 1, INK);
    let y = swatch(&mut sheet, (lb.swatch_x, lb.bar.1), |_, _| DEVIATION_BAND, "within the tolerance band");
    let y = swatch(
        &mut sheet,
        (lb.swatch_x, y),
        |x, y| hatch(x, y, INVENTED_GREY, INVENTED_INK),
        "invented: caps, fills, unseen",
    );
    if !dev.far.is_empty() {
        swatch(&mut sheet, (lb.swatch_x, y), |_, _| crate::geometry::raster::BACKGROUND, "ringed: the scan's far tail");
        ring_at(&mut sheet, ((lb.swatch_x + 8) as f64, (y + 8) as f64), 5.0);
    }
    sheet
}

/// One panel of the deviation map (also the thumbnail's).
pub fn paint_deviation(
    snap: &crate::geometry::raster::Snapshot,
    scene: &Scene,
    dev: &Deviation,
    colours: &[[u8; 3]],
) -> Image {
    let mesh = scene.mesh;
    snap.paint(|x, y, f, l| {
        let t = mesh.triangles[f];
        if t.iter().all(|&i| dev.is_invented(i as usize)) {
            return hatch(x, y, INVENTED_GREY, INVENTED_INK);
        }
        blend(t.map(|i| colours[i as usize]), l)
    })
}

/// Barycentric blend of three corner colours.
fn blend(c: [[u8; 3]; 3], l: [f32; 3]) -> [u8; 3] {
    std::array::from_fn(|k| {
        (l[0] * f32::from(c[0][k]) + l[1] * f32::from(c[1][k]) + l[2] * f32::from(c[2][k])).round().clamp(0.0, 255.0)
            as u8
    })
}

/// The quad net over the shaded solid: its edges dark blue where they are in front of (or within `slack`
/// of) the surface, extraordinary vertices (valence other than 4) as red dots.
pub fn net_sheet(scene: &Scene, net: &PolyMesh, slack: f64) -> Image {
    const EDGE: [u8; 3] = [30, 60, 150];
    const ODD: [u8; 3] = [210, 30, 30];
    let edges = crate::geometry::polygon::unique_edges(net.faces());
    let mut valence = vec![0u32; net.positions.len()];
    for &(a, b) in &edges {
        valence[a as usize] += 1;
        valence[b as usize] += 1;
    }
    let p = |i: u32| net.positions[i as usize].map(f64::from);
    let odd: Vec<u32> = (0..net.positions.len() as u32).filter(|&i| valence[i as usize] != 4).collect();
    let mut sheet = scene.sheet(|snap| {
        let mut img = snap.paint(|_, _, _, _| SOLID_GREY);
        for &(a, b) in &edges {
            snap.segment(&mut img, p(a), p(b), slack, EDGE);
        }
        for &v in &odd {
            if let Some(s) = snap.screen(p(v)).filter(|s| snap.visible(*s, slack)) {
                img.disc(s[0] as i64, s[1] as i64, 2, ODD);
            }
        }
        img
    });
    let lb = legend_box();
    let caption = format!(
        "quad control net: {} vertices, {} faces; {} extraordinary vertices (valence other than 4)",
        net.positions.len(),
        net.face_count(),
        odd.len()
    );
    sheet.text(lb.bar.0, lb.caption_y, &caption, 1, INK);
    let y = swatch(&mut sheet, (lb.swatch_x, lb.bar.1), |_, _| EDGE, "net edge");
    swatch(&mut sheet, (lb.swatch_x, y), |_, _| ODD, "extraordinary vertex");
    sheet
}

/// A face's colour: hues spread by the golden ratio, so neighbours in face order differ.
pub fn face_colour(face: u32) -> [u8; 3] {
    let h = (f64::from(face) * 0.618_033_988_749_895).fract();
    hsv(h, 0.45, 0.92)
}

/// HSV (each in [0, 1]) to RGB.
fn hsv(h: f64, s: f64, v: f64) -> [u8; 3] {
    let i = (h * 6.0).floor();
    let f = h * 6.0 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - f * s), v * (1.0 - (1.0 - f) * s));
    let (r, g, b) = match i as i64 % 6 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [r, g, b].map(|c| (c * 255.0).round() as u8)
}

/// The B-rep faces, each in its own colour (`face_of[t]`: the face of the scene's triangle t).
pub fn faces_sheet(scene: &Scene, face_of: &[u32]) -> Image {
    let mut sheet =
        scene.sheet(|snap| snap.paint(|_, _, f, _| face_of.get(f).map_or(SOLID_GREY, |&id| face_colour(id))));
    let faces = face_of.iter().copied().max().map_or(0, |m| m + 1);
    let lb = legend_box();
    sheet.text(lb.bar.0, lb.caption_y, &format!("B-rep faces: {faces}, each in its own colour"), 1, INK);
    for k in 0..12u32.min(faces) {
        let x = lb.bar.0 + i64::from(k) * 22;
        sheet.fill_rect(x, lb.bar.1, 16, 16, face_colour(k));
        sheet.stroke_rect(x - 1, lb.bar.1 - 1, 18, 18, INK);
    }
    sheet
}

/// A sequential, colour-blind-safe scale (viridis, 6 stops) for t in [0, 1] (clamped; NaN is the low end).
pub fn viridis(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 6] = [
        [68.0, 1.0, 84.0],
        [65.0, 68.0, 135.0],
        [42.0, 120.0, 142.0],
        [34.0, 168.0, 132.0],
        [122.0, 209.0, 81.0],
        [253.0, 231.0, 37.0],
    ];
    let x = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * 5.0;
    let i = (x.floor() as usize).min(4);
    let f = x - i as f64;
    std::array::from_fn(|k| (STOPS[i][k] + (STOPS[i + 1][k] - STOPS[i][k]) * f).round() as u8)
}

/// What a stress map shows.
pub struct Stress<'a> {
    /// Von Mises stress per vertex of the scene's mesh, MPa.
    pub von_mises: &'a [f64],
    /// Vertices a support holds.
    pub supported: &'a [bool],
    /// Vertices a load acts on.
    pub loaded: &'a [bool],
}

/// Von Mises on the solid (viridis from 0 to the 99th percentile: the clamps' singular peaks saturate),
/// supports hatched black, loads hatched magenta.
pub fn stress_sheet(scene: &Scene, s: &Stress) -> Image {
    const SUPPORT: [u8; 3] = [0, 0, 0];
    const LOAD: [u8; 3] = [220, 0, 180];
    let mut finite: Vec<f64> = s.von_mises.iter().copied().filter(|v| v.is_finite()).collect();
    let top = if finite.is_empty() { 1.0 } else { percentile(&mut finite, 0.99).max(1e-300) };
    let colours: Vec<[u8; 3]> = s.von_mises.iter().map(|&v| viridis(v / top)).collect();
    let all = |mask: &[bool], t: [u32; 3]| t.iter().all(|&i| mask.get(i as usize).copied().unwrap_or(false));
    let mesh = scene.mesh;
    let mut sheet = scene.sheet(|snap| {
        snap.paint(|x, y, f, l| {
            let t = mesh.triangles[f];
            let c = blend(t.map(|i| colours[i as usize]), l);
            if all(s.supported, t) {
                hatch(x, y, c, SUPPORT)
            } else if all(s.loaded, t) {
                hatch(x, y, c, LOAD)
            } else {
                c
            }
        })
    });
    let lb = legend_box();
    colour_bar(&mut sheet, lb.bar, viridis);
    let mid = format!("{} MPa", num(0.5 * top));
    ticks(&mut sheet, lb.bar, lb.ticks_y, &[(0.0, "0 MPa".into()), (0.5, mid), (1.0, format!(">= {} MPa", num(top)))]);
    sheet.text(
        lb.bar.0,
        lb.caption_y,
        "von Mises stress (scale to the 99th percentile; higher is the top colour)",
        1,
        INK,
    );
    let y = swatch(&mut sheet, (lb.swatch_x, lb.bar.1), |x, y| hatch(x, y, [200; 3], SUPPORT), "support (held)");
    swatch(&mut sheet, (lb.swatch_x, y), |x, y| hatch(x, y, [200; 3], LOAD), "load applied");
    sheet
}

/// Unseen surface on a coverage map: hatched red.
const UNSEEN: [u8; 3] = [215, 48, 39];

/// A scan's coverage: each vertex coloured by how many views saw it (`seen_by`), from light (one) to dark
/// (`views` or more); surface no view saw hatched red.
pub fn coverage_sheet(scene: &Scene, seen_by: &[u16], views: u16) -> Image {
    let most = f64::from(views.max(1));
    let colour = |n: u16| if n == 0 { [250, 250, 250] } else { viridis(1.0 - f64::from(n) / most) };
    let colours: Vec<[u8; 3]> = seen_by.iter().map(|&n| colour(n)).collect();
    let mesh = scene.mesh;
    let mut sheet = scene.sheet(|snap| {
        snap.paint(|x, y, f, l| {
            let t = mesh.triangles[f];
            if t.iter().all(|&i| seen_by.get(i as usize).is_some_and(|&n| n == 0)) {
                return hatch(x, y, [250, 250, 250], UNSEEN);
            }
            blend(t.map(|i| colours[i as usize]), l)
        })
    });
    let lb = legend_box();
    colour_bar(&mut sheet, lb.bar, |t| colour(1 + (t * most).floor().min(most - 1.0) as u16));
    ticks(&mut sheet, lb.bar, lb.ticks_y, &[(0.0, "1 view".into()), (1.0, format!("{views} views"))]);
    let unseen = seen_by.iter().filter(|&&n| n == 0).count();
    let caption = format!(
        "views that saw each point; {:.1} % of the vertices unseen (hatched)",
        100.0 * unseen as f64 / seen_by.len().max(1) as f64
    );
    sheet.text(lb.bar.0, lb.caption_y, &caption, 1, INK);
    swatch(&mut sheet, (lb.swatch_x, lb.bar.1), |x, y| hatch(x, y, [250, 250, 250], UNSEEN), "unseen: no view saw it");
    sheet
}
