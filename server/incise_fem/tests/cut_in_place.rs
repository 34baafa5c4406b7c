//! A cut carried in place (`HexModel::update`, `State::carry`, `HexForceField::remap`) gives the
//! same bits as the model rebuilt from the grid, the state carried from the old model to the new
//! (`State::across_cut`) and the field remapped onto a copy (`HexForceField::remapped`), through
//! cuts that split elements, add and remove nodes, and keep every node; with each kind of
//! element.

use incise_fem::forcefield::hex::Formulation;
use incise_fem::linsolve::cg::CgSettings;
use incise_fem::model::{Loads, State};
use incise_fem::ode::{BackwardEuler, Rayleigh};
use incise_fem::{ElementKind, FixedNodes, HexForceField, HexModel};
use incise_grid::procedural::{TISSUE, TUMOUR, ellipsoid_with_inclusion};
use incise_grid::{BranchedGrid, GridEdit, Material, MaterialTable};
use incise_math::Vec3;

fn bits(v: &[Vec3]) -> Vec<u64> {
    v.iter().flatten().map(|x| x.to_bits()).collect()
}

fn bits_of(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn assert_same_model(a: &HexModel, b: &HexModel, what: &str) {
    assert_eq!(bits(&a.rest), bits(&b.rest), "{what}: rest positions");
    assert_eq!(a.grid_node, b.grid_node, "{what}: node numbering");
    let mass = |m: &[f64]| m.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(mass(&a.lumped_mass), mass(&b.lumped_mass), "{what}: lumped masses");
    assert_eq!(a.elements.len(), b.elements.len(), "{what}: element count");
    for (ea, eb) in a.elements.iter().zip(&b.elements) {
        assert_eq!((ea.grid_id, ea.nodes), (eb.grid_id, eb.nodes), "{what}: element");
        let same = |x: &[f64], y: &[f64]| x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits());
        assert!(same(&ea.stiffness.0, &eb.stiffness.0), "{what}: stiffness of {}", ea.grid_id);
        assert!(same(&ea.mass, &eb.mass), "{what}: mass of element {}", ea.grid_id);
    }
}

#[test]
fn a_cut_in_place_equals_a_cut_on_copies() {
    cut_in_place_equals_cut_on_copies(ElementKind::Condensed);
}

#[test]
fn a_cut_in_place_equals_a_cut_on_copies_with_incompatible_modes() {
    cut_in_place_equals_cut_on_copies(ElementKind::Incompatible);
}

#[test]
fn a_cut_in_place_equals_a_cut_on_copies_with_composite_cells() {
    cut_in_place_equals_cut_on_copies(ElementKind::Composite);
}

