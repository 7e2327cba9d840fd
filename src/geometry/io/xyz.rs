//! Text point clouds: one point per line, `x y z` (3 values), `x y z intensity` (4), `x y z nx ny nz` (6) or
//! `x y z intensity r g b` (7, Leica PTS). Separators: blanks, commas or semicolons. An optional first line
//! holding a single count (PTS) is checked against the data. `#` and `//` comment lines are skipped. Every
//! line must have the column count of the first.

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::text::{Lines, parse_num};
use crate::geometry::io::{Input, finite_point};
use crate::geometry::mesh::{Geometry, PointCloud};

const BUDGET_CHECK_EVERY: usize = 1 << 16;

pub(crate) fn read(input: &mut Input) -> Result<Geometry> {
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut normals: Vec<[f32; 3]> = Vec::new();
    let mut colors: Vec<[u8; 3]> = Vec::new();
    let mut columns = 0usize;
    let mut declared: Option<(u64, crate::error::Location)> = None;
    let mut vals = [0f64; 7];
    let mut reader = std::mem::replace(&mut input.reader, Box::new(std::io::empty()));
    let mut lines = Lines::new(&mut *reader);
    let budget = |n: usize| input.check_memory(27 * n as u64, "the points read so far");
    while let Some((line, loc)) = lines.next_line()? {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let toks: Vec<&str> =
            line.split(|c: char| c.is_whitespace() || c == ',' || c == ';').filter(|t| !t.is_empty()).collect();
        if columns == 0 && positions.is_empty() && declared.is_none() && toks.len() == 1 {
            declared = Some((parse_num(toks[0], "point count", loc)?, loc));
            continue;
        }
        if columns == 0 {
            columns = toks.len();
            if ![3, 4, 6, 7].contains(&columns) {
                return Err(Error::new(
                    ErrorCode::InputBadRecord,
                    format!("{columns} values per line; expected 3 (x y z), 4, 6 (with normals) or 7 (PTS)"),
                )
                .at(loc));
            }
        } else if toks.len() != columns {
            return Err(Error::new(
                ErrorCode::InputBadRecord,
                format!("{} values on this line, {columns} on the first", toks.len()),
            )
            .at(loc));
        }
        for (v, t) in vals.iter_mut().zip(&toks) {
            *v = parse_num(t, "coordinate", loc)?;
        }
        let i = positions.len();
        positions.push(finite_point([vals[0] as f32, vals[1] as f32, vals[2] as f32], || format!("point {i}"), loc)?);
        match columns {
            6 => normals.push([vals[3] as f32, vals[4] as f32, vals[5] as f32]),
            7 => colors.push([vals[4], vals[5], vals[6]].map(|c| c.clamp(0.0, 255.0) as u8)),
            _ => {}
        }
        if positions.len().is_multiple_of(BUDGET_CHECK_EVERY) {
            budget(positions.len()).map_err(|e| e.at(loc))?;
        }
    }
    if let Some((n, loc)) = declared
        && n != positions.len() as u64
    {
        let code = if n > positions.len() as u64 { ErrorCode::InputTruncated } else { ErrorCode::InputBadHeader };
        return Err(
            Error::new(code, format!("the header declares {n} points, the file has {}", positions.len())).at(loc)
        );
    }
    let normals = (columns == 6).then_some(normals);
    let colors = (columns == 7).then_some(colors);
    Ok(Geometry::Cloud(PointCloud::new(positions, normals, colors)?))
}
