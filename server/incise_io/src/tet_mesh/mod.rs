//! Tetrahedral meshes: Gmsh MSH 2.2 and 4.1 (`.msh`), legacy VTK (`.vtk`) and VTK XML
//! unstructured grids (`.vtu`), read into an [`incise_mesh::TetMesh`].
//!
//! The decoders take bytes, not text, because what meshing tools write by default is binary:
//! Gmsh and meshio write binary MSH 4.1, meshio and VTK write base64 or raw appended VTU,
//! often zlib-compressed. Refusing those would send every user through a conversion step. So
//! each format is read in all its encodings: ASCII and binary MSH 4.1 (either byte order),
//! ASCII and `BINARY` legacy VTK, and VTU arrays that are ASCII, inline base64, or appended raw
//! or base64, with or without `vtkZLibDataCompressor`, `UInt32` or `UInt64` headers, little- or
//! big-endian. Binary MSH 2.2 is refused with a message saying to save as ASCII or MSH 4.1.
//!
//! Only 4-node tetrahedra are kept (Gmsh element type 4, VTK cell type 10); points, lines,
//! triangles and every other element are skipped. Every node of the file becomes a vertex, in
//! file order (Gmsh node tags, which may have gaps, are mapped to compact indices). A
//! tetrahedron's region label is
//! - MSH 2.2: the element's first tag (its physical tag), 1 when it has no tags;
//! - MSH 4.1: the first physical tag of the element block's volume entity in `$Entities`, else
//!   the entity tag itself;
//! - VTK: the integer cell-data array with one component that [`MeshOptions::region`] names;
//!   else the first of `gmsh:physical`, `medit:ref` and `CellEntityIds` (what meshio, Gmsh and
//!   VTK's own filters call it) that the file has; else the first integer cell-data array with
//!   one component (in `.vtk` a `SCALARS` array is preferred to a `FIELD` array, in `.vtu` the
//!   array `CellData Scalars="…"` names is preferred to the others); 1 when there is none.
//!   In Gmsh files `region = "gmsh:geometrical"` takes the elementary entity tag instead of the
//!   physical tag (meshio's names for the two).
//!
//! [`read_tet_mesh_with`] also says where the regions came from and counts the cells it skipped
//! by type, so a caller can tell its user that the file's boundary triangles were not lost by
//! accident.
//!
//! Writers differ in orientation convention, so a tetrahedron with a negative signed volume has
//! its last two vertices swapped; any other defect [`TetMesh::new`] finds (a degenerate
//! tetrahedron, a repeated vertex, a triangle in three tetrahedra, a non-finite coordinate) is an
//! error naming the element and where it is.
//!
//! Errors name the file and where: the line in text, the byte offset in binary MSH and legacy
//! VTK (whose lines mean nothing), the `DataArray` and the line of its tag in VTU. Counts in
//! headers are never trusted for allocation: text vectors grow with the values actually read,
//! and a binary count is checked against the bytes left before anything is read, so a header
//! announcing 10^12 nodes in a short file is an error, not an allocation. Compressed VTU blocks
//! are inflated into buffers that grow with the output, never beyond the size announced.
//!
//! The encoders write every variant the decoders read, so each is tested by a round trip;
//! files written by meshio and VTK themselves are tested in `tests/foreign.rs`.

mod binary;
mod gmsh;
#[cfg(test)]
mod tests;
mod vtk;
mod vtu;

pub use gmsh::{decode_gmsh, decode_gmsh_with, encode_gmsh22, encode_gmsh41_binary};
pub use vtk::{
    VtkCells, decode_vtk_legacy, decode_vtk_legacy_with, encode_vtk_legacy,
    encode_vtk_legacy_binary,
};
pub use vtu::{VtuBinary, VtuData, decode_vtu, decode_vtu_with, encode_vtu, encode_vtu_binary};

use crate::error::{IoError, grouped};
use incise_mesh::TetMesh;
use incise_mesh::{TetMeshError, signed_volume};
use std::collections::BTreeMap;
use std::path::Path;
use std::str::FromStr;

/// Gmsh's element type of the 4-node tetrahedron.
const GMSH_TETRAHEDRON: u64 = 4;
/// VTK's cell type of the 4-node tetrahedron (`VTK_TETRA`).
const VTK_TETRA: i64 = 10;
/// Region label of tetrahedra whose file gives none.
const DEFAULT_REGION: u32 = 1;

