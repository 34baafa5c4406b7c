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
    decode: fn(&[u8], &str) -> Result<TetMesh, IoError>,
    text: impl AsRef<[u8]>,
    name: &str,
) -> String {
    let e = decode(text.as_ref(), name).expect_err("the text is invalid");
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
    expect(&decode_gmsh(MSH22.as_bytes(), "a.msh").unwrap(), [7, 8]);
    // Windows line ends and a byte-order mark change nothing.
    let windows = format!("\u{feff}{}", MSH22.replace('\n', "\r\n"));
    expect(&decode_gmsh(windows.as_bytes(), "a.msh").unwrap(), [7, 8]);
    // An element without tags gets the default region.
    let untagged = MSH22.replace("3 4 2 7 1 10 20 30 40", "3 4 0 10 20 30 40");
    expect(&decode_gmsh(untagged.as_bytes(), "a.msh").unwrap(), [1, 8]);
}

#[test]
fn gmsh41_maps_entities_to_physical_tags() {
    // Volume 3 has physical tag 42; volume 4 has none, so its entity tag is the region.
    expect(&decode_gmsh(MSH41.as_bytes(), "b.msh").unwrap(), [42, 4]);
    // Without $Entities every region is the entity tag.
    let start = MSH41.find("$Entities").unwrap();
    let end = MSH41.find("$Nodes").unwrap();
    let bare = format!("{}{}", &MSH41[..start], &MSH41[end..]);
    expect(&decode_gmsh(bare.as_bytes(), "b.msh").unwrap(), [3, 4]);
}

#[test]
fn gmsh_errors_name_the_line_and_element() {
    let m = message(decode_gmsh, MSH22.replace("1 10 20 30 40", "1 10 20 30 99"), "c.msh");
    assert!(m.contains("line 21") && m.contains("element 3") && m.contains("node 99"), "{m}");
    let m = message(decode_gmsh, MSH41.replace("5 10 20 30 40", "5 10 20 30 41"), "c.msh");
    assert!(m.contains("line 31") && m.contains("element 5") && m.contains("node 41"), "{m}");
    let twice = MSH22.replace("7 1 1 1", "20 1 1 1");
    let m = message(decode_gmsh, &twice, "c.msh");
    assert!(
        m.contains("line 15") && m.contains("node 20 is defined twice (first on line 12)"),
        "{m}"
    );
    // A tetrahedron flattened into a plane: the mesh check names the element and its line.
    let flat = MSH22.replace("7 1 1 1", "7 0.5 0.5 0");
    let e = decode_gmsh(flat.as_bytes(), "c.msh").unwrap_err();
    assert!(matches!(e, IoError::Mesh { source: TetMeshError::Degenerate { tet: 1, .. }, .. }));
    let m = e.to_string();
    assert!(m.starts_with("c.msh: line 22: element 9: tetrahedron 1"), "{m}");
    let m = message(decode_gmsh, MSH22.replace("7 1 1 1", "7 1 nan 1"), "c.msh");
    assert!(m.starts_with("c.msh: line 15: node 7: vertex 4 has a non-finite"), "{m}");
    let m = message(decode_gmsh, MSH22.replace("20 1 0 0", "20 1 zero 0"), "c.msh");
    assert!(m.contains("line 12") && m.contains("\"zero\""), "{m}");
    let m = message(decode_gmsh, MSH41.replace("3 3 1 12", "3 4 1 12"), "c.msh");
    assert!(m.contains("announces 4 elements, its blocks hold 3"), "{m}");
}

