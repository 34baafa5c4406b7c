//! Tetrahedral meshes generated from structured hexahedral lattices: a label volume at any grid
//! level (so the same organ runs in both model families) and the cylinder of paper 2's Table 1;
//! and an icosphere, a closed triangle mesh of a sphere.
//!
//! Every hexahedral cell is split into the 6 tetrahedra around its main diagonal (corner 0 to
//! corner 7, Kuhn's subdivision). All cells use the same diagonal, so two cells sharing a face split
//! it along the same diagonal: the mesh is conforming.

use crate::mesh::{TetMesh, TetMeshError, signed_volume};
use incise_grid::LabelVolume;
use incise_math::Vec3;
use std::collections::BTreeMap;

/// The 6 tetrahedra of a cell (corner `c` at `(c & 1, (c >> 1) & 1, c >> 2)`): for each order of
/// the three axes, the path 0 → one axis → two axes → 7.
pub const KUHN: [[usize; 4]; 6] = {
    let orders = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut out = [[0; 4]; 6];
    let mut i = 0;
    while i < 6 {
        let [a, b, _] = orders[i];
        out[i] = [0, 1 << a, (1 << a) | (1 << b), 7];
        i += 1;
    }
    out
};

/// Tetrahedralises the cells of a `cells[0] × cells[1] × cells[2]` lattice for which `region`
/// gives a label, with lattice node `(i, j, k)` at `position(i, j, k)`. Only used nodes are kept,
/// numbered in lattice order (x fastest); tetrahedra come cell by cell in the same order.
pub fn lattice_to_tets(
    cells: [usize; 3],
    region: impl Fn(usize, usize, usize) -> Option<u32>,
    position: impl Fn(usize, usize, usize) -> Vec3,
) -> Result<TetMesh, TetMeshError> {
    lattice_to_tets_with_cells(cells, region, position).map(|(mesh, _)| mesh)
}

/// [`lattice_to_tets`], also returning the lattice cell of each group of 6 tetrahedra
/// (tetrahedra `6k..6k + 6` come from cell `k` of the list).
pub fn lattice_to_tets_with_cells(
    cells: [usize; 3],
    region: impl Fn(usize, usize, usize) -> Option<u32>,
    position: impl Fn(usize, usize, usize) -> Vec3,
) -> Result<(TetMesh, Vec<[usize; 3]>), TetMeshError> {
    let node_key = |i: usize, j: usize, k: usize| (k * (cells[1] + 1) + j) * (cells[0] + 1) + i;
    let mut used: BTreeMap<usize, u32> = BTreeMap::new();
    let mut cell_tets: Vec<([usize; 8], u32)> = Vec::new();
    let mut cell_list = Vec::new();
    for k in 0..cells[2] {
        for j in 0..cells[1] {
            for i in 0..cells[0] {
                if let Some(r) = region(i, j, k) {
                    let corners: [usize; 8] = std::array::from_fn(|c| {
                        node_key(i + (c & 1), j + ((c >> 1) & 1), k + (c >> 2))
                    });
                    for &n in &corners {
                        used.insert(n, 0);
                    }
                    cell_tets.push((corners, r));
                    cell_list.push([i, j, k]);
                }
            }
        }
    }
    let mut vertices = Vec::with_capacity(used.len());
    for (n, id) in &mut used {
        *id = vertices.len() as u32;
        let i = n % (cells[0] + 1);
        let j = (n / (cells[0] + 1)) % (cells[1] + 1);
        let k = n / ((cells[0] + 1) * (cells[1] + 1));
        vertices.push(position(i, j, k));
    }
    let mut tets = Vec::with_capacity(6 * cell_tets.len());
    let mut regions = Vec::with_capacity(6 * cell_tets.len());
    for (corners, r) in &cell_tets {
        for kuhn in &KUHN {
            let mut t = kuhn.map(|c| used[&corners[c]]);
            if signed_volume(&t.map(|v| vertices[v as usize])) < 0.0 {
                t.swap(2, 3);
            }
            tets.push(t);
            regions.push(*r);
        }
    }
    Ok((TetMesh::new(vertices, tets, regions)?, cell_list))
}

/// The tetrahedralisation of `volume` at grid `level`: cells of `2^level` voxels per axis, a cell
/// present when any of its voxels is tissue, its region the most common tissue label among them
/// (the smallest on a tie). Positions are in the grid frame (voxel corner 0 at the origin), like
/// the hexahedral model's.
pub fn from_volume(volume: &LabelVolume, level: u32) -> Result<TetMesh, TetMeshError> {
    from_volume_with_cells(volume, level).map(|(mesh, _)| mesh)
}

/// [`from_volume`], also returning the grid cell (at `level`) of each group of 6 tetrahedra.
pub fn from_volume_with_cells(
    volume: &LabelVolume,
    level: u32,
) -> Result<(TetMesh, Vec<[usize; 3]>), TetMeshError> {
    let step = 1usize << level;
    let dims = volume.dims();
    let cells: [usize; 3] = std::array::from_fn(|a| dims[a].div_ceil(step));
    let spacing = volume.spacing();
    lattice_to_tets_with_cells(
        cells,
        |i, j, k| {
            let mut counts: BTreeMap<u16, usize> = BTreeMap::new();
            for z in k * step..((k + 1) * step).min(dims[2]) {
                for y in j * step..((j + 1) * step).min(dims[1]) {
                    for x in i * step..((i + 1) * step).min(dims[0]) {
                        let l = volume.label(x, y, z);
                        if l != 0 {
                            *counts.entry(l).or_default() += 1;
                        }
                    }
                }
            }
            counts.iter().max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0))).map(|(&l, _)| u32::from(l))
        },
        |i, j, k| {
            let p = [i, j, k];
            std::array::from_fn(|a| (p[a] * step).min(dims[a]) as f64 * spacing[a])
        },
    )
}