fn cut_in_place_equals_cut_on_copies(kind: ElementKind) {
    let v = ellipsoid_with_inclusion(24, 5e-3);
    let mut table = MaterialTable::new();
    table.insert(TISSUE, Material::new(3e3, 0.45, 1000.0));
    table.insert(TUMOUR, Material::new(3e4, 0.45, 1000.0));
    let mut grid = BranchedGrid::build(&v, &table, 2).unwrap();
    let mut model = HexModel::from_grid_of_kind(&grid, kind);
    assert_eq!(model.element, kind);
    let mut ff = HexForceField::new(&model, Formulation::Corotational);
    let mut state = State::at_rest(&model);
    let dims = grid.fine().dims();
    let voxel = |x: u32, y: u32, z: u32| x + dims[0] * (y + dims[1] * z);
    let column = |x: u32| -> Vec<u32> {
        (0..dims[2]).flat_map(|z| (0..dims[1] / 2).map(move |y| voxel(x, y, z))).collect()
    };
    let mut edits: Vec<GridEdit> = [5u32, 9, 12, 13, 17]
        .into_iter()
        .map(|x| {
            let remove = column(x);
            let links = remove.iter().map(|&i| (i + 1, i + 2)).collect();
            GridEdit { remove_voxels: remove, sever_links: links }
        })
        .collect();
    // One voxel inside the organ: re-condenses its element, moves no node.
    let inside = (0..grid.fine().voxel_count() as u32)
        .find(|&i| {
            let c = [i % dims[0], (i / dims[0]) % dims[1], i / (dims[0] * dims[1])];
            (0..3).all(|a| c[a] % 4 == 1) && c[0] > 18 && grid.fine().material(i).is_some()
        })
        .unwrap();
    edits.insert(2, GridEdit { remove_voxels: vec![inside], sever_links: vec![] });
    // A whole level-2 cell first: its element goes, and a later split reuses its id, so a new
    // element lands among the old ones.
    let cell: Vec<u32> = (8..12)
        .flat_map(|z| (8..12).flat_map(move |y| (8..12).map(move |x| voxel(x, y, z))))
        .collect();
    edits.insert(0, GridEdit { remove_voxels: cell, sever_links: vec![] });

    let loads = Loads::gravity([0.0, 0.0, -9.81]);
    let mut be =
        BackwardEuler::new(1e-2, Rayleigh { alpha: 1.0, beta: 0.01 }, CgSettings::default());
    let (mut node_moves, mut element_moves, mut node_keeps) = (0, 0, 0);
    let mut enriched = 0;
    for (k, edit) in edits.iter().enumerate() {
        // Some motion first, so that rotations and velocities are not trivial.
        let fixed = FixedNodes::by_position(&model.rest, |p| p[2] < 0.03);
        for _ in 0..3 {
            be.step(&model, &mut ff, &fixed, &loads, &mut state);
        }
        let changes = grid.apply(edit).unwrap();
        let what = format!("cut {k}");
        let copy = model.updated(&grid, &changes);
        let carried = state.across_cut(&model, &copy, &changes);
        let origin = |g: u32| {
            changes.top.elements_added.iter().find(|&&(id, _)| id == g).and_then(|&(_, o)| o)
        };
        let remapped = ff.remapped(&model, &copy, origin);

        let renumbering = model.update(&grid, &changes);
        assert_same_model(&model, &copy, &what);
        let rebuilt = HexModel::from_grid_of_kind(&grid, kind);
        assert_same_model(&model, &rebuilt, &what);
        // The enriched kinds kept to themselves: the cut elements' stiffnesses are not the
        // condensed ones the grid holds.
        let condensed = HexModel::from_grid(&grid);
        let differ = renumbering
            .new_matrices
            .iter()
            .filter(|&&i| {
                let i = i as usize;
                bits_of(&model.elements[i].stiffness.0)
                    != bits_of(&condensed.elements[i].stiffness.0)
            })
            .count();
        if kind == ElementKind::Condensed {
            assert_eq!(differ, 0, "{what}");
        }
        enriched += differ;
        for (i, before) in renumbering.node_before.iter().enumerate() {
            if let Some(j) = before {
                assert_eq!(renumbering.grid_node_before[*j as usize], model.grid_node[i], "{what}");
            }
        }
        for (i, before) in renumbering.element_before.iter().enumerate() {
            if let Some(j) = before {
                assert_eq!(renumbering.grid_id_before[*j as usize], model.elements[i].grid_id);
            }
        }
        let old_of_new = state.carry(&model, &renumbering, &changes);
        assert_eq!(old_of_new, carried.old_of_new, "{what}: node origins");
        assert_eq!(bits(&state.x), bits(&carried.state.x), "{what}: positions");
        assert_eq!(bits(&state.v), bits(&carried.state.v), "{what}: velocities");
        ff.remap(&model, &renumbering, origin);

        // The same rotations now and after re-extraction (off-centre gradients included), and the
        // same forces (the permuted matrices and their Walsh forms).
        let mut other = remapped;
        for e in 0..model.elements.len() {
            assert_eq!(ff.rotation(e), other.rotation(e), "{what}: rotation of element {e}");
        }
        ff.update_rotations(&model, &state.x);
        other.update_rotations(&model, &state.x);
        for e in 0..model.elements.len() {
            assert_eq!(ff.rotation(e), other.rotation(e), "{what}: rotation of element {e}");
        }
        let (mut f, mut g) =
            (vec![[0.0; 3]; model.node_count()], vec![[0.0; 3]; model.node_count()]);
        ff.add_forces(&model, &state.x, &mut f);
        other.add_forces(&model, &state.x, &mut g);
        assert_eq!(bits(&f), bits(&g), "{what}: forces");
        be.remap_warm_start(&old_of_new);

        println!(
            "{what}: {} voxels removed, {} links severed; {} of {} elements with new matrices, {} nodes added, {} removed",
            changes.voxels_removed,
            changes.links_severed,
            renumbering.new_matrices.len(),
            model.elements.len(),
            changes.top.nodes_added.len(),
            changes.top.nodes_removed.len()
        );
        if renumbering.same_nodes() {
            node_keeps += 1;
        } else {
            node_moves += 1;
        }
        // A new element before an old one: an id the edit (or an earlier one) freed, reused.
        let first_new = renumbering.element_before.iter().position(Option::is_none);
        let last_old = renumbering.element_before.iter().rposition(Option::is_some);
        if let (Some(new), Some(old)) = (first_new, last_old)
            && new < old
        {
            element_moves += 1;
        }
    }
    assert!(node_moves > 0 && node_keeps > 0 && element_moves > 0, "{node_moves} {node_keeps}");
    if kind != ElementKind::Condensed {
        assert!(enriched > 0, "every re-made stiffness was the condensed one");
    }
}
