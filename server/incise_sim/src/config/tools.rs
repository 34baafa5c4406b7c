//! `[[tools]]`: the tools of a scene, their shapes, contact, cutting, jaws and scripted path.
//!
//! ```toml
//! [[tools]]
//! name = "scalpel"
//! contact = "points"          # "points" (default: a proxy) or "volume" (a mesh outer shape)
//! coupling_stiffness = 1000.0  # N/m between the device and the proxy (default 1000)
//! coupling_damping = 2.0       # N·s/m (default: critical against a node of the tissue, implicit)
//! max_force = 8.0              # N, the most the coupling pushes the tissue with (default 8)
//! friction = 0.0               # Coulomb μ between the proxy and the tissue (default 0)
//! stiffness = 400.0            # N/m per point of tissue overlapping the proxy (default 500)
//! damping = 0.02               # N·s/m per such point, along the normal (default: stiffness × dt)
//! cutting = "remove"           # "off" (default), "remove" (voxels), "separate" (links)
//! cut_force = 1.0              # N across the inner shape at which it cuts (default 1)
//! outer = { shape = "capsule", radius = 0.002, length = 0.05 }
//! inner = { shape = "blade", length = 0.004, height = 0.003, thickness = 0.001 }
//! # a closed triangle mesh instead: outer = { mesh = "tools/probe.stl", unit = "mm" }
//!
//! [tools.jaws]                 # a grasper
//! length = 0.01
//! width = 0.004
//! close_below = 0.05           # rad
//! open_above = 0.3
//! stiffness = 300.0
//!
//! [[tools.path]]               # scripted waypoints (optional)
//! time = 0.0
//! position = [0.0, 0.0, 0.05]
//! rotation = [1.0, 0.0, 0.0, 0.0]   # w, x, y, z
//! gripper = 0.5
//! ```

use super::{Checker, LengthUnit, SceneError};
use incise_math::Vec3;
use incise_tool::{Jaws, Primitive, Shape, ToolPath, ToolPose, Waypoint};
use serde::Deserialize;
use toml::Spanned;

/// A tool of the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolSpec {
    /// Its name (messages, recordings).
    pub name: String,
    /// The shape that pushes the tissue (`outer`).
    pub outer: ShapeSpec,
    /// The shape that cuts (`inner`), when the tool cuts.
    pub inner: Option<ShapeSpec>,
    /// How its outer shape pushes the tissue (`contact`).
    pub contact: ToolContact,
    /// The virtual coupling between the device and the tool's proxy (`coupling_stiffness`,
    /// `coupling_damping`, `max_force`, `friction`; `contact = "points"` only).
    pub coupling: CouplingSpec,
    /// Penalty stiffness per point of tissue overlapping the proxy (N/m, `stiffness`; default
    /// [`DEFAULT_PENALTY_STIFFNESS`] with `contact = "points"`, 0 and unused with `"volume"`):
    /// what pushes the walls of a cut out of the blade in it, or tissue that moved onto a tool.
    pub stiffness: f64,
    /// Damping per overlapping point along the contact normal, on its velocity relative to the
    /// tool (N·s/m, `damping`). Without the key, `stiffness × dt` (the jaws' stiffness for a
    /// grasp) with an implicit integrator, 0 with an explicit one. A stiff contact resolves a
    /// penetration `d` within one implicit step and leaves the point moving off at `d / dt`,
    /// which throws it out of contact and lets it fall back, frame after frame; damping `k·dt`
    /// closes half the penetration per step without overshoot, so the contact settles, and it
    /// is small beside the contact's stiffness at haptic rates.
    pub damping: Option<f64>,
    /// Whether and how it cuts (`cutting`).
    pub cutting: Cutting,
    /// The force across its inner shape at which it cuts (N, `cut_force`; default
    /// [`DEFAULT_CUT_FORCE`]): paper 1's pressure threshold (Fig. 11) as the coupling's push
    /// through the part of the outer shape in front of the inner one, so a broad tool spreads the
    /// same push over more surface and cuts later than a sharp one.
    pub cut_force: f64,
    /// Its jaws, for a grasper (`[tools.jaws]`).
    pub jaws: Option<Jaws>,
    /// Its scripted path (`[[tools.path]]`), when the scene drives it.
    pub path: Option<ToolPath>,
}

