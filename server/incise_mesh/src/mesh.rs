//! A tetrahedral mesh as read from a file or generated: vertex positions, tetrahedra (four vertex
//! indices each, positively oriented) and a region label per tetrahedron that selects its material.
//! Construction checks every tetrahedron and names the first bad one.

use incise_math::Vec3;
use incise_math::mat3::{cross, dot};
use std::collections::HashMap;

/// A checked tetrahedral mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct TetMesh {
    vertices: Vec<Vec3>,
    tets: Vec<[u32; 4]>,
    regions: Vec<u32>,
}

/// What is wrong with a mesh, naming the element (0-based index in the input order).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TetMeshError {
    /// No tetrahedra at all.
    #[error("the mesh has no tetrahedra")]
    Empty,
    /// A vertex coordinate is NaN or infinite.
    #[error("vertex {vertex} has a non-finite coordinate {position:?}")]
    NonFiniteVertex {
        /// The vertex.
        vertex: usize,
        /// Its coordinates.
        position: Vec3,
    },
    /// A tetrahedron names a vertex that does not exist.
    #[error("tetrahedron {tet} names vertex {index}, but the mesh has {vertices} vertices")]
    IndexOutOfRange {
        /// The tetrahedron.
        tet: usize,
        /// The bad index.
        index: u32,
        /// Vertices in the mesh.
        vertices: usize,
    },
    /// A tetrahedron uses one vertex twice.
    #[error("tetrahedron {tet} repeats a vertex: {nodes:?}")]
    RepeatedVertex {
        /// The tetrahedron.
        tet: usize,
        /// Its vertices.
        nodes: [u32; 4],
    },
    /// A tetrahedron with (almost) no volume.
    #[error(
        "tetrahedron {tet} {nodes:?} is degenerate: volume {volume:e} m^3 against {scale:e} m^3 for its edge lengths"
    )]
    Degenerate {
        /// The tetrahedron.
        tet: usize,
        /// Its vertices.
        nodes: [u32; 4],
        /// Its signed volume.
        volume: f64,
        /// The cube of its longest edge, for scale.
        scale: f64,
    },
    /// A tetrahedron with negative volume (vertices in the wrong order, or folded).
    #[error(
        "tetrahedron {tet} {nodes:?} is inverted: signed volume {volume:e} m^3 (vertices 1, 2, 3 must turn anticlockwise seen from vertex 0's opposite side)"
    )]
    Inverted {
        /// The tetrahedron.
        tet: usize,
        /// Its vertices.
        nodes: [u32; 4],
        /// Its signed volume.
        volume: f64,
    },
    /// A triangle shared by more than two tetrahedra.
    #[error(
        "triangle {triangle:?} is shared by {count} tetrahedra (first: {first_tet}); a solid's triangle has one or two"
    )]
    NonManifold {
        /// The triangle's vertices (sorted).
        triangle: [u32; 3],
        /// How many tetrahedra share it.
        count: usize,
        /// The first tetrahedron that has it.
        first_tet: usize,
    },
    /// The region list does not match the tetrahedra.
    #[error("{regions} region labels for {tets} tetrahedra")]
    RegionCount {
        /// Labels given.
        regions: usize,
        /// Tetrahedra given.
        tets: usize,
    },
}

/// Volumes below this fraction of (longest edge)³ count as degenerate: a regular tetrahedron has
/// 0.118, a sliver worth simulating well above 1e-6.
const DEGENERATE_RATIO: f64 = 1e-9;

/// Signed volume of the tetrahedron `p` (positive when `p1 − p0, p2 − p0, p3 − p0` is right-handed).
#[must_use]
// Inline across crates: the incompressibility penalty calls it per tetrahedron per step.
#[inline]
pub fn signed_volume(p: &[Vec3; 4]) -> f64 {
    let e = |i: usize| -> Vec3 { std::array::from_fn(|a| p[i][a] - p[0][a]) };
    dot(&e(1), &cross(&e(2), &e(3))) / 6.0
}

