//! Gmsh MSH 2.2 and 4.1.

use super::binary::read_unsigned;
use super::{
    Assembly, At, BOM, DEFAULT_REGION, GMSH_TETRAHEDRON, MeshFile, MeshOptions, Origin, error_at,
    find_bytes, parse, shown, syntax,
};
use crate::error::{IoError, grouped};
use incise_mesh::TetMesh;
use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;

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
    fn add(&mut self, file: &str, tag: u64, p: [f64; 3], at: At) -> Result<(), IoError> {
        let index = u32::try_from(self.coords.len())
            .map_err(|_| error_at(file, at, "more than 2^32 nodes"))?;
        if let Some(&first) = self.index.get(&tag) {
            let first = self.origins.get(first as usize).map_or(At::Line(0), |o| o.at);
            return Err(error_at(
                file,
                at,
                format!("node {tag} is defined twice (first on {first})"),
            ));
        }
        self.index.insert(tag, index);
        self.coords.push(p);
        self.origins.push(Origin { id: tag, at });
        Ok(())
    }
}

/// A tetrahedron as read, before its node tags and region are resolved.
struct GmshTet {
    tag: u64,
    at: At,
    nodes: [u64; 4],
    /// Its physical tag, where the element line gives it (MSH 2.2's first tag).
    physical: Option<i64>,
    /// Its elementary entity tag (MSH 2.2's second tag, MSH 4.1's block entity), whose physical
    /// tag `$Entities` may give.
    entity: Option<i64>,
}

/// The elements of a Gmsh file as read: the tetrahedra, and how many of each other type were
/// skipped.
#[derive(Default)]
struct GmshElements {
    tets: Vec<GmshTet>,
    skipped: BTreeMap<String, usize>,
}

impl GmshElements {
    fn skip(&mut self, kind: i64) {
        *self.skipped.entry(gmsh_element_name(kind)).or_default() += 1;
    }
}

/// Gmsh's name of an element type, for the note on skipped elements.
fn gmsh_element_name(kind: i64) -> String {
    match kind {
        1 => "line".to_owned(),
        2 => "triangle".to_owned(),
        3 => "quadrangle".to_owned(),
        5 => "hexahedron".to_owned(),
        6 => "prism".to_owned(),
        7 => "pyramid".to_owned(),
        8 => "quadratic line".to_owned(),
        9 => "quadratic triangle".to_owned(),
        11 => "quadratic tetrahedron".to_owned(),
        15 => "point".to_owned(),
        other => format!("type-{other} element"),
    }
}

/// Which tag of a Gmsh element is its region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum GmshRegion {
    /// The physical tag (`"gmsh:physical"`, the default), else the entity tag.
    Physical,
    /// The elementary entity tag (`"gmsh:geometrical"`).
    Geometrical,
}

impl GmshRegion {
    fn of(file: &str, options: &MeshOptions) -> Result<Self, IoError> {
        match options.region.as_deref() {
            None | Some("gmsh:physical") => Ok(Self::Physical),
            Some("gmsh:geometrical") => Ok(Self::Geometrical),
            Some(other) => Err(IoError::RegionArray {
                file: file.to_owned(),
                what: format!(
                    "the scene names {other:?}, but a Gmsh file's regions are \
                     \"gmsh:physical\" (physical tags, the default) or \"gmsh:geometrical\" \
                     (elementary entity tags)"
                ),
            }),
        }
    }
}

/// A Gmsh file being read.
struct Gmsh<'a> {
    file: &'a str,
    lines: Lines<'a>,
}

/// Decodes a Gmsh mesh: ASCII MSH 2.2 or 4.1, or binary MSH 4.1 (either byte order). `name`
/// names the bytes in errors.
pub fn decode_gmsh(bytes: &[u8], name: &str) -> Result<TetMesh, IoError> {
    decode_gmsh_with(bytes, name, &MeshOptions::default()).map(|file| file.mesh)
}