#[test]
fn gmsh_binary_other_than_41_and_other_versions_are_refused() {
    let binary = "$MeshFormat\n2.2 1 8\n\u{1}\0\0\0\n$EndMeshFormat\n";
    let e = decode_gmsh(binary.as_bytes(), "bin.msh").unwrap_err();
    assert!(matches!(e, IoError::UnsupportedType { .. }));
    assert!(e.to_string().contains("binary MSH 2.2: binary files are read in version 4.1"), "{e}");
    // Binary 4.1 with no sections after its format: the error is at the byte where it ends.
    let m = message(decode_gmsh, "$MeshFormat\n4.1 1 8\n\u{1}\0\0\0\n$EndMeshFormat\n", "b.msh");
    assert!(m.contains("byte 40") && m.contains("no $Nodes section"), "{m}");
    let m = message(decode_gmsh, "$MeshFormat\n4.1 1 8\n\u{2}\0\0\0\n$EndMeshFormat\n", "b.msh");
    assert!(m.contains("byte 20") && m.contains("endianness check"), "{m}");
    let m = message(decode_gmsh, "$MeshFormat\n4.1 1 2\n\u{1}\0\0\0\n$EndMeshFormat\n", "b.msh");
    assert!(m.contains("line 2") && m.contains("data-size \"2\""), "{m}");
    let m = message(decode_gmsh, MSH41.replace("4.1 0 8", "4.0 0 8"), "old.msh");
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
            assert!(decode_gmsh(cut.as_bytes(), "cut.msh").is_err(), "{keep} lines: {cut}");
        }
    }
}

#[test]
fn huge_counts_end_in_errors_not_allocations() {
    let nodes = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1000000000000\n1 0 0 0\n$EndNodes\n";
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
    expect(&decode_vtk_legacy(VTK.as_bytes(), "a.vtk").unwrap(), [3, 6]);
    let windows = format!("\u{feff}{}", VTK.replace('\n', "\r\n"));
    expect(&decode_vtk_legacy(windows.as_bytes(), "a.vtk").unwrap(), [3, 6]);
    let no_data = &VTK[..VTK.find("POINT_DATA").unwrap()];
    expect(&decode_vtk_legacy(no_data.as_bytes(), "a.vtk").unwrap(), [1, 1]);
}

#[test]
fn vtk_legacy_reads_the_vtk5_layout_and_field_arrays() {
    expect(&decode_vtk_legacy(VTK51.as_bytes(), "b.vtk").unwrap(), [2, 5]);
}

#[test]
fn vtk_legacy_errors_name_the_line_and_cell() {
    let m = message(decode_vtk_legacy, VTK.replace("4 1 2 4 3", "4 1 2 5 3"), "c.vtk");
    assert!(m.contains("line 12") && m.contains("cell 2 names point 5"), "{m}");
    let m = message(decode_vtk_legacy, VTK.replace("4 1 2 4 3", "4 1 2 -1 3"), "c.vtk");
    assert!(m.contains("cell 2 names point -1"), "{m}");
    let m = message(decode_vtk_legacy, VTK51.replace("0 4 7 11", "0 4 3 11"), "c.vtk");
    assert!(m.contains("line 13") && m.contains("offset 2 is 3"), "{m}");
    let m = message(decode_vtk_legacy, VTK.replace("3 0 6", "3 0 -6"), "c.vtk");
    assert!(m.contains("line 27") && m.contains("cell 2: region label -6"), "{m}");
    let m = message(decode_vtk_legacy, VTK.replace("CELLS 3 14", "CELLS 3 15"), "c.vtk");
    assert!(m.contains("line 9") && m.contains("size 15"), "{m}");
    let m = message(
        decode_vtk_legacy,
        VTK.replace("4 1 2 4 3", "3 1 2 4").replace("CELLS 3 14", "CELLS 3 13"),
        "c.vtk",
    );
    assert!(m.contains("cell 2 has type 10 (tetra) but 3 points"), "{m}");
    // ASCII values in a file that says BINARY: 45 bytes of text are not 15 floats and the
    // cells.
    let binary = VTK.replace("\nASCII\n", "\nBINARY\n");
    let e = decode_vtk_legacy(binary.as_bytes(), "bin.vtk").unwrap_err();
    assert!(matches!(e, IoError::Binary { .. }), "{e}");
    let m = message(decode_vtk_legacy, VTK.replace("UNSTRUCTURED_GRID", "POLYDATA"), "p.vtk");
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
            assert!(decode_vtk_legacy(cut.as_bytes(), "cut.vtk").is_err(), "{keep} lines: {cut}");
        }
    }
}

