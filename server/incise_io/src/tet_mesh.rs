//! Tetrahedral meshes: Gmsh MSH 2.2 and 4.1 (`.msh`), legacy VTK (`.vtk`) and VTK XML
//! unstructured grids (`.vtu`), all ASCII, read into an [`incise_mesh::TetMesh`].
//!
//! Only 4-node tetrahedra are kept (Gmsh element type 4, VTK cell type 10); points, lines,
//! triangles and every other element are skipped. Every node of the file becomes a vertex, in
//! file order (Gmsh node tags, which may have gaps, are mapped to compact indices). A
//! tetrahedron's region label is
//! - MSH 2.2: the element's first tag (its physical tag), 1 when it has no tags;
//! - MSH 4.1: the first physical tag of the element block's volume entity in `$Entities`, else
//!   the entity tag itself;
//! - VTK: the first integer cell-data array with one component (in `.vtk` a `SCALARS` array is
//!   preferred to a `FIELD` array, in `.vtu` the array `CellData Scalars="…"` names is preferred
//!   to the others), 1 when there is none.
//!
//! Writers differ in orientation convention, so a tetrahedron with a negative signed volume has
//! its last two vertices swapped; any other defect [`TetMesh::new`] finds (a degenerate
//! tetrahedron, a repeated vertex, a triangle in three tetrahedra, a non-finite coordinate) is an
//! error naming the element and its line.
//!
//! Errors name the file and the line. Counts in headers are never trusted for allocation: vectors
//! grow with the data actually read, so a header announcing 10^12 nodes in a short file ends in an
//! error where the file ends. Binary variants (binary MSH, `BINARY` legacy VTK, `binary` or
//! `appended` VTK XML arrays) are refused with a message saying to save as ASCII.

use crate::error::IoError;
use incise_mesh::TetMesh;
use incise_mesh::{TetMeshError, signed_volume};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;
use std::str::FromStr;

/// Gmsh's element type of the 4-node tetrahedron.
const GMSH_TETRAHEDRON: u64 = 4;
/// VTK's cell type of the 4-node tetrahedron (`VTK_TETRA`).
const VTK_TETRA: i64 = 10;
/// Region label of tetrahedra whose file gives none.
const DEFAULT_REGION: u32 = 1;

/// Reads a tetrahedral mesh, choosing the format by extension: `.msh` (Gmsh MSH 2.2 or 4.1),
/// `.vtk` (legacy VTK) or `.vtu` (VTK XML), in any letter case.
pub fn read_tet_mesh(path: &Path) -> Result<TetMesh, IoError> {
    let file = path.display().to_string();
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let decode: fn(&str, &str) -> Result<TetMesh, IoError> = match ext.as_deref() {
        Some("msh") => decode_gmsh,
        Some("vtk") => decode_vtk_legacy,
        Some("vtu") => decode_vtu,
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
    // Binary files are not UTF-8; replacing the stray bytes lets their header say "binary"
    // rather than the reader stopping at the first byte that is not text.
    decode(&String::from_utf8_lossy(&bytes), &file)
}

// ------------------------------------------------------------------------------------------------
// Shared pieces

fn syntax(file: &str, line: usize, what: impl Into<String>) -> IoError {
    IoError::Syntax { file: file.to_owned(), line, what: what.into() }
}

/// `text` quoted and shortened for an error message.
fn shown(text: &str) -> String {
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

/// Where a vertex or tetrahedron came from: its number in the file and its line.
#[derive(Clone, Copy, Debug)]
struct Origin {
    id: u64,
    line: usize,
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
        }
    }

    fn push_tet(&mut self, tet: [u32; 4], region: u32, origin: Origin) {
        self.tets.push(tet);
        self.regions.push(region);
        self.tet_origins.push(origin);
    }

    /// Orients every tetrahedron positively and checks the mesh.
    fn finish(self, file: &str) -> Result<TetMesh, IoError> {
        let Self {
            vertex_noun,
            tet_noun,
            vertices,
            vertex_origins,
            mut tets,
            tet_origins,
            regions,
        } = self;
        for tet in &mut tets {
            if let [Some(a), Some(b), Some(c), Some(d)] =
                tet.map(|i| vertices.get(i as usize).copied())
                && signed_volume(&[a, b, c, d]) < 0.0
            {
                tet.swap(2, 3);
            }
        }
        TetMesh::new(vertices, tets, regions).map_err(|source| {
            let name = |noun: &str, origin: Option<&Origin>| {
                origin.map(|o| format!("line {}: {noun} {}", o.line, o.id))
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
        })
    }
}

/// Whitespace-separated tokens of a text, with the line each is on.
#[derive(Clone)]
struct Tokens<'a> {
    rest: &'a str,
    /// The line `rest` starts on.
    line: usize,
}

impl<'a> Tokens<'a> {
    fn new(text: &'a str, line: usize) -> Self {
        Self { rest: text, line }
    }

    /// The next token, without consuming it.
    fn peek(&self) -> Option<&'a str> {
        let mut copy = self.clone();
        copy.next().map(|(token, _)| token)
    }

    /// Skips the rest of the current line and everything up to and including the next blank line
    /// (how legacy VTK ends a `METADATA` block).
    fn skip_past_blank_line(&mut self) {
        let mut first = true;
        while let Some((line, rest)) = self.rest.split_once('\n') {
            self.rest = rest;
            self.line += 1;
            if !first && line.trim().is_empty() {
                return;
            }
            first = false;
        }
        self.rest = "";
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

/// Integer values with the line of each.
#[derive(Debug, Default)]
struct Labels {
    values: Vec<i64>,
    lines: Vec<usize>,
}

/// VTK cells as read: where each starts in the connectivity, its type and its region label.
struct CellBlock {
    /// Start of each cell in `connectivity`, plus its end: one more entry than cells,
    /// non-decreasing, the last at most `connectivity.len()`.
    starts: Vec<usize>,
    connectivity: Vec<i64>,
    /// The line of each cell.
    lines: Vec<usize>,
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
                continue;
            }
            let cell = first_cell + i;
            let line = self.lines.get(i).copied().unwrap_or_default();
            let nodes = match (self.starts.get(i), self.starts.get(i + 1)) {
                (Some(&a), Some(&b)) => self.connectivity.get(a..b).unwrap_or_default(),
                _ => &[],
            };
            if nodes.len() != 4 {
                return Err(syntax(
                    file,
                    line,
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
                        syntax(
                            file,
                            line,
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
                        syntax(
                            file,
                            labels.lines.get(i).copied().unwrap_or(line),
                            format!("cell {cell}: region label {value} is not in 0..={}", u32::MAX),
                        )
                    })?
                }
            };
            mesh.push_tet(tet, region, Origin { id: cell as u64, line });
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

// ------------------------------------------------------------------------------------------------
// Gmsh

/// The MSH versions read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum MshVersion {
    /// 2.0, 2.1 and 2.2, which share their layout.
    V2,
    V41,
}

/// Non-blank lines of a text, trimmed, with their 1-based numbers.
struct Lines<'a> {
    rest: &'a str,
    /// The number of the last line handed out (or skipped).
    line: usize,
}

impl<'a> Lines<'a> {
    fn next_line(&mut self) -> Option<(usize, &'a str)> {
        while !self.rest.is_empty() {
            let (line, rest) = self.rest.split_once('\n').unwrap_or((self.rest, ""));
            self.rest = rest;
            self.line += 1;
            let line = line.trim();
            if !line.is_empty() {
                return Some((self.line, line));
            }
        }
        None
    }
}

/// Nodes read so far: positions, where they came from, and the index of each tag.
#[derive(Default)]
struct GmshNodes {
    coords: Vec<[f64; 3]>,
    origins: Vec<Origin>,
    index: HashMap<u64, u32>,
}

impl GmshNodes {
    fn add(&mut self, file: &str, tag: u64, p: [f64; 3], line: usize) -> Result<(), IoError> {
        let index = u32::try_from(self.coords.len())
            .map_err(|_| syntax(file, line, "more than 2^32 nodes"))?;
        if let Some(&first) = self.index.get(&tag) {
            let first_line = self.origins.get(first as usize).map_or(0, |o| o.line);
            return Err(syntax(
                file,
                line,
                format!("node {tag} is defined twice (first on line {first_line})"),
            ));
        }
        self.index.insert(tag, index);
        self.coords.push(p);
        self.origins.push(Origin { id: tag, line });
        Ok(())
    }
}

/// A tetrahedron as read, before its node tags and region are resolved.
struct GmshTet {
    tag: u64,
    line: usize,
    nodes: [u64; 4],
    /// The physical tag (2.2) or the entity tag (4.1).
    label: i64,
    /// Whether `label` is an entity tag to map through `$Entities`.
    entity: bool,
}

/// A Gmsh file being read.
struct Gmsh<'a> {
    file: &'a str,
    lines: Lines<'a>,
}

