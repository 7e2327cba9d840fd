//! A job's pictures (PNG): the deviation map, the quad net, the B-rep faces, the von Mises stress and a
//! scan's coverage on the solid, each from four views with its legend ([`sheet`]); the deviation histogram
//! and the convergence of the chain ([`plots`]); a 256 × 256 thumbnail. Made on the CPU from what the chain
//! holds, deterministic (the same job gives the same bytes with any thread count).
//!
//! Files beside the STEP file `NAME.step`: `NAME.deviation.png`, `NAME.net.png`, `NAME.faces.png`,
//! `NAME.histogram.png`, `NAME.convergence.png` (where the chain made more than one attempt),
//! `NAME.thumbnail.png`; `stress.png` in an FEA result directory; `NAME.coverage.png` for a scan.

pub mod maps;
pub mod plots;
pub mod sheet;

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::error::Result;
use crate::geometry::io::{FileDigest, write_png};
use crate::geometry::mesh::{PolyMesh, TriMesh};
use crate::geometry::raster::Image;
use crate::geometry::vec3::V3;
pub use maps::{Deviation, Stress};
pub use plots::AttemptPoint;
pub use sheet::Scene;

/// The thumbnail's side, pixels.
pub const THUMBNAIL: u32 = 256;

/// The object's up axis in the pictures (front, side and top views follow it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Up {
    /// +x up.
    X,
    /// +y up (the default: most scanned meshes are stored y-up).
    #[default]
    Y,
    /// +z up (a turntable's axis).
    Z,
}

impl Up {
    /// The axis as a unit vector.
    pub fn axis(self) -> V3 {
        match self {
            Up::X => [1.0, 0.0, 0.0],
            Up::Y => [0.0, 1.0, 0.0],
            Up::Z => [0.0, 0.0, 1.0],
        }
    }

    /// Parse `x`, `y` or `z`.
    pub fn parse(s: &str) -> Option<Up> {
        match s {
            "x" => Some(Up::X),
            "y" => Some(Up::Y),
            "z" => Some(Up::Z),
            _ => None,
        }
    }
}

/// One picture written.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Picture {
    /// `deviation`, `net`, `faces`, `histogram`, `convergence`, `thumbnail`, `stress` or `coverage`.
    pub kind: &'static str,
    /// The PNG file.
    pub file: PathBuf,
    /// Its size, bytes.
    pub bytes: u64,
    /// Its SHA-256.
    pub sha256: String,
}

impl Picture {
    /// The file's digest.
    pub fn digest(&self) -> FileDigest {
        FileDigest { bytes: self.bytes, sha256: self.sha256.clone() }
    }
}

/// `NAME.KIND.png` beside the STEP file `NAME.step`.
pub fn picture_path(step: &Path, kind: &str) -> PathBuf {
    step.with_extension(format!("{kind}.png"))
}

/// What the pictures of a conversion are made from.
pub struct ConvertPictures<'a> {
    /// The solid's tessellation.
    pub solid: &'a TriMesh,
    /// The B-rep face of each of its triangles.
    pub face_of: &'a [u32],
    /// Its deviation from the scan.
    pub deviation: Deviation<'a>,
    /// The quad control net.
    pub net: &'a PolyMesh,
    /// Every attempt of the chain.
    pub attempts: Vec<AttemptPoint>,
    /// The RMS gate's bound, % of the diagonal.
    pub rms_bound_pct: f64,
}

/// Write the pictures of a conversion beside `step` (see the module's docs), in a fixed order.
///
/// # Errors
/// `resource.output` when a file cannot be written.
///
/// Cost: four rasterisations of the solid (O(F) each), the paint passes (O(pixels)), PNG encoding.
pub fn write_convert_pictures(step: &Path, p: &ConvertPictures, up: Up) -> Result<Vec<Picture>> {
    let scene = Scene::new(p.solid, up.axis());
    let dev = &p.deviation;
    let slack = 0.01 * dev.diag;
    let colours = dev.colours();
    type Make<'b> = Box<dyn Fn() -> Image + Send + Sync + 'b>;
    let mut jobs: Vec<(&'static str, Make)> = vec![
        ("deviation", Box::new(|| maps::deviation_sheet(&scene, dev, &colours))),
        ("histogram", Box::new(|| plots::histogram(dev))),
        ("net", Box::new(|| maps::net_sheet(&scene, p.net, slack))),
        ("faces", Box::new(|| maps::faces_sheet(&scene, p.face_of))),
        ("thumbnail", Box::new(|| scene.thumbnail(THUMBNAIL, |s| maps::paint_deviation(s, &scene, dev, &colours)))),
    ];
    if p.attempts.len() > 1 {
        jobs.push(("convergence", Box::new(|| plots::convergence(&p.attempts, p.rms_bound_pct))));
    }
    jobs.par_iter()
        .map(|(kind, make)| write_picture(&picture_path(step, kind), kind, &make()))
        .collect::<Result<Vec<_>>>()
}

