//! The FEA spec: material, loads, supports, resolution and probes, read from TOML and kept apart from the
//! geometry so one spec serves many solids. Lengths are in the solid's units (mm by default), forces in N,
//! stresses in MPa, density in t/mm³ and gravity in mm/s² (the consistent mm–N–MPa–t set).
//!
//! Regions pick the surface by location, never by B-rep face:
//! - `sphere = { center = [x, y, z], radius = r }`: surface points within `r` of the centre;
//! - `plane = { point = [x, y, z], normal = [nx, ny, nz] }`: surface points on the side the normal points to
//!   ("beyond the plane"), e.g. `point = [0.001, 0, 0], normal = [-1, 0, 0]` is every point with x ≤ 0.001.

use serde::Deserialize;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::vec3::{V3, dot, norm, sub};

/// A whole FEA spec. Unknown keys are rejected.
#[derive(Clone, Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct FeaSpec {
    /// Isotropic linear-elastic material.
    pub material: Material,
    /// Gravitational acceleration (mm/s², e.g. `[0, 0, -9810]`); with a density it loads the solid by its own
    /// weight.
    #[serde(default)]
    pub gravity: Option<V3>,
    /// Forces and pressures on parts of the surface.
    #[serde(default)]
    pub loads: Vec<Load>,
    /// Fixed parts of the surface (all three displacement components held, weakly).
    #[serde(default)]
    pub supports: Vec<Support>,
    /// Grid and quadrature settings.
    #[serde(default)]
    pub resolution: Resolution,
    /// Points where displacement and stress are reported by name.
    #[serde(default)]
    pub probes: Vec<Probe>,
}

/// Isotropic material.
#[derive(Clone, Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Young's modulus E (MPa), in (0, 1e9].
    pub youngs_modulus: f64,
    /// Poisson's ratio ν, in (−1, 0.5).
    pub poissons_ratio: f64,
    /// Density (t/mm³; steel 7.85e-9); only used with `gravity`.
    #[serde(default)]
    pub density: f64,
}

/// Where on the surface a load or support acts: a sphere or a half-space (exactly one is set).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Region {
    /// Points within a sphere.
    pub sphere: Option<Sphere>,
    /// Points beyond a plane (on its normal's side, the plane included).
    pub plane: Option<HalfSpace>,
}

/// A sphere.
#[derive(Clone, Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Sphere {
    /// Centre.
    pub center: V3,
    /// Radius.
    pub radius: f64,
}

/// A half-space bounded by a plane.
#[derive(Clone, Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct HalfSpace {
    /// A point on the plane.
    pub point: V3,
    /// Outward normal: the half-space is the side it points to.
    pub normal: V3,
}

/// A load on the surface inside a region: a total force spread as a uniform traction over the selected area,
/// or a pressure (positive pushes into the solid).
#[derive(Clone, Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Load {
    /// A name for the report.
    #[serde(default)]
    pub name: Option<String>,
    /// Where it acts: points within a sphere…
    #[serde(default)]
    pub sphere: Option<Sphere>,
    /// …or beyond a plane.
    #[serde(default)]
    pub plane: Option<HalfSpace>,
    /// Total force (N).
    #[serde(default)]
    pub force: Option<V3>,
    /// Pressure (MPa).
    #[serde(default)]
    pub pressure: Option<f64>,
}

/// A fixed support on the surface inside a region.
#[derive(Clone, Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Support {
    /// A name for the report.
    #[serde(default)]
    pub name: Option<String>,
    /// Where it holds: points within a sphere…
    #[serde(default)]
    pub sphere: Option<Sphere>,
    /// …or beyond a plane.
    #[serde(default)]
    pub plane: Option<HalfSpace>,
}

