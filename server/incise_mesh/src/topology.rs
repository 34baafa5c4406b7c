//! Vertices, edges, triangles and tetrahedra of a mesh with the neighbour relations the
//! tensor-mass storage needs (paper 2 §3.2: "a data structure incorporating the notion of vertices,
//! edges, triangles, and tetrahedra, with all the necessary neighbours"), and the boundary surface,
//! kept current as tetrahedra are removed.

use crate::mesh::TetMesh;
use std::collections::HashMap;

/// The faces of tetrahedron `[v0, v1, v2, v3]`, face `f` opposite vertex `f`, each ordered so that
/// its normal points out of a positively oriented tetrahedron.
pub const FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// The 6 edges of a tetrahedron as pairs of local vertices.
pub const EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

/// Mesh topology with live/removed tetrahedra.
#[derive(Clone, Debug)]
pub struct TetTopology {
    vertex_count: usize,
    tets: Vec<[u32; 4]>,
    alive: Vec<bool>,
    edges: Vec<[u32; 2]>,
    triangles: Vec<[u32; 3]>,
    tet_edges: Vec<[u32; 6]>,
    tet_triangles: Vec<[u32; 4]>,
    /// Live tetrahedra around each vertex, edge and triangle.
    vertex_tets: Vec<u32>,
    edge_tets: Vec<u32>,
    triangle_tets: Vec<u32>,
    /// Tetrahedra of each triangle (`u32::MAX` when fewer than two).
    triangle_owners: Vec<[u32; 2]>,
    /// Tetrahedra (live or not) of each vertex.
    vertex_star: Vec<Vec<u32>>,
    live: usize,
}

fn sorted<const N: usize>(mut a: [u32; N]) -> [u32; N] {
    a.sort_unstable();
    a
}

impl TetTopology {
    /// The topology of every tetrahedron of `mesh` (all live).
    #[must_use]
    pub fn new(mesh: &TetMesh) -> Self {
        let tets = mesh.tets().to_vec();
        let mut edge_id: HashMap<[u32; 2], u32> = HashMap::with_capacity(tets.len() * 2);
        let mut tri_id: HashMap<[u32; 3], u32> = HashMap::with_capacity(tets.len() * 3);
        let mut edges = Vec::new();
        let mut triangles = Vec::new();
        let mut triangle_owners: Vec<[u32; 2]> = Vec::new();
        let mut tet_edges = Vec::with_capacity(tets.len());
        let mut tet_triangles = Vec::with_capacity(tets.len());
        for (t, v) in tets.iter().enumerate() {
            tet_edges.push(EDGES.map(|[a, b]| {
                let key = sorted([v[a], v[b]]);
                *edge_id.entry(key).or_insert_with(|| {
                    edges.push(key);
                    (edges.len() - 1) as u32
                })
            }));
            tet_triangles.push(FACES.map(|f| {
                let key = sorted(f.map(|i| v[i]));
                let id = *tri_id.entry(key).or_insert_with(|| {
                    triangles.push(key);
                    triangle_owners.push([u32::MAX; 2]);
                    (triangles.len() - 1) as u32
                });
                let owners = &mut triangle_owners[id as usize];
                if owners[0] == u32::MAX {
                    owners[0] = t as u32;
                } else {
                    owners[1] = t as u32;
                }
                id
            }));
        }
        let mut vertex_star = vec![Vec::new(); mesh.vertices().len()];
        for (t, v) in tets.iter().enumerate() {
            for &n in v {
                vertex_star[n as usize].push(t as u32);
            }
        }
        let mut topo = Self {
            vertex_star,
            vertex_count: mesh.vertices().len(),
            alive: vec![true; tets.len()],
            vertex_tets: vec![0; mesh.vertices().len()],
            edge_tets: vec![0; edges.len()],
            triangle_tets: vec![0; triangles.len()],
            tets,
            edges,
            triangles,
            tet_edges,
            tet_triangles,
            triangle_owners,
            live: 0,
        };
        for t in 0..topo.tets.len() {
            topo.count(t, 1);
        }
        topo.live = topo.tets.len();
        topo
    }

