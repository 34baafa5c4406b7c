use super::*;
use std::collections::HashMap;

/// The unit cube `[0, 1]³`: corner `c` at `(c & 1, (c >> 1) & 1, c >> 2)`, 12 triangles.
pub(crate) fn cube() -> TriMesh {
    let vertices =
        (0..8u32).map(|c| [f64::from(c & 1), f64::from((c >> 1) & 1), f64::from(c >> 2)]).collect();
    let triangles = vec![
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    TriMesh::new(vertices, triangles).expect("the cube is closed")
}

/// A sphere of radius 1 cm off the origin, subdivided `levels` times, with coordinates that no
/// short decimal writes exactly.
pub(crate) fn icosphere(levels: usize) -> TriMesh {
    incise_mesh::generate::icosphere([0.02, -0.01, 1.0 / 3.0], 0.01, levels)
}

/// The cube with a vertex no triangle uses, inserted in the middle of the list.
pub(crate) fn with_unused_vertex() -> TriMesh {
    let base = cube();
    let mut vertices = base.vertices().to_vec();
    vertices.insert(3, [5.0, 5.0, 5.0]);
    let triangles = base.triangles().iter().map(|t| t.map(|i| if i >= 3 { i + 1 } else { i }));
    TriMesh::new(vertices, triangles.collect()).expect("an unused vertex is allowed")
}

/// `mesh` with its coordinates rounded to `f32`, what binary STL holds.
pub(crate) fn rounded_to_f32(mesh: &TriMesh) -> TriMesh {
    let vertices = mesh.vertices().iter().map(|p| p.map(|c| f64::from(c as f32))).collect();
    TriMesh::new(vertices, mesh.triangles().to_vec()).expect("rounding keeps the mesh valid")
}

/// `mesh` as STL gives it back: the vertices the triangles use, in order of first appearance.
pub(crate) fn in_appearance_order(mesh: &TriMesh) -> TriMesh {
    let mut index: HashMap<u32, u32> = HashMap::new();
    let mut vertices = Vec::new();
    let triangles = mesh
        .triangles()
        .iter()
        .map(|t| {
            t.map(|i| {
                *index.entry(i).or_insert_with(|| {
                    vertices.push(mesh.vertices()[i as usize]);
                    vertices.len() as u32 - 1
                })
            })
        })
        .collect();
    TriMesh::new(vertices, triangles).expect("renumbering keeps the mesh valid")
}

fn bits(mesh: &TriMesh) -> Vec<[u64; 3]> {
    mesh.vertices().iter().map(|p| p.map(f64::to_bits)).collect()
}

/// The message of the error `decode` gives for `bytes`, checked to name `name`.
fn message(
    decode: fn(&[u8], &str) -> Result<TriMesh, IoError>,
    bytes: impl AsRef<[u8]>,
    name: &str,
) -> String {
    let e = decode(bytes.as_ref(), name).expect_err("the file is invalid");
    assert_eq!(e.file(), name);
    let m = e.to_string();
    assert!(m.starts_with(&format!("{name}: ")), "{m}");
    m
}

/// The line `needle` first appears on.
fn line_of(text: &str, needle: &str) -> usize {
    let at = text.find(needle).unwrap_or_else(|| panic!("{needle:?} is not in the text"));
    1 + text[..at].matches('\n').count()
}

#[test]
fn stl_ascii_round_trips_are_bit_identical() {
    for mesh in [cube(), icosphere(2), with_unused_vertex()] {
        let text = encode_stl_ascii(&mesh);
        let back = decode_stl(text.as_bytes(), "rt.stl").unwrap_or_else(|e| panic!("{e}"));
        let expected = in_appearance_order(&mesh);
        assert_eq!(back, expected);
        assert_eq!(bits(&back), bits(&expected));
    }
    // The welded vertices are the cube's corners, in order of first appearance.
    let back = decode_stl(encode_stl_ascii(&with_unused_vertex()).as_bytes(), "rt.stl").unwrap();
    assert_eq!(back.vertices().len(), 8);
    assert_eq!(back.vertices()[..3], [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]);
}

#[test]
fn stl_binary_round_trips_are_bit_identical() {
    for mesh in [cube(), icosphere(2), with_unused_vertex()] {
        let mesh = rounded_to_f32(&mesh);
        let bytes = encode_stl_binary(&mesh);
        assert_eq!(bytes.len(), 84 + 50 * mesh.triangles().len());
        assert!(!bytes.starts_with(b"solid"));
        let back = decode_stl(&bytes, "rt.stl").unwrap_or_else(|e| panic!("{e}"));
        let expected = in_appearance_order(&mesh);
        assert_eq!(back, expected);
        assert_eq!(bits(&back), bits(&expected));
    }
}

#[test]
fn obj_round_trips_are_bit_identical() {
    for mesh in [cube(), icosphere(2), with_unused_vertex()] {
        let text = encode_obj(&mesh);
        let back = decode_obj(text.as_bytes(), "rt.obj").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back, mesh, "vertices are kept as listed, unused ones included");
        assert_eq!(bits(&back), bits(&mesh));
    }
}