/// Grid and quadrature settings.
#[derive(Clone, Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Resolution {
    /// Background grid spacing (length units). Default: the bounding box's longest side / `cells_along_longest`.
    #[serde(default)]
    pub cell_size: Option<f64>,
    /// Cells along the longest side of the bounding box when `cell_size` is not given.
    #[serde(default = "default_cells")]
    pub cells_along_longest: usize,
    /// Integration lines per cell side for the inside of cut cells (each line is integrated exactly).
    #[serde(default = "default_subcells")]
    pub subcells: usize,
    /// Stiffness factor of the fictitious (outside) part of cut cells.
    #[serde(default = "default_alpha")]
    pub fictitious_stiffness: f64,
    /// How supports are imposed: `nitsche` (default; consistent, β chosen per cell) or `penalty`.
    #[serde(default)]
    pub support_method: SupportMethod,
    /// Nitsche: β of a cell = factor · the largest eigenvalue of its trace inequality (> 2 keeps the system
    /// positive definite).
    #[serde(default = "default_nitsche")]
    pub nitsche_factor: f64,
    /// Penalty: β = factor · E / h.
    #[serde(default = "default_penalty")]
    pub penalty_factor: f64,
}

/// How supports (u = 0 on a part of the surface) are imposed weakly.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SupportMethod {
    /// Nitsche's method: consistent, so cut cells at the edge of a support do not lock.
    #[default]
    Nitsche,
    /// A penalty β ∫ u·v: simple, but too stiff near the edges of small supports (error O(h) and O(1/β)).
    Penalty,
}

fn default_cells() -> usize {
    48
}
fn default_subcells() -> usize {
    16
}
fn default_alpha() -> f64 {
    1e-8
}
fn default_nitsche() -> f64 {
    4.0
}
fn default_penalty() -> f64 {
    1e3
}

impl Default for Resolution {
    fn default() -> Self {
        Resolution {
            cell_size: None,
            cells_along_longest: default_cells(),
            subcells: default_subcells(),
            fictitious_stiffness: default_alpha(),
            support_method: SupportMethod::default(),
            nitsche_factor: default_nitsche(),
            penalty_factor: default_penalty(),
        }
    }
}

/// A named point where results are reported.
#[derive(Clone, Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Probe {
    /// The probe's name.
    pub name: String,
    /// Where results are reported.
    pub point: V3,
}

impl Region {
    /// Whether `p` is selected.
    pub fn contains(&self, p: V3) -> bool {
        if let Some(s) = &self.sphere {
            return norm(sub(p, s.center)) <= s.radius;
        }
        if let Some(h) = &self.plane {
            return dot(sub(p, h.point), h.normal) >= 0.0;
        }
        false
    }

    /// Whether the triangle `t` may hold selected points (conservative: never false when one is).
    pub fn may_touch(&self, t: &[V3; 3]) -> bool {
        if let Some(s) = &self.sphere {
            let q = crate::geometry::bvh::closest_point_on_triangle(s.center, t[0], t[1], t[2]);
            return norm(sub(q, s.center)) <= s.radius * (1.0 + 1e-9);
        }
        if let Some(h) = &self.plane {
            return t.iter().any(|&p| dot(sub(p, h.point), h.normal) >= 0.0);
        }
        false
    }

    fn validate(&self, what: &str) -> Result<()> {
        match (&self.sphere, &self.plane) {
            (Some(s), None) => {
                if !(finite(&s.center) && s.radius.is_finite() && s.radius > 0.0) {
                    return Err(bad(format!("{what}: the sphere needs a finite centre and a positive radius")));
                }
            }
            (None, Some(h)) => {
                if !(finite(&h.point) && finite(&h.normal) && norm(h.normal) > 0.0) {
                    return Err(bad(format!("{what}: the plane needs a finite point and a non-zero normal")));
                }
            }
            _ => return Err(bad(format!("{what}: give exactly one of `sphere` or `plane`"))),
        }
        Ok(())
    }
}

impl Region {
    fn of(sphere: &Option<Sphere>, plane: &Option<HalfSpace>) -> Region {
        Region { sphere: sphere.clone(), plane: plane.clone() }
    }
}

