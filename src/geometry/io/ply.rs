//! PLY reader: ascii and binary (both endiannesses), any property order, any list count type, unknown
//! elements and properties skipped. `vertex` (x, y, z [nx ny nz] [red green blue]) and `face`
//! (`vertex_indices` or `vertex_index`) are kept; a file without faces is a point cloud.

use std::io::BufRead;

use crate::error::{Error, ErrorCode, Location, Result};
use crate::geometry::io::text::{Lines, parse_num};
use crate::geometry::io::{Input, finite_point, read_exact_at};
use crate::geometry::mesh::{Geometry, PointCloud, PolyMesh};

/// Longest header we accept; real headers are a few hundred bytes.
const MAX_HEADER_BYTES: u64 = 1 << 20;
/// Longest face we accept (vertices); larger lists are junk, not polygons.
const MAX_FACE_DEGREE: u64 = 1 << 16;

#[derive(Copy, Clone, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
    /// Decode from raw bytes in the file's byte order.
    #[inline]
    fn decode(self, b: &[u8], big: bool) -> f64 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().unwrap();
                (if big { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }) as f64
            }};
        }
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => get!(i16, 2),
            Scalar::U16 => get!(u16, 2),
            Scalar::I32 => get!(i32, 4),
            Scalar::U32 => get!(u32, 4),
            Scalar::F32 => get!(f32, 4),
            Scalar::F64 => get!(f64, 8),
        }
    }
}

#[derive(Clone, Debug)]
enum PropType {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    ty: PropType,
}

#[derive(Clone, Debug)]
struct Element {
    /// Header line that declares it.
    line: u64,
    name: String,
    count: u64,
    props: Vec<Property>,
}

impl Element {
    fn prop(&self, names: &[&str]) -> Option<usize> {
        self.props.iter().position(|p| names.contains(&p.name.as_str()))
    }
    /// Minimum stored bytes per element (lists empty): binary sizes, or 2 characters per value in ascii.
    fn min_bytes(&self, ascii: bool) -> u64 {
        self.props
            .iter()
            .map(|p| match (&p.ty, ascii) {
                (_, true) => 2,
                (PropType::Scalar(s), false) => s.size() as u64,
                (PropType::List { count, .. }, false) => count.size() as u64,
            })
            .sum()
    }
}

#[derive(Copy, Clone, Debug, PartialEq)]
enum Encoding {
    Ascii,
    BinaryLe,
    BinaryBe,
}

struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    /// Bytes and lines of the header, `end_header` included.
    bytes: u64,
    lines: u64,
}

fn bad_header(msg: impl Into<String>, line: u64) -> Error {
    Error::new(ErrorCode::InputBadHeader, msg).at(Location::Line(line))
}

fn read_header(lines: &mut Lines) -> Result<Header> {
    match lines.next_line()? {
        Some(("ply", _)) => {}
        _ => {
            return Err(bad_header("the file does not start with the line \"ply\"", 1));
        }
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        if lines.bytes > MAX_HEADER_BYTES {
            return Err(bad_header("no end_header within the first 1 MiB", lines.line));
        }
        let line_no = lines.line + 1;
        let Some((line, _)) = lines.next_line()? else {
            return Err(
                Error::new(ErrorCode::InputTruncated, "the header ends without end_header").at(Location::Line(line_no))
            );
        };
        let toks: Vec<&str> = line.split_whitespace().collect();
        match toks.as_slice() {
            [] => {}
            ["comment" | "obj_info", ..] => {}
            ["format", enc, _version] => {
                encoding = Some(match *enc {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLe,
                    "binary_big_endian" => Encoding::BinaryBe,
                    other => return Err(bad_header(format!("unknown format {other:?}"), line_no)),
                });
            }
            ["element", name, count] => {
                let count: u64 = count
                    .parse()
                    .map_err(|_| bad_header(format!("element {name}: count {count:?} is not a count"), line_no))?;
                elements.push(Element { line: line_no, name: name.to_string(), count, props: Vec::new() });
            }
            ["property", "list", ct, it, name] => {
                let el = elements.last_mut().ok_or_else(|| bad_header("property before any element", line_no))?;
                let (Some(count), Some(item)) = (Scalar::parse(ct), Scalar::parse(it)) else {
                    return Err(bad_header(format!("unknown list types {ct:?} {it:?}"), line_no));
                };
                if !count.is_integer() {
                    return Err(bad_header(format!("list count type {ct:?} is not an integer type"), line_no));
                }
                el.props.push(Property { name: name.to_string(), ty: PropType::List { count, item } });
            }
            ["property", ty, name] => {
                let el = elements.last_mut().ok_or_else(|| bad_header("property before any element", line_no))?;
                let s = Scalar::parse(ty).ok_or_else(|| bad_header(format!("unknown type {ty:?}"), line_no))?;
                el.props.push(Property { name: name.to_string(), ty: PropType::Scalar(s) });
            }
            ["end_header"] => break,
            _ => {
                return Err(bad_header(format!("cannot read header line {line:?}"), line_no));
            }
        }
    }
    let encoding = encoding.ok_or_else(|| bad_header("no format line", lines.line))?;
    Ok(Header { encoding, elements, bytes: lines.bytes, lines: lines.line })
}