#[test]
fn vtu_reads_ascii_arrays_and_prefers_the_named_scalars() {
    expect(&decode_vtu(VTU.as_bytes(), "a.vtu").unwrap(), [3, 6]);
    let windows = format!("\u{feff}{}", VTU.replace('\n', "\r\n"));
    expect(&decode_vtu(windows.as_bytes(), "a.vtu").unwrap(), [3, 6]);
    let unnamed = VTU.replace(" Scalars=\"tissue\"", "");
    expect(&decode_vtu(unnamed.as_bytes(), "a.vtu").unwrap(), [7, 7]);
    let start = VTU.find("<CellData").unwrap();
    let end = VTU.find("<Points>").unwrap();
    let bare = format!("{}{}", &VTU[..start], &VTU[end..]);
    expect(&decode_vtu(bare.as_bytes(), "a.vtu").unwrap(), [1, 1]);
}

#[test]
fn vtu_pieces_are_joined() {
    let mesh = cylinder(0.01, 0.03, 2, 1);
    let one = encode_vtu(&mesh);
    let start = one.find("<Piece").unwrap();
    let end = one.find("</Piece>").unwrap() + "</Piece>".len();
    let two = format!("{}{}{}", &one[..end], &one[start..end], &one[end..]);
    let joined = decode_vtu(two.as_bytes(), "two.vtu").unwrap();
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
        VTU.replace("0 1 2 3  1 2 3  1 2 4 3", "0 1 2 3 1 2 3 1 2 4 7"),
        "c.vtu",
    );
    assert!(m.contains("line 27") && m.contains("cell 2 names point 7, but there are 5"), "{m}");
    let appended = VTU.replace(
        r#"<DataArray type="Float32" NumberOfComponents="3" format="ascii">"#,
        r#"<DataArray type="Float32" NumberOfComponents="3" format="appended" offset="0">"#,
    );
    let m = message(decode_vtu, &appended, "d.vtu");
    assert!(m.contains("line 17") && m.contains("the file has no <AppendedData>"), "{m}");
    // "4 7 11" read as base64 is three bytes, short of the four-byte header.
    let binary =
        VTU.replace(r#"Name="offsets" format="ascii""#, r#"Name="offsets" format="binary""#);
    let m = message(decode_vtu, &binary, "d.vtu");
    assert!(
        m.contains("line 27: DataArray \"offsets\": the header (byte count): needs 4 bytes"),
        "{m}"
    );
    let m = message(decode_vtu, VTU.replace(">4 7 11<", ">4 3 11<"), "e.vtu");
    assert!(m.contains("offset 1 is 3"), "{m}");
    let m = message(
        decode_vtu,
        VTU.replace("UnstructuredGrid\" version", "PolyData\" version"),
        "f.vtu",
    );
    assert!(m.contains("type=\"PolyData\""), "{m}");
    let m = message(decode_vtu, VTU.replace("</Cells>", "</Cell>"), "g.vtu");
    assert!(m.contains("line 29") && m.contains("</Cell> closes <Cells>"), "{m}");
    let m = message(decode_vtu, "<html></html>", "h.vtu");
    assert!(m.contains("expected <VTKFile>"), "{m}");
}

