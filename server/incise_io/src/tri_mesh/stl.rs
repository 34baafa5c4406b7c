//! STL, binary and ASCII.
//!
//! Binary: an 80-byte header whose content means nothing, a little-endian `u32` triangle count,
//! then 50 bytes per triangle: a normal and three corners as little-endian `f32`, and a `u16`
//! attribute. ASCII: `solid name`, then per triangle `facet normal nx ny nz`, `outer loop`,
//! three `vertex x y z`, `endloop`, `endfacet`, and `endsolid name`; keywords in any letter
//! case, separated by any whitespace. Several solids in one file are read as one mesh.

use super::{Origin, Soup};
use crate::error::{IoError, grouped};
use crate::tet_mesh::{At, BOM, Tokens, shown, syntax};
use incise_mesh::TriMesh;
use std::fmt::Write as _;

/// Bytes before a binary STL's triangle count.
const HEADER: usize = 80;
/// Bytes before a binary STL's first triangle.
const PREAMBLE: usize = HEADER + 4;
/// Bytes per binary STL triangle.
const RECORD: usize = 50;
/// What the format calls a triangle.
const FACET: &str = "facet";

/// Decodes an STL mesh, binary or ASCII; `name` names the bytes in errors. The file is binary
/// when its length is `84 + 50 × count` for the triangle count at byte 80, whatever its header
/// says, else ASCII when it starts with `solid`.
pub fn decode_stl(bytes: &[u8], name: &str) -> Result<TriMesh, IoError> {
    if let Some(count) = binary_count(bytes).filter(|&n| expected_len(n) == bytes.len() as u64) {
        return decode_binary(bytes, count as usize, name);
    }
    let text = bytes.strip_prefix(BOM).unwrap_or(bytes);
    let solid = text.trim_ascii_start().get(..5).is_some_and(|w| w.eq_ignore_ascii_case(b"solid"));
    if solid {
        // Bytes that are not UTF-8 become U+FFFD, which no keyword or number matches: the error
        // names the line.
        return decode_ascii(&String::from_utf8_lossy(text), name).map_err(|e| {
            // A binary file of the wrong length whose header starts with `solid`: its size says
            // more than the line where the ASCII reader gave up in its bytes.
            if looks_binary(bytes) { size_mismatch(bytes, name, true).unwrap_or(e) } else { e }
        });
    }
    if let Some(e) = size_mismatch(bytes, name, false) {
        return Err(e);
    }
    Err(IoError::BadHeader {
        file: name.to_owned(),
        what: format!(
            "not STL: {} bytes, too short for binary STL ({PREAMBLE} bytes or more), and no \
             \"solid\" at the start as ASCII STL has",
            bytes.len()
        ),
    })
}

/// The triangle count at byte 80, when the file is long enough to have one.
fn binary_count(bytes: &[u8]) -> Option<u32> {
    let count = bytes.get(HEADER..PREAMBLE)?;
    Some(u32::from_le_bytes(count.try_into().ok()?))
}

/// The length of a binary STL file of `count` triangles.
fn expected_len(count: u32) -> u64 {
    PREAMBLE as u64 + RECORD as u64 * u64::from(count)
}

/// Whether `bytes` hold a NUL (other than trailing padding) or are not UTF-8: binary, whatever
/// the first word says.
fn looks_binary(bytes: &[u8]) -> bool {
    let end = bytes.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    let body = &bytes[..end];
    body.contains(&0) || std::str::from_utf8(body).is_err()
}

/// The error for a binary file whose length disagrees with its triangle count; `None` when it is
/// too short to have a count.
fn size_mismatch(bytes: &[u8], name: &str, solid: bool) -> Option<IoError> {
    let count = binary_count(bytes)?;
    let (expected, found) = (expected_len(count), bytes.len() as u64);
    let why = if found < expected {
        "it is truncated".to_owned()
    } else {
        format!("{} bytes follow the last triangle", grouped(found - expected))
    };
    let note = if solid {
        " (its header starts with \"solid\", but the file is not ASCII STL: it holds bytes that \
         are not text)"
    } else {
        ""
    };
    Some(IoError::Binary {
        file: name.to_owned(),
        offset: HEADER as u64,
        what: format!(
            "binary STL{note}: the header counts {} triangles, which take {} bytes \
             ({PREAMBLE} + {RECORD} per triangle), but the file holds {}: {why}",
            grouped(u64::from(count)),
            grouped(expected),
            grouped(found)
        ),
    })
}

