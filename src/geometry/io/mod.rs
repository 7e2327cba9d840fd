//! Readers and writers for the mesh and point-cloud formats of scanners and CAD tools.
//!
//! Readers stream from a buffered file (gzip is decompressed on the fly) and never trust a count from a
//! header: before any allocation a declared count is checked against the number of bytes the input can still
//! hold (for gzip, the deflate limit of 1032 output bytes per input byte) and against the memory budget.
//! Every error names the file and the line (text formats) or byte offset (binary formats).

pub mod e57;
mod obj;
mod off;
mod ply;
mod png;
pub mod scanset;
mod stl;
mod text;
mod view;
mod write;
mod xyz;

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

pub use png::{encode_png, write_png};
pub use write::{
    HashingFile, VertexAttributes, ensure_not_input, ensure_replaceable, write_atomic, write_obj, write_ply,
    write_ply_cloud,
};

use crate::error::{Error, ErrorCode, Location, Result};
use crate::geometry::mesh::{Geometry, PolyMesh};

/// Supported input formats.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Stanford PLY, ascii or binary (either endianness).
    Ply,
    /// Wavefront OBJ (polygons kept).
    Obj,
    /// STL, ascii or binary.
    Stl,
    /// Object File Format (OFF, COFF, NOFF, …).
    Off,
    /// Text point cloud: `x y z [nx ny nz]` per line (`.xyz`, `.pts`, `.txt`).
    Xyz,
}

/// Options common to all readers.
#[derive(Copy, Clone, Debug)]
pub struct ReadOptions {
    /// The most memory (bytes) a reader may allocate for the data it returns.
    pub memory_budget: u64,
    /// The most bytes a reader consumes: the file's size, or for gzip the decompressed size (the daemon's
    /// `limits.max_input_size`). Beyond it: `input.too-large`. Default 4 GiB.
    pub max_input_size: u64,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions { memory_budget: 8 << 30, max_input_size: DEFAULT_MAX_INPUT_SIZE }
    }
}

/// Default of [`ReadOptions::max_input_size`]: 4 GiB, as the daemon's `limits.max_input_size`.
pub const DEFAULT_MAX_INPUT_SIZE: u64 = 4 << 30;

/// Deflate cannot expand one input byte into more than 1032 output bytes.
const GZIP_MAX_RATIO: u64 = 1032;

/// Most decompressed bytes per compressed byte a gzip input may show once it has expanded past
/// [`GZIP_RATIO_GRACE`]: beyond it the input is `input.decompression-bomb`. Scans compress little
/// (measured 2026-12-05 with `gzip -9`: the shared dragon 3.1×, spot 2.0×, armadillo 1.5×; ASCII clouds
/// 3–8×), a run of zeros 1032×.
pub const GZIP_BOMB_RATIO: u64 = 100;

/// Decompressed bytes before [`GZIP_BOMB_RATIO`] is enforced (64 MiB), so that a small but very regular
/// file (a synthetic cube in ASCII) is never called a bomb.
pub const GZIP_RATIO_GRACE: u64 = 64 << 20;

/// Counts the bytes read from a source into a shared cell.
struct Counted<R> {
    inner: R,
    count: std::rc::Rc<std::cell::Cell<u64>>,
    /// The raw bytes' digest, when the caller asked for one ([`read_geometry_digest`]).
    hash: Option<std::rc::Rc<std::cell::RefCell<sha2::Sha256>>>,
}

impl<R: Read> Read for Counted<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.count.set(self.count.get() + n as u64);
        if let Some(h) = &self.hash {
            sha2::Digest::update(&mut *h.borrow_mut(), &buf[..n]);
        }
        Ok(n)
    }
}

/// A file's size and SHA-256, as [`read_geometry_digest`] measures them while reading it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FileDigest {
    /// Bytes in the file.
    pub bytes: u64,
    /// Its SHA-256, lower-case hex.
    pub sha256: String,
}

/// A gzip decoder that stops with an error once the output passes `max_input_size`, or passes
/// [`GZIP_RATIO_GRACE`] at more than [`GZIP_BOMB_RATIO`] times the compressed bytes read so far. The
/// error travels as `io::ErrorKind::Other` carrying the [`Error`] ([`io_err`] unwraps it).
struct GuardedGz<R: BufRead> {
    dec: flate2::bufread::MultiGzDecoder<R>,
    compressed: std::rc::Rc<std::cell::Cell<u64>>,
    out: u64,
    max: u64,
}