/// How to read a tetrahedral mesh file.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MeshOptions {
    /// The cell-data array that holds each tetrahedron's region (VTK), or `"gmsh:physical"`
    /// (the default) or `"gmsh:geometrical"` (Gmsh). `None` picks as the module doc says; a name
    /// the file does not have is an error listing the arrays it does have.
    pub region: Option<String>,
}

/// A tetrahedral mesh file as read: the mesh, where its regions came from, and what was skipped.
#[derive(Clone, Debug)]
pub struct MeshFile {
    /// The tetrahedra, positively oriented, with their regions.
    pub mesh: TetMesh,
    /// Where the regions came from (`cell array "gmsh:physical"`, `physical tags`, …); `None`
    /// when the file gives none and every tetrahedron is in region 1.
    pub region_source: Option<String>,
    /// The cells that are not 4-node tetrahedra and were skipped: how many of each type, by
    /// type name, in name order.
    pub skipped: Vec<(String, usize)>,
}

impl MeshFile {
    /// How many cells were skipped.
    #[must_use]
    pub fn skipped_cells(&self) -> usize {
        self.skipped.iter().map(|(_, n)| n).sum()
    }

    /// A sentence for the user about the skipped cells, `None` when there were none.
    #[must_use]
    pub fn skipped_note(&self) -> Option<String> {
        let total = self.skipped_cells();
        (total > 0).then(|| {
            let kinds: Vec<String> = self
                .skipped
                .iter()
                .map(|(kind, n)| format!("{} {kind}", grouped(*n as u64)))
                .collect();
            format!(
                "skipped {} cells that are not tetrahedra ({})",
                grouped(total as u64),
                kinds.join(", ")
            )
        })
    }
}

/// Reads a tetrahedral mesh, choosing the format by extension: `.msh` (Gmsh MSH 2.2 or 4.1),
/// `.vtk` (legacy VTK) or `.vtu` (VTK XML), in any letter case.
pub fn read_tet_mesh(path: &Path) -> Result<TetMesh, IoError> {
    read_tet_mesh_with(path, &MeshOptions::default()).map(|file| file.mesh)
}

/// Reads a tetrahedral mesh as [`read_tet_mesh`] does, with `options`, and says where its
/// regions came from and what it skipped.
pub fn read_tet_mesh_with(path: &Path, options: &MeshOptions) -> Result<MeshFile, IoError> {
    let file = path.display().to_string();
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let decode: fn(&[u8], &str, &MeshOptions) -> Result<MeshFile, IoError> = match ext.as_deref() {
        Some("msh") => decode_gmsh_with,
        Some("vtk") => decode_vtk_legacy_with,
        Some("vtu") => decode_vtu_with,
        _ => {
            return Err(IoError::UnsupportedType {
                file,
                what: "tetrahedral mesh file name: the readers take .msh (Gmsh), .vtk (legacy \
                       VTK) and .vtu (VTK XML)"
                    .to_owned(),
            });
        }
    };
    let bytes = std::fs::read(path).map_err(|source| IoError::Io { file: file.clone(), source })?;
    decode(&bytes, &file, options)
}

/// Cell-data arrays that hold regions by convention, the most specific first: meshio's name for
/// Gmsh physical groups, its name for Medit references, and VTK's (and `ParaView`'s) name.
const REGION_ARRAYS: [&str; 3] = ["gmsh:physical", "medit:ref", "CellEntityIds"];

/// How strongly a cell-data array named `name` claims to hold the regions, higher first; `None`
/// when it is not a candidate at all (another array was asked for). `hint` ranks the arrays no
/// convention names: 1 for the array the file marks as its scalars, 0 for the others.
fn region_rank(name: &str, hint: u8, wanted: Option<&str>) -> Option<u8> {
    match wanted {
        Some(wanted) => (name == wanted).then_some(u8::MAX),
        None => Some(
            REGION_ARRAYS
                .iter()
                .position(|&known| known == name)
                .map_or(hint, |i| (2 + REGION_ARRAYS.len() - i) as u8),
        ),
    }
}