    fn count(&mut self, t: usize, delta: i64) {
        let apply = |c: &mut u32| *c = (i64::from(*c) + delta) as u32;
        for &v in &self.tets[t] {
            apply(&mut self.vertex_tets[v as usize]);
        }
        for &e in &self.tet_edges[t] {
            apply(&mut self.edge_tets[e as usize]);
        }
        for &f in &self.tet_triangles[t] {
            apply(&mut self.triangle_tets[f as usize]);
        }
    }

    /// Cuts tetrahedron `t` out, and with it any tetrahedra that would otherwise hang on the
    /// rest by an edge or a vertex alone: around every vertex and edge of a removed tetrahedron
    /// the live tetrahedra must stay connected through faces, or the smaller groups go too (the
    /// largest stays; on a tie, the one with the lowest tetrahedron); and where the tetrahedra
    /// around a vertex form a ring around a tunnel through it (the surface would touch itself
    /// there), the ring goes. So a manifold boundary stays a closed manifold surface, and no piece
    /// is held by a hinge a real cut would not leave.
    /// Returns every tetrahedron removed, `t` first (empty when `t` was already removed).
    pub fn cut(&mut self, t: usize) -> Vec<usize> {
        if !self.remove(t) {
            return Vec::new();
        }
        let mut removed = vec![t];
        let mut work: Vec<Vec<u32>> = Vec::new();
        let push_simplices = |t: usize, work: &mut Vec<Vec<u32>>, tets: &[[u32; 4]]| {
            let v = tets[t];
            work.extend(v.iter().map(|&a| vec![a]));
            work.extend(EDGES.iter().map(|&[a, b]| vec![v[a], v[b]]));
        };
        push_simplices(t, &mut work, &self.tets);
        while let Some(simplex) = work.pop() {
            let groups = self.star_groups(&simplex);
            if groups.len() < 2 {
                // One group around a vertex can still be a ring around a tunnel through it, the
                // surface meeting itself there in two sheets: the ring goes.
                if let ([v], [ring]) = (simplex.as_slice(), groups.as_slice())
                    && self.sheets_at(*v, ring) > 1
                {
                    for &u in ring {
                        if self.remove(u as usize) {
                            removed.push(u as usize);
                            push_simplices(u as usize, &mut work, &self.tets);
                        }
                    }
                }
                continue;
            }
            let mut keep = 0;
            for g in 1..groups.len() {
                // The largest; on a tie the one with the lowest tetrahedron (groups come in
                // order of their first member, so the earlier one).
                if groups[g].len() > groups[keep].len() {
                    keep = g;
                }
            }
            for (g, group) in groups.iter().enumerate() {
                if g == keep {
                    continue;
                }
                for &u in group {
                    if self.remove(u as usize) {
                        removed.push(u as usize);
                        push_simplices(u as usize, &mut work, &self.tets);
                    }
                }
            }
        }
        removed
    }