impl<R: BufRead> Read for GuardedGz<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.dec.read(buf)?;
        self.out += n as u64;
        let fail = |e: Error| Err(std::io::Error::other(e));
        if self.out > self.max {
            return fail(
                Error::new(
                    ErrorCode::InputTooLarge,
                    format!("the compressed input expands to more than {} bytes (the input size limit)", self.max),
                )
                .with_hint("raise limits.max_input_size (daemon) or decimate the scan"),
            );
        }
        let compressed = self.compressed.get().max(1);
        if self.out > GZIP_RATIO_GRACE && self.out / compressed > GZIP_BOMB_RATIO {
            return fail(
                Error::new(
                    ErrorCode::InputDecompressionBomb,
                    format!(
                        "{} compressed bytes expanded to {} bytes, more than {GZIP_BOMB_RATIO} times (scans compress \
                         about 2-8 times)",
                        compressed, self.out
                    ),
                )
                .with_hint("this is not a compressed scan; decompress it yourself if it really is one"),
            );
        }
        Ok(n)
    }
}

/// An open, decompressed input stream and what we know about its size.
pub(crate) struct Input<'a> {
    pub reader: Box<dyn BufRead + 'a>,
    /// An upper bound of the bytes the stream can still deliver.
    pub max_bytes: u64,
    pub options: ReadOptions,
}

impl Input<'_> {
    /// Check a declared element count before allocating for it, and return how many elements may be
    /// reserved up front.
    ///
    /// A count larger than the number of bytes left (`left`) cannot be true for any format and is
    /// `input.absurd-count`; `count × mem_bytes` beyond the budget is `resource.memory`. A count that
    /// is merely more than `left / min_bytes` may be a truncated file: the reservation is capped there and
    /// the reader reports `input.truncated` where the data actually ends.
    pub fn check_count(&self, left: u64, count: u64, min_bytes: u64, mem_bytes: u64, what: &str) -> Result<usize> {
        if count > left || count > u32::MAX as u64 {
            return Err(Error::new(
                ErrorCode::InputAbsurdCount,
                format!("{count} {what} declared, but only {left} bytes of data can follow"),
            ));
        }
        self.check_memory(count.saturating_mul(mem_bytes), what)?;
        Ok(count.min(left / min_bytes.max(1)) as usize)
    }

    /// Fail with `resource.memory` when `bytes` exceed the budget.
    pub fn check_memory(&self, bytes: u64, what: &str) -> Result<()> {
        if bytes > self.options.memory_budget {
            return Err(Error::new(
                ErrorCode::ResourceMemoryBudget,
                format!("{what} need {bytes} bytes; the memory budget is {} bytes", self.options.memory_budget),
            )
            .with_hint("raise the memory budget or decimate the input first"));
        }
        Ok(())
    }
}

/// Decide the format from the file name (ignoring a `.gz` suffix) or, failing that, from the first bytes.
pub fn detect_format(path: &Path, head: &[u8]) -> Result<Format> {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    let ext = name.rsplit_once('.').map(|(_, e)| e).unwrap_or("");
    match ext {
        "ply" => return Ok(Format::Ply),
        "obj" => return Ok(Format::Obj),
        "stl" => return Ok(Format::Stl),
        "off" => return Ok(Format::Off),
        "xyz" | "xyzn" | "pts" => return Ok(Format::Xyz),
        _ => {}
    }
    sniff_format(head).ok_or_else(|| {
        Error::new(ErrorCode::InputUnknownFormat, "neither the extension nor the content names a supported format")
            .with_hint("supported: .ply .obj .stl .off .xyz .pts (optionally .gz)")
    })
}

fn sniff_format(head: &[u8]) -> Option<Format> {
    let text = String::from_utf8_lossy(&head[..head.len().min(512)]);
    let first = text.lines().map(str::trim).find(|l| !l.is_empty() && !l.starts_with('#')).unwrap_or("");
    if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
        Some(Format::Ply)
    } else if first.ends_with("OFF") && first.len() <= 6 || first.starts_with("OFF ") {
        Some(Format::Off)
    } else if head.starts_with(b"solid") && text.contains("facet") {
        Some(Format::Stl)
    } else if text.lines().any(|l| l.starts_with("v ") || l.starts_with("f ")) {
        Some(Format::Obj)
    } else if !first.is_empty() && first.split_whitespace().all(|t| t.parse::<f64>().is_ok()) {
        Some(Format::Xyz)
    } else {
        None
    }
}

/// Read a mesh or point cloud from `path`, any supported format, optionally gzip-compressed.
///
/// # Errors
/// Stable codes `input.*` for bad data (naming the file and line/byte), `resource.memory` when the
/// declared data exceeds `options.memory_budget`. Cost: one pass over the file; memory ≈ the returned data.
pub fn read_geometry(path: &Path, options: &ReadOptions) -> Result<Geometry> {
    read_inner(path, options, None).map_err(|e| e.in_file(path))
}

