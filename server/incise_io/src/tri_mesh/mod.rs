//! Closed triangle meshes, the shapes of surgical tools: STL (`.stl`, binary or ASCII) and
//! Wavefront OBJ (`.obj`), read into an [`incise_mesh::TriMesh`].
//!
//! These are what CAD tools export a part as. STL is a list of independent triangles that repeat
//! their corners' coordinates; corners whose coordinates are bit-identical as read (with −0 and
//! +0 taken as one) are welded into one vertex, numbered in order of first appearance. Nothing
//! closer than identical is welded: a tolerance would merge what a fine mesh keeps apart, and a
//! surface that only closes up to a tolerance is reported as open where it is. Binary and ASCII
//! STL are told apart by size, not by the first word: many binary files start their 80-byte
//! header with `solid`, so a file is binary exactly when `84 + 50 × count` (the count at byte 80)
//! is its length. Facet normals are ignored; orientation comes from the order of the corners.
//!
//! OBJ vertices are kept as listed, unused ones included. Faces may be any polygon (split into a
//! fan of triangles from their first vertex) and their vertex references may carry texture and
//! normal indices (`a/t`, `a/t/n`, `a//n`) or count back from the last vertex (`-1`). Texture
//! coordinates, normals, groups, materials, smoothing groups, lines and points are ignored;
//! free-form curves and surfaces are refused, since dropping them would lose part of the shape.
//!
//! The triangles are then checked by [`TriMesh::new`]: closed (every edge in exactly two
//! triangles), consistently wound, and oriented outwards as a whole. A winding that disagrees
//! between neighbours is an error naming both facets, never repaired, as is an open surface (a
//! missing facet, a gap between parts). Every error names the file and where: the line in text,
//! the byte offset in binary STL, and the facet (STL) or face (OBJ) involved, numbered from 0.
//! A binary STL's triangle count is checked against the file's length before anything is
//! allocated for it.
//!
//! The encoders write every variant the decoders read, so each is tested by a round trip.

mod obj;
mod stl;
#[cfg(test)]
pub(crate) mod tests;

pub use obj::{decode_obj, encode_obj};
pub use stl::{decode_stl, encode_stl_ascii, encode_stl_binary};

use crate::error::IoError;
use crate::tet_mesh::{At, error_at};
use incise_mesh::{TriMesh, TriMeshError};
use std::collections::HashMap;
use std::path::Path;

/// Reads a closed triangle mesh, choosing the format by extension: `.stl` (binary or ASCII STL)
/// or `.obj` (Wavefront OBJ), in any letter case. Coordinates are as in the file: STL and OBJ
/// carry no unit, so a caller converts (CAD exports in millimetres: [`TriMesh::scaled`] by
/// `0.001`).
pub fn read_tri_mesh(path: &Path) -> Result<TriMesh, IoError> {
    let file = path.display().to_string();
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let decode: fn(&[u8], &str) -> Result<TriMesh, IoError> = match ext.as_deref() {
        Some("stl") => decode_stl,
        Some("obj") => decode_obj,
        _ => {
            return Err(IoError::UnsupportedType {
                file,
                what: "triangle mesh file name: the readers take .stl (STL, binary or ASCII) \
                       and .obj (Wavefront OBJ)"
                    .to_owned(),
            });
        }
    };
    let bytes = std::fs::read(path).map_err(|source| IoError::Io { file: file.clone(), source })?;
    decode(&bytes, &file)
}

/// Where a vertex or triangle came from: its line or byte, and the facet or face it belongs to.
#[derive(Clone, Copy, Debug)]
struct Origin {
    at: At,
    /// What the format calls a triangle ("facet", "face") and its number in the file, from 0.
    item: Option<(&'static str, usize)>,
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.item {
            Some((noun, id)) => write!(f, "{}: {noun} {id}", self.at),
            None => write!(f, "{}", self.at),
        }
    }
}

impl Origin {
    /// The origin as a side note: `facet 3 (line 20)`.
    fn aside(&self) -> String {
        match self.item {
            Some((noun, id)) => format!("{noun} {id} ({})", self.at),
            None => self.at.to_string(),
        }
    }
}

/// Vertices and triangles as read, with where each came from, before [`TriMesh::new`] checks
/// them.
#[derive(Default)]
struct Soup {
    vertices: Vec<[f64; 3]>,
    vertex_origins: Vec<Origin>,
    triangles: Vec<[u32; 3]>,
    triangle_origins: Vec<Origin>,
    /// The vertex at each position, by the bits of its coordinates (STL's welding).
    welded: HashMap<[u64; 3], u32>,
}

impl Soup {
    /// Adds a vertex and returns its index.
    fn push_vertex(&mut self, p: [f64; 3], origin: Origin, file: &str) -> Result<u32, IoError> {
        let index = u32::try_from(self.vertices.len())
            .map_err(|_| error_at(file, origin.at, format!("more than {} vertices", u32::MAX)))?;
        self.vertices.push(p);
        self.vertex_origins.push(origin);
        Ok(index)
    }

    /// The vertex at `p`, added at its first appearance. `+ 0.0` turns −0 into +0, which a
    /// writer may print for a coordinate its neighbour prints as 0; any other difference in bits
    /// is a different point.
    fn weld(&mut self, p: [f64; 3], origin: Origin, file: &str) -> Result<u32, IoError> {
        let key = p.map(|c| (c + 0.0).to_bits());
        if let Some(&index) = self.welded.get(&key) {
            return Ok(index);
        }
        let index = self.push_vertex(p, origin, file)?;
        self.welded.insert(key, index);
        Ok(index)
    }

    fn push_triangle(&mut self, triangle: [u32; 3], origin: Origin) {
        self.triangles.push(triangle);
        self.triangle_origins.push(origin);
    }

    /// Checks and orients the mesh, naming where each problem is.
    fn finish(self, file: &str) -> Result<TriMesh, IoError> {
        let Self { vertices, vertex_origins, triangles, triangle_origins, .. } = self;
        TriMesh::new(vertices, triangles).map_err(|source| {
            let one = |t: usize| triangle_origins.get(t).map(ToString::to_string);
            let with = |t: usize, others: &[usize]| {
                let others: Vec<String> = others
                    .iter()
                    .filter_map(|&o| triangle_origins.get(o).map(Origin::aside))
                    .collect();
                one(t).map(|main| format!("{main}, with {}", others.join(" and ")))
            };
            let at = match &source {
                TriMeshError::NonFiniteVertex { vertex, .. } => {
                    vertex_origins.get(*vertex).map(ToString::to_string)
                }
                TriMeshError::IndexOutOfRange { triangle, .. }
                | TriMeshError::RepeatedVertex { triangle, .. }
                | TriMeshError::Degenerate { triangle, .. }
                | TriMeshError::OpenEdge { triangle, .. } => one(*triangle),
                TriMeshError::DuplicateTriangle { first, second, .. }
                | TriMeshError::InconsistentWinding { first, second, .. } => {
                    with(*second, &[*first])
                }
                TriMeshError::NonManifoldEdge { triangles, .. } => {
                    with(triangles[2], &triangles[..2])
                }
                TriMeshError::Empty | TriMeshError::ZeroVolume { .. } => None,
            };
            IoError::TriMesh { file: file.to_owned(), at, source: Box::new(source) }
        })
    }
}
