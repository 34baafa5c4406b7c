//! The surface inside one marching cube, from its 8 corners (inside or not) and the severed state
//! of its 12 edges alone: face contours, the loops they close, and the triangles that fill them.
//!
//! A cube's corners are the centres of 8 voxels, corner `c` at offset `(c & 1, (c >> 1) & 1,
//! c >> 2)`; each cube edge is the face link between two voxels. A surface vertex sits on a cube
//! edge whose link leaves an inside voxel for an outside one, or crosses a severed link (then one
//! vertex per side, both at the edge's midpoint).
//!
//! **Face contours.** On each cube face the contour depends only on that face's 4 corners and 4
//! edges, so the two cubes sharing a face draw the same segments there and the surface has no
//! cracks. Inside corners joined by an intact edge belong together; diagonal corners never do (the
//! inside is 6-connected, like the grid's voxels). Each run of consecutive inside corners in cyclic
//! order, cut at outside corners and severed edges, gives one segment between the vertices where
//! the run ends. A face whose 4 corners are inside with exactly one severed edge is the front of
//! a crack: its run goes all the way round and ends on both sides of the severed edge. Joining
//! those two vertices directly would make the same segment on every such face around the link,
//! and a crack one link wide would then have edges in four triangles; so the segment goes through
//! a *front vertex* of its own, one per face, and every segment lies on exactly one face.
//!
//! **Loops.** Segments are oriented with the face's corners counter-clockwise seen from outside
//! the cube, from the vertex where the run starts to the vertex where it ends. In a cube every
//! vertex then has one segment in and one out (an edge vertex on the two faces through its edge,
//! a front vertex on its face), so the segments form closed directed loops, and triangles that
//! follow a loop face away from the inside corners.
//! The two cubes sharing a face traverse its segments in opposite directions, so the surface is
//! closed and consistently oriented.
//!
//! **Triangles.** A loop is filled with a fan from an apex that shares no cube face with any loop
//! vertex other than its two neighbours. Every fan edge is then inside this cube alone, and every
//! loop edge is a segment shared with exactly the cube across its face: each surface edge is in
//! two triangles. (Fanning from an arbitrary vertex can put a triangle flat on a face with a
//! saddle, where the neighbouring cube puts the same triangle too.) An exhaustive test checks that
//! such an apex exists in every one of the 12,643 configurations a cube can be in.

/// Number of local vertex slots in a cube: 24 edge vertices (`3·corner + axis`: on the edge from
/// `corner` along `axis`, owned by `corner`) and 6 front vertices (`24 + face`).
pub(crate) const LOCAL_VERTICES: usize = 30;

/// First local id of a front vertex.
pub(crate) const FRONT: u8 = 24;

const NONE: u8 = u8::MAX;

/// What the surface in one cube depends on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CubeConfig {
    /// Bit `c`: corner `c` is inside.
    pub inside: u8,
    /// Bit `3·c + a` (for the corner `c` with bit `a` clear): the edge from `c` along axis `a` is
    /// severed. Only read where both ends are inside.
    pub severed: u32,
}

impl CubeConfig {
    fn is_inside(self, c: u8) -> bool {
        self.inside & (1 << c) != 0
    }

    /// True when corners `c` and `d` (one axis apart) are both inside and their link is intact.
    fn joined(self, c: u8, d: u8) -> bool {
        let axis = (c ^ d).trailing_zeros();
        let lo = c.min(d);
        self.is_inside(c)
            && self.is_inside(d)
            && self.severed & (1 << (3 * u32::from(lo) + axis)) == 0
    }
}

/// The corners of cube face `f = 2·axis + side`, counter-clockwise seen from outside the cube.
pub(crate) fn face_corners(f: u8) -> [u8; 4] {
    let axis = f / 2;
    let side = f % 2;
    let (b, g) = ((axis + 1) % 3, (axis + 2) % 3);
    let at = |x: u8, y: u8| (side << axis) | (x << b) | (y << g);
    // (b, g) is right-handed about +axis: counter-clockwise seen from outside on the + side.
    if side == 1 {
        [at(0, 0), at(1, 0), at(1, 1), at(0, 1)]
    } else {
        [at(0, 0), at(0, 1), at(1, 1), at(1, 0)]
    }
}

/// Local id of the edge vertex owned by corner `c` on its edge towards corner `d`.
fn edge_vertex(c: u8, d: u8) -> u8 {
    3 * c + (c ^ d).trailing_zeros() as u8
}

