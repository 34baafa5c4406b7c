//! `model.kind = "auto"`: model only what the scene needs. Each level of the branched grid up to
//! `max_level` is solved statically (linear elasticity, the scene's own supports and loads), with
//! each element kind (condensed, incompatible modes, composite cells) unless the scene fixes
//! one, and its error estimated against the finest level that is affordable to solve (at most
//! [`REFERENCE_MAX_DOFS`] unknowns; level 0 whenever it fits). The scene then runs on the
//! coarsest level where some kind's estimate is within `max_error`. A level of up to
//! [`CHOLESKY_MAX_DOFS`] unknowns is solved with a sparse Cholesky factor; a finer one by CG
//! preconditioned with the multigrid over it and the two levels above it
//! (`incise_fem::linsolve::multigrid`), which needs neither the factor's fill nor its time.
//!
//! The error measure is the displacement of the centre of mass, `ū = Σ mₙuₙ / Σ mₙ` with the
//! condensed lumped masses: `|ū_l − ū_ref| / |ū_ref|`. Under gravity it is the error of the work
//! the load does (the compliance), the global stiffness a user feels; it is the measure of the
//! Nesme comparison in `tests/nesme.rs`.

use crate::SceneConfig;
use crate::config::AutoLevel;
use crate::regions::{fixed_nodes, patch_loads};
use incise_fem::linsolve::multigrid::{LevelSpec, Multigrid};
use incise_fem::ode::{static_solve_multigrid, static_solve_with};
use incise_fem::{ElementKind, Executor, Formulation, HexForceField, HexModel};
use incise_grid::{BranchedGrid, LabelVolume, MaterialTable};

/// The reference level is the finest with at most this many unknowns: the 109,201-voxel liver's
/// level 0 (364,668) is within it, a solve of seconds with the multigrid on two cores.
pub const REFERENCE_MAX_DOFS: usize = 500_000;

/// Levels with at most this many unknowns are solved with a sparse Cholesky factor (the
/// 13,648-voxel liver's level 0, 50,184 unknowns, among them), finer ones with the multigrid
/// (the factor of the 109,201-voxel liver's level 0 would take minutes).
pub const CHOLESKY_MAX_DOFS: usize = 60_000;

