//! The surface as slot vectors of vertices and triangles, and its extraction from a fine level.
//!
//! **Cubes.** The marching-cubes grid has a corner at every voxel centre (paper 1, Fig. 8): cube
//! `(i, j, k)` has voxels `(i..=i+1, j..=j+1, k..=k+1)` as corners, for `i` in `-1..dims[0]` (and
//! so on), so that cubes reaching past the volume close the surface at its border. Cube `(i, j, k)`
//! is stored as the linear index `(i + 1) + p₀·((j + 1) + p₁·(k + 1))` over the padded grid of
//! `p = dims + 1` cubes per axis: shifted by one, the cube whose lowest corner is voxel `v` has
//! `v`'s coordinates, which is the paper's "same indices for the voxels and the cubes". Voxel `v`
//! is a corner of the 8 cubes `v − {0, 1}³`, so removed voxels name exactly the cubes to re-mesh.
//!
//! **Vertices** are named by a [`VertexKey`]: label group, owner voxel (always inside) and face
//! code. Codes `0..6` are the owner's exposed faces `+x, −x, +y, −y, +z, −z` (`2·axis + [negative]`),
//! at the face's centre: the midpoint of the cube edge that crosses it, no interpolation. Codes
//! `6..18` are crack-front vertices (see the `contour` module): `6 + 4·axis + 2·j + [negative]` sits
//! on the severed link from the owner to its `+axis` neighbour, on the cube face that extends from
//! that link along `±` axis `(axis + 1 + j) mod 3`; at rest it is at the link's midpoint too.
//!
//! **Groups.** A corner is inside for group `g` when its voxel's material is one of the group's.
//! Each group gets its own closed surface and its own vertices; two groups touching give two
//! coincident surfaces at their interface, one per side.

use crate::contour::{CubeConfig, CubeMesh, FRONT, intact_cube, mesh_cube};
use incise_grid::topology::FineLevel;
use incise_math::Vec3;
use std::cmp::Reverse;
use std::collections::{BTreeSet, BinaryHeap};

/// Which materials form one closed surface.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SurfaceOptions {
    /// Material indices (as [`FineLevel::material`] gives them) of each label group. Empty, the
    /// default, means one group holding every material: one closed surface of the whole organ.
    pub groups: Vec<Vec<u16>>,
}

impl SurfaceOptions {
    /// One group per material `0..count`: a closed surface per tissue, coincident where tissues
    /// touch (for a scene that renders label interfaces).
    #[must_use]
    pub fn per_material(count: u16) -> Self {
        Self { groups: (0..count).map(|m| vec![m]).collect() }
    }
}

/// The name of a vertex, stable across re-meshing: group, owner voxel, face code (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct VertexKey {
    /// Label group.
    pub group: u16,
    /// The inside voxel the vertex belongs to.
    pub voxel: u32,
    /// Face code: `0..6` an exposed voxel face, `6..18` a crack-front vertex.
    pub face: u8,
}

/// One vertex slot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceVertex {
    /// Owner voxel (inside; the vertex is embedded in the element that owns it).
    pub voxel: u32,
    /// Face code (see [`VertexKey::face`]).
    pub face: u8,
    /// Label group.
    pub group: u16,
    /// Rest position in the grid frame (m; voxel `(0, 0, 0)` spans `[0, spacing]`).
    pub rest: Vec3,
    /// False for a free slot.
    pub alive: bool,
}

impl SurfaceVertex {
    /// Its key.
    #[must_use]
    pub fn key(&self) -> VertexKey {
        VertexKey { group: self.group, voxel: self.voxel, face: self.face }
    }
}

/// One triangle slot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Triangle {
    /// Vertex ids, counter-clockwise seen from outside.
    pub v: [u32; 3],
    /// The marching cube it lies in (padded linear index, module doc); for a [`crate::TetSurface`]
    /// the topology's triangle id.
    pub cube: u32,
    /// Label group.
    pub group: u16,
    /// False for a free slot.
    pub alive: bool,
}