/// The cube faces a local vertex lies on, as a 6-bit mask.
fn face_mask(v: u8) -> u8 {
    if v >= FRONT {
        return 1 << (v - FRONT);
    }
    let (c, axis) = (v / 3, v % 3);
    let mut m = 0;
    for a in 0..3 {
        if a != axis {
            m |= 1 << (2 * a + ((c >> a) & 1));
        }
    }
    m
}

/// The surface of one cube, in local vertex ids.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct CubeMesh {
    /// Triangles, each oriented outwards.
    pub triangles: Vec<[u8; 3]>,
    /// For each face with a front vertex, the severed edge it sits on: (corner with the axis bit
    /// clear, axis).
    pub front_edges: [Option<(u8, u8)>; 6],
}

/// The surface of the cube whose inside corners are the bits of `inside`, no edge severed: what
/// removing voxels makes, looked up instead of traced (tracing the loops was most of a cube's
/// cost in re-meshing a cut).
pub(crate) fn intact_cube(inside: u8) -> &'static CubeMesh {
    static TABLE: std::sync::OnceLock<Vec<CubeMesh>> = std::sync::OnceLock::new();
    &TABLE.get_or_init(|| {
        (0..=u8::MAX)
            .map(|inside| {
                let mut mesh = CubeMesh::default();
                mesh_cube(CubeConfig { inside, severed: 0 }, &mut mesh);
                mesh
            })
            .collect()
    })[usize::from(inside)]
}

/// Builds the loops and triangles of one cube into `out` (cleared first).
pub(crate) fn mesh_cube(config: CubeConfig, out: &mut CubeMesh) {
    out.triangles.clear();
    out.front_edges = [None; 6];
    let mut next = [NONE; LOCAL_VERTICES];
    for f in 0..6u8 {
        face_segments(config, f, &mut next, &mut out.front_edges);
    }
    let mut seen = [false; LOCAL_VERTICES];
    let mut lp: Vec<u8> = Vec::with_capacity(LOCAL_VERTICES);
    for start in 0..LOCAL_VERTICES as u8 {
        if next[start as usize] == NONE || seen[start as usize] {
            continue;
        }
        lp.clear();
        let mut v = start;
        while !seen[v as usize] {
            seen[v as usize] = true;
            lp.push(v);
            v = next[v as usize];
            debug_assert!(v != NONE, "every vertex in a cube has a segment out");
        }
        debug_assert_eq!(v, start, "segments in a cube close into loops");
        fill_loop(&lp, &mut out.triangles);
    }
}

/// Adds the segments of face `f` to `next` (segment `u → w` sets `next[u] = w`).
fn face_segments(
    config: CubeConfig,
    f: u8,
    next: &mut [u8; LOCAL_VERTICES],
    front_edges: &mut [Option<(u8, u8)>; 6],
) {
    let k = face_corners(f);
    let inside: [bool; 4] = std::array::from_fn(|i| config.is_inside(k[i]));
    // Edge i joins k[i] and k[i + 1].
    let joined: [bool; 4] = std::array::from_fn(|i| config.joined(k[i], k[(i + 1) % 4]));
    let mut link = |u: u8, w: u8| {
        debug_assert_eq!(next[u as usize], NONE, "one segment out of each vertex per cube");
        next[u as usize] = w;
    };
    if inside.iter().all(|&x| x) {
        let open: Vec<usize> = (0..4).filter(|&i| !joined[i]).collect();
        match open.as_slice() {
            [] => return,
            &[j] => {
                // A crack front: the run wraps round from k[j + 1] to k[j].
                let (a, b) = (k[j], k[(j + 1) % 4]);
                let front = FRONT + f;
                link(edge_vertex(b, a), front);
                link(front, edge_vertex(a, b));
                let lo = a.min(b);
                front_edges[f as usize] = Some((lo, (a ^ b).trailing_zeros() as u8));
                return;
            }
            _ => {}
        }
    }
    for i in 0..4 {
        let before = (i + 3) % 4;
        if !inside[i] || joined[before] {
            continue;
        }
        let mut e = i;
        while joined[e] {
            e = (e + 1) % 4;
        }
        link(edge_vertex(k[i], k[before]), edge_vertex(k[e], k[(e + 1) % 4]));
    }
}

