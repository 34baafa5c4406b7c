//! Whether a point lies inside the tissue's volume, as the tool proxy asks: in a hexahedral
//! scene, in an occupied fine voxel of the deformed element that owns it (Jeřábková 2010 §2:
//! the voxels are embedded in their element's trilinear field, so the element's map, inverted
//! by Newton's method, takes the point back to the voxel it lies in); in a tensor-mass scene, in
//! a live deformed tetrahedron.
//!
//! A proxy asks many times within one step about points near its path, so the elements (or
//! tetrahedra) whose deformed boxes meet that path are gathered once ([`TissueVolume::near`]).

use incise_grid::BranchedGrid;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, det};
use incise_mesh::TetTopology;

/// One deformed element that may hold a point: its corners (Morton order), its cell's first
/// voxel, and its id.
pub(crate) struct Element {
    id: u32,
    corners: [Vec3; 8],
    first_voxel: [u32; 3],
}

/// The part of the tissue near a region, for point-inside tests.
pub(crate) enum TissueVolume<'a> {
    /// Hexahedral elements over a branched grid.
    Hex { grid: &'a BranchedGrid, elements: Vec<Element> },
    /// Live tetrahedra by their deformed corners.
    Tet(Vec<[Vec3; 4]>),
}

/// Whether box `(lo, hi)` meets the box of `points`.
fn meets(points: &[Vec3], lo: Vec3, hi: Vec3) -> bool {
    (0..3).all(|k| {
        let (a, b) = points
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p[k]), b.max(p[k])));
        b >= lo[k] && a <= hi[k]
    })
}

impl<'a> TissueVolume<'a> {
    /// The top-level elements of `grid` (node positions by grid node id `by_grid_node`) whose
    /// deformed boxes meet `(lo, hi)`.
    pub(crate) fn hex_near(
        grid: &'a BranchedGrid,
        by_grid_node: &[Vec3],
        (lo, hi): (Vec3, Vec3),
    ) -> Self {
        let top = grid.top();
        let scale = 1u32 << grid.top_level();
        let elements = top
            .elements()
            .filter_map(|(id, e)| {
                let corners = e.nodes.map(|n| by_grid_node[n as usize]);
                meets(&corners, lo, hi).then(|| Element {
                    id,
                    corners,
                    first_voxel: top.cell_coords(e.cell).map(|c| c * scale),
                })
            })
            .collect();
        Self::Hex { grid, elements }
    }

    /// The live tetrahedra of `topology` (positions `x`) whose deformed boxes meet `(lo, hi)`.
    pub(crate) fn tet_near(topology: &TetTopology, x: &[Vec3], (lo, hi): (Vec3, Vec3)) -> Self {
        let tets = topology
            .tets()
            .iter()
            .enumerate()
            .filter(|&(t, _)| topology.is_alive(t))
            .map(|(_, v)| v.map(|i| x[i as usize]))
            .filter(|c| meets(c, lo, hi))
            .collect();
        Self::Tet(tets)
    }

    /// Whether `p` (grid frame, deformed) lies inside the tissue.
    pub(crate) fn contains(&self, p: Vec3) -> bool {
        match self {
            Self::Hex { grid, elements } => elements.iter().any(|e| in_element(grid, e, p)),
            Self::Tet(tets) => tets.iter().any(|t| in_tet(t, p)),
        }
    }
}

/// Whether `p` lies in an occupied voxel that element `e` owns.
fn in_element(grid: &BranchedGrid, e: &Element, p: Vec3) -> bool {
    if !meets(&e.corners, p, p) {
        return false;
    }
    let Some(xi) = local(&e.corners, p) else { return false };
    let fine = grid.fine();
    let dims = fine.dims();
    let per_cell = 1u32 << grid.top_level();
    let mut v = [0u32; 3];
    for k in 0..3 {
        // The point's voxel within the cell; a point on the cell's far face belongs to its last
        // voxel.
        let within = (xi[k] * f64::from(per_cell)).floor().clamp(0.0, f64::from(per_cell - 1));
        v[k] = e.first_voxel[k] + within as u32;
        if v[k] >= dims[k] {
            return false;
        }
    }
    let index = v[0] + dims[0] * (v[1] + dims[1] * v[2]);
    grid.voxel_element(index) == Some(e.id)
}

