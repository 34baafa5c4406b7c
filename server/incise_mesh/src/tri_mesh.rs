//! A closed triangle mesh: the surface of a solid, as a surgical tool's shape is given (read from
//! STL or OBJ by `incise_io`). Construction checks that the triangles bound a solid — every edge
//! in exactly two triangles, which run along it in opposite directions — and orients the whole
//! surface so that its normals point outwards. A mesh whose winding disagrees between neighbours
//! is refused, not repaired: which side is outside is the modeller's decision, and guessing it
//! wrong would turn a tool inside out without a word.

use incise_math::Vec3;
use incise_math::mat3::{cross, dot};
use std::collections::HashMap;
use std::collections::hash_map::Entry;

/// A checked closed triangle mesh, normals outwards.
#[derive(Clone, Debug, PartialEq)]
pub struct TriMesh {
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
}

/// What is wrong with a triangle mesh, naming the triangles (0-based, in input order), vertices
/// and edges involved.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TriMeshError {
    /// No triangles at all.
    #[error("the mesh has no triangles")]
    Empty,
    /// A vertex coordinate is NaN or infinite.
    #[error("vertex {vertex} has a non-finite coordinate {position:?}")]
    NonFiniteVertex {
        /// The vertex.
        vertex: usize,
        /// Its coordinates.
        position: Vec3,
    },
    /// A triangle names a vertex that does not exist.
    #[error("triangle {triangle} names vertex {index}, but the mesh has {vertices} vertices")]
    IndexOutOfRange {
        /// The triangle.
        triangle: usize,
        /// The bad index.
        index: u32,
        /// Vertices in the mesh.
        vertices: usize,
    },
    /// A triangle uses one vertex twice.
    #[error("triangle {triangle} repeats a vertex: {nodes:?}")]
    RepeatedVertex {
        /// The triangle.
        triangle: usize,
        /// Its vertices.
        nodes: [u32; 3],
    },
    /// A triangle with (almost) no area: its corners are on one line.
    #[error("triangle {triangle} {nodes:?} has no area: its corners {positions:?} are on one line")]
    Degenerate {
        /// The triangle.
        triangle: usize,
        /// Its vertices.
        nodes: [u32; 3],
        /// Their coordinates.
        positions: [Vec3; 3],
    },
    /// Two triangles with the same three vertices, in either order.
    #[error("triangles {first} and {second} both join vertices {nodes:?}")]
    DuplicateTriangle {
        /// The first of the two.
        first: usize,
        /// The second.
        second: usize,
        /// The second's vertices.
        nodes: [u32; 3],
    },
    /// An edge in one triangle only: the surface has a hole or a gap there.
    #[error(
        "triangle {triangle}'s edge {edge:?} (from {from:?} to {to:?}) is in no other triangle: \
         the surface is open there"
    )]
    OpenEdge {
        /// The triangle.
        triangle: usize,
        /// The edge's vertices, in the triangle's order.
        edge: [u32; 2],
        /// The first vertex's coordinates.
        from: Vec3,
        /// The second vertex's coordinates.
        to: Vec3,
    },
    /// An edge in more than two triangles: surfaces meet along it, so no side is inside.
    #[error(
        "edge {edge:?} (from {from:?} to {to:?}) is in {count} triangles (first: {triangles:?}); \
         a closed surface has each edge in exactly two"
    )]
    NonManifoldEdge {
        /// The edge's vertices, the lower index first.
        edge: [u32; 2],
        /// The first vertex's coordinates.
        from: Vec3,
        /// The second vertex's coordinates.
        to: Vec3,
        /// How many triangles have it.
        count: usize,
        /// The first three of them.
        triangles: [usize; 3],
    },
    /// Two neighbours that run along their shared edge in the same direction: one of them is
    /// wound the other way, so their normals point to opposite sides of the surface.
    #[error(
        "triangles {first} and {second} both run along edge {edge:?} (from {from:?} to {to:?}) \
         in the same direction: their windings disagree, so one of them faces inwards"
    )]
    InconsistentWinding {
        /// The edge's vertices, in the direction both triangles use.
        edge: [u32; 2],
        /// The first vertex's coordinates.
        from: Vec3,
        /// The second vertex's coordinates.
        to: Vec3,
        /// The first of the two triangles.
        first: usize,
        /// The second.
        second: usize,
    },
    /// A closed surface that encloses (almost) nothing: flat, or folded onto itself.
    #[error(
        "the surface encloses a volume of {volume:e}, against {scale:e} for its bounding box: \
         it is flat or folded onto itself"
    )]
    ZeroVolume {
        /// The signed volume enclosed.
        volume: f64,
        /// The volume of the bounding box, for scale.
        scale: f64,
    },
}