/// [`read_geometry`], with the file's size and SHA-256 taken from the same read (the bytes after the data,
/// if any, are read for the digest too): a file is read once where it must be both parsed and hashed.
///
/// # Errors
/// As [`read_geometry`].
pub fn read_geometry_digest(path: &Path, options: &ReadOptions) -> Result<(Geometry, FileDigest)> {
    let hash = std::rc::Rc::new(std::cell::RefCell::new(<sha2::Sha256 as sha2::Digest>::new()));
    let geometry = read_inner(path, options, Some(hash.clone())).map_err(|e| e.in_file(path))?;
    let hash = std::rc::Rc::try_unwrap(hash).map_err(|_| Error::internal("the digest is still shared"))?;
    let sha256: String = sha2::Digest::finalize(hash.into_inner()).iter().map(|b| format!("{b:02x}")).collect();
    let bytes = std::fs::metadata(path).map_err(|e| Error::new(ErrorCode::InputIo, e.to_string()).in_file(path))?.len();
    Ok((geometry, FileDigest { bytes, sha256 }))
}

/// Read a file that must be a mesh (have faces).
///
/// # Errors
/// As [`read_geometry`]; `input.no-geometry` for a point cloud.
///
/// # Example
/// ```
/// use scanstation::geometry::io::{ReadOptions, read_mesh};
///
/// let path = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/spot.ply"));
/// let mesh = read_mesh(path, &ReadOptions::default())?;
/// assert!(mesh.face_count() > 1_000);
/// assert!(mesh.bbox().diagonal() > 0.0);
/// # Ok::<(), scanstation::Error>(())
/// ```
pub fn read_mesh(path: &Path, options: &ReadOptions) -> Result<PolyMesh> {
    match read_geometry(path, options)? {
        Geometry::Mesh(m) => Ok(m),
        Geometry::Cloud(_) => Err(Error::new(ErrorCode::InputNoGeometry, "the file has points but no faces")
            .in_file(path)
            .with_hint("this step needs a surface mesh; reconstruct one from the cloud first")),
    }
}

fn read_inner(
    path: &Path,
    options: &ReadOptions,
    hash: Option<std::rc::Rc<std::cell::RefCell<sha2::Sha256>>>,
) -> Result<Geometry> {
    let hashing = hash.is_some();
    let file = File::open(path).map_err(|e| {
        let code = if e.kind() == std::io::ErrorKind::NotFound { ErrorCode::InputNotFound } else { ErrorCode::InputIo };
        Error::new(code, format!("cannot open: {e}"))
    })?;
    let meta = file.metadata().map_err(|e| Error::new(ErrorCode::InputIo, e.to_string()))?;
    if meta.is_dir() {
        return Err(Error::new(ErrorCode::InputIo, "is a directory"));
    }
    let size = meta.len();
    if size == 0 {
        return Err(Error::new(ErrorCode::InputEmpty, "the file is empty"));
    }
    if size > options.max_input_size {
        return Err(Error::new(
            ErrorCode::InputTooLarge,
            format!("{size} bytes exceed the input size limit of {} bytes", options.max_input_size),
        ));
    }
    let compressed = std::rc::Rc::new(std::cell::Cell::new(0u64));
    let mut raw = BufReader::with_capacity(1 << 16, Counted { inner: file, count: compressed.clone(), hash });
    let gz = raw.fill_buf().map_err(io_err)?.starts_with(&[0x1f, 0x8b]);
    let (mut reader, max_bytes): (Box<dyn BufRead>, u64) = if gz {
        let dec = flate2::bufread::MultiGzDecoder::new(raw);
        let guarded = GuardedGz { dec, compressed, out: 0, max: options.max_input_size };
        let max_bytes = size.saturating_mul(GZIP_MAX_RATIO).min(options.max_input_size);
        (Box::new(BufReader::with_capacity(1 << 16, guarded)), max_bytes)
    } else {
        (Box::new(raw), size)
    };
    let head = reader.fill_buf().map_err(|e| io_err(e).at(Location::Byte(0)))?.to_vec();
    if head.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(Error::new(ErrorCode::InputEmpty, "the file holds no data"));
    }
    let format = detect_format(path, &head)?;
    let mut input = Input { reader, max_bytes, options: *options };
    let geometry = match format {
        Format::Ply => ply::read(&mut input),
        Format::Obj => obj::read(&mut input),
        Format::Stl => stl::read(&mut input, if gz { None } else { Some(size) }),
        Format::Off => off::read(&mut input),
        Format::Xyz => xyz::read(&mut input),
    }?;
    if hashing {
        // The digest covers the whole file: read what the parser left.
        std::io::copy(&mut input.reader, &mut std::io::sink()).map_err(io_err)?;
    }
    drop(input);
    if geometry.positions().is_empty() {
        return Err(Error::new(ErrorCode::InputNoGeometry, "the file holds no vertices"));
    }
    tracing::debug!(file = %path.display(), ?format, kind = geometry.kind(), vertices = geometry.positions().len(), "read");
    Ok(geometry)
}

