//! `SceneConfig`: a scene described in TOML — the volume and its striding, the grid level, label →
//! material, the model, the integrator, damping, gravity, fixed regions and loads.
//!
//! Unknown keys and out-of-range values are errors that name the key and the line of the file:
//! the raw document is deserialised with spans (`toml::Spanned`), then checked into the plain
//! [`SceneConfig`] the simulation uses.

use serde::Deserialize;
use std::ops::Range;
use toml::Spanned;

/// A scene file that cannot be used.
#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
pub enum SceneError {
    /// Not TOML, an unknown key, or a value of the wrong type.
    #[error("{file}:{line}: {message}")]
    Parse {
        /// The file (or name given for the text).
        file: String,
        /// 1-based line, 0 when unknown.
        line: usize,
        /// What was wrong.
        message: String,
    },
    /// A key whose value is out of range or inconsistent.
    #[error("{file}:{line}: `{key}` {message}")]
    Invalid {
        /// The file.
        file: String,
        /// 1-based line of the value.
        line: usize,
        /// The key, dotted (`integrator.dt`).
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// The scene could not be built (its volume, grid or materials).
    #[error("{file}: {message}")]
    Build {
        /// The file.
        file: String,
        /// What failed.
        message: String,
    },
}

/// Where the scene's label volume comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum VolumeSpec {
    /// A label volume file (NIfTI or INR), relative to the scene file's folder.
    File {
        /// The path as written in the scene.
        path: String,
        /// Per-axis stride after cropping to the foreground.
        stride: [usize; 3],
        /// Labels to keep (empty = all).
        labels: Vec<u16>,
    },
    /// A box of `voxels` cells filling `size_m` (label 1).
    Block {
        /// Edge lengths (m).
        size_m: [f64; 3],
        /// Voxels per axis.
        voxels: [usize; 3],
    },
}

/// The mechanical model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelKind {
    /// Small-strain linear hexahedra.
    Linear,
    /// Corotational hexahedra.
    Corotational,
    /// Paper 2's tensor-mass tetrahedra (6 per grid cell at `level`), explicit; its settings are
    /// [`SceneConfig::tensor_mass`].
    TensorMass,
}

/// `model.kind = "tensor-mass"`: the tetrahedral model's settings (`[model]` keys).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TensorMassSpec {
    /// `model.elasticity`: `"svk"` (default) or `"linear"`.
    pub elasticity: incise_fem::forcefield::tet::Elasticity,
    /// `model.incompressibility`: the penalty strength κ (Pa), none by default.
    pub incompressibility: Option<f64>,
    /// `model.adaptive_threshold`: displacement (m) above which a vertex is non-linear (paper 2
    /// §6); none (every tetrahedron SVK) by default.
    pub adaptive_threshold: Option<f64>,
    /// `model.fibre` and `model.fibre_ratio`: a fibre direction for every tetrahedron and how
    /// many times stiffer (λ and μ) the tissue is along it.
    pub fibre: Option<([f64; 3], f64)>,
}

/// `model.kind = "auto"`: the grid level is chosen when the scene is built, as the coarsest level
/// (up to `max_level`) whose estimated error fits `max_error`; the error of each level is
/// estimated by a static calibration against the finest affordable level (see
/// `incise_sim::calibration`). The model is corotational.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AutoLevel {
    /// Largest acceptable relative error (0.05 = 5 %).
    pub max_error: f64,
    /// Coarsest level considered.
    pub max_level: u32,
}

/// The time integrator.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntegratorKind {
    /// Linearised backward Euler, one solve per step.
    ImplicitEuler,
    /// Symplectic Euler (explicit).
    Explicit,
    /// Newton iterations to static equilibrium every step (for references).
    Static,
}

/// A tissue of one label.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaterialSpec {
    /// The label it applies to.
    pub label: u16,
    /// The material.
    pub material: incise_grid::Material,
}

