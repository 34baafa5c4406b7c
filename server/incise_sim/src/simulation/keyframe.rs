//! Keyframes: the state a frame left, taken once a second of simulated time, from which a replay
//! starts in the middle of a session instead of at its first frame.
//!
//! The state of a running scene has two parts. Its topology (grid, model, surface, their slot
//! numbering and free lists) is the scene's plus the cuts made since, and a cut's effect on it
//! does not depend on the motion: re-applying each frame's recorded edit in order
//! ([`Simulation::apply_edit`]) rebuilds it exactly. What moves is in a [`Keyframe`]: positions
//! and velocities, each corotational element's rotation (the warm start of the next
//! extraction), the implicit integrator's warm start, the explicit integrators' previous
//! positions and sub-step count, the adaptive tensor-mass's non-linear vertices, and each
//! tool's pose, its proxy's pose and its grasp.
//!
//! Some things a step keeps are built from the rotations of whichever step built them (the
//! block-Jacobi blocks and the Cholesky factor of the implicit solve), or are sums whose bits
//! depend on the order of every change since the start (the adaptive tensor-mass's non-linear
//! term tables). A keyframe does not carry them: at every keyframe frame the simulation drops
//! them and builds them again from the state alone, whether or not anyone records, so a replay
//! restored at a keyframe steps exactly as the session did.

use super::{Body, HexStepper, Simulation, TetStepper, fnv};
use crate::simulation::CutError;
use incise_grid::GridEdit;
use incise_math::Vec3;
use incise_math::mat3::Mat3;
use incise_tool::{Grasp, Pose, ToolPose};

/// Simulated time between two keyframes (s).
pub const KEYFRAME_INTERVAL_S: f64 = 1.0;

/// One tool's part of a keyframe.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolState {
    /// Its device's pose at the frame (`None`: it takes no part yet); the next frame's device
    /// velocity starts from it.
    pub pose: Option<ToolPose>,
    /// Its proxy's pose at the frame: where the next frame's proxy moves from.
    pub proxy: Option<Pose>,
    /// Its jaws.
    pub grasp: Grasp,
}

/// The state a frame left beyond the scene and its topology (see the module's description).
#[derive(Clone, Debug, PartialEq)]
pub struct Keyframe {
    /// The frame.
    pub frame: u64,
    /// [`super::Frame::state_hash`] of the frame: checked when restored.
    pub state_hash: u64,
    /// The counts that describe the topology at the frame (nodes, elements or live tetrahedra,
    /// surface triangles and vertices), hashed: checked when restored, so that a keyframe given
    /// without the edits before it is refused.
    pub topology: u64,
    /// Node positions (m) and velocities (m/s), in model node order.
    pub x: Vec<Vec3>,
    /// See `x`.
    pub v: Vec<Vec3>,
    /// Corotational hexahedra: each element's rotation, as quaternion `(w, x, y, z)` and
    /// matrix (empty otherwise).
    pub rotations: Vec<([f64; 4], Mat3)>,
    /// Implicit integrators: the last steps' velocity changes, most recent first.
    pub warm_start: Vec<Vec<Vec3>>,
    /// Explicit tensor-mass: the positions at the previous step (empty otherwise).
    pub previous: Vec<Vec3>,
    /// Explicit hexahedra: the cut mesh's stable step (s) and the sub-steps per frame.
    pub explicit: Option<(f64, usize)>,
    /// Adaptive tensor-mass: which vertices are non-linear (empty otherwise).
    pub nonlinear: Vec<bool>,
    /// The scene's tools, in scene order.
    pub tools: Vec<ToolState>,
}

/// A keyframe that does not fit the simulation it was given to.
#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
#[error("the keyframe of frame {frame}: {what}")]
pub struct KeyframeError {
    /// The keyframe's frame.
    pub frame: u64,
    /// What does not fit.
    pub what: String,
}

impl Simulation {
    /// Frames between two keyframes: [`KEYFRAME_INTERVAL_S`] of simulated time, at least 1.
    #[must_use]
    pub fn keyframe_interval(&self) -> u64 {
        ((KEYFRAME_INTERVAL_S / self.config.dt()).round() as u64).max(1)
    }