#[test]
fn binary_stl_whose_header_starts_with_solid_is_read_as_binary() {
    let mesh = rounded_to_f32(&icosphere(1));
    let mut bytes = encode_stl_binary(&mesh);
    let header = b"solid tool exported by a CAD tool\nfacet normal 0 0 1\n";
    bytes[..header.len()].copy_from_slice(header);
    assert_eq!(decode_stl(&bytes, "cad.stl").unwrap(), in_appearance_order(&mesh));
    // Cut short, it is still reported as binary: its size, not a line of its bytes.
    bytes.truncate(bytes.len() - 7);
    let m = message(decode_stl, &bytes, "cut.stl");
    assert!(m.starts_with("cut.stl: byte 80: binary STL (its header starts with \"solid\""), "{m}");
    assert!(m.ends_with("but the file holds 4,077: it is truncated"), "{m}");
}

#[test]
fn ascii_stl_is_tolerant_of_case_whitespace_and_several_solids() {
    let text = encode_stl_ascii(&cube());
    let (start, end) = (text.find("  facet").unwrap(), text.find("endsolid").unwrap());
    let facets: Vec<&str> = text[start..end].split_inclusive("endfacet\n").collect();
    assert_eq!(facets.len(), 12);
    let mut odd = String::from("\u{feff}  SOLID  tool part 7 \n");
    for (i, facet) in facets.iter().enumerate() {
        let facet = match i {
            // Normals are ignored, however a writer spells their NaN.
            0 => facet.replacen("normal 0.0 0.0 -1.0", "normal -nan 1.#QNAN -inf", 1),
            1 => facet.to_ascii_uppercase(),
            2 => facet.replace(' ', "\t"),
            3 => facet.replace('\n', " "),
            6 => format!(
                "endsolid tool part 7\nsolid  second\n{}",
                facet.replace("vertex", "VeRtEx")
            ),
            _ => (*facet).to_owned(),
        };
        odd.push_str(&facet);
    }
    odd.push_str("EndSolid second");
    let odd = format!("{}\0\0\0", odd.replace('\n', "\r\n"));
    assert!(odd.contains("-nan 1.#QNAN -inf"), "facet 0's normal is (0, 0, -1)");
    assert_eq!(decode_stl(odd.as_bytes(), "odd.stl").unwrap(), in_appearance_order(&cube()));
}

#[test]
fn stl_corners_are_welded_by_their_bits_with_both_zeros_one() {
    let text = encode_stl_ascii(&cube());
    // A writer that prints -0 for some zeros: the corners still weld.
    let negative = text.replacen("vertex 0.0 0.0 0.0", "vertex -0.0 0.0 -0e0", 1);
    assert_eq!(decode_stl(negative.as_bytes(), "z.stl").unwrap().vertices().len(), 8);
    // A corner one f64 step away is another point, so the surface is open there.
    let apart = text.replacen("vertex 1.0 1.0 1.0", "vertex 1.0000000000000002 1.0 1.0", 1);
    let m = message(decode_stl, &apart, "apart.stl");
    assert!(m.contains("is in no other triangle: the surface is open there"), "{m}");
}