/// A solid cylinder along z: `radius`, `height`, base at z = 0 centred on the axis, region 1.
/// The cross-section is an `across × across` square lattice mapped onto the disc
/// (`(u, v) ↦ (u √(1 − v²/2), v √(1 − u²/2))`, smooth inside, exactly round outside); `across`
/// must be even so that the axis is a vertex ([`cylinder_top_centre`]). `layers` cells along z.
///
/// # Panics
/// If `across` is odd or zero, or `layers` is zero.
#[must_use]
pub fn cylinder(radius: f64, height: f64, across: usize, layers: usize) -> TetMesh {
    assert!(
        across > 0 && across.is_multiple_of(2),
        "the cylinder needs an even number of cells across"
    );
    assert!(layers > 0, "the cylinder needs at least one layer");
    lattice_to_tets(
        [across, across, layers],
        |_, _, _| Some(1),
        |i, j, k| {
            let u = 2.0 * i as f64 / across as f64 - 1.0;
            let v = 2.0 * j as f64 / across as f64 - 1.0;
            [
                radius * u * (1.0 - 0.5 * v * v).sqrt(),
                radius * v * (1.0 - 0.5 * u * u).sqrt(),
                height * k as f64 / layers as f64,
            ]
        },
    )
    .expect("the disc mapping keeps every tetrahedron positive")
}

/// The vertex on the axis at the top of a [`cylinder`] mesh.
///
/// # Panics
/// Never: a checked mesh has vertices.
#[must_use]
pub fn cylinder_top_centre(mesh: &TetMesh) -> usize {
    let top = mesh.vertices().iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
    (0..mesh.vertices().len())
        .min_by(|&a, &b| {
            let d = |n: usize| {
                let p = mesh.vertices()[n];
                p[0] * p[0] + p[1] * p[1] + (p[2] - top).powi(2)
            };
            d(a).total_cmp(&d(b))
        })
        .expect("a mesh has vertices")
}

/// A closed triangle mesh of a sphere of `radius` about `centre`: the icosahedron with each
/// triangle split into four `levels` times, the new vertices pushed out to the sphere (20 · 4^levels
/// triangles, normals outwards). A round tool shape, and a test mesh with no flat faces.
///
/// # Panics
/// If `radius` is not finite and positive, or `centre` not finite.
#[must_use]
pub fn icosphere(centre: Vec3, radius: f64, levels: usize) -> crate::TriMesh {
    let t = f64::midpoint(1.0, 5f64.sqrt());
    let normalised = |p: Vec3| {
        let n = p.iter().map(|c| c * c).sum::<f64>().sqrt();
        p.map(|c| c / n)
    };
    let mut unit: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .map(normalised)
    .to_vec();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        // Each edge's middle is made once, by whichever triangle reaches it first.
        let mut middles: BTreeMap<[u32; 2], u32> = BTreeMap::new();
        let mut middle = |a: u32, b: u32, unit: &mut Vec<Vec3>| {
            *middles.entry([a.min(b), a.max(b)]).or_insert_with(|| {
                let (p, q) = (unit[a as usize], unit[b as usize]);
                unit.push(normalised(std::array::from_fn(|i| p[i] + q[i])));
                unit.len() as u32 - 1
            })
        };
        triangles = triangles
            .iter()
            .flat_map(|&[a, b, c]| {
                let ab = middle(a, b, &mut unit);
                let bc = middle(b, c, &mut unit);
                let ca = middle(c, a, &mut unit);
                [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
            })
            .collect();
    }
    let vertices =
        unit.iter().map(|p| std::array::from_fn(|a| centre[a] + radius * p[a])).collect();
    crate::TriMesh::new(vertices, triangles).expect("a sphere of finite positive radius is closed")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cylinder_volume_approaches_pi_r2_h() {
        let (r, h) = (0.01, 0.03);
        let exact = std::f64::consts::PI * r * r * h;
        let coarse = cylinder(r, h, 4, 6);
        let fine = cylinder(r, h, 16, 12);
        let err = |m: &TetMesh| (m.volume() - exact).abs() / exact;
        assert!(err(&fine) < err(&coarse), "{} vs {}", err(&fine), err(&coarse));
        assert!(err(&fine) < 0.01, "{}", err(&fine));
        assert_eq!(fine.tets().len(), 6 * 16 * 16 * 12);
        let c = fine.vertices()[cylinder_top_centre(&fine)];
        assert!(c[0].abs() < 1e-15 && c[1].abs() < 1e-15 && (c[2] - h).abs() < 1e-15);
    }

    #[test]
    fn a_volume_tetrahedralises_at_every_level() {
        let dims = [6, 5, 4];
        let labels: Vec<u16> = (0..120)
            .map(|i| {
                let (x, y) = (i % 6, (i / 6) % 5);
                if x == 0 && y == 0 {
                    0
                } else if x < 3 {
                    1
                } else {
                    2
                }
            })
            .collect();
        let v = LabelVolume::new(dims, [0.001; 3], labels).unwrap();
        let l0 = from_volume(&v, 0).unwrap();
        assert_eq!(l0.tets().len(), 6 * (120 - 4));
        assert!((l0.volume() - 116e-9).abs() < 1e-20);
        assert!(l0.regions().iter().filter(|&&r| r == 2).count() == 6 * 60);
        let l1 = from_volume(&v, 1).unwrap();
        assert_eq!(l1.tets().len(), 6 * 3 * 3 * 2);
        assert!((l1.volume() - 120e-9).abs() < 1e-20, "{}", l1.volume());
    }
}