/// Decodes binary STL whose length is checked to hold `count` triangles.
fn decode_binary(bytes: &[u8], count: usize, name: &str) -> Result<TriMesh, IoError> {
    let mut soup = Soup::default();
    soup.triangles.reserve_exact(count);
    soup.triangle_origins.reserve_exact(count);
    let records = bytes.get(PREAMBLE..).unwrap_or_default().chunks_exact(RECORD);
    for (facet, record) in records.enumerate() {
        let start = PREAMBLE + RECORD * facet;
        // The normal (floats 0..3) is ignored; the corners are floats 3..12.
        let (floats, _) = record.as_chunks::<4>();
        let mut triangle = [0u32; 3];
        for (corner, slot) in triangle.iter_mut().enumerate() {
            let p: [f64; 3] = std::array::from_fn(|a| {
                floats
                    .get(3 + 3 * corner + a)
                    .map_or(f64::NAN, |&b| f64::from(f32::from_le_bytes(b)))
            });
            let origin =
                Origin { at: At::Byte(start + 12 + 12 * corner), item: Some((FACET, facet)) };
            *slot = soup.weld(p, origin, name)?;
        }
        soup.push_triangle(triangle, Origin { at: At::Byte(start), item: Some((FACET, facet)) });
    }
    soup.finish(name)
}

/// ASCII STL's tokens, with the line of the last one taken.
struct Ascii<'a> {
    file: &'a str,
    tokens: Tokens<'a>,
    line: usize,
}

impl<'a> Ascii<'a> {
    fn next(&mut self) -> Option<&'a str> {
        let (token, line) = self.tokens.next()?;
        self.line = line;
        Some(token)
    }

    /// Takes the keyword `word` of facet `facet`, or says what is there instead.
    fn keyword(&mut self, word: &str, facet: usize) -> Result<(), IoError> {
        match self.next() {
            Some(token) if token.eq_ignore_ascii_case(word) => Ok(()),
            Some(token) => Err(syntax(
                self.file,
                self.line,
                format!("facet {facet}: expected \"{word}\", found {}", shown(token)),
            )),
            None => Err(syntax(
                self.file,
                self.line,
                format!("facet {facet}: the file ends before \"{word}\""),
            )),
        }
    }

    /// Takes a number, or says `what` was expected.
    fn number(&mut self, what: &str, facet: usize) -> Result<f64, IoError> {
        let token = self.next();
        token.and_then(|t| t.parse().ok()).ok_or_else(|| {
            let found = token.map_or_else(|| "the end of the file".to_owned(), shown);
            syntax(self.file, self.line, format!("facet {facet}: expected {what}, found {found}"))
        })
    }

    /// Skips what follows a `solid` or `endsolid` keyword on its line: the solid's name, which
    /// may be several words.
    fn skip_name(&mut self) {
        let line = self.line;
        let mut ahead = self.tokens.clone();
        while let Some((token, at)) = ahead.next() {
            let keyword =
                ["facet", "endsolid", "solid"].iter().any(|k| token.eq_ignore_ascii_case(k));
            if at != line || keyword {
                break;
            }
            self.tokens = ahead.clone();
        }
    }

    /// Reads one facet, its `facet` keyword taken, into `soup`.
    fn facet(&mut self, facet: usize, soup: &mut Soup) -> Result<(), IoError> {
        let origin = Origin { at: At::Line(self.line), item: Some((FACET, facet)) };
        self.keyword("normal", facet)?;
        for axis in ["x", "y", "z"] {
            // Normals are ignored, so the NaN some writers give a degenerate facet's normal, in
            // whatever spelling ("-nan", MSVC's "1.#QNAN"), is no reason to refuse the file.
            let token = self.next();
            let ignored = token.is_some_and(|t| {
                let t = t.to_ascii_lowercase();
                t.parse::<f64>().is_ok()
                    || t.contains("nan")
                    || t.contains("inf")
                    || t.contains('#')
            });
            if !ignored {
                let found = token.map_or_else(|| "the end of the file".to_owned(), shown);
                return Err(syntax(
                    self.file,
                    self.line,
                    format!("facet {facet}: expected the normal's {axis}, found {found}"),
                ));
            }
        }
        self.keyword("outer", facet)?;
        self.keyword("loop", facet)?;
        let mut triangle = [0u32; 3];
        for slot in &mut triangle {
            self.keyword("vertex", facet)?;
            let at = At::Line(self.line);
            let mut p = [0.0; 3];
            for (c, axis) in p.iter_mut().zip(["x", "y", "z"]) {
                *c = self.number(&format!("the vertex's {axis}"), facet)?;
            }
            *slot = soup.weld(p, Origin { at, item: Some((FACET, facet)) }, self.file)?;
        }
        self.keyword("endloop", facet)?;
        self.keyword("endfacet", facet)?;
        soup.push_triangle(triangle, origin);
        Ok(())
    }
}