/// A region of fixed nodes.
#[derive(Clone, Debug, PartialEq)]
pub enum FixedSpec {
    /// Nodes on the plane `x[axis] = value` (m).
    Plane {
        /// 0 = x, 1 = y, 2 = z.
        axis: usize,
        /// Coordinate of the plane (m, grid frame).
        value: f64,
    },
    /// Nodes inside the box `[min, max]` (m, grid frame).
    Box {
        /// Lower corner.
        min: [f64; 3],
        /// Upper corner.
        max: [f64; 3],
    },
    /// Every node of every element (hexahedron, or a tensor-mass cell's tetrahedra) that holds a
    /// voxel with this label: tissue held by an attachment segmented in the image (a ligament, a
    /// vessel, a neighbouring organ). At a coarse level the whole element holding such a voxel is
    /// held.
    Label {
        /// The voxel label (one of the scene's `[[materials]]`).
        label: u16,
    },
}

/// A force spread evenly over the nodes within `radius` of `centre`.
#[derive(Clone, Debug, PartialEq)]
pub struct PatchLoad {
    /// Centre of the patch (m, grid frame).
    pub centre: [f64; 3],
    /// Radius (m).
    pub radius: f64,
    /// Total force (N).
    pub force: [f64; 3],
}

/// A validated scene.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneConfig {
    /// Scene name (used in keys and reports).
    pub name: String,
    /// The label volume.
    pub volume: VolumeSpec,
    /// Grid level the mechanics runs on.
    pub level: u32,
    /// Label → material.
    pub materials: Vec<MaterialSpec>,
    /// The model.
    pub model: ModelKind,
    /// Set when `model.kind = "auto"`: `level` is then chosen by calibration (and `model` is
    /// corotational).
    pub auto_level: Option<AutoLevel>,
    /// With `model.kind = "tensor-mass"`, its settings.
    pub tensor_mass: Option<TensorMassSpec>,
    /// The integrator.
    pub integrator: IntegratorKind,
    /// Time step (s).
    pub dt: f64,
    /// CG relative tolerance.
    pub cg_tolerance: f64,
    /// Linear solver of the implicit integrator.
    pub solver: incise_fem::ode::LinearSolver,
    /// Mass matrix of the implicit integrator (`integrator.mass`: `"lumped"`, the default, or
    /// `"consistent"`).
    pub mass: incise_fem::ode::MassMatrix,
    /// Rayleigh damping α (1/s).
    pub rayleigh_alpha: f64,
    /// Rayleigh damping β (s).
    pub rayleigh_beta: f64,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// Fixed regions.
    pub fixed: Vec<FixedSpec>,
    /// Patch loads.
    pub loads: Vec<PatchLoad>,
}

