//! The surgical frame (Jeřábková 2010, §3; §4.1 for where its time goes): each step every posed
//! tool's proxy moves toward its device and stops on the deformed tissue (`incise_tool::proxy`),
//! pushes the surface's triangles it touches with the coupling's spring, cuts with its inner
//! shape once the push across that shape passes the tool's threshold (the proxy then moves into
//! the space the cut opened), and holds with its jaws; a cut updates the grid, the model and
//! solver state, and the surface locally, in that order, within the step; then the mechanics is
//! solved with the proxies' and the jaws' springs as force fields beside the tissue's, and each
//! tool's force, torque and their linearisation in the device's pose are read from the springs
//! at the new positions.
//!
//! A tool that is given no pose (and has no scripted path) takes no part; one that stops being
//! given poses stays where it was last put, as a hand that lets go of a haptic device leaves
//! the instrument in place. A tool first posed inside the tissue gets its proxy once its device
//! is brought out: a proxy is never placed in tissue.

mod cut;
mod inside;
mod proxy;
mod surface;
mod volume;

pub use surface::OrganSurface;

pub(crate) use volume::VolumeContact;
use volume::{Nodes, PosedMesh};

use super::keyframe::ToolState;
use super::{CutError, InputError, Simulation, StageCounters, StepInputs};
use crate::config::{Cutting, ShapeSpec, ToolContact, ToolSpec};
use cut::DeformedGrid;
use incise_fem::Executor;
use incise_fem::forcefield::springs::{EmbeddedSpring, EmbeddedSprings};
use incise_fem::forcefield::volume::VolumePenalty;
use incise_grid::GridEdit;
use incise_math::Vec3;
use incise_surface::{SurfaceChanges, SurfaceOptions};
use incise_tool::{
    ContactSettings, Coupling, Grasp, GraspEvent, Linearisation, Pose, Shape, SweptBlade, ToolPose,
    proxy::{Facet, Touch},
};
use proxy::{Body, Cut, ProxyStep, TissueView};
use std::ops::Range;
use std::time::Instant;

/// The organ's surface, or part of it, for drawing ([`Simulation::surface_geometry`]). Ids are
/// the surface's slots: stable while the topology is, reused after a cut.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfaceGeometry {
    /// The vertices' ids, ascending.
    pub vertex_ids: Vec<u32>,
    /// Their deformed positions (m, grid frame), in `vertex_ids`' order.
    pub positions: Vec<[f32; 3]>,
    /// The triangles' ids, ascending.
    pub triangle_ids: Vec<u32>,
    /// Their corners as vertex ids, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Each triangle's tissue label: the label of the voxel that owns its first corner (0 on a
    /// tensor-mass surface, whose triangles carry no label).
    pub triangle_labels: Vec<u16>,
}

/// The live triangles among `ids` (every live one when `None`) of `surface`, with their labels
/// (`grid`: the voxel surface's grid).
fn surface_triangles(
    surface: &OrganSurface,
    grid: Option<&incise_grid::BranchedGrid>,
    ids: Option<&[u32]>,
) -> (Vec<u32>, Vec<[u32; 3]>, Vec<u16>) {
    let slots = surface.triangle_slots();
    let live = |&id: &u32| slots.get(id as usize).is_some_and(|t| t.alive);
    let ids: Vec<u32> = match ids {
        Some(ids) => ids.iter().copied().filter(live).collect(),
        None => (0..slots.len() as u32).filter(live).collect(),
    };
    let corners: Vec<[u32; 3]> = ids.iter().map(|&id| slots[id as usize].v).collect();
    let labels = match (surface, grid) {
        (OrganSurface::Voxels { surface, .. }, Some(grid)) => {
            let by_material: Vec<u16> = grid.materials().map(|(label, _)| label).collect();
            let vertices = surface.vertices();
            corners
                .iter()
                .map(|t| {
                    grid.fine()
                        .material(vertices[t[0] as usize].voxel)
                        .and_then(|m| by_material.get(usize::from(m)).copied())
                        .unwrap_or(0)
                })
                .collect()
        }
        _ => vec![0; corners.len()],
    };
    (ids, corners, labels)
}

/// A pose for one of the scene's tools, for one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolInput {
    /// The tool's index in the scene's `[[tools]]`.
    pub tool: usize,
    /// Where it is, and its gripper angle.
    pub pose: ToolPose,
}