/// Triangles filling the directed loop `lp` (no triangle for fewer than 3 vertices): a fan from
/// the apex with the smallest local id whose diagonals all stay off the cube's faces.
///
/// # Panics
/// If a loop had no such apex; the exhaustive test over every cube configuration rules it out.
fn fill_loop(lp: &[u8], out: &mut Vec<[u8; 3]>) {
    let n = lp.len();
    if n < 3 {
        return;
    }
    let p = apex(lp).expect("every loop of every cube configuration has an apex");
    for t in 1..n - 1 {
        out.push([lp[p], lp[(p + t) % n], lp[(p + t + 1) % n]]);
    }
}

/// Position in `lp` of the vertex with the smallest local id that shares no cube face with any
/// loop vertex but its two neighbours.
fn apex(lp: &[u8]) -> Option<usize> {
    let n = lp.len();
    let masks: Vec<u8> = lp.iter().map(|&v| face_mask(v)).collect();
    (0..n)
        .filter(|&i| {
            (0..n).all(|j| {
                let d = (i + n - j) % n;
                d == 0 || d == 1 || d == n - 1 || masks[i] & masks[j] == 0
            })
        })
        .min_by_key(|&i| lp[i])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every cube edge as (corner with the axis bit clear, axis).
    fn edges() -> Vec<(u8, u8)> {
        let mut e = Vec::new();
        for c in 0..8u8 {
            for a in 0..3u8 {
                if c & (1 << a) == 0 {
                    e.push((c, a));
                }
            }
        }
        e
    }

    /// Every configuration that can occur: each inside mask with every subset of its
    /// inside–inside edges severed.
    fn all_configs() -> Vec<CubeConfig> {
        let mut out = Vec::new();
        for inside in 0..=255u8 {
            let cut: Vec<u32> = edges()
                .into_iter()
                .filter(|&(c, a)| inside & (1 << c) != 0 && inside & (1 << (c | (1 << a))) != 0)
                .map(|(c, a)| 3 * u32::from(c) + u32::from(a))
                .collect();
            for subset in 0..1u32 << cut.len() {
                let severed = cut
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| subset & (1 << i) != 0)
                    .map(|(_, b)| 1 << b)
                    .sum();
                out.push(CubeConfig { inside, severed });
            }
        }
        out
    }

    #[test]
    fn faces_are_counter_clockwise_from_outside() {
        for f in 0..6u8 {
            let k = face_corners(f);
            let p = |c: u8| [f64::from(c & 1), f64::from((c >> 1) & 1), f64::from(c >> 2)];
            let d1: [f64; 3] = std::array::from_fn(|a| p(k[1])[a] - p(k[0])[a]);
            let d2: [f64; 3] = std::array::from_fn(|a| p(k[2])[a] - p(k[1])[a]);
            let n = [
                d1[1] * d2[2] - d1[2] * d2[1],
                d1[2] * d2[0] - d1[0] * d2[2],
                d1[0] * d2[1] - d1[1] * d2[0],
            ];
            let axis = usize::from(f / 2);
            let outward = if f % 2 == 1 { 1.0 } else { -1.0 };
            assert!((n[axis] - outward).abs() < 1e-15, "face {f}: {n:?}");
            for c in k {
                assert_eq!((c >> (f / 2)) & 1, f % 2);
            }
        }
    }

    #[test]
    fn every_configuration_closes_its_loops_with_fans_off_the_faces() {
        // `mesh_cube` asserts (in debug builds) one segment in and out of every vertex and panics
        // on a loop without an apex; here every configuration runs through it.
        let configs = all_configs();
        assert_eq!(configs.len(), 12_643, "configurations counted once");
        let mut mesh = CubeMesh::default();
        for cfg in configs {
            mesh_cube(cfg, &mut mesh);
            // Inside a cube, every surface edge is either a fan edge (used twice, opposite ways)
            // or a loop edge (used once; the neighbouring cube uses it the other way).
            let mut directed = std::collections::BTreeMap::new();
            for t in &mesh.triangles {
                for i in 0..3 {
                    *directed.entry((t[i], t[(i + 1) % 3])).or_insert(0) += 1;
                }
            }
            for (&(a, b), &n) in &directed {
                assert_eq!(n, 1, "{cfg:?}: edge {a}->{b} used {n} times");
                if directed.contains_key(&(b, a)) {
                    assert_eq!(face_mask(a) & face_mask(b), 0, "{cfg:?}: a fan edge on a face");
                }
            }
        }
    }
}
