//! OFF reader (`OFF`, `COFF`, `NOFF`, `CNOFF`, …): counts line, vertex lines (extra values such as colours
//! ignored), face lines `n i1 … in [colour]`. `#` comments and blank lines skipped. No faces: a point cloud.

use crate::error::{Error, ErrorCode, Location, Result};
use crate::geometry::io::text::{Lines, parse_num, parse_xyz};
use crate::geometry::io::{Input, finite_point};
use crate::geometry::mesh::{Geometry, PointCloud, PolyMesh};

/// Next non-blank line with `#` comments removed, and its location.
fn content<'l>(lines: &'l mut Lines) -> Result<Option<(&'l str, Location)>> {
    loop {
        let Some((line, _)) = lines.next_line()? else {
            return Ok(None);
        };
        if !line.split('#').next().unwrap_or("").trim().is_empty() {
            break;
        }
    }
    let loc = Location::Line(lines.line);
    Ok(Some((lines.current().split('#').next().unwrap_or("").trim(), loc)))
}

pub(crate) fn read(input: &mut Input) -> Result<Geometry> {
    let max_bytes = input.max_bytes;
    let mut reader = std::mem::replace(&mut input.reader, Box::new(std::io::empty()));
    let mut lines = Lines::new(&mut *reader);
    let Some((first, loc)) = content(&mut lines)? else {
        return Err(Error::new(ErrorCode::InputEmpty, "no OFF header"));
    };
    let mut toks = first.split_whitespace();
    let keyword = toks.next().unwrap_or("");
    if !keyword.ends_with("OFF") {
        return Err(Error::new(ErrorCode::InputBadHeader, format!("expected OFF, found {keyword:?}")).at(loc));
    }
    let mut counts: Vec<&str> = toks.collect();
    let mut count_loc = loc;
    if counts.is_empty() {
        let Some((l, loc)) = content(&mut lines)? else {
            return Err(Error::new(ErrorCode::InputTruncated, "no counts line").at(loc));
        };
        counts = l.split_whitespace().collect();
        count_loc = loc;
    }
    if counts.len() < 2 {
        return Err(Error::new(ErrorCode::InputBadHeader, "counts line needs vertex and face counts").at(count_loc));
    }
    let nv: u64 = parse_num(counts[0], "vertex count", count_loc)?;
    let nf: u64 = parse_num(counts[1], "face count", count_loc)?;
    let left = max_bytes.saturating_sub(lines.bytes);
    let nv_cap = input.check_count(left, nv, 6, 12, "vertices").map_err(|e| e.at(count_loc))?;
    let nf_cap = input.check_count(left, nf, 8, 16, "faces").map_err(|e| e.at(count_loc))?;
    let mut positions = Vec::with_capacity(nv_cap);
    for i in 0..nv {
        let Some((l, loc)) = content(&mut lines)? else {
            return Err(Error::new(ErrorCode::InputTruncated, format!("only {i} of {nv} vertices"))
                .at(Location::Line(lines.line + 1)));
        };
        let p = parse_xyz(&mut l.split_whitespace(), "vertex", loc)?;
        positions.push(finite_point(p, || format!("vertex {i}"), loc)?);
    }
    if nf == 0 {
        return Ok(Geometry::Cloud(PointCloud::new(positions, None, None)?));
    }
    let mut mesh = PolyMesh::with_capacity(nf_cap, 3 * nf_cap);
    let mut face = Vec::new();
    for i in 0..nf {
        let Some((l, loc)) = content(&mut lines)? else {
            return Err(Error::new(ErrorCode::InputTruncated, format!("only {i} of {nf} faces"))
                .at(Location::Line(lines.line + 1)));
        };
        let mut toks = l.split_whitespace();
        let n: usize = parse_num(toks.next().unwrap_or(""), "face size", loc)?;
        face.clear();
        for _ in 0..n {
            let tok = toks.next().ok_or_else(|| {
                Error::new(ErrorCode::InputBadRecord, format!("face {i} declares {n} vertices but lists fewer")).at(loc)
            })?;
            let v: i64 = parse_num(tok, "face index", loc)?;
            if v < 0 || v as u64 >= nv {
                return Err(Error::new(ErrorCode::InputBadIndex, format!("face {i}: index {v} not in 0..{nv}")).at(loc));
            }
            face.push(v as u32);
        }
        mesh.push_face_unchecked(&face).map_err(|e| e.at(loc))?;
    }
    mesh.positions = positions;
    mesh.validate()?;
    Ok(Geometry::Mesh(mesh))
}