/// Twice a triangle's area below this fraction of its longest edge squared counts as none. The
/// rounding of exactly collinear corners leaves about 1e-16; any sliver a file's precision can
/// resolve (f32 STL: 1e-7) is far above.
const DEGENERATE_RATIO: f64 = 1e-12;

/// An enclosed volume below this fraction of the bounding box's counts as none: far below any
/// solid, far above the rounding of a flat surface's signed volume.
const FLAT_RATIO: f64 = 1e-12;

/// One undirected edge as the triangles use it.
struct EdgeUse {
    count: usize,
    /// The first three triangles that have it.
    triangles: [usize; 3],
    /// Whether each of the first two runs from the lower index to the higher.
    forward: [bool; 2],
}

impl TriMesh {
    /// Checks and orients a mesh: every index in range, every coordinate finite, no triangle with
    /// a repeated vertex or no area, no two triangles on the same three vertices, and closed and
    /// manifold: every undirected edge is in exactly two triangles, which use it in opposite
    /// directions. If the enclosed signed volume is negative every triangle is flipped, so that
    /// normals (right-handed in the vertex order) point outwards. A winding that disagrees
    /// between neighbours is an error, never repaired. Unused vertices are allowed and kept.
    pub fn new(vertices: Vec<Vec3>, mut triangles: Vec<[u32; 3]>) -> Result<Self, TriMeshError> {
        if triangles.is_empty() {
            return Err(TriMeshError::Empty);
        }
        if let Some((vertex, p)) =
            vertices.iter().enumerate().find(|(_, p)| p.iter().any(|c| !c.is_finite()))
        {
            return Err(TriMeshError::NonFiniteVertex { vertex, position: *p });
        }
        let mut seen: HashMap<[u32; 3], usize> = HashMap::with_capacity(triangles.len());
        for (t, nodes) in triangles.iter().enumerate() {
            if let Some(&index) = nodes.iter().find(|&&i| i as usize >= vertices.len()) {
                return Err(TriMeshError::IndexOutOfRange {
                    triangle: t,
                    index,
                    vertices: vertices.len(),
                });
            }
            let [a, b, c] = *nodes;
            if a == b || b == c || a == c {
                return Err(TriMeshError::RepeatedVertex { triangle: t, nodes: *nodes });
            }
            let p = nodes.map(|i| vertices[i as usize]);
            if is_degenerate(&p) {
                return Err(TriMeshError::Degenerate { triangle: t, nodes: *nodes, positions: p });
            }
            let mut sorted = *nodes;
            sorted.sort_unstable();
            if let Some(&first) = seen.get(&sorted) {
                return Err(TriMeshError::DuplicateTriangle { first, second: t, nodes: *nodes });
            }
            seen.insert(sorted, t);
        }
        drop(seen);
        check_edges(&vertices, &triangles)?;
        let (lo, hi) = bounds_of(&vertices, &triangles);
        let volume = signed_volume_of(&vertices, &triangles, centre(lo, hi));
        let scale = (0..3).map(|a| hi[a] - lo[a]).product::<f64>();
        if volume.abs() <= FLAT_RATIO * scale {
            return Err(TriMeshError::ZeroVolume { volume, scale });
        }
        if volume < 0.0 {
            for t in &mut triangles {
                t.swap(1, 2);
            }
        }
        Ok(Self { vertices, triangles })
    }

    /// Vertex positions, unused ones included.
    #[must_use]
    #[inline]
    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices
    }

    /// Triangles, each wound anticlockwise seen from outside (normals outwards).
    #[must_use]
    #[inline]
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// The volume the surface encloses, positive.
    #[must_use]
    pub fn volume(&self) -> f64 {
        let (lo, hi) = self.bounds();
        signed_volume_of(&self.vertices, &self.triangles, centre(lo, hi))
    }

    /// The smallest and largest coordinate on each axis over the vertices the triangles use
    /// (unused vertices are not part of the shape).
    #[must_use]
    pub fn bounds(&self) -> (Vec3, Vec3) {
        bounds_of(&self.vertices, &self.triangles)
    }

    /// The mesh with every coordinate multiplied by `factor`, for a change of units (a file in
    /// millimetres read into metres: `0.001`). Orientation and topology are unchanged.
    ///
    /// # Panics
    ///
    /// If `factor` is not finite and positive: zero would flatten the mesh, and a negative factor
    /// would mirror it and turn its normals inwards.
    #[must_use]
    pub fn scaled(&self, factor: f64) -> Self {
        assert!(factor.is_finite() && factor > 0.0, "scale factor {factor} is not positive");
        Self {
            vertices: self.vertices.iter().map(|p| p.map(|c| c * factor)).collect(),
            triangles: self.triangles.clone(),
        }
    }
}

