//! Scan sets: several range scans (views), each with its pose (view frame → common frame, a [`Pose`]).
//!
//! Three ways to give one, all read by [`read_scan_set`]:
//!
//! 1. **A Stanford `.conf` file** (scanalyze):
//!    ```text
//!    camera tx ty tz qx qy qz qw      (ignored)
//!    bmesh FILE tx ty tz qx qy qz qw  (one view: its file, relative to the .conf, and its pose)
//!    ```
//!    A view's points go to the common frame as `R(q)ᵀ·p + t` (unit quaternion, scalar last): scanalyze
//!    stores the quaternion of the inverse rotation (checked on the Stanford bunny: with `R(q)ᵀ·p + t` 91 % of
//!    bun045's points lie within 1 mm of bun000's, with `R(q)·p + t` 0.3 %).
//! 2. **A `scanset.toml` manifest** ([`MANIFEST`]): one `[[view]]` table per view with its `file` and one pose
//!    form: `matrix` (4×4, row-major, view → common frame), `translation` + `quaternion` (`[x, y, z, w]`,
//!    the rotation itself: `R(q)·p + t`, unlike `.conf`), or `angle_deg`, a turntable angle about the
//!    `[axis]` table's `point` and `direction` (see [`Pose::turntable`]); optionally its `pass` (1, 2, …:
//!    the object turned over between passes, each pass's poses in its own frame, fusion finds the frames),
//!    and at the top `table_frame = true` when each pass's frame is its turntable's table frame (z up, the
//!    table top at z = 0). What the station's own scans write.
//! 3. **An E57 file** ([`super::e57`]): each point cloud a view, the scanner at its frame's origin.
//! 4. **A directory** holding one of them (`scanset.toml` first, else its only `.conf` file): what the daemon
//!    takes when a scan set is renamed into its inbox in one step.
//!
//! In every view's frame the scanner looks down −z: a surface it sees faces +z (Stanford's convention and the
//! station's). Errors name the line: a malformed pose or a duplicate view is `input.bad-record`, a missing
//! view file `input.not-found`, a set without views `input.no-geometry`.

use std::path::{Path, PathBuf};

use crate::error::{Error, ErrorCode, Location, Result};
use crate::geometry::io::{ReadOptions, read_geometry};
use crate::geometry::pose::Pose;
use crate::geometry::vec3::V3;

pub use super::view::{MAX_VIEWS, View, placed};

/// The manifest's file name inside a scan-set directory.
pub const MANIFEST: &str = "scanset.toml";

/// Most passes in one scan set (the object turned over between two).
pub const MAX_PASSES: u32 = 16;

/// Largest `.conf` or manifest file, bytes.
pub const MAX_CONF_BYTES: u64 = 1 << 20;

/// Whether `path` names a scan set: an E57 file, a `.conf` file, a manifest, or a directory holding either.
pub fn is_scan_set(path: &Path) -> bool {
    super::e57::is_e57(path) || is_conf(path) || is_manifest(path) || (path.is_dir() && manifest_in(path).is_ok())
}

fn is_conf(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("conf"))
}

fn is_manifest(path: &Path) -> bool {
    path.file_name().is_some_and(|n| n == MANIFEST)
}

/// The manifest a scan-set directory holds: `scanset.toml`, else its only `.conf` file.
///
/// # Errors
/// `input.no-geometry` for a directory with neither, `input.bad-record` for one with several `.conf` files.
pub fn manifest_in(dir: &Path) -> Result<PathBuf> {
    let toml = dir.join(MANIFEST);
    if toml.is_file() {
        return Ok(toml);
    }
    let mut confs: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::new(ErrorCode::InputIo, format!("cannot list the scan set: {e}")).in_file(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| is_conf(p) && p.is_file())
        .collect();
    confs.sort();
    match confs.len() {
        1 => Ok(confs.remove(0)),
        0 => Err(Error::new(
            ErrorCode::InputNoGeometry,
            format!("the directory holds no scan set: neither {MANIFEST} nor a .conf file"),
        )
        .in_file(dir)),
        n => Err(Error::new(ErrorCode::InputBadRecord, format!("the directory holds {n} .conf files; keep one"))
            .in_file(dir)),
    }
}

/// Read a scan set in any of its forms (see the module docs) and every view it lists, each within `options`.
///
/// # Errors
/// Those of [`read_conf`] and [`read_manifest`]; for a directory, those of [`manifest_in`].
pub fn read_scan_set(path: &Path, options: &ReadOptions) -> Result<Vec<View>> {
    if super::e57::is_e57(path) {
        return super::e57::read_e57(path, options);
    }
    let file = if path.is_dir() { manifest_in(path)? } else { path.to_path_buf() };
    if is_conf(&file) { read_conf(&file, options) } else { read_manifest(&file, options) }
}