/// Decodes a Gmsh mesh as [`decode_gmsh`] does, with `options`: its `region` may be
/// `"gmsh:physical"` (the default) or `"gmsh:geometrical"`.
pub fn decode_gmsh_with(
    bytes: &[u8],
    name: &str,
    options: &MeshOptions,
) -> Result<MeshFile, IoError> {
    let region = GmshRegion::of(name, options)?;
    let bytes = bytes.strip_prefix(BOM).unwrap_or(bytes);
    if let Some(format) = binary_41(bytes) {
        return decode_binary(bytes, &format, name, region);
    }
    // Bytes that are not UTF-8 become U+FFFD, which no number parses as: the error names the
    // line. A binary file of another version still has a text header that says what it is.
    decode_text(&String::from_utf8_lossy(bytes), name, region)
}

/// Decodes ASCII MSH 2.2 or 4.1.
fn decode_text(text: &str, name: &str, region: GmshRegion) -> Result<MeshFile, IoError> {
    let mut g = Gmsh { file: name, lines: Lines { rest: text, line: 0 } };
    let version = g.mesh_format()?;
    let mut nodes = GmshNodes::default();
    let mut tets = GmshElements::default();
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
    assemble(name, nodes, tets, &volumes, region)
}

/// Resolves the tetrahedra's node tags and regions and checks the mesh.
fn assemble(
    name: &str,
    nodes: GmshNodes,
    elements: GmshElements,
    volumes: &HashMap<i64, i64>,
    choice: GmshRegion,
) -> Result<MeshFile, IoError> {
    let mut mesh = Assembly::new("node", "element");
    mesh.skipped = elements.skipped;
    let (mut physical, mut geometrical) = (false, false);
    for t in elements.tets {
        let mut tet = [0u32; 4];
        for (slot, tag) in tet.iter_mut().zip(t.nodes) {
            *slot = *nodes.index.get(&tag).ok_or_else(|| {
                error_at(
                    name,
                    t.at,
                    format!("element {} names node {tag}, which $Nodes does not define", t.tag),
                )
            })?;
        }
        let via_entity = t.entity.and_then(|e| volumes.get(&e).copied());
        let (label, what) = match (choice, t.physical.or(via_entity), t.entity) {
            (GmshRegion::Physical, Some(tag), _) => {
                physical = true;
                (tag, "physical tag")
            }
            (_, _, Some(tag)) => {
                geometrical = true;
                (tag, "entity tag")
            }
            _ => (i64::from(DEFAULT_REGION), "default region"),
        };
        let region = u32::try_from(label).map_err(|_| {
            error_at(
                name,
                t.at,
                format!(
                    "element {}: region label {label} ({what}) is not in 0..={}",
                    t.tag,
                    u32::MAX
                ),
            )
        })?;
        mesh.push_tet(tet, region, Origin { id: t.tag, at: t.at });
    }
    mesh.region_source = match (physical, geometrical) {
        (true, false) => Some("physical tags".to_owned()),
        (true, true) => Some("physical tags (entity tags where a volume has none)".to_owned()),
        (false, true) => Some("elementary entity tags".to_owned()),
        (false, false) => None,
    };
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
                    what: format!(
                        "binary MSH {version}: binary files are read in version 4.1 only, save \
                         as ASCII or as MSH 4.1 (in Gmsh: Mesh.Binary = 0 or \
                         Mesh.MshFileVersion = 4.1)"
                    ),
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
            nodes.add(file, tag, p, At::Line(line))?;
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
                nodes.add(file, tag, p, At::Line(line))?;
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
    fn elements_2(&mut self, tets: &mut GmshElements) -> Result<(), IoError> {
        let file = self.file;
        let (line, text) = self.data_line("Elements", || "the element count".to_owned())?;
        let count: usize = parse(file, line, Some(text), "the element count")?;
        for k in 1..=count {
            let (line, text) = self.data_line("Elements", || {
                format!("element {k} of {count} (`tag type numTags tags… nodes…`)")
            })?;
            let mut f = text.split_ascii_whitespace();
            let tag: u64 = parse(file, line, f.next(), "an element tag")?;
            let kind: i64 = parse(file, line, f.next(), "an element type")?;
            if kind != GMSH_TETRAHEDRON as i64 {
                tets.skip(kind);
                continue;
            }
            let tag_count: usize = parse(file, line, f.next(), "the number of tags")?;
            let (mut physical, mut entity) = (None, None);
            for i in 0..tag_count {
                let value: i64 = parse(file, line, f.next(), "an element tag")?;
                match i {
                    0 => physical = Some(value),
                    1 => entity = Some(value),
                    _ => {}
                }
            }
            let nodes = self.tet_nodes(line, tag, f)?;
            tets.tets.push(GmshTet { tag, at: At::Line(line), nodes, physical, entity });
        }
        self.end("Elements")
    }

    /// MSH 4.1 `$Elements`: a header, then blocks of elements of one type and entity.
    fn elements_41(&mut self, tets: &mut GmshElements) -> Result<(), IoError> {
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
            let kind: i64 = parse(file, line, f.next(), "the element type")?;
            let count: usize = parse(file, line, f.next(), "the number of elements in the block")?;
            for k in 1..=count {
                let (line, text) =
                    self.data_line("Elements", || format!("element {k} of {count} in block {b}"))?;
                read += 1;
                if kind != GMSH_TETRAHEDRON as i64 {
                    tets.skip(kind);
                    continue;
                }
                let mut f = text.split_ascii_whitespace();
                let tag: u64 = parse(file, line, f.next(), "an element tag")?;
                let nodes = self.tet_nodes(line, tag, f)?;
                let (physical, entity) = (None, Some(entity));
                tets.tets.push(GmshTet { tag, at: At::Line(line), nodes, physical, entity });
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
// Binary MSH 4.1

/// What the `$MeshFormat` of a binary MSH 4.1 file says.
struct BinaryFormat {
    /// The `data-size` field as written (`sizeof(size_t)`).
    data_size: String,
    /// The line of the version line.
    line: usize,
    /// The byte after the version line, where the endianness check starts.
    start: usize,
}

/// Whether `bytes` start like binary MSH 4.1: a `$MeshFormat` line, then `4.1 1 …`.
fn binary_41(bytes: &[u8]) -> Option<BinaryFormat> {
    let mut pos = 0;
    let mut line = 0;
    let mut next_line = || {
        while pos < bytes.len() {
            let end = find_bytes(bytes, b"\n", pos).unwrap_or(bytes.len());
            let text = bytes.get(pos..end)?;
            pos = end + 1;
            line += 1;
            let text = text.trim_ascii();
            if !text.is_empty() {
                return Some((text, line, pos));
            }
        }
        None
    };
    let (first, _, _) = next_line()?;
    if first != b"$MeshFormat" {
        return None;
    }
    let (text, line, start) = next_line()?;
    let text = std::str::from_utf8(text).ok()?;
    let mut fields = text.split_ascii_whitespace();
    let (version, file_type) = (fields.next()?, fields.next()?);
    (version == "4.1" && file_type == "1").then(|| BinaryFormat {
        data_size: fields.next().unwrap_or_default().to_owned(),
        line,
        start: start.min(bytes.len()),
    })
}

/// The number of nodes of a Gmsh element type: binary element blocks hold no line ends, so a
/// block of another type can be passed over only by knowing its size.
fn nodes_per_element(kind: i32) -> Option<u64> {
    Some(match kind {
        15 => 1,
        1 => 2,
        2 | 8 => 3,
        3 | 4 | 26 => 4,
        7 | 27 => 5,
        6 | 9 | 28 => 6,
        5 | 16 => 8,
        10 | 20 => 9,
        11 | 21 => 10,
        22 => 12,
        19 => 13,
        14 => 14,
        18 | 23 | 24 => 15,
        13 => 18,
        17 | 29 => 20,
        25 => 21,
        12 => 27,
        30 => 35,
        31 => 56,
        92 => 64,
        93 => 125,
        _ => return None,
    })
}

/// A binary MSH 4.1 file being read: its sections' header lines are text, their contents
/// `int`s (4 bytes), `size_t`s (`data-size` bytes) and `double`s in the file's byte order.
struct MshBinary<'a> {
    file: &'a str,
    bytes: &'a [u8],
    pos: usize,
    big: bool,
    size_t: usize,
}

/// Decodes binary MSH 4.1.
fn decode_binary(
    bytes: &[u8],
    format: &BinaryFormat,
    name: &str,
    region: GmshRegion,
) -> Result<MeshFile, IoError> {
    let Ok(size_t @ (4 | 8)) = format.data_size.parse::<usize>() else {
        return Err(syntax(
            name,
            format.line,
            format!(
                "data-size {}: binary MSH stores size_t in 4 or 8 bytes",
                shown(&format.data_size)
            ),
        ));
    };
    let mut r = MshBinary { file: name, bytes, pos: format.start, big: false, size_t };
    let check = r.take(4, "the endianness check (the int 1)")?;
    r.big = match (read_unsigned(check, 4, false), read_unsigned(check, 4, true)) {
        (Some(1), _) => false,
        (_, Some(1)) => true,
        _ => {
            return Err(r.error_at(
                format.start,
                format!("expected the int 1 (the endianness check), found the bytes {check:02x?}"),
            ));
        }
    };
    r.end("MeshFormat")?;
    let mut nodes = GmshNodes::default();
    let mut tets = GmshElements::default();
    let mut volumes: HashMap<i64, i64> = HashMap::new();
    let (mut saw_nodes, mut saw_elements) = (false, false);
    while let Some((at, text)) = r.header_line() {
        match text.as_str() {
            "$Nodes" => r.nodes(&mut nodes)?,
            "$Elements" => r.elements(&mut tets)?,
            "$Entities" => r.entities(&mut volumes)?,
            _ => match text.strip_prefix('$') {
                Some(section) if !section.is_empty() && !section.starts_with("End") => {
                    r.skip(section)?;
                }
                _ => {
                    return Err(r.error_at(
                        at,
                        format!(
                            "expected a section ($Nodes, $Elements, …), found {}",
                            shown(&text)
                        ),
                    ));
                }
            },
        }
        saw_nodes |= text == "$Nodes";
        saw_elements |= text == "$Elements";
    }
    for (seen, section) in [(saw_nodes, "$Nodes"), (saw_elements, "$Elements")] {
        if !seen {
            return Err(r.error_at(r.pos, format!("the file has no {section} section")));
        }
    }
    assemble(name, nodes, tets, &volumes, region)
}

impl<'a> MshBinary<'a> {
    fn error_at(&self, pos: usize, what: impl Into<String>) -> IoError {
        error_at(self.file, At::Byte(pos), what)
    }

    fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }

    /// The next `n` bytes, which hold `what`.
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], IoError> {
        let bytes = self.bytes;
        match self.pos.checked_add(n).and_then(|end| bytes.get(self.pos..end)) {
            Some(taken) => {
                self.pos += n;
                Ok(taken)
            }
            None => Err(self.error_at(
                self.pos,
                format!("the file ends inside {what} ({n} bytes, {} left)", self.remaining()),
            )),
        }
    }

    fn int(&mut self, what: &str) -> Result<i32, IoError> {
        let big = self.big;
        let bytes = self.take(4, what)?;
        Ok(read_unsigned(bytes, 4, big).unwrap_or_default() as u32 as i32)
    }

    fn size(&mut self, what: &str) -> Result<u64, IoError> {
        let (big, size) = (self.big, self.size_t);
        let bytes = self.take(size, what)?;
        Ok(read_unsigned(bytes, size, big).unwrap_or_default())
    }

    fn double(&mut self, what: &str) -> Result<f64, IoError> {
        let big = self.big;
        let bytes = self.take(8, what)?;
        Ok(f64::from_bits(read_unsigned(bytes, 8, big).unwrap_or_default()))
    }

    /// Checks that `count` items of `each` bytes fit in the rest of the file before any is read,
    /// so that no count drives a loop or an allocation past the data.
    fn need(
        &self,
        count: u64,
        each: u64,
        noun: &str,
        what: impl FnOnce() -> String,
    ) -> Result<(), IoError> {
        let total = count.checked_mul(each);
        if total.is_none_or(|t| t > self.remaining() as u64) {
            return Err(self.error_at(
                self.pos,
                format!(
                    "{} announces {} {noun} of {each} bytes each, the file holds {} more bytes",
                    what(),
                    grouped(count),
                    grouped(self.remaining() as u64)
                ),
            ));
        }
        Ok(())
    }

    /// A count of `noun`s read as a `size_t`, checked to fit `each` bytes per item in the rest
    /// of the file.
    fn count(&mut self, each: u64, noun: &str, what: &str) -> Result<u64, IoError> {
        let at = self.pos;
        let count = self.size(what)?;
        self.need(count, each, noun, || {
            format!("{what} (counted at byte {})", grouped(at as u64))
        })?;
        Ok(count)
    }

    /// The next non-blank text line, trimmed, and where it starts; `None` at the end.
    fn header_line(&mut self) -> Option<(usize, String)> {
        let rest = self.bytes.get(self.pos..)?;
        let skip = rest.iter().position(|b| !b.is_ascii_whitespace())?;
        let start = self.pos + skip;
        let end = find_bytes(self.bytes, b"\n", start).unwrap_or(self.bytes.len());
        self.pos = (end + 1).min(self.bytes.len());
        let text = self.bytes.get(start..end).unwrap_or_default().trim_ascii();
        Some((start, String::from_utf8_lossy(text).into_owned()))
    }

    /// Reads the line that must close `$section`, after the section's binary data.
    fn end(&mut self, section: &str) -> Result<(), IoError> {
        match self.header_line() {
            Some((_, text)) if text.strip_prefix("$End") == Some(section) => Ok(()),
            Some((at, text)) => {
                let hint = if section == "MeshFormat" {
                    ""
                } else {
                    " (the counts of the section disagree with its data)"
                };
                Err(self
                    .error_at(at, format!("expected $End{section}, found {}{hint}", shown(&text))))
            }
            None => Err(self
                .error_at(self.pos, format!("the file ends inside ${section} (no $End{section})"))),
        }
    }

    /// Skips a section this reader does not use, up to its `$End` line.
    fn skip(&mut self, section: &str) -> Result<(), IoError> {
        let end = format!("$End{section}");
        match find_bytes(self.bytes, end.as_bytes(), self.pos) {
            Some(at) => {
                self.pos = at;
                self.end(section)
            }
            None => Err(self
                .error_at(self.pos, format!("the file ends inside ${section} (no $End{section})"))),
        }
    }

    /// `$Entities`: records the first physical tag of each volume that has one.
    fn entities(&mut self, volumes: &mut HashMap<i64, i64>) -> Result<(), IoError> {
        let size_t = self.size_t as u64;
        // The smallest entity: a tag, three coordinates and a physical tag count.
        let smallest = 4 + 24 + size_t;
        let mut counts = [0u64; 4];
        for (count, what) in counts.iter_mut().zip(["points", "curves", "surfaces", "volumes"]) {
            *count = self.size(&format!("the number of {what} of $Entities"))?;
        }
        let total = counts.iter().try_fold(0u64, |sum, &c| sum.checked_add(c)).unwrap_or(u64::MAX);
        self.need(total, smallest, "entities", || "$Entities".to_owned())?;
        for (dim, (&count, what)) in
            counts.iter().zip(["point", "curve", "surface", "volume"]).enumerate()
        {
            for k in 1..=count {
                let what = format!("{what} entity {k} of {count}");
                let tag = self.int(&what)?;
                let box_bytes = if dim == 0 { 24 } else { 48 };
                self.take(box_bytes, &what)?;
                let physicals = self.count(4, "physical tags", &what)?;
                for p in 0..physicals {
                    let physical = self.int(&what)?;
                    if dim == 3 && p == 0 {
                        volumes.insert(tag.into(), physical.into());
                    }
                }
                if dim > 0 {
                    let bounding = self.count(4, "bounding entities", &what)?;
                    // `need` has checked the bytes are there.
                    self.take(bounding as usize * 4, &what)?;
                }
            }
        }
        self.end("Entities")
    }

    /// `$Nodes`: a header, then blocks of node tags followed by their coordinates.
    fn nodes(&mut self, nodes: &mut GmshNodes) -> Result<(), IoError> {
        let size_t = self.size_t as u64;
        let header = self.pos;
        let blocks = self.count(12 + size_t, "node blocks", "$Nodes")?;
        let total = self.size("the node count of $Nodes")?;
        self.take(2 * self.size_t, "the node tag range of $Nodes")?;
        let before = nodes.coords.len();
        for b in 1..=blocks {
            let what = format!("the header of node block {b} of {blocks}");
            let block_at = self.pos;
            let dim = self.int(&what)?;
            let _entity = self.int(&what)?;
            let parametric = self.int(&what)?;
            let extra = match (parametric, dim) {
                (0, 0..=3) => 0,
                (1, 0..=3) => dim as u64,
                _ => {
                    return Err(self.error_at(
                        block_at,
                        format!(
                            "node block {b} of {blocks}: entity dimension {dim} and parametric \
                             flag {parametric} (expected 0 to 3, and 0 or 1)"
                        ),
                    ));
                }
            };
            let per_node = size_t + 8 * (3 + extra);
            let count = self.count(per_node, "nodes", &format!("node block {b} of {blocks}"))?;
            let mut tags = Vec::new();
            for k in 1..=count {
                tags.push(self.size(&format!("the tag of node {k} of {count} in block {b}"))?);
            }
            for (k, tag) in tags.into_iter().enumerate() {
                let at = At::Byte(self.pos);
                let what = format!("the coordinates of node {} of {count} in block {b}", k + 1);
                let p = [self.double(&what)?, self.double(&what)?, self.double(&what)?];
                self.take(8 * extra as usize, &what)?;
                nodes.add(self.file, tag, p, at)?;
            }
        }
        let read = nodes.coords.len() - before;
        if read as u64 != total {
            return Err(self.error_at(
                header,
                format!("$Nodes announces {total} nodes, its blocks hold {read}"),
            ));
        }
        self.end("Nodes")
    }

    /// `$Elements`: a header, then blocks of elements of one type and entity.
    fn elements(&mut self, tets: &mut GmshElements) -> Result<(), IoError> {
        let size_t = self.size_t as u64;
        let header = self.pos;
        let blocks = self.count(12 + size_t, "element blocks", "$Elements")?;
        let total = self.size("the element count of $Elements")?;
        self.take(2 * self.size_t, "the element tag range of $Elements")?;
        let mut read = 0u64;
        for b in 1..=blocks {
            let what = format!("the header of element block {b} of {blocks}");
            let block_at = self.pos;
            let _dim = self.int(&what)?;
            let entity = self.int(&what)?;
            let kind = self.int(&what)?;
            let Some(per_element) = nodes_per_element(kind) else {
                return Err(self.error_at(
                    block_at,
                    format!(
                        "element block {b} of {blocks} has element type {kind}, whose node count \
                         this reader does not know, so it cannot pass over the block"
                    ),
                ));
            };
            let count = self.count(
                size_t * (1 + per_element),
                "elements",
                &format!("element block {b} of {blocks} (type {kind})"),
            )?;
            for k in 1..=count {
                let at = At::Byte(self.pos);
                let what = format!("element {k} of {count} in block {b}");
                if kind as u64 != GMSH_TETRAHEDRON {
                    self.take(self.size_t * (1 + per_element as usize), &what)?;
                    tets.skip(kind.into());
                    continue;
                }
                let tag = self.size(&what)?;
                let nodes =
                    [self.size(&what)?, self.size(&what)?, self.size(&what)?, self.size(&what)?];
                let (physical, entity) = (None, Some(entity.into()));
                tets.tets.push(GmshTet { tag, at, nodes, physical, entity });
            }
            read += count;
        }
        if read != total {
            return Err(self.error_at(
                header,
                format!("$Elements announces {total} elements, its blocks hold {read}"),
            ));
        }
        self.end("Elements")
    }
}