/// A cube as quads, in every reference form, with statements the reader ignores.
pub(crate) const CUBE_OBJ: &str = "\
# a cube as quads
mtllib tool.mtl
o cube
v 0 0 0
v 1 0 0
v 0 1 0
v 1 1 0
f -4 -2 -1 -3  # bottom: corners 0 2 3 1, counted back from the last vertex
v 0 0 1 1.0
v 1 0 1
v 0 1 1 0.5 0.5 0.5
v 1 1 1
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
g top
usemtl steel
s off
f 5/1 6/2 8/3 7/4
f 1/1/1 2/2/1 6/3/1 5/4/1
f 3//1 7//1 8//1 4//1
f -8 -4 -2 -6
f 2 4 8 6
l 1 2
p 3
";

#[test]
fn obj_reads_quads_negative_indices_and_texture_and_normal_references() {
    let mesh = decode_obj(CUBE_OBJ.as_bytes(), "cube.obj").unwrap();
    let fans = vec![
        [0, 2, 3],
        [0, 3, 1],
        [4, 5, 7],
        [4, 7, 6],
        [0, 1, 5],
        [0, 5, 4],
        [2, 6, 7],
        [2, 7, 3],
        [0, 4, 6],
        [0, 6, 2],
        [1, 3, 7],
        [1, 7, 5],
    ];
    assert_eq!(mesh, TriMesh::new(cube().vertices().to_vec(), fans).unwrap());
    assert!((mesh.volume() - 1.0).abs() < 1e-15);
    // Windows line ends and a byte-order mark change nothing.
    let windows = format!("\u{feff}{}", CUBE_OBJ.replace('\n', "\r\n"));
    assert_eq!(decode_obj(windows.as_bytes(), "cube.obj").unwrap(), mesh);
}

#[test]
fn stl_errors_name_the_line_or_byte_and_the_facet() {
    let text = encode_stl_ascii(&cube());
    let m = message(decode_stl, text.replacen("    endloop\n", "", 1), "a.stl");
    assert_eq!(m, "a.stl: line 7: facet 0: expected \"endloop\", found \"endfacet\"");
    let m =
        message(decode_stl, text.replacen("vertex 1.0 0.0 0.0", "vertex 1.0 O.0 0.0", 1), "a.stl");
    assert_eq!(m, "a.stl: line 6: facet 0: expected the vertex's y, found \"O.0\"");
    let m = message(decode_stl, text.replace("endsolid incise\n", ""), "a.stl");
    assert_eq!(m, "a.stl: line 85: the file ends before \"endsolid\"");
    let m = message(decode_stl, text.replacen("outer loop", "outer", 1), "a.stl");
    assert_eq!(m, "a.stl: line 4: facet 0: expected \"loop\", found \"vertex\"");
    let m = message(decode_stl, format!("{text}junk\n"), "a.stl");
    assert!(m.starts_with("a.stl: line 87: expected \"solid\" or the end of the file"), "{m}");

    let bytes = encode_stl_binary(&cube());
    assert_eq!(bytes.len(), 684);
    let m = message(decode_stl, &bytes[..654], "t.stl");
    assert_eq!(
        m,
        "t.stl: byte 80: binary STL: the header counts 12 triangles, which take 684 bytes \
         (84 + 50 per triangle), but the file holds 654: it is truncated"
    );
    let m = message(decode_stl, [bytes.as_slice(), &[0; 30]].concat(), "t.stl");
    assert!(m.ends_with("the file holds 714: 30 bytes follow the last triangle"), "{m}");
    for short in [&b""[..], b"hello", &bytes[..83]] {
        let m = message(decode_stl, short, "s.stl");
        assert!(m.contains("not STL") && m.contains("too short for binary STL"), "{m}");
    }
}

