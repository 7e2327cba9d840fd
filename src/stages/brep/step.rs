//! ISO 10303-21 (STEP) writer for a [`Solid`]: AP214 (`AUTOMOTIVE_DESIGN`), one
//! `MANIFOLD_SOLID_BREP` of `ADVANCED_FACE`s on `B_SPLINE_SURFACE_WITH_KNOTS`, shared `EDGE_CURVE`s on
//! `B_SPLINE_CURVE_WITH_KNOTS` with both faces' `PCURVE`s (straight uv lines: our edges are iso-curves),
//! `VERTEX_POINT`s, the product chain, and length units.
//!
//! The output depends only on the solid and the options: no clock, no host name, shortest round-trip
//! numbers, so the same input gives the same bytes.

use super::{Solid, bspline::knot_multiplicities};
use crate::error::Result;
use crate::geometry::io::write_atomic;
use crate::geometry::vec3::V3;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

/// The length unit written into the file (the input's units; meshes carry none, so mm by default).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LengthUnit {
    #[default]
    /// mm.
    Millimetre,
    /// cm.
    Centimetre,
    /// m.
    Metre,
}

impl LengthUnit {
    /// Parse `mm`, `cm` or `m`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "mm" => Some(LengthUnit::Millimetre),
            "cm" => Some(LengthUnit::Centimetre),
            "m" => Some(LengthUnit::Metre),
            _ => None,
        }
    }

    /// The unit's symbol: `mm`, `cm` or `m`.
    pub fn symbol(self) -> &'static str {
        match self {
            LengthUnit::Millimetre => "mm",
            LengthUnit::Centimetre => "cm",
            LengthUnit::Metre => "m",
        }
    }

    fn si(self) -> &'static str {
        match self {
            LengthUnit::Millimetre => "SI_UNIT(.MILLI.,.METRE.)",
            LengthUnit::Centimetre => "SI_UNIT(.CENTI.,.METRE.)",
            LengthUnit::Metre => "SI_UNIT($,.METRE.)",
        }
    }
}

/// What to write besides the geometry.
#[derive(Clone, Debug)]
pub struct StepOptions {
    /// Product name (and file name in the header).
    pub name: String,
    /// Length unit of the model's coordinates.
    pub unit: LengthUnit,
    /// Write both faces' parameter-space curves for every edge (exact; spares readers a projection).
    pub pcurves: bool,
}

impl Default for StepOptions {
    fn default() -> Self {
        StepOptions { name: "scan".into(), unit: LengthUnit::Millimetre, pcurves: true }
    }
}

/// A STEP real: shortest round-trip digits, always with a decimal point (`1.E0`, `-2.5E-3`).
fn real(x: f64) -> String {
    let x = if x == 0.0 { 0.0 } else { x };
    let s = format!("{x:E}");
    match s.find('E') {
        Some(e) if !s[..e].contains('.') => format!("{}.{}", &s[..e], &s[e..]),
        _ => s,
    }
}

fn text(s: &str) -> String {
    s.chars().filter(|c| c.is_ascii() && !c.is_ascii_control()).collect::<String>().replace('\'', "''")
}

struct Out {
    buf: String,
    next: usize,
}

impl Out {
    fn add(&mut self, body: impl AsRef<str>) -> usize {
        let id = self.next;
        self.next += 1;
        let _ = writeln!(self.buf, "#{id}={};", body.as_ref());
        id
    }

    fn point(&mut self, p: V3) -> usize {
        self.add(format!("CARTESIAN_POINT('',({},{},{}))", real(p[0]), real(p[1]), real(p[2])))
    }
}

fn list(ids: impl IntoIterator<Item = usize>) -> String {
    let v: Vec<String> = ids.into_iter().map(|i| format!("#{i}")).collect();
    format!("({})", v.join(","))
}

fn reals(xs: &[f64]) -> String {
    let v: Vec<String> = xs.iter().map(|&x| real(x)).collect();
    format!("({})", v.join(","))
}

/// How far knot removal may move the control points `poles`: [`KNOT_REMOVAL_REL`] of their bbox diagonal.
///
/// [`KNOT_REMOVAL_REL`]: crate::geometry::tolerance::KNOT_REMOVAL_REL
fn knot_tolerance(poles: &[V3]) -> f64 {
    let mut bbox = crate::geometry::vec3::Aabb::EMPTY;
    for &p in poles {
        bbox.add(p);
    }
    crate::geometry::tolerance::KNOT_REMOVAL_REL * bbox.diagonal()
}

/// An edge's curve as written: its control points and expanded knot vector, with every knot removed that
/// the curve does not need.
fn reduced_curve(edge: &super::Edge) -> (Vec<V3>, Vec<f64>) {
    let mut knots = vec![edge.knots[0]; 4];
    for &k in &edge.knots[1..edge.knots.len() - 1] {
        knots.extend([k; 3]);
    }
    knots.extend([edge.length(); 4]);
    let tol = knot_tolerance(&edge.curve);
    let mut curves = vec![edge.curve.clone()];
    super::bspline::remove_curve_knots(&mut knots, &mut curves, tol);
    (curves.pop().expect("one curve"), knots)
}

