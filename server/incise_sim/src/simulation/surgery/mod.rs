//! The surgical frame (Jeřábková 2010, §3; §4.1 for where its time goes): each step the posed
//! tools push the organ's surface with their outer shapes (contact), cut with their inner
//! shapes, and hold with their jaws; a cut updates the grid, the model and solver state, and the
//! surface locally, in that order, within the step; then the mechanics is solved with the
//! contact and grasp springs as force fields beside the tissue's, and each tool's force, torque
//! and their linearisation in the pose are read from the springs at the new positions.
//!
//! A tool that is given no pose (and has no scripted path) takes no part; one that stops being
//! given poses stays where it was last put, as a hand that lets go of a haptic device leaves
//! the instrument in place.

mod cut;
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
    Contact, ContactMemory, ContactSettings, Grasp, GraspEvent, Linearisation, Pose, Shape,
    SweptBlade, ToolPose, detect,
};
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
    /// The pose it had this step (`None`: it takes no part yet).
    pub pose: Option<ToolPose>,
    /// Surface points its outer shape pushes.
    pub contact_points: usize,
    /// Of those, points its motion swept over since the last step (carried, not tunnelled).
    pub swept_points: usize,
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
    pose: Option<ToolPose>,
    /// Its pose at the previous step, for the swept tests.
    previous: Option<Pose>,
    /// Its contact's stiffness and damping (the damping resolved from the implicit step when
    /// the tool names none).
    contact: ContactSettings,
    /// Its grasp's damping per point (N·s/m).
    grasp_damping: f64,
    /// The push directions of its last contact.
    memory: ContactMemory,
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

/// The springs of the step's tools: all of them as one field, and which belong to which tool.
pub(crate) struct ToolSprings {
    pub(crate) field: EmbeddedSprings,
    ranges: Vec<Option<Range<usize>>>,
}