/// The error for an array `wanted` names that cannot hold regions.
fn unusable_region_array(file: &str, name: &str, kind: &str, components: usize) -> IoError {
    IoError::RegionArray {
        file: file.to_owned(),
        what: format!(
            "cell array {name:?} is {kind} with {components} component(s); regions must be one \
             integer per cell"
        ),
    }
}

/// The VTK name of a cell type, for the note on skipped cells.
fn vtk_cell_name(kind: i64) -> String {
    match kind {
        1 => "vertex".to_owned(),
        2 => "poly-vertex".to_owned(),
        3 => "line".to_owned(),
        4 => "poly-line".to_owned(),
        5 => "triangle".to_owned(),
        6 => "triangle strip".to_owned(),
        7 => "polygon".to_owned(),
        8 => "pixel".to_owned(),
        9 => "quad".to_owned(),
        11 => "voxel".to_owned(),
        12 => "hexahedron".to_owned(),
        13 => "wedge".to_owned(),
        14 => "pyramid".to_owned(),
        21 => "quadratic line".to_owned(),
        22 => "quadratic triangle".to_owned(),
        24 => "quadratic tetrahedron".to_owned(),
        other => format!("type-{other} cell"),
    }
}

// ------------------------------------------------------------------------------------------------
// Shared pieces

/// The UTF-8 byte-order mark some editors put before text.
pub(crate) const BOM: &[u8] = b"\xef\xbb\xbf";

pub(crate) fn syntax(file: &str, line: usize, what: impl Into<String>) -> IoError {
    IoError::Syntax { file: file.to_owned(), line, what: what.into() }
}

/// Where in a file something is: a line of text, or a byte of binary data, where lines mean
/// nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum At {
    Line(usize),
    Byte(usize),
}

impl std::fmt::Display for At {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Line(line) => write!(f, "line {line}"),
            Self::Byte(offset) => write!(f, "byte {}", grouped(*offset as u64)),
        }
    }
}

/// An error at `at`: a [`IoError::Syntax`] on a line, a [`IoError::Binary`] at a byte.
pub(crate) fn error_at(file: &str, at: At, what: impl Into<String>) -> IoError {
    match at {
        At::Line(line) => syntax(file, line, what),
        At::Byte(offset) => {
            IoError::Binary { file: file.to_owned(), offset: offset as u64, what: what.into() }
        }
    }
}

/// The first position of `needle` in `haystack` at or after `from`.
fn find_bytes(haystack: &[u8], needle: &[u8], from: usize) -> Option<usize> {
    if needle.is_empty() {
        return None;
    }
    haystack.get(from..)?.windows(needle.len()).position(|w| w == needle).map(|i| from + i)
}

/// `text` quoted and shortened for an error message.
pub(crate) fn shown(text: &str) -> String {
    const MAX: usize = 40;
    match text.char_indices().nth(MAX) {
        Some((at, _)) => format!("{:?}…", &text[..at]),
        None => format!("{text:?}"),
    }
}

/// `token` parsed as a `T`, or an error on `line` saying `what` was expected.
fn parse<T: FromStr>(
    file: &str,
    line: usize,
    token: Option<&str>,
    what: &str,
) -> Result<T, IoError> {
    let token = token.ok_or_else(|| syntax(file, line, format!("the line ends before {what}")))?;
    token
        .parse()
        .map_err(|_| syntax(file, line, format!("expected {what}, found {}", shown(token))))
}

/// Where a vertex or tetrahedron came from: its number in the file and its line or byte.
#[derive(Clone, Copy, Debug)]
struct Origin {
    id: u64,
    at: At,
}

/// Vertices and tetrahedra as read, with where each came from, before [`TetMesh::new`] checks
/// them.
struct Assembly {
    /// What the format calls a vertex ("node", "point").
    vertex_noun: &'static str,
    /// What the format calls a tetrahedron ("element", "cell").
    tet_noun: &'static str,
    vertices: Vec<[f64; 3]>,
    vertex_origins: Vec<Origin>,
    tets: Vec<[u32; 4]>,
    tet_origins: Vec<Origin>,
    regions: Vec<u32>,
    /// Skipped cells by type name.
    skipped: BTreeMap<String, usize>,
    /// Where the regions came from, once known.
    region_source: Option<String>,
}