    /// How many separate fans the boundary triangles around vertex `v` form, for the live
    /// tetrahedra `star` around it (1 on a manifold surface, 0 inside).
    fn sheets_at(&self, v: u32, star: &[u32]) -> usize {
        let mut link: Vec<[u32; 2]> = Vec::new();
        for &t in star {
            let tet = self.tets[t as usize];
            for (f, face) in FACES.iter().enumerate() {
                let tri = face.map(|i| tet[i]);
                if tri.contains(&v)
                    && self.triangle_tets[self.tet_triangles[t as usize][f] as usize] == 1
                {
                    let others: Vec<u32> = tri.iter().copied().filter(|&x| x != v).collect();
                    link.push([others[0], others[1]]);
                }
            }
        }
        let mut seen = vec![false; link.len()];
        let mut fans = 0;
        for start in 0..link.len() {
            if seen[start] {
                continue;
            }
            fans += 1;
            seen[start] = true;
            let mut stack = vec![start];
            while let Some(i) = stack.pop() {
                for j in 0..link.len() {
                    if !seen[j] && link[j].iter().any(|x| link[i].contains(x)) {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
        }
        fans
    }

    /// How many groups of live tetrahedra, connected through faces, meet at vertex `v` (more than
    /// one: they are joined by the vertex alone; [`TetTopology::cut`] never leaves that).
    #[must_use]
    pub fn vertex_groups(&self, v: u32) -> usize {
        self.star_groups(&[v]).len()
    }

    /// The live tetrahedra containing every vertex of `simplex`, grouped by connection through
    /// faces that contain the simplex; each group sorted, groups in order of their first member.
    fn star_groups(&self, simplex: &[u32]) -> Vec<Vec<u32>> {
        let star: Vec<u32> = self.vertex_star[simplex[0] as usize]
            .iter()
            .copied()
            .filter(|&u| {
                self.alive[u as usize] && simplex.iter().all(|v| self.tets[u as usize].contains(v))
            })
            .collect();
        let mut group = vec![usize::MAX; star.len()];
        let mut groups = Vec::new();
        for start in 0..star.len() {
            if group[start] != usize::MAX {
                continue;
            }
            let id = groups.len();
            let mut members = vec![star[start]];
            group[start] = id;
            let mut stack = vec![start];
            while let Some(i) = stack.pop() {
                let a = self.tets[star[i] as usize];
                for (j, &other) in star.iter().enumerate() {
                    if group[j] != usize::MAX {
                        continue;
                    }
                    let b = self.tets[other as usize];
                    // Adjacent: they share a triangle (three vertices), which contains the simplex.
                    if a.iter().filter(|v| b.contains(v)).count() == 3 {
                        group[j] = id;
                        members.push(other);
                        stack.push(j);
                    }
                }
            }
            members.sort_unstable();
            groups.push(members);
        }
        groups
    }

    /// Removes tetrahedron `t` alone (no clean-up; see [`TetTopology::cut`]); false when it was
    /// already removed.
    pub fn remove(&mut self, t: usize) -> bool {
        if !self.alive[t] {
            return false;
        }
        self.alive[t] = false;
        self.count(t, -1);
        self.live -= 1;
        true
    }

    /// Vertices (all, including those no live tetrahedron uses any more).
    #[must_use]
    #[inline]
    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    /// All tetrahedra ever in the mesh (live or removed), by index.
    #[must_use]
    #[inline]
    pub fn tets(&self) -> &[[u32; 4]] {
        &self.tets
    }

    /// Whether tetrahedron `t` is live.
    #[must_use]
    #[inline]
    pub fn is_alive(&self, t: usize) -> bool {
        self.alive[t]
    }

    /// Live tetrahedra.
    #[must_use]
    #[inline]
    pub fn live_count(&self) -> usize {
        self.live
    }

    /// Edges as sorted vertex pairs.
    #[must_use]
    #[inline]
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    /// Triangles as sorted vertex triples.
    #[must_use]
    #[inline]
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Edge ids of tetrahedron `t`, in [`EDGES`] order.
    #[must_use]
    #[inline]
    pub fn tet_edges(&self, t: usize) -> &[u32; 6] {
        &self.tet_edges[t]
    }

    /// Triangle ids of tetrahedron `t`, face `f` opposite vertex `f`.
    #[must_use]
    #[inline]
    pub fn tet_triangles(&self, t: usize) -> &[u32; 4] {
        &self.tet_triangles[t]
    }

    /// Live tetrahedra using vertex `v`.
    #[must_use]
    #[inline]
    pub fn vertex_degree(&self, v: usize) -> u32 {
        self.vertex_tets[v]
    }

    /// Live tetrahedra around edge `e`.
    #[must_use]
    #[inline]
    pub fn edge_degree(&self, e: usize) -> u32 {
        self.edge_tets[e]
    }

    /// Live tetrahedra on triangle `f` (0, 1 or 2).
    #[must_use]
    #[inline]
    pub fn triangle_degree(&self, f: usize) -> u32 {
        self.triangle_tets[f]
    }

    /// The live tetrahedron across face `f` of tetrahedron `t`, if any.
    #[must_use]
    #[inline]
    pub fn neighbour(&self, t: usize, f: usize) -> Option<usize> {
        let tri = self.tet_triangles[t][f] as usize;
        self.triangle_owners[tri]
            .iter()
            .map(|&o| o as usize)
            .find(|&o| o != u32::MAX as usize && o != t && self.alive[o])
    }

    /// The boundary surface: every face of a live tetrahedron with no live tetrahedron across it,
    /// oriented outwards, in tetrahedron order.
    #[must_use]
    pub fn boundary(&self) -> Vec<[u32; 3]> {
        let mut out = Vec::new();
        for (t, v) in self.tets.iter().enumerate() {
            if !self.alive[t] {
                continue;
            }
            for (f, face) in FACES.iter().enumerate() {
                if self.triangle_tets[self.tet_triangles[t][f] as usize] == 1 {
                    out.push(face.map(|i| v[i]));
                }
            }
        }
        out
    }
}

/// Checks that `surface` is closed and consistently oriented: every directed edge of a triangle
/// is matched by the same edge in the opposite direction in another triangle. Returns the first
/// unmatched directed edge.
pub fn check_closed(surface: &[[u32; 3]]) -> Result<(), [u32; 2]> {
    let mut balance: HashMap<[u32; 2], i64> = HashMap::new();
    for tri in surface {
        for i in 0..3 {
            let (a, b) = (tri[i], tri[(i + 1) % 3]);
            let (key, d) = if a < b { ([a, b], 1) } else { ([b, a], -1) };
            *balance.entry(key).or_default() += d;
        }
    }
    let mut bad: Vec<_> = balance.into_iter().filter(|(_, d)| *d != 0).map(|(k, _)| k).collect();
    bad.sort_unstable();
    bad.first().map_or(Ok(()), |&e| Err(e))
}

/// Checks that `surface` is a manifold: every edge in exactly two triangles, and around every
/// vertex its triangles form one fan (the link of the vertex is one cycle). Returns what fails.
pub fn check_manifold(surface: &[[u32; 3]]) -> Result<(), String> {
    if let Some(e) = non_manifold_edges(surface).first() {
        return Err(format!("edge {e:?} is in more than two triangles"));
    }
    let mut link: HashMap<u32, Vec<[u32; 2]>> = HashMap::new();
    for tri in surface {
        for i in 0..3 {
            link.entry(tri[i]).or_default().push([tri[(i + 1) % 3], tri[(i + 2) % 3]]);
        }
    }
    let mut vertices: Vec<_> = link.keys().copied().collect();
    vertices.sort_unstable();
    for v in vertices {
        let edges = &link[&v];
        // One cycle: walking from the first edge along shared endpoints visits every edge.
        let mut seen = vec![false; edges.len()];
        let mut stack = vec![0];
        seen[0] = true;
        while let Some(i) = stack.pop() {
            for (j, e) in edges.iter().enumerate() {
                if !seen[j] && e.iter().any(|x| edges[i].contains(x)) {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        if seen.iter().any(|s| !s) {
            return Err(format!("the triangles around vertex {v} form more than one fan"));
        }
    }
    Ok(())
}

/// Edges of `surface` shared by more than two of its triangles: where two parts of the solid touch
/// only along an edge (tetrahedra removed around it on two sides).
#[must_use]
pub fn non_manifold_edges(surface: &[[u32; 3]]) -> Vec<[u32; 2]> {
    let mut count: HashMap<[u32; 2], u32> = HashMap::new();
    for tri in surface {
        for i in 0..3 {
            *count.entry(sorted([tri[i], tri[(i + 1) % 3]])).or_default() += 1;
        }
    }
    let mut out: Vec<_> = count.into_iter().filter(|&(_, c)| c > 2).map(|(e, _)| e).collect();
    out.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::cylinder;

    #[test]
    fn counts_and_boundary_of_a_cylinder() {
        let mesh = cylinder(1.0, 3.0, 4, 3);
        let mut topo = TetTopology::new(&mesh);
        let v = topo.vertex_count() as i64;
        let e = topo.edges().len() as i64;
        let f = topo.triangles().len() as i64;
        let t = topo.tets().len() as i64;
        // Euler characteristic of a ball: V − E + F − T = 1.
        assert_eq!(v - e + f - t, 1);
        let surface = topo.boundary();
        assert!(check_closed(&surface).is_ok());
        // Every boundary triangle faces outwards: its normal points away from the axis or along z.
        let removed = (0..topo.tets().len()).step_by(7).filter(|&t| topo.remove(t)).count();
        assert_eq!(topo.live_count(), topo.tets().len() - removed);
        assert!(check_closed(&topo.boundary()).is_ok());
        assert!(!topo.remove(0));
    }
}