/// Where the kept properties of the vertex element are.
struct VertexLayout {
    xyz: [usize; 3],
    normal: Option<[usize; 3]>,
    color: Option<[usize; 3]>,
}

fn vertex_layout(el: &Element) -> Result<VertexLayout> {
    let find = |n: &[&str]| el.prop(n).filter(|&i| matches!(el.props[i].ty, PropType::Scalar(_)));
    let xyz = match (find(&["x"]), find(&["y"]), find(&["z"])) {
        (Some(x), Some(y), Some(z)) => [x, y, z],
        _ => {
            return Err(Error::new(ErrorCode::InputBadHeader, "element vertex lacks scalar x, y, z properties"));
        }
    };
    let normal = match (find(&["nx"]), find(&["ny"]), find(&["nz"])) {
        (Some(x), Some(y), Some(z)) => Some([x, y, z]),
        _ => None,
    };
    let color = match (find(&["red", "r"]), find(&["green", "g"]), find(&["blue", "b"])) {
        (Some(x), Some(y), Some(z)) => Some([x, y, z]),
        _ => None,
    };
    Ok(VertexLayout { xyz, normal, color })
}

fn face_list(el: &Element) -> Result<usize> {
    let i = el
        .prop(&["vertex_indices", "vertex_index"])
        .ok_or_else(|| Error::new(ErrorCode::InputBadHeader, "element face lacks a vertex_indices list"))?;
    match el.props[i].ty {
        PropType::List { item, .. } if item.is_integer() => Ok(i),
        _ => Err(Error::new(ErrorCode::InputBadHeader, "face vertex_indices is not a list of integers")),
    }
}

/// Accumulates what we keep.
struct Sink {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    colors: Option<Vec<[u8; 3]>>,
    mesh: Option<PolyMesh>,
    face_buf: Vec<u32>,
}

/// Convert a decoded index value, rejecting negatives and non-integers.
#[inline]
fn to_index(v: f64, loc: Location) -> Result<u32> {
    if v >= 0.0 && v <= u32::MAX as f64 && v.fract() == 0.0 {
        Ok(v as u32)
    } else {
        Err(Error::new(ErrorCode::InputBadIndex, format!("face index {v} is negative or not an integer")).at(loc))
    }
}

fn color_u8(v: f64, ty: &PropType) -> u8 {
    match ty {
        PropType::Scalar(Scalar::F32 | Scalar::F64) => (v.clamp(0.0, 1.0) * 255.0).round() as u8,
        _ => v.clamp(0.0, 255.0) as u8,
    }
}