impl Surgery {
    /// After a re-mesh: the tools forget what they remembered of surface vertex slots it gave
    /// to new vertices, and the volume contact notes the new walls.
    fn surface_changed(&mut self, changes: &SurfaceChanges) {
        for rig in &mut self.rigs {
            rig.memory.forget(&changes.vertices_added);
        }
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

    /// The tools of `tools` on `surface`, in a scene whose implicit step is `dt` (s; 0 for an
    /// explicit integrator: the tools' default damping per unit of stiffness); refuses a shape
    /// the scene reader did not load.
    pub(crate) fn new(tools: &[ToolSpec], surface: OrganSurface, dt: f64) -> Result<Self, String> {
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
                    spec: t.clone(),
                    pose: None,
                    previous: None,
                    contact: ContactSettings {
                        stiffness: t.stiffness,
                        damping: t.damping.unwrap_or(dt * t.stiffness),
                    },
                    grasp_damping: t
                        .damping
                        .unwrap_or_else(|| t.jaws.map_or(0.0, |j| dt * j.stiffness)),
                    memory: ContactMemory::default(),
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
            .map(|rig| ToolState {
                pose: rig.pose,
                memory: rig.memory.clone(),
                grasp: rig.grasp.clone(),
            })
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
            rig.memory = state.memory.clone();
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
    /// Checks this step's tool inputs before anything moves.
    pub(super) fn check_tools(&self, inputs: &StepInputs) -> Result<(), InputError> {
        let tools = self.surgery.as_ref().map_or(0, |s| s.tool_count());
        for (entry, input) in inputs.tools.iter().enumerate() {
            if input.tool >= tools {
                return Err(InputError::NoSuchTool { entry, tool: input.tool, tools });
            }
            // `Pose::at` and `Pose::moved` build poses unchecked: a NaN from a device driver
            // would otherwise drop the tool's contact for a frame and poison the next frame's
            // swept test, with the state moved as if the tool had been withdrawn.
            let (position, rotation) = (input.pose.pose.position(), input.pose.pose.rotation());
            if !position.iter().chain(&rotation).all(|c| c.is_finite()) {
                return Err(InputError::BadPose { entry, position, rotation });
            }
            let gripper = input.pose.gripper;
            if !(gripper.is_finite() && gripper >= 0.0) {
                return Err(InputError::BadGripper { entry, gripper });
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
        for (i, rig) in surgery.rigs.iter_mut().enumerate() {
            rig.previous = rig.pose.map(|p| p.pose);
            let given = inputs.tools.iter().rev().find(|t| t.tool == i).map(|t| t.pose);
            let scripted = rig.spec.path.as_ref().map(|p| p.at(now));
            rig.pose = given.or(scripted).or(rig.pose);
        }
        frame.tools = surgery
            .rigs
            .iter()
            .map(|rig| ToolFrame {
                pose: rig.pose,
                contact_points: 0,
                swept_points: 0,
                held_points: 0,
                overlap_volume: 0.0,
                grasp: GraspEvent::None,
                linearisation: Linearisation::none(
                    rig.pose.map_or([0.0; 3], |p| p.pose.position()),
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
        let mut contacts = Self::contacts(surgery, dt);
        let Surgery { rigs, surface, positions, .. } = &mut *surgery;
        for (i, rig) in rigs.iter_mut().enumerate() {
            let (Some(pose), Some(jaws)) = (rig.pose, rig.spec.jaws) else { continue };
            // A tool pushing by volume has no contact points: it touches where a surface point
            // lies inside its mesh (from this step's positions alone, so that a keyframe
            // restores what its jaws do).
            let touching = !contacts[i].points.is_empty()
                || (rig.volume_mesh.is_some()
                    && holds_a_point(&rig.outer, &pose.pose, surface, positions));
            let points = surface.live_vertices().iter().map(|&v| (v, positions[v as usize]));
            frame.tools[i].grasp =
                rig.grasp.update(&jaws, &pose.pose, pose.gripper, touching, points);
        }
        counters.contact_ns += elapsed(t);

        if self.cut_with_tools(surgery, counters, frame)? {
            // The cut renumbered the nodes and moved the surface: find the contact again on the
            // surface as it now is (the walls a cut opens inside the outer shape are pushed too).
            let t = Instant::now();
            self.deform_surface(surgery);
            counters.surface_ns += elapsed(t);
            let t = Instant::now();
            let surface = &surgery.surface;
            for rig in &mut surgery.rigs {
                rig.grasp.retain(|v| surface.is_live(v));
            }
            contacts = Self::contacts(surgery, dt);
            counters.contact_ns += elapsed(t);
        }

        let mut springs: Vec<EmbeddedSpring> = Vec::new();
        let mut ranges = Vec::with_capacity(surgery.rigs.len());
        for (i, (rig, contact)) in surgery.rigs.iter_mut().zip(contacts).enumerate() {
            rig.memory = ContactMemory::of(&contact);
            let Some(pose) = rig.pose else {
                ranges.push(None);
                continue;
            };
            let start = springs.len();
            frame.tools[i].contact_points = contact.points.len();
            frame.tools[i].swept_points = contact.points.iter().filter(|c| c.swept).count();
            springs.extend(contact.springs);
            if let Some(jaws) = &rig.spec.jaws {
                let surface = &surgery.surface;
                let previous = rig.previous.as_ref().map(|p| (p, self.config.dt()));
                let held = rig.grasp.springs(jaws, &pose.pose, previous, rig.grasp_damping, |v| {
                    surface.is_live(v).then(|| surface.embedding(v))
                });
                frame.tools[i].held_points = held.len();
                springs.extend(held);
            }
            ranges.push(Some(start..springs.len()));
        }
        counters.contact_points = springs.len();
        let exec = Executor::single_thread();
        Ok(Some(ToolSprings { field: EmbeddedSprings::new(springs, exec), ranges }))
    }

    /// After the mechanics: each tool's force, torque and linearisation at the new positions.
    pub(super) fn finish_tools(&self, springs: &ToolSprings, frame: &mut SurgicalFrame) {
        let all = springs.field.springs();
        for (tool, range) in frame.tools.iter_mut().zip(&springs.ranges) {
            if let (Some(pose), Some(range)) = (tool.pose, range) {
                let (x, v, origin) = (&self.state.x, &self.state.v, pose.pose.position());
                tool.linearisation = Linearisation::of(&all[range.clone()], x, v, origin);
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
            let origin = pose.pose.position();
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
                    let positions = vertices.iter().map(|&p| pose.pose.grid_from_tool(p)).collect();
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

    /// Each tool's contact (empty for a tool without a pose).
    fn contacts(surgery: &Surgery, dt: f64) -> Vec<Contact> {
        let Surgery { surface, positions, rigs, .. } = surgery;
        let live = surface.live_vertices();
        rigs.iter()
            .map(|rig| {
                let Some(pose) = rig.pose.filter(|_| rig.volume_mesh.is_none()) else {
                    return Contact::default();
                };
                let previous = rig.previous.as_ref().map(|p| (p, dt));
                detect(
                    &rig.outer,
                    &pose.pose,
                    previous,
                    &rig.memory,
                    &rig.contact,
                    live.iter().map(|&v| (v, positions[v as usize])),
                    |v: u32| surface.embedding(v),
                )
            })
            .collect()
    }

    /// Finds what each cutting tool cuts and cuts it; returns whether anything was cut.
    fn cut_with_tools(
        &mut self,
        surgery: &mut Surgery,
        counters: &mut StageCounters,
        frame: &mut SurgicalFrame,
    ) -> Result<bool, CutError> {
        let t = Instant::now();
        let mut edit = GridEdit::default();
        let mut tets: Vec<usize> = Vec::new();
        let mut events: Vec<CutEvent> = Vec::new();
        let scattered = self.grid().map(|_| self.positions_by_grid_node());
        let Surgery { rigs, surface, positions, volume, .. } = &mut *surgery;
        let mut mismatches = 0;
        for (i, rig) in rigs.iter().enumerate() {
            let (Some(pose), Some(inner)) = (rig.pose, rig.inner.as_ref()) else { continue };
            let mut event = CutEvent { tool: i, ..CutEvent::default() };
            match (rig.spec.cutting, self.grid(), &scattered) {
                (Cutting::Off, ..) => continue,
                (Cutting::Remove, Some(grid), Some(by_grid_node)) => {
                    let deformed = DeformedGrid { grid, by_grid_node };
                    let marker = volume.as_mut().and_then(|v| v.marker(&mut mismatches));
                    let voxels = cut::voxels_inside(
                        inner, &pose.pose, &deformed, surface, positions, marker,
                    );
                    event.voxels_removed = voxels.len();
                    edit.remove_voxels.extend(voxels);
                }
                (Cutting::Separate, Some(grid), Some(by_grid_node)) => {
                    let deformed = DeformedGrid { grid, by_grid_node };
                    let from = rig.previous.unwrap_or(pose.pose);
                    let link = grid.spacing().into_iter().fold(f64::INFINITY, f64::min);
                    let Some(blade) = SweptBlade::new(inner, &from, &pose.pose, link) else {
                        continue;
                    };
                    let links = cut::links_crossed(&blade, &deformed, surface, positions);
                    event.links_severed = links.len();
                    edit.sever_links.extend(links);
                }
                (_, None, _) | (_, _, None) => {
                    let Some(tet) = self.tet() else { continue };
                    let found = cut::tets_inside(inner, &pose.pose, &tet.topology, &self.state.x);
                    event.tets_removed = found.len();
                    tets.extend(found);
                }
            }
            if event != (CutEvent { tool: i, ..CutEvent::default() }) {
                events.push(event);
            }
        }
        counters.cut_ns += elapsed(t);
        counters.gpu_cpu_cut_mismatches += mismatches;
        if events.is_empty() {
            return Ok(false);
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
        Ok(true)
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
        self.surgery =
            Some(Box::new(Surgery::new(&[], surface, 0.0).expect("no tools: nothing to load")));
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
