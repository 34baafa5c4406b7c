//! The scene's fixed regions and patch loads on a model's nodes: what the simulation applies
//! and what the level calibration solves with, kept apart from both so that neither imports the
//! other.

use crate::config::{FixedSpec, SceneConfig};
use incise_fem::model::Loads;
use incise_fem::{FixedNodes, HexModel};
use incise_grid::BranchedGrid;
use incise_math::Vec3;

/// The nodes of the scene's fixed regions.
pub(crate) fn fixed_nodes(
    config: &SceneConfig,
    grid: &BranchedGrid,
    model: &HexModel,
) -> FixedNodes {
    // Only a label hold reads the labels (a copy of the fine level: not on every cut otherwise).
    fixed_at(config, &model.rest, grid.element_size(), |label| {
        let labels = grid.fine_labels();
        model
            .elements
            .iter()
            .filter(|e| grid.element_voxels(e.grid_id).iter().any(|&v| labels[v as usize] == label))
            .flat_map(|e| e.nodes.iter().map(|&n| n as usize))
            .collect()
    })
}

/// The nodes at `rest` in the scene's fixed regions (`size`: the element size, for tolerances;
/// `held(label)`: the nodes of the elements holding a voxel with `label`).
pub(crate) fn fixed_at(
    config: &SceneConfig,
    rest: &[Vec3],
    size: Vec3,
    held: impl Fn(u16) -> Vec<usize>,
) -> FixedNodes {
    let tolerance = 1e-9 * size.iter().copied().fold(0.0, f64::max);
    let mut fixed = FixedNodes::none(rest.len());
    for f in &config.fixed {
        let region = match f {
            FixedSpec::Plane { axis, value } => FixedNodes::plane(rest, *axis, *value, tolerance),
            FixedSpec::Box { min, max } => FixedNodes::aabb(rest, *min, *max),
            FixedSpec::Label { label } => FixedNodes::from_list(rest.len(), &held(*label)),
        };
        fixed = fixed.union(&region);
    }
    fixed
}

/// The first plane or box hold that holds no node at `rest` (a mistyped coordinate would leave
/// the body free without a word).
pub(crate) fn empty_region_hold(config: &SceneConfig, rest: &[Vec3], size: Vec3) -> Option<String> {
    let tolerance = 1e-9 * size.iter().copied().fold(0.0, f64::max);
    let extent = |a: usize| {
        rest.iter()
            .map(|p| p[a])
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), c| (lo.min(c), hi.max(c)))
    };
    config.fixed.iter().enumerate().find_map(|(k, f)| match f {
        FixedSpec::Plane { axis, value } => {
            (FixedNodes::plane(rest, *axis, *value, tolerance).count() == 0).then(|| {
                let (lo, hi) = extent(*axis);
                format!(
                    "fixed[{k}]: no node lies on the plane {} = {value} (the nodes span {lo} … {hi} m)",
                    ["x", "y", "z"][*axis]
                )
            })
        }
        FixedSpec::Box { min, max } => (FixedNodes::aabb(rest, *min, *max).count() == 0)
            .then(|| format!("fixed[{k}]: no node lies in the box {min:?} … {max:?}")),
        FixedSpec::Label { .. } => None,
    })
}

/// The labels a scene holds by (`[[fixed]] label`) that no voxel of its model carries: a hold
/// that would hold nothing is an error when the scene is built.
pub(crate) fn missing_label_holds(
    config: &SceneConfig,
    present: impl Fn(u16) -> bool,
) -> Option<String> {
    config.fixed.iter().enumerate().find_map(|(k, f)| match f {
        FixedSpec::Label { label } if !present(*label) => {
            Some(format!("fixed[{k}].label: no voxel of the volume has label {label}"))
        }
        _ => None,
    })
}

/// Gravity plus the scene's patch loads spread over the model's nodes.
pub(crate) fn patch_loads(config: &SceneConfig, model: &HexModel) -> Result<Loads, String> {
    Ok(Loads { gravity: config.gravity, nodal: patch_forces(config, &model.rest)? })
}

/// The scene's patch loads spread over the nodes at `rest` (N per node); an error names the
/// first patch that holds no node.
pub(crate) fn patch_forces(config: &SceneConfig, rest: &[Vec3]) -> Result<Vec<Vec3>, String> {
    match spread_patches(config, rest) {
        (nodal, None) => Ok(nodal),
        (_, Some(k)) => {
            let load = &config.loads[k];
            Err(format!("loads[{k}]: no node lies within {} m of {:?}", load.radius, load.centre))
        }
    }
}

/// Every patch load spread over the nodes at `rest` (N per node), and the first patch that holds
/// no node (it adds nothing).
pub(crate) fn spread_patches(config: &SceneConfig, rest: &[Vec3]) -> (Vec<Vec3>, Option<usize>) {
    let mut loads = Loads { gravity: [0.0; 3], nodal: vec![[0.0; 3]; rest.len()] };
    let mut empty = None;
    for (k, load) in config.loads.iter().enumerate() {
        if loads.add_patch(rest, load.centre, load.radius, load.force) == 0 {
            empty = empty.or(Some(k));
        }
    }
    (loads.nodal, empty)
}