/// What one tool did in a step.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolFrame {
    /// Its device's pose this step (`None`: it takes no part yet).
    pub pose: Option<ToolPose>,
    /// Its proxy's pose this step: where the tissue feels the tool (`None`: no proxy, for a tool
    /// not posed yet, one whose device has been inside the tissue since it was first posed, or
    /// one with `contact = "volume"`, which acts from its device's pose).
    pub proxy: Option<Pose>,
    /// Points where its proxy touches the surface's triangles (with `contact = "volume"`, see
    /// `overlap_volume`).
    pub contact_points: usize,
    /// The force its proxy pushed the tissue with across its inner shape at the step's start
    /// (N): what its `cut_force` is compared with.
    pub across_inner: f64,
    /// Points its jaws hold.
    pub held_points: usize,
    /// With `contact = "volume"`: the volume by which its mesh overlapped the tissue at the
    /// step's start (m³); `contact_points` counts the surface vertices bounding that overlap.
    pub overlap_volume: f64,
    /// What its jaws did.
    pub grasp: GraspEvent,
    /// The force and torque the tissue puts on it at the end of the step, and their derivative
    /// in its pose, for a haptic loop to extrapolate between steps.
    pub linearisation: Linearisation,
}

impl ToolFrame {
    /// The force on the tool (N).
    #[must_use]
    pub fn force(&self) -> Vec3 {
        self.linearisation.force
    }

    /// The torque on the tool about its origin (N·m).
    #[must_use]
    pub fn torque(&self) -> Vec3 {
        self.linearisation.torque
    }
}

/// A cut a tool made in a step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CutEvent {
    /// The tool's index.
    pub tool: usize,
    /// Fine voxels removed.
    pub voxels_removed: usize,
    /// Links between voxels severed.
    pub links_severed: usize,
    /// Tetrahedra removed (tensor-mass scenes).
    pub tets_removed: usize,
}

/// What the surgical part of a step adds to its frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurgicalFrame {
    /// Each tool's part, in scene order (empty in a scene without tools).
    pub tools: Vec<ToolFrame>,
    /// The cuts made.
    pub cuts: Vec<CutEvent>,
    /// What the cuts did to the grid: the voxels removed and the links severed, sorted (what a
    /// recording needs to replay them).
    pub edit: GridEdit,
    /// The tetrahedra removed (tensor-mass scenes), in order of removal.
    pub tets_removed: Vec<usize>,
    /// How the surface changed.
    pub surface: SurfaceChanges,
}

/// One tool as the simulation drives it.
pub(crate) struct ToolRig {
    spec: ToolSpec,
    outer: Shape,
    inner: Option<Shape>,
    /// What its proxy's cuts remove and what stops it until they have: in a voxel scene that
    /// removes, the inner shape grown by half a voxel, so that tissue it presses aside by a
    /// little is still what it cuts (a blade thinner than a voxel would otherwise wedge the
    /// voxels ahead apart and slip between them); otherwise the inner shape.
    cutter: Option<Shape>,
    /// Its device's pose.
    pose: Option<ToolPose>,
    /// Its device's pose at the previous step: the device's velocity, a blade's sweep.
    previous: Option<Pose>,
    /// Its proxy's pose.
    proxy: Option<Pose>,
    /// Where its proxy started the step under way (`None`: placed afresh): the carry measures
    /// how far tissue came into it against that.
    step_start: Option<Pose>,
    /// The penalty on tissue overlapping its proxy (the damping resolved from the implicit step
    /// when the tool names none).
    contact: ContactSettings,
    /// The coupling between its device and its proxy (likewise resolved).
    coupling: Coupling,
    /// Its grasp's damping per point (N·s/m).
    grasp_damping: f64,
    grasp: Grasp,
    /// With `contact = "volume"`: its outer mesh in the tool frame (vertices, outward
    /// triangles), measured against the tissue by volume contact instead of point by point.
    volume_mesh: Option<(Vec<Vec3>, Vec<[u32; 3]>)>,
}

/// The tools, the volume contact, and the surface they act on.
pub(crate) struct Surgery {
    rigs: Vec<ToolRig>,
    surface: OrganSurface,
    /// Deformed surface positions (per vertex slot), as of the state at the start of step
    /// `deformed_at` (or after that step's cut).
    positions: Vec<Vec3>,
    deformed_at: Option<u64>,
    volume: Option<VolumeContact>,
}

/// What the tools' defaults depend on: the scene's step and its tissue's nodes.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct ToolDefaults {
    /// The implicit step (s; 0 with an explicit integrator).
    pub(crate) implicit_dt: f64,
    /// The model's mean node mass (kg).
    pub(crate) node_mass: f64,
    /// With an explicit integrator: the stiffest default coupling its step keeps stable on the
    /// lightest node (N/m).
    pub(crate) explicit_limit: Option<f64>,
    /// In a voxel scene, the fine voxels' largest edge (m).
    pub(crate) voxel: Option<f64>,
}

