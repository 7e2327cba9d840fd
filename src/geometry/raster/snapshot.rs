//! A mesh seen from a view: an orthographic projection and a z-buffer that keeps, for each pixel, the
//! nearest triangle, where on it the pixel lies (barycentric weights) and its Lambert shade. Painting is a
//! second pass over the pixels with any colour rule (per vertex, per face, hatched), so the pictures of one
//! job (deviation, net, faces, stresses, coverage) rasterise the mesh once per view.
//!
//! Deterministic: one pass over the triangles in order; a nearer fragment wins, an equal one keeps the first.

use super::Image;
use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{V3, cross, dot, norm, scale, sub, wide};

/// Where the viewer looks from: `toward` points from the object to the viewer, `up` is the image's up
/// (made perpendicular to `toward`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// From the object toward the viewer.
    pub toward: V3,
    /// Up in the image.
    pub up: V3,
}

impl View {
    /// The front view of an object whose up is `up` (a unit axis) and whose front faces +z, or −y when up
    /// is z.
    pub fn front(up: V3) -> View {
        let toward = if up[2].abs() > 0.5 { [0.0, -1.0, 0.0] } else { [0.0, 0.0, 1.0] };
        View { toward, up }
    }

    /// The view from the object's right side.
    pub fn side(up: V3) -> View {
        View { toward: cross(up, View::front(up).toward), up }
    }

    /// The view from above (the image's up is the front view's away-from-viewer direction).
    pub fn top(up: V3) -> View {
        let front = View::front(up).toward;
        View { toward: up, up: scale(front, -1.0) }
    }

    /// An isometric view from the front, right and above.
    pub fn iso(up: V3) -> View {
        let (f, s) = (View::front(up).toward, View::side(up).toward);
        View { toward: [f[0] + s[0] + up[0], f[1] + s[1] + up[1], f[2] + s[2] + up[2]], up }
    }

    /// The four views of a job's pictures, in their order: front, side, top, isometric.
    pub fn four(up: V3) -> [(&'static str, View); 4] {
        [("front", View::front(up)), ("side", View::side(up)), ("top", View::top(up)), ("iso", View::iso(up))]
    }

    /// The view's orthonormal frame: image right, image up, toward the viewer.
    fn frame(&self) -> (V3, V3, V3) {
        let w = scale(self.toward, 1.0 / norm(self.toward).max(1e-300));
        let u = cross(self.up, w);
        let u = scale(u, 1.0 / norm(u).max(1e-300));
        (u, cross(w, u), w)
    }
}

/// The background: white.
pub const BACKGROUND: [u8; 3] = [255, 255, 255];

/// Share of the image left free around the object on each side.
pub const MARGIN: f64 = 0.05;

/// No triangle covers the pixel.
const EMPTY: u32 = u32::MAX;

/// A mesh rasterised from one view: per pixel the nearest triangle, its barycentric weights there and its
/// shade (see the module's docs).
#[derive(Clone, Debug)]
pub struct Snapshot {
    width: u32,
    height: u32,
    frame: (V3, V3, V3),
    fit: Option<Fit>,
    /// Per pixel: the triangle, or [`EMPTY`].
    face: Vec<u32>,
    /// Per pixel: the weights of the triangle's second and third corners.
    bary: Vec<[f32; 2]>,
    /// Per pixel: Lambert shade in [0.3, 1].
    shade: Vec<f32>,
    /// Per pixel: depth (larger is nearer; −∞ where empty).
    depth: Vec<f32>,
}

impl Snapshot {
    /// Rasterise `mesh` from `view` into `width × height` pixels, the object scaled to fit with [`MARGIN`]
    /// free, lit from the viewer's upper left.
    ///
    /// Cost: O(V + F + the pixels the triangles cover); memory 16 bytes a pixel.
    pub fn take(mesh: &TriMesh, view: &View, width: u32, height: u32) -> Snapshot {
        let frame = view.frame();
        let (u, v, w) = frame;
        let (wd, ht) = (width.max(1) as usize, height.max(1) as usize);
        let n = wd * ht;
        let projected: Vec<V3> =
            mesh.positions.iter().map(|&p| wide(p)).map(|p| [dot(p, u), dot(p, v), dot(p, w)]).collect();
        let fit = Fit::of(&projected, wd, ht);
        let mut snap = Snapshot {
            width: wd as u32,
            height: ht as u32,
            frame,
            fit,
            face: vec![EMPTY; n],
            bary: vec![[0.0; 2]; n],
            shade: vec![0.0; n],
            depth: vec![f32::NEG_INFINITY; n],
        };
        let Some(fit) = snap.fit.clone() else { return snap };
        let light = {
            let l = [-0.4 * u[0] + 0.5 * v[0] + w[0], -0.4 * u[1] + 0.5 * v[1] + w[1], -0.4 * u[2] + 0.5 * v[2] + w[2]];
            scale(l, 1.0 / norm(l))
        };
        for (k, t) in mesh.triangles.iter().enumerate() {
            let [a, b, c] = t.map(|i| i as usize);
            let (pa, pb, pc) = (wide(mesh.positions[a]), wide(mesh.positions[b]), wide(mesh.positions[c]));
            let nrm = cross(sub(pb, pa), sub(pc, pa));
            let shade = 0.3 + 0.7 * (dot(nrm, light).abs() / norm(nrm).max(1e-300));
            let s = [a, b, c].map(|i| fit.screen(projected[i]));
            snap.fill(k as u32, s, shade as f32);
        }
        snap
    }