/// A triangle named by what does not depend on ids: group, cube, and vertex keys rotated so the
/// smallest comes first (orientation kept).
pub type CanonicalTriangle = (u16, u32, [VertexKey; 3]);

/// The embedded surface of an organ: marching cubes on the fine labels (paper 1, §3).
#[derive(Clone, Debug)]
pub struct Surface {
    dims: [u32; 3],
    spacing: Vec3,
    /// `inside[g][m]`: material `m` belongs to group `g`.
    inside: Vec<Vec<bool>>,
    pub(crate) vertices: Vec<SurfaceVertex>,
    /// Live triangles using each vertex slot.
    pub(crate) uses: Vec<u32>,
    /// Freed vertex slots, smallest first (a heap: a cut frees and takes a few dozen at a
    /// time, and a tree's node allocations cost more than that).
    pub(crate) free_vertices: BinaryHeap<Reverse<u32>>,
    pub(crate) live_vertices: usize,
    pub(crate) triangles: Vec<Triangle>,
    /// Freed triangle slots, smallest first (as `free_vertices`).
    pub(crate) free_triangles: BinaryHeap<Reverse<u32>>,
    pub(crate) live_triangles: usize,
    /// The last vertex made of each voxel (its owner), [`NO_VERTEX`] for none; the others
    /// follow through [`VertexLink::next`]. Re-meshing looks up three keys per triangle: a tree of
    /// the liver's 50,000 vertices made that most of a cut's re-meshing, and a hash table cost
    /// two cache misses a look-up once a frame's mechanics had run. A voxel owns a handful of
    /// vertices, mostly made together, so their links share a cache line.
    pub(crate) voxel_first: Vec<u32>,
    /// Each vertex slot's key and the next vertex of its voxel.
    pub(crate) vertex_links: Vec<VertexLink>,
    /// The first triangle of each cube (padded linear index), [`NO_TRIANGLE`] for none: a dense
    /// table, not a map, since re-meshing looks up every cube around a cut and a hashed look-up
    /// of a table that a frame's mechanics has pushed out of cache costs two misses, not one.
    pub(crate) cube_first: Vec<u32>,
    /// The next triangle of the same cube after each triangle slot, in the order the cube made
    /// them ([`NO_TRIANGLE`] after the last).
    pub(crate) cube_next: Vec<u32>,
}

/// The end of a voxel's vertex list.
pub(crate) const NO_VERTEX: u32 = u32::MAX;

/// A vertex's place in its voxel's list: what tells it from the voxel's other vertices, and the
/// next one.
#[derive(Clone, Copy, Debug)]
pub(crate) struct VertexLink {
    pub(crate) next: u32,
    pub(crate) group: u16,
    pub(crate) face: u8,
}

/// The end of a cube's triangle list.
pub(crate) const NO_TRIANGLE: u32 = u32::MAX;

/// The triangle ids of one cube, in the order it made them ([`Surface::cube_triangles`]).
#[derive(Clone, Debug)]
pub struct CubeTriangles<'a> {
    next: u32,
    links: &'a [u32],
}

impl Iterator for CubeTriangles<'_> {
    type Item = u32;

    fn next(&mut self) -> Option<u32> {
        let t = self.next;
        (t != NO_TRIANGLE).then(|| {
            self.next = self.links[t as usize];
            t
        })
    }
}

/// Reusable buffers for meshing cubes.
#[derive(Default)]
pub(crate) struct CubeScratch {
    mesh: CubeMesh,
    pub(crate) out: Vec<(u16, [VertexKey; 3])>,
}