/// The trilinear weight of corner `c` (Morton order) at local coordinates `xi`, and its
/// gradient.
fn weight(c: usize, xi: Vec3) -> (f64, Vec3) {
    let f = |k: usize| if c >> k & 1 == 1 { xi[k] } else { 1.0 - xi[k] };
    let d = |k: usize| if c >> k & 1 == 1 { 1.0 } else { -1.0 };
    (f(0) * f(1) * f(2), [d(0) * f(1) * f(2), f(0) * d(1) * f(2), f(0) * f(1) * d(2)])
}

/// The local coordinates in `[0, 1]³` of `p` in the trilinear cell with `corners`, if it lies in
/// the cell: Newton's method from the centre. A corotational element turns and stretches but
/// stays far from folding, where the map is near affine and Newton converges in a few steps.
fn local(corners: &[Vec3; 8], p: Vec3) -> Option<Vec3> {
    let mut xi = [0.5; 3];
    let size = corners
        .iter()
        .map(|c| (0..3).map(|k| (c[k] - corners[0][k]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    for _ in 0..12 {
        let mut x = [0.0; 3];
        let mut j: Mat3 = [[0.0; 3]; 3];
        for (c, q) in corners.iter().enumerate() {
            let (w, g) = weight(c, xi);
            for r in 0..3 {
                x[r] += w * q[r];
                for s in 0..3 {
                    j[r][s] += g[s] * q[r];
                }
            }
        }
        let residual: Vec3 = std::array::from_fn(|k| p[k] - x[k]);
        let step = solve(&j, residual)?;
        for k in 0..3 {
            xi[k] += step[k];
        }
        if xi.iter().any(|c| !c.is_finite() || c.abs() > 4.0) {
            return None;
        }
        if residual.iter().map(|c| c.abs()).fold(0.0, f64::max) <= 1e-12 * size {
            break;
        }
    }
    let slack = 1e-9;
    xi.iter().all(|&c| (-slack..=1.0 + slack).contains(&c)).then_some(xi)
}

/// `J⁻¹ r` by Cramer's rule; `None` for a singular `J`.
fn solve(j: &Mat3, r: Vec3) -> Option<Vec3> {
    let d = det(j);
    if d.abs() < 1e-300 {
        return None;
    }
    let with = |col: usize| -> Mat3 {
        std::array::from_fn(|a| std::array::from_fn(|b| if b == col { r[a] } else { j[a][b] }))
    };
    Some(std::array::from_fn(|k| det(&with(k)) / d))
}

/// Whether `p` lies in the tetrahedron with corners `t` (either orientation).
fn in_tet(t: &[Vec3; 4], p: Vec3) -> bool {
    if !meets(t, p, p) {
        return false;
    }
    let sub = |a: Vec3, b: Vec3| -> Vec3 { std::array::from_fn(|k| a[k] - b[k]) };
    let volume = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| det(&[sub(b, a), sub(c, a), sub(d, a)]);
    let whole = volume(t[0], t[1], t[2], t[3]);
    if whole == 0.0 {
        return false;
    }
    let parts = [
        volume(p, t[1], t[2], t[3]),
        volume(t[0], p, t[2], t[3]),
        volume(t[0], t[1], p, t[3]),
        volume(t[0], t[1], t[2], p),
    ];
    parts.iter().all(|&v| v * whole >= 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newton_finds_a_point_in_a_turned_and_sheared_cell() {
        // The unit cell turned 30° about z, stretched 1.2× along x and sheared in z.
        let (s, c) = (0.5f64, 3f64.sqrt() / 2.0);
        let map = |q: Vec3| -> Vec3 {
            let x = 1.2 * q[0];
            [c * x - s * q[1], s * x + c * q[1], q[2] + 0.1 * q[0] * q[1]]
        };
        let corners: [Vec3; 8] =
            std::array::from_fn(|n| map([(n & 1) as f64, (n >> 1 & 1) as f64, (n >> 2) as f64]));
        let xi = [0.3, 0.8, 0.55];
        // The point the trilinear map of the corners gives (the shear is bilinear: exact).
        let p = map(xi);
        let found = local(&corners, p).expect("inside");
        for k in 0..3 {
            assert!((found[k] - xi[k]).abs() < 1e-10, "{found:?}");
        }
        assert!(local(&corners, map([1.2, 0.5, 0.5])).is_none());
    }

    #[test]
    fn a_point_is_inside_a_tetrahedron_of_either_orientation() {
        let t = [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(in_tet(&t, [0.2, 0.2, 0.2]));
        assert!(!in_tet(&t, [0.5, 0.5, 0.5]));
        let flipped = [t[1], t[0], t[2], t[3]];
        assert!(in_tet(&flipped, [0.2, 0.2, 0.2]));
    }
}