/// Decodes a Gmsh ASCII mesh, MSH 2.2 or 4.1. `name` names the text in errors.
pub fn decode_gmsh(text: &str, name: &str) -> Result<TetMesh, IoError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut g = Gmsh { file: name, lines: Lines { rest: text, line: 0 } };
    let version = g.mesh_format()?;
    let mut nodes = GmshNodes::default();
    let mut tets: Vec<GmshTet> = Vec::new();
    let mut volumes: HashMap<i64, i64> = HashMap::new();
    let (mut saw_nodes, mut saw_elements) = (false, false);
    while let Some((line, text)) = g.lines.next_line() {
        match (text, version) {
            ("$Nodes", MshVersion::V2) => g.nodes_2(&mut nodes)?,
            ("$Nodes", MshVersion::V41) => g.nodes_41(&mut nodes)?,
            ("$Elements", MshVersion::V2) => g.elements_2(&mut tets)?,
            ("$Elements", MshVersion::V41) => g.elements_41(&mut tets)?,
            ("$Entities", MshVersion::V41) => g.entities(&mut volumes)?,
            _ => match text.strip_prefix('$') {
                Some(section) if !section.is_empty() && !section.starts_with("End") => {
                    g.skip(section)?;
                }
                _ => {
                    return Err(syntax(
                        name,
                        line,
                        format!("expected a section ($Nodes, $Elements, …), found {}", shown(text)),
                    ));
                }
            },
        }
        saw_nodes |= text == "$Nodes";
        saw_elements |= text == "$Elements";
    }
    for (seen, section) in [(saw_nodes, "$Nodes"), (saw_elements, "$Elements")] {
        if !seen {
            return Err(syntax(name, g.lines.line, format!("the file has no {section} section")));
        }
    }

    let mut mesh = Assembly::new("node", "element");
    for t in tets {
        let mut tet = [0u32; 4];
        for (slot, tag) in tet.iter_mut().zip(t.nodes) {
            *slot = *nodes.index.get(&tag).ok_or_else(|| {
                syntax(
                    name,
                    t.line,
                    format!("element {} names node {tag}, which $Nodes does not define", t.tag),
                )
            })?;
        }
        let label =
            if t.entity { volumes.get(&t.label).copied().unwrap_or(t.label) } else { t.label };
        let region = u32::try_from(label).map_err(|_| {
            let what = if t.entity { "physical or entity tag" } else { "physical tag" };
            syntax(
                name,
                t.line,
                format!(
                    "element {}: region label {label} ({what}) is not in 0..={}",
                    t.tag,
                    u32::MAX
                ),
            )
        })?;
        mesh.push_tet(tet, region, Origin { id: t.tag, line: t.line });
    }
    mesh.vertices = nodes.coords;
    mesh.vertex_origins = nodes.origins;
    mesh.finish(name)
}

impl<'a> Gmsh<'a> {
    /// The next non-blank line of `$section`, which must be data (not a `$` line): the data
    /// `what` describes.
    fn data_line(
        &mut self,
        section: &str,
        what: impl FnOnce() -> String,
    ) -> Result<(usize, &'a str), IoError> {
        match self.lines.next_line() {
            None => Err(syntax(
                self.file,
                self.lines.line,
                format!("the file ends inside ${section}, before {}", what()),
            )),
            Some((line, text)) if text.starts_with('$') => {
                Err(syntax(self.file, line, format!("expected {}, found {}", what(), shown(text))))
            }
            Some(found) => Ok(found),
        }
    }

    /// Reads the line that must close `$section`.
    fn end(&mut self, section: &str) -> Result<(), IoError> {
        match self.lines.next_line() {
            Some((_, text)) if text.strip_prefix("$End") == Some(section) => Ok(()),
            Some((line, text)) => Err(syntax(
                self.file,
                line,
                format!("expected $End{section}, found {}", shown(text)),
            )),
            None => Err(syntax(
                self.file,
                self.lines.line,
                format!("the file ends inside ${section} (no $End{section})"),
            )),
        }
    }

    /// Skips a section this reader does not use, up to its `$End` line.
    fn skip(&mut self, section: &str) -> Result<(), IoError> {
        while let Some((_, text)) = self.lines.next_line() {
            if text.strip_prefix("$End") == Some(section) {
                return Ok(());
            }
        }
        Err(syntax(
            self.file,
            self.lines.line,
            format!("the file ends inside ${section} (no $End{section})"),
        ))
    }

    /// Reads `$MeshFormat` (the first section) and returns the version.
    fn mesh_format(&mut self) -> Result<MshVersion, IoError> {
        let file = self.file;
        let Some((line, first)) = self.lines.next_line() else {
            return Err(syntax(file, 1, "the file is empty; a Gmsh mesh starts with $MeshFormat"));
        };
        if first != "$MeshFormat" {
            return Err(syntax(
                file,
                line,
                format!("expected $MeshFormat (the start of a Gmsh mesh), found {}", shown(first)),
            ));
        }
        let (line, text) =
            self.data_line("MeshFormat", || "the line `version file-type data-size`".to_owned())?;
        let mut fields = text.split_ascii_whitespace();
        let version = fields.next().unwrap_or_default();
        let file_type: u32 =
            parse(file, line, fields.next(), "the file type (0 for ASCII, 1 for binary)")?;
        match file_type {
            0 => {}
            1 => {
                return Err(IoError::UnsupportedType {
                    file: file.to_owned(),
                    what: "binary MSH is not supported, save as ASCII (in Gmsh: Mesh.Binary = 0)"
                        .to_owned(),
                });
            }
            other => {
                return Err(syntax(
                    file,
                    line,
                    format!("file type {other} is neither 0 (ASCII) nor 1 (binary)"),
                ));
            }
        }
        let v = match version.parse::<f64>() {
            _ if version == "4.1" => MshVersion::V41,
            Ok(v) if (2.0..3.0).contains(&v) => MshVersion::V2,
            Ok(_) => {
                return Err(IoError::UnsupportedType {
                    file: file.to_owned(),
                    what: format!("MSH version {version}; this reader takes 2.2 and 4.1"),
                });
            }
            Err(_) => {
                return Err(syntax(
                    file,
                    line,
                    format!("expected the MSH version, found {}", shown(version)),
                ));
            }
        };
        self.end("MeshFormat")?;
        Ok(v)
    }

    /// MSH 2.2 `$Nodes`: a count, then `tag x y z` lines.
    fn nodes_2(&mut self, nodes: &mut GmshNodes) -> Result<(), IoError> {
        let file = self.file;
        let (line, text) = self.data_line("Nodes", || "the node count".to_owned())?;
        let count: usize = parse(file, line, Some(text), "the node count")?;
        for k in 0..count {
            let (line, text) =
                self.data_line("Nodes", || format!("node {} of {count} (`tag x y z`)", k + 1))?;
            let mut f = text.split_ascii_whitespace();
            let tag: u64 = parse(file, line, f.next(), "a node tag")?;
            let p = [
                parse(file, line, f.next(), "an x coordinate")?,
                parse(file, line, f.next(), "a y coordinate")?,
                parse(file, line, f.next(), "a z coordinate")?,
            ];
            nodes.add(file, tag, p, line)?;
        }
        self.end("Nodes")
    }

    /// MSH 4.1 `$Nodes`: a header, then blocks of node tags followed by their coordinates.
    fn nodes_41(&mut self, nodes: &mut GmshNodes) -> Result<(), IoError> {
        let file = self.file;
        let (header_line, text) = self.data_line("Nodes", || {
            "the line `numEntityBlocks numNodes minNodeTag maxNodeTag`".to_owned()
        })?;
        let mut f = text.split_ascii_whitespace();
        let blocks: usize = parse(file, header_line, f.next(), "the number of node blocks")?;
        let total: usize = parse(file, header_line, f.next(), "the number of nodes")?;
        let before = nodes.coords.len();
        for b in 1..=blocks {
            let (line, text) = self.data_line("Nodes", || {
                format!(
                    "the header of node block {b} of {blocks} \
                     (`entityDim entityTag parametric numNodesInBlock`)"
                )
            })?;
            let mut f = text.split_ascii_whitespace();
            let _dim: u32 = parse(file, line, f.next(), "the entity dimension")?;
            let _entity: i64 = parse(file, line, f.next(), "the entity tag")?;
            let _parametric: u32 = parse(file, line, f.next(), "the parametric flag")?;
            let count: usize = parse(file, line, f.next(), "the number of nodes in the block")?;
            let mut tags = Vec::new();
            for k in 1..=count {
                let (line, text) = self.data_line("Nodes", || {
                    format!("the tag of node {k} of {count} in block {b}")
                })?;
                tags.push(parse::<u64>(file, line, Some(text), "a node tag")?);
            }
            for (k, &tag) in tags.iter().enumerate() {
                let (line, text) = self.data_line("Nodes", || {
                    format!("the coordinates of node {} of {count} in block {b}", k + 1)
                })?;
                let mut f = text.split_ascii_whitespace();
                let p = [
                    parse(file, line, f.next(), "an x coordinate")?,
                    parse(file, line, f.next(), "a y coordinate")?,
                    parse(file, line, f.next(), "a z coordinate")?,
                ];
                nodes.add(file, tag, p, line)?;
            }
        }
        let read = nodes.coords.len() - before;
        if read != total {
            return Err(syntax(
                file,
                header_line,
                format!("$Nodes announces {total} nodes, its blocks hold {read}"),
            ));
        }
        self.end("Nodes")
    }