/// Whether the triangle `p` has no area, relative to its size.
fn is_degenerate(p: &[Vec3; 3]) -> bool {
    let e = |i: usize, j: usize| -> Vec3 { std::array::from_fn(|a| p[j][a] - p[i][a]) };
    let n = cross(&e(0, 1), &e(0, 2));
    let twice_area = dot(&n, &n).sqrt();
    let longest = [e(0, 1), e(1, 2), e(2, 0)].iter().map(|d| dot(d, d)).fold(0.0f64, f64::max);
    twice_area <= DEGENERATE_RATIO * longest
}

/// Checks that every edge is in exactly two triangles that use it in opposite directions; the
/// error is about the first triangle (in order) with a bad edge.
fn check_edges(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Result<(), TriMeshError> {
    let edges_of = |t: &[u32; 3]| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]];
    let mut uses: HashMap<[u32; 2], EdgeUse> = HashMap::with_capacity(3 * triangles.len() / 2);
    for (t, nodes) in triangles.iter().enumerate() {
        for [a, b] in edges_of(nodes) {
            let forward = a < b;
            match uses.entry([a.min(b), a.max(b)]) {
                Entry::Vacant(slot) => {
                    slot.insert(EdgeUse { count: 1, triangles: [t; 3], forward: [forward; 2] });
                }
                Entry::Occupied(mut slot) => {
                    let used = slot.get_mut();
                    if used.count < 3 {
                        used.triangles[used.count] = t;
                    }
                    if used.count == 1 {
                        used.forward[1] = forward;
                    }
                    used.count += 1;
                }
            }
        }
    }
    let position = |i: u32| vertices[i as usize];
    for (t, nodes) in triangles.iter().enumerate() {
        for [a, b] in edges_of(nodes) {
            let key = [a.min(b), a.max(b)];
            let Some(used) = uses.get(&key) else { continue };
            match used.count {
                1 => {
                    return Err(TriMeshError::OpenEdge {
                        triangle: t,
                        edge: [a, b],
                        from: position(a),
                        to: position(b),
                    });
                }
                2 if used.forward[0] == used.forward[1] => {
                    return Err(TriMeshError::InconsistentWinding {
                        edge: [a, b],
                        from: position(a),
                        to: position(b),
                        first: used.triangles[0],
                        second: used.triangles[1],
                    });
                }
                2 => {}
                count => {
                    return Err(TriMeshError::NonManifoldEdge {
                        edge: key,
                        from: position(key[0]),
                        to: position(key[1]),
                        count,
                        triangles: used.triangles,
                    });
                }
            }
        }
    }
    Ok(())
}

/// The bounds of the vertices `triangles` use (all indices in range).
fn bounds_of(vertices: &[Vec3], triangles: &[[u32; 3]]) -> (Vec3, Vec3) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in triangles.as_flattened() {
        let p = vertices[i as usize];
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

fn centre(lo: Vec3, hi: Vec3) -> Vec3 {
    std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]))
}