impl TetMesh {
    /// Checks and builds a mesh. Inverted tetrahedra are an error here; readers of formats whose
    /// orientation convention differs reorder vertices before calling this.
    pub fn new(
        vertices: Vec<Vec3>,
        tets: Vec<[u32; 4]>,
        regions: Vec<u32>,
    ) -> Result<Self, TetMeshError> {
        if tets.is_empty() {
            return Err(TetMeshError::Empty);
        }
        if regions.len() != tets.len() {
            return Err(TetMeshError::RegionCount { regions: regions.len(), tets: tets.len() });
        }
        if let Some((vertex, p)) =
            vertices.iter().enumerate().find(|(_, p)| p.iter().any(|c| !c.is_finite()))
        {
            return Err(TetMeshError::NonFiniteVertex { vertex, position: *p });
        }
        let mut faces: HashMap<[u32; 3], (usize, usize)> = HashMap::with_capacity(2 * tets.len());
        for (t, nodes) in tets.iter().enumerate() {
            if let Some(&index) = nodes.iter().find(|&&i| i as usize >= vertices.len()) {
                return Err(TetMeshError::IndexOutOfRange {
                    tet: t,
                    index,
                    vertices: vertices.len(),
                });
            }
            let mut sorted = *nodes;
            sorted.sort_unstable();
            if sorted.windows(2).any(|w| w[0] == w[1]) {
                return Err(TetMeshError::RepeatedVertex { tet: t, nodes: *nodes });
            }
            let p = nodes.map(|i| vertices[i as usize]);
            let volume = signed_volume(&p);
            let longest = (0..4)
                .flat_map(|i| (i + 1..4).map(move |j| (i, j)))
                .map(|(i, j)| (0..3).map(|a| (p[i][a] - p[j][a]).powi(2)).sum::<f64>().sqrt())
                .fold(0.0f64, f64::max);
            let scale = longest.powi(3);
            if volume.abs() <= DEGENERATE_RATIO * scale {
                return Err(TetMeshError::Degenerate { tet: t, nodes: *nodes, volume, scale });
            }
            if volume < 0.0 {
                return Err(TetMeshError::Inverted { tet: t, nodes: *nodes, volume });
            }
            for f in 0..4 {
                let mut tri = [sorted[(f + 1) % 4], sorted[(f + 2) % 4], sorted[(f + 3) % 4]];
                tri.sort_unstable();
                let entry = faces.entry(tri).or_insert((0, t));
                entry.0 += 1;
                if entry.0 > 2 {
                    return Err(TetMeshError::NonManifold {
                        triangle: tri,
                        count: entry.0,
                        first_tet: entry.1,
                    });
                }
            }
        }
        Ok(Self { vertices, tets, regions })
    }

    /// Vertex rest positions (m).
    #[must_use]
    #[inline]
    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices
    }

    /// Tetrahedra, positively oriented.
    #[must_use]
    #[inline]
    pub fn tets(&self) -> &[[u32; 4]] {
        &self.tets
    }

    /// Region label of each tetrahedron.
    #[must_use]
    #[inline]
    pub fn regions(&self) -> &[u32] {
        &self.regions
    }

    /// Rest positions of tetrahedron `t`'s vertices.
    #[must_use]
    #[inline]
    pub fn tet_positions(&self, t: usize) -> [Vec3; 4] {
        self.tets[t].map(|i| self.vertices[i as usize])
    }

    /// Total rest volume (m³).
    #[must_use]
    pub fn volume(&self) -> f64 {
        (0..self.tets.len()).map(|t| signed_volume(&self.tet_positions(t))).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit() -> (Vec<Vec3>, Vec<[u32; 4]>) {
        (
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            vec![[0, 1, 2, 3]],
        )
    }

    #[test]
    fn bad_tetrahedra_are_named() {
        let (v, t) = unit();
        assert!(TetMesh::new(v.clone(), t.clone(), vec![1]).is_ok());
        let inverted = TetMesh::new(v.clone(), vec![[0, 2, 1, 3]], vec![1]).unwrap_err();
        assert!(matches!(inverted, TetMeshError::Inverted { tet: 0, .. }), "{inverted}");
        let out = TetMesh::new(v.clone(), vec![[0, 1, 2, 3], [0, 1, 2, 9]], vec![1, 1]);
        assert!(matches!(out, Err(TetMeshError::IndexOutOfRange { tet: 1, index: 9, .. })));
        let mut flat = v.clone();
        flat[3] = [0.3, 0.3, 0.0];
        let e = TetMesh::new(flat, t.clone(), vec![1]).unwrap_err();
        assert!(matches!(e, TetMeshError::Degenerate { tet: 0, .. }), "{e}");
        assert!(e.to_string().contains("tetrahedron 0"));
        assert!(matches!(
            TetMesh::new(v.clone(), vec![[0, 1, 1, 3]], vec![1]),
            Err(TetMeshError::RepeatedVertex { tet: 0, .. })
        ));
        assert!(matches!(
            TetMesh::new(v.clone(), t.clone(), vec![]),
            Err(TetMeshError::RegionCount { .. })
        ));
        let mut nan = v;
        nan[2][1] = f64::NAN;
        assert!(matches!(
            TetMesh::new(nan, t, vec![1]),
            Err(TetMeshError::NonFiniteVertex { vertex: 2, .. })
        ));
    }

    #[test]
    fn a_triangle_in_three_tetrahedra_is_refused() {
        let v = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.2, 0.2, 2.0],
        ];
        let e = TetMesh::new(v, vec![[0, 1, 2, 3], [0, 2, 1, 4], [0, 1, 2, 5]], vec![1; 3])
            .unwrap_err();
        assert!(
            matches!(e, TetMeshError::NonManifold { triangle: [0, 1, 2], count: 3, .. }),
            "{e}"
        );
    }
}