/// The STEP text of `solid`.
pub fn to_step(solid: &Solid, opts: &StepOptions) -> String {
    let name = text(&opts.name);
    let mut o = Out { buf: String::with_capacity(256 * (solid.faces.len() * 20 + solid.edges.len() * 6)), next: 1 };
    let app = o.add("APPLICATION_CONTEXT('automotive design')");
    o.add(format!("APPLICATION_PROTOCOL_DEFINITION('international standard','automotive_design',2000,#{app})"));
    let pctx = o.add(format!("PRODUCT_CONTEXT('',#{app},'mechanical')"));
    let product = o.add(format!("PRODUCT('{name}','{name}','',(#{pctx}))"));
    o.add(format!("PRODUCT_RELATED_PRODUCT_CATEGORY('part',$,(#{product}))"));
    let pdf = o.add(format!("PRODUCT_DEFINITION_FORMATION('','',#{product})"));
    let pdc = o.add(format!("PRODUCT_DEFINITION_CONTEXT('part definition',#{app},'design')"));
    let pd = o.add(format!("PRODUCT_DEFINITION('design','',#{pdf},#{pdc})"));
    let pds = o.add(format!("PRODUCT_DEFINITION_SHAPE('','',#{pd})"));
    let len = o.add(format!("( LENGTH_UNIT() NAMED_UNIT(*) {} )", opts.unit.si()));
    let ang = o.add("( NAMED_UNIT(*) PLANE_ANGLE_UNIT() SI_UNIT($,.RADIAN.) )");
    let sol = o.add("( NAMED_UNIT(*) SI_UNIT($,.STERADIAN.) SOLID_ANGLE_UNIT() )");
    let unc = o.add(format!(
        "UNCERTAINTY_MEASURE_WITH_UNIT(LENGTH_MEASURE(1.E-07),#{len},'distance_accuracy_value','confusion accuracy')"
    ));
    let ctx = o.add(format!(
        "( GEOMETRIC_REPRESENTATION_CONTEXT(3) GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT((#{unc})) \
         GLOBAL_UNIT_ASSIGNED_CONTEXT((#{len},#{ang},#{sol})) REPRESENTATION_CONTEXT('','3D') )"
    ));
    let ctx2 = o.add(
        "( GEOMETRIC_REPRESENTATION_CONTEXT(2) PARAMETRIC_REPRESENTATION_CONTEXT() REPRESENTATION_CONTEXT('','2D') )",
    );
    let origin = o.point([0.0; 3]);
    let dz = o.add("DIRECTION('',(0.,0.,1.))");
    let dx = o.add("DIRECTION('',(1.,0.,0.))");
    let axis = o.add(format!("AXIS2_PLACEMENT_3D('',#{origin},#{dz},#{dx})"));

    // Vertices.
    let mut vpoint = Vec::with_capacity(solid.vertices.len());
    let mut vertex = Vec::with_capacity(solid.vertices.len());
    for &p in &solid.vertices {
        let cp = o.point(p);
        vpoint.push(cp);
        vertex.push(o.add(format!("VERTEX_POINT('',#{cp})")));
    }
    // Surfaces first (pcurves refer to them).
    let mut surf = Vec::with_capacity(solid.faces.len());
    for face in &solid.faces {
        // Written with every knot removed that the face does not need (pieces that join C¹ or C²).
        let mut s = face.surface.clone();
        s.remove_knots(knot_tolerance(&s.poles));
        let s = &s;
        let mut rows = Vec::with_capacity(s.nu);
        for i in 0..s.nu {
            let ids: Vec<usize> = (0..s.nv).map(|j| o.point(s.poles[j * s.nu + i])).collect();
            rows.push(list(ids));
        }
        let (ku, mu) = knot_multiplicities(&s.knots_u);
        let (kv, mv) = knot_multiplicities(&s.knots_v);
        let ints = |m: &[u32]| format!("({})", m.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(","));
        surf.push(o.add(format!(
            "B_SPLINE_SURFACE_WITH_KNOTS('',3,3,({}),.UNSPECIFIED.,.F.,.F.,.F.,{},{},{},{},.UNSPECIFIED.)",
            rows.join(","),
            ints(&mu),
            ints(&mv),
            reals(&ku),
            reals(&kv)
        )));
    }
    // Which faces (and where) use each edge, for the pcurves.
    let mut users: Vec<Vec<(usize, usize)>> = vec![Vec::new(); solid.edges.len()];
    for (fi, face) in solid.faces.iter().enumerate() {
        for (k, c) in face.bound.iter().enumerate() {
            users[c.edge as usize].push((fi, k));
        }
    }
    // Edges.
    let mut edge_curve = Vec::with_capacity(solid.edges.len());
    for (e, edge) in solid.edges.iter().enumerate() {
        let (curve, expanded) = reduced_curve(edge);
        let last = curve.len() - 1;
        let ctrl: Vec<usize> = (0..=last)
            .map(|i| match i {
                0 => vpoint[edge.start as usize],
                i if i == last => vpoint[edge.end as usize],
                i => o.point(curve[i]),
            })
            .collect();
        let (knots, mults) = knot_multiplicities(&expanded);
        let mults: Vec<String> = mults.iter().map(|m| m.to_string()).collect();
        let c3 = o.add(format!(
            "B_SPLINE_CURVE_WITH_KNOTS('',3,{},.UNSPECIFIED.,.F.,.F.,({}),{},.UNSPECIFIED.)",
            list(ctrl),
            mults.join(","),
            reals(&knots)
        ));
        let geom = if opts.pcurves {
            let mut pcs = Vec::with_capacity(2);
            for &(fi, k) in &users[e] {
                let c = solid.faces[fi].bound[k];
                // uv at curve parameter 0 and `spans`.
                let (a, b) = if c.forward { (c.uv[0], c.uv[1]) } else { (c.uv[1], c.uv[0]) };
                let pa = o.add(format!("CARTESIAN_POINT('',({},{}))", real(a[0]), real(a[1])));
                let pb = o.add(format!("CARTESIAN_POINT('',({},{}))", real(b[0]), real(b[1])));
                let line = o.add(format!(
                    "B_SPLINE_CURVE_WITH_KNOTS('',1,(#{pa},#{pb}),.POLYLINE_FORM.,.F.,.F.,(2,2),(0.,{}),.UNSPECIFIED.)",
                    real(edge.length())
                ));
                let dr = o.add(format!("DEFINITIONAL_REPRESENTATION('',(#{line}),#{ctx2})"));
                pcs.push(o.add(format!("PCURVE('',#{},#{dr})", surf[fi])));
            }
            o.add(format!("SURFACE_CURVE('',#{c3},{},.PCURVE_S1.)", list(pcs)))
        } else {
            c3
        };
        edge_curve.push(o.add(format!(
            "EDGE_CURVE('',#{},#{},#{geom},.T.)",
            vertex[edge.start as usize], vertex[edge.end as usize]
        )));
    }
    // Faces.
    let mut faces = Vec::with_capacity(solid.faces.len());
    for (fi, face) in solid.faces.iter().enumerate() {
        let oes: Vec<usize> = face
            .bound
            .iter()
            .map(|c| {
                o.add(format!(
                    "ORIENTED_EDGE('',*,*,#{},{})",
                    edge_curve[c.edge as usize],
                    if c.forward { ".T." } else { ".F." }
                ))
            })
            .collect();
        let lp = o.add(format!("EDGE_LOOP('',{})", list(oes)));
        let bound = o.add(format!("FACE_OUTER_BOUND('',#{lp},.T.)"));
        faces.push(o.add(format!("ADVANCED_FACE('',(#{bound}),#{},.T.)", surf[fi])));
    }
    let shell = o.add(format!("CLOSED_SHELL('',{})", list(faces)));
    let brep = o.add(format!("MANIFOLD_SOLID_BREP('{name}',#{shell})"));
    let rep = o.add(format!("ADVANCED_BREP_SHAPE_REPRESENTATION('{name}',(#{axis},#{brep}),#{ctx})"));
    o.add(format!("SHAPE_DEFINITION_REPRESENTATION(#{pds},#{rep})"));

    let mut out = String::with_capacity(o.buf.len() + 512);
    out.push_str("ISO-10303-21;\nHEADER;\n");
    let _ = writeln!(out, "FILE_DESCRIPTION(('scanstation solid: B-spline B-rep fitted to a scan'),'2;1');");
    // A fixed time stamp keeps the bytes reproducible.
    let _ = writeln!(
        out,
        "FILE_NAME('{name}.step','1970-01-01T00:00:00',(''),(''),'scanstation {}','scanstation','');",
        env!("CARGO_PKG_VERSION")
    );
    out.push_str("FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));\nENDSEC;\nDATA;\n");
    out.push_str(&o.buf);
    out.push_str("ENDSEC;\nEND-ISO-10303-21;\n");
    out
}

/// Write `solid` to `path` atomically: a temporary file beside it, renamed when complete, so a failed
/// run leaves no half-written STEP file. Returns the file's size and SHA-256, taken while writing.
///
/// # Errors
/// `resource.output` when the file cannot be written or renamed.
pub fn write_step(path: &Path, solid: &Solid, opts: &StepOptions) -> Result<crate::geometry::io::FileDigest> {
    let body = to_step(solid, opts);
    write_atomic(path, |w| w.write_all(body.as_bytes()))
}