/// Encodes `mesh` as little-endian binary MSH 4.1 with 8-byte `size_t`: one volume entity per
/// region with that region as its physical tag, node tags from 1 in one block, and one element
/// block per run of consecutive tetrahedra in the same region, so that the mesh reads back in
/// its own order. Fails for a region beyond `i32::MAX`, which Gmsh's `int` tags cannot hold.
pub fn encode_gmsh41_binary(mesh: &TetMesh) -> Result<Vec<u8>, IoError> {
    encode_gmsh41_binary_in(mesh, false)
}

/// Binary MSH being written, in one byte order.
struct MshOut {
    bytes: Vec<u8>,
    big: bool,
}

impl MshOut {
    /// A value given as its little-endian bytes.
    fn put<const N: usize>(&mut self, mut le: [u8; N]) {
        if self.big {
            le.reverse();
        }
        self.bytes.extend(le);
    }
}

/// [`encode_gmsh41_binary`] in either byte order.
pub(super) fn encode_gmsh41_binary_in(mesh: &TetMesh, big: bool) -> Result<Vec<u8>, IoError> {
    let mut regions: Vec<u32> = mesh.regions().to_vec();
    regions.sort_unstable();
    regions.dedup();
    let int = |r: u32| {
        i32::try_from(r).map_err(|_| IoError::UnsupportedType {
            file: "encode_gmsh41_binary".to_owned(),
            what: format!("region {r} is beyond the int physical tags of MSH"),
        })
    };
    let entity = |r: u32| regions.binary_search(&r).map_or(0, |i| i as i32 + 1);
    let mut out = MshOut { bytes: b"$MeshFormat\n4.1 1 8\n".to_vec(), big };
    out.put(1i32.to_le_bytes());
    out.bytes.extend(b"\n$EndMeshFormat\n$Entities\n");
    for count in [0, 0, 0, regions.len() as u64] {
        out.put(count.to_le_bytes());
    }
    for &r in &regions {
        out.put(entity(r).to_le_bytes());
        for v in [0.0f64; 6] {
            out.put(v.to_le_bytes());
        }
        out.put(1u64.to_le_bytes());
        out.put(int(r)?.to_le_bytes());
        out.put(0u64.to_le_bytes());
    }
    out.bytes.extend(b"\n$EndEntities\n$Nodes\n");
    let n = mesh.vertices().len() as u64;
    for v in [1, n, 1, n] {
        out.put(v.to_le_bytes());
    }
    for v in [3i32, 1, 0] {
        out.put(v.to_le_bytes());
    }
    out.put(n.to_le_bytes());
    for tag in 1..=n {
        out.put(tag.to_le_bytes());
    }
    for p in mesh.vertices() {
        for c in p {
            out.put(c.to_le_bytes());
        }
    }
    out.bytes.extend(b"\n$EndNodes\n$Elements\n");
    let mut runs: Vec<(u32, usize, usize)> = Vec::new();
    for (t, &r) in mesh.regions().iter().enumerate() {
        match runs.last_mut() {
            Some((region, _, end)) if *region == r => *end = t + 1,
            _ => runs.push((r, t, t + 1)),
        }
    }
    let t = mesh.tets().len() as u64;
    for v in [runs.len() as u64, t, 1, t] {
        out.put(v.to_le_bytes());
    }
    for (r, start, end) in runs {
        for v in [3, entity(r), 4] {
            out.put(v.to_le_bytes());
        }
        out.put(((end - start) as u64).to_le_bytes());
        for (e, tet) in mesh.tets().iter().enumerate().take(end).skip(start) {
            out.put((e as u64 + 1).to_le_bytes());
            for &i in tet {
                out.put((u64::from(i) + 1).to_le_bytes());
            }
        }
    }
    out.bytes.extend(b"\n$EndElements\n");
    Ok(out.bytes)
}
