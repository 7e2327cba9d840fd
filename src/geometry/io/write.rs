//! Writers: binary PLY (mesh or cloud, optional per-vertex colour and scalar) and OBJ with polygons.
//!
//! Every writer writes to a temporary file beside the target and renames it into place, so a reader never
//! sees a half-written file and a failed write leaves any previous file intact. Writing onto one of the
//! inputs is refused.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::FileDigest;
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::mesh::{PointCloud, PolyMesh};

/// Optional per-vertex attributes for PLY output.
#[derive(Clone, Copy, Debug, Default)]
pub struct VertexAttributes<'a> {
    /// 8-bit RGB colour per vertex (`red green blue` uchar properties).
    pub colors: Option<&'a [[u8; 3]]>,
    /// A named float scalar per vertex (e.g. `distance`; MeshLab shows a property named `quality`).
    pub scalar: Option<(&'a str, &'a [f32])>,
    /// Unit normals per vertex.
    pub normals: Option<&'a [[f32; 3]]>,
}

fn out_err(path: &Path, e: std::io::Error) -> Error {
    Error::new(ErrorCode::ResourceOutput, format!("cannot write: {e}")).in_file(path)
}

/// Refuse to write `out` when it is one of `inputs`: the same file (device and inode, so through hard and
/// symbolic links too) or, for paths that do not exist yet, the same name in the same directory.
///
/// # Errors
/// `resource.output` naming the path it clashes with.
pub fn ensure_not_input(out: &Path, inputs: &[&Path]) -> Result<()> {
    use std::os::unix::fs::MetadataExt;
    let id = |p: &Path| std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
    // The directory resolved, the name kept: equal for two spellings of one path, existing or not.
    let name = |p: &Path| {
        let dir = p.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        std::fs::canonicalize(dir).ok().zip(p.file_name().map(|n| n.to_os_string())).map(|(d, n)| d.join(n))
    };
    let (out_id, out_name) = (id(out), name(out));
    for i in inputs {
        let same_file = out_id.is_some() && out_id == id(i);
        let same_name = out_name.is_some() && out_name == name(i);
        if same_file || same_name {
            return Err(Error::new(
                ErrorCode::ResourceOutput,
                format!("refusing to write over {}, which this run reads or writes", i.display()),
            )
            .in_file(out)
            .with_hint("choose another output path"));
        }
    }
    Ok(())
}

/// Refuse an output path that names a device, a FIFO, a socket or a directory: an atomic write would replace
/// it with a regular file. A missing path or a regular file (or a link to one) is fine. Callers that work
/// long before they write check it first.
///
/// # Errors
/// `resource.output` naming the path.
pub fn ensure_replaceable(path: &Path) -> Result<()> {
    match std::fs::metadata(path) {
        Ok(m) if !m.is_file() => {
            Err(Error::new(ErrorCode::ResourceOutput, "refusing to replace a device, FIFO, socket or directory")
                .in_file(path)
                .with_hint("write to a regular file's path"))
        }
        _ => Ok(()),
    }
}

/// A file being written, its SHA-256 and size taken from the bytes as they pass (so that nothing reads a
/// written file back to hash it).
pub struct HashingFile {
    file: File,
    hash: sha2::Sha256,
    bytes: u64,
}

impl Write for HashingFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.file.write(buf)?;
        sha2::Digest::update(&mut self.hash, &buf[..n]);
        self.bytes += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

/// Write through a temporary file in the same directory (created if missing), fsync, then rename onto `path`.
/// Returns the file's size and SHA-256, taken while writing.
///
/// # Errors
/// `resource.output` when writing or renaming fails (the temporary file is removed), or when `path` is a
/// device, a FIFO, a socket or a directory (the rename would replace it with a regular file: run as root,
/// `-o /dev/null` would replace the system's `/dev/null`); `input.bad-argument` for a path without a file
/// name.
pub fn write_atomic(
    path: &Path,
    body: impl FnOnce(&mut BufWriter<HashingFile>) -> std::io::Result<()>,
) -> Result<FileDigest> {
    ensure_replaceable(path)?;
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name =
        path.file_name().ok_or_else(|| Error::new(ErrorCode::InputBadArgument, "output path has no file name"))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".{}.tmp", std::process::id()));
    let tmp: PathBuf = dir.join(tmp_name);
    let result = (|| {
        std::fs::create_dir_all(dir)?;
        let file = HashingFile { file: File::create(&tmp)?, hash: <sha2::Sha256 as sha2::Digest>::new(), bytes: 0 };
        let mut w = BufWriter::with_capacity(1 << 16, file);
        body(&mut w)?;
        let f = w.into_inner().map_err(|e| e.into_error())?;
        f.file.sync_all()?;
        std::fs::rename(&tmp, path)?;
        let sha256 = sha2::Digest::finalize(f.hash).iter().map(|b| format!("{b:02x}")).collect();
        Ok(FileDigest { bytes: f.bytes, sha256 })
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        out_err(path, e)
    })
}

fn check_len(what: &str, len: usize, n: usize) -> Result<()> {
    if len != n {
        return Err(Error::new(ErrorCode::InputBadArgument, format!("{what}: {len} values for {n} vertices")));
    }
    Ok(())
}

