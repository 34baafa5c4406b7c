//! What a recording draws beside the frame records: the organ's surface at a frame, and how
//! each tool looks. Both are plain data the physics thread builds; the MCAP file, the `.rrd`
//! file and the live viewer render them in their own schemas.

use incise_protocol::v1;
use std::collections::BTreeMap;

/// The organ's surface at one frame: whole, or what changed since the last surface frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfaceFrame {
    /// The frame (from 1) and its simulated time (s).
    pub frame: u64,
    /// See `frame`.
    pub sim_time_s: f64,
    /// Every live vertex and triangle follows, and a reader drops what it had (the first
    /// frame, and a keyframe once a second).
    pub whole: bool,
    /// Vertices whose positions follow (ascending): every live one on a frame taken at the
    /// geometry rate, only the new ones on a frame taken for a topology change alone.
    pub vertex_ids: Vec<u32>,
    /// Their deformed positions (m, grid frame), in `vertex_ids`' order.
    pub positions: Vec<[f32; 3]>,
    /// New triangles (every live one when `whole`): id, corners (vertex ids, counter-clockwise
    /// seen from outside) and tissue label.
    pub triangles: Vec<(u32, [u32; 3], u16)>,
    /// Triangles and vertices freed since the last surface frame.
    pub removed_triangles: Vec<u32>,
    /// See `removed_triangles`.
    pub removed_vertices: Vec<u32>,
}

impl SurfaceFrame {
    /// Whether it changes the topology (a reader redraws the triangles).
    #[must_use]
    pub fn changes_topology(&self) -> bool {
        self.whole
            || !self.triangles.is_empty()
            || !self.removed_triangles.is_empty()
            || !self.removed_vertices.is_empty()
    }

    /// The `incise.v1.SurfaceMesh` the MCAP file holds.
    #[must_use]
    pub fn to_message(&self) -> v1::SurfaceMesh {
        v1::SurfaceMesh {
            frame: self.frame,
            full: self.whole,
            vertex_ids: self.vertex_ids.clone(),
            positions: self.positions.iter().flatten().copied().collect(),
            triangle_ids: self.triangles.iter().map(|t| t.0).collect(),
            triangles: self.triangles.iter().flat_map(|t| t.1).collect(),
            triangle_labels: self.triangles.iter().map(|t| u32::from(t.2)).collect(),
            removed_vertex_ids: self.removed_vertices.clone(),
            removed_triangle_ids: self.removed_triangles.clone(),
        }
    }

    /// A surface frame read back from its message (`sim_time_s`: its log time), or why not.
    pub fn from_message(m: &v1::SurfaceMesh, sim_time_s: f64) -> Result<Self, String> {
        let at = |what: String| format!("surface of frame {}: {what}", m.frame);
        if m.positions.len() != 3 * m.vertex_ids.len() {
            let n = (m.positions.len(), m.vertex_ids.len());
            return Err(at(format!("{} position values for {} vertices", n.0, n.1)));
        }
        let n = m.triangle_ids.len();
        if m.triangles.len() != 3 * n || m.triangle_labels.len() != n {
            return Err(at(format!(
                "{} corners and {} labels for {n} triangles",
                m.triangles.len(),
                m.triangle_labels.len()
            )));
        }
        let triangles = m
            .triangle_ids
            .iter()
            .zip(m.triangles.chunks_exact(3))
            .zip(&m.triangle_labels)
            .map(|((&id, t), &l)| (id, [t[0], t[1], t[2]], l.min(u32::from(u16::MAX)) as u16))
            .collect();
        Ok(Self {
            frame: m.frame,
            sim_time_s,
            whole: m.full,
            vertex_ids: m.vertex_ids.clone(),
            positions: m.positions.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect(),
            triangles,
            removed_triangles: m.removed_triangle_ids.clone(),
            removed_vertices: m.removed_vertex_ids.clone(),
        })
    }
}

/// The surface as a reader has it after the surface frames so far.
#[derive(Clone, Debug, Default)]
pub struct SurfaceState {
    vertices: BTreeMap<u32, [f32; 3]>,
    triangles: BTreeMap<u32, ([u32; 3], u16)>,
}

/// A surface ready to draw: positions, and triangles as indices into them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions (m).
    pub positions: Vec<[f32; 3]>,
    /// Triangles, as indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
    /// Each triangle's tissue label.
    pub labels: Vec<u16>,
}

impl SurfaceState {
    /// Takes a surface frame in.
    pub fn apply(&mut self, frame: &SurfaceFrame) {
        if frame.whole {
            self.vertices.clear();
            self.triangles.clear();
        }
        for id in &frame.removed_triangles {
            self.triangles.remove(id);
        }
        for id in &frame.removed_vertices {
            self.vertices.remove(id);
        }
        for &(id, corners, label) in &frame.triangles {
            self.triangles.insert(id, (corners, label));
        }
        for (&id, &p) in frame.vertex_ids.iter().zip(&frame.positions) {
            self.vertices.insert(id, p);
        }
    }