impl ToolDefaults {
    /// A tool's coupling with the scene's defaults filled in.
    fn coupling(&self, spec: &crate::config::CouplingSpec) -> Coupling {
        let stiffness = spec.stiffness.unwrap_or_else(|| {
            let limit = self.explicit_limit.unwrap_or(f64::INFINITY);
            crate::config::DEFAULT_COUPLING_STIFFNESS.min(limit)
        });
        // Critical damping of the coupling spring against a node of the tissue: the tissue
        // under a proxy that starts pushing it takes up the device's speed without ringing on
        // the spring. An explicit step damps nothing it does not have to.
        let damping = spec.damping.unwrap_or(if self.implicit_dt > 0.0 {
            2.0 * (stiffness * self.node_mass).sqrt()
        } else {
            0.0
        });
        Coupling { stiffness, damping, max_force: spec.max_force, friction: spec.friction }
    }
}

/// The springs of the step's tools: all of them as one field, and which belong to which tool.
pub(crate) struct ToolSprings {
    pub(crate) field: EmbeddedSprings,
    ranges: Vec<Option<Range<usize>>>,
    /// Where each tool's proxy touched the surface, and the triangles around it: what carries
    /// the proxy after the step.
    touches: Vec<(Vec<Touch>, Vec<Facet>)>,
}

impl Surgery {
    /// After a re-mesh: the volume contact notes the new walls.
    fn surface_changed(&mut self, changes: &SurfaceChanges) {
        if let Some(volume) = &mut self.volume {
            volume.surface_changed(changes);
        }
    }

    /// Adds volume contact.
    pub(crate) fn set_volume_contact(&mut self, volume: VolumeContact) {
        self.volume = Some(volume);
    }

    /// The volume contact, if the scene has one.
    pub(crate) fn volume_contact_mut(&mut self) -> Option<&mut VolumeContact> {
        self.volume.as_mut()
    }

    /// The volume contact, if the scene has one.
    pub(crate) fn volume_contact(&self) -> Option<&VolumeContact> {
        self.volume.as_ref()
    }

    /// The tools of `tools` on `surface`, in a scene whose step and tissue `tissue` describes
    /// (the tools' defaults); refuses a shape the scene reader did not load.
    pub(crate) fn new(
        tools: &[ToolSpec],
        surface: OrganSurface,
        tissue: &ToolDefaults,
    ) -> Result<Self, String> {
        let dt = tissue.implicit_dt;
        let shape = |s: &ShapeSpec, name: &str, which: &str| match s {
            ShapeSpec::Shape(shape) => Ok(shape.clone()),
            ShapeSpec::Mesh { path, .. } => Err(format!(
                "tool {name:?}: its {which} shape is the mesh file {path}, which was not read \
                 (scenes with mesh tools are read by incise_scene::read_scene)"
            )),
        };
        let rigs = tools
            .iter()
            .map(|t| {
                let outer = shape(&t.outer, &t.name, "outer")?;
                let volume_mesh = match t.contact {
                    ToolContact::Points => None,
                    ToolContact::Volume => {
                        let Some((vertices, triangles)) = outer.closed_surface() else {
                            return Err(format!(
                                "tool {:?}: contact = \"volume\" needs a mesh outer shape",
                                t.name
                            ));
                        };
                        Some((vertices, triangles.to_vec()))
                    }
                };
                Ok(ToolRig {
                    outer,
                    volume_mesh,
                    inner: t.inner.as_ref().map(|s| shape(s, &t.name, "inner")).transpose()?,
                    cutter: match (&t.inner, t.cutting, tissue.voxel) {
                        (Some(s), Cutting::Remove, Some(voxel)) => {
                            Some(shape(s, &t.name, "inner")?.inflated(0.25 * voxel))
                        }
                        (Some(s), _, _) => Some(shape(s, &t.name, "inner")?),
                        (None, _, _) => None,
                    },
                    spec: t.clone(),
                    pose: None,
                    previous: None,
                    proxy: None,
                    step_start: None,
                    contact: ContactSettings {
                        // An explicit step integrates the penalty as it does the coupling: no
                        // stiffer than it keeps stable on the lightest node. The walls of a
                        // voxel cut may start a voxel deep in the tool, and a stiffer penalty
                        // would throw them out.
                        stiffness: t.stiffness.min(tissue.explicit_limit.unwrap_or(f64::INFINITY)),
                        damping: t.damping.unwrap_or(dt * t.stiffness),
                    },
                    coupling: tissue.coupling(&t.coupling),
                    grasp_damping: t
                        .damping
                        .unwrap_or_else(|| t.jaws.map_or(0.0, |j| dt * j.stiffness)),
                    grasp: Grasp::default(),
                })
            })
            .collect::<Result<Vec<_>, String>>()?;
        Ok(Self { rigs, surface, positions: Vec::new(), deformed_at: None, volume: None })
    }

    /// Each tool's part of a keyframe.
    pub(crate) fn tool_states(&self) -> Vec<ToolState> {
        self.rigs
            .iter()
            .map(|rig| ToolState { pose: rig.pose, proxy: rig.proxy, grasp: rig.grasp.clone() })
            .collect()
    }