    /// Whether frame `index` is a keyframe: its state is what [`Self::keyframe`] takes, the
    /// solver's kept matrices having been dropped at its end.
    #[must_use]
    pub fn is_keyframe(&self, index: u64) -> bool {
        index > 0 && index.is_multiple_of(self.keyframe_interval())
    }

    /// FNV-1a of the counts that describe the topology: nodes, elements (hexahedra) or live
    /// tetrahedra, the surface's triangles and vertices.
    fn topology_fingerprint(&self) -> u64 {
        let cells = match &self.body {
            Body::Hex(hex) => hex.model.elements.len(),
            Body::Tet(tet) => tet.topology.live_count(),
        };
        let (triangles, vertices) =
            self.surface().map_or((0, 0), |s| (s.triangle_count(), s.live_vertices().len()));
        [self.state.x.len(), cells, triangles, vertices]
            .iter()
            .flat_map(|&n| (n as u64).to_le_bytes())
            .fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
    }

    /// At the end of a keyframe frame: drops what the step keeps that a keyframe cannot carry
    /// (see the module's description); the next step builds it again from the state.
    pub(super) fn settle_for_keyframe(&mut self) {
        match &mut self.body {
            Body::Hex(hex) => {
                if let HexStepper::Implicit(be) = &mut hex.stepper {
                    be.drop_kept();
                }
            }
            Body::Tet(tet) => {
                if let TetStepper::Implicit(be) = &mut tet.stepper {
                    be.drop_kept();
                }
                tet.force_field.rebuild_adaptive_tables(&tet.model, &tet.topology);
            }
        }
    }

    /// The state the last frame left, for a replay to start from after re-applying the edits
    /// of every frame up to it (see the module's description). Taken at a keyframe frame
    /// ([`Self::is_keyframe`]) it restores bit for bit; at another frame the solver's kept
    /// matrices differ and a replay from it only comes close.
    #[must_use]
    pub fn keyframe(&self) -> Keyframe {
        let mut k = Keyframe {
            frame: self.index,
            state_hash: fnv(&self.state),
            topology: self.topology_fingerprint(),
            x: self.state.x.clone(),
            v: self.state.v.clone(),
            rotations: Vec::new(),
            warm_start: Vec::new(),
            previous: Vec::new(),
            explicit: None,
            nonlinear: Vec::new(),
            tools: self.surgery.as_ref().map(|s| s.tool_states()).unwrap_or_default(),
        };
        match &self.body {
            Body::Hex(hex) => {
                if hex.force_field.formulation() == incise_fem::Formulation::Corotational {
                    k.rotations = hex.force_field.rotations();
                }
                match &hex.stepper {
                    HexStepper::Implicit(be) => k.warm_start = be.warm_start().to_vec(),
                    HexStepper::Explicit { stable_dt, substeps, .. } => {
                        k.explicit = Some((*stable_dt, *substeps));
                    }
                    HexStepper::Static { .. } => {}
                }
            }
            Body::Tet(tet) => {
                match &tet.stepper {
                    TetStepper::Implicit(be) => k.warm_start = be.warm_start().to_vec(),
                    TetStepper::Explicit(cd) => k.previous = cd.previous().to_vec(),
                }
                if let Some(flags) = tet.force_field.nonlinear_vertices() {
                    k.nonlinear = flags.to_vec();
                }
            }
        }
        k
    }

    /// Applies the topology change a frame's tools made, as that frame's step applied it: the
    /// grid edit ([`super::SurgicalFrame::edit`]) with the model, solver state and surface,
    /// or the tetrahedra removed ([`super::SurgicalFrame::tets_removed`]). Nothing is stepped;
    /// the state the nodes are carried with is overwritten by [`Self::restore`].
    ///
    /// # Errors
    /// When the edit names voxels, links or tetrahedra the scene does not have.
    pub fn apply_edit(&mut self, edit: &GridEdit, tets_removed: &[usize]) -> Result<(), CutError> {
        if self.grid().is_some() {
            if *edit == GridEdit::default() {
                return Ok(());
            }
            let changes = self.cut_grid(edit)?;
            self.surface_after_cut(Some(edit), Some(&changes));
        } else if !tets_removed.is_empty() {
            self.remove_tets_only(tets_removed)?;
            self.surface_after_cut(None, None);
        }
        Ok(())
    }

