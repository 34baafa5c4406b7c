//! A recording's state messages: each frame's topology edit (`incise.v1.TopologyEdit`) and the
//! keyframes (`incise.v1.Keyframe`), to and from `incise_sim`'s types. Reading checks every
//! length and value, so a damaged message gives an error that says what, never a panic.

use incise_grid::GridEdit;
use incise_math::Vec3;
use incise_protocol::v1;
use incise_sim::{Frame, Keyframe, ToolState};
use incise_tool::grasp::Held;
use incise_tool::{Grasp, Pose, ToolPose};

/// The topology change `frame` made, when it made one.
#[must_use]
pub fn edit_message(frame: &Frame) -> Option<v1::TopologyEdit> {
    let s = &frame.surgical;
    if s.edit == GridEdit::default() && s.tets_removed.is_empty() {
        return None;
    }
    Some(v1::TopologyEdit {
        frame: frame.index,
        removed_voxels: s.edit.remove_voxels.clone(),
        severed_links: s.edit.sever_links.iter().flat_map(|&(a, b)| [a, b]).collect(),
        // A mesh of more than 2³² tetrahedra is not a surgical scene.
        removed_tets: s.tets_removed.iter().map(|&t| t as u32).collect(),
    })
}

/// The edit a message describes, as [`incise_sim::Simulation::apply_edit`] takes it.
///
/// # Errors
/// When its links do not come in pairs.
pub fn edit_from_message(m: &v1::TopologyEdit) -> Result<(GridEdit, Vec<usize>), String> {
    if !m.severed_links.len().is_multiple_of(2) {
        return Err(format!(
            "the edit of frame {}: {} link ends, not pairs",
            m.frame,
            m.severed_links.len()
        ));
    }
    let edit = GridEdit {
        remove_voxels: m.removed_voxels.clone(),
        sever_links: m.severed_links.chunks_exact(2).map(|p| (p[0], p[1])).collect(),
    };
    Ok((edit, m.removed_tets.iter().map(|&t| t as usize).collect()))
}

fn flat(v: &[Vec3]) -> Vec<f64> {
    v.iter().flatten().copied().collect()
}

