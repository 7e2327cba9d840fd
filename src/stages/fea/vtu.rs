//! VTK XML unstructured grid (`.vtu`, ASCII) of the solid's surface with the FEA fields on its vertices:
//! `displacement` (3), `von_mises`, `principal_stress` (3, largest first). ParaView and meshio open it.

use std::io::Write;

use super::SurfaceFields;
use crate::geometry::mesh::TriMesh;

/// Write the surface and its fields as a VTU document.
pub fn write_vtu(w: &mut impl Write, mesh: &TriMesh, fields: &SurfaceFields) -> std::io::Result<()> {
    let (nv, nt) = (mesh.positions.len(), mesh.triangles.len());
    writeln!(w, r#"<?xml version="1.0"?>"#)?;
    writeln!(w, r#"<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">"#)?;
    writeln!(w, "<UnstructuredGrid>")?;
    writeln!(w, r#"<Piece NumberOfPoints="{nv}" NumberOfCells="{nt}">"#)?;
    writeln!(w, "<Points>")?;
    writeln!(w, r#"<DataArray type="Float64" NumberOfComponents="3" format="ascii">"#)?;
    for p in &mesh.positions {
        writeln!(w, "{} {} {}", p[0], p[1], p[2])?;
    }
    writeln!(w, "</DataArray>\n</Points>\n<Cells>")?;
    writeln!(w, r#"<DataArray type="Int64" Name="connectivity" format="ascii">"#)?;
    for t in &mesh.triangles {
        writeln!(w, "{} {} {}", t[0], t[1], t[2])?;
    }
    writeln!(w, "</DataArray>")?;
    writeln!(w, r#"<DataArray type="Int64" Name="offsets" format="ascii">"#)?;
    for i in 0..nt {
        writeln!(w, "{}", 3 * (i + 1))?;
    }
    writeln!(w, "</DataArray>")?;
    writeln!(w, r#"<DataArray type="UInt8" Name="types" format="ascii">"#)?;
    for _ in 0..nt {
        writeln!(w, "5")?;
    }
    writeln!(w, "</DataArray>\n</Cells>")?;
    writeln!(w, r#"<PointData Vectors="displacement" Scalars="von_mises">"#)?;
    writeln!(w, r#"<DataArray type="Float64" Name="displacement" NumberOfComponents="3" format="ascii">"#)?;
    for d in &fields.displacement {
        writeln!(w, "{:e} {:e} {:e}", d[0], d[1], d[2])?;
    }
    writeln!(w, "</DataArray>")?;
    writeln!(w, r#"<DataArray type="Float64" Name="von_mises" format="ascii">"#)?;
    for v in &fields.von_mises {
        writeln!(w, "{v:e}")?;
    }
    writeln!(w, "</DataArray>")?;
    writeln!(w, r#"<DataArray type="Float64" Name="principal_stress" NumberOfComponents="3" format="ascii">"#)?;
    for s in &fields.principal_stress {
        writeln!(w, "{:e} {:e} {:e}", s[0], s[1], s[2])?;
    }
    writeln!(w, "</DataArray>\n</PointData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>")?;
    Ok(())
}