    /// Reads the four node tags that end a tetrahedron's line.
    fn tet_nodes<'t>(
        &self,
        line: usize,
        tag: u64,
        mut f: impl Iterator<Item = &'t str>,
    ) -> Result<[u64; 4], IoError> {
        let file = self.file;
        let nodes = [
            parse(file, line, f.next(), "a node tag of the tetrahedron")?,
            parse(file, line, f.next(), "a node tag of the tetrahedron")?,
            parse(file, line, f.next(), "a node tag of the tetrahedron")?,
            parse(file, line, f.next(), "a node tag of the tetrahedron")?,
        ];
        if f.next().is_some() {
            return Err(syntax(
                file,
                line,
                format!("element {tag} has type 4 (tetrahedron) but more than 4 nodes"),
            ));
        }
        Ok(nodes)
    }

    /// MSH 2.2 `$Elements`: a count, then `tag type numTags tags… nodes…` lines.
    fn elements_2(&mut self, tets: &mut Vec<GmshTet>) -> Result<(), IoError> {
        let file = self.file;
        let (line, text) = self.data_line("Elements", || "the element count".to_owned())?;
        let count: usize = parse(file, line, Some(text), "the element count")?;
        for k in 1..=count {
            let (line, text) = self.data_line("Elements", || {
                format!("element {k} of {count} (`tag type numTags tags… nodes…`)")
            })?;
            let mut f = text.split_ascii_whitespace();
            let tag: u64 = parse(file, line, f.next(), "an element tag")?;
            let kind: u64 = parse(file, line, f.next(), "an element type")?;
            if kind != GMSH_TETRAHEDRON {
                continue;
            }
            let tag_count: usize = parse(file, line, f.next(), "the number of tags")?;
            let mut label = i64::from(DEFAULT_REGION);
            for i in 0..tag_count {
                let value: i64 = parse(file, line, f.next(), "an element tag")?;
                if i == 0 {
                    label = value;
                }
            }
            let nodes = self.tet_nodes(line, tag, f)?;
            tets.push(GmshTet { tag, line, nodes, label, entity: false });
        }
        self.end("Elements")
    }

    /// MSH 4.1 `$Elements`: a header, then blocks of elements of one type and entity.
    fn elements_41(&mut self, tets: &mut Vec<GmshTet>) -> Result<(), IoError> {
        let file = self.file;
        let (header_line, text) = self.data_line("Elements", || {
            "the line `numEntityBlocks numElements minElementTag maxElementTag`".to_owned()
        })?;
        let mut f = text.split_ascii_whitespace();
        let blocks: usize = parse(file, header_line, f.next(), "the number of element blocks")?;
        let total: usize = parse(file, header_line, f.next(), "the number of elements")?;
        let mut read = 0usize;
        for b in 1..=blocks {
            let (line, text) = self.data_line("Elements", || {
                format!(
                    "the header of element block {b} of {blocks} \
                     (`entityDim entityTag elementType numElementsInBlock`)"
                )
            })?;
            let mut f = text.split_ascii_whitespace();
            let _dim: u32 = parse(file, line, f.next(), "the entity dimension")?;
            let entity: i64 = parse(file, line, f.next(), "the entity tag")?;
            let kind: u64 = parse(file, line, f.next(), "the element type")?;
            let count: usize = parse(file, line, f.next(), "the number of elements in the block")?;
            for k in 1..=count {
                let (line, text) =
                    self.data_line("Elements", || format!("element {k} of {count} in block {b}"))?;
                read += 1;
                if kind != GMSH_TETRAHEDRON {
                    continue;
                }
                let mut f = text.split_ascii_whitespace();
                let tag: u64 = parse(file, line, f.next(), "an element tag")?;
                let nodes = self.tet_nodes(line, tag, f)?;
                tets.push(GmshTet { tag, line, nodes, label: entity, entity: true });
            }
        }
        if read != total {
            return Err(syntax(
                file,
                header_line,
                format!("$Elements announces {total} elements, its blocks hold {read}"),
            ));
        }
        self.end("Elements")
    }

    /// MSH 4.1 `$Entities`: records the first physical tag of each volume that has one.
    fn entities(&mut self, volumes: &mut HashMap<i64, i64>) -> Result<(), IoError> {
        let file = self.file;
        let (line, text) = self.data_line("Entities", || {
            "the line `numPoints numCurves numSurfaces numVolumes`".to_owned()
        })?;
        let mut f = text.split_ascii_whitespace();
        let mut counts = [0usize; 4];
        for (count, what) in counts.iter_mut().zip(["points", "curves", "surfaces", "volumes"]) {
            *count = parse(file, line, f.next(), &format!("the number of {what}"))?;
        }
        for (count, what) in counts[..3].iter().zip(["point", "curve", "surface"]) {
            for k in 1..=*count {
                self.data_line("Entities", || format!("{what} entity {k} of {count}"))?;
            }
        }
        let count = counts[3];
        for k in 1..=count {
            let (line, text) =
                self.data_line("Entities", || format!("volume entity {k} of {count}"))?;
            let mut f = text.split_ascii_whitespace();
            let tag: i64 = parse(file, line, f.next(), "a volume tag")?;
            for what in ["minX", "minY", "minZ", "maxX", "maxY", "maxZ"] {
                let _: f64 = parse(file, line, f.next(), what)?;
            }
            let physicals: usize = parse(file, line, f.next(), "the number of physical tags")?;
            if physicals > 0 {
                let physical: i64 = parse(file, line, f.next(), "a physical tag")?;
                volumes.insert(tag, physical);
            }
        }
        self.end("Entities")
    }
}

/// Encodes `mesh` as Gmsh ASCII MSH 2.2: node tags from 1, each tetrahedron's physical and
/// elementary tags both its region. Coordinates print as the shortest decimals that read back
/// bit-identical.
#[must_use]
pub fn encode_gmsh22(mesh: &TetMesh) -> String {
    let mut out = String::from("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n");
    let _ = writeln!(out, "{}", mesh.vertices().len());
    for (i, [x, y, z]) in mesh.vertices().iter().enumerate() {
        let _ = writeln!(out, "{} {x:?} {y:?} {z:?}", i + 1);
    }
    let _ = write!(out, "$EndNodes\n$Elements\n{}\n", mesh.tets().len());
    for (e, (t, r)) in mesh.tets().iter().zip(mesh.regions()).enumerate() {
        let [a, b, c, d] = t.map(|i| u64::from(i) + 1);
        let _ = writeln!(out, "{} 4 2 {r} {r} {a} {b} {c} {d}", e + 1);
    }
    out.push_str("$EndElements\n");
    out
}

// ------------------------------------------------------------------------------------------------
// Legacy VTK

/// Where the attribute arrays being read belong.
#[derive(Clone, Copy, Debug)]
enum Attach {
    None,
    /// `POINT_DATA n`.
    Points(usize),
    /// `CELL_DATA n`.
    Cells(usize),
}

/// A legacy VTK file being read, token by token.
struct Vtk<'a> {
    file: &'a str,
    tokens: Tokens<'a>,
}

impl<'a> Vtk<'a> {
    fn token(&mut self, what: impl FnOnce() -> String) -> Result<(&'a str, usize), IoError> {
        let line = self.tokens.line;
        self.tokens
            .next()
            .ok_or_else(|| syntax(self.file, line, format!("the file ends before {}", what())))
    }

    fn value<T: FromStr>(&mut self, what: impl Fn() -> String) -> Result<(T, usize), IoError> {
        let (token, line) = self.token(&what)?;
        match token.parse() {
            Ok(v) => Ok((v, line)),
            Err(_) => {
                Err(syntax(self.file, line, format!("expected {}, found {}", what(), shown(token))))
            }
        }
    }

    /// Consumes `keyword` (any letter case), or errors.
    fn keyword(&mut self, keyword: &str, after: &str) -> Result<(), IoError> {
        let (token, line) = self.token(|| format!("{keyword} (after {after})"))?;
        if token.eq_ignore_ascii_case(keyword) {
            Ok(())
        } else {
            Err(syntax(
                self.file,
                line,
                format!("expected {keyword} after {after}, found {}", shown(token)),
            ))
        }
    }

    /// `POINTS n type` (after the keyword) and its `3n` coordinates.
    fn points(&mut self) -> Result<(Vec<[f64; 3]>, Vec<usize>), IoError> {
        let (count, _) = self.value::<usize>(|| "the number of POINTS".to_owned())?;
        self.token(|| "the data type of POINTS".to_owned())?;
        let (mut coords, mut lines) = (Vec::new(), Vec::new());
        for i in 0..count {
            let mut p = [0.0; 3];
            let mut first_line = 0;
            for (a, c) in p.iter_mut().enumerate() {
                let (v, line) = self.value(|| format!("coordinate {a} of point {i} of {count}"))?;
                *c = v;
                if a == 0 {
                    first_line = line;
                }
            }
            coords.push(p);
            lines.push(first_line);
        }
        Ok((coords, lines))
    }

    /// `CELLS` (after the keyword): the classic `CELLS n size` with `k i1 … ik` per cell, or the
    /// VTK 5 `CELLS nOffsets nConnectivity` with `OFFSETS` and `CONNECTIVITY` arrays.
    fn cells(&mut self) -> Result<CellBlock, IoError> {
        let file = self.file;
        let (a, header) = self.value::<usize>(|| "the number of CELLS".to_owned())?;
        let (b, _) = self.value::<usize>(|| "the size of CELLS".to_owned())?;
        let mut starts = vec![0usize];
        let mut lines = Vec::new();
        let mut connectivity = Vec::new();
        if self.tokens.peek().is_some_and(|t| t.eq_ignore_ascii_case("OFFSETS")) {
            self.tokens.next();
            self.token(|| "the data type of OFFSETS".to_owned())?;
            for k in 0..a {
                let (offset, line) =
                    self.value::<usize>(|| format!("offset {k} of {a} (a non-negative integer)"))?;
                let last = starts.last().copied().unwrap_or_default();
                if k == 0 && offset != 0 {
                    return Err(syntax(file, line, format!("the first offset is {offset}, not 0")));
                }
                if offset < last || offset > b {
                    return Err(syntax(
                        file,
                        line,
                        format!(
                            "offset {k} is {offset}: offsets must not decrease and must stay \
                             within the {b} connectivity entries"
                        ),
                    ));
                }
                if k > 0 {
                    starts.push(offset);
                }
                // Offset `k` starts cell `k`; its line stands for the cell's.
                lines.push(line);
            }
            // The last offset ends the last cell and starts none.
            lines.pop();
            if a > 0 && starts.last() != Some(&b) {
                return Err(syntax(
                    file,
                    header,
                    format!(
                        "the last offset is {}, CELLS announces {b} connectivity entries",
                        starts.last().copied().unwrap_or_default()
                    ),
                ));
            }
            self.keyword("CONNECTIVITY", "the OFFSETS of CELLS")?;
            self.token(|| "the data type of CONNECTIVITY".to_owned())?;
            for k in 0..b {
                let (index, _) = self.value::<i64>(|| format!("connectivity entry {k} of {b}"))?;
                connectivity.push(index);
            }
        } else {
            for k in 0..a {
                let (n, line) =
                    self.value::<usize>(|| format!("the point count of cell {k} of {a}"))?;
                let used = connectivity.len() + k + 1;
                if n > b.saturating_sub(used) {
                    return Err(syntax(
                        file,
                        line,
                        format!("cell {k} runs past the size {b} that CELLS announces"),
                    ));
                }
                for j in 0..n {
                    let (index, _) = self.value::<i64>(|| format!("point {j} of cell {k}"))?;
                    connectivity.push(index);
                }
                starts.push(connectivity.len());
                lines.push(line);
            }
            if connectivity.len() + a != b {
                return Err(syntax(
                    file,
                    header,
                    format!("CELLS announces size {b}, its cells hold {}", connectivity.len() + a),
                ));
            }
        }
        Ok(CellBlock { starts, connectivity, lines, types: Vec::new(), labels: None })
    }