impl Surface {
    /// The surface of every group over `fine`, whose voxels have edge lengths `spacing` (m).
    ///
    /// # Panics
    /// If the padded cube grid has more than `u32::MAX` cubes.
    #[must_use]
    pub fn extract(fine: &FineLevel, spacing: Vec3, options: &SurfaceOptions) -> Self {
        let dims = fine.dims();
        let cubes: u64 = dims.iter().map(|&d| u64::from(d) + 1).product();
        assert!(u32::try_from(cubes).is_ok(), "{cubes} marching cubes do not fit u32 indices");
        let count = dims.iter().map(|&d| d as usize).product::<usize>();
        let materials =
            (0..count as u32).filter_map(|v| fine.material(v)).max().map_or(0, |m| m as usize + 1);
        let inside: Vec<Vec<bool>> = if options.groups.is_empty() {
            vec![vec![true; materials]]
        } else {
            options
                .groups
                .iter()
                .map(|g| (0..materials).map(|m| g.contains(&(m as u16))).collect())
                .collect()
        };
        let mut s = Self {
            dims,
            spacing,
            inside,
            vertices: Vec::new(),
            uses: Vec::new(),
            free_vertices: BinaryHeap::new(),
            live_vertices: 0,
            triangles: Vec::new(),
            free_triangles: BinaryHeap::new(),
            live_triangles: 0,
            voxel_first: vec![NO_VERTEX; count],
            vertex_links: Vec::new(),
            cube_first: vec![NO_TRIANGLE; cubes as usize],
            cube_next: Vec::new(),
        };
        let mut scratch = CubeScratch::default();
        let mut added = Vec::new();
        for cube in 0..cubes as u32 {
            s.cube_keys(fine, cube, &mut scratch);
            let out = std::mem::take(&mut scratch.out);
            for &(group, keys) in &out {
                s.add_triangle(cube, group, keys, &mut added);
            }
            scratch.out = out;
        }
        // Room for the vertices and triangles of a few cuts: growing a full vector or map moves
        // every entry, and that would fall on one cut's re-meshing.
        let room = |n: usize| n / 8 + 64;
        s.vertices.reserve(room(s.vertices.len()));
        s.uses.reserve(room(s.uses.len()));
        s.triangles.reserve(room(s.triangles.len()));
        s.cube_next.reserve(room(s.cube_next.len()));
        s.vertex_links.reserve(room(s.vertex_links.len()));
        s
    }

    /// Voxels per axis of the volume it was extracted from.
    #[must_use]
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Voxel edge lengths (m).
    #[must_use]
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// Number of label groups.
    #[must_use]
    pub fn group_count(&self) -> usize {
        self.inside.len()
    }

    /// Live vertices.
    #[must_use]
    pub fn vertex_count(&self) -> usize {
        self.live_vertices
    }

    /// Live triangles.
    #[must_use]
    pub fn triangle_count(&self) -> usize {
        self.live_triangles
    }

    /// Vertex slots (free ones have `alive == false`).
    #[must_use]
    pub fn vertices(&self) -> &[SurfaceVertex] {
        &self.vertices
    }

    /// Triangle slots (free ones have `alive == false`).
    #[must_use]
    pub fn triangles(&self) -> &[Triangle] {
        &self.triangles
    }

    /// Live triangles with their ids, in id order.
    pub fn live_triangles(&self) -> impl Iterator<Item = (u32, &Triangle)> {
        self.triangles.iter().enumerate().filter(|(_, t)| t.alive).map(|(i, t)| (i as u32, t))
    }

    /// The vertex ids of the live triangles, in id order (for closedness checks and rendering).
    #[must_use]
    pub fn triangle_list(&self) -> Vec<[u32; 3]> {
        self.live_triangles().map(|(_, t)| t.v).collect()
    }

    /// The id of the live vertex named `key`.
    #[must_use]
    pub fn vertex_id(&self, key: VertexKey) -> Option<u32> {
        self.voxel_vertices(key.voxel).find(|&v| {
            let link = self.vertex_links[v as usize];
            link.group == key.group && link.face == key.face
        })
    }