/// The virtual coupling between a tool's device and its proxy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CouplingSpec {
    /// The spring (N/m, `coupling_stiffness`); without the key, [`DEFAULT_COUPLING_STIFFNESS`],
    /// or with an explicit integrator as much of it as the explicit step `h` keeps stable on the
    /// tissue's lightest node `m`: `m / 8h²`.
    pub stiffness: Option<f64>,
    /// The damper (N·s/m, `coupling_damping`); without the key, the critical damping of the
    /// spring against the model's mean node mass `m`, `2 √(k m)` (a tissue node pushed through
    /// the spring takes up the device's speed without ringing), with an implicit integrator; 0
    /// with an explicit one.
    pub damping: Option<f64>,
    /// The largest force it pushes the tissue with (N, `max_force`; default
    /// [`DEFAULT_MAX_FORCE`]).
    pub max_force: f64,
    /// Coulomb friction between the proxy and the tissue (`friction`, ≥ 0; default 0).
    pub friction: f64,
}

impl Default for CouplingSpec {
    fn default() -> Self {
        Self { stiffness: None, damping: None, max_force: DEFAULT_MAX_FORCE, friction: 0.0 }
    }
}

/// The default coupling stiffness (N/m): within what a desktop haptic device renders stably.
pub const DEFAULT_COUPLING_STIFFNESS: f64 = 1000.0;
/// The default largest coupling force (N): a desktop device's continuous maximum.
pub const DEFAULT_MAX_FORCE: f64 = 8.0;
/// The default per-point penalty on tissue overlapping a proxy (N/m).
pub const DEFAULT_PENALTY_STIFFNESS: f64 = 500.0;
/// The default force across a tool's inner shape at which it cuts (N).
pub const DEFAULT_CUT_FORCE: f64 = 1.0;

/// How a tool's outer shape pushes the tissue.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ToolContact {
    /// A proxy that follows the device but never enters the tissue, pushing the surface's
    /// triangles it touches with the coupling's spring (`"points"`, the default): any shape.
    #[default]
    Points,
    /// The volume of the overlap of the tool's closed mesh with the organ's surface, pushed
    /// apart with `[volume_contact]`'s pressure (its defaults without that table), as organs
    /// are pushed from each other (`"volume"`; an `outer = { mesh = … }` shape). It pushes
    /// with the whole overlap's stiffness at once, and sees a tool edge or corner that no
    /// surface point lies inside; it has no swept test: a tool moving more than its own depth
    /// in a step can pass through a thin layer.
    Volume,
}

/// How a tool cuts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cutting {
    /// It does not (`"off"`, the default).
    Off,
    /// It removes the fine voxels whose deformed centres its inner shape contains (paper 1 §3);
    /// in a tensor-mass scene, the tetrahedra whose centroids it contains.
    Remove,
    /// It severs the links between voxels that its inner blade's mid-plane sweeps through,
    /// so no material is lost (`"separate"`; hexahedral scenes, blade inner shapes).
    Separate,
}