    /// Reads `count` values: as labels when `keep`, else only consumed.
    fn array(&mut self, count: usize, keep: bool, name: &str) -> Result<Option<Labels>, IoError> {
        if !keep {
            for k in 0..count {
                self.token(|| format!("value {k} of {count} of array {name}"))?;
            }
            return Ok(None);
        }
        let mut labels = Labels::default();
        for k in 0..count {
            let (v, line) =
                self.value::<i64>(|| format!("integer {k} of {count} of array {name}"))?;
            labels.values.push(v);
            labels.lines.push(line);
        }
        Ok(Some(labels))
    }

    /// `SCALARS name type [numComp]` (after the keyword), its `LOOKUP_TABLE` line and its values.
    fn scalars(&mut self, attach: Attach, found: &mut Option<Labels>) -> Result<(), IoError> {
        let (name, line) = self.token(|| "the name of a SCALARS array".to_owned())?;
        let (kind, _) = self.token(|| format!("the data type of SCALARS {name}"))?;
        let mut components = 1usize;
        if self.tokens.peek().is_some_and(|t| t.eq_ignore_ascii_case("LOOKUP_TABLE")) {
            self.tokens.next();
        } else {
            (components, _) =
                self.value(|| format!("the component count or LOOKUP_TABLE of SCALARS {name}"))?;
            self.keyword("LOOKUP_TABLE", &format!("SCALARS {name}"))?;
        }
        self.token(|| format!("the lookup table name of SCALARS {name}"))?;
        let tuples = match attach {
            Attach::Points(n) | Attach::Cells(n) => n,
            Attach::None => {
                return Err(syntax(
                    self.file,
                    line,
                    format!("SCALARS {name} is outside POINT_DATA and CELL_DATA"),
                ));
            }
        };
        let count = tuples.checked_mul(components).ok_or_else(|| {
            syntax(self.file, line, format!("SCALARS {name} announces too many values"))
        })?;
        let keep = matches!(attach, Attach::Cells(_))
            && components == 1
            && is_integer_type(kind)
            && found.is_none();
        if let Some(labels) = self.array(count, keep, name)? {
            *found = Some(labels);
        }
        Ok(())
    }

    /// `FIELD name numArrays` (after the keyword) and its arrays.
    fn field(&mut self, attach: Attach, found: &mut Option<Labels>) -> Result<(), IoError> {
        let (name, _) = self.token(|| "the name of a FIELD".to_owned())?;
        let (arrays, _) =
            self.value::<usize>(|| format!("the number of arrays of FIELD {name}"))?;
        for k in 0..arrays {
            let (array, line) =
                self.token(|| format!("the name of array {k} of {arrays} of FIELD {name}"))?;
            let (components, _) =
                self.value::<usize>(|| format!("the component count of array {array}"))?;
            let (tuples, _) =
                self.value::<usize>(|| format!("the tuple count of array {array}"))?;
            let (kind, _) = self.token(|| format!("the data type of array {array}"))?;
            let count = components.checked_mul(tuples).ok_or_else(|| {
                syntax(self.file, line, format!("array {array} announces too many values"))
            })?;
            let keep = matches!(attach, Attach::Cells(n) if n == tuples)
                && components == 1
                && is_integer_type(kind)
                && found.is_none();
            if let Some(labels) = self.array(count, keep, array)? {
                *found = Some(labels);
            }
            if self.tokens.peek().is_some_and(|t| t.eq_ignore_ascii_case("METADATA")) {
                self.tokens.next();
                self.tokens.skip_past_blank_line();
            }
        }
        Ok(())
    }
}

/// Checks the three header lines of a legacy VTK file and returns the text after them.
fn vtk_header<'a>(text: &'a str, file: &str) -> Result<&'a str, IoError> {
    let mut rest = text;
    let mut lines = [""; 3];
    for (i, slot) in lines.iter_mut().enumerate() {
        let Some((line, after)) = rest.split_once('\n') else {
            return Err(syntax(
                file,
                i + 1,
                "the file ends inside the header (version line, title, ASCII or BINARY)",
            ));
        };
        *slot = line.trim();
        rest = after;
    }
    if !lines[0].get(..14).is_some_and(|s| s.eq_ignore_ascii_case("# vtk DataFile")) {
        return Err(syntax(
            file,
            1,
            format!(
                "expected \"# vtk DataFile Version …\" (a legacy VTK file), found {}",
                shown(lines[0])
            ),
        ));
    }
    if lines[2].eq_ignore_ascii_case("BINARY") {
        return Err(IoError::UnsupportedType {
            file: file.to_owned(),
            what: "binary legacy VTK is not supported, save as ASCII".to_owned(),
        });
    }
    if !lines[2].eq_ignore_ascii_case("ASCII") {
        return Err(syntax(
            file,
            3,
            format!("expected ASCII or BINARY, found {}", shown(lines[2])),
        ));
    }
    Ok(rest)
}

/// Decodes an ASCII legacy VTK `DATASET UNSTRUCTURED_GRID` (classic or VTK 5 cell layout).
/// `name` names the text in errors.
pub fn decode_vtk_legacy(text: &str, name: &str) -> Result<TetMesh, IoError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let body = vtk_header(text, name)?;
    let mut r = Vtk { file: name, tokens: Tokens::new(body, 4) };
    r.keyword("DATASET", "the header")?;
    let (kind, _) = r.token(|| "the DATASET type".to_owned())?;
    if !kind.eq_ignore_ascii_case("UNSTRUCTURED_GRID") {
        return Err(IoError::UnsupportedType {
            file: name.to_owned(),
            what: format!("DATASET {kind}; this reader takes UNSTRUCTURED_GRID"),
        });
    }
    let mut points = None;
    let mut cells: Option<CellBlock> = None;
    let mut types: Option<(Vec<i64>, usize)> = None;
    let mut cell_data: Option<(usize, usize)> = None;
    let mut attach = Attach::None;
    let (mut scalars, mut field) = (None, None);
    let twice =
        |line: usize, section: &str| Err(syntax(name, line, format!("a second {section} section")));
    while let Some((token, line)) = r.tokens.next() {
        let is = |keyword: &str| token.eq_ignore_ascii_case(keyword);
        if is("POINTS") {
            if points.is_some() {
                return twice(line, "POINTS");
            }
            points = Some(r.points()?);
        } else if is("CELLS") {
            if cells.is_some() {
                return twice(line, "CELLS");
            }
            cells = Some(r.cells()?);
        } else if is("CELL_TYPES") {
            if types.is_some() {
                return twice(line, "CELL_TYPES");
            }
            let (count, _) = r.value::<usize>(|| "the number of CELL_TYPES".to_owned())?;
            let mut values = Vec::new();
            for k in 0..count {
                values.push(r.value::<i64>(|| format!("cell type {k} of {count}"))?.0);
            }
            types = Some((values, line));
        } else if is("POINT_DATA") {
            attach = Attach::Points(r.value(|| "the number of POINT_DATA values".to_owned())?.0);
        } else if is("CELL_DATA") {
            if cell_data.is_some() {
                return twice(line, "CELL_DATA");
            }
            let (count, _) = r.value(|| "the number of CELL_DATA values".to_owned())?;
            attach = Attach::Cells(count);
            cell_data = Some((count, line));
        } else if is("SCALARS") {
            r.scalars(attach, &mut scalars)?;
        } else if is("FIELD") {
            r.field(attach, &mut field)?;
        } else if is("METADATA") {
            r.tokens.skip_past_blank_line();
        }
        // Anything else (VECTORS, NORMALS, LOOKUP_TABLE, their values) is skipped token by
        // token: none of it is a keyword above.
    }
    let end = r.tokens.line;
    let missing = |section: &str| syntax(name, end, format!("the file has no {section} section"));
    let (coords, point_lines) = points.ok_or_else(|| missing("POINTS"))?;
    let mut block = cells.ok_or_else(|| missing("CELLS"))?;
    let (types, types_line) = types.ok_or_else(|| missing("CELL_TYPES"))?;
    let cell_count = block.lines.len();
    if types.len() != cell_count {
        return Err(syntax(
            name,
            types_line,
            format!("CELL_TYPES has {} entries for {cell_count} cells", types.len()),
        ));
    }
    if let Some((count, line)) = cell_data
        && count != cell_count
    {
        return Err(syntax(
            name,
            line,
            format!("CELL_DATA announces {count} values for {cell_count} cells"),
        ));
    }
    block.types = types;
    block.labels = scalars.or(field);

    let mut mesh = Assembly::new("point", "cell");
    block.append_tets(name, coords.len(), 0, 0, &mut mesh)?;
    mesh.vertex_origins =
        point_lines.iter().enumerate().map(|(i, &line)| Origin { id: i as u64, line }).collect();
    mesh.vertices = coords;
    mesh.finish(name)
}

/// The region labels' VTK type: `int` when every label fits, else `unsigned_int`.
fn region_type_fits_i32(mesh: &TetMesh) -> bool {
    mesh.regions().iter().all(|&r| i32::try_from(r).is_ok())
}

/// Encodes `mesh` as an ASCII legacy VTK unstructured grid (classic cell layout) with the
/// regions as the `int` cell scalars `region`.
#[must_use]
pub fn encode_vtk_legacy(mesh: &TetMesh) -> String {
    let (v, t) = (mesh.vertices().len(), mesh.tets().len());
    let mut out = format!(
        "# vtk DataFile Version 3.0\nincise tetrahedral mesh\nASCII\nDATASET UNSTRUCTURED_GRID\n\
         POINTS {v} double\n"
    );
    for [x, y, z] in mesh.vertices() {
        let _ = writeln!(out, "{x:?} {y:?} {z:?}");
    }
    let _ = writeln!(out, "CELLS {t} {}", 5 * t);
    for [a, b, c, d] in mesh.tets() {
        let _ = writeln!(out, "4 {a} {b} {c} {d}");
    }
    let _ = writeln!(out, "CELL_TYPES {t}");
    for _ in 0..t {
        out.push_str("10\n");
    }
    let kind = if region_type_fits_i32(mesh) { "int" } else { "unsigned_int" };
    let _ = write!(out, "CELL_DATA {t}\nSCALARS region {kind} 1\nLOOKUP_TABLE default\n");
    for r in mesh.regions() {
        let _ = writeln!(out, "{r}");
    }
    out
}