    /// Paint every covered pixel with `colour(x, y, triangle, barycentric weights)` times its shade; the
    /// rest is [`BACKGROUND`].
    pub fn paint(&self, colour: impl Fn(u32, u32, usize, [f32; 3]) -> [u8; 3]) -> Image {
        let mut image = Image::filled(self.width, self.height, BACKGROUND);
        for (k, px) in image.rgb.chunks_exact_mut(3).enumerate() {
            let f = self.face[k];
            if f == EMPTY {
                continue;
            }
            let [l1, l2] = self.bary[k];
            let (x, y) = ((k % self.width as usize) as u32, (k / self.width as usize) as u32);
            let c = colour(x, y, f as usize, [1.0 - l1 - l2, l1, l2]);
            let shade = f64::from(self.shade[k]);
            for (out, ch) in px.iter_mut().zip(c) {
                *out = (f64::from(ch) * shade).round().clamp(0.0, 255.0) as u8;
            }
        }
        image
    }

    /// [`Snapshot::paint`] with one colour per vertex of `mesh`, interpolated across each triangle (a
    /// vertex without a colour is light grey).
    pub fn paint_vertices(&self, mesh: &TriMesh, colours: &[[u8; 3]]) -> Image {
        self.paint(|_, _, f, l| {
            let col = mesh.triangles[f].map(|i| colours.get(i as usize).copied().unwrap_or([200, 200, 200]));
            std::array::from_fn(|ch| {
                let c = l[0] * f32::from(col[0][ch]) + l[1] * f32::from(col[1][ch]) + l[2] * f32::from(col[2][ch]);
                c.round().clamp(0.0, 255.0) as u8
            })
        })
    }

    /// Where the model point `p` lands: pixel coordinates (x right, y down) and depth (larger is nearer);
    /// `None` for an empty mesh.
    pub fn screen(&self, p: V3) -> Option<[f64; 3]> {
        let (u, v, w) = self.frame;
        self.fit.as_ref().map(|f| f.screen([dot(p, u), dot(p, v), dot(p, w)]))
    }

    /// Whether a point at screen position `s` (from [`Snapshot::screen`]) is in front of the surface there,
    /// or behind it by less than `slack` model units (a point on the surface itself is visible).
    pub fn visible(&self, s: [f64; 3], slack: f64) -> bool {
        let (x, y) = (s[0].floor(), s[1].floor());
        if x < 0.0 || y < 0.0 || x >= f64::from(self.width) || y >= f64::from(self.height) {
            return false;
        }
        let d = self.depth[y as usize * self.width as usize + x as usize];
        s[2] + slack >= f64::from(d)
    }