    /// The live vertices owned by `voxel`, in key order.
    pub fn vertices_of_voxel(&self, voxel: u32) -> impl Iterator<Item = u32> + '_ {
        let mut owned: Vec<u32> = self.voxel_vertices(voxel).collect();
        owned.sort_unstable_by_key(|&v| {
            let link = self.vertex_links[v as usize];
            (link.group, link.face)
        });
        owned.into_iter()
    }

    /// The live vertices owned by `voxel`, newest first (none for a voxel out of range).
    fn voxel_vertices(&self, voxel: u32) -> impl Iterator<Item = u32> + '_ {
        let first = self.voxel_first.get(voxel as usize).copied().unwrap_or(NO_VERTEX);
        let some = |v: u32| (v != NO_VERTEX).then_some(v);
        std::iter::successors(some(first), move |&v| some(self.vertex_links[v as usize].next))
    }

    /// Takes vertex `v` out of its voxel's list.
    pub(crate) fn unlink_vertex(&mut self, v: u32) {
        let voxel = self.vertices[v as usize].voxel as usize;
        let next = self.vertex_links[v as usize].next;
        let mut at = self.voxel_first[voxel];
        if at == v {
            self.voxel_first[voxel] = next;
            return;
        }
        while self.vertex_links[at as usize].next != v {
            at = self.vertex_links[at as usize].next;
        }
        self.vertex_links[at as usize].next = next;
    }

    /// The triangle ids of cube `cube` (padded linear index, module doc), in the order it made
    /// them.
    ///
    /// # Panics
    /// If `cube` is beyond the padded cube grid.
    #[must_use]
    pub fn cube_triangles(&self, cube: u32) -> CubeTriangles<'_> {
        CubeTriangles { next: self.cube_first[cube as usize], links: &self.cube_next }
    }

    /// Padded linear index of cube `(i, j, k)`, `i` in `-1..dims[0]` (module doc).
    #[must_use]
    pub fn cube_index(&self, c: [i64; 3]) -> u32 {
        let p = self.dims.map(|d| i64::from(d) + 1);
        ((c[0] + 1) + p[0] * ((c[1] + 1) + p[1] * (c[2] + 1))) as u32
    }

    /// Coordinates `(i, j, k)` of cube `cube`; its corners are voxels `(i..=i+1, …)`.
    #[must_use]
    pub fn cube_coords(&self, cube: u32) -> [i64; 3] {
        let p = self.dims.map(|d| i64::from(d) + 1);
        let c = i64::from(cube);
        [c % p[0] - 1, (c / p[0]) % p[1] - 1, c / (p[0] * p[1]) - 1]
    }

    /// The 8 cubes having voxel `v` as a corner.
    #[must_use]
    pub fn cubes_of_voxel(&self, v: u32) -> [u32; 8] {
        Self::cubes_around(self.voxel_coords(v)).map(|c| self.cube_index(c))
    }

    /// Coordinates of the 8 cubes having the voxel at coordinates `x` as a corner: `x − o` for
    /// each corner offset `o` of a cube, so all lie in `x − 1 ..= x`.
    #[must_use]
    pub fn cubes_around(x: [i64; 3]) -> [[i64; 3]; 8] {
        std::array::from_fn(|c| {
            let o = incise_grid::hex8::corner(c);
            std::array::from_fn(|a| x[a] - o[a] as i64)
        })
    }

    /// Coordinates `(i, j, k)` of voxel `v` (its linear index in the fine grid).
    #[must_use]
    pub fn voxel_coords(&self, v: u32) -> [i64; 3] {
        let d = self.dims;
        [i64::from(v % d[0]), i64::from((v / d[0]) % d[1]), i64::from(v / (d[0] * d[1]))]
    }

    /// Rest position of the vertex named `key` (grid frame, m).
    #[must_use]
    pub fn rest_position(&self, key: VertexKey) -> Vec3 {
        let x = self.voxel_coords(key.voxel);
        let mut p: Vec3 = std::array::from_fn(|a| (x[a] as f64 + 0.5) * self.spacing[a]);
        if key.face < 6 {
            let axis = usize::from(key.face / 2);
            let sign = if key.face.is_multiple_of(2) { 0.5 } else { -0.5 };
            p[axis] += sign * self.spacing[axis];
        } else {
            let axis = usize::from((key.face - 6) / 4);
            p[axis] += 0.5 * self.spacing[axis];
        }
        p
    }

    /// Every live triangle as a [`CanonicalTriangle`], sorted: equal for two surfaces of the same
    /// volume whatever the ids (a re-meshed surface against a fresh extraction).
    #[must_use]
    pub fn canonical_triangles(&self) -> Vec<CanonicalTriangle> {
        let mut out: Vec<CanonicalTriangle> = self
            .live_triangles()
            .map(|(_, t)| {
                let k = t.v.map(|v| self.vertices[v as usize].key());
                let first = usize::from(k[1] < k[0] && k[1] < k[2])
                    + 2 * usize::from(k[2] < k[0] && k[2] < k[1]);
                (t.group, t.cube, std::array::from_fn(|i| k[(first + i) % 3]))
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// The volume enclosed by the live triangles at `positions` (indexed by vertex slot), by the
    /// divergence theorem: positive for a closed outward-oriented surface.
    #[must_use]
    pub fn enclosed_volume(&self, positions: &[Vec3]) -> f64 {
        self.live_triangles()
            .map(|(_, t)| {
                let [a, b, c] = t.v.map(|v| positions[v as usize]);
                let cross = [
                    b[1] * c[2] - b[2] * c[1],
                    b[2] * c[0] - b[0] * c[2],
                    b[0] * c[1] - b[1] * c[0],
                ];
                (a[0] * cross[0] + a[1] * cross[1] + a[2] * cross[2]) / 6.0
            })
            .sum()
    }

    /// Rest positions of every vertex slot (free slots keep their last position).
    #[must_use]
    pub fn rest_positions(&self) -> Vec<Vec3> {
        self.vertices.iter().map(|v| v.rest).collect()
    }

    /// Number of pieces: classes of live triangles connected through shared vertices.
    #[must_use]
    pub fn components(&self) -> usize {
        let mut parent: Vec<u32> = (0..self.vertices.len() as u32).collect();
        for (_, t) in self.live_triangles() {
            for k in 1..3 {
                let (a, b) = (find(&mut parent, t.v[0]), find(&mut parent, t.v[k]));
                parent[a.max(b) as usize] = a.min(b);
            }
        }
        let mut roots = BTreeSet::new();
        for (_, t) in self.live_triangles() {
            roots.insert(find(&mut parent, t.v[0]));
        }
        roots.len()
    }
}

/// Root of `i` in the union-find forest `p`, halving paths on the way.
fn find(p: &mut [u32], mut i: u32) -> u32 {
    while p[i as usize] != i {
        p[i as usize] = p[p[i as usize] as usize];
        i = p[i as usize];
    }
    i
}

impl Surface {
    /// The triangles of cube `cube` for every group, as keys, into `scratch.out` (cleared first).
    pub(crate) fn cube_keys(&self, fine: &FineLevel, cube: u32, scratch: &mut CubeScratch) {
        scratch.out.clear();
        let base = self.cube_coords(cube);
        let d = self.dims;
        let voxel: [Option<u32>; 8] = std::array::from_fn(|c| {
            let o = incise_grid::hex8::corner(c);
            let x: [i64; 3] = std::array::from_fn(|a| base[a] + o[a] as i64);
            let inside = (0..3).all(|a| x[a] >= 0 && x[a] < i64::from(d[a]));
            inside.then(|| (x[0] + i64::from(d[0]) * (x[1] + i64::from(d[1]) * x[2])) as u32)
        });
        let material: [Option<u16>; 8] =
            std::array::from_fn(|c| voxel[c].and_then(|v| fine.material(v)));
        if material.iter().all(Option::is_none) {
            return;
        }
        for (g, member) in self.inside.iter().enumerate() {
            let mut inside = 0u8;
            for c in 0..8 {
                if material[c].is_some_and(|m| member.get(usize::from(m)).copied().unwrap_or(false))
                {
                    inside |= 1 << c;
                }
            }
            if inside == 0 {
                continue;
            }
            let mut severed = 0u32;
            for c in 0..8u8 {
                for a in 0..3u8 {
                    let n = c | (1 << a);
                    if n != c && inside & (1 << c) != 0 && inside & (1 << n) != 0 {
                        // Corner `n` is corner `c`'s `+a` neighbour.
                        let (p, q) = (voxel[c as usize], voxel[n as usize]);
                        if let (Some(p), Some(_)) = (p, q)
                            && fine.is_severed_along(p, usize::from(a))
                        {
                            severed |= 1 << (3 * u32::from(c) + u32::from(a));
                        }
                    }
                }
            }
            if inside == u8::MAX && severed == 0 {
                continue;
            }
            let mesh = if severed == 0 {
                intact_cube(inside)
            } else {
                mesh_cube(CubeConfig { inside, severed }, &mut scratch.mesh);
                &scratch.mesh
            };
            let group = g as u16;
            let key = |local: u8| -> VertexKey {
                if local < FRONT {
                    let (c, a) = (local / 3, local % 3);
                    let negative = (c >> a) & 1;
                    let owner = voxel[c as usize].expect("an inside corner is a voxel");
                    VertexKey { group, voxel: owner, face: 2 * a + negative }
                } else {
                    let f = local - FRONT;
                    let (lo, a) = mesh.front_edges[f as usize].expect("front edge recorded");
                    let normal = f / 2;
                    let across = 3 - a - normal;
                    let negative = (lo >> across) & 1;
                    let j = u8::from(across == (a + 2) % 3);
                    let owner = voxel[lo as usize].expect("an inside corner is a voxel");
                    VertexKey { group, voxel: owner, face: 6 + 4 * a + 2 * j + negative }
                }
            };
            for t in &mesh.triangles {
                scratch.out.push((group, t.map(key)));
            }
        }
    }

    /// Adds one triangle of `cube`, reusing the vertices of keys that exist; new vertex ids go to
    /// `added`. Returns the triangle's id.
    pub(crate) fn add_triangle(
        &mut self,
        cube: u32,
        group: u16,
        keys: [VertexKey; 3],
        added: &mut Vec<u32>,
    ) -> u32 {
        let v = keys.map(|k| self.vertex_for(k, added));
        for &x in &v {
            self.uses[x as usize] += 1;
        }
        let tri = Triangle { v, cube, group, alive: true };
        let id = if let Some(Reverse(id)) = self.free_triangles.pop() {
            self.triangles[id as usize] = tri;
            self.cube_next[id as usize] = NO_TRIANGLE;
            id
        } else {
            self.triangles.push(tri);
            self.cube_next.push(NO_TRIANGLE);
            (self.triangles.len() - 1) as u32
        };
        self.live_triangles += 1;
        // Appended after the cube's last: a cube holds a handful, all just written.
        let mut last = self.cube_first[cube as usize];
        if last == NO_TRIANGLE {
            self.cube_first[cube as usize] = id;
        } else {
            while self.cube_next[last as usize] != NO_TRIANGLE {
                last = self.cube_next[last as usize];
            }
            self.cube_next[last as usize] = id;
        }
        id
    }

    fn vertex_for(&mut self, key: VertexKey, added: &mut Vec<u32>) -> u32 {
        if let Some(id) = self.vertex_id(key) {
            return id;
        }
        let vertex = SurfaceVertex {
            voxel: key.voxel,
            face: key.face,
            group: key.group,
            rest: self.rest_position(key),
            alive: true,
        };
        let link = VertexLink {
            next: self.voxel_first[key.voxel as usize],
            group: key.group,
            face: key.face,
        };
        let id = if let Some(Reverse(id)) = self.free_vertices.pop() {
            self.vertices[id as usize] = vertex;
            self.uses[id as usize] = 0;
            self.vertex_links[id as usize] = link;
            id
        } else {
            self.vertices.push(vertex);
            self.uses.push(0);
            self.vertex_links.push(link);
            (self.vertices.len() - 1) as u32
        };
        self.voxel_first[key.voxel as usize] = id;
        self.live_vertices += 1;
        added.push(id);
        id
    }
}