impl Assembly {
    fn new(vertex_noun: &'static str, tet_noun: &'static str) -> Self {
        Self {
            vertex_noun,
            tet_noun,
            vertices: Vec::new(),
            vertex_origins: Vec::new(),
            tets: Vec::new(),
            tet_origins: Vec::new(),
            regions: Vec::new(),
            skipped: BTreeMap::new(),
            region_source: None,
        }
    }

    /// Counts a skipped cell of type `kind`.
    fn skip(&mut self, kind: String) {
        *self.skipped.entry(kind).or_default() += 1;
    }

    fn push_tet(&mut self, tet: [u32; 4], region: u32, origin: Origin) {
        self.tets.push(tet);
        self.regions.push(region);
        self.tet_origins.push(origin);
    }

    /// Orients every tetrahedron positively and checks the mesh.
    fn finish(self, file: &str) -> Result<MeshFile, IoError> {
        let Self {
            vertex_noun,
            tet_noun,
            vertices,
            vertex_origins,
            mut tets,
            tet_origins,
            regions,
            skipped,
            region_source,
        } = self;
        for tet in &mut tets {
            if let [Some(a), Some(b), Some(c), Some(d)] =
                tet.map(|i| vertices.get(i as usize).copied())
                && signed_volume(&[a, b, c, d]) < 0.0
            {
                tet.swap(2, 3);
            }
        }
        let mesh = TetMesh::new(vertices, tets, regions).map_err(|source| {
            let name = |noun: &str, origin: Option<&Origin>| {
                origin.map(|o| format!("{}: {noun} {}", o.at, o.id))
            };
            let at = match &source {
                TetMeshError::NonFiniteVertex { vertex, .. } => {
                    name(vertex_noun, vertex_origins.get(*vertex))
                }
                TetMeshError::IndexOutOfRange { tet, .. }
                | TetMeshError::RepeatedVertex { tet, .. }
                | TetMeshError::Degenerate { tet, .. }
                | TetMeshError::Inverted { tet, .. }
                | TetMeshError::NonManifold { first_tet: tet, .. } => {
                    name(tet_noun, tet_origins.get(*tet))
                }
                TetMeshError::Empty | TetMeshError::RegionCount { .. } => None,
            };
            IoError::Mesh { file: file.to_owned(), at, source }
        })?;
        Ok(MeshFile { mesh, region_source, skipped: skipped.into_iter().collect() })
    }
}

/// Whitespace-separated tokens of a text, with the line each is on.
#[derive(Clone)]
pub(crate) struct Tokens<'a> {
    rest: &'a str,
    /// The line `rest` starts on.
    line: usize,
}

impl<'a> Tokens<'a> {
    pub(crate) fn new(text: &'a str, line: usize) -> Self {
        Self { rest: text, line }
    }
}

impl<'a> Iterator for Tokens<'a> {
    type Item = (&'a str, usize);

    fn next(&mut self) -> Option<Self::Item> {
        let bytes = self.rest.as_bytes();
        let mut i = 0;
        while i < bytes.len() && bytes[i].is_ascii_whitespace() {
            if bytes[i] == b'\n' {
                self.line += 1;
            }
            i += 1;
        }
        let start = i;
        while i < bytes.len() && !bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        // ASCII whitespace never sits inside a multi-byte character, so both ends are boundaries.
        let token = &self.rest[start..i];
        self.rest = &self.rest[i..];
        (!token.is_empty()).then_some((token, self.line))
    }
}

/// Integer values with where each is.
#[derive(Debug, Default)]
struct Labels {
    values: Vec<i64>,
    ats: Vec<At>,
}

/// A cell-data array chosen as the regions: its values, its name and its rank
/// ([`region_rank`]).
#[derive(Debug)]
struct RegionArray {
    labels: Labels,
    name: String,
    rank: u8,
}

impl RegionArray {
    /// Keeps `candidate` in `slot` when it ranks above what is there (the first of equals wins).
    fn offer(slot: &mut Option<Self>, candidate: Self) {
        if slot.as_ref().is_none_or(|kept| candidate.rank > kept.rank) {
            *slot = Some(candidate);
        }
    }

