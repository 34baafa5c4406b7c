//! Wavefront OBJ: the polygonal subset.
//!
//! One statement per line, its keyword first, `#` starting a comment. `v x y z [w]` adds a
//! vertex (`w`, a weight for rational curves, means nothing to polygons and is ignored; so are
//! the `r g b` colours some writers append). `f a b c …` adds a polygon; each reference is
//! `a`, `a/t`, `a/t/n` or `a//n`, where `a` counts vertices from 1, or back from the last one
//! defined so far when negative. A reference must name a vertex defined before its line, which
//! is what every writer does and what makes a relative index mean one thing.

use super::{Origin, Soup};
use crate::error::IoError;
use crate::tet_mesh::{At, BOM, shown, syntax};
use incise_mesh::TriMesh;
use std::fmt::Write as _;

/// What the format calls a polygon.
const FACE: &str = "face";

/// Statements that carry nothing about the shape: texture coordinates, normals, parameter-space
/// vertices, names, groups, smoothing, materials, lines, points and display attributes.
const IGNORED: [&str; 19] = [
    "vt",
    "vn",
    "vp",
    "o",
    "g",
    "s",
    "mg",
    "usemtl",
    "mtllib",
    "l",
    "p",
    "bevel",
    "c_interp",
    "d_interp",
    "lod",
    "maplib",
    "usemap",
    "shadow_obj",
    "trace_obj",
];

/// Statements of free-form geometry, whose curves and surfaces would be lost if skipped.
const FREE_FORM: [&str; 16] = [
    "cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm", "trim", "hole", "scrv", "sp",
    "end", "con", "ctech", "stech",
];

/// Decodes a Wavefront OBJ mesh; `name` names the bytes in errors. Polygons are split into fans
/// of triangles from their first vertex, which is right for the convex polygons CAD tools write.
pub fn decode_obj(bytes: &[u8], name: &str) -> Result<TriMesh, IoError> {
    let bytes = bytes.strip_prefix(BOM).unwrap_or(bytes);
    // Bytes that are not UTF-8 become U+FFFD, which no keyword or number matches: the error names
    // the line.
    let text = String::from_utf8_lossy(bytes);
    let mut soup = Soup::default();
    let mut faces = 0;
    for (i, raw) in text.split('\n').enumerate() {
        let line = i + 1;
        let content = raw.split_once('#').map_or(raw, |(before, _)| before);
        let mut tokens = content.split_ascii_whitespace();
        let Some(keyword) = tokens.next() else { continue };
        match keyword {
            "v" => {
                let p = vertex(tokens, name, line)?;
                soup.push_vertex(p, Origin { at: At::Line(line), item: None }, name)?;
            }
            "f" => {
                let defined = soup.vertices.len();
                let refs = tokens
                    .map(|token| reference(token, defined, name, line))
                    .collect::<Result<Vec<u32>, IoError>>()?;
                if refs.len() < 3 {
                    return Err(syntax(
                        name,
                        line,
                        format!("face {faces} has {} vertices; a face has 3 or more", refs.len()),
                    ));
                }
                let origin = Origin { at: At::Line(line), item: Some((FACE, faces)) };
                for pair in refs[1..].windows(2) {
                    soup.push_triangle([refs[0], pair[0], pair[1]], origin);
                }
                faces += 1;
            }
            k if IGNORED.contains(&k) => {}
            k if FREE_FORM.contains(&k) => {
                return Err(syntax(
                    name,
                    line,
                    format!(
                        "free-form geometry ({}) is not read: export the shape as polygons",
                        shown(k)
                    ),
                ));
            }
            k => {
                return Err(syntax(
                    name,
                    line,
                    format!("expected a statement (v, f, vt, vn, g, …), found {}", shown(k)),
                ));
            }
        }
    }
    soup.finish(name)
}

/// The coordinates of a `v` statement, whose keyword is taken.
fn vertex<'a>(
    tokens: impl Iterator<Item = &'a str>,
    name: &str,
    line: usize,
) -> Result<[f64; 3], IoError> {
    const WHAT: [&str; 6] = ["x", "y", "z", "w or r", "g", "b"];
    let mut values = [0.0; 6];
    let mut count = 0;
    for token in tokens {
        let Some(slot) = values.get_mut(count) else {
            return Err(syntax(
                name,
                line,
                format!(
                    "a vertex has 3 coordinates, then a weight w or a colour r g b; found more \
                     numbers: {}",
                    shown(token)
                ),
            ));
        };
        *slot = token.parse().map_err(|_| {
            syntax(
                name,
                line,
                format!("expected the vertex's {}, found {}", WHAT[count], shown(token)),
            )
        })?;
        count += 1;
    }
    if count < 3 || count == 5 {
        let next = WHAT.get(count).copied().unwrap_or_default();
        return Err(syntax(name, line, format!("the line ends before the vertex's {next}")));
    }
    Ok([values[0], values[1], values[2]])
}

/// The vertex index a face's reference `token` names, when `defined` vertices are defined.
fn reference(token: &str, defined: usize, name: &str, line: usize) -> Result<u32, IoError> {
    let malformed = || {
        syntax(
            name,
            line,
            format!(
                "expected a vertex reference (a, a/t, a/t/n or a//n, integers), found {}",
                shown(token)
            ),
        )
    };
    let mut parts = token.split('/');
    let vertex = parts.next().unwrap_or_default();
    let texture = parts.next();
    let normal = parts.next();
    let integer = |part: &str| part.parse::<i64>().is_ok();
    let well_formed = parts.next().is_none()
        && match (texture, normal) {
            (None, _) => true,
            (Some(t), None) => integer(t),
            (Some(t), Some(n)) => (t.is_empty() || integer(t)) && integer(n),
        };
    let index: i64 = vertex.parse().map_err(|_| malformed())?;
    if !well_formed {
        return Err(malformed());
    }
    let found = match index {
        0 => {
            return Err(syntax(
                name,
                line,
                format!("{}: vertex index 0, but OBJ numbers vertices from 1", shown(token)),
            ));
        }
        i if i > 0 => usize::try_from(i - 1).ok().filter(|&i| i < defined),
        i => usize::try_from(i.unsigned_abs()).ok().and_then(|back| defined.checked_sub(back)),
    };
    let found = found.ok_or_else(|| {
        syntax(
            name,
            line,
            format!(
                "{} names vertex {index}, but {defined} vertices are defined before this line",
                shown(token)
            ),
        )
    })?;
    // `found < defined`, and vertices are counted in u32 as they are added.
    u32::try_from(found).map_err(|_| malformed())
}

/// Encodes `mesh` as OBJ: every vertex, unused ones included, then every triangle. Coordinates
/// print as the shortest decimals that read back bit-identical.
#[must_use]
pub fn encode_obj(mesh: &TriMesh) -> String {
    let mut out = String::from("# closed triangle mesh written by incise\n");
    for [x, y, z] in mesh.vertices() {
        let _ = writeln!(out, "v {x:?} {y:?} {z:?}");
    }
    for t in mesh.triangles() {
        let [a, b, c] = t.map(|i| u64::from(i) + 1);
        let _ = writeln!(out, "f {a} {b} {c}");
    }
    out
}