/// Read a small text file (a spec, a sidecar, a config) of at most `max` bytes, reading no more than
/// `max + 1` bytes whatever the file is (a device such as `/dev/urandom`, a FIFO, a growing file).
///
/// # Errors
/// `input.not-found`/`input.io` when it cannot be read, `input.too-large` past `max` bytes, `input.bad-record`
/// when it is not UTF-8 text; each names the file and `what` it was read as.
pub fn read_small_text(path: &Path, max: u64, what: &str) -> Result<String> {
    let file = File::open(path).map_err(|e| {
        let code = if e.kind() == std::io::ErrorKind::NotFound { ErrorCode::InputNotFound } else { ErrorCode::InputIo };
        Error::new(code, format!("cannot open {what}: {e}")).in_file(path)
    })?;
    if file.metadata().is_ok_and(|m| m.is_dir()) {
        return Err(Error::new(ErrorCode::InputIo, format!("{what} is a directory")).in_file(path));
    }
    let mut bytes = Vec::new();
    file.take(max + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::new(ErrorCode::InputIo, format!("cannot read {what}: {e}")).in_file(path))?;
    if bytes.len() as u64 > max {
        return Err(Error::new(ErrorCode::InputTooLarge, format!("{what} is longer than {max} bytes")).in_file(path));
    }
    String::from_utf8(bytes).map_err(|e| {
        Error::new(ErrorCode::InputBadRecord, format!("{what} is not UTF-8 text"))
            .in_file(path)
            .at(Location::Byte(e.utf8_error().valid_up_to() as u64))
    })
}

/// Map an I/O error while reading: an unexpected end is `input.truncated`, invalid gzip data is
/// `input.truncated` too when the stream ends early, a guard's own error (size, bomb) is itself, anything
/// else `input.io`.
pub(crate) fn io_err(e: std::io::Error) -> Error {
    if e.get_ref().is_some_and(|inner| inner.is::<Error>()) {
        let inner = e.into_inner().expect("checked above");
        return *inner.downcast::<Error>().expect("checked above");
    }
    match e.kind() {
        std::io::ErrorKind::UnexpectedEof => Error::new(ErrorCode::InputTruncated, "the data ends early"),
        std::io::ErrorKind::InvalidData | std::io::ErrorKind::InvalidInput => {
            Error::new(ErrorCode::InputTruncated, format!("corrupt or truncated compressed data: {e}"))
        }
        _ => Error::new(ErrorCode::InputIo, format!("read error: {e}")),
    }
}

/// Read exactly `buf.len()` bytes at byte offset `*pos`, advancing it.
#[inline]
pub(crate) fn read_exact_at(r: &mut dyn Read, buf: &mut [u8], pos: &mut u64) -> Result<()> {
    r.read_exact(buf).map_err(|e| io_err(e).at(Location::Byte(*pos)))?;
    *pos += buf.len() as u64;
    Ok(())
}

/// Most bytes a binary file may carry after its declared data (padding some exporters add): 64 KiB. More
/// is not a scan's padding (a file of zeros behind a small header, a gzip bomb): `input.bad-record`.
pub const MAX_TRAILING_BYTES: u64 = 64 << 10;

/// Fail when more than [`MAX_TRAILING_BYTES`] follow the declared data, which ended at byte `pos`; reads at
/// most that many bytes more.
pub(crate) fn check_trailing(r: &mut dyn Read, pos: u64) -> Result<()> {
    let n = std::io::copy(&mut r.take(MAX_TRAILING_BYTES + 1), &mut std::io::sink())
        .map_err(|e| io_err(e).at(Location::Byte(pos)))?;
    if n > MAX_TRAILING_BYTES {
        return Err(Error::new(
            ErrorCode::InputBadRecord,
            format!("more than {MAX_TRAILING_BYTES} bytes follow the declared data, which ends here"),
        )
        .at(Location::Byte(pos))
        .with_hint("the header's counts do not describe this file"));
    }
    Ok(())
}

/// Finite-coordinate check used by every reader, with location.
#[inline]
pub(crate) fn finite_point(p: [f32; 3], what: impl FnOnce() -> String, loc: Location) -> Result<[f32; 3]> {
    if p.iter().all(|c| c.is_finite()) {
        Ok(p)
    } else {
        Err(Error::new(ErrorCode::InputNonFinite, format!("{} has a non-finite coordinate {p:?}", what())).at(loc))
    }
}