    /// Whether an array of rank `rank` would replace what `slot` holds.
    fn wanted(slot: Option<&Self>, rank: u8) -> bool {
        slot.is_none_or(|kept| rank > kept.rank)
    }
}

/// Checks that the array `wanted` names was found among the cell arrays `seen`.
fn check_wanted(
    file: &str,
    wanted: Option<&str>,
    found: bool,
    seen: &[String],
) -> Result<(), IoError> {
    match wanted {
        Some(name) if !found => Err(IoError::RegionArray {
            file: file.to_owned(),
            what: if seen.is_empty() {
                format!("the scene names {name:?}, but the file has no cell-data arrays")
            } else {
                format!(
                    "the scene names {name:?}, but the file's cell-data arrays are {}",
                    seen.iter().map(|s| format!("{s:?}")).collect::<Vec<_>>().join(", ")
                )
            },
        }),
        _ => Ok(()),
    }
}

/// VTK cells as read: where each starts in the connectivity, its type and its region label.
struct CellBlock {
    /// Start of each cell in `connectivity`, plus its end: one more entry than cells,
    /// non-decreasing, the last at most `connectivity.len()`.
    starts: Vec<usize>,
    connectivity: Vec<i64>,
    /// Where each cell is.
    ats: Vec<At>,
    /// The VTK cell type of each cell.
    types: Vec<i64>,
    /// The region label of each cell, where the file has them.
    labels: Option<Labels>,
}

impl CellBlock {
    /// Adds the tetrahedra among the cells to `mesh`, their points numbered from `base`; the
    /// cells are numbered from `first_cell` in messages. `points` is how many points the cells
    /// may name.
    fn append_tets(
        &self,
        file: &str,
        points: usize,
        base: usize,
        first_cell: usize,
        mesh: &mut Assembly,
    ) -> Result<(), IoError> {
        for (i, &kind) in self.types.iter().enumerate() {
            if kind != VTK_TETRA {
                mesh.skip(vtk_cell_name(kind));
                continue;
            }
            let cell = first_cell + i;
            let at = self.ats.get(i).copied().unwrap_or(At::Line(0));
            let nodes = match (self.starts.get(i), self.starts.get(i + 1)) {
                (Some(&a), Some(&b)) => self.connectivity.get(a..b).unwrap_or_default(),
                _ => &[],
            };
            if nodes.len() != 4 {
                return Err(error_at(
                    file,
                    at,
                    format!("cell {cell} has type 10 (tetra) but {} points", nodes.len()),
                ));
            }
            let mut tet = [0u32; 4];
            for (slot, &p) in tet.iter_mut().zip(nodes) {
                let index = usize::try_from(p)
                    .ok()
                    .filter(|&p| p < points)
                    .and_then(|p| u32::try_from(base + p).ok())
                    .ok_or_else(|| {
                        error_at(
                            file,
                            at,
                            format!("cell {cell} names point {p}, but there are {points} points"),
                        )
                    })?;
                *slot = index;
            }
            let region = match &self.labels {
                None => DEFAULT_REGION,
                Some(labels) => {
                    let value = labels.values.get(i).copied().unwrap_or_default();
                    u32::try_from(value).map_err(|_| {
                        error_at(
                            file,
                            labels.ats.get(i).copied().unwrap_or(at),
                            format!("cell {cell}: region label {value} is not in 0..={}", u32::MAX),
                        )
                    })?
                }
            };
            mesh.push_tet(tet, region, Origin { id: cell as u64, at });
        }
        Ok(())
    }
}

/// Whether a VTK data type name (legacy or XML) is an integer type.
fn is_integer_type(kind: &str) -> bool {
    const INTEGER: [&str; 25] = [
        "char",
        "unsigned_char",
        "short",
        "unsigned_short",
        "int",
        "unsigned_int",
        "long",
        "unsigned_long",
        "vtkIdType",
        "vtktypeint8",
        "vtktypeuint8",
        "vtktypeint16",
        "vtktypeuint16",
        "vtktypeint32",
        "vtktypeuint32",
        "vtktypeint64",
        "vtktypeuint64",
        "Int8",
        "UInt8",
        "Int16",
        "UInt16",
        "Int32",
        "UInt32",
        "Int64",
        "UInt64",
    ];
    INTEGER.iter().any(|t| kind.eq_ignore_ascii_case(t))
}