    /// Draw the model segment a–b onto `image` (this snapshot's size) where it is [`Snapshot::visible`]
    /// with `slack`, one pixel wide, stepping a pixel at a time.
    pub fn segment(&self, image: &mut Image, a: V3, b: V3, slack: f64, colour: [u8; 3]) {
        let (Some(sa), Some(sb)) = (self.screen(a), self.screen(b)) else { return };
        let steps = ((sb[0] - sa[0]).abs().max((sb[1] - sa[1]).abs()).ceil() as usize).clamp(1, 4096);
        for i in 0..=steps {
            let t = i as f64 / steps as f64;
            let s = [0, 1, 2].map(|k| sa[k] + t * (sb[k] - sa[k]));
            if self.visible(s, slack) {
                image.put(s[0].floor() as i64, s[1].floor() as i64, colour);
            }
        }
    }

    /// Record one triangle (screen corners `s`, `shade`) where it is nearer than the depth buffer; pixel
    /// centres at half-integers, edges by barycentric weights.
    fn fill(&mut self, face: u32, s: [[f64; 3]; 3], shade: f32) {
        let (wd, ht) = (self.width as usize, self.height as usize);
        let area = (s[1][0] - s[0][0]) * (s[2][1] - s[0][1]) - (s[2][0] - s[0][0]) * (s[1][1] - s[0][1]);
        if !(area.abs() >= 1e-12) {
            return;
        }
        let x0 = s.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min).floor().max(0.0) as usize;
        let x1 = (s.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max).ceil().max(0.0) as usize).min(wd);
        let y0 = s.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min).floor().max(0.0) as usize;
        let y1 = (s.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max).ceil().max(0.0) as usize).min(ht);
        for y in y0..y1 {
            for x in x0..x1 {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let edge =
                    |a: [f64; 3], b: [f64; 3]| ((b[0] - a[0]) * (py - a[1]) - (px - a[0]) * (b[1] - a[1])) / area;
                let l = [edge(s[1], s[2]), edge(s[2], s[0]), edge(s[0], s[1])];
                if l.iter().any(|&x| x < 0.0) {
                    continue;
                }
                let z = (l[0] * s[0][2] + l[1] * s[1][2] + l[2] * s[2][2]) as f32;
                let k = y * wd + x;
                if z <= self.depth[k] {
                    continue;
                }
                self.depth[k] = z;
                self.face[k] = face;
                self.bary[k] = [l[1] as f32, l[2] as f32];
                self.shade[k] = shade;
            }
        }
    }
}

/// Render `mesh` coloured per vertex (`colours`, one per vertex) from `view` into a `width × height` image:
/// [`Snapshot::take`] then [`Snapshot::paint_vertices`].
///
/// Cost: as [`Snapshot::take`].
pub fn render(mesh: &TriMesh, colours: &[[u8; 3]], view: &View, width: u32, height: u32) -> Image {
    Snapshot::take(mesh, view, width, height).paint_vertices(mesh, colours)
}

/// The object's projected extent scaled into the image, centred.
#[derive(Clone, Debug)]
struct Fit {
    scale: f64,
    centre: [f64; 2],
    half: [f64; 2],
}

impl Fit {
    fn of(p: &[V3], wd: usize, ht: usize) -> Option<Fit> {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for q in p {
            for k in 0..2 {
                lo[k] = lo[k].min(q[k]);
                hi[k] = hi[k].max(q[k]);
            }
        }
        let ext = [hi[0] - lo[0], hi[1] - lo[1]];
        if !(ext[0].is_finite() && ext[1].is_finite()) {
            return None;
        }
        let room = [wd as f64 * (1.0 - 2.0 * MARGIN), ht as f64 * (1.0 - 2.0 * MARGIN)];
        let scale = (room[0] / ext[0].max(1e-300)).min(room[1] / ext[1].max(1e-300));
        let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
        Some(Fit { scale, centre, half: [0.5 * wd as f64, 0.5 * ht as f64] })
    }