// ------------------------------------------------------------------------------------------------
// VTK XML

/// One piece of XML markup.
#[derive(Debug)]
enum Markup<'a> {
    /// `<name attrs>` or, when `empty`, `<name attrs/>`.
    Open { name: &'a str, attrs: &'a str, empty: bool },
    /// `</name>`.
    Close(&'a str),
    /// Text between tags (or a CDATA section's content).
    Text(&'a str),
}

/// A tolerant XML scanner: tags, their attributes and the text between them; declarations,
/// comments, processing instructions and `DOCTYPE` are skipped, entities are not expanded.
struct Xml<'a> {
    file: &'a str,
    text: &'a str,
    pos: usize,
    line: usize,
}

impl<'a> Xml<'a> {
    /// Moves to byte `to`, counting lines.
    fn advance(&mut self, to: usize) {
        let to = to.min(self.text.len());
        // Every position handed here is a character boundary: the end of the text, or next to
        // an ASCII `<`, `>` or the start of a found needle.
        self.line += self.text.get(self.pos..to).map_or(0, |s| s.matches('\n').count());
        self.pos = to;
    }

    /// Skips to just before `needle` (raw appended data, which may hold any bytes).
    fn skip_to(&mut self, needle: &str) -> Result<(), IoError> {
        let (file, text, line) = (self.file, self.text, self.line);
        let at = text[self.pos..]
            .find(needle)
            .ok_or_else(|| syntax(file, line, format!("the file ends before {needle}")))?;
        self.advance(self.pos + at);
        Ok(())
    }

    /// The next piece of markup and the line it starts on.
    fn next(&mut self) -> Result<Option<(Markup<'a>, usize)>, IoError> {
        let (file, text) = (self.file, self.text);
        loop {
            let rest = &text[self.pos..];
            let line = self.line;
            if rest.is_empty() {
                return Ok(None);
            }
            if !rest.starts_with('<') {
                let end = rest.find('<').unwrap_or(rest.len());
                self.advance(self.pos + end);
                return Ok(Some((Markup::Text(&rest[..end]), line)));
            }
            let unclosed = |what: &str| syntax(file, line, format!("{what} is not closed"));
            if let Some(inner) = rest.strip_prefix("<![CDATA[") {
                let end = inner.find("]]>").ok_or_else(|| unclosed("a CDATA section"))?;
                self.advance(self.pos + 9 + end + 3);
                return Ok(Some((Markup::Text(&inner[..end]), line)));
            }
            let skipped = [("<?", "?>"), ("<!--", "-->"), ("<!", ">")]
                .into_iter()
                .find(|(open, _)| rest.starts_with(open));
            if let Some((open, close)) = skipped {
                let end = rest[open.len()..].find(close).ok_or_else(|| unclosed(open))?;
                self.advance(self.pos + open.len() + end + close.len());
                continue;
            }
            // A tag: up to the first `>` outside quotes.
            let bytes = rest.as_bytes();
            let mut quote = None;
            let mut end = None;
            for (i, &b) in bytes.iter().enumerate().skip(1) {
                match (quote, b) {
                    (None, b'"' | b'\'') => quote = Some(b),
                    (Some(q), _) if b == q => quote = None,
                    (None, b'>') => {
                        end = Some(i);
                        break;
                    }
                    _ => {}
                }
            }
            let end = end.ok_or_else(|| unclosed("a tag"))?;
            let inner = &rest[1..end];
            self.advance(self.pos + end + 1);
            if let Some(name) = inner.strip_prefix('/') {
                return Ok(Some((Markup::Close(name.trim()), line)));
            }
            let (inner, empty) = match inner.strip_suffix('/') {
                Some(inner) => (inner, true),
                None => (inner, false),
            };
            let name_end = inner.find(|c: char| c.is_ascii_whitespace()).unwrap_or(inner.len());
            let name = &inner[..name_end];
            if name.is_empty() {
                return Err(syntax(file, line, "a tag without a name"));
            }
            return Ok(Some((Markup::Open { name, attrs: &inner[name_end..], empty }, line)));
        }
    }
}

/// The value of attribute `key` in a tag's attribute text.
fn attr<'a>(attrs: &'a str, key: &str) -> Option<&'a str> {
    let mut rest = attrs;
    loop {
        let (k, after) = rest.split_once('=')?;
        let after = after.trim_start();
        let quote = after.chars().next().filter(|&q| q == '"' || q == '\'')?;
        let value_and_rest = &after[1..];
        let close = value_and_rest.find(quote)?;
        if k.trim() == key {
            return Some(&value_and_rest[..close]);
        }
        rest = &value_and_rest[close + 1..];
    }
}

/// What a `DataArray` of a piece holds, as far as this reader cares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Points,
    Connectivity,
    Offsets,
    Types,
    /// An integer cell array, a region label candidate; `preferred` when `CellData Scalars`
    /// names it.
    Labels {
        preferred: bool,
    },
}

/// A `DataArray` being read: its role, where it starts, and its text.
struct DataArray<'a> {
    role: Role,
    name: &'a str,
    /// Open elements outside it.
    depth: usize,
    line: usize,
    text: Vec<(&'a str, usize)>,
}

/// A `Piece` being read.
#[derive(Default)]
struct Piece<'a> {
    line: usize,
    points: usize,
    cells: usize,
    /// The array `CellData Scalars="…"` names.
    scalars: Option<&'a str>,
    coords: Option<(Vec<[f64; 3]>, Vec<usize>)>,
    connectivity: Option<Vec<i64>>,
    offsets: Option<Labels>,
    types: Option<Vec<i64>>,
    labels: Option<(Labels, bool)>,
}

/// Decodes an ASCII VTK XML `UnstructuredGrid` (`.vtu`), all pieces. `name` names the text in
/// errors.
pub fn decode_vtu(text: &str, name: &str) -> Result<TetMesh, IoError> {
    let mut xml = Xml { file: name, text, pos: 0, line: 1 };
    let mut stack: Vec<&str> = Vec::new();
    let mut mesh = Assembly::new("point", "cell");
    let mut cells_so_far = 0usize;
    let mut pieces = 0usize;
    let mut piece: Option<Piece> = None;
    let mut array: Option<DataArray> = None;
    while let Some((markup, line)) = xml.next()? {
        match markup {
            Markup::Open { name: tag, attrs, empty } => {
                let parent = stack.last().copied();
                match (parent, tag) {
                    (None, "VTKFile") => match attr(attrs, "type") {
                        Some("UnstructuredGrid") | None => {}
                        Some(other) => {
                            return Err(IoError::UnsupportedType {
                                file: name.to_owned(),
                                what: format!(
                                    "VTKFile type=\"{other}\"; this reader takes UnstructuredGrid"
                                ),
                            });
                        }
                    },
                    (None, _) => {
                        return Err(syntax(
                            name,
                            line,
                            format!("expected <VTKFile> (a VTK XML file), found <{tag}>"),
                        ));
                    }
                    (Some("UnstructuredGrid"), "Piece") => {
                        let count = |key: &str| -> Result<usize, IoError> {
                            let value = attr(attrs, key).ok_or_else(|| {
                                syntax(name, line, format!("<Piece> has no {key}"))
                            })?;
                            value.trim().parse().map_err(|_| {
                                syntax(name, line, format!("{key}={} is not a count", shown(value)))
                            })
                        };
                        piece = Some(Piece {
                            line,
                            points: count("NumberOfPoints")?,
                            cells: count("NumberOfCells")?,
                            ..Piece::default()
                        });
                    }
                    (Some("Piece"), "CellData") => {
                        if let Some(p) = &mut piece {
                            p.scalars = attr(attrs, "Scalars");
                        }
                    }
                    (Some(parent), "DataArray") if array.is_none() => {
                        let role = piece.as_ref().and_then(|p| role_of(parent, attrs, p));
                        if let Some(role) = role {
                            check_ascii(name, line, attrs)?;
                            let a = DataArray {
                                role,
                                name: attr(attrs, "Name").unwrap_or(""),
                                depth: stack.len(),
                                line,
                                text: Vec::new(),
                            };
                            if empty {
                                finish_array(name, &a, piece.as_mut())?;
                            } else {
                                array = Some(a);
                            }
                        }
                    }
                    (_, "AppendedData") if !empty => xml.skip_to("</AppendedData")?,
                    _ => {}
                }
                if !empty {
                    stack.push(tag);
                }
            }
            Markup::Close(tag) => {
                let Some(open) = stack.pop() else {
                    return Err(syntax(name, line, format!("</{tag}> closes nothing")));
                };
                if open != tag {
                    return Err(syntax(name, line, format!("</{tag}> closes <{open}>")));
                }
                if tag == "DataArray"
                    && let Some(a) = array.take_if(|a| a.depth == stack.len())
                {
                    finish_array(name, &a, piece.as_mut())?;
                }
                if tag == "Piece"
                    && let Some(p) = piece.take()
                {
                    cells_so_far += finish_piece(name, p, cells_so_far, &mut mesh)?;
                    pieces += 1;
                }
            }
            Markup::Text(content) => {
                if let Some(a) = &mut array
                    && stack.len() == a.depth + 1
                {
                    a.text.push((content, line));
                }
            }
        }
    }
    if let Some(open) = stack.last() {
        return Err(syntax(name, xml.line, format!("the file ends inside <{open}>")));
    }
    if pieces == 0 {
        return Err(syntax(name, xml.line, "the file has no <UnstructuredGrid><Piece>"));
    }
    mesh.finish(name)
}