    /// Restores each tool's part of a keyframe.
    pub(crate) fn restore_tools(&mut self, tools: &[ToolState]) -> Result<(), String> {
        if tools.len() != self.rigs.len() {
            return Err(format!("{} tools for the scene's {}", tools.len(), self.rigs.len()));
        }
        for (rig, state) in self.rigs.iter_mut().zip(tools) {
            // The next step moves `pose` to `previous` before it takes the new pose.
            rig.pose = state.pose;
            rig.proxy = state.proxy;
            rig.grasp = state.grasp.clone();
        }
        Ok(())
    }

    /// The tools' count.
    pub(crate) fn tool_count(&self) -> usize {
        self.rigs.len()
    }
}

/// The scene's surface groups: one closed surface of all the organ's materials, or one per
/// material with `[surface] interfaces = true`.
pub(crate) fn surface_options(
    config: &crate::SceneConfig,
    grid: &incise_grid::BranchedGrid,
) -> SurfaceOptions {
    if config.surface.interfaces {
        SurfaceOptions::per_material(grid.materials().count() as u16)
    } else {
        SurfaceOptions::default()
    }
}

impl Simulation {
    /// Checks this step's tool inputs before anything moves: each names a tool of the scene
    /// (their poses were checked where they were made: a [`ToolPose`] cannot hold a bad one).
    pub(super) fn check_tools(&self, inputs: &StepInputs) -> Result<(), InputError> {
        let tools = self.surgery.as_ref().map_or(0, |s| s.tool_count());
        for (entry, input) in inputs.tools.iter().enumerate() {
            if input.tool >= tools {
                return Err(InputError::NoSuchTool { entry, tool: input.tool, tools });
            }
        }
        Ok(())
    }

    /// The surgical part of a step before the mechanics: poses, contact, grasping, cutting and
    /// the updates a cut makes. Returns the springs to solve with (`None` when no tool takes
    /// part).
    pub(super) fn prepare_tools(
        &mut self,
        inputs: &StepInputs,
        counters: &mut StageCounters,
        frame: &mut SurgicalFrame,
    ) -> Result<Option<ToolSprings>, CutError> {
        let Some(mut surgery) = self.surgery.take() else { return Ok(None) };
        let result = self.prepare_with(&mut surgery, inputs, counters, frame);
        self.surgery = Some(surgery);
        result
    }