    /// Pixel coordinates (x right, y down) and depth (larger is nearer) of a projected point.
    fn screen(&self, q: V3) -> [f64; 3] {
        [self.half[0] + (q[0] - self.centre[0]) * self.scale, self.half[1] - (q[1] - self.centre[1]) * self.scale, q[2]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::icosphere;

    fn covered(img: &Image) -> usize {
        img.rgb.chunks(3).filter(|p| *p != BACKGROUND).count()
    }

    /// A unit sphere fills a disc of the fitted radius: 200 × 200 with 5 % margins is a radius of 90 pixels.
    #[test]
    fn a_sphere_is_a_disc_of_the_fitted_size() {
        let s = icosphere(1.0, 5, [0.0; 3]);
        let grey = vec![[200, 200, 200]; s.positions.len()];
        let img = render(&s, &grey, &View::front([0.0, 1.0, 0.0]), 200, 200);
        let want = std::f64::consts::PI * 90.0 * 90.0;
        let got = covered(&img) as f64;
        assert!((got / want - 1.0).abs() < 0.01, "{got} pixels, a disc of radius 90 has {want:.0}");
        assert_eq!(img.pixel(2, 2), BACKGROUND);
        let centre = img.pixel(100, 100);
        assert!(centre[0] > 150 && centre[0] == centre[1] && centre[1] == centre[2], "lit grey: {centre:?}");
    }

    /// A bump on the sphere's +x side shows at its projected column in the front view, and the side view
    /// sees it face on (the sphere's silhouette there stays a disc).
    #[test]
    fn a_bump_shows_where_it_is() {
        let mut s = icosphere(1.0, 4, [0.0; 3]);
        let tip = (0..s.positions.len()).max_by(|&a, &b| s.positions[a][0].total_cmp(&s.positions[b][0])).unwrap();
        s.positions[tip] = [1.5, s.positions[tip][1], s.positions[tip][2]];
        let grey = vec![[200, 200, 200]; s.positions.len()];
        let img = render(&s, &grey, &View::front([0.0, 1.0, 0.0]), 250, 200);
        // Extent x −1 … 1.5: scale min(225 / 2.5, 180 / 2) = 90, centre 0.25, so the tip (1.5, 0) projects to
        // (237.5, 100) and the sphere's own rim (x = 1) to column 192.5. The spike narrows to the tip: a pixel
        // centre is covered up to about 3 pixels short of it (the neighbours are 7 pixels off its axis).
        let (mut right, mut at_row) = (0, 0);
        for y in 0..200 {
            if let Some(x) = (0..250).rev().find(|&x| img.pixel(x, y) != BACKGROUND)
                && x > right
            {
                (right, at_row) = (x, y);
            }
        }
        assert!((229..=238).contains(&right), "the bump's tip at column {right}, expected 234-237 (rim at 192)");
        assert!(at_row.abs_diff(100) <= 2, "the bump's tip at row {at_row}, expected 100");
    }

    #[test]
    fn renders_repeat_to_the_byte_and_colours_follow_the_vertices() {
        let s = icosphere(1.0, 3, [0.0; 3]);
        let colours: Vec<[u8; 3]> =
            s.positions.iter().map(|p| if p[0] > 0.0 { [255, 0, 0] } else { [0, 0, 255] }).collect();
        for view in [
            View::front([0.0, 1.0, 0.0]),
            View::side([0.0, 1.0, 0.0]),
            View::top([0.0, 1.0, 0.0]),
            View::iso([0.0, 0.0, 1.0]),
        ] {
            let a = render(&s, &colours, &view, 120, 90);
            assert_eq!(a, render(&s, &colours, &view, 120, 90), "{view:?}");
            assert!(covered(&a) > 2000, "{view:?}: {} pixels", covered(&a));
        }
        let front = render(&s, &colours, &View::front([0.0, 1.0, 0.0]), 200, 200);
        let (left, right) = (front.pixel(40, 100), front.pixel(160, 100));
        assert!(left[2] > left[0] && right[0] > right[2], "blue left (−x), red right (+x): {left:?} {right:?}");
    }
}