impl Load {
    /// Where it acts.
    pub fn region(&self) -> Region {
        Region::of(&self.sphere, &self.plane)
    }

    /// The name used in reports: the given one or `load N`.
    pub fn label(&self, i: usize) -> String {
        self.name.clone().unwrap_or_else(|| format!("load {}", i + 1))
    }
}

impl Support {
    /// Where it holds.
    pub fn region(&self) -> Region {
        Region::of(&self.sphere, &self.plane)
    }

    /// The name used in reports: the given one or `support N`.
    pub fn label(&self, i: usize) -> String {
        self.name.clone().unwrap_or_else(|| format!("support {}", i + 1))
    }
}

/// Most `[[loads]]` a spec may hold: each is a selection pass over the surface, and real load cases have a few.
pub const MAX_LOADS: usize = 64;
/// Most `[[supports]]` a spec may hold.
pub const MAX_SUPPORTS: usize = 64;
/// Most `[[probes]]` a spec may hold.
pub const MAX_PROBES: usize = 1024;
/// Longest name of a region or probe, characters.
pub const MAX_NAME_CHARS: usize = 200;
/// Largest spec file, bytes (the shipped specs are about 1.5 KiB).
pub const MAX_SPEC_BYTES: u64 = 1 << 20;
/// Largest |force| of a load, N, and |pressure|, MPa: beyond any structure a scan station measures.
pub const MAX_FORCE: f64 = 1e12;
/// Largest |pressure| of a load, MPa.
pub const MAX_PRESSURE: f64 = 1e6;
/// Largest |gravity|, mm/s² (10⁶ g).
pub const MAX_GRAVITY: f64 = 1e10;

fn finite(v: &V3) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn bad(message: String) -> Error {
    Error::new(ErrorCode::FeaBadSpec, message)
}

impl FeaSpec {
    /// Parse and validate a spec from TOML text.
    ///
    /// # Errors
    /// `fea.bad-spec` for TOML errors, unknown keys and absurd values; `fea.singular` for a spec without
    /// supports.
    pub fn from_toml(text: &str) -> Result<Self> {
        let spec: FeaSpec = toml::from_str(text).map_err(|e| bad(format!("spec: {}", e.to_string().trim())))?;
        spec.validate()?;
        Ok(spec)
    }

    /// Read and validate a spec file (at most [`MAX_SPEC_BYTES`]).
    ///
    /// # Errors
    /// `input.not-found`/`input.io` when it cannot be read, `input.too-large` beyond [`MAX_SPEC_BYTES`] (a
    /// device such as `/dev/urandom` too); otherwise as [`FeaSpec::from_toml`], with the file.
    pub fn read(path: &std::path::Path) -> Result<Self> {
        let text = crate::geometry::io::read_small_text(path, MAX_SPEC_BYTES, "an FEA spec")?;
        Self::from_toml(&text).map_err(|e| e.in_file(path))
    }

