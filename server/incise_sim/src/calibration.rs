//! `model.kind = "auto"`: model only what the scene needs. Each level of the branched grid up to
//! `max_level` is solved statically (linear elasticity, the scene's own supports and loads), with
//! each element kind (condensed, incompatible modes, composite cells) unless the scene fixes
//! one, and its error estimated against the finest level that is affordable to solve (at most
//! [`REFERENCE_MAX_DOFS`] unknowns; level 0 whenever it fits). The scene then runs on the
//! coarsest level where some kind's estimate is within `max_error`.
//!
//! The error measure is the displacement of the centre of mass, `ū = Σ mₙuₙ / Σ mₙ` with the
//! condensed lumped masses: `|ū_l − ū_ref| / |ū_ref|`. Under gravity it is the error of the work
//! the load does (the compliance), the global stiffness a user feels; it is the measure of the
//! Nesme comparison in `tests/nesme.rs`.

use crate::SceneConfig;
use crate::config::AutoLevel;
use crate::regions::{fixed_nodes, patch_loads};
use incise_fem::ode::static_solve_with;
use incise_fem::{ElementKind, Executor, Formulation, HexForceField, HexModel};
use incise_grid::{BranchedGrid, LabelVolume, MaterialTable};

/// The reference level is the finest with at most this many unknowns (a sparse Cholesky solve
/// of a few seconds on two cores).
pub const REFERENCE_MAX_DOFS: usize = 60_000;

/// One calibrated level and element kind.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelEstimate {
    /// Grid level.
    pub level: u32,
    /// How its elements' stiffnesses are made.
    pub element: ElementKind,
    /// Elements of the level's model.
    pub elements: usize,
    /// Unknowns (3 per node).
    pub dofs: usize,
    /// Estimated relative error against the reference level (0 for the reference itself).
    pub error: f64,
}

/// What the calibration found and chose.
#[derive(Clone, Debug, PartialEq)]
pub struct Calibration {
    /// The level the errors are measured against.
    pub reference_level: u32,
    /// Every level from the reference up to `max_level`, each with every element kind
    /// considered (one row at level 0, where the kinds are the same model), by level then in
    /// the order of [`ElementKind::ALL`].
    pub levels: Vec<LevelEstimate>,
    /// The level the scene runs on.
    pub chosen: u32,
    /// The element kind it runs with.
    pub chosen_element: ElementKind,
    /// The acceptable error it was chosen for.
    pub max_error: f64,
}

/// Calibrates `volume` (already filtered and strided) for `config` and picks the level and,
/// unless `element` is fixed (`auto.any_element` false), the element kind: the coarsest level
/// where some kind is within `max_error`, and there the first such kind of
/// [`ElementKind::ALL`] (the cheapest to cut; at one level the kinds step at about the same
/// rate). The reference is the finest affordable level with `element`.
///
/// # Errors
/// When a level cannot be built, the scene has no support (a static solve needs fixed nodes), or
/// a static solve does not converge.
pub fn calibrate(
    config: &SceneConfig,
    volume: &LabelVolume,
    table: &MaterialTable,
    auto: AutoLevel,
    element: ElementKind,
    exec: &Executor,
) -> Result<Calibration, String> {
    let mut solved: Vec<(u32, ElementKind, usize, usize, [f64; 3])> = Vec::new();
    for level in (0..=auto.max_level).rev() {
        let grid = BranchedGrid::build(volume, table, level).map_err(|e| e.to_string())?;
        let dofs = 3 * grid.top().node_count();
        if dofs > REFERENCE_MAX_DOFS && !solved.is_empty() {
            break;
        }
        // The reference kind last, so that the finest level's last row is the reference.
        let kinds: Vec<ElementKind> = if level > 0 && auto.any_element {
            ElementKind::ALL.into_iter().filter(|&k| k != element).chain([element]).collect()
        } else {
            vec![element]
        };
        for kind in kinds {
            let model = HexModel::from_grid_of_kind(&grid, kind);
            let shift = centre_shift(config, &grid, &model, exec)?;
            solved.push((level, kind, model.elements.len(), model.dof_count(), shift));
        }
    }
    let Some(&(reference_level, _, _, _, reference)) = solved.last() else {
        return Err("no level to calibrate".into());
    };
    let size = reference.iter().map(|x| x * x).sum::<f64>().sqrt();
    if size == 0.0 {
        return Err("the loads do not move the centre of mass; nothing to calibrate".into());
    }
    let mut levels: Vec<LevelEstimate> = solved
        .iter()
        .map(|&(level, element, elements, dofs, u)| LevelEstimate {
            level,
            element,
            elements,
            dofs,
            error: (0..3).map(|a| (u[a] - reference[a]).powi(2)).sum::<f64>().sqrt() / size,
        })
        .collect();
    let rank = |k: ElementKind| ElementKind::ALL.iter().position(|&a| a == k);
    levels.sort_by_key(|l| (l.level, rank(l.element)));
    let coarsest_within = levels
        .iter()
        .filter(|l| l.error <= auto.max_error)
        .map(|l| l.level)
        .max()
        .unwrap_or(reference_level);
    let chosen = levels
        .iter()
        .find(|l| l.level == coarsest_within && l.error <= auto.max_error)
        .map_or((reference_level, element), |l| (l.level, l.element));
    Ok(Calibration {
        reference_level,
        levels,
        chosen: chosen.0,
        chosen_element: chosen.1,
        max_error: auto.max_error,
    })
}

/// Static displacement of the centre of mass of the level's model under the scene's loads.
fn centre_shift(
    config: &SceneConfig,
    grid: &BranchedGrid,
    model: &HexModel,
    exec: &Executor,
) -> Result<[f64; 3], String> {
    let fixed = fixed_nodes(config, grid, model);
    if fixed.count() == 0 {
        return Err(
            "model.kind = \"auto\" calibrates with a static solve, which needs a `[[fixed]]` region"
                .into(),
        );
    }
    let loads = patch_loads(config, model)?;
    let mut ff = HexForceField::new(model, Formulation::Linear).with_executor(exec.clone());
    let mut x = model.rest.clone();
    let report = static_solve_with(model, &mut ff, &fixed, &loads, &mut x, 1e-8, 4, true);
    if !report.converged {
        return Err(format!(
            "the static calibration solve at level {} did not converge (residual {:.2e})",
            grid.top_level(),
            report.relative_residual
        ));
    }
    Ok(model.centre_of_mass_shift(&x))
}