#[test]
fn huge_binary_counts_are_errors_not_allocations() {
    let mut bytes = vec![b' '; 100];
    bytes[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    let m = message(decode_stl, &bytes, "big.stl");
    assert!(m.contains("counts 4,294,967,295 triangles, which take 214,748,364,834 bytes"), "{m}");
}

#[test]
fn obj_errors_name_the_line_and_the_reference() {
    let last = line_of(CUBE_OBJ, "f 2 4 8 6");
    let m = message(decode_obj, CUBE_OBJ.replace("f 2 4 8 6", "f 2 4 8 0"), "e.obj");
    assert_eq!(
        m,
        format!("e.obj: line {last}: \"0\": vertex index 0, but OBJ numbers vertices from 1")
    );
    let m = message(decode_obj, CUBE_OBJ.replace("f 2 4 8 6", "f 2 4 8 9/1/1"), "e.obj");
    assert_eq!(
        m,
        format!(
            "e.obj: line {last}: \"9/1/1\" names vertex 9, but 8 vertices are defined before \
             this line"
        )
    );
    let bottom = line_of(CUBE_OBJ, "f -4");
    let m = message(decode_obj, CUBE_OBJ.replace("f -4 -2 -1 -3", "f -4 -2 -1 -5"), "e.obj");
    assert_eq!(
        m,
        format!(
            "e.obj: line {bottom}: \"-5\" names vertex -5, but 4 vertices are defined before \
             this line"
        )
    );
    for (bad, what) in [
        (
            "f 2 4 8 6/",
            "expected a vertex reference (a, a/t, a/t/n or a//n, integers), found \"6/\"",
        ),
        ("f 2 4 8 6/1/2/3", "expected a vertex reference"),
        ("f 2 4 8 six", "found \"six\""),
        ("f 2 4", "face 5 has 2 vertices; a face has 3 or more"),
        ("surf 0 1 0 1 1 2 3", "free-form geometry (\"surf\") is not read"),
        ("fo 2 4 8 6", "expected a statement (v, f, vt, vn, g, …), found \"fo\""),
    ] {
        let m = message(decode_obj, CUBE_OBJ.replace("f 2 4 8 6", bad), "e.obj");
        assert!(m.starts_with(&format!("e.obj: line {last}: ")) && m.contains(what), "{bad}: {m}");
    }
    let top = line_of(CUBE_OBJ, "v 1 1 1");
    for (bad, what) in [
        ("v 1 1", "the line ends before the vertex's z"),
        ("v 1 1 1 0.2 0.2", "the line ends before the vertex's b"),
        ("v 1 1 1 1 1 1 1", "found more numbers: \"1\""),
        ("v 1 1 one", "expected the vertex's z, found \"one\""),
    ] {
        let m = message(decode_obj, CUBE_OBJ.replace("v 1 1 1", bad), "e.obj");
        assert!(m.starts_with(&format!("e.obj: line {top}: ")) && m.contains(what), "{bad}: {m}");
    }
    message(decode_obj, "", "empty.obj");
}

#[test]
fn broken_surfaces_name_the_facets_and_faces_involved() {
    // An open cube: the last facet missing. Triangle 3 is the first to have one of its edges.
    let text = encode_stl_ascii(&cube());
    let cut = text.rfind("  facet").unwrap();
    let open = format!("{}endsolid incise\n", &text[..cut]);
    let e = decode_stl(open.as_bytes(), "open.stl").unwrap_err();
    assert!(
        matches!(&e, IoError::TriMesh { source, .. }
            if matches!(**source, TriMeshError::OpenEdge { triangle: 3, .. })),
        "{e}"
    );
    let m = message(decode_stl, &open, "open.stl");
    assert!(m.starts_with("open.stl: line 23: facet 3: triangle 3's edge "), "{m}");
    assert!(m.ends_with("(from [1.0, 0.0, 1.0] to [1.0, 1.0, 1.0]) is in no other triangle: the surface is open there"), "{m}");

    // Facet 7 wound the other way: it and facet 3 run along one edge in the same direction.
    let lines: Vec<&str> = text.lines().collect();
    let mut flipped = lines.clone();
    // Lines from 0: facet k's keyword is line 1 + 7k, its corners 3 + 7k to 5 + 7k.
    flipped.swap(4 + 7 * 7, 5 + 7 * 7);
    let flipped = flipped.join("\n");
    let m = message(decode_stl, &flipped, "w.stl");
    assert!(
        m.starts_with(
            "w.stl: line 51: facet 7, with facet 3 (line 23): triangles 3 and 7 both run along \
             edge "
        ),
        "{m}"
    );
    assert!(
        m.ends_with("in the same direction: their windings disagree, so one of them faces inwards"),
        "{m}"
    );

    let nan = text.replacen("vertex 0.0 0.0 0.0", "vertex 0.0 nan 0.0", 1);
    let m = message(decode_stl, &nan, "nan.stl");
    assert_eq!(m, "nan.stl: line 4: facet 0: vertex 0 has a non-finite coordinate [0.0, NaN, 0.0]");
    let mut bytes = encode_stl_binary(&cube());
    // Facet 5's second corner's y; every corner of the cube is known by then.
    bytes[84 + 5 * 50 + 24 + 4..][..4].copy_from_slice(&f32::NAN.to_le_bytes());
    let m = message(decode_stl, &bytes, "nan.stl");
    assert!(
        m.starts_with("nan.stl: byte 358: facet 5: vertex 8 has a non-finite coordinate"),
        "{m}"
    );
    let mut bytes = encode_stl_binary(&cube());
    bytes.truncate(84 + 11 * 50);
    bytes[80..84].copy_from_slice(&11u32.to_le_bytes());
    let m = message(decode_stl, &bytes, "open.stl");
    assert!(m.starts_with("open.stl: byte 234: facet 3: triangle 3's edge "), "{m}");

    // The same in OBJ: a face missing, a face flipped, a coordinate not a number.
    let last = line_of(CUBE_OBJ, "f 2 4 8 6");
    let m = message(decode_obj, CUBE_OBJ.replace("f 2 4 8 6\n", ""), "open.obj");
    assert!(
        m.contains(": face 0: triangle 1's edge [3, 1]") && m.contains("the surface is open"),
        "{m}"
    );
    let m = message(decode_obj, CUBE_OBJ.replace("f 2 4 8 6", "f 6 8 4 2"), "w.obj");
    let bottom = line_of(CUBE_OBJ, "f -4");
    assert!(
        m.starts_with(&format!(
            "w.obj: line {last}: face 5, with face 0 (line {bottom}): triangles 1 and "
        )),
        "{m}"
    );
    let top = line_of(CUBE_OBJ, "v 1 1 1");
    let m = message(decode_obj, CUBE_OBJ.replace("v 1 1 1", "v 1 NaN 1"), "nan.obj");
    assert_eq!(
        m,
        format!("nan.obj: line {top}: vertex 7 has a non-finite coordinate [1.0, NaN, 1.0]")
    );
}

#[test]
fn read_tri_mesh_picks_the_format_by_extension() {
    let dir = std::env::temp_dir().join(format!("incise_io_tri_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mesh = rounded_to_f32(&icosphere(1));
    let expected = in_appearance_order(&mesh);
    for (file, bytes, expected) in [
        ("a.stl", encode_stl_ascii(&mesh).into_bytes(), &expected),
        ("B.STL", encode_stl_binary(&mesh), &expected),
        ("c.Obj", encode_obj(&mesh).into_bytes(), &mesh),
    ] {
        let path = dir.join(file);
        std::fs::write(&path, bytes).unwrap();
        assert_eq!(&read_tri_mesh(&path).unwrap(), expected, "{file}");
    }
    let ply = dir.join("m.ply");
    std::fs::write(&ply, "ply\n").unwrap();
    let e = read_tri_mesh(&ply).unwrap_err();
    assert!(matches!(e, IoError::UnsupportedType { .. }), "{e}");
    assert!(e.to_string().contains(".stl (STL, binary or ASCII) and .obj"), "{e}");
    let missing = read_tri_mesh(&dir.join("none.obj")).unwrap_err();
    assert!(matches!(missing, IoError::Io { .. }), "{missing}");
    let _ = std::fs::remove_dir_all(&dir);
}