/// What a `DataArray` under `parent` with `attrs` holds, if this reader needs it.
fn role_of(parent: &str, attrs: &str, piece: &Piece) -> Option<Role> {
    match (parent, attr(attrs, "Name")) {
        ("Points", _) if piece.coords.is_none() => Some(Role::Points),
        ("Cells", Some("connectivity")) => Some(Role::Connectivity),
        ("Cells", Some("offsets")) => Some(Role::Offsets),
        ("Cells", Some("types")) => Some(Role::Types),
        ("CellData", name) => {
            let integer = attr(attrs, "type").is_some_and(is_integer_type);
            let single = attr(attrs, "NumberOfComponents").is_none_or(|n| n.trim() == "1");
            let preferred = name.is_some() && name == piece.scalars;
            (integer && single).then_some(Role::Labels { preferred })
        }
        _ => None,
    }
}

/// Refuses a `DataArray` whose data is not inline ASCII.
fn check_ascii(file: &str, line: usize, attrs: &str) -> Result<(), IoError> {
    match attr(attrs, "format") {
        None | Some("ascii") => Ok(()),
        Some(format @ ("binary" | "appended")) => Err(IoError::UnsupportedType {
            file: file.to_owned(),
            what: format!(
                "line {line}: DataArray format=\"{format}\"; only format=\"ascii\" is read, save \
                 as ASCII"
            ),
        }),
        Some(other) => Err(syntax(
            file,
            line,
            format!("DataArray format={} is not ascii, binary or appended", shown(other)),
        )),
    }
}

/// Parses a finished array's text into its piece.
fn finish_array(file: &str, array: &DataArray, piece: Option<&mut Piece>) -> Result<(), IoError> {
    let Some(piece) = piece else { return Ok(()) };
    let tokens = array.text.iter().flat_map(|&(text, line)| Tokens::new(text, line));
    let label = array.name;
    match array.role {
        Role::Points => {
            let (mut coords, mut lines) = (Vec::new(), Vec::new());
            let mut p = [0.0; 3];
            for (k, (token, line)) in tokens.enumerate() {
                p[k % 3] = parse(file, line, Some(token), "a point coordinate")?;
                if k % 3 == 0 {
                    lines.push(line);
                }
                if k % 3 == 2 {
                    coords.push(p);
                }
            }
            if lines.len() != coords.len() {
                return Err(syntax(
                    file,
                    array.line,
                    "the Points array does not hold whole (x, y, z) triples",
                ));
            }
            piece.coords = Some((coords, lines));
        }
        Role::Connectivity | Role::Offsets | Role::Types | Role::Labels { .. } => {
            let mut values = Labels::default();
            let what = format!("an integer in array {label:?}");
            for (token, line) in tokens {
                values.values.push(parse(file, line, Some(token), &what)?);
                values.lines.push(line);
            }
            match array.role {
                Role::Connectivity => piece.connectivity = Some(values.values),
                Role::Offsets => piece.offsets = Some(values),
                Role::Types => piece.types = Some(values.values),
                Role::Labels { preferred } => {
                    let replace = match &piece.labels {
                        None => true,
                        Some((_, was_preferred)) => preferred && !was_preferred,
                    };
                    if replace {
                        piece.labels = Some((values, preferred));
                    }
                }
                Role::Points => {}
            }
        }
    }
    Ok(())
}

/// Checks a finished piece and adds its points and tetrahedra to `mesh`; returns its cell count.
fn finish_piece(
    file: &str,
    piece: Piece,
    first_cell: usize,
    mesh: &mut Assembly,
) -> Result<usize, IoError> {
    let line = piece.line;
    let (coords, lines) = piece.coords.unwrap_or_default();
    if coords.len() != piece.points {
        return Err(syntax(
            file,
            line,
            format!(
                "<Piece NumberOfPoints=\"{}\"> but its Points array holds {} points",
                piece.points,
                coords.len()
            ),
        ));
    }
    let missing = |name: &str| {
        syntax(file, line, format!("<Piece> has cells but no <Cells><DataArray Name=\"{name}\">"))
    };
    let n = piece.cells;
    let block = if n == 0 {
        CellBlock {
            starts: vec![0],
            connectivity: Vec::new(),
            lines: Vec::new(),
            types: Vec::new(),
            labels: None,
        }
    } else {
        let connectivity = piece.connectivity.ok_or_else(|| missing("connectivity"))?;
        let offsets = piece.offsets.ok_or_else(|| missing("offsets"))?;
        let types = piece.types.ok_or_else(|| missing("types"))?;
        let count_error = |what: &str, found: usize| {
            syntax(
                file,
                line,
                format!("<Piece NumberOfCells=\"{n}\"> but its {what} array holds {found} values"),
            )
        };
        if offsets.values.len() != n {
            return Err(count_error("offsets", offsets.values.len()));
        }
        if types.len() != n {
            return Err(count_error("types", types.len()));
        }
        let labels = match piece.labels {
            Some((labels, _)) if labels.values.len() != n => {
                return Err(count_error("region label", labels.values.len()));
            }
            other => other.map(|(labels, _)| labels),
        };
        let mut starts = vec![0usize];
        for (k, (&offset, &at)) in offsets.values.iter().zip(&offsets.lines).enumerate() {
            let previous = starts.last().copied().unwrap_or_default();
            match usize::try_from(offset) {
                Ok(o) if o >= previous && o <= connectivity.len() => starts.push(o),
                _ => {
                    return Err(syntax(
                        file,
                        at,
                        format!(
                            "offset {k} is {offset}: offsets must not decrease and must stay \
                             within the {} connectivity entries",
                            connectivity.len()
                        ),
                    ));
                }
            }
        }
        CellBlock { starts, connectivity, lines: offsets.lines, types, labels }
    };
    let base = mesh.vertices.len();
    block.append_tets(file, coords.len(), base, first_cell, mesh)?;
    mesh.vertex_origins
        .extend(lines.iter().enumerate().map(|(i, &line)| Origin { id: (base + i) as u64, line }));
    mesh.vertices.extend(coords);
    Ok(n)
}

/// Encodes `mesh` as an ASCII VTK XML unstructured grid with the regions as the cell array
/// `region`.
#[must_use]
pub fn encode_vtu(mesh: &TetMesh) -> String {
    let (v, t) = (mesh.vertices().len(), mesh.tets().len());
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n\
         <VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\">\n\
         <UnstructuredGrid>\n<Piece NumberOfPoints=\"{v}\" NumberOfCells=\"{t}\">\n\
         <Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n"
    );
    for [x, y, z] in mesh.vertices() {
        let _ = writeln!(out, "{x:?} {y:?} {z:?}");
    }
    out.push_str(
        "</DataArray>\n</Points>\n<Cells>\n\
         <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n",
    );
    for [a, b, c, d] in mesh.tets() {
        let _ = writeln!(out, "{a} {b} {c} {d}");
    }
    out.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for k in 1..=t {
        let _ = writeln!(out, "{}", 4 * k);
    }
    out.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in 0..t {
        out.push_str("10\n");
    }
    let kind = if region_type_fits_i32(mesh) { "Int32" } else { "UInt32" };
    let _ = write!(
        out,
        "</DataArray>\n</Cells>\n<CellData Scalars=\"region\">\n\
         <DataArray type=\"{kind}\" Name=\"region\" format=\"ascii\">\n"
    );
    for r in mesh.regions() {
        let _ = writeln!(out, "{r}");
    }
    out.push_str("</DataArray>\n</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use incise_mesh::generate::cylinder;

    /// Five vertices and two tetrahedra sharing the triangle (1, 0, 0), (0, 1, 0), (0, 0, 1);
    /// the files below list the second one inverted.
    const VERTICES: [[f64; 3]; 5] =
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]];
    const TETS: [[u32; 4]; 2] = [[0, 1, 2, 3], [1, 2, 3, 4]];

    const MSH22: &str = "\
$MeshFormat
2.2 0 8
$EndMeshFormat
$PhysicalNames
2
2 5 \"skin\"
3 7 \"liver\"
$EndPhysicalNames
$Nodes
5
10 0 0 0
20 1 0 0
30 0 1 0
40 0 0 1
7 1 1 1
$EndNodes
$Elements
4
1 15 2 0 1 10
2 2 2 5 3 20 30 40
3 4 2 7 1 10 20 30 40
9 4 3 8 2 0 20 30 7 40
$EndElements
";

    const MSH41: &str = "\
$MeshFormat
4.1 0 8
$EndMeshFormat
$Entities
1 0 1 2
1 0 0 0 0
5 0 0 0 1 1 0 1 9 3 1 2 3
3 0 0 0 1 1 1 1 42 1 5
4 0 0 0 1 1 1 0 1 5
$EndEntities
$Nodes
2 5 7 40
3 3 0 4
10
20
30
40
0 0 0
1 0 0
0 1 0
0 0 1
2 5 1 1
7
1 1 1 0.3 0.7
$EndNodes
$Elements
3 3 1 12
2 5 2 1
1 20 30 40
3 3 4 1
5 10 20 30 40
3 4 4 1
12 20 30 7 40
$EndElements
";

    const VTK: &str = "\
# vtk DataFile Version 3.0
two tetrahedra and a triangle
ASCII

DATASET UNSTRUCTURED_GRID
POINTS 5 float
0 0 0  1 0 0  0 1 0
0 0 1  1 1 1
CELLS 3 14
4 0 1 2 3
3 1 2 3
4 1 2 4 3
CELL_TYPES 3
10
5
10
POINT_DATA 5
SCALARS id int
LOOKUP_TABLE default
9 9 9 9 9
CELL_DATA 3
SCALARS quality float 1
LOOKUP_TABLE default
0.5 0.5 0.5
SCALARS region int 1
LOOKUP_TABLE default
3 0 6
";

    const VTK51: &str = "\
# vtk DataFile Version 5.1
vtk output
ASCII
DATASET UNSTRUCTURED_GRID
POINTS 5 double
0 0 0 1 0 0 0 1 0
0 0 1 1 1 1
METADATA
INFORMATION 0

CELLS 4 11
OFFSETS vtktypeint64
0 4 7 11
CONNECTIVITY vtktypeint64
0 1 2 3
1 2 3
1 2 4 3
CELL_TYPES 3
10
5
10

CELL_DATA 3
FIELD FieldData 2
quality 1 3 double
0.5 0.5 0.5
METADATA
INFORMATION 0

gmsh:physical 1 3 int
2 2 5
";

    const VTU: &str = r#"<?xml version="1.0"?>
