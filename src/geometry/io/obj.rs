//! Wavefront OBJ reader: `v` positions and `f` polygons (kept, not triangulated; `v/t/n` and negative
//! relative indices accepted). Everything else (`vt`, `vn`, groups, materials, lines) is skipped. A file
//! without faces is a point cloud.

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::Input;
use crate::geometry::io::finite_point;
use crate::geometry::io::text::{Lines, parse_num, parse_xyz};
use crate::geometry::mesh::{Geometry, PointCloud, PolyMesh};

/// Records between memory-budget checks.
const BUDGET_CHECK_EVERY: usize = 1 << 16;

pub(crate) fn read(input: &mut Input) -> Result<Geometry> {
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut mesh = PolyMesh::default();
    let mut face = Vec::new();
    let mut records = 0usize;
    let mut reader = std::mem::replace(&mut input.reader, Box::new(std::io::empty()));
    let mut lines = Lines::new(&mut *reader);
    let check =
        |v: usize, c: usize| input.check_memory(12 * v as u64 + 4 * c as u64, "the vertices and faces read so far");
    while let Some((line, loc)) = lines.next_line()? {
        let mut toks = line.split_whitespace();
        match toks.next() {
            Some("v") => {
                let i = positions.len();
                let p = parse_xyz(&mut toks, "vertex", loc)?;
                positions.push(finite_point(p, || format!("vertex {}", i + 1), loc)?);
            }
            Some("f") => {
                face.clear();
                for tok in toks {
                    let first = tok.split('/').next().unwrap_or("");
                    let i: i64 = parse_num(first, "face index", loc)?;
                    let n = positions.len() as i64;
                    let zero_based = if i > 0 {
                        i - 1
                    } else if i < 0 {
                        n + i
                    } else {
                        -1
                    };
                    if zero_based < 0 || zero_based > u32::MAX as i64 {
                        return Err(Error::new(
                            ErrorCode::InputBadIndex,
                            format!("face index {i} is out of range ({n} vertices so far)"),
                        )
                        .at(loc));
                    }
                    face.push(zero_based as u32);
                }
                mesh.push_face_unchecked(&face).map_err(|e| e.at(loc))?;
            }
            _ => continue,
        }
        records += 1;
        if records.is_multiple_of(BUDGET_CHECK_EVERY) {
            check(positions.len(), mesh.corner_count()).map_err(|e| e.at(loc))?;
        }
    }
    if mesh.face_count() == 0 {
        return Ok(Geometry::Cloud(PointCloud::new(positions, None, None)?));
    }
    mesh.positions = positions;
    mesh.validate()?;
    Ok(Geometry::Mesh(mesh))
}