/// Write `image` as the picture `kind` at `path`.
///
/// # Errors
/// `resource.output` when the file cannot be written.
pub fn write_picture(path: &Path, kind: &'static str, image: &Image) -> Result<Picture> {
    let d = write_png(path, image)?;
    Ok(Picture { kind, file: path.to_path_buf(), bytes: d.bytes, sha256: d.sha256 })
}

/// Write the stress picture of an FEA result (`surface` with per-vertex von Mises, supports and loads
/// marked) at `path`.
///
/// # Errors
/// `resource.output` when the file cannot be written.
pub fn write_stress_picture(path: &Path, surface: &TriMesh, stress: &Stress, up: Up) -> Result<Picture> {
    let scene = Scene::new(surface, up.axis());
    write_picture(path, "stress", &maps::stress_sheet(&scene, stress))
}

/// Write a scan's coverage picture (`seen_by[v]`: how many of `views` saw vertex v of `solid`) at `path`.
///
/// # Errors
/// `resource.output` when the file cannot be written.
pub fn write_coverage_picture(path: &Path, solid: &TriMesh, seen_by: &[u16], views: u16, up: Up) -> Result<Picture> {
    let scene = Scene::new(solid, up.axis());
    write_picture(path, "coverage", &maps::coverage_sheet(&scene, seen_by, views))
}

#[cfg(test)]
mod tests {
    use super::sheet::{SHEET, panel_size};
    use super::*;
    use crate::geometry::raster::BACKGROUND;
    use crate::geometry::shapes::icosphere;
    use crate::stages::quality::{DEVIATION_INSIDE, DEVIATION_OUTSIDE, signed_vertex_distances};

    /// Whether `px` is `colour` times one shade (Lambert's factor, the same on every channel), to rounding.
    fn shaded(px: [u8; 3], colour: [u8; 3]) -> bool {
        // The shade from the brightest channel: the least rounding.
        let c = (0..3).max_by_key(|&c| colour[c]).unwrap_or(0);
        let k = f64::from(px[c]) / f64::from(colour[c]);
        (0..3).all(|c| (f64::from(px[c]) - k * f64::from(colour[c])).abs() <= 1.5)
    }

    /// The panels' covered pixels (not background, not a panel's name in its corner, not the rules).
    fn covered(sheet: &Image) -> Vec<(u32, u32)> {
        let (pw, ph) = panel_size();
        (0..2 * ph)
            .flat_map(|y| (0..SHEET.0).map(move |x| (x, y)))
            .filter(|&(x, y)| (x % pw) > 100 || (y % ph) > 30)
            .filter(|&(x, y)| x % pw != 0 && y % ph != 0)
            .filter(|&(x, y)| sheet.pixel(x, y) != BACKGROUND)
            .collect()
    }

    /// Acceptance: a sphere against a sphere 1 % larger is one colour everywhere, the scale's inside end
    /// (−1 %: every vertex is 1 % of the radius inside), in all four views.
    #[test]
    fn a_sphere_inside_one_1_percent_larger_is_the_inside_colour_everywhere() {
        let (small, large) = (icosphere(1.0, 5, [0.0; 3]), icosphere(1.01, 5, [0.0; 3]));
        let signed = signed_vertex_distances(&small, &large);
        assert!(signed.iter().all(|&d| (d + 0.01).abs() < 1e-4), "every vertex 0.01 inside");
        let diag = large.bbox().diagonal();
        let dev = Deviation { signed: &signed, invented: None, band: 0.001, diag, unit: "mm", far: &[] };
        let sheet = maps::deviation_sheet(&Scene::new(&small, Up::Y.axis()), &dev, &dev.colours());
        let px = covered(&sheet);
        assert!(px.len() > 4 * 40_000, "four discs: {} pixels", px.len());
        let off: Vec<_> = px.iter().filter(|&&(x, y)| !shaded(sheet.pixel(x, y), DEVIATION_INSIDE)).take(5).collect();
        assert!(
            off.is_empty(),
            "pixels not the inside colour: {:?}",
            off.iter().map(|&&(x, y)| ((x, y), sheet.pixel(x, y))).collect::<Vec<_>>()
        );
    }