<!-- written by hand; <Piece> in a comment is no piece -->
<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian">
  <UnstructuredGrid>
    <Piece NumberOfPoints="5" NumberOfCells="3">
      <PointData>
        <DataArray type="Int32" Name="id" format="ascii">1 2 3 4 5</DataArray>
      </PointData>
      <CellData Scalars="tissue">
        <DataArray type="Int32" Name="other" format="ascii">7 7 7</DataArray>
        <DataArray type="Float64" Name="quality" format="ascii">0.5 0.5 0.5</DataArray>
        <DataArray type='Int32' Name='tissue' format='ascii'>
          3 0 6
        </DataArray>
      </CellData>
      <Points>
        <DataArray type="Float32" NumberOfComponents="3" format="ascii">
          <InformationKey name="L2_NORM_RANGE" location="vtkDataArray" length="2">
            <Value index="0">0</Value>
          </InformationKey>
          0 0 0 1 0 0 0 1 0
          0 0 1 1 1 1
        </DataArray>
      </Points>
      <Cells>
        <DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3  1 2 3  1 2 4 3</DataArray>
        <DataArray type="Int64" Name="offsets" format="ascii">4 7 11</DataArray>
        <DataArray type="UInt8" Name="types" format="ascii">10 5 10</DataArray>
      </Cells>
    </Piece>
  </UnstructuredGrid>