    fn prepare_with(
        &mut self,
        surgery: &mut Surgery,
        inputs: &StepInputs,
        counters: &mut StageCounters,
        frame: &mut SurgicalFrame,
    ) -> Result<Option<ToolSprings>, CutError> {
        // Positions deformed before this step (by an earlier step, or before a cut or a
        // restore between steps) are not this step's.
        surgery.deformed_at = None;
        let dt = self.config.dt();
        let now = self.index as f64 * dt;
        for rig in &mut surgery.rigs {
            rig.previous = rig.pose.map(|p| *p.pose());
        }
        for (i, rig) in surgery.rigs.iter_mut().enumerate() {
            let given = inputs.tools.iter().rev().find(|t| t.tool == i).map(|t| t.pose);
            let scripted = rig.spec.path.as_ref().map(|p| p.at(now));
            rig.pose = given.or(scripted).or(rig.pose);
        }
        frame.tools = surgery
            .rigs
            .iter()
            .map(|rig| ToolFrame {
                pose: rig.pose,
                proxy: None,
                contact_points: 0,
                across_inner: 0.0,
                held_points: 0,
                overlap_volume: 0.0,
                grasp: GraspEvent::None,
                linearisation: Linearisation::none(
                    rig.pose.map_or([0.0; 3], |p| p.pose().position()),
                ),
            })
            .collect();
        if surgery.rigs.iter().all(|r| r.pose.is_none()) {
            return Ok(None);
        }

        let t = Instant::now();
        self.deform_surface(surgery);
        counters.surface_ns += elapsed(t);

        let t = Instant::now();
        let mut steps = self.step_proxies(surgery, None);
        let Surgery { rigs, surface, positions, .. } = &mut *surgery;
        for (i, rig) in rigs.iter_mut().enumerate() {
            let (Some(device), Some(jaws)) = (rig.pose, rig.spec.jaws) else { continue };
            let Some(felt) = rig.felt_pose() else { continue };
            // A tool pushing by volume has no proxy: it touches where a surface point lies
            // inside its mesh (from this step's positions alone, so that a keyframe restores
            // what its jaws do).
            let touching = steps[i].as_ref().is_some_and(|s| !s.touches.is_empty())
                || (!rig.has_proxy() && holds_a_point(&rig.outer, &felt, surface, positions));
            let points = surface.live_vertices().iter().map(|&v| (v, positions[v as usize]));
            frame.tools[i].grasp =
                rig.grasp.update(&jaws, &felt, device.gripper(), touching, points);
        }
        counters.contact_ns += elapsed(t);

        let cut_step = std::cell::OnceCell::new();
        let cuts: Vec<Option<Cut>> = surgery
            .rigs
            .iter()
            .zip(&steps)
            .map(|(rig, pushed)| {
                let step = || *cut_step.get_or_init(|| self.cut_step(&surgery.surface));
                rig.cut(pushed.as_ref(), &step)
            })
            .collect();
        for (tool, step) in frame.tools.iter_mut().zip(&steps) {
            tool.across_inner = step.as_ref().map_or(0.0, |s| s.push.across_inner);
        }
        let cut = self.cut_with_tools(surgery, &cuts, counters, frame)?;
        if !cut.is_empty() {
            // The cut renumbered the nodes and moved the surface: the proxies that cut move into
            // the space they opened, and every proxy finds its touches again on the surface as
            // it now is.
            let t = Instant::now();
            self.deform_surface(surgery);
            counters.surface_ns += elapsed(t);
            let t = Instant::now();
            let surface = &surgery.surface;
            for rig in &mut surgery.rigs {
                rig.grasp.retain(|v| surface.is_live(v));
            }
            let mut entered: Vec<Option<Pose>> = surgery.rigs.iter().map(|r| r.proxy).collect();
            for (i, at) in cut {
                surgery.rigs[i].enter_cut(&at);
                entered[i] = surgery.rigs[i].proxy;
            }
            steps = self.step_proxies(surgery, Some(&entered));
            counters.contact_ns += elapsed(t);
        }

        let mut springs: Vec<EmbeddedSpring> = Vec::new();
        let mut ranges = Vec::with_capacity(surgery.rigs.len());
        let mut touches = Vec::with_capacity(surgery.rigs.len());
        for (i, (rig, step)) in surgery.rigs.iter_mut().zip(steps).enumerate() {
            frame.tools[i].proxy = if rig.has_proxy() { rig.proxy } else { None };
            let (Some(_), Some(felt)) = (rig.pose, rig.felt_pose()) else {
                ranges.push(None);
                touches.push((Vec::new(), Vec::new()));
                continue;
            };
            let start = springs.len();
            if let Some(step) = step {
                frame.tools[i].contact_points = step.touches.len();
                springs.extend(step.push.springs);
                touches.push((step.touches, step.facets));
            } else {
                touches.push((Vec::new(), Vec::new()));
            }
            if let Some(jaws) = &rig.spec.jaws {
                let surface = &surgery.surface;
                let previous = rig.previous.as_ref().map(|p| (p, self.config.dt()));
                let held = rig.grasp.springs(jaws, &felt, previous, rig.grasp_damping, |v| {
                    surface.is_live(v).then(|| surface.embedding(v))
                });
                frame.tools[i].held_points = held.len();
                springs.extend(held);
            }
            ranges.push(Some(start..springs.len()));
        }
        counters.contact_points = springs.len();
        let exec = Executor::single_thread();
        Ok(Some(ToolSprings { field: EmbeddedSprings::new(springs, exec), ranges, touches }))
    }

    /// Moves every posed tool's proxy (from `from`, each tool's, when given; from where it is
    /// otherwise) and finds what it touches and pushes.
    fn step_proxies(
        &self,
        surgery: &mut Surgery,
        from: Option<&[Option<Pose>]>,
    ) -> Vec<Option<ProxyStep>> {
        let Surgery { rigs, surface, positions, .. } = surgery;
        let by_grid_node = self.positions_by_grid_node();
        let body = match (self.grid(), self.tet()) {
            (Some(grid), _) => Body::Hex { grid, by_grid_node: &by_grid_node },
            (None, Some(tet)) => Body::Tet { topology: &tet.topology, x: &self.state.x },
            (None, None) => return rigs.iter().map(|_| None).collect(),
        };
        let view = TissueView { surface, positions, body };
        let embedding = |v: u32| surface.embedding(v);
        let dt = self.config.dt();
        rigs.iter_mut()
            .enumerate()
            .map(|(i, rig)| {
                let start = from.map_or(rig.proxy, |f| f[i]);
                rig.step_proxy(&view, start, dt, &embedding)
            })
            .collect()
    }