/// `values` as 3-vectors, or an error naming `what`.
fn vec3s(values: &[f64], what: &str) -> Result<Vec<Vec3>, String> {
    if !values.len().is_multiple_of(3) {
        return Err(format!("{what}: {} values, not a multiple of 3", values.len()));
    }
    Ok(values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// Surface vertices paired with a 3-vector each (`values`, three per vertex), or an error
/// naming `what`.
fn per_vertex(ids: &[u32], values: &[f64], what: &str) -> Result<Vec<(u32, Vec3)>, String> {
    let vectors = vec3s(values, what)?;
    if vectors.len() != ids.len() {
        return Err(format!("{} {what} for {} vertices", vectors.len(), ids.len()));
    }
    Ok(ids.iter().copied().zip(vectors).collect())
}

/// `keyframe` as its message.
#[must_use]
pub fn keyframe_message(keyframe: &Keyframe) -> v1::Keyframe {
    let (stable_dt, substeps) = keyframe.explicit.unwrap_or((0.0, 0));
    v1::Keyframe {
        frame: keyframe.frame,
        state_hash: keyframe.state_hash,
        topology: keyframe.topology,
        positions: flat(&keyframe.x),
        velocities: flat(&keyframe.v),
        element_rotations: keyframe
            .rotations
            .iter()
            .flat_map(|(q, r)| q.iter().chain(r.iter().flatten()).copied())
            .collect(),
        warm_start: keyframe
            .warm_start
            .iter()
            .map(|h| v1::NodeVectors { values: flat(h) })
            .collect(),
        previous_positions: flat(&keyframe.previous),
        explicit_stable_dt_s: stable_dt,
        explicit_substeps: u32::try_from(substeps).unwrap_or(u32::MAX),
        nonlinear_vertices: keyframe.nonlinear.clone(),
        tools: keyframe.tools.iter().enumerate().map(|(i, t)| tool_message(i, t)).collect(),
    }
}

fn tool_message(i: usize, t: &ToolState) -> v1::ToolKeyState {
    let held = t.grasp.held();
    v1::ToolKeyState {
        tool_id: i as u32,
        posed: t.pose.is_some(),
        position: t.pose.map(|p| p.pose().position().to_vec()).unwrap_or_default(),
        rotation: t.pose.map(|p| p.pose().rotation().to_vec()).unwrap_or_default(),
        gripper: t.pose.map_or(0.0, |p| p.gripper()),
        jaws_closed: t.grasp.is_closed(),
        held_vertices: held.iter().map(|h| h.id).collect(),
        held_anchors: held.iter().flat_map(|h| h.anchor).collect(),
        proxy: t
            .proxy
            .map(|p| p.position().into_iter().chain(p.rotation()).collect())
            .unwrap_or_default(),
    }
}

/// The keyframe a message describes.
///
/// # Errors
/// When a list's length does not fit its layout (positions in threes, rotations in thirteens,
/// a tool's pose and points); what fits the simulation is checked when it is restored
/// ([`incise_sim::Simulation::restore`]).
pub fn keyframe_from_message(m: &v1::Keyframe) -> Result<Keyframe, String> {
    let at = |what: &str| format!("the keyframe of frame {}: {what}", m.frame);
    if !m.element_rotations.len().is_multiple_of(13) {
        return Err(at(&format!(
            "{} rotation values, not 13 (quaternion and matrix) per element",
            m.element_rotations.len()
        )));
    }
    let rotations = m
        .element_rotations
        .chunks_exact(13)
        .map(|c| {
            let q = [c[0], c[1], c[2], c[3]];
            let r = [[c[4], c[5], c[6]], [c[7], c[8], c[9]], [c[10], c[11], c[12]]];
            (q, r)
        })
        .collect();
    let warm_start = m
        .warm_start
        .iter()
        .map(|h| vec3s(&h.values, "a warm-start step"))
        .collect::<Result<_, _>>()
        .map_err(|e| at(&e))?;
    let tools = m
        .tools
        .iter()
        .enumerate()
        .map(|(i, t)| {
            if t.tool_id as usize != i {
                return Err(format!("tool {} listed as tool {i}", t.tool_id));
            }
            tool_state(t).map_err(|e| format!("tool {i}: {e}"))
        })
        .collect::<Result<_, _>>()
        .map_err(|e| at(&e))?;
    Ok(Keyframe {
        frame: m.frame,
        state_hash: m.state_hash,
        topology: m.topology,
        x: vec3s(&m.positions, "positions").map_err(|e| at(&e))?,
        v: vec3s(&m.velocities, "velocities").map_err(|e| at(&e))?,
        rotations,
        warm_start,
        previous: vec3s(&m.previous_positions, "previous positions").map_err(|e| at(&e))?,
        explicit: (m.explicit_substeps > 0)
            .then_some((m.explicit_stable_dt_s, m.explicit_substeps as usize)),
        nonlinear: m.nonlinear_vertices.clone(),
        tools,
    })
}

fn tool_state(t: &v1::ToolKeyState) -> Result<ToolState, String> {
    let pose = if t.posed {
        let (Ok(position), Ok(rotation)) =
            (<[f64; 3]>::try_from(&t.position[..]), <[f64; 4]>::try_from(&t.rotation[..]))
        else {
            return Err(format!(
                "a pose of {} position and {} rotation values (3 and 4 wanted)",
                t.position.len(),
                t.rotation.len()
            ));
        };
        // A session only ever steps with checked poses.
        let finite = position.iter().chain(&rotation).all(|c| c.is_finite());
        if !(finite && t.gripper.is_finite() && t.gripper >= 0.0) {
            return Err(format!(
                "the pose (position {position:?}, rotation {rotation:?}, gripper {}) is not finite",
                t.gripper
            ));
        }
        Some(ToolPose::restored(position, rotation, t.gripper))
    } else {
        None
    };
    let proxy = match t.proxy.len() {
        0 => None,
        7 if t.proxy.iter().all(|c| c.is_finite()) => Some(Pose::restored(
            [t.proxy[0], t.proxy[1], t.proxy[2]],
            [t.proxy[3], t.proxy[4], t.proxy[5], t.proxy[6]],
        )),
        n => {
            return Err(format!(
                "a proxy pose of {n} values, or not finite (7 finite ones wanted: position, \
                 rotation)"
            ));
        }
    };
    let held = per_vertex(&t.held_vertices, &t.held_anchors, "held anchors")?
        .into_iter()
        .map(|(id, anchor)| Held { id, anchor })
        .collect();
    Ok(ToolState { pose, proxy, grasp: Grasp::restored(t.jaws_closed, held) })
}