</VTKFile>
"#;

    fn expect(mesh: &TetMesh, regions: [u32; 2]) {
        assert_eq!(mesh.vertices(), &VERTICES);
        assert_eq!(mesh.tets(), &TETS, "the second tetrahedron is reordered to positive volume");
        assert_eq!(mesh.regions(), &regions);
    }

    /// The message of the error `decode` gives for `text`, checked to name `name`.
    fn message(
        decode: fn(&str, &str) -> Result<TetMesh, IoError>,
        text: &str,
        name: &str,
    ) -> String {
        let e = decode(text, name).expect_err("the text is invalid");
        assert_eq!(e.file(), name);
        let m = e.to_string();
        assert!(m.starts_with(&format!("{name}: ")), "{m}");
        m
    }

    /// A mesh with regions 1..=3 and one tetrahedron with awkward coordinates, to test that
    /// every bit of every coordinate survives a round trip.
    fn awkward_mesh() -> TetMesh {
        let base = cylinder(0.01, 0.03, 2, 3);
        let mut vertices = base.vertices().to_vec();
        let mut tets = base.tets().to_vec();
        let n = vertices.len() as u32;
        vertices.extend([
            [-0.0, 1.0 / 3.0, 1e-7 + 0.1],
            [0.1 + 0.2, 2.0 / 3.0, 1e-7 + 0.1],
            [-0.0, 1.0, 0.1 + 1e-7],
            [-1e-5, 1.0 / 3.0, 1.0 + 1e-16 * 3.0],
        ]);
        let extra = [n, n + 1, n + 2, n + 3];
        let p = extra.map(|i| vertices[i as usize]);
        tets.push(if signed_volume(&p) > 0.0 { extra } else { [n, n + 1, n + 3, n + 2] });
        let regions = (0..tets.len()).map(|t| (t % 3) as u32 + 1).collect();
        TetMesh::new(vertices, tets, regions).expect("the awkward mesh is valid")
    }

    fn bits(mesh: &TetMesh) -> Vec<[u64; 3]> {
        mesh.vertices().iter().map(|p| p.map(f64::to_bits)).collect()
    }

    #[test]
    fn gmsh22_skips_other_elements_and_maps_node_tags() {
        expect(&decode_gmsh(MSH22, "a.msh").unwrap(), [7, 8]);
        // Windows line ends and a byte-order mark change nothing.
        let windows = format!("\u{feff}{}", MSH22.replace('\n', "\r\n"));
        expect(&decode_gmsh(&windows, "a.msh").unwrap(), [7, 8]);
        // An element without tags gets the default region.
        let untagged = MSH22.replace("3 4 2 7 1 10 20 30 40", "3 4 0 10 20 30 40");
        expect(&decode_gmsh(&untagged, "a.msh").unwrap(), [1, 8]);
    }

    #[test]
    fn gmsh41_maps_entities_to_physical_tags() {
        // Volume 3 has physical tag 42; volume 4 has none, so its entity tag is the region.
        expect(&decode_gmsh(MSH41, "b.msh").unwrap(), [42, 4]);
        // Without $Entities every region is the entity tag.
        let start = MSH41.find("$Entities").unwrap();
        let end = MSH41.find("$Nodes").unwrap();
        let bare = format!("{}{}", &MSH41[..start], &MSH41[end..]);
        expect(&decode_gmsh(&bare, "b.msh").unwrap(), [3, 4]);
    }

    #[test]
    fn gmsh_errors_name_the_line_and_element() {
        let m = message(decode_gmsh, &MSH22.replace("1 10 20 30 40", "1 10 20 30 99"), "c.msh");
        assert!(m.contains("line 21") && m.contains("element 3") && m.contains("node 99"), "{m}");
        let m = message(decode_gmsh, &MSH41.replace("5 10 20 30 40", "5 10 20 30 41"), "c.msh");
        assert!(m.contains("line 31") && m.contains("element 5") && m.contains("node 41"), "{m}");
        let twice = MSH22.replace("7 1 1 1", "20 1 1 1");
        let m = message(decode_gmsh, &twice, "c.msh");
        assert!(
            m.contains("line 15") && m.contains("node 20 is defined twice (first on line 12)"),
            "{m}"
        );
        // A tetrahedron flattened into a plane: the mesh check names the element and its line.
        let flat = MSH22.replace("7 1 1 1", "7 0.5 0.5 0");
        let e = decode_gmsh(&flat, "c.msh").unwrap_err();
        assert!(matches!(e, IoError::Mesh { source: TetMeshError::Degenerate { tet: 1, .. }, .. }));
        let m = e.to_string();
        assert!(m.starts_with("c.msh: line 22: element 9: tetrahedron 1"), "{m}");
        let m = message(decode_gmsh, &MSH22.replace("7 1 1 1", "7 1 nan 1"), "c.msh");
        assert!(m.starts_with("c.msh: line 15: node 7: vertex 4 has a non-finite"), "{m}");
        let m = message(decode_gmsh, &MSH22.replace("20 1 0 0", "20 1 zero 0"), "c.msh");
        assert!(m.contains("line 12") && m.contains("\"zero\""), "{m}");
        let m = message(decode_gmsh, &MSH41.replace("3 3 1 12", "3 4 1 12"), "c.msh");
        assert!(m.contains("announces 4 elements, its blocks hold 3"), "{m}");
    }

    #[test]
    fn gmsh_binary_and_other_versions_are_refused() {
        let binary = "$MeshFormat\n4.1 1 8\n\u{1}\0\0\0\n$EndMeshFormat\n";
        let e = decode_gmsh(binary, "bin.msh").unwrap_err();
        assert!(matches!(e, IoError::UnsupportedType { .. }));
        assert!(e.to_string().contains("binary MSH is not supported, save as ASCII"), "{e}");
        let m = message(decode_gmsh, &MSH41.replace("4.1 0 8", "4.0 0 8"), "old.msh");
        assert!(m.contains("MSH version 4.0"), "{m}");
        let m = message(decode_gmsh, "solid cube\n", "cube.msh");
        assert!(m.contains("line 1") && m.contains("$MeshFormat"), "{m}");
        message(decode_gmsh, "", "empty.msh");
    }

    #[test]
    fn gmsh_truncated_files_are_errors() {
        for text in [MSH22, MSH41] {
            let lines: Vec<&str> = text.lines().collect();
            for keep in 0..lines.len() {
                let cut = lines[..keep].join("\n");
                assert!(decode_gmsh(&cut, "cut.msh").is_err(), "{keep} lines: {cut}");
            }
        }
    }

    #[test]
    fn huge_counts_end_in_errors_not_allocations() {
        let nodes =
            "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1000000000000\n1 0 0 0\n$EndNodes\n";
        let m = message(decode_gmsh, nodes, "big.msh");
        assert!(m.contains("line 7") && m.contains("node 2 of 1000000000000"), "{m}");
        let blocks = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n\
                      1 1000000000000 1 1000000000000\n3 1 0 1000000000000\n1\n$EndNodes\n";
        message(decode_gmsh, blocks, "big.msh");
        let elements = MSH22.replace("$Elements\n4\n", "$Elements\n18446744073709551615\n");
        message(decode_gmsh, &elements, "big.msh");
        let points = VTK.replace("POINTS 5 float", "POINTS 1000000000000 float");
        let m = message(decode_vtk_legacy, &points, "big.vtk");
        assert!(m.contains("line 9") && m.contains("point 5 of 1000000000000"), "{m}");
        let cells = VTK.replace("CELLS 3 14", "CELLS 1000000000000 1000000000000");
        message(decode_vtk_legacy, &cells, "big.vtk");
        let tags = MSH22.replace("3 4 2 7 1", "3 4 1000000000000 7 1");
        message(decode_gmsh, &tags, "big.msh");
        let vtu = VTU.replace("NumberOfPoints=\"5\"", "NumberOfPoints=\"1000000000000\"");
        let m = message(decode_vtu, &vtu, "big.vtu");
        assert!(m.contains("holds 5 points"), "{m}");
    }

    #[test]
    fn vtk_legacy_reads_cells_types_and_cell_scalars() {
        // The float SCALARS and the point SCALARS are not labels; the int cell SCALARS are.
        expect(&decode_vtk_legacy(VTK, "a.vtk").unwrap(), [3, 6]);
        let windows = format!("\u{feff}{}", VTK.replace('\n', "\r\n"));
        expect(&decode_vtk_legacy(&windows, "a.vtk").unwrap(), [3, 6]);
        let no_data = &VTK[..VTK.find("POINT_DATA").unwrap()];
        expect(&decode_vtk_legacy(no_data, "a.vtk").unwrap(), [1, 1]);
    }

    #[test]
    fn vtk_legacy_reads_the_vtk5_layout_and_field_arrays() {
        expect(&decode_vtk_legacy(VTK51, "b.vtk").unwrap(), [2, 5]);
    }

    #[test]
    fn vtk_legacy_errors_name_the_line_and_cell() {
        let m = message(decode_vtk_legacy, &VTK.replace("4 1 2 4 3", "4 1 2 5 3"), "c.vtk");
        assert!(m.contains("line 12") && m.contains("cell 2 names point 5"), "{m}");
        let m = message(decode_vtk_legacy, &VTK.replace("4 1 2 4 3", "4 1 2 -1 3"), "c.vtk");
        assert!(m.contains("cell 2 names point -1"), "{m}");
        let m = message(decode_vtk_legacy, &VTK51.replace("0 4 7 11", "0 4 3 11"), "c.vtk");
        assert!(m.contains("line 13") && m.contains("offset 2 is 3"), "{m}");
        let m = message(decode_vtk_legacy, &VTK.replace("3 0 6", "3 0 -6"), "c.vtk");
        assert!(m.contains("line 27") && m.contains("cell 2: region label -6"), "{m}");
        let m = message(decode_vtk_legacy, &VTK.replace("CELLS 3 14", "CELLS 3 15"), "c.vtk");
        assert!(m.contains("line 9") && m.contains("size 15"), "{m}");
        let m = message(
            decode_vtk_legacy,
            &VTK.replace("4 1 2 4 3", "3 1 2 4").replace("CELLS 3 14", "CELLS 3 13"),
            "c.vtk",
        );
        assert!(m.contains("cell 2 has type 10 (tetra) but 3 points"), "{m}");
        let binary = VTK.replace("\nASCII\n", "\nBINARY\n");
        let e = decode_vtk_legacy(&binary, "bin.vtk").unwrap_err();
        assert!(matches!(e, IoError::UnsupportedType { .. }));
        assert!(e.to_string().contains("binary legacy VTK is not supported, save as ASCII"));
        let m = message(decode_vtk_legacy, &VTK.replace("UNSTRUCTURED_GRID", "POLYDATA"), "p.vtk");
        assert!(m.contains("DATASET POLYDATA"), "{m}");
        let m = message(decode_vtk_legacy, "ply\nformat ascii 1.0\nend_header\n", "x.vtk");
        assert!(m.contains("line 1"), "{m}");
    }

    #[test]
    fn vtk_legacy_truncated_files_are_errors() {
        for text in [VTK, VTK51] {
            let lines: Vec<&str> = text.lines().collect();
            // Up to the cell types everything is required; a cut inside an attribute array
            // leaves values missing.
            let required = lines.iter().position(|l| l.starts_with("POINT_DATA")).unwrap_or(0);
            let required = if required == 0 {
                lines.iter().position(|l| l.starts_with("CELL_DATA")).unwrap()
            } else {
                required
            };
            for keep in (0..required - 1).chain([lines.len() - 1]) {
                let cut = lines[..keep].join("\n");
                assert!(decode_vtk_legacy(&cut, "cut.vtk").is_err(), "{keep} lines: {cut}");
            }
        }
    }

    #[test]
    fn vtu_reads_ascii_arrays_and_prefers_the_named_scalars() {
        expect(&decode_vtu(VTU, "a.vtu").unwrap(), [3, 6]);
        let windows = format!("\u{feff}{}", VTU.replace('\n', "\r\n"));
        expect(&decode_vtu(&windows, "a.vtu").unwrap(), [3, 6]);
        let unnamed = VTU.replace(" Scalars=\"tissue\"", "");
        expect(&decode_vtu(&unnamed, "a.vtu").unwrap(), [7, 7]);
        let start = VTU.find("<CellData").unwrap();
        let end = VTU.find("<Points>").unwrap();
        let bare = format!("{}{}", &VTU[..start], &VTU[end..]);
        expect(&decode_vtu(&bare, "a.vtu").unwrap(), [1, 1]);
    }

    #[test]
    fn vtu_pieces_are_joined() {
        let mesh = cylinder(0.01, 0.03, 2, 1);
        let one = encode_vtu(&mesh);
        let start = one.find("<Piece").unwrap();
        let end = one.find("</Piece>").unwrap() + "</Piece>".len();
        let two = format!("{}{}{}", &one[..end], &one[start..end], &one[end..]);
        let joined = decode_vtu(&two, "two.vtu").unwrap();
        let n = mesh.vertices().len() as u32;
        assert_eq!(joined.vertices().len(), 2 * mesh.vertices().len());
        assert_eq!(&joined.vertices()[..n as usize], mesh.vertices());
        assert_eq!(&joined.tets()[..mesh.tets().len()], mesh.tets());
        let shifted: Vec<[u32; 4]> = mesh.tets().iter().map(|t| t.map(|i| i + n)).collect();
        assert_eq!(&joined.tets()[mesh.tets().len()..], &shifted[..]);
    }

    #[test]
    fn vtu_errors_name_the_line_and_cell() {
        let m = message(
            decode_vtu,
            &VTU.replace("0 1 2 3  1 2 3  1 2 4 3", "0 1 2 3 1 2 3 1 2 4 7"),
            "c.vtu",
        );
        assert!(
            m.contains("line 27") && m.contains("cell 2 names point 7, but there are 5"),
            "{m}"
        );
        let appended = VTU.replace(
            r#"<DataArray type="Float32" NumberOfComponents="3" format="ascii">"#,
            r#"<DataArray type="Float32" NumberOfComponents="3" format="appended" offset="0">"#,
        );
        let e = decode_vtu(&appended, "d.vtu").unwrap_err();
        assert!(matches!(e, IoError::UnsupportedType { .. }));
        assert!(
            e.to_string().contains("format=\"appended\"")
                && e.to_string().contains("save as ASCII")
        );
        let binary =
            VTU.replace(r#"Name="offsets" format="ascii""#, r#"Name="offsets" format="binary""#);
        let m = message(decode_vtu, &binary, "d.vtu");
        assert!(m.contains("line 27") && m.contains("format=\"binary\""), "{m}");
        let m = message(decode_vtu, &VTU.replace(">4 7 11<", ">4 3 11<"), "e.vtu");
        assert!(m.contains("offset 1 is 3"), "{m}");
        let m = message(
            decode_vtu,
            &VTU.replace("UnstructuredGrid\" version", "PolyData\" version"),
            "f.vtu",
        );
        assert!(m.contains("type=\"PolyData\""), "{m}");
        let m = message(decode_vtu, &VTU.replace("</Cells>", "</Cell>"), "g.vtu");
        assert!(m.contains("line 29") && m.contains("</Cell> closes <Cells>"), "{m}");
        let m = message(decode_vtu, "<html></html>", "h.vtu");
        assert!(m.contains("expected <VTKFile>"), "{m}");
    }

    #[test]
    fn vtu_truncated_files_are_errors() {
        let lines: Vec<&str> = VTU.lines().collect();
        for keep in 0..lines.len() {
            let cut = lines[..keep].join("\n");
            assert!(decode_vtu(&cut, "cut.vtu").is_err(), "{keep} lines: {cut}");
        }
        for cut in (0..VTU.len()).filter(|&i| VTU.is_char_boundary(i)).step_by(7) {
            if !VTU[..cut].contains("</VTKFile>") {
                assert!(decode_vtu(&VTU[..cut], "cut.vtu").is_err(), "{cut} bytes");
            }
        }
    }

    #[test]
    fn round_trips_are_bit_identical() {
        let mesh = awkward_mesh();
        for (format, text) in [
            ("msh", encode_gmsh22(&mesh)),
            ("vtk", encode_vtk_legacy(&mesh)),
            ("vtu", encode_vtu(&mesh)),
        ] {
            let back = match format {
                "msh" => decode_gmsh(&text, "rt.msh"),
                "vtk" => decode_vtk_legacy(&text, "rt.vtk"),
                _ => decode_vtu(&text, "rt.vtu"),
            }
            .unwrap_or_else(|e| panic!("{format}: {e}"));
            assert_eq!(back, mesh, "{format}");
            assert_eq!(bits(&back), bits(&mesh), "{format}");
        }
        // Labels beyond i32 are written as unsigned and read back.
        let big = TetMesh::new(VERTICES[..4].to_vec(), vec![TETS[0]], vec![u32::MAX]).unwrap();
        assert_eq!(decode_vtk_legacy(&encode_vtk_legacy(&big), "u.vtk").unwrap(), big);
        assert_eq!(decode_vtu(&encode_vtu(&big), "u.vtu").unwrap(), big);
        assert_eq!(decode_gmsh(&encode_gmsh22(&big), "u.msh").unwrap(), big);
    }

    #[test]
    fn read_tet_mesh_picks_the_format_by_extension() {
        let dir = std::env::temp_dir().join(format!("incise_io_tet_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mesh = awkward_mesh();
        for (file, text) in [
            ("m.msh", encode_gmsh22(&mesh)),
            ("M.MSH", encode_gmsh22(&mesh)),
            ("m.Vtk", encode_vtk_legacy(&mesh)),
            ("m.vtu", encode_vtu(&mesh)),
        ] {
            let path = dir.join(file);
            std::fs::write(&path, text).unwrap();
            assert_eq!(read_tet_mesh(&path).unwrap(), mesh, "{file}");
        }
        let stl = dir.join("m.stl");
        std::fs::write(&stl, "solid\n").unwrap();
        let e = read_tet_mesh(&stl).unwrap_err();
        assert!(matches!(e, IoError::UnsupportedType { .. }), "{e}");
        // A binary MSH is not UTF-8; its header still says why it is refused.
        let binary = dir.join("b.msh");
        std::fs::write(
            &binary,
            b"$MeshFormat\n4.1 1 8\n\x01\x00\x00\x00\xff\xfe\n$EndMeshFormat\n",
        )
        .unwrap();
        let e = read_tet_mesh(&binary).unwrap_err();
        assert!(e.to_string().contains("binary MSH is not supported"), "{e}");
        let missing = read_tet_mesh(&dir.join("none.vtu")).unwrap_err();
        assert!(matches!(missing, IoError::Io { .. }), "{missing}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