    /// Acceptance: a bump of known size shows in the front view where it is: a sphere whose vertices above
    /// x > 0.8 are pushed out by 5 % of the radius, against the plain sphere, is red exactly there.
    #[test]
    fn a_bump_shows_red_at_its_place_in_the_front_view() {
        let plain = icosphere(1.0, 5, [0.0; 3]);
        let mut bumped = plain.clone();
        for p in &mut bumped.positions {
            if p[0] > 0.8 {
                *p = p.map(|c| c * 1.05);
            }
        }
        let signed = signed_vertex_distances(&bumped, &plain);
        let dev = Deviation { signed: &signed, invented: None, band: 0.002, diag: 3.46, unit: "mm", far: &[] };
        let sheet = maps::deviation_sheet(&Scene::new(&bumped, Up::Y.axis()), &dev, &dev.colours());
        // Front panel 512 × 336 with 5 % margins: x from −1.05 to 1.05 over 302.4 rows → scale 144 px/unit,
        // centred at column 256 (a sphere's extent is symmetric up to the bump's 0.05). The bump spans
        // x in (0.8, 1.05]: columns 256 + 144 · 0.8 ≈ 371 onward.
        let (pw, ph) = panel_size();
        let red: Vec<u32> = (0..pw)
            .filter(|&x| {
                let p = sheet.pixel(x, ph / 2);
                p != BACKGROUND && p[0] > p[2] + 40 && shaded(p, DEVIATION_OUTSIDE)
            })
            .collect();
        let (lo, hi) = (red.first().copied().unwrap_or(0), red.last().copied().unwrap_or(0));
        assert!((365..=380).contains(&lo), "the bump starts at column {lo}, expected about 371");
        assert!((400..=420).contains(&hi), "the bump ends at column {hi} (the rim at 256 + 144 · 1.05 = 407)");
        let left = sheet.pixel(150, ph / 2);
        assert!(left[0] <= left[2] + 40, "the other side is not red: {left:?}");
    }

    /// Acceptance: the same job gives byte-identical PNGs with 1 and 2 threads.
    #[test]
    fn pictures_are_the_same_bytes_with_one_and_two_threads() {
        let solid = icosphere(1.0, 4, [0.0; 3]);
        let reference = icosphere(1.003, 3, [0.01, 0.0, 0.0]);
        let signed = signed_vertex_distances(&solid, &reference);
        let face_of: Vec<u32> = (0..solid.triangles.len() as u32).map(|t| t / 40).collect();
        let net = PolyMesh::from(icosphere(1.0, 2, [0.0; 3]));
        let dir = std::env::temp_dir().join(format!("scanstation-pictures-{}", std::process::id()));
        let run = |threads: usize| -> Vec<(String, Vec<u8>)> {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let out = dir.join(format!("t{threads}"));
            std::fs::create_dir_all(&out).unwrap();
            let dev = Deviation { signed: &signed, invented: None, band: 0.001, diag: 3.46, unit: "mm", far: &[] };
            let attempts = vec![
                AttemptPoint { target_vertices: 5000, rms_pct: 0.09, rejected: true },
                AttemptPoint { target_vertices: 10000, rms_pct: 0.03, rejected: false },
            ];
            let p = ConvertPictures {
                solid: &solid,
                face_of: &face_of,
                deviation: dev,
                net: &net,
                attempts,
                rms_bound_pct: 0.05,
            };
            let pics = pool.install(|| write_convert_pictures(&out.join("s.step"), &p, Up::Z)).unwrap();
            pics.iter().map(|p| (p.kind.to_string(), std::fs::read(&p.file).unwrap())).collect()
        };
        let (one, two) = (run(1), run(2));
        let _ = std::fs::remove_dir_all(&dir);
        let kinds: Vec<&str> = one.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(kinds, ["deviation", "histogram", "net", "faces", "thumbnail", "convergence"]);
        for ((k, a), (_, b)) in one.iter().zip(&two) {
            assert!(a == b, "{k}: {} bytes with 1 thread, {} with 2, and they differ", a.len(), b.len());
            assert!(a.len() > 2000, "{k}: {} bytes", a.len());
        }
    }
}