/// Collects views, checking names, files and the view count.
struct Views<'a> {
    path: &'a Path,
    options: &'a ReadOptions,
    views: Vec<View>,
}

impl Views<'_> {
    fn push(&mut self, name: &str, pose: Pose, loc: Location) -> Result<()> {
        self.push_in(name, pose, (1, false), loc)
    }

    /// [`Views::push`] for a view of `pass`, in a table frame or not.
    fn push_in(&mut self, name: &str, pose: Pose, (pass, table_frame): (u32, bool), loc: Location) -> Result<()> {
        let bad = |m: String| Error::new(ErrorCode::InputBadRecord, m).in_file(self.path).at(loc);
        if self.views.len() >= MAX_VIEWS {
            return Err(bad(format!("more than {MAX_VIEWS} views")));
        }
        if self.views.iter().any(|v| v.name == name) {
            return Err(bad(format!("view {name} is listed twice")));
        }
        let rel = Path::new(name);
        if name.is_empty()
            || rel.is_absolute()
            || rel.components().any(|c| matches!(c, std::path::Component::ParentDir))
        {
            return Err(bad(format!("view file {name:?} must be a relative path inside the scan set's directory")));
        }
        let file = self.path.parent().unwrap_or(Path::new(".")).join(rel);
        if !file.is_file() {
            return Err(Error::new(ErrorCode::InputNotFound, format!("view {name} is missing: {}", file.display()))
                .in_file(self.path)
                .at(loc));
        }
        let points = read_geometry(&file, self.options)?.positions().to_vec();
        self.views.push(View {
            name: name.to_string(),
            file,
            pose,
            point_count: points.len(),
            points,
            scanner: None,
            pass,
            table_frame,
        });
        Ok(())
    }

    fn finish(self) -> Result<Vec<View>> {
        if self.views.is_empty() {
            return Err(Error::new(ErrorCode::InputNoGeometry, "the scan set lists no views").in_file(self.path));
        }
        Ok(self.views)
    }
}