    /// Restores `keyframe`, taken by [`Self::keyframe`] on a simulation of the same scene after
    /// the same edits ([`Self::apply_edit`]): the next step is the frame after the keyframe's.
    ///
    /// # Errors
    /// When the keyframe does not fit this simulation (another node, element or tool count,
    /// state the integrator does not have), or its state does not hash to its recorded hash; the
    /// simulation is then left partly restored and should be built again.
    pub fn restore(&mut self, keyframe: &Keyframe) -> Result<(), KeyframeError> {
        let fail = |what: String| KeyframeError { frame: keyframe.frame, what };
        let topology = self.topology_fingerprint();
        if topology != keyframe.topology {
            return Err(fail(format!(
                "its topology ({:016x}) is not the simulation's ({topology:016x}): give it the \
                 edits of every frame up to it first",
                keyframe.topology
            )));
        }
        let nodes = self.state.x.len();
        if keyframe.x.len() != nodes || keyframe.v.len() != nodes {
            return Err(fail(format!(
                "{} positions and {} velocities for {nodes} nodes (are the edits before it applied?)",
                keyframe.x.len(),
                keyframe.v.len()
            )));
        }
        match &mut self.surgery {
            Some(surgery) => surgery.restore_tools(&keyframe.tools).map_err(&fail)?,
            None if !keyframe.tools.is_empty() => {
                return Err(fail(format!(
                    "{} tools in a scene without tools",
                    keyframe.tools.len()
                )));
            }
            None => {}
        }
        match &mut self.body {
            Body::Hex(hex) => {
                if hex.force_field.formulation() == incise_fem::Formulation::Corotational {
                    hex.force_field.set_rotations(&keyframe.rotations).map_err(&fail)?;
                } else if !keyframe.rotations.is_empty() {
                    return Err(fail("element rotations for a linear model".into()));
                }
                match (&mut hex.stepper, keyframe.explicit) {
                    (HexStepper::Implicit(be), None) => {
                        be.set_warm_start(keyframe.warm_start.clone(), nodes).map_err(&fail)?;
                    }
                    (HexStepper::Explicit { stable_dt, substeps, .. }, Some((limit, steps))) => {
                        if limit.is_nan() || limit <= 0.0 || steps == 0 {
                            return Err(fail(format!(
                                "an explicit stable step of {limit} s in {steps} sub-steps"
                            )));
                        }
                        (*stable_dt, *substeps) = (limit, steps);
                    }
                    (HexStepper::Static { .. }, None) => {}
                    _ => return Err(fail("integrator state of another integrator".into())),
                }
            }
            Body::Tet(tet) => {
                match &mut tet.stepper {
                    TetStepper::Implicit(be) => {
                        be.set_warm_start(keyframe.warm_start.clone(), nodes).map_err(&fail)?;
                    }
                    TetStepper::Explicit(cd) => {
                        cd.set_previous(&keyframe.previous).map_err(&fail)?;
                    }
                }
                if tet.force_field.nonlinear_vertices().is_some() {
                    tet.force_field
                        .set_nonlinear_vertices(&tet.model, &tet.topology, &keyframe.nonlinear)
                        .map_err(&fail)?;
                } else if !keyframe.nonlinear.is_empty() {
                    return Err(fail("non-linear vertices for a field without adaptivity".into()));
                }
            }
        }
        self.state.x.clone_from(&keyframe.x);
        self.state.v.clone_from(&keyframe.v);
        self.index = keyframe.frame;
        let hash = fnv(&self.state);
        if hash != keyframe.state_hash {
            return Err(fail(format!(
                "its state hashes to {hash:016x}, not to its recorded {:016x}",
                keyframe.state_hash
            )));
        }
        Ok(())
    }
}