    /// The step by which a tool's inner shape looks ahead of its outer shape's touch for
    /// material to cut: a fine voxel's largest edge, or a tetrahedral surface's mean edge.
    fn cut_step(&self, surface: &OrganSurface) -> f64 {
        if let Some(grid) = self.grid() {
            return grid.spacing().into_iter().fold(0.0, f64::max);
        }
        let positions = &self.state.x;
        let (mut sum, mut count) = (0.0, 0usize);
        for t in surface.triangle_slots().iter().filter(|t| t.alive) {
            for e in 0..3 {
                let (a, b) = (positions[t.v[e] as usize], positions[t.v[(e + 1) % 3] as usize]);
                sum += (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
                count += 1;
            }
        }
        if count == 0 { 0.0 } else { sum / count as f64 }
    }

    /// After the mechanics: each tool's force, torque and linearisation at the new positions.
    /// The tissue that moved toward a proxy during the step carries it along.
    pub(super) fn finish_tools(&mut self, springs: &ToolSprings, frame: &mut SurgicalFrame) {
        let all = springs.field.springs();
        for (tool, range) in frame.tools.iter_mut().zip(&springs.ranges) {
            if let (Some(pose), Some(range)) = (tool.pose, range) {
                let (x, v, origin) = (&self.state.x, &self.state.v, pose.pose().position());
                tool.linearisation = Linearisation::of(&all[range.clone()], x, v, origin);
            }
        }
        let Some(surgery) = self.surgery.as_mut() else { return };
        let x = &self.state.x;
        let surface = &surgery.surface;
        for ((rig, (touches, facets)), tool) in
            surgery.rigs.iter_mut().zip(&springs.touches).zip(&mut frame.tools)
        {
            let now = |v: &[u32; 3]| v.map(|v| surface.embedding(v).position(x));
            rig.carry(touches, facets, now);
            if rig.has_proxy() {
                tool.proxy = rig.proxy;
            }
        }
    }

    /// After the mechanics: each tool mesh's part of the volume contact `field` (the penalty
    /// of its overlaps at the new positions, and its derivative in the pose) added to its
    /// frame.
    pub(super) fn finish_volume_tools(&self, field: &VolumePenalty, frame: &mut SurgicalFrame) {
        let Some(volume) = self.surgery.as_ref().and_then(|s| s.volume.as_ref()) else { return };
        for o in volume.tool_overlaps() {
            let (Some(tool), Some(region)) =
                (frame.tools.get_mut(o.tool), field.regions().get(o.region))
            else {
                continue;
            };
            let Some(pose) = tool.pose else { continue };
            let volume = region.volume_at(&self.state.x);
            let origin = pose.pose().position();
            let lin = Linearisation::of_overlap(
                origin,
                region.stiffness(),
                volume,
                o.gradients.iter().copied(),
            );
            tool.linearisation.add(&lin);
            tool.overlap_volume += o.volume;
            tool.contact_points += o.surface_points;
        }
    }

    /// The surface's deformed positions from the state.
    fn deform_surface(&self, surgery: &mut Surgery) {
        let Surgery { surface, positions, deformed_at, .. } = surgery;
        surface.deform(&self.state.x, self.model(), positions);
        *deformed_at = Some(self.index);
    }

    /// The volume contact of the step, after the tools' part (and its cut): the overlaps of
    /// the surface as it now is, as one penalty field. `None` without volume contact or
    /// without overlap.
    pub(super) fn prepare_volume_contact(
        &mut self,
        counters: &mut StageCounters,
    ) -> Option<VolumePenalty> {
        let mut surgery = self.surgery.take()?;
        let step = if surgery.volume.is_some() {
            if surgery.deformed_at != Some(self.index) {
                let t = Instant::now();
                self.deform_surface(&mut surgery);
                counters.surface_ns += elapsed(t);
            }
            let t = Instant::now();
            let Surgery { surface, positions, volume, rigs, .. } = &mut *surgery;
            let meshes: Vec<PosedMesh> = rigs
                .iter()
                .enumerate()
                .filter_map(|(tool, rig)| {
                    let ((vertices, triangles), pose) = (rig.volume_mesh.as_ref()?, rig.pose?);
                    let positions =
                        vertices.iter().map(|&p| pose.pose().grid_from_tool(p)).collect();
                    Some(PosedMesh { tool, positions, triangles })
                })
                .collect();
            let (x, model) = (&self.state.x, self.model());
            let diff = &mut counters.gpu_cpu_volume_diff;
            let nodes = Nodes { x, model, fixed: &self.fixed };
            let step =
                volume.as_mut().and_then(|v| v.step(surface, positions, nodes, &meshes, diff));
            counters.volume_contact_ns = elapsed(t);
            if let Some(s) = &step {
                counters.overlap_regions = s.regions().len();
                counters.overlap_volume = s.volume();
            }
            step
        } else {
            None
        };
        self.surgery = Some(surgery);
        step
    }

    /// Cuts with each tool that cuts this step, as `cuts` says; returns the tools that cut
    /// something and the poses they cut at.
    fn cut_with_tools(
        &mut self,
        surgery: &mut Surgery,
        cuts: &[Option<Cut>],
        counters: &mut StageCounters,
        frame: &mut SurgicalFrame,
    ) -> Result<Vec<(usize, Pose)>, CutError> {
        if cuts.iter().all(Option::is_none) {
            return Ok(Vec::new());
        }
        let t = Instant::now();
        let mut edit = GridEdit::default();
        let mut tets: Vec<usize> = Vec::new();
        let mut events: Vec<CutEvent> = Vec::new();
        let scattered = self.grid().map(|_| self.positions_by_grid_node());
        let Surgery { rigs, surface, positions, volume, .. } = &mut *surgery;
        let mut mismatches = 0;
        let mut entered: Vec<(usize, Pose)> = Vec::new();
        for (i, (rig, cut)) in rigs.iter().zip(cuts).enumerate() {
            let (Some(Cut { from, ahead, pressed }), Some(inner)) = (cut, rig.inner.as_ref())
            else {
                continue;
            };
            for at in ahead {
                let mut event = CutEvent { tool: i, ..CutEvent::default() };
                match (rig.spec.cutting, self.grid(), &scattered) {
                    (Cutting::Off, ..) => break,
                    (Cutting::Remove, Some(grid), Some(by_grid_node)) => {
                        let deformed = DeformedGrid { grid, by_grid_node };
                        let marker = volume.as_mut().and_then(|v| v.marker(&mut mismatches));
                        let cutter = rig.cutter.as_ref().unwrap_or(inner);
                        let voxels =
                            cut::voxels_inside(cutter, at, &deformed, surface, positions, marker);
                        event.voxels_removed = voxels.len();
                        edit.remove_voxels.extend(voxels);
                    }
                    (Cutting::Separate, Some(grid), Some(by_grid_node)) => {
                        let deformed = DeformedGrid { grid, by_grid_node };
                        let link = grid.spacing().into_iter().fold(f64::INFINITY, f64::min);
                        let Some(blade) = SweptBlade::new(inner, from, at, link) else {
                            continue;
                        };
                        let links = cut::links_crossed(&blade, &deformed, surface, positions);
                        event.links_severed = links.len();
                        edit.sever_links.extend(links);
                    }
                    (_, None, _) | (_, _, None) => {
                        let Some(tet) = self.tet() else { break };
                        let mut found = cut::tets_inside(inner, at, &tet.topology, &self.state.x);
                        let facets: Vec<_> = pressed.iter().map(|p| p.0).collect();
                        found.extend(cut::tets_under(&tet.topology, &facets));
                        found.sort_unstable();
                        found.dedup();
                        event.tets_removed = found.len();
                        tets.extend(found);
                    }
                }
                if event != (CutEvent { tool: i, ..CutEvent::default() }) {
                    events.push(event);
                    if rig.has_proxy() {
                        entered.push((i, *at));
                    }
                    break;
                }
            }
        }
        counters.cut_ns += elapsed(t);
        counters.gpu_cpu_cut_mismatches += mismatches;
        if events.is_empty() {
            return Ok(Vec::new());
        }
        edit.remove_voxels.sort_unstable();
        edit.remove_voxels.dedup();
        edit.sever_links.sort_unstable();
        edit.sever_links.dedup();
        tets.sort_unstable();
        tets.dedup();

        let t = Instant::now();
        let changes = if self.grid().is_some() {
            Some(self.cut_grid(&edit)?)
        } else {
            let removed = self.remove_tets_only(&tets)?;
            counters.tets_removed = removed.len();
            frame.tets_removed = removed;
            None
        };
        counters.grid_ns += elapsed(t);

        let t = Instant::now();
        frame.surface = match (&changes, self.grid(), self.model()) {
            (Some(changes), Some(grid), Some(model)) => {
                counters.voxels_removed = changes.voxels_removed;
                counters.links_severed = changes.links_severed;
                surgery.surface.after_grid_edit(grid, model, &touched(&edit), changes)
            }
            _ => match self.tet() {
                Some(tet) => surgery.surface.after_tet_removal(&tet.topology),
                None => SurfaceChanges::default(),
            },
        };
        surgery.surface_changed(&frame.surface);
        counters.remesh_ns += elapsed(t);
        frame.cuts = events;
        if changes.is_some() {
            frame.edit = edit;
        }
        Ok(entered)
    }

    /// The organ's surface (scenes with tools; [`Simulation::enable_surface`] builds it in
    /// others).
    #[must_use]
    pub fn surface(&self) -> Option<&OrganSurface> {
        self.surgery.as_ref().map(|s| &s.surface)
    }

    /// Builds the organ's surface in a scene without tools, so that [`Self::surface`] and
    /// [`Self::surface_positions`] have it (a scene with tools has it from the start).
    ///
    /// # Panics
    /// Never: a scene without tools has no mesh file to load.
    pub fn enable_surface(&mut self) {
        if self.surgery.is_some() {
            return;
        }
        let surface = match &self.body {
            super::Body::Hex(hex) => OrganSurface::voxels(
                &hex.grid,
                &hex.model,
                &surface_options(&self.config, &hex.grid),
                self.config.surface.smoothing,
            ),
            super::Body::Tet(tet) => OrganSurface::tetrahedra(&tet.topology),
        };
        self.surgery = Some(Box::new(
            Surgery::new(&[], surface, &ToolDefaults::default())
                .expect("no tools: nothing to load"),
        ));
    }

    /// The deformed position of every surface vertex slot now (dead slots hold anything), for
    /// rendering: index them with [`OrganSurface::triangle_list`].
    #[must_use]
    pub fn surface_positions(&self) -> Option<Vec<Vec3>> {
        let surgery = self.surgery.as_ref()?;
        let mut out = Vec::new();
        surgery.surface.deform(&self.state.x, self.model(), &mut out);
        Some(out)
    }

    /// The organ's surface as a viewer or a recording draws it: the deformed positions of the
    /// live vertices among `vertices`, and the live triangles among `triangles`, with their
    /// tissue labels (`None`: every live one). `None` in a scene without a surface.
    #[must_use]
    pub fn surface_geometry(
        &self,
        vertices: Option<&[u32]>,
        triangles: Option<&[u32]>,
    ) -> Option<SurfaceGeometry> {
        let surgery = self.surgery.as_ref()?;
        let surface = &surgery.surface;
        // Rendering precision: f32 holds a micrometre within 16 m of the origin.
        let f32s = |p: Vec3| p.map(|c| c as f32);
        // A few vertices (a cut's new ones) from their embeddings: no whole deform on the
        // physics thread for them.
        let (vertex_ids, positions): (Vec<u32>, Vec<[f32; 3]>) = if let Some(ids) = vertices {
            ids.iter()
                .copied()
                .filter(|&v| surface.is_live(v))
                .map(|v| {
                    let e = surface.embedding(v);
                    let mut p = [0.0; 3];
                    for (&n, &w) in e.nodes.iter().zip(&e.weights) {
                        if w != 0.0 {
                            for (c, x) in p.iter_mut().zip(self.state.x[n as usize]) {
                                *c += w * x;
                            }
                        }
                    }
                    (v, f32s(p))
                })
                .unzip()
        } else {
            let mut slots = Vec::new();
            surface.deform(&self.state.x, self.model(), &mut slots);
            let ids = surface.live_vertices().to_vec();
            let positions = ids.iter().map(|&v| f32s(slots[v as usize])).collect();
            (ids, positions)
        };
        let (triangle_ids, triangles, triangle_labels) =
            surface_triangles(surface, self.grid(), triangles);
        Some(SurfaceGeometry { vertex_ids, positions, triangle_ids, triangles, triangle_labels })
    }

    /// After a cut made from outside the tools (`Simulation::cut`, `Simulation::remove_tets`):
    /// the surface follows.
    pub(super) fn surface_after_cut(
        &mut self,
        edit: Option<&GridEdit>,
        changes: Option<&incise_grid::GridChanges>,
    ) {
        let Some(mut surgery) = self.surgery.take() else { return };
        let changes = match (edit, changes, self.grid(), self.model()) {
            (Some(edit), Some(changes), Some(grid), Some(model)) => {
                surgery.surface.after_grid_edit(grid, model, &touched(edit), changes)
            }
            _ => match self.tet() {
                Some(tet) => surgery.surface.after_tet_removal(&tet.topology),
                None => SurfaceChanges::default(),
            },
        };
        surgery.surface_changed(&changes);
        self.surgery = Some(surgery);
    }

    /// The node positions by grid node id (hexahedral scenes).
    fn positions_by_grid_node(&self) -> Vec<Vec3> {
        let Some(model) = self.model() else { return Vec::new() };
        let size = model.grid_node.iter().map(|&g| g as usize + 1).max().unwrap_or(0);
        let mut out = vec![[0.0; 3]; size];
        for (p, &g) in self.state.x.iter().zip(&model.grid_node) {
            out[g as usize] = *p;
        }
        out
    }
}

/// Whether a live vertex of `surface` at `positions` lies inside `shape` at `pose`.
fn holds_a_point(shape: &Shape, pose: &Pose, surface: &OrganSurface, positions: &[Vec3]) -> bool {
    let (lo, hi) = shape.grid_bounds(pose);
    surface.live_vertices().iter().any(|&v| {
        let p = positions[v as usize];
        (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k])
            && shape.distance(pose.tool_from_grid(p)).0 < 0.0
    })
}

/// The voxels an edit touches: those removed and both ends of the links severed, sorted.
fn touched(edit: &GridEdit) -> Vec<u32> {
    let mut touched = edit.remove_voxels.clone();
    touched.extend(edit.sever_links.iter().flat_map(|&(a, b)| [a, b]));
    touched.sort_unstable();
    touched.dedup();
    touched
}

fn elapsed(t: Instant) -> u64 {
    u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX)
}