/// The signed volume enclosed by `triangles`: the sum of the tetrahedra each spans with
/// `origin`. Any origin gives the same sum for a closed surface; one inside the bounds keeps the
/// terms small, so a mesh far from the coordinate origin loses no digits to cancellation.
fn signed_volume_of(vertices: &[Vec3], triangles: &[[u32; 3]], origin: Vec3) -> f64 {
    let from_origin = |i: u32| -> Vec3 {
        let p = vertices[i as usize];
        std::array::from_fn(|a| p[a] - origin[a])
    };
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(from_origin);
            dot(&a, &cross(&b, &c))
        })
        .sum::<f64>()
        / 6.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use incise_math::mat3::{axis_angle, mul_vec};
    use proptest::prelude::*;

    /// The unit cube `[0, 1]³`: 8 corners (corner `c` at `(c & 1, (c >> 1) & 1, c >> 2)`) and
    /// 12 triangles, normals outwards.
    fn cube() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let vertices = (0..8u32)
            .map(|c| [f64::from(c & 1), f64::from((c >> 1) & 1), f64::from(c >> 2)])
            .collect();
        let triangles = vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ];
        (vertices, triangles)
    }

    /// The unit sphere's icosahedron subdivided `levels` times, normals outwards.
    fn icosphere(levels: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let mesh = crate::generate::icosphere([0.0; 3], 1.0, levels);
        (mesh.vertices().to_vec(), mesh.triangles().to_vec())
    }

    fn normalised(p: Vec3) -> Vec3 {
        let n = dot(&p, &p).sqrt();
        p.map(|c| c / n)
    }

    fn flipped(triangles: &[[u32; 3]]) -> Vec<[u32; 3]> {
        triangles.iter().map(|&[a, b, c]| [a, c, b]).collect()
    }

    #[test]
    fn a_cube_is_checked_and_measured() {
        let (v, t) = cube();
        let mesh = TriMesh::new(v.clone(), t.clone()).unwrap();
        assert!((mesh.volume() - 1.0).abs() < 1e-15, "{}", mesh.volume());
        assert_eq!(mesh.bounds(), ([0.0; 3], [1.0; 3]));
        assert_eq!(mesh.triangles(), &t[..]);
        let mm = TriMesh::new(v.iter().map(|p| p.map(|c| c * 20.0)).collect(), t).unwrap();
        let m = mm.scaled(1e-3);
        assert!((m.volume() - 8e-6).abs() < 1e-20, "{}", m.volume());
        assert_eq!(m.bounds(), ([0.0; 3], [0.02; 3]));
    }

    #[test]
    fn an_inside_out_mesh_is_flipped_outwards() {
        let (v, t) = cube();
        let mesh = TriMesh::new(v, flipped(&t)).unwrap();
        assert_eq!(mesh.triangles(), &t[..]);
        assert!((mesh.volume() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn unused_vertices_are_kept_and_left_out_of_the_bounds() {
        let (mut v, t) = cube();
        v.push([9.0, 9.0, 9.0]);
        let mesh = TriMesh::new(v.clone(), t).unwrap();
        assert_eq!(mesh.vertices(), &v[..]);
        assert_eq!(mesh.bounds(), ([0.0; 3], [1.0; 3]));
    }

    #[test]
    fn an_icosphere_encloses_nearly_a_ball() {
        let (v, t) = icosphere(3);
        let mesh = TriMesh::new(v, t).unwrap();
        let ball = 4.0 / 3.0 * std::f64::consts::PI;
        assert!(mesh.volume() < ball && mesh.volume() > 0.97 * ball, "{}", mesh.volume());
    }

    #[test]
    fn bad_triangles_are_named() {
        let (v, t) = cube();
        assert_eq!(TriMesh::new(v.clone(), vec![]), Err(TriMeshError::Empty));
        let mut nan = v.clone();
        nan[7][2] = f64::NAN;
        let e = TriMesh::new(nan, t.clone()).unwrap_err();
        assert!(matches!(e, TriMeshError::NonFiniteVertex { vertex: 7, .. }), "{e}");
        assert!(e.to_string().starts_with("vertex 7 has a non-finite coordinate [1.0, 1.0, NaN]"));
        let mut out = t.clone();
        out[3] = [5, 7, 8];
        let e = TriMesh::new(v.clone(), out).unwrap_err();
        assert_eq!(e, TriMeshError::IndexOutOfRange { triangle: 3, index: 8, vertices: 8 });
        assert_eq!(e.to_string(), "triangle 3 names vertex 8, but the mesh has 8 vertices");
        let mut repeated = t.clone();
        repeated[4] = [0, 1, 0];
        let e = TriMesh::new(v.clone(), repeated).unwrap_err();
        assert_eq!(e.to_string(), "triangle 4 repeats a vertex: [0, 1, 0]");
        let mut twice = t.clone();
        twice[5] = [4, 0, 1];
        let e = TriMesh::new(v.clone(), twice).unwrap_err();
        assert_eq!(e.to_string(), "triangles 4 and 5 both join vertices [4, 0, 1]");
        // A corner moved onto the line through the other two.
        let mut flat = v.clone();
        flat.push([2.0, 0.0, 0.0]);
        let mut sliver = t.clone();
        sliver[0] = [0, 1, 8];
        let e = TriMesh::new(flat, sliver).unwrap_err();
        assert!(matches!(e, TriMeshError::Degenerate { triangle: 0, .. }), "{e}");
        assert!(e.to_string().contains("has no area"), "{e}");
    }

    #[test]
    fn open_non_manifold_and_inconsistent_surfaces_are_refused() {
        let (v, t) = cube();
        // Without triangle 11 (3, 7, 5), the first triangle with one of its edges is 3.
        let e = TriMesh::new(v.clone(), t[..11].to_vec()).unwrap_err();
        assert_eq!(
            e,
            TriMeshError::OpenEdge {
                triangle: 3,
                edge: [5, 7],
                from: [1.0, 0.0, 1.0],
                to: [1.0, 1.0, 1.0]
            }
        );
        assert_eq!(
            e.to_string(),
            "triangle 3's edge [5, 7] (from [1.0, 0.0, 1.0] to [1.0, 1.0, 1.0]) is in no other \
             triangle: the surface is open there"
        );
        let mut wound = t.clone();
        wound[7] = [3, 7, 6];
        let e = TriMesh::new(v.clone(), wound).unwrap_err();
        assert!(matches!(e, TriMeshError::InconsistentWinding { first: 3, second: 7, .. }), "{e}");
        assert!(e.to_string().starts_with("triangles 3 and 7 both run along edge [7, 6]"), "{e}");
        // A closed tetrahedron hung on the bottom edge 0-1: four triangles meet along it.
        let mut fin_v = v;
        fin_v.extend([[0.5, -1.0, -1.0], [0.5, -1.0, 0.5]]);
        let mut fin = t;
        fin.extend([[0, 1, 8], [1, 0, 9], [0, 8, 9], [1, 9, 8]]);
        let e = TriMesh::new(fin_v, fin).unwrap_err();
        assert!(
            matches!(
                e,
                TriMeshError::NonManifoldEdge { edge: [0, 1], count: 4, triangles: [0, 4, 12], .. }
            ),
            "{e}"
        );
    }

    #[test]
    fn a_closed_flat_surface_is_refused() {
        // Both sides of a square, each side split along a different diagonal.
        let v = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        let t = vec![[0, 1, 2], [0, 2, 3], [1, 0, 3], [1, 3, 2]];
        let e = TriMesh::new(v, t).unwrap_err();
        assert!(matches!(e, TriMeshError::ZeroVolume { .. }), "{e}");
    }

    #[test]
    #[should_panic(expected = "scale factor -1 is not positive")]
    fn mirroring_by_scale_is_refused() {
        let (v, t) = cube();
        let _ = TriMesh::new(v, t).unwrap().scaled(-1.0);
    }

    /// A valid closed mesh: the cube, or an icosphere of 0 to 2 subdivisions.
    fn closed_mesh() -> impl Strategy<Value = (Vec<Vec3>, Vec<[u32; 3]>)> {
        prop_oneof![Just(cube()), (0usize..3).prop_map(icosphere)]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

        #[test]
        fn rigid_motions_keep_a_mesh_valid_and_its_volume(
            (v, t) in closed_mesh(),
            axis in prop::array::uniform3(-1.0f64..1.0),
            angle in -std::f64::consts::PI..std::f64::consts::PI,
            shift in prop::array::uniform3(-100.0f64..100.0),
            inside_out in any::<bool>(),
        ) {
            prop_assume!(dot(&axis, &axis) > 1e-6);
            let before = TriMesh::new(v.clone(), t.clone()).unwrap();
            let r = axis_angle(&normalised(axis), angle);
            let moved: Vec<Vec3> = v
                .iter()
                .map(|p| {
                    let q = mul_vec(&r, p);
                    std::array::from_fn(|a| q[a] + shift[a])
                })
                .collect();
            let given = if inside_out { flipped(&t) } else { t.clone() };
            let after = TriMesh::new(moved, given).unwrap();
            prop_assert_eq!(after.triangles(), &t[..], "oriented outwards again");
            let (a, b) = (before.volume(), after.volume());
            prop_assert!(a > 0.0 && (a - b).abs() <= 1e-9 * a, "{} against {}", a, b);
        }

        #[test]
        fn removing_any_one_triangle_opens_the_mesh(
            (v, t) in closed_mesh(),
            which in any::<prop::sample::Index>(),
        ) {
            let mut open = t.clone();
            let removed = open.remove(which.index(t.len()));
            let e = TriMesh::new(v, open).unwrap_err();
            let TriMeshError::OpenEdge { edge: [a, b], .. } = e.clone() else {
                return Err(TestCaseError::fail(format!("{e}")));
            };
            prop_assert!(removed.contains(&a) && removed.contains(&b), "{}", e);
        }
    }
}
