//! STL reader, ascii and binary. STL stores each triangle's corners separately; corners with bit-identical
//! coordinates are merged into one vertex so the result is an indexed mesh whose topology can be inspected.
//! (Welding *near*-coincident vertices is a repair step, not the reader's.)

use std::collections::HashMap;

use crate::error::{Error, ErrorCode, Location, Result};
use crate::geometry::io::text::{Lines, parse_xyz};
use crate::geometry::io::{Input, finite_point, read_exact_at};
use crate::geometry::mesh::{Geometry, PolyMesh};

/// Bytes of one binary STL triangle record.
const RECORD: u64 = 50;

/// Exact-position vertex merging.
#[derive(Default)]
struct Welder {
    map: HashMap<[u32; 3], u32>,
    positions: Vec<[f32; 3]>,
    corners: Vec<u32>,
}

impl Welder {
    fn push(&mut self, p: [f32; 3]) {
        let key = p.map(|c| if c == 0.0 { 0 } else { c.to_bits() });
        let next = self.positions.len() as u32;
        let id = *self.map.entry(key).or_insert(next);
        if id == next {
            self.positions.push(p);
        }
        self.corners.push(id);
    }
    fn finish(self) -> Result<Geometry> {
        let n = self.corners.len() / 3;
        let offsets = (0..=n as u32).map(|i| 3 * i).collect();
        Ok(Geometry::Mesh(PolyMesh::from_parts(self.positions, offsets, self.corners)?))
    }
}

pub(crate) fn read(input: &mut Input, file_size: Option<u64>) -> Result<Geometry> {
    let head = input.reader.fill_buf().map_err(crate::geometry::io::io_err)?;
    let looks_ascii = head.starts_with(b"solid") && {
        let text = String::from_utf8_lossy(&head[..head.len().min(1024)]);
        text.contains("facet") || text.contains("endsolid")
    };
    let binary_size_matches = file_size.is_some_and(|s| {
        s >= 84 && head.len() >= 84 && {
            let n = u32::from_le_bytes(head[80..84].try_into().unwrap()) as u64;
            s == 84 + RECORD * n
        }
    });
    if looks_ascii && !binary_size_matches { read_ascii(input) } else { read_binary(input) }
}

fn read_binary(input: &mut Input) -> Result<Geometry> {
    let mut pos = 0u64;
    let mut header = [0u8; 84];
    read_exact_at(&mut *input.reader, &mut header, &mut pos).map_err(|e| {
        Error::new(ErrorCode::InputTruncated, format!("binary STL shorter than its 84-byte header: {}", e.message))
            .at(Location::Byte(0))
    })?;
    let n = u32::from_le_bytes(header[80..84].try_into().unwrap()) as u64;
    let cap = input
        .check_count(input.max_bytes.saturating_sub(84), n, RECORD, 3 * 4 + 3 * 12, "triangles")
        .map_err(|e| e.at(Location::Byte(80)))?;
    let mut w = Welder { corners: Vec::with_capacity(3 * cap), ..Default::default() };
    let mut rec = [0u8; RECORD as usize];
    for t in 0..n {
        let at = pos;
        read_exact_at(&mut *input.reader, &mut rec, &mut pos)?;
        for k in 0..3 {
            let o = 12 + 12 * k;
            let c = |j: usize| f32::from_le_bytes(rec[o + 4 * j..o + 4 * j + 4].try_into().unwrap());
            w.push(finite_point([c(0), c(1), c(2)], || format!("triangle {t}"), Location::Byte(at))?);
        }
    }
    crate::geometry::io::check_trailing(&mut *input.reader, pos)?;
    w.finish()
}

fn read_ascii(input: &mut Input) -> Result<Geometry> {
    let budget = input.options.memory_budget;
    let mut w = Welder::default();
    let mut lines = Lines::new(&mut *input.reader);
    let mut in_loop = 0usize;
    while let Some((line, loc)) = lines.next_line()? {
        let mut toks = line.split_whitespace();
        match toks.next() {
            Some("vertex") => {
                let t = w.corners.len() / 3;
                let p = parse_xyz(&mut toks, "vertex", loc)?;
                w.push(finite_point(p, || format!("triangle {t}"), loc)?);
                in_loop += 1;
            }
            Some("outer") => in_loop = 0,
            Some("endloop") => {
                if in_loop != 3 {
                    return Err(Error::new(
                        ErrorCode::InputBadFace,
                        format!("a facet has {in_loop} vertices; STL facets have 3"),
                    )
                    .at(loc));
                }
            }
            _ => {}
        }
        if w.corners.len() % (3 << 16) == 0 && !w.corners.is_empty() {
            check_budget(&w, budget).map_err(|e| e.at(loc))?;
        }
    }
    if w.corners.len() % 3 != 0 {
        return Err(
            Error::new(ErrorCode::InputTruncated, "the last facet is incomplete").at(Location::Line(lines.line))
        );
    }
    if w.corners.is_empty() {
        return Err(Error::new(ErrorCode::InputNoGeometry, "no facets"));
    }
    w.finish()
}

fn check_budget(w: &Welder, budget: u64) -> Result<()> {
    let bytes = 4 * w.corners.len() as u64 + 28 * w.positions.len() as u64;
    if bytes > budget {
        return Err(Error::new(
            ErrorCode::ResourceMemoryBudget,
            format!("{bytes} bytes read so far exceed the memory budget of {budget} bytes"),
        ));
    }
    Ok(())
}