pub(crate) fn read(input: &mut Input) -> Result<Geometry> {
    let header = {
        let mut lines = Lines::new(&mut *input.reader);
        read_header(&mut lines)?
    };
    let ascii = header.encoding == Encoding::Ascii;
    // Check every declared count against the bytes that follow the header, before allocating anything.
    // (Each element alone is checked against all bytes left: a count that only the sum exceeds is left to
    // the reader, which reports `input.truncated` where the data ends.)
    let left = input.max_bytes.saturating_sub(header.bytes);
    let mut vertex_count = 0usize;
    let mut face_count = 0usize;
    for el in &header.elements {
        let min = el.min_bytes(ascii);
        let mem = match el.name.as_str() {
            "vertex" => 12 + 12 * vertex_layout(el).map(|l| l.normal.is_some() as u64).unwrap_or(0),
            "face" => 4 * 4,
            _ => 0,
        };
        let n = input
            .check_count(left, el.count, min, mem, &format!("{} elements", el.name))
            .map_err(|e| e.at(Location::Line(el.line)))?;
        match el.name.as_str() {
            "vertex" => vertex_count = n,
            "face" => face_count = n,
            _ => {}
        }
    }
    let vertex_el = header.elements.iter().find(|e| e.name == "vertex");
    let layout = vertex_el.map(vertex_layout).transpose()?;
    let has_faces = header.elements.iter().any(|e| e.name == "face" && e.count > 0);
    let mut sink = Sink {
        positions: Vec::with_capacity(vertex_count),
        normals: layout.as_ref().and_then(|l| l.normal).map(|_| Vec::with_capacity(vertex_count)),
        colors: layout.as_ref().and_then(|l| l.color).map(|_| Vec::with_capacity(vertex_count)),
        mesh: has_faces.then(|| PolyMesh::with_capacity(face_count, 3 * face_count)),
        face_buf: Vec::new(),
    };
    let mut pos = header.bytes;
    match header.encoding {
        Encoding::Ascii => read_ascii(input, &header, layout.as_ref(), &mut sink)?,
        Encoding::BinaryLe | Encoding::BinaryBe => {
            let big = header.encoding == Encoding::BinaryBe;
            for el in &header.elements {
                read_binary_element(&mut *input.reader, el, big, layout.as_ref(), &mut sink, &mut pos)?;
            }
            crate::geometry::io::check_trailing(&mut *input.reader, pos)?;
        }
    }
    finish(sink)
}

fn finish(sink: Sink) -> Result<Geometry> {
    match sink.mesh {
        Some(mut mesh) => {
            mesh.positions = sink.positions;
            mesh.validate()?;
            Ok(Geometry::Mesh(mesh))
        }
        None => Ok(Geometry::Cloud(PointCloud::new(sink.positions, sink.normals, sink.colors)?)),
    }
}

/// One vertex from decoded property values.
fn push_vertex(sink: &mut Sink, el: &Element, l: &VertexLayout, vals: &[f64], loc: Location) -> Result<()> {
    let i = sink.positions.len();
    let p = l.xyz.map(|k| vals[k] as f32);
    sink.positions.push(finite_point(p, || format!("vertex {i}"), loc)?);
    if let (Some(n), Some(out)) = (l.normal, sink.normals.as_mut()) {
        out.push(n.map(|k| vals[k] as f32));
    }
    if let (Some(c), Some(out)) = (l.color, sink.colors.as_mut()) {
        out.push([0, 1, 2].map(|j| color_u8(vals[c[j]], &el.props[c[j]].ty)));
    }
    Ok(())
}

fn push_face(sink: &mut Sink, loc: Location) -> Result<()> {
    if let Some(mesh) = sink.mesh.as_mut() {
        mesh.push_face_unchecked(&sink.face_buf).map_err(|e| e.at(loc))?;
    }
    Ok(())
}