    /// The surface to draw: the vertices in id order, and the triangles whose corners are all
    /// known.
    #[must_use]
    pub fn mesh(&self) -> Mesh {
        let index: BTreeMap<u32, u32> =
            self.vertices.keys().enumerate().map(|(i, &id)| (id, i as u32)).collect();
        let (triangles, labels) = self
            .triangles
            .values()
            .filter_map(|(t, l)| {
                Some(([index.get(&t[0])?, index.get(&t[1])?, index.get(&t[2])?].map(|&i| i), *l))
            })
            .unzip();
        Mesh { positions: self.vertices.values().copied().collect(), triangles, labels }
    }

    /// Live vertices.
    #[must_use]
    pub fn vertex_count(&self) -> usize {
        self.vertices.len()
    }

    /// The triangles by id: corners (vertex ids) and label.
    #[must_use]
    pub fn triangles(&self) -> &BTreeMap<u32, ([u32; 3], u16)> {
        &self.triangles
    }

    /// The positions alone, in the order of [`Self::mesh`]'s.
    #[must_use]
    pub fn positions(&self) -> Vec<[f32; 3]> {
        self.vertices.values().copied().collect()
    }
}

/// How a tool is drawn: its outer shape in the tool frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolLook {
    /// The tool's name in the scene.
    pub name: String,
    /// Its outer (pushing) shape.
    pub shape: ToolShape,
}

/// A tool's outer shape in the tool frame (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToolShape {
    /// A ball.
    Sphere {
        /// Its centre.
        centre: [f64; 3],
        /// Its radius.
        radius: f64,
    },
    /// A rounded shaft from `start` along `+z` for `length`.
    Capsule {
        /// The start of its axis.
        start: [f64; 3],
        /// Its radius.
        radius: f64,
        /// Its axis' length.
        length: f64,
    },
    /// An axis-aligned box (a box, a blade, a mesh's bounds).
    Box {
        /// Its lowest corner.
        min: [f64; 3],
        /// Its highest corner.
        max: [f64; 3],
    },
}

/// The colour a tissue label is drawn in (RGBA): a fixed palette, so label 1 looks the same in
/// every recording and viewer.
#[must_use]
pub fn label_colour(label: u16) -> [u8; 4] {
    const PALETTE: [[u8; 4]; 8] = [
        [196, 92, 80, 255],   // liver-like red-brown
        [214, 170, 96, 255],  // fat yellow
        [120, 60, 140, 255],  // kidney purple
        [80, 140, 200, 255],  // vessel blue
        [230, 120, 140, 255], // pink
        [110, 170, 90, 255],  // green
        [200, 200, 200, 255], // grey
        [240, 150, 60, 255],  // orange
    ];
    PALETTE[usize::from(label.saturating_sub(1)) % PALETTE.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn whole() -> SurfaceFrame {
        SurfaceFrame {
            frame: 1,
            sim_time_s: 0.001,
            whole: true,
            vertex_ids: vec![2, 5, 9, 11],
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]],
            triangles: vec![(0, [2, 5, 9], 1), (3, [5, 11, 9], 2)],
            ..SurfaceFrame::default()
        }
    }

    #[test]
    fn a_whole_frame_and_an_edit_give_the_surface_they_describe() {
        let mut state = SurfaceState::default();
        state.apply(&whole());
        let mesh = state.mesh();
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [1, 3, 2]]);
        assert_eq!(mesh.labels, vec![1, 2]);
        // A cut: triangle 3 and vertex 11 go, a new vertex 4 and triangle 7 come.
        let edit = SurfaceFrame {
            frame: 2,
            vertex_ids: vec![4],
            positions: vec![[0.5, 0.5, -1.0]],
            triangles: vec![(7, [4, 5, 9], 1)],
            removed_triangles: vec![3],
            removed_vertices: vec![11],
            ..SurfaceFrame::default()
        };
        assert!(edit.changes_topology());
        state.apply(&edit);
        let mesh = state.mesh();
        assert_eq!(mesh.positions.len(), 4);
        assert_eq!(
            mesh.positions[1].map(f32::to_bits),
            [0.5f32, 0.5, -1.0].map(f32::to_bits),
            "vertex 4 comes second in id order (2, 4, 5, 9)"
        );
        assert_eq!(mesh.triangles, vec![[0, 2, 3], [1, 2, 3]]);
    }

    #[test]
    fn a_surface_frame_survives_its_message_and_a_broken_message_is_refused() {
        let frame = whole();
        let message = frame.to_message();
        assert!(message.full);
        assert_eq!(message.triangles, vec![2, 5, 9, 5, 11, 9]);
        assert_eq!(SurfaceFrame::from_message(&message, 0.001), Ok(frame));
        let short = v1::SurfaceMesh { positions: vec![0.0; 4], ..message.clone() };
        assert!(SurfaceFrame::from_message(&short, 0.0).is_err());
        let unlabelled = v1::SurfaceMesh { triangle_labels: vec![1], ..message };
        assert!(SurfaceFrame::from_message(&unlabelled, 0.0).is_err());
    }
}