/// Coarser levels in a multigrid hierarchy below the level it solves (two: the fastest setting
/// on the liver, `incise-bench multigrid`).
const MULTIGRID_DEPTH: u32 = 2;

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
    // The grids built so far, by level: a multigrid's coarser levels.
    let mut grids: Vec<Option<BranchedGrid>> = Vec::new();
    let grid_at = |level: u32| -> Result<BranchedGrid, String> {
        BranchedGrid::build(volume, table, level).map_err(|e| e.to_string())
    };
    for level in (0..=auto.max_level).rev() {
        let grid = grid_at(level)?;
        let dofs = 3 * grid.top().node_count();
        if dofs > REFERENCE_MAX_DOFS && !solved.is_empty() {
            break;
        }
        // The grid has no levels above its deepest: a hierarchy stops there, and a level with
        // none above it is factorised.
        let coarser: Vec<BranchedGrid> = if dofs > CHOLESKY_MAX_DOFS {
            let mut out = Vec::new();
            for l in level + 1..=(level + MULTIGRID_DEPTH).min(incise_grid::grid::MAX_LEVELS) {
                let built = grids.get_mut(l as usize).and_then(Option::take);
                out.push(match built {
                    Some(g) => g,
                    None => grid_at(l)?,
                });
            }
            out
        } else {
            Vec::new()
        };
        // The reference kind last, so that the finest level's last row is the reference.
        let kinds: Vec<ElementKind> = if level > 0 && auto.any_element {
            ElementKind::ALL.into_iter().filter(|&k| k != element).chain([element]).collect()
        } else {
            vec![element]
        };
        for kind in kinds {
            let model = HexModel::from_grid_of_kind(&grid, kind);
            let shift = centre_shift(config, &grid, &model, &coarser, exec)?;
            solved.push((level, kind, model.elements.len(), model.dof_count(), shift));
        }
        // Keep what the next finer level's hierarchy may use: this level and the one above it.
        grids.resize_with(grids.len().max(level as usize + 2), || None);
        grids.truncate(level as usize + MULTIGRID_DEPTH as usize);
        if let Some(above) = coarser.into_iter().next() {
            grids[level as usize + 1] = Some(above);
        }
        grids[level as usize] = Some(grid);
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

/// Static displacement of the centre of mass of the level's model under the scene's loads:
/// solved with a sparse Cholesky factor, or with the multigrid over the level and the `coarser`
/// grids when there are any.
fn centre_shift(
    config: &SceneConfig,
    grid: &BranchedGrid,
    model: &HexModel,
    coarser: &[BranchedGrid],
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
    let report = if coarser.is_empty() {
        static_solve_with(model, &mut ff, &fixed, &loads, &mut x, 1e-8, 4, true)
    } else {
        let mut levels = vec![LevelSpec { grid, model: model.clone(), fixed: fixed.clone() }];
        for g in coarser {
            let m = HexModel::from_grid_of_kind(g, ElementKind::Condensed);
            let fixed = fixed_nodes(config, g, &m);
            levels.push(LevelSpec { grid: g, model: m, fixed });
        }
        let mut mg = Multigrid::new(levels, Formulation::Linear, 0.0, 1.0, 2, exec)?;
        static_solve_multigrid(model, &mut ff, &fixed, &loads, &mut x, 1e-8, 4, &mut mg)
    };
    if !report.converged {
        return Err(format!(
            "the static calibration solve at level {} did not converge (residual {:.2e})",
            grid.top_level(),
            report.relative_residual
        ));
    }
    Ok(model.centre_of_mass_shift(&x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The multigrid path gives the Cholesky path's answer: both solve the same linear system to
    /// 1e-8 of the load, so their centres of mass agree far below the sag (1e-6 of it allows for
    /// the two residuals' directions).
    #[test]
    fn the_multigrid_solve_gives_the_factors_centre_of_mass() {
        let text = "name = \"organ\"\n[volume]\nprocedural = \"organ\"\nsize_m = [0.12, 0.09, 0.08]\n\
                    voxels = [24, 18, 16]\n[[materials]]\nlabel = 1\nyoungs_modulus = 3000.0\n\
                    poisson_ratio = 0.45\ndensity = 1000.0\n[[materials]]\nlabel = 2\n\
                    youngs_modulus = 9000.0\npoisson_ratio = 0.45\ndensity = 1000.0\n\
                    [integrator]\nkind = \"implicit-euler\"\ndt = 0.001\n[[fixed]]\nmin = [-1.0, -1.0, 0.06]\n\
                    max = [1.0, 1.0, 1.0]\n";
        let config = SceneConfig::from_toml(text, "organ.toml").unwrap();
        let volume = config.procedural_volume().unwrap();
        let mut table = MaterialTable::new();
        for m in &config.materials {
            table.insert(m.label, m.material());
        }
        let exec = Executor::default();
        let grid = BranchedGrid::build(&volume, &table, 0).unwrap();
        let coarser: Vec<BranchedGrid> =
            (1..=2).map(|l| BranchedGrid::build(&volume, &table, l).unwrap()).collect();
        let model = HexModel::from_grid_of_kind(&grid, ElementKind::Condensed);
        let factor = centre_shift(&config, &grid, &model, &[], &exec).unwrap();
        let multigrid = centre_shift(&config, &grid, &model, &coarser, &exec).unwrap();
        let sag = factor.iter().map(|x| x * x).sum::<f64>().sqrt();
        let diff = (0..3).map(|a| (factor[a] - multigrid[a]).powi(2)).sum::<f64>().sqrt();
        assert!(sag > 1e-4, "the organ sags: {sag:e} m");
        assert!(diff <= 1e-6 * sag, "{factor:?} against {multigrid:?}");
    }
}
