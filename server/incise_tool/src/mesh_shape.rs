//! A closed triangle mesh as a tool shape: its signed distance by the closest triangle, the sign
//! by angle-weighted pseudonormals (Bærentzen & Aanæs 2005), so it is right at every point,
//! also where the closest point is an edge or a vertex of a non-convex mesh.
//!
//! Tool meshes are small (a grasper's jaws, a retractor: hundreds to a few thousand triangles),
//! and contact asks only about surface points inside the tool's bounding box, so the closest
//! triangle is found by a scan with a bounding-sphere test per triangle.

use crate::geometry::{Feature, closest_on_triangle, norm, sub, unit};
use incise_math::Vec3;
use incise_math::mat3::{cross, dot};
use incise_mesh::TriMesh;
use std::collections::HashMap;

/// A closed triangle mesh with what its signed distance needs.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshShape {
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    /// Unit outward normal of each triangle.
    face_normals: Vec<Vec3>,
    /// Angle-weighted pseudonormal of each vertex.
    vertex_normals: Vec<Vec3>,
    /// Pseudonormal of each triangle's edges (0: v0–v1, 1: v1–v2, 2: v2–v0).
    edge_normals: Vec<[Vec3; 3]>,
    /// Each triangle's circumscribing sphere: centre and radius.
    spheres: Vec<(Vec3, f64)>,
    bounds: (Vec3, Vec3),
}

impl MeshShape {
    /// The vertices (m, the mesh's own frame).
    #[must_use]
    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices
    }

    /// The triangles, outward (counter-clockwise seen from outside).
    #[must_use]
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// The shape of a checked closed mesh (outward oriented, as [`TriMesh::new`] leaves it).
    #[must_use]
    pub fn new(mesh: &TriMesh) -> Self {
        let vertices = mesh.vertices().to_vec();
        let triangles = mesh.triangles().to_vec();
        let corner = |t: &[u32; 3], i: usize| vertices[t[i] as usize];
        let face_normals: Vec<Vec3> = triangles
            .iter()
            .map(|t| {
                unit(cross(&sub(corner(t, 1), corner(t, 0)), &sub(corner(t, 2), corner(t, 0))))
            })
            .collect();
        let mut vertex_normals = vec![[0.0; 3]; vertices.len()];
        let mut edge_sum: HashMap<(u32, u32), Vec3> = HashMap::new();
        for (t, n) in triangles.iter().zip(&face_normals) {
            for i in 0..3 {
                let (a, b, c) = (corner(t, i), corner(t, (i + 1) % 3), corner(t, (i + 2) % 3));
                let angle = dot(&unit(sub(b, a)), &unit(sub(c, a))).clamp(-1.0, 1.0).acos();
                let v = &mut vertex_normals[t[i] as usize];
                for k in 0..3 {
                    v[k] += angle * n[k];
                }
                let key = (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3]));
                let e = edge_sum.entry(key).or_insert([0.0; 3]);
                for k in 0..3 {
                    e[k] += n[k];
                }
            }
        }
        let vertex_normals = vertex_normals.into_iter().map(unit).collect();
        let edge_normals = triangles
            .iter()
            .map(|t| {
                std::array::from_fn(|i| {
                    let key = (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3]));
                    unit(edge_sum[&key])
                })
            })
            .collect();
        let spheres = triangles
            .iter()
            .map(|t| {
                let c: Vec3 =
                    std::array::from_fn(|k| (0..3).map(|i| corner(t, i)[k]).sum::<f64>() / 3.0);
                let r = (0..3).map(|i| norm(sub(corner(t, i), c))).fold(0.0, f64::max);
                (c, r)
            })
            .collect();
        Self {
            vertices,
            triangles,
            face_normals,
            vertex_normals,
            edge_normals,
            spheres,
            bounds: mesh.bounds(),
        }
    }

    /// The signed distance (negative inside) of `p` and the outward unit normal there.
    #[must_use]
    pub fn distance(&self, p: Vec3) -> (f64, Vec3) {
        let mut best = (f64::INFINITY, 0usize, [0.0; 3], Feature::Face);
        for (t, tri) in self.triangles.iter().enumerate() {
            let (c, r) = self.spheres[t];
            let lower = norm(sub(p, c)) - r;
            if lower * lower.abs() >= best.0 {
                continue;
            }
            let v = |i: usize| self.vertices[tri[i] as usize];
            let (q, feature) = closest_on_triangle(p, [v(0), v(1), v(2)]).point_feature();
            let d = sub(p, q);
            let d2 = dot(&d, &d);
            if d2 < best.0 {
                best = (d2, t, q, feature);
            }
        }
        let (d2, t, q, feature) = best;
        let pseudo = match feature {
            Feature::Face => self.face_normals[t],
            Feature::Edge(e) => self.edge_normals[t][e],
            Feature::Vertex(i) => self.vertex_normals[self.triangles[t][i] as usize],
        };
        let d = sub(p, q);
        let inside = dot(&d, &pseudo) < 0.0;
        let dist = d2.sqrt();
        let normal = if dist > 1e-12 * (1.0 + norm(p)) {
            d.map(|c| if inside { -c / dist } else { c / dist })
        } else {
            pseudo
        };
        (if inside { -dist } else { dist }, normal)
    }

    /// The bounding box of its vertices.
    #[must_use]
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube [0, 1]³ as 12 outward triangles.
    fn cube() -> TriMesh {
        let v: Vec<Vec3> = (0..8)
            .map(|i| [f64::from(i & 1), f64::from((i >> 1) & 1), f64::from(i >> 2)])
            .collect();
        let quads =
            [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let t = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        TriMesh::new(v, t).unwrap()
    }

    #[test]
    fn a_mesh_cube_measures_like_the_analytic_box() {
        let mesh = MeshShape::new(&cube());
        let cuboid =
            crate::Shape::new(crate::Primitive::Cuboid { half_extents: [0.5; 3] }, [0.5; 3])
                .unwrap();
        for i in 0..400 {
            let p: Vec3 =
                std::array::from_fn(|k| 0.5 + 1.2 * ((i * 7 + k * 3) as f64 * 0.61).sin());
            let (a, na) = mesh.distance(p);
            let (b, nb) = cuboid.distance(p);
            assert!((a - b).abs() < 1e-12, "{p:?}: mesh {a}, box {b}");
            if b.abs() > 1e-9 {
                let off_medial = (0..3).map(|k| (na[k] - nb[k]).abs()).fold(0.0, f64::max);
                // Inside, at points equidistant from two faces, either face's normal is right.
                assert!(off_medial < 1e-9 || b < 0.0, "{p:?}: {na:?} vs {nb:?}");
            }
        }
    }
}
