//! Scene B's block, shared by the integration tests.

use incise_fem::{FixedNodes, HexModel};
use incise_grid::procedural::from_fn;
use incise_grid::{BranchedGrid, Material, MaterialTable};
use incise_math::Vec3;

/// The block's size (m).
pub const SIZE: Vec3 = [0.15, 0.10, 0.08];

/// Scene B's block at `cells` hexahedra per axis (E = 3 kPa, ν = 0.45, ρ = 1000), its top face
/// fixed.
pub fn block(cells: [usize; 3]) -> (HexModel, FixedNodes) {
    let spacing = std::array::from_fn(|a| SIZE[a] / cells[a] as f64);
    let v = from_fn(cells, spacing, |_, _, _| 1);
    let grid =
        BranchedGrid::build(&v, &MaterialTable::uniform(&[1], Material::new(3e3, 0.45, 1000.0)), 0)
            .unwrap();
    let model = HexModel::from_grid(&grid);
    let fixed = FixedNodes::plane(&model.rest, 2, SIZE[2], 1e-9);
    (model, fixed)
}
