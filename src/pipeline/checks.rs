//! What a conversion checks before it spends time on a scan: outputs that would land on the input or on
//! each other, the gates' bounds, and a repaired scan of several separate parts.

use std::path::Path;

use super::gates::GateOptions;
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::ensure_not_input;
use crate::geometry::mesh::TriMesh;
use crate::stages::repair::RepairReport;

/// Step 1 of [`convert_held`](super::convert_held): no output may overwrite the input or another output, nor replace what is not
/// a regular file; the gates' bounds make sense.
pub(super) fn check_outputs(input: &Path, output: &Path, gates: &GateOptions, quads: Option<&Path>) -> Result<()> {
    gates.validated()?;
    ensure_not_input(output, &[input])?;
    // The artifacts beside the STEP file must not land on the input either (`convert X.solid.ply -o X.step`).
    let (solid_path, map_path) =
        (super::provenance::solid_artifact_path(output), super::provenance::error_map_path(output));
    ensure_not_input(&solid_path, &[input])?;
    ensure_not_input(&map_path, &[input])?;
    for p in [output, &solid_path, &map_path] {
        crate::geometry::io::ensure_replaceable(p)?;
    }
    if let Some(q) = quads {
        ensure_not_input(q, &[input, output, &solid_path, &map_path])?;
        crate::geometry::io::ensure_replaceable(q)?;
    }
    Ok(())
}

/// The chain makes one solid of one connected surface: a repaired scan of several closed parts (each at
/// least repair's share of the area kept; smaller ones repair drops) is refused before the minutes of
/// remeshing and fitting that would end in a shell of several pieces. Passes repair's result on.
///
/// # Errors
/// `input.several-parts`, naming the count.
pub(super) fn one_part(repaired: (TriMesh, RepairReport)) -> Result<(TriMesh, RepairReport)> {
    let parts = repaired.1.output.components;
    if parts <= 1 {
        return Ok(repaired);
    }
    Err(Error::new(
        ErrorCode::InputSeveralParts,
        format!(
            "the scan is {parts} separate closed parts after repair; the chain makes one solid of one connected surface"
        ),
    )
    .with_hint("split the scan into its parts (one file each) and convert each; or join them in the scan"))
}