#[test]
fn vtu_truncated_files_are_errors() {
    let lines: Vec<&str> = VTU.lines().collect();
    for keep in 0..lines.len() {
        let cut = lines[..keep].join("\n");
        assert!(decode_vtu(cut.as_bytes(), "cut.vtu").is_err(), "{keep} lines: {cut}");
    }
    for cut in (0..VTU.len()).filter(|&i| VTU.is_char_boundary(i)).step_by(7) {
        if !VTU[..cut].contains("</VTKFile>") {
            assert!(decode_vtu(&VTU.as_bytes()[..cut], "cut.vtu").is_err(), "{cut} bytes");
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
            "msh" => decode_gmsh(text.as_bytes(), "rt.msh"),
            "vtk" => decode_vtk_legacy(text.as_bytes(), "rt.vtk"),
            _ => decode_vtu(text.as_bytes(), "rt.vtu"),
        }
        .unwrap_or_else(|e| panic!("{format}: {e}"));
        assert_eq!(back, mesh, "{format}");
        assert_eq!(bits(&back), bits(&mesh), "{format}");
    }
    // Labels beyond i32 are written as unsigned and read back.
    let big = TetMesh::new(VERTICES[..4].to_vec(), vec![TETS[0]], vec![u32::MAX]).unwrap();
    assert_eq!(decode_vtk_legacy(encode_vtk_legacy(&big).as_bytes(), "u.vtk").unwrap(), big);
    assert_eq!(decode_vtu(encode_vtu(&big).as_bytes(), "u.vtu").unwrap(), big);
    assert_eq!(decode_gmsh(encode_gmsh22(&big).as_bytes(), "u.msh").unwrap(), big);
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
    // Binary files are read as bytes, never as text.
    for (file, bytes) in [
        ("b.msh", encode_gmsh41_binary(&mesh).unwrap()),
        ("b.vtk", encode_vtk_legacy_binary(&mesh, VtkCells::Classic)),
        ("b.vtu", encode_vtu_binary(&mesh, VtuBinary::default())),
    ] {
        let path = dir.join(file);
        std::fs::write(&path, bytes).unwrap();
        assert_eq!(read_tet_mesh(&path).unwrap(), mesh, "{file}");
    }
    let binary = dir.join("bad.msh");
    std::fs::write(&binary, b"$MeshFormat\n4.1 1 8\n\x01\x00\x00\x00\xff\xfe\n$EndMeshFormat\n")
        .unwrap();
    let e = read_tet_mesh(&binary).unwrap_err();
    assert!(e.to_string().contains("byte 24: expected $EndMeshFormat, found"), "{e}");
    let missing = read_tet_mesh(&dir.join("none.vtu")).unwrap_err();
    assert!(matches!(missing, IoError::Io { .. }), "{missing}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every binary variant the encoders write.
fn binary_encodings(mesh: &TetMesh) -> Vec<(String, &'static str, Vec<u8>)> {
    let mut out = vec![
        ("msh 4.1 binary".to_owned(), "msh", encode_gmsh41_binary(mesh).unwrap()),
        ("vtk classic".to_owned(), "vtk", encode_vtk_legacy_binary(mesh, VtkCells::Classic)),
        (
            "vtk 5.1".to_owned(),
            "vtk",
            encode_vtk_legacy_binary(mesh, VtkCells::OffsetsConnectivity),
        ),
    ];
    for data in [VtuData::Inline, VtuData::AppendedBase64, VtuData::AppendedRaw] {
        for zlib in [false, true] {
            for header64 in [false, true] {
                for big_endian in [false, true] {
                    // Small blocks, so that arrays span several and end in a partial one.
                    let options = VtuBinary { data, zlib, header64, big_endian, block_size: 100 };
                    out.push((format!("{options:?}"), "vtu", encode_vtu_binary(mesh, options)));
                }
            }
        }
    }
    out
}

fn decode_by(format: &str, bytes: &[u8], name: &str) -> Result<TetMesh, IoError> {
    match format {
        "msh" => decode_gmsh(bytes, name),
        "vtk" => decode_vtk_legacy(bytes, name),
        _ => decode_vtu(bytes, name),
    }
}

#[test]
fn binary_round_trips_are_bit_identical() {
    let mesh = awkward_mesh();
    for (what, format, bytes) in binary_encodings(&mesh) {
        let back = decode_by(format, &bytes, "rt").unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(back, mesh, "{what}");
        assert_eq!(bits(&back), bits(&mesh), "{what}");
    }
    // Labels beyond i32 are written as unsigned and read back; MSH's int tags cannot hold them.
    let big = TetMesh::new(VERTICES[..4].to_vec(), vec![TETS[0]], vec![u32::MAX]).unwrap();
    for cells in [VtkCells::Classic, VtkCells::OffsetsConnectivity] {
        let bytes = encode_vtk_legacy_binary(&big, cells);
        assert_eq!(decode_vtk_legacy(&bytes, "u.vtk").unwrap(), big);
    }
    let bytes = encode_vtu_binary(&big, VtuBinary { zlib: true, ..VtuBinary::default() });
    assert_eq!(decode_vtu(&bytes, "u.vtu").unwrap(), big);
    let e = encode_gmsh41_binary(&big).unwrap_err();
    assert!(e.to_string().contains("region 4294967295"), "{e}");
}

#[test]
fn binary_msh_reads_either_byte_order() {
    // Regions alternate, so the encoder writes one element block per tetrahedron.
    let mesh = awkward_mesh();
    for big in [false, true] {
        let bytes = gmsh::encode_gmsh41_binary_in(&mesh, big).unwrap();
        assert_eq!(decode_gmsh(&bytes, "o.msh").unwrap(), mesh, "big-endian: {big}");
        // The wrong endianness check: every count reads byte-swapped, and the first, the
        // number of point entities, is refused before anything is read or allocated.
        let start = "$MeshFormat\n4.1 1 8\n".len();
        let mut swapped = bytes.clone();
        swapped[start..start + 4].reverse();
        let m = message(decode_gmsh, &swapped, "o.msh");
        assert!(m.contains("announces") && m.contains("the file holds"), "{m}");
    }
}

#[test]
fn binary_errors_name_the_byte_or_the_array() {
    let mesh = awkward_mesh();
    // MSH: a node naming a tag that does not exist, and a count beyond the file.
    let bytes = encode_gmsh41_binary(&mesh).unwrap();
    let elements = find_bytes(&bytes, b"$Elements\n", 0).unwrap() + 10;
    let mut bad = bytes.clone();
    // The header: 4 size_t; the first block: 3 ints and a size_t; then the first element's tag
    // and its first node.
    let node = elements + 32 + 12 + 8 + 8;
    bad[node..node + 8].copy_from_slice(&999_999u64.to_le_bytes());
    let m = message(decode_gmsh, &bad, "e.msh");
    let at = grouped((node - 8) as u64);
    assert!(
        m.contains(&format!("byte {at}: element 1 names node 999999, which $Nodes does not")),
        "{m}"
    );
    let mut huge = bytes.clone();
    huge[elements..elements + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
    let m = message(decode_gmsh, &huge, "e.msh");
    assert!(
        m.contains(&format!("byte {}", grouped(elements as u64 + 8)))
            && m.contains("announces 1,099,511,627,776 element blocks of 20 bytes each"),
        "{m}"
    );

    // Legacy VTK: POINTS announcing more than the file holds, and a cell naming a missing point.
    let bytes = encode_vtk_legacy_binary(&mesh, VtkCells::Classic);
    let n = mesh.vertices().len();
    let huge = String::from_utf8_lossy(&bytes).replacen(
        &format!("POINTS {n} double"),
        "POINTS 1000000000000 double",
        1,
    );
    let m = message(decode_vtk_legacy, huge.as_bytes(), "e.vtk");
    assert!(m.contains("POINTS announces 3,000,000,000,000 values of double"), "{m}");
    let cells = find_bytes(&bytes, b"\nCELLS ", 0).unwrap();
    let data = find_bytes(&bytes, b"\n", cells + 1).unwrap() + 1;
    let mut bad = bytes.clone();
    bad[data + 4..data + 8].copy_from_slice(&(n as i32).to_be_bytes());
    let m = message(decode_vtk_legacy, &bad, "e.vtk");
    assert!(m.contains(&format!("byte {}: cell 0 names point {n}", grouped(data as u64))), "{m}");

    // VTU: a zlib block that does not inflate, a byte count beyond the data, a bad offset.
    for data in [VtuData::Inline, VtuData::AppendedRaw] {
        let options = VtuBinary { data, zlib: true, ..VtuBinary::default() };
        let bytes = encode_vtu_binary(&mesh, options);
        let text = String::from_utf8_lossy(&bytes);
        let line = text.lines().position(|l| l.contains("Name=\"offsets\"")).unwrap() + 1;
        // Corrupt the offsets array's zlib stream header (its first compressed byte).
        let mut bad = bytes.clone();
        if data == VtuData::AppendedRaw {
            let start = find_bytes(&bytes, b"_", find_bytes(&bytes, b"<AppendedData", 0).unwrap())
                .unwrap()
                + 1;
            let offset: usize = text
                .lines()
                .nth(line - 1)
                .and_then(|l| l.split("offset=\"").nth(1))
                .and_then(|o| o.split('"').next())
                .unwrap()
                .parse()
                .unwrap();
            // One block: the 4 header entries of 4 bytes, then the stream.
            bad[start + offset + 16] ^= 0xff;
            let m = message(decode_vtu, &bad, "e.vtu");
            assert!(
                m.contains(&format!("line {line}: DataArray \"offsets\": appended data from offset {offset}: zlib block 1 of 1 does not inflate")),
                "{m}"
            );
        } else {
            let m = message(
                decode_vtu,
                text.replacen("format=\"binary\">\n", "format=\"binary\">\nA!", 1).as_bytes(),
                "e.vtu",
            );
            assert!(
                m.contains(
                    "line 6: the <Points> DataArray: the header (block count): \
                            character 2 of the base64 text, '!', is not base64 here"
                ),
                "{m}"
            );
        }
    }
    let bytes =
        encode_vtu_binary(&mesh, VtuBinary { data: VtuData::AppendedRaw, ..VtuBinary::default() });
    let text = String::from_utf8_lossy(&bytes);
    let huge = text.replacen("offset=\"0\"", "offset=\"1000000000000\"", 1);
    let m = message(decode_vtu, huge.as_bytes(), "e.vtu");
    assert!(m.contains("offset 1000000000000 is beyond the"), "{m}");
    // A header announcing 2^32 - 1 bytes in a short file.
    let start =
        find_bytes(&bytes, b"_", find_bytes(&bytes, b"<AppendedData", 0).unwrap()).unwrap() + 1;
    let mut bad = bytes.clone();
    bad[start..start + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    let m = message(decode_vtu, &bad, "e.vtu");
    assert!(m.contains("the header announces 4,294,967,295 bytes, at most"), "{m}");
    let m = message(
        decode_vtu,
        text.replacen("<VTKFile ", "<VTKFile compressor=\"vtkLZ4DataCompressor\" ", 1).as_bytes(),
        "e.vtu",
    );
    assert!(m.contains("compressor \"vtkLZ4DataCompressor\" is not supported"), "{m}");
}

#[test]
fn binary_truncated_files_are_errors() {
    let mesh = cylinder(0.01, 0.03, 2, 1);
    for (what, format, bytes) in binary_encodings(&mesh) {
        // The last bytes are closing text the readers do not all need; legacy VTK's attribute
        // data is optional, as in ASCII files.
        let end = match format {
            "vtu" => find_bytes(&bytes, b"</VTKFile>", 0).unwrap(),
            "vtk" => find_bytes(&bytes, b"CELL_DATA", 0).unwrap(),
            _ => find_bytes(&bytes, b"$EndElements", 0).unwrap() + 1,
        };
        for cut in (0..end).step_by(3) {
            assert!(decode_by(format, &bytes[..cut], "cut").is_err(), "{what}: {cut} bytes");
        }
    }
}
