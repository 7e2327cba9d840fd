//! `scanstation render`: one picture of a mesh file, coloured by its deviation from a scan, its quad net,
//! its faces, its FEA stress under a spec, or a scan set's coverage of it ([`super::pictures`]).

use std::path::{Path, PathBuf};

use super::pictures::{Deviation, Picture, Scene, Up, maps, write_picture};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::{ReadOptions, ensure_not_input, read_geometry, read_mesh};
use crate::geometry::mesh::Geometry;
use crate::stages::NoProgress;
use crate::stages::quality::{signed_vertex_distances, vertex_distances, with_side};

/// What a render colours the mesh by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColorBy {
    /// Signed distance to `--ref` (a mesh gives the sign; a cloud, distance only).
    Deviation,
    /// The mesh's own polygons as a net (a quad net from `convert --quads`), over its shaded surface.
    Net,
    /// Each polygon of the mesh in its own colour.
    Faces,
    /// Von Mises stress of the FEA under `--spec`.
    Stress,
    /// How many views of the scan set `--ref` saw each vertex.
    Coverage,
}

impl ColorBy {
    /// Parse `deviation`, `net`, `faces`, `stress` or `coverage`.
    pub fn parse(s: &str) -> Option<ColorBy> {
        Some(match s {
            "deviation" => ColorBy::Deviation,
            "net" => ColorBy::Net,
            "faces" => ColorBy::Faces,
            "stress" => ColorBy::Stress,
            "coverage" => ColorBy::Coverage,
            _ => return None,
        })
    }
}

/// Settings of a render.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// What the colours show.
    pub color_by: ColorBy,
    /// The scan (deviation) or scan set (coverage).
    pub reference: Option<PathBuf>,
    /// The FEA spec (stress).
    pub spec: Option<PathBuf>,
    /// The object's up axis.
    pub up: Up,
    /// Half width of the deviation's neutral band, % of the reference's diagonal.
    pub band_pct: f64,
    /// The model unit's name for the legend.
    pub unit: &'static str,
    /// Most bytes a stage may allocate.
    pub memory_budget: u64,
}

/// Render `mesh` as `opts` asks into the PNG `out`.
///
/// # Errors
/// Reader errors; `input.bad-argument` when the colouring needs `--ref` or `--spec` and it is missing, or
/// when `out` is an input; the FEA's errors for `stress`; `resource.output` when `out` cannot be written.
pub fn render_file(mesh_path: &Path, out: &Path, read: &ReadOptions, opts: &RenderOptions) -> Result<Picture> {
    let inputs: Vec<&Path> =
        [Some(mesh_path), opts.reference.as_deref(), opts.spec.as_deref()].into_iter().flatten().collect();
    ensure_not_input(out, &inputs)?;
    let poly = read_mesh(mesh_path, read)?;
    let (tri, polygon_of) = poly.triangulate();
    let need = |what: Option<&PathBuf>, flag: &str| {
        what.cloned().ok_or_else(|| {
            Error::new(
                ErrorCode::InputBadArgument,
                format!("--color-by {:?} needs {flag}", opts.color_by).to_lowercase(),
            )
        })
    };
    let scene = || Scene::new(&tri, opts.up.axis());
    let image = match opts.color_by {
        ColorBy::Deviation => {
            let reference = read_geometry(&need(opts.reference.as_ref(), "--ref SCAN")?, read)?;
            let mut d = vertex_distances(&Geometry::Mesh(poly.clone()), &reference)?;
            if let Geometry::Mesh(r) = &reference {
                d = with_side(&d, &signed_vertex_distances(&tri, &r.triangulate().0));
            }
            let diag = reference.bbox().diagonal();
            let dev = Deviation {
                signed: &d,
                invented: None,
                band: opts.band_pct / 100.0 * diag,
                diag,
                unit: opts.unit,
                far: &[],
            };
            maps::deviation_sheet(&scene(), &dev, &dev.colours())
        }
        ColorBy::Net => maps::net_sheet(&scene(), &poly, 0.01 * tri.bbox().diagonal()),
        ColorBy::Faces => maps::faces_sheet(&scene(), &polygon_of),
        ColorBy::Stress => {
            let spec = crate::stages::fea::FeaSpec::read(&need(opts.spec.as_ref(), "--spec SPEC.toml")?)?;
            let fo = crate::stages::fea::FeaOptions { memory_budget: opts.memory_budget };
            let solution =
                crate::stages::fea::solve(&tri, &spec, &fo, &NoProgress).map_err(|e| e.in_file(mesh_path))?;
            return super::fea::stress_picture(out, &spec, &solution, opts.up);
        }
        ColorBy::Coverage => {
            let set = need(opts.reference.as_ref(), "--ref SCANSET")?;
            let fuse = crate::stages::reconstruct::fusion::FuseOptions::default();
            let (_, fused) = super::reconstruct::read_input_views(&set, read, &fuse)?;
            let fused = fused.ok_or_else(|| {
                Error::new(
                    ErrorCode::InputBadArgument,
                    "--color-by coverage needs --ref to be a scan set (views with poses)",
                )
                .in_file(&set)
            })?;
            let (seen_by, views) = super::reconstruct::fused_seen_by(&tri, &fused);
            maps::coverage_sheet(&scene(), &seen_by, views)
        }
    };
    let kind = match opts.color_by {
        ColorBy::Deviation => "deviation",
        ColorBy::Net => "net",
        ColorBy::Faces => "faces",
        ColorBy::Stress => "stress",
        ColorBy::Coverage => "coverage",
    };
    write_picture(out, kind, &image)
}