fn read_binary_element(
    r: &mut dyn BufRead,
    el: &Element,
    big: bool,
    layout: Option<&VertexLayout>,
    sink: &mut Sink,
    pos: &mut u64,
) -> Result<()> {
    let is_vertex = el.name == "vertex";
    let face_prop = if el.name == "face" { Some(face_list(el)?) } else { None };
    let mut vals = vec![0f64; el.props.len()];
    let mut buf = [0u8; 8];
    let mut skip = Vec::new();
    if el.props.is_empty() {
        return Ok(()); // nothing is stored, however large the declared count
    }
    for _ in 0..el.count {
        let start = *pos;
        for (k, p) in el.props.iter().enumerate() {
            match p.ty {
                PropType::Scalar(s) => {
                    read_exact_at(r, &mut buf[..s.size()], pos)?;
                    vals[k] = s.decode(&buf, big);
                }
                PropType::List { count, item } => {
                    let at = *pos;
                    read_exact_at(r, &mut buf[..count.size()], pos)?;
                    let n = count.decode(&buf, big);
                    if !(0.0..=MAX_FACE_DEGREE as f64).contains(&n) {
                        return Err(Error::new(
                            ErrorCode::InputAbsurdCount,
                            format!("{}: list property {} has {n} items", el.name, p.name),
                        )
                        .at(Location::Byte(at)));
                    }
                    let n = n as usize;
                    if Some(k) == face_prop {
                        sink.face_buf.clear();
                        for _ in 0..n {
                            let at = *pos;
                            read_exact_at(r, &mut buf[..item.size()], pos)?;
                            sink.face_buf.push(to_index(item.decode(&buf, big), Location::Byte(at))?);
                        }
                    } else {
                        skip.resize(n * item.size(), 0);
                        read_exact_at(r, &mut skip, pos)?;
                    }
                }
            }
        }
        if is_vertex {
            push_vertex(sink, el, layout.expect("vertex layout"), &vals, Location::Byte(start))?;
        } else if face_prop.is_some() {
            push_face(sink, Location::Byte(start))?;
        }
    }
    Ok(())
}

fn read_ascii(input: &mut Input, header: &Header, layout: Option<&VertexLayout>, sink: &mut Sink) -> Result<()> {
    let mut lines = Lines::new(&mut *input.reader);
    lines.line = header.lines;
    for el in &header.elements {
        let is_vertex = el.name == "vertex";
        let face_prop = if el.name == "face" { Some(face_list(el)?) } else { None };
        let mut vals = vec![0f64; el.props.len()];
        let mut read = 0u64;
        while read < el.count {
            let line_no = lines.line + 1;
            let Some((line, loc)) = lines.next_line()? else {
                return Err(Error::new(
                    ErrorCode::InputTruncated,
                    format!("{} {} of {} declared are missing", el.count - read, el.name, el.count),
                )
                .at(Location::Line(line_no)));
            };
            let mut toks = line.split_whitespace().peekable();
            if toks.peek().is_none() {
                continue;
            }
            for (k, p) in el.props.iter().enumerate() {
                let mut next = |what: &str| {
                    toks.next().ok_or_else(|| {
                        Error::new(ErrorCode::InputBadRecord, format!("{}: missing {what}", el.name)).at(loc)
                    })
                };
                match p.ty {
                    PropType::Scalar(_) => vals[k] = parse_num::<f64>(next(&p.name)?, &p.name, loc)?,
                    PropType::List { .. } => {
                        let n: u64 = parse_num(next(&p.name)?, &p.name, loc)?;
                        if n > MAX_FACE_DEGREE {
                            return Err(Error::new(
                                ErrorCode::InputAbsurdCount,
                                format!("{}: list {} has {n} items", el.name, p.name),
                            )
                            .at(loc));
                        }
                        if Some(k) == face_prop {
                            sink.face_buf.clear();
                            for _ in 0..n {
                                let v: f64 = parse_num(next("index")?, "face index", loc)?;
                                sink.face_buf.push(to_index(v, loc)?);
                            }
                        } else {
                            for _ in 0..n {
                                next("list item")?;
                            }
                        }
                    }
                }
            }
            if toks.next().is_some() {
                return Err(
                    Error::new(ErrorCode::InputBadRecord, format!("{}: more values than properties", el.name)).at(loc)
                );
            }
            if is_vertex {
                push_vertex(sink, el, layout.expect("vertex layout"), &vals, loc)?;
            } else if face_prop.is_some() {
                push_face(sink, loc)?;
            }
            read += 1;
        }
    }
    Ok(())
}