// --- the raw document, with spans --------------------------------------------------------------

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    name: String,
    volume: Spanned<RawVolume>,
    #[serde(default)]
    level: Option<Spanned<i64>>,
    #[serde(default)]
    materials: Option<Spanned<Vec<Spanned<RawMaterial>>>>,
    #[serde(default)]
    model: Option<RawModel>,
    integrator: RawIntegrator,
    #[serde(default)]
    gravity: Option<Spanned<[f64; 3]>>,
    #[serde(default)]
    fixed: Vec<Spanned<RawFixed>>,
    #[serde(default)]
    loads: Vec<RawLoad>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVolume {
    file: Option<String>,
    stride: Option<Spanned<[i64; 3]>>,
    labels: Option<Spanned<Vec<u16>>>,
    procedural: Option<Spanned<String>>,
    size_m: Option<Spanned<[f64; 3]>>,
    voxels: Option<Spanned<[i64; 3]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMaterial {
    label: Spanned<i64>,
    youngs_modulus: Spanned<f64>,
    poisson_ratio: Spanned<f64>,
    density: Spanned<f64>,
    #[serde(default)]
    rayleigh_mass: Option<Spanned<f64>>,
    #[serde(default)]
    rayleigh_stiffness: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModel {
    kind: Spanned<String>,
    #[serde(default)]
    max_error: Option<Spanned<f64>>,
    #[serde(default)]
    max_level: Option<Spanned<i64>>,
    #[serde(default)]
    elasticity: Option<Spanned<String>>,
    #[serde(default)]
    incompressibility: Option<Spanned<f64>>,
    #[serde(default)]
    adaptive_threshold: Option<Spanned<f64>>,
    #[serde(default)]
    fibre: Option<Spanned<[f64; 3]>>,
    #[serde(default)]
    fibre_ratio: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawIntegrator {
    kind: Spanned<String>,
    dt: Spanned<f64>,
    #[serde(default)]
    cg_tolerance: Option<Spanned<f64>>,
    #[serde(default)]
    solver: Option<Spanned<String>>,
    #[serde(default)]
    mass: Option<Spanned<String>>,
    #[serde(default)]
    rayleigh_alpha: Option<Spanned<f64>>,
    #[serde(default)]
    rayleigh_beta: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFixed {
    plane: Option<Spanned<String>>,
    value: Option<Spanned<f64>>,
    min: Option<Spanned<[f64; 3]>>,
    max: Option<Spanned<[f64; 3]>>,
    label: Option<Spanned<u16>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLoad {
    centre: Spanned<[f64; 3]>,
    radius: Spanned<f64>,
    force: Spanned<[f64; 3]>,
}

/// 1-based line of byte offset `at` in `text`.
fn line_of(text: &str, at: usize) -> usize {
    text[..at.min(text.len())].bytes().filter(|&b| b == b'\n').count() + 1
}

struct Checker<'a> {
    text: &'a str,
    file: &'a str,
}

impl Checker<'_> {
    fn invalid(&self, span: Range<usize>, key: &str, message: impl Into<String>) -> SceneError {
        SceneError::Invalid {
            file: self.file.to_owned(),
            line: line_of(self.text, span.start),
            key: key.to_owned(),
            message: message.into(),
        }
    }

    /// The tensor-mass keys of `[model]`: read when `on`, refused (naming the key) otherwise.
    fn tensor_mass(&self, m: &RawModel, on: bool) -> Result<Option<TensorMassSpec>, SceneError> {
        if !on {
            let stray = m
                .elasticity
                .as_ref()
                .map(|v| (v.span(), "model.elasticity"))
                .or_else(|| {
                    m.incompressibility.as_ref().map(|v| (v.span(), "model.incompressibility"))
                })
                .or_else(|| {
                    m.adaptive_threshold.as_ref().map(|v| (v.span(), "model.adaptive_threshold"))
                })
                .or_else(|| m.fibre.as_ref().map(|v| (v.span(), "model.fibre")))
                .or_else(|| m.fibre_ratio.as_ref().map(|v| (v.span(), "model.fibre_ratio")));
            return match stray {
                Some((span, key)) => {
                    Err(self.invalid(span, key, "applies only to `model.kind = \"tensor-mass\"`"))
                }
                None => Ok(None),
            };
        }
        let elasticity = match m.elasticity.as_ref().map(|e| (e.span(), e.get_ref().as_str())) {
            None | Some((_, "svk")) => incise_fem::forcefield::tet::Elasticity::StVenantKirchhoff,
            Some((_, "linear")) => incise_fem::forcefield::tet::Elasticity::Linear,
            Some((span, other)) => {
                return Err(self.invalid(
                    span,
                    "model.elasticity",
                    format!("is \"{other}\"; expected \"svk\" or \"linear\""),
                ));
            }
        };
        let incompressibility = m
            .incompressibility
            .as_ref()
            .map(|v| self.positive(v, "model.incompressibility"))
            .transpose()?;
        let adaptive_threshold = m
            .adaptive_threshold
            .as_ref()
            .map(|v| self.positive(v, "model.adaptive_threshold"))
            .transpose()?;
        let fibre = match (&m.fibre, &m.fibre_ratio) {
            (None, None) => None,
            (Some(f), ratio) => {
                let d = *f.get_ref();
                if !(d.iter().all(|x| x.is_finite()) && d.iter().any(|&x| x != 0.0)) {
                    return Err(self.invalid(
                        f.span(),
                        "model.fibre",
                        format!("{d:?} is not a direction"),
                    ));
                }
                let r =
                    ratio.as_ref().map_or(Ok(1.0), |r| self.positive(r, "model.fibre_ratio"))?;
                Some((d, r))
            }
            (None, Some(r)) => {
                return Err(self.invalid(
                    r.span(),
                    "model.fibre_ratio",
                    "needs `model.fibre` (a direction)",
                ));
            }
        };
        Ok(Some(TensorMassSpec { elasticity, incompressibility, adaptive_threshold, fibre }))
    }

    /// A finite number (NaN and infinities are TOML numbers too).
    fn finite(&self, v: &Spanned<f64>, key: &str) -> Result<f64, SceneError> {
        let x = *v.get_ref();
        if x.is_finite() {
            Ok(x)
        } else {
            Err(self.invalid(v.span(), key, format!("is {x}; it must be finite")))
        }
    }

    /// Three finite numbers.
    fn finite3(&self, v: &Spanned<[f64; 3]>, key: &str) -> Result<[f64; 3], SceneError> {
        let x = *v.get_ref();
        if x.iter().all(|c| c.is_finite()) {
            Ok(x)
        } else {
            Err(self.invalid(v.span(), key, format!("is {x:?}; every entry must be finite")))
        }
    }

    /// A number in `[lo, hi]`, with its unit in the message.
    fn within(
        &self,
        v: &Spanned<f64>,
        key: &str,
        (lo, hi): (f64, f64),
        unit: &str,
    ) -> Result<f64, SceneError> {
        let x = *v.get_ref();
        if (lo..=hi).contains(&x) {
            Ok(x)
        } else {
            Err(self.invalid(
                v.span(),
                key,
                format!("is {x}; it must be between {lo:e} and {hi:e} {unit}"),
            ))
        }
    }

    fn positive(&self, v: &Spanned<f64>, key: &str) -> Result<f64, SceneError> {
        let x = *v.get_ref();
        if x.is_finite() && x > 0.0 {
            Ok(x)
        } else {
            Err(self.invalid(v.span(), key, format!("is {x}; it must be finite and positive")))
        }
    }

    fn non_negative(
        &self,
        v: Option<&Spanned<f64>>,
        key: &str,
        default: f64,
    ) -> Result<f64, SceneError> {
        let Some(v) = v else { return Ok(default) };
        let x = *v.get_ref();
        if x.is_finite() && x >= 0.0 {
            Ok(x)
        } else {
            Err(self.invalid(v.span(), key, format!("is {x}; it must be finite and non-negative")))
        }
    }

    /// `[volume]`: a file (with its `stride` and `labels`) or a procedural block (with its
    /// `size_m` and `voxels`); a key of the other kind is refused rather than ignored.
    fn volume(&self, v: &Spanned<RawVolume>) -> Result<VolumeSpec, SceneError> {
        let header = v.span();
        let v = v.get_ref();
        if let Some(path) = &v.file {
            let stray = v
                .procedural
                .as_ref()
                .map(|p| (p.span(), "volume.procedural"))
                .or_else(|| v.size_m.as_ref().map(|p| (p.span(), "volume.size_m")))
                .or_else(|| v.voxels.as_ref().map(|p| (p.span(), "volume.voxels")));
            if let Some((span, key)) = stray {
                return Err(self.invalid(
                    span,
                    key,
                    "describes a procedural volume; it cannot be given together with `volume.file`",
                ));
            }
            let stride = match &v.stride {
                Some(s) => self.counts(s, "volume.stride", 64)?,
                None => [1, 1, 1],
            };
            let labels = v.labels.as_ref().map(|l| l.get_ref().clone()).unwrap_or_default();
            return Ok(VolumeSpec::File { path: path.clone(), stride, labels });
        }
        let Some(kind) = &v.procedural else {
            return Err(self.invalid(header, "volume", "needs `file` or `procedural`"));
        };
        let stray = v
            .stride
            .as_ref()
            .map(|p| (p.span(), "volume.stride"))
            .or_else(|| v.labels.as_ref().map(|p| (p.span(), "volume.labels")));
        if let Some((span, key)) = stray {
            return Err(self.invalid(
                span,
                key,
                "applies to a volume file; a procedural volume has no stride or labels",
            ));
        }
        if kind.get_ref() != "block" {
            return Err(self.invalid(
                kind.span(),
                "volume.procedural",
                format!("is \"{}\"; the known volume is \"block\"", kind.get_ref()),
            ));
        }
        let (Some(size), Some(voxels)) = (&v.size_m, &v.voxels) else {
            return Err(self.invalid(
                kind.span(),
                "volume.procedural",
                "\"block\" needs `size_m` and `voxels`",
            ));
        };
        let s = *size.get_ref();
        if !s.iter().all(|&x| x.is_finite() && x > 0.0) {
            return Err(self.invalid(
                size.span(),
                "volume.size_m",
                format!("is {s:?}; every edge must be finite and positive"),
            ));
        }
        Ok(VolumeSpec::Block { size_m: s, voxels: self.counts(voxels, "volume.voxels", 4096)? })
    }

    /// `[[fixed]]` entry `k`: a `plane` with its `value`, a box (`min` + `max`) or a `label`;
    /// a key of another kind of region is refused rather than ignored.
    fn fixed(
        &self,
        f: &Spanned<RawFixed>,
        k: usize,
        materials: &[MaterialSpec],
    ) -> Result<FixedSpec, SceneError> {
        let header = f.span();
        let f = f.get_ref();
        let key = |name: &str| format!("fixed[{k}].{name}");
        if let Some(label) = &f.label {
            if let Some((span, name)) = f
                .plane
                .as_ref()
                .map(|v| (v.span(), "plane"))
                .or_else(|| f.value.as_ref().map(|v| (v.span(), "value")))
                .or_else(|| f.min.as_ref().map(|v| (v.span(), "min")))
                .or_else(|| f.max.as_ref().map(|v| (v.span(), "max")))
            {
                return Err(self.invalid(
                    span,
                    &key(name),
                    "cannot be given with `label`: a fixed region is a `plane`, a box (`min` + `max`) or a `label`",
                ));
            }
            let l = *label.get_ref();
            if !materials.iter().any(|m| m.label == l) {
                return Err(self.invalid(
                    label.span(),
                    &key("label"),
                    format!("is {l}, which no `[[materials]]` entry has"),
                ));
            }
            return Ok(FixedSpec::Label { label: l });
        }
        if let Some(axis) = &f.plane {
            if let Some((span, name)) = f
                .min
                .as_ref()
                .map(|v| (v.span(), "min"))
                .or_else(|| f.max.as_ref().map(|v| (v.span(), "max")))
            {
                return Err(self.invalid(
                    span,
                    &key(name),
                    "cannot be given with `plane`: a plane region is `plane` + `value`",
                ));
            }
            let a = match axis.get_ref().as_str() {
                "x" => 0,
                "y" => 1,
                "z" => 2,
                other => {
                    return Err(self.invalid(
                        axis.span(),
                        &key("plane"),
                        format!("is \"{other}\"; expected \"x\", \"y\" or \"z\""),
                    ));
                }
            };
            let Some(value) = &f.value else {
                return Err(self.invalid(axis.span(), &key("plane"), "needs a `value` (m)"));
            };
            return Ok(FixedSpec::Plane { axis: a, value: self.finite(value, &key("value"))? });
        }
        if let Some(value) = &f.value {
            return Err(self.invalid(
                value.span(),
                &key("value"),
                "needs `plane` (the axis the value is a coordinate on)",
            ));
        }
        match (&f.min, &f.max) {
            (Some(min), Some(max)) => {
                let lo = self.finite3(min, &key("min"))?;
                let hi = self.finite3(max, &key("max"))?;
                if (0..3).any(|a| hi[a] < lo[a]) {
                    return Err(self.invalid(
                        max.span(),
                        &key("max"),
                        format!("{hi:?} is below `min` {lo:?}"),
                    ));
                }
                Ok(FixedSpec::Box { min: lo, max: hi })
            }
            (Some(min), None) => {
                Err(self.invalid(min.span(), &key("min"), "needs `max`: a box is `min` + `max`"))
            }
            (None, Some(max)) => {
                Err(self.invalid(max.span(), &key("max"), "needs `min`: a box is `min` + `max`"))
            }
            (None, None) => Err(self.invalid(
                header,
                &format!("fixed[{k}]"),
                "needs `plane` + `value`, `min` + `max`, or `label`",
            )),
        }
    }

    fn counts(&self, v: &Spanned<[i64; 3]>, key: &str, max: i64) -> Result<[usize; 3], SceneError> {
        let a = *v.get_ref();
        if a.iter().all(|&n| (1..=max).contains(&n)) {
            Ok(a.map(|n| n as usize))
        } else {
            Err(self.invalid(
                v.span(),
                key,
                format!("is {a:?}; each entry must be between 1 and {max}"),
            ))
        }
    }
}

impl SceneConfig {
    /// Parses and checks a scene; `file` names the text in errors.
    pub fn from_toml(text: &str, file: &str) -> Result<Self, SceneError> {
        let raw: RawScene = toml::from_str(text).map_err(|e| SceneError::Parse {
            file: file.to_owned(),
            line: e.span().map_or(0, |s| line_of(text, s.start)),
            message: e.message().trim().to_owned(),
        })?;
        let c = Checker { text, file };
        let volume = c.volume(&raw.volume)?;
        let level = match &raw.level {
            Some(l) if !(0..=i64::from(incise_grid::grid::MAX_LEVELS)).contains(l.get_ref()) => {
                return Err(c.invalid(
                    l.span(),
                    "level",
                    format!(
                        "is {}; it must be between 0 and {}",
                        l.get_ref(),
                        incise_grid::grid::MAX_LEVELS
                    ),
                ));
            }
            Some(l) => *l.get_ref() as u32,
            None => 0,
        };
        let mut materials = Vec::new();
        let no_materials: &[Spanned<RawMaterial>] = &[];
        let (materials_at, raw_materials) = match &raw.materials {
            Some(list) => (list.span(), list.get_ref().as_slice()),
            None => (0..0, no_materials),
        };
        for (i, m) in raw_materials.iter().enumerate() {
            let m = m.get_ref();
            let key = |k: &str| format!("materials[{i}].{k}");
            // Damping is one Rayleigh pair for the scene: the implicit system is a·M + b·K with
            // two scalars (its matrix-free product and factorisation rely on that), so a value
            // per tissue would be silently dropped. Refused until per-tissue damping exists.
            if let Some((span, k)) =
                m.rayleigh_mass.as_ref().map(|v| (v.span(), "rayleigh_mass")).or_else(|| {
                    m.rayleigh_stiffness.as_ref().map(|v| (v.span(), "rayleigh_stiffness"))
                })
            {
                return Err(c.invalid(
                    span,
                    &key(k),
                    "is not supported per material yet: damping is set for the whole scene by \
                     `integrator.rayleigh_alpha` (mass) and `integrator.rayleigh_beta` (stiffness)",
                ));
            }
            let label = *m.label.get_ref();
            if !(1..=i64::from(u16::MAX)).contains(&label) {
                return Err(c.invalid(
                    m.label.span(),
                    &key("label"),
                    format!("is {label}; labels are 1..=65535"),
                ));
            }
            if let Some(j) =
                materials.iter().position(|m: &MaterialSpec| i64::from(m.label) == label)
            {
                return Err(c.invalid(
                    m.label.span(),
                    &key("label"),
                    format!("{label} is already materials[{j}]'s label; a label has one material"),
                ));
            }
            let nu = *m.poisson_ratio.get_ref();
            if !(nu > -1.0 && nu < 0.5) {
                return Err(c.invalid(
                    m.poisson_ratio.span(),
                    &key("poisson_ratio"),
                    format!("is {nu}; it must lie in (-1, 0.5)"),
                ));
            }
            let material = incise_grid::Material {
                // From a gel (1 Pa) to steel (2e11 Pa) and beyond; outside, the condensed
                // matrices over- or underflow against the mass.
                youngs_modulus: c.within(
                    &m.youngs_modulus,
                    &key("youngs_modulus"),
                    (1e-3, 1e13),
                    "Pa",
                )?,
                poisson_ratio: nu,
                // Lighter than air to denser than osmium (22,590 kg/m³).
                density: c.within(&m.density, &key("density"), (1e-3, 1e5), "kg/m³")?,
                rayleigh_mass: 0.0,
                rayleigh_stiffness: 0.0,
            };
            materials.push(MaterialSpec { label: label as u16, material });
        }
        if materials.is_empty() {
            // An empty `materials = []` at its line; a missing table at line 1, as serde reports
            // its own "missing field" errors.
            return Err(c.invalid(
                materials_at,
                "materials",
                "is missing: the scene needs at least one `[[materials]]` entry",
            ));
        }
        let mut auto_level = None;
        let mut tensor_mass = None;
        let model = match &raw.model {
            None => ModelKind::Corotational,
            Some(m) => {
                let kind = match m.kind.get_ref().as_str() {
                    "linear" => ModelKind::Linear,
                    "corotational" | "auto" => ModelKind::Corotational,
                    "tensor-mass" => ModelKind::TensorMass,
                    other => {
                        return Err(c.invalid(
                            m.kind.span(),
                            "model.kind",
                            format!(
                                "is \"{other}\"; expected \"linear\", \"corotational\", \"auto\" or \"tensor-mass\""
                            ),
                        ));
                    }
                };
                tensor_mass = c.tensor_mass(m, kind == ModelKind::TensorMass)?;
                if m.kind.get_ref() == "auto" {
                    if let Some(l) = &raw.level {
                        return Err(c.invalid(
                            l.span(),
                            "level",
                            "is chosen by `model.kind = \"auto\"`; remove `level` (or set `model.max_level`)",
                        ));
                    }
                    auto_level = Some(AutoLevel {
                        max_error: match &m.max_error {
                            None => 0.05,
                            Some(e) if *e.get_ref() > 0.0 && *e.get_ref() <= 1.0 => *e.get_ref(),
                            Some(e) => {
                                return Err(c.invalid(
                                    e.span(),
                                    "model.max_error",
                                    format!(
                                        "is {}; it is a relative error in (0, 1], e.g. 0.05",
                                        e.get_ref()
                                    ),
                                ));
                            }
                        },
                        max_level: match &m.max_level {
                            None => 3,
                            Some(l)
                                if (0..=i64::from(incise_grid::grid::MAX_LEVELS))
                                    .contains(l.get_ref()) =>
                            {
                                *l.get_ref() as u32
                            }
                            Some(l) => {
                                return Err(c.invalid(
                                    l.span(),
                                    "model.max_level",
                                    format!(
                                        "is {}; it must be between 0 and {}",
                                        l.get_ref(),
                                        incise_grid::grid::MAX_LEVELS
                                    ),
                                ));
                            }
                        },
                    });
                } else if let Some((span, key)) = m
                    .max_error
                    .as_ref()
                    .map(|e| (e.span(), "model.max_error"))
                    .or_else(|| m.max_level.as_ref().map(|l| (l.span(), "model.max_level")))
                {
                    return Err(c.invalid(span, key, "applies only to `model.kind = \"auto\"`"));
                }
                kind
            }
        };
        let i = &raw.integrator;
        let integrator = match i.kind.get_ref().as_str() {
            "implicit-euler" => IntegratorKind::ImplicitEuler,
            "explicit" => IntegratorKind::Explicit,
            "static" => IntegratorKind::Static,
            other => {
                return Err(c.invalid(
                    i.kind.span(),
                    "integrator.kind",
                    format!(
                        "is \"{other}\"; expected \"implicit-euler\", \"explicit\" or \"static\""
                    ),
                ));
            }
        };
        if model == ModelKind::TensorMass && integrator == IntegratorKind::Static {
            return Err(c.invalid(
                i.kind.span(),
                "integrator.kind",
                "\"static\" is for hexahedra; with `model.kind = \"tensor-mass\"` use \"explicit\" (paper 2's central differences) or \"implicit-euler\"",
            ));
        }
        let mass = match &i.mass {
            None => incise_fem::ode::MassMatrix::Lumped,
            Some(m) => {
                let kind = match m.get_ref().as_str() {
                    "lumped" => incise_fem::ode::MassMatrix::Lumped,
                    "consistent" => incise_fem::ode::MassMatrix::Consistent,
                    other => {
                        return Err(c.invalid(
                            m.span(),
                            "integrator.mass",
                            format!("is \"{other}\"; expected \"lumped\" or \"consistent\""),
                        ));
                    }
                };
                if kind == incise_fem::ode::MassMatrix::Consistent
                    && integrator != IntegratorKind::ImplicitEuler
                {
                    return Err(c.invalid(
                        m.span(),
                        "integrator.mass",
                        "\"consistent\" needs `kind = \"implicit-euler\"` (explicit steps need a diagonal mass)",
                    ));
                }
                kind
            }
        };
        let dt = c.positive(&i.dt, "integrator.dt")?;
        if dt > 1.0 {
            return Err(c.invalid(
                i.dt.span(),
                "integrator.dt",
                format!("is {dt} s; a step above 1 s is not an interactive scene"),
            ));
        }
        let cg_tolerance = match &i.cg_tolerance {
            Some(t) => {
                let v = c.positive(t, "integrator.cg_tolerance")?;
                if v >= 1.0 {
                    return Err(c.invalid(
                        t.span(),
                        "integrator.cg_tolerance",
                        format!("is {v}; it must be below 1"),
                    ));
                }
                v
            }
            None => 1e-6,
        };
        let solver = match &i.solver {
            None => incise_fem::ode::LinearSolver::JacobiCg,
            Some(sv) => match sv.get_ref().as_str() {
                "jacobi-cg" => incise_fem::ode::LinearSolver::JacobiCg,
                "cholesky-cg" => {
                    incise_fem::ode::LinearSolver::CholeskyCg { refresh_iterations: 8 }
                }
                "cholesky" => incise_fem::ode::LinearSolver::Cholesky,
                other => {
                    return Err(c.invalid(sv.span(), "integrator.solver", format!("is \"{other}\"; expected \"jacobi-cg\", \"cholesky-cg\" or \"cholesky\"")));
                }
            },
        };
        if model == ModelKind::TensorMass
            && let Some((span, key, what)) = i
                .solver
                .as_ref()
                .filter(|_| solver != incise_fem::ode::LinearSolver::JacobiCg)
                .map(|v| (v.span(), "integrator.solver", "a sparse factor"))
                .or_else(|| {
                    i.mass
                        .as_ref()
                        .filter(|_| mass == incise_fem::ode::MassMatrix::Consistent)
                        .map(|v| (v.span(), "integrator.mass", "a consistent mass matrix"))
                })
        {
            return Err(c.invalid(
                span,
                key,
                format!("tensor-mass tetrahedra have no {what}; use the default (`solver = \"jacobi-cg\"`, `mass = \"lumped\"`)"),
            ));
        }
        if integrator == IntegratorKind::ImplicitEuler
            && solver == incise_fem::ode::LinearSolver::Cholesky
            && let Some(t) = &i.cg_tolerance
        {
            return Err(c.invalid(
                t.span(),
                "integrator.cg_tolerance",
                "does not apply to `solver = \"cholesky\"`: the implicit step then solves exactly, without CG",
            ));
        }
        if integrator == IntegratorKind::Explicit {
            // An explicit step has no linear solve; and stiffness-proportional damping would cap
            // its stable step near 2/(β ω²) (ω the mesh's highest frequency): microseconds here.
            if let Some((span, key, why)) = i
                .solver
                .as_ref()
                .map(|v| (v.span(), "integrator.solver", "an explicit step solves no linear system"))
                .or_else(|| {
                    i.cg_tolerance.as_ref().map(|v| {
                        (v.span(), "integrator.cg_tolerance", "an explicit step solves no linear system")
                    })
                })
                .or_else(|| {
                    i.rayleigh_beta.as_ref().filter(|b| *b.get_ref() != 0.0).map(|v| {
                        (
                            v.span(),
                            "integrator.rayleigh_beta",
                            "(stiffness damping) would cap an explicit step near 2/(β·ω²) for the mesh's highest frequency ω; use `rayleigh_alpha` or `kind = \"implicit-euler\"`",
                        )
                    })
                })
            {
                return Err(c.invalid(span, key, format!("does not apply to `integrator.kind = \"explicit\"`: {why}")));
            }
        }
        let mut fixed = Vec::new();
        for (k, f) in raw.fixed.iter().enumerate() {
            fixed.push(c.fixed(f, k, &materials)?);
        }
        let mut loads = Vec::new();
        for (k, l) in raw.loads.iter().enumerate() {
            loads.push(PatchLoad {
                centre: c.finite3(&l.centre, &format!("loads[{k}].centre"))?,
                radius: c.positive(&l.radius, &format!("loads[{k}].radius"))?,
                force: c.finite3(&l.force, &format!("loads[{k}].force"))?,
            });
        }
        Ok(Self {
            name: raw.name,
            volume,
            level,
            materials,
            model,
            auto_level,
            tensor_mass,
            integrator,
            dt,
            cg_tolerance,
            solver,
            mass,
            rayleigh_alpha: c.non_negative(
                i.rayleigh_alpha.as_ref(),
                "integrator.rayleigh_alpha",
                0.0,
            )?,
            rayleigh_beta: c.non_negative(
                i.rayleigh_beta.as_ref(),
                "integrator.rayleigh_beta",
                0.0,
            )?,
            gravity: match &raw.gravity {
                Some(g) => c.finite3(g, "gravity")?,
                None => [0.0, 0.0, -9.81],
            },
            fixed,
            loads,
        })
    }
}