fn ply_header(
    w: &mut impl Write,
    n: usize,
    attrs: &VertexAttributes,
    faces: Option<usize>,
    comments: &[&str],
) -> std::io::Result<()> {
    writeln!(w, "ply\nformat binary_little_endian 1.0\ncomment written by scanstation {}", env!("CARGO_PKG_VERSION"))?;
    for c in comments {
        writeln!(w, "comment {}", c.replace('\n', " "))?;
    }
    writeln!(w, "element vertex {n}\nproperty float x\nproperty float y\nproperty float z")?;
    if attrs.normals.is_some() {
        writeln!(w, "property float nx\nproperty float ny\nproperty float nz")?;
    }
    if attrs.colors.is_some() {
        writeln!(w, "property uchar red\nproperty uchar green\nproperty uchar blue")?;
    }
    if let Some((name, _)) = attrs.scalar {
        writeln!(w, "property float {name}")?;
    }
    if let Some(f) = faces {
        writeln!(w, "element face {f}\nproperty list uchar int vertex_indices")?;
    }
    writeln!(w, "end_header")
}

fn ply_vertices(w: &mut impl Write, positions: &[[f32; 3]], attrs: &VertexAttributes) -> std::io::Result<()> {
    for (i, p) in positions.iter().enumerate() {
        for c in p {
            w.write_all(&c.to_le_bytes())?;
        }
        if let Some(n) = attrs.normals {
            for c in n[i] {
                w.write_all(&c.to_le_bytes())?;
            }
        }
        if let Some(c) = attrs.colors {
            w.write_all(&c[i])?;
        }
        if let Some((_, s)) = attrs.scalar {
            w.write_all(&s[i].to_le_bytes())?;
        }
    }
    Ok(())
}

fn check_attrs(attrs: &VertexAttributes, n: usize) -> Result<()> {
    if let Some(c) = attrs.colors {
        check_len("colors", c.len(), n)?;
    }
    if let Some((name, s)) = attrs.scalar {
        check_len(name, s.len(), n)?;
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(Error::new(ErrorCode::InputBadArgument, format!("bad PLY property name {name:?}")));
        }
    }
    if let Some(nr) = attrs.normals {
        check_len("normals", nr.len(), n)?;
    }
    Ok(())
}

/// Write a mesh as binary little-endian PLY (`property list uchar int vertex_indices`), with optional
/// per-vertex attributes and header comments.
///
/// # Errors
/// `input.bad-argument` (attribute length mismatch, face of more than 255 vertices), `resource.output`.
pub fn write_ply(path: &Path, mesh: &PolyMesh, attrs: &VertexAttributes, comments: &[&str]) -> Result<FileDigest> {
    let n = mesh.positions.len();
    check_attrs(attrs, n)?;
    if mesh.faces().any(|f| f.len() > 255) {
        return Err(Error::new(ErrorCode::InputBadArgument, "a face has more than 255 vertices"));
    }
    write_atomic(path, |w| {
        ply_header(w, n, attrs, Some(mesh.face_count()), comments)?;
        ply_vertices(w, &mesh.positions, attrs)?;
        for f in mesh.faces() {
            w.write_all(&[f.len() as u8])?;
            for &i in f {
                w.write_all(&(i as i32).to_le_bytes())?;
            }
        }
        Ok(())
    })
}

/// Write a point cloud as binary PLY (with its normals and colours, or the ones in `attrs`).
///
/// # Errors
/// As [`write_ply`].
pub fn write_ply_cloud(
    path: &Path,
    cloud: &PointCloud,
    attrs: &VertexAttributes,
    comments: &[&str],
) -> Result<FileDigest> {
    let attrs = VertexAttributes {
        normals: attrs.normals.or(cloud.normals.as_deref()),
        colors: attrs.colors.or(cloud.colors.as_deref()),
        scalar: attrs.scalar,
    };
    check_attrs(&attrs, cloud.positions.len())?;
    write_atomic(path, |w| {
        ply_header(w, cloud.positions.len(), &attrs, None, comments)?;
        ply_vertices(w, &cloud.positions, &attrs)
    })
}

/// Write a polygon mesh as OBJ, faces kept as they are (quads stay quads). Coordinates use the shortest
/// decimal form that reads back to the same f32.
///
/// # Errors
/// `resource.output`.
pub fn write_obj(path: &Path, mesh: &PolyMesh) -> Result<FileDigest> {
    write_atomic(path, |w| {
        writeln!(w, "# written by scanstation {}", env!("CARGO_PKG_VERSION"))?;
        writeln!(w, "# {} vertices, {} faces", mesh.positions.len(), mesh.face_count())?;
        for p in &mesh.positions {
            writeln!(w, "v {} {} {}", p[0], p[1], p[2])?;
        }
        let mut line = String::new();
        for f in mesh.faces() {
            line.clear();
            line.push('f');
            for &i in f {
                line.push(' ');
                line.push_str(&(i + 1).to_string());
            }
            writeln!(w, "{line}")?;
        }
        Ok(())
    })
}