    /// Check every value. Cost: O(loads + supports).
    ///
    /// # Errors
    /// `fea.bad-spec` naming the first bad value; `fea.singular` when there are no supports.
    pub fn validate(&self) -> Result<()> {
        let m = &self.material;
        if !(m.youngs_modulus.is_finite() && m.youngs_modulus > 0.0 && m.youngs_modulus <= 1e9) {
            return Err(bad(format!("material.youngs_modulus = {} must lie in (0, 1e9] MPa", m.youngs_modulus)));
        }
        if !(m.poissons_ratio.is_finite() && m.poissons_ratio > -1.0 && m.poissons_ratio < 0.5) {
            return Err(bad(format!("material.poissons_ratio = {} must lie in (-1, 0.5)", m.poissons_ratio)));
        }
        if !(m.density.is_finite() && m.density >= 0.0 && m.density < 1.0) {
            return Err(bad(format!("material.density = {} must lie in [0, 1) t/mm³", m.density)));
        }
        if let Some(g) = &self.gravity
            && !(finite(g) && norm(*g) <= MAX_GRAVITY)
        {
            return Err(bad(format!("gravity must be finite, at most {MAX_GRAVITY:e} mm/s²")));
        }
        for (what, n, max) in [
            ("[[loads]]", self.loads.len(), MAX_LOADS),
            ("[[supports]]", self.supports.len(), MAX_SUPPORTS),
            ("[[probes]]", self.probes.len(), MAX_PROBES),
        ] {
            if n > max {
                return Err(bad(format!("{n} {what} entries; at most {max} are accepted")));
            }
        }
        let names = self.loads.iter().filter_map(|l| l.name.as_ref());
        let names = names
            .chain(self.supports.iter().filter_map(|s| s.name.as_ref()))
            .chain(self.probes.iter().map(|p| &p.name));
        if let Some(n) = names.into_iter().find(|n| n.chars().count() > MAX_NAME_CHARS) {
            return Err(bad(format!("a name of {} characters; at most {MAX_NAME_CHARS}", n.chars().count())));
        }
        for (i, l) in self.loads.iter().enumerate() {
            let what = l.label(i);
            l.region().validate(&what)?;
            match (&l.force, &l.pressure) {
                (Some(f), None) if finite(f) && norm(*f) <= MAX_FORCE => {}
                (None, Some(p)) if p.is_finite() && p.abs() <= MAX_PRESSURE => {}
                _ => {
                    return Err(bad(format!(
                        "{what}: give exactly one finite `force` (|F| ≤ {MAX_FORCE:e} N) or `pressure` (|p| ≤ {MAX_PRESSURE:e} MPa)"
                    )));
                }
            }
        }
        for (i, s) in self.supports.iter().enumerate() {
            s.region().validate(&s.label(i))?;
        }
        let self_weight = self.gravity.is_some_and(|g| norm(g) > 0.0) && m.density > 0.0;
        if self.loads.is_empty() && !self_weight {
            return Err(bad("nothing loads the solid: give a [[loads]] entry, or gravity with a density".into()));
        }
        if self.supports.is_empty() {
            return Err(Error::new(ErrorCode::FeaSingular, "no [[supports]]: the solid could move freely")
                .with_hint("fix part of the surface with a `sphere` or `plane` region"));
        }
        let r = &self.resolution;
        if let Some(h) = r.cell_size
            && !(h.is_finite() && h > 0.0)
        {
            return Err(bad(format!("resolution.cell_size = {h} must be positive")));
        }
        if !(2..=4096).contains(&r.cells_along_longest) {
            return Err(bad(format!(
                "resolution.cells_along_longest = {} must lie in [2, 4096]",
                r.cells_along_longest
            )));
        }
        if !(1..=64).contains(&r.subcells) {
            return Err(bad(format!("resolution.subcells = {} must lie in [1, 64]", r.subcells)));
        }
        if !(r.fictitious_stiffness.is_finite() && r.fictitious_stiffness > 0.0 && r.fictitious_stiffness < 1e-2) {
            return Err(bad(format!(
                "resolution.fictitious_stiffness = {} must lie in (0, 0.01)",
                r.fictitious_stiffness
            )));
        }
        if !(r.nitsche_factor.is_finite() && r.nitsche_factor > 2.0 && r.nitsche_factor <= 1e6) {
            return Err(bad(format!("resolution.nitsche_factor = {} must lie in (2, 1e6]", r.nitsche_factor)));
        }
        if !(r.penalty_factor.is_finite() && r.penalty_factor >= 1.0 && r.penalty_factor <= 1e8) {
            return Err(bad(format!("resolution.penalty_factor = {} must lie in [1, 1e8]", r.penalty_factor)));
        }
        for p in &self.probes {
            if !finite(&p.point) {
                return Err(bad(format!("probe {}: the point must be finite", p.name)));
            }
        }
        Ok(())
    }
}