/// Decodes ASCII STL.
fn decode_ascii(text: &str, name: &str) -> Result<TriMesh, IoError> {
    // Some writers pad the file with NULs; they end it as well as whitespace does.
    let text = text.trim_end_matches(|c: char| c == '\0' || c.is_ascii_whitespace());
    let mut p = Ascii { file: name, tokens: Tokens::new(text, 1), line: 1 };
    let mut soup = Soup::default();
    let mut facets = 0;
    match p.next() {
        Some(token) if token.eq_ignore_ascii_case("solid") => {}
        found => {
            let found = found.map_or_else(|| "nothing".to_owned(), shown);
            return Err(syntax(name, p.line, format!("expected \"solid\", found {found}")));
        }
    }
    loop {
        p.skip_name();
        loop {
            match p.next() {
                Some(token) if token.eq_ignore_ascii_case("facet") => {
                    p.facet(facets, &mut soup)?;
                    facets += 1;
                }
                Some(token) if token.eq_ignore_ascii_case("endsolid") => break,
                Some(token) => {
                    return Err(syntax(
                        name,
                        p.line,
                        format!("expected \"facet\" or \"endsolid\", found {}", shown(token)),
                    ));
                }
                None => {
                    return Err(syntax(name, p.line, "the file ends before \"endsolid\""));
                }
            }
        }
        p.skip_name();
        match p.next() {
            None => break,
            Some(token) if token.eq_ignore_ascii_case("solid") => {}
            Some(token) => {
                return Err(syntax(
                    name,
                    p.line,
                    format!(
                        "expected \"solid\" or the end of the file after \"endsolid\", found {}",
                        shown(token)
                    ),
                ));
            }
        }
    }
    soup.finish(name)
}

/// The unit normal of each triangle of `mesh`, outwards.
fn normals(mesh: &TriMesh) -> impl Iterator<Item = [f64; 3]> + '_ {
    mesh.triangles().iter().map(|t| {
        let [a, b, c] = t.map(|i| mesh.vertices()[i as usize]);
        let (u, v) = (sub(b, a), sub(c, a));
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let length = n.iter().map(|x| x * x).sum::<f64>().sqrt();
        n.map(|x| x / length)
    })
}

fn sub(p: [f64; 3], q: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|k| p[k] - q[k])
}

/// Encodes `mesh` as ASCII STL, solid `incise`. Coordinates print as the shortest decimals that
/// read back bit-identical; unused vertices are not written (STL has no vertex list).
#[must_use]
pub fn encode_stl_ascii(mesh: &TriMesh) -> String {
    let mut out = String::from("solid incise\n");
    for (t, [nx, ny, nz]) in mesh.triangles().iter().zip(normals(mesh)) {
        let _ = write!(out, "  facet normal {nx:?} {ny:?} {nz:?}\n    outer loop\n");
        for &i in t {
            let [x, y, z] = mesh.vertices()[i as usize];
            let _ = writeln!(out, "      vertex {x:?} {y:?} {z:?}");
        }
        out.push_str("    endloop\n  endfacet\n");
    }
    out.push_str("endsolid incise\n");
    out
}

/// Encodes `mesh` as binary STL. Coordinates are rounded to `f32`, which is all the format
/// holds, so vertices closer than that resolution become one when read back; unused vertices
/// are not written.
///
/// # Panics
///
/// If the mesh has more than `u32::MAX` triangles, which binary STL cannot count.
#[must_use]
pub fn encode_stl_binary(mesh: &TriMesh) -> Vec<u8> {
    let count = u32::try_from(mesh.triangles().len()).expect("binary STL counts triangles in u32");
    let mut out = Vec::with_capacity(PREAMBLE + RECORD * mesh.triangles().len());
    // Not "solid …": that is where readers that go by the first word take a file for ASCII.
    out.extend_from_slice(b"binary STL written by incise");
    out.resize(HEADER, b' ');
    out.extend_from_slice(&count.to_le_bytes());
    for (t, normal) in mesh.triangles().iter().zip(normals(mesh)) {
        let corners = t.map(|i| mesh.vertices()[i as usize]);
        for p in std::iter::once(normal).chain(corners) {
            for c in p {
                out.extend_from_slice(&(c as f32).to_le_bytes());
            }
        }
        out.extend_from_slice(&0u16.to_le_bytes());
    }
    out
}