/// A shape as the scene gives it.
#[derive(Clone, Debug, PartialEq)]
pub enum ShapeSpec {
    /// A shape ready to use: an analytic one, or a mesh file the scene reader has read.
    Shape(Shape),
    /// A closed triangle mesh file (`.stl`, `.obj`), relative to the scene file, in `unit`,
    /// offset in the tool frame, not read yet (`incise_scene::read_scene` reads it and turns it
    /// into a [`ShapeSpec::Shape`]).
    Mesh {
        /// The file.
        path: String,
        /// The unit of its coordinates.
        unit: LengthUnit,
        /// Where its origin is in the tool frame (m).
        offset: Vec3,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawTool {
    name: Spanned<String>,
    outer: Spanned<RawShape>,
    #[serde(default)]
    inner: Option<Spanned<RawShape>>,
    #[serde(default)]
    contact: Option<Spanned<String>>,
    #[serde(default)]
    stiffness: Option<Spanned<f64>>,
    #[serde(default)]
    damping: Option<Spanned<f64>>,
    #[serde(default)]
    coupling_stiffness: Option<Spanned<f64>>,
    #[serde(default)]
    coupling_damping: Option<Spanned<f64>>,
    #[serde(default)]
    max_force: Option<Spanned<f64>>,
    #[serde(default)]
    friction: Option<Spanned<f64>>,
    #[serde(default)]
    cutting: Option<Spanned<String>>,
    #[serde(default)]
    cut_force: Option<Spanned<f64>>,
    #[serde(default)]
    jaws: Option<Spanned<RawJaws>>,
    #[serde(default)]
    path: Vec<Spanned<RawWaypoint>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawShape {
    shape: Option<Spanned<String>>,
    mesh: Option<Spanned<String>>,
    unit: Option<Spanned<String>>,
    radius: Option<Spanned<f64>>,
    length: Option<Spanned<f64>>,
    height: Option<Spanned<f64>>,
    thickness: Option<Spanned<f64>>,
    half_extents: Option<Spanned<[f64; 3]>>,
    #[serde(default)]
    offset: Option<Spanned<[f64; 3]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawJaws {
    length: Spanned<f64>,
    width: Spanned<f64>,
    close_below: Spanned<f64>,
    open_above: Spanned<f64>,
    stiffness: Spanned<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWaypoint {
    time: Spanned<f64>,
    position: Spanned<[f64; 3]>,
    #[serde(default)]
    rotation: Option<Spanned<[f64; 4]>>,
    #[serde(default)]
    gripper: Option<Spanned<f64>>,
}

/// Stiffer than this per point is a typing error, not a tool (N/m): 1e7 N/m on a single
/// surface point would need steps of nanoseconds even implicitly to resolve anything.
const MAX_STIFFNESS: f64 = 1e7;

impl Checker<'_> {
    /// `[[tools]]`.
    pub(super) fn tools(&self, raw: &[Spanned<RawTool>]) -> Result<Vec<ToolSpec>, SceneError> {
        let mut tools: Vec<ToolSpec> = Vec::new();
        for (k, t) in raw.iter().enumerate() {
            let at = |key: &str| format!("tools[{k}].{key}");
            let raw_tool = t.get_ref();
            let name = raw_tool.name.get_ref().trim().to_owned();
            if name.is_empty() {
                return Err(self.invalid(raw_tool.name.span(), &at("name"), "is empty"));
            }
            if tools.iter().any(|other| other.name == name) {
                return Err(self.invalid(
                    raw_tool.name.span(),
                    &at("name"),
                    format!("{name:?} names two tools; tool names must differ"),
                ));
            }
            let contact = match raw_tool.contact.as_ref().map(|c| (c.span(), c.get_ref().as_str()))
            {
                None | Some((_, "points")) => ToolContact::Points,
                Some((_, "volume")) => ToolContact::Volume,
                Some((span, other)) => {
                    return Err(self.invalid(
                        span,
                        &at("contact"),
                        format!("is {other:?}; expected \"points\" or \"volume\""),
                    ));
                }
            };
            let stiffness = match (&raw_tool.stiffness, contact) {
                (Some(s), ToolContact::Points) => {
                    self.within(s, &at("stiffness"), (0.0, MAX_STIFFNESS), "N/m")?
                }
                (None, ToolContact::Points) => DEFAULT_PENALTY_STIFFNESS,
                (Some(s), ToolContact::Volume) => {
                    return Err(self.invalid(
                        s.span(),
                        &at("stiffness"),
                        "is per surface point, for contact = \"points\"; a tool with contact = \
                         \"volume\" pushes with [volume_contact] pressure",
                    ));
                }
                (None, ToolContact::Volume) => 0.0,
            };
            let damping = match raw_tool.damping.as_ref() {
                Some(_) => {
                    Some(self.non_negative(raw_tool.damping.as_ref(), &at("damping"), 0.0)?)
                }
                None => None,
            };
            let coupling = self.coupling(raw_tool, contact, k)?;
            let outer = self.shape(&raw_tool.outer, &at("outer"))?;
            if contact == ToolContact::Volume && !matches!(outer, ShapeSpec::Mesh { .. }) {
                let span = raw_tool.contact.as_ref().map_or(t.span(), Spanned::span);
                return Err(self.invalid(
                    span,
                    &at("contact"),
                    "\"volume\" measures the overlap of a closed surface: the outer shape must \
                     be a mesh (outer = { mesh = \"…\" })",
                ));
            }
            let inner = raw_tool.inner.as_ref().map(|s| self.shape(s, &at("inner"))).transpose()?;
            let cutting = match raw_tool.cutting.as_ref().map(|c| (c.span(), c.get_ref().as_str()))
            {
                None | Some((_, "off")) => Cutting::Off,
                Some((_, "remove")) => Cutting::Remove,
                Some((_, "separate")) => Cutting::Separate,
                Some((span, other)) => {
                    return Err(self.invalid(
                        span,
                        &at("cutting"),
                        format!("is {other:?}; expected \"off\", \"remove\" or \"separate\""),
                    ));
                }
            };
            if cutting != Cutting::Off {
                let span = raw_tool.cutting.as_ref().map_or(t.span(), Spanned::span);
                match &inner {
                    None => {
                        return Err(self.invalid(
                            span,
                            &at("cutting"),
                            "needs an `inner` shape: the part of the tool that cuts",
                        ));
                    }
                    Some(ShapeSpec::Shape(s))
                        if cutting == Cutting::Separate
                            && !matches!(s.primitive(), Some(Primitive::Blade { .. })) =>
                    {
                        return Err(self.invalid(
                            span,
                            &at("cutting"),
                            "\"separate\" severs links along a blade's mid-plane: the inner \
                             shape must be a `blade`",
                        ));
                    }
                    Some(ShapeSpec::Mesh { .. }) if cutting == Cutting::Separate => {
                        return Err(self.invalid(
                            span,
                            &at("cutting"),
                            "\"separate\" needs a `blade` inner shape, not a mesh",
                        ));
                    }
                    Some(_) => {}
                }
            }
            let cut_force = match &raw_tool.cut_force {
                Some(f) if cutting == Cutting::Off => {
                    return Err(self.invalid(
                        f.span(),
                        &at("cut_force"),
                        "is the force at which the tool cuts; it needs `cutting`",
                    ));
                }
                Some(f) => self.positive(f, &at("cut_force"))?,
                None => DEFAULT_CUT_FORCE,
            };
            let jaws = raw_tool.jaws.as_ref().map(|j| self.jaws(j, k)).transpose()?;
            let path =
                if raw_tool.path.is_empty() { None } else { Some(self.path(&raw_tool.path, k)?) };
            tools.push(ToolSpec {
                name,
                outer,
                inner,
                contact,
                coupling,
                stiffness,
                damping,
                cutting,
                cut_force,
                jaws,
                path,
            });
        }
        Ok(tools)
    }

    fn shape(&self, s: &Spanned<RawShape>, key: &str) -> Result<ShapeSpec, SceneError> {
        let raw = s.get_ref();
        let offset = match &raw.offset {
            Some(o) => self.finite3(o, &format!("{key}.offset"))?,
            None => [0.0; 3],
        };
        if let Some(path) = &raw.mesh {
            let extra = [
                (raw.shape.as_ref().map(Spanned::span), "shape"),
                (raw.radius.as_ref().map(Spanned::span), "radius"),
                (raw.length.as_ref().map(Spanned::span), "length"),
                (raw.height.as_ref().map(Spanned::span), "height"),
                (raw.thickness.as_ref().map(Spanned::span), "thickness"),
                (raw.half_extents.as_ref().map(Spanned::span), "half_extents"),
            ];
            if let Some((Some(span), name)) = extra.into_iter().find(|(s, _)| s.is_some()) {
                return Err(self.invalid(
                    span,
                    &format!("{key}.{name}"),
                    "describes an analytic shape; it cannot be given with `mesh`",
                ));
            }
            let unit = self.unit(raw.unit.as_ref(), &format!("{key}.unit"))?;
            return Ok(ShapeSpec::Mesh { path: path.get_ref().clone(), unit, offset });
        }
        if let Some(unit) = &raw.unit {
            return Err(self.invalid(
                unit.span(),
                &format!("{key}.unit"),
                "applies only to `mesh`",
            ));
        }
        let Some(kind) = &raw.shape else {
            return Err(self.invalid(
                s.span(),
                key,
                "needs `shape` (\"sphere\", \"capsule\", \"box\", \"blade\") or `mesh`",
            ));
        };
        let need = |v: &Option<Spanned<f64>>, name: &str| -> Result<f64, SceneError> {
            match v {
                Some(v) => self.positive(v, &format!("{key}.{name}")),
                None => Err(self.invalid(
                    kind.span(),
                    &format!("{key}.{name}"),
                    format!("is missing: a {} needs it", kind.get_ref()),
                )),
            }
        };
        // Keys another primitive takes are refused, so a misplaced size is not silently unused.
        let allowed: &[&str] = match kind.get_ref().as_str() {
            "sphere" => &["radius"],
            "capsule" => &["radius", "length"],
            "box" => &["half_extents"],
            "blade" => &["length", "height", "thickness"],
            other => {
                return Err(self.invalid(
                    kind.span(),
                    &format!("{key}.shape"),
                    format!("is {other:?}; expected \"sphere\", \"capsule\", \"box\" or \"blade\""),
                ));
            }
        };
        let given = [
            (raw.radius.as_ref().map(Spanned::span), "radius"),
            (raw.length.as_ref().map(Spanned::span), "length"),
            (raw.height.as_ref().map(Spanned::span), "height"),
            (raw.thickness.as_ref().map(Spanned::span), "thickness"),
            (raw.half_extents.as_ref().map(Spanned::span), "half_extents"),
        ];
        for (span, name) in given {
            if let Some(span) = span
                && !allowed.contains(&name)
            {
                return Err(self.invalid(
                    span,
                    &format!("{key}.{name}"),
                    format!("is not a size of a {}", kind.get_ref()),
                ));
            }
        }
        let primitive = match kind.get_ref().as_str() {
            "sphere" => Primitive::Sphere { radius: need(&raw.radius, "radius")? },
            "capsule" => Primitive::Capsule {
                radius: need(&raw.radius, "radius")?,
                length: need(&raw.length, "length")?,
            },
            "box" => {
                let Some(h) = &raw.half_extents else {
                    return Err(self.invalid(
                        kind.span(),
                        &format!("{key}.half_extents"),
                        "is missing: a box needs it",
                    ));
                };
                let half_extents = self.finite3(h, &format!("{key}.half_extents"))?;
                Primitive::Cuboid { half_extents }
            }
            _ => Primitive::Blade {
                length: need(&raw.length, "length")?,
                height: need(&raw.height, "height")?,
                thickness: need(&raw.thickness, "thickness")?,
            },
        };
        Shape::new(primitive, offset)
            .map(ShapeSpec::Shape)
            .map_err(|e| self.invalid(s.span(), key, e.to_string()))
    }

    /// A tool's coupling keys; a tool with `contact = "volume"` has no proxy and takes none.
    fn coupling(
        &self,
        raw: &RawTool,
        contact: ToolContact,
        k: usize,
    ) -> Result<CouplingSpec, SceneError> {
        let at = |key: &str| format!("tools[{k}].{key}");
        let keys = [
            (&raw.coupling_stiffness, "coupling_stiffness"),
            (&raw.coupling_damping, "coupling_damping"),
            (&raw.max_force, "max_force"),
            (&raw.friction, "friction"),
        ];
        if contact == ToolContact::Volume {
            if let Some((Some(v), name)) = keys.into_iter().find(|(v, _)| v.is_some()) {
                return Err(self.invalid(
                    v.span(),
                    &at(name),
                    "belongs to a tool's proxy; a tool with contact = \"volume\" has none (it \
                     pushes with [volume_contact] pressure)",
                ));
            }
            return Ok(CouplingSpec::default());
        }
        let stiffness = match &raw.coupling_stiffness {
            Some(s) => {
                Some(self.within(s, &at("coupling_stiffness"), (0.0, MAX_STIFFNESS), "N/m")?)
            }
            None => None,
        };
        let damping = match raw.coupling_damping.as_ref() {
            Some(_) => Some(self.non_negative(
                raw.coupling_damping.as_ref(),
                &at("coupling_damping"),
                0.0,
            )?),
            None => None,
        };
        let max_force = match &raw.max_force {
            Some(f) => self.positive(f, &at("max_force"))?,
            None => DEFAULT_MAX_FORCE,
        };
        let friction = self.non_negative(raw.friction.as_ref(), &at("friction"), 0.0)?;
        Ok(CouplingSpec { stiffness, damping, max_force, friction })
    }

    fn jaws(&self, j: &Spanned<RawJaws>, k: usize) -> Result<Jaws, SceneError> {
        let raw = j.get_ref();
        let at = |key: &str| format!("tools[{k}].jaws.{key}");
        let jaws = Jaws {
            length: self.positive(&raw.length, &at("length"))?,
            width: self.positive(&raw.width, &at("width"))?,
            close_below: self.within(&raw.close_below, &at("close_below"), (0.0, 3.2), "rad")?,
            open_above: self.within(&raw.open_above, &at("open_above"), (0.0, 3.2), "rad")?,
            stiffness: self.within(
                &raw.stiffness,
                &at("stiffness"),
                (0.0, MAX_STIFFNESS),
                "N/m",
            )?,
        };
        if jaws.open_above <= jaws.close_below {
            return Err(self.invalid(
                raw.open_above.span(),
                &at("open_above"),
                format!(
                    "is {}; it must be above close_below ({}), or the jaws would open and close \
                     at the same angle",
                    jaws.open_above, jaws.close_below
                ),
            ));
        }
        Ok(jaws)
    }

    fn path(&self, raw: &[Spanned<RawWaypoint>], k: usize) -> Result<ToolPath, SceneError> {
        let mut waypoints = Vec::new();
        for (i, w) in raw.iter().enumerate() {
            let at = |key: &str| format!("tools[{k}].path[{i}].{key}");
            let r = w.get_ref();
            let time = self.finite(&r.time, &at("time"))?;
            if let Some(last) = waypoints.last().map(|p: &Waypoint| p.time)
                && time <= last
            {
                return Err(self.invalid(
                    r.time.span(),
                    &at("time"),
                    format!("is {time} s; waypoints must come in increasing time (the previous is at {last} s)"),
                ));
            }
            let position = self.finite3(&r.position, &at("position"))?;
            let rotation = r.rotation.as_ref().map_or([1.0, 0.0, 0.0, 0.0], |q| *q.get_ref());
            let gripper = match &r.gripper {
                Some(g) => self.within(g, &at("gripper"), (0.0, 3.2), "rad")?,
                None => 0.0,
            };
            let pose = ToolPose::new(position, rotation, gripper).map_err(|e| {
                let span = r.rotation.as_ref().map_or(r.position.span(), Spanned::span);
                self.invalid(span, &at("rotation"), e.to_string())
            })?;
            waypoints.push(Waypoint { time, pose });
        }
        ToolPath::new(waypoints).map_err(|e| {
            self.invalid(
                raw.first().map_or(0..0, Spanned::span),
                &format!("tools[{k}].path"),
                e.to_string(),
            )
        })
    }
}