/// Read a Stanford `.conf` scan set and every view it lists (each within `options`).
///
/// # Errors
/// `input.bad-record` for a malformed line, a pose that is not finite or whose quaternion is not of unit
/// length (within 1 %), or a view listed twice; `input.not-found` for a missing view file (named); the
/// readers' errors for a view; `input.no-geometry` for a set without views.
pub fn read_conf(path: &Path, options: &ReadOptions) -> Result<Vec<View>> {
    let text = super::read_small_text(path, MAX_CONF_BYTES, "the scan set")?;
    let mut views = Views { path, options, views: Vec::new() };
    for (k, line) in text.lines().enumerate() {
        let loc = Location::Line(k as u64 + 1);
        let bad = |m: String| Error::new(ErrorCode::InputBadRecord, m).in_file(path).at(loc);
        let toks: Vec<&str> = line.split_whitespace().collect();
        match toks.first() {
            None | Some(&"camera") => continue,
            Some(t) if t.starts_with('#') => continue,
            Some(&"bmesh") => {}
            Some(other) => {
                return Err(bad(format!("unknown entry {other:?}; expected `bmesh FILE tx ty tz qx qy qz qw`")));
            }
        }
        if toks.len() != 9 {
            return Err(bad(format!(
                "{} values; `bmesh FILE tx ty tz qx qy qz qw` has 8 after the keyword",
                toks.len() - 1
            )));
        }
        let nums: Vec<f64> = toks[2..]
            .iter()
            .map(|t| t.parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<Vec<f64>>>()
            .ok_or_else(|| bad("the pose has a value that is not a finite number".into()))?;
        // scanalyze's quaternion is the inverse rotation's: its conjugate gives R(q)ᵀ.
        let pose =
            Pose::from_quaternion([nums[0], nums[1], nums[2]], [-nums[3], -nums[4], -nums[5], nums[6]]).map_err(bad)?;
        views.push(toks[1], pose, loc)?;
    }
    views.finish()
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    axis: Option<Axis>,
    /// Each pass's common frame is its turntable's table frame (z up, the table top at z = 0).
    #[serde(default)]
    table_frame: bool,
    #[serde(default)]
    view: Vec<ManifestView>,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Axis {
    point: V3,
    direction: V3,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestView {
    file: String,
    matrix: Option<[[f64; 4]; 4]>,
    translation: Option<V3>,
    quaternion: Option<[f64; 4]>,
    angle_deg: Option<f64>,
    /// The view's pass (1 when not given).
    pass: Option<u32>,
}

/// Read a `scanset.toml` manifest (see the module docs) and every view it lists.
///
/// # Errors
/// `input.bad-record` for TOML that does not parse or has unknown keys (with its line), a view with no pose
/// or more than one form of pose, a turntable angle without an `[axis]`, a pose refused by [`Pose`]'s
/// constructors, or a view listed twice; `input.not-found` for a missing view file; the readers' errors for a
/// view; `input.no-geometry` for a manifest without views.
pub fn read_manifest(path: &Path, options: &ReadOptions) -> Result<Vec<View>> {
    let text = super::read_small_text(path, MAX_CONF_BYTES, "the scan set")?;
    let line_of = |offset: usize| Location::Line(text[..offset.min(text.len())].matches('\n').count() as u64 + 1);
    let manifest: Manifest = toml::from_str(&text).map_err(|e| {
        let err = Error::new(ErrorCode::InputBadRecord, format!("the manifest: {}", e.message())).in_file(path);
        match e.span() {
            Some(s) => err.at(line_of(s.start)),
            None => err,
        }
    })?;
    // Lines of the `[[view]]` headers, to name the view's line in errors.
    let headers: Vec<usize> = text.match_indices("[[view]]").map(|(i, _)| i).collect();
    let mut views = Views { path, options, views: Vec::new() };
    for (k, v) in manifest.view.iter().enumerate() {
        let loc = headers.get(k).map_or(Location::Line(1), |&o| line_of(o));
        let bad =
            |m: String| Error::new(ErrorCode::InputBadRecord, format!("view {}: {m}", v.file)).in_file(path).at(loc);
        let forms = [v.matrix.is_some(), v.translation.is_some() || v.quaternion.is_some(), v.angle_deg.is_some()];
        match forms.iter().filter(|f| **f).count() {
            0 => return Err(bad("no pose: give `matrix`, `translation` + `quaternion`, or `angle_deg`".into())),
            1 => {}
            _ => return Err(bad("more than one form of pose; give one".into())),
        }
        let pose = if let Some(m) = v.matrix {
            Pose::from_matrix(m)
        } else if let Some(angle) = v.angle_deg {
            match &manifest.axis {
                Some(a) => Pose::turntable(a.point, a.direction, angle),
                None => Err("a turntable angle needs the `[axis]` table (point, direction)".into()),
            }
        } else {
            match (v.translation, v.quaternion) {
                (Some(t), Some(q)) => Pose::from_quaternion(t, q),
                _ => Err("`translation` and `quaternion` go together".into()),
            }
        }
        .map_err(bad)?;
        let pass = v.pass.unwrap_or(1);
        if !(1..=MAX_PASSES).contains(&pass) {
            return Err(bad(format!("pass {pass} is outside 1..={MAX_PASSES}")));
        }
        views.push_in(&v.file, pose, (pass, manifest.table_frame), loc)?;
    }
    let passes: std::collections::BTreeSet<u32> = views.views.iter().map(|v| v.pass).collect();
    if let Some(missing) = (1..=passes.last().copied().unwrap_or(0)).find(|p| !passes.contains(p)) {
        return Err(Error::new(
            ErrorCode::InputBadRecord,
            format!("pass {missing} has no view, but a later pass has: passes are numbered 1, 2, … in order"),
        )
        .in_file(path));
    }
    views.finish()
}

/// Write a `scanset.toml` manifest for `views` (file names relative to the manifest, poses as matrices).
///
/// # Errors
/// `resource.output` when the file cannot be written.
pub fn write_manifest(path: &Path, views: &[(String, Pose)]) -> Result<()> {
    let listed: Vec<(String, Pose, u32)> = views.iter().map(|(n, p)| (n.clone(), *p, 1)).collect();
    write_manifest_passes(path, &listed, false)
}

/// [`write_manifest`] for views of several passes (`(file, pose within its pass, pass)`), each pass's
/// common frame a table frame when `table_frame` (the station's scans).
///
/// # Errors
/// `resource.output` when the file cannot be written.
pub fn write_manifest_passes(path: &Path, views: &[(String, Pose, u32)], table_frame: bool) -> Result<()> {
    let mut s = String::from("# scan set: one [[view]] per range scan, its pose view frame -> common frame\n");
    if table_frame {
        s += "# each pass's common frame is its table frame: z up the axis, the table top at z = 0\ntable_frame = true\n";
    }
    for (name, pose, pass) in views {
        let r = &pose.rotation;
        let t = pose.translation;
        s += &format!("\n[[view]]\nfile = {}\n", toml_string(name));
        if *pass != 1 {
            s += &format!("pass = {pass}\n");
        }
        s += "matrix = [\n";
        for i in 0..3 {
            s += &format!("  [{:?}, {:?}, {:?}, {:?}],\n", r[i][0], r[i][1], r[i][2], t[i]);
        }
        s += "  [0.0, 0.0, 0.0, 1.0],\n]\n";
    }
    super::write::write_atomic(path, |w| std::io::Write::write_all(w, s.as_bytes())).map(|_| ())
}

fn toml_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out += "\\\"",
            '\\' => out += "\\\\",
            c if c.is_control() => out += &format!("\\u{:04X}", c as u32),
            c => out.push(c),
        }
    }
    out + "\""
}
