//! Files as other tools write them: volumes built byte by byte (big-endian NIfTI and INR, float
//! and signed voxel types, scaled values, units, and the three NIfTI placement methods), and
//! tetrahedral meshes written by meshio and VTK themselves (`data/foreign`, made by
//! `make_foreign.py` there), in every encoding those tools write by default or on request.

#![allow(clippy::float_cmp, reason = "exact values are written and must read back exactly")]

mod common;

use common::{Nifti, assert_close, gz, inr_file};
use incise_io::{
    MeshFile, MeshOptions, decode_gmsh, decode_gmsh_with, decode_inr, decode_nifti,
    decode_vtk_legacy, decode_vtk_legacy_with, decode_vtu, decode_vtu_with,
};
use incise_mesh::TetMesh;

fn labels_le<T: Copy>(values: &[T], to: impl Fn(T) -> Vec<u8>) -> Vec<u8> {
    values.iter().flat_map(|&v| to(v)).collect()
}

#[test]
fn big_endian_nifti_reads_like_little_endian() {
    let values: Vec<i16> = vec![0, 1, 2, 300, 4, 5, 6, 7];
    let mut h = Nifti::new([2, 2, 2], 4, 16);
    h.pixdim = [1.0, 0.9, 0.8, 3.0, 0.0, 0.0, 0.0, 0.0];
    h.qform_code = 1;
    h.qoffset = [10.0, -20.0, 30.0];
    let le = h.file(&labels_le(&values, |v| v.to_le_bytes().to_vec()));
    h.big_endian = true;
    let be = h.file(&labels_le(&values, |v| v.to_be_bytes().to_vec()));
    assert_eq!(&be[0..4], &348i32.to_be_bytes());
    for bytes in [le, be.clone(), gz(&be)] {
        let v = decode_nifti(&bytes, "be.nii").unwrap();
        assert_eq!(v.dims(), [2, 2, 2]);
        assert_eq!(v.labels(), &[0, 1, 2, 300, 4, 5, 6, 7]);
        assert_close(&v.spacing(), &[0.9e-3, 0.8e-3, 3e-3], 1e-7, "spacing");
        assert_close(&v.origin(), &[0.01, -0.02, 0.03], 1e-7, "origin");
    }
}

#[test]
fn float32_nifti_labels_are_read_when_integral() {
    let values = [0.0f32, 1.0, 2.0, 255.0, 65535.0, -0.0];
    let h = Nifti::new([3, 2, 1], 16, 32);
    let v =
        decode_nifti(&h.file(&labels_le(&values, |v| v.to_le_bytes().to_vec())), "f.nii").unwrap();
    assert_eq!(v.labels(), &[0, 1, 2, 255, 65535, 0]);

    let mut h = Nifti::new([3, 2, 1], 64, 64);
    h.big_endian = true;
    let values = [3.0f64, 1.0, 2.0, 4.0, 5.0, 6.0];
    let v =
        decode_nifti(&h.file(&labels_le(&values, |v| v.to_be_bytes().to_vec())), "d.nii").unwrap();
    assert_eq!(v.labels(), &[3, 1, 2, 4, 5, 6]);
}

#[test]
fn every_integer_datatype_is_read() {
    let cases: [(i16, i16, Vec<u8>); 8] = [
        (2, 8, vec![7, 200]),
        (256, 8, vec![7, 100]),
        (4, 16, labels_le(&[7i16, 1000], |v| v.to_le_bytes().to_vec())),
        (512, 16, labels_le(&[7u16, 60000], |v| v.to_le_bytes().to_vec())),
        (8, 32, labels_le(&[7i32, 1000], |v| v.to_le_bytes().to_vec())),
        (768, 32, labels_le(&[7u32, 1000], |v| v.to_le_bytes().to_vec())),
        (1024, 64, labels_le(&[7i64, 1000], |v| v.to_le_bytes().to_vec())),
        (1280, 64, labels_le(&[7u64, 1000], |v| v.to_le_bytes().to_vec())),
    ];
    for (datatype, bitpix, data) in cases {
        let v = decode_nifti(&Nifti::new([2, 1, 1], datatype, bitpix).file(&data), "t.nii")
            .unwrap_or_else(|e| panic!("datatype {datatype}: {e}"));
        assert_eq!(v.labels()[0], 7, "datatype {datatype}");
    }
}

#[test]
fn scl_slope_and_inter_are_applied() {
    // Stored 0, 2, 4, 6 with slope 0.5 and intercept 10 encode labels 10..=13.
    let mut h = Nifti::new([4, 1, 1], 2, 8);
    h.scl_slope = 0.5;
    h.scl_inter = 10.0;
    let v = decode_nifti(&h.file(&[0, 2, 4, 6]), "s.nii").unwrap();
    assert_eq!(v.labels(), &[10, 11, 12, 13]);

    // A float32 slope of 0.1 is not exactly 0.1; the labels must still come out exact.
    h.scl_slope = 0.1;
    h.scl_inter = 0.0;
    let v = decode_nifti(&h.file(&[0, 10, 20, 250]), "s.nii").unwrap();
    assert_eq!(v.labels(), &[0, 1, 2, 25]);

    // Slope 0 means "no scaling" and slope 1, intercept 0 is the identity.
    for (slope, inter) in [(0.0, 99.0), (1.0, 0.0)] {
        h.scl_slope = slope;
        h.scl_inter = inter;
        assert_eq!(decode_nifti(&h.file(&[0, 1, 2, 3]), "s.nii").unwrap().labels(), &[0, 1, 2, 3]);
    }
}

#[test]
fn spatial_units_convert_to_metres() {
    for (units, to_metres) in [(0u8, 1e-3), (2, 1e-3), (1, 1.0), (3, 1e-6), (2 | 8, 1e-3)] {
        let mut h = Nifti::new([1, 1, 1], 2, 8);
        h.xyzt_units = units;
        h.pixdim = [1.0, 2.0, 3.0, 4.0, 0.0, 0.0, 0.0, 0.0];
        let v = decode_nifti(&h.file(&[1]), "u.nii").unwrap();
        let want = [2.0 * to_metres, 3.0 * to_metres, 4.0 * to_metres];
        assert_close(&v.spacing(), &want, 1e-7, "spacing");
    }
}

#[test]
fn sform_gives_spacing_direction_and_origin() {
    // Voxel axes: x → world -y (1.5 mm), y → world +x (0.5 mm), z → world +z (2 mm). pixdim is
    // deliberately wrong: with an sform, spacing comes from its column lengths.
    let mut h = Nifti::new([2, 1, 1], 2, 8);
    h.pixdim = [1.0, 9.0, 9.0, 9.0, 0.0, 0.0, 0.0, 0.0];
    h.sform_code = 2;
    h.qform_code = 1;
    h.quatern = [0.3, 0.3, 0.3];
    h.srow = [[0.0, 0.5, 0.0, -5.0], [-1.5, 0.0, 0.0, 6.0], [0.0, 0.0, 2.0, 7.0]];
    let v = decode_nifti(&h.file(&[1, 2]), "s.nii").unwrap();
    assert_close(&v.spacing(), &[1.5e-3, 0.5e-3, 2e-3], 1e-12, "spacing");
    assert_close(&v.origin(), &[-5e-3, 6e-3, 7e-3], 1e-12, "origin");
    assert_eq!(v.direction(), [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]);
}

#[test]
fn qform_quaternion_and_qfac_give_the_direction() {
    // 90° about z: (a, b, c, d) = (cos 45°, 0, 0, sin 45°). qfac = -1 flips the third axis.
    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.qform_code = 1;
    h.quatern = [0.0, 0.0, std::f32::consts::FRAC_1_SQRT_2];
    h.pixdim = [-1.0, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0];
    h.qoffset = [1.0, 2.0, 3.0];
    let v = decode_nifti(&h.file(&[5]), "q.nii").unwrap();
    let want = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]];
    assert_close(v.direction().as_flattened(), want.as_flattened(), 1e-7, "direction");
    assert_close(&v.spacing(), &[1e-3, 2e-3, 3e-3], 1e-7, "spacing");
    assert_close(&v.origin(), &[1e-3, 2e-3, 3e-3], 1e-7, "origin");
}

#[test]
fn nifti_without_transform_is_axis_aligned_at_the_origin() {
    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.qoffset = [5.0, 5.0, 5.0]; // ignored: qform_code is 0
    let v = decode_nifti(&h.file(&[5]), "n.nii").unwrap();
    assert_eq!(v.origin(), [0.0; 3]);
    assert_eq!(v.direction(), common::IDENTITY);
}

#[test]
fn lower_dimensional_and_single_frame_4d_images_are_volumes() {
    let mut h = Nifti::new([3, 2, 1], 2, 8);
    h.dim = [2, 3, 2, 0, 0, 0, 0, 0];
    h.pixdim[3] = 0.0; // meaningless for a 2-D image
    let v = decode_nifti(&h.file(&[1, 2, 3, 4, 5, 6]), "2d.nii").unwrap();
    assert_eq!(v.dims(), [3, 2, 1]);
    assert_close(&v.spacing(), &[1e-3; 3], 1e-12, "spacing");

    h.dim = [4, 3, 2, 1, 1, 7, 7, 7];
    h.pixdim[3] = 1.0;
    assert_eq!(decode_nifti(&h.file(&[1, 2, 3, 4, 5, 6]), "4d.nii").unwrap().dims(), [3, 2, 1]);
}

#[test]
fn extensions_before_vox_offset_are_skipped() {
    let mut h = Nifti::new([2, 1, 1], 2, 8);
    h.vox_offset = 400.0;
    let mut bytes = h.file(&[]);
    bytes[348] = 1; // "an extension follows"
    bytes.extend_from_slice(&[8, 9]);
    for b in [bytes.clone(), gz(&bytes)] {
        assert_eq!(decode_nifti(&b, "x.nii").unwrap().labels(), &[8, 9]);
    }
}

#[test]
fn big_endian_inr_from_a_sun_reads_like_little_endian() {
    let values = [1u16, 2, 513, 4, 5, 65535];
    let fields = "XDIM=3\nYDIM=2\nZDIM=1\nVDIM=1\nTYPE=unsigned fixed\nPIXSIZE=16 bits\n\
                  SCALE=2**0\nCPU=sun\nVX=0.5\nVY=0.25\nVZ=2\nTX=1\nTY=-2\nTZ=3.5\n";
    let be = inr_file(fields, 256, &labels_le(&values, |v| v.to_be_bytes().to_vec()));
    let le_fields = fields.replace("CPU=sun", "CPU=decm");
    let le = inr_file(&le_fields, 256, &labels_le(&values, |v| v.to_le_bytes().to_vec()));
    for bytes in [be.clone(), gz(&be), le] {
        let v = decode_inr(&bytes, "sun.inr").unwrap();
        assert_eq!(v.dims(), [3, 2, 1]);
        assert_eq!(v.labels(), &values);
        assert_close(&v.spacing(), &[0.5e-3, 0.25e-3, 2e-3], 1e-12, "spacing");
        assert_close(&v.origin(), &[1e-3, -2e-3, 3.5e-3], 1e-12, "origin");
    }
}

#[test]
fn inr_signed_and_float_types_and_defaults() {
    // No VX/VY/VZ: 1 mm. No CPU: little-endian. A comment line and a 512-byte header.
    let fields = "XDIM=2\nYDIM=1\nZDIM=1\n#GEOMETRY=CARTESIAN\nTYPE=float\nPIXSIZE=32 bits\n";
    let data = labels_le(&[3.0f32, 70.0], |v| v.to_le_bytes().to_vec());
    let v = decode_inr(&inr_file(fields, 512, &data), "f.inr").unwrap();
    assert_eq!(v.labels(), &[3, 70]);
    assert_eq!(v.spacing(), [1e-3; 3]);

    let fields = "XDIM=2\nYDIM=1\nZDIM=1\nTYPE=signed fixed\nPIXSIZE=64 bits\nCPU=sgi\n";
    let data = labels_le(&[3i64, 70], |v| v.to_be_bytes().to_vec());
    assert_eq!(decode_inr(&inr_file(fields, 256, &data), "s.inr").unwrap().labels(), &[3, 70]);

    let fields = "XDIM=2\nYDIM=1\nZDIM=1\nTYPE=float\nPIXSIZE=64 bits\nCPU=alpha\n";
    let data = labels_le(&[9.0f64, 0.0], |v| v.to_le_bytes().to_vec());
    assert_eq!(decode_inr(&inr_file(fields, 256, &data), "d.inr").unwrap().labels(), &[9, 0]);
}

/// The cube of `make_foreign.py`: side 1/32 at (1/8, -1/4, 1/2), corner `i` at bits (x, y, z)
/// of `i`, the centre last.
fn foreign_points() -> Vec<[f64; 3]> {
    let side = 1.0 / 32.0;
    let mut points: Vec<[f64; 3]> = (0..8)
        .map(|i| [f64::from(i & 1), f64::from((i >> 1) & 1), f64::from((i >> 2) & 1)])
        .map(|[x, y, z]| [0.125 + x * side, -0.25 + y * side, 0.5 + z * side])
        .collect();
    points.push([0.125 + side / 2.0, -0.25 + side / 2.0, 0.5 + side / 2.0]);
    points
}

/// The twelve tetrahedra of `make_foreign.py`, as it printed them: two per cube face, each
/// with the centre, positively oriented.
const FOREIGN_TETS: [[u32; 4]; 12] = [
    [0, 2, 6, 8],
    [0, 6, 4, 8],
    [1, 5, 7, 8],
    [1, 7, 3, 8],
    [0, 4, 5, 8],
    [0, 5, 1, 8],
    [2, 3, 7, 8],
    [2, 7, 6, 8],
    [0, 1, 3, 8],
    [0, 3, 2, 8],
    [4, 6, 7, 8],
    [4, 7, 5, 8],
];

/// Every fixture, with the reader for its format.
fn foreign_meshes() -> Vec<(&'static str, Result<TetMesh, incise_io::IoError>)> {
    macro_rules! read {
        ($decode:ident, $file:literal) => {
            ($file, $decode(include_bytes!(concat!("data/foreign/", $file)), $file))
        };
    }
    vec![
        read!(decode_gmsh, "meshio_binary.msh"),
        read!(decode_gmsh, "meshio_ascii.msh"),
        read!(decode_vtu, "meshio_ascii.vtu"),
        read!(decode_vtu, "meshio_zlib.vtu"),
        read!(decode_vtu, "meshio_uint64.vtu"),
        read!(decode_vtu, "vtk_appended_raw.vtu"),
        read!(decode_vtu, "vtk_appended_raw_zlib64.vtu"),
        read!(decode_vtu, "vtk_appended_base64_zlib.vtu"),
        read!(decode_vtu, "vtk_binary_bigendian.vtu"),
        read!(decode_vtk_legacy, "meshio_51_binary.vtk"),
        read!(decode_vtk_legacy, "meshio_42_binary.vtk"),
        read!(decode_vtk_legacy, "vtk_binary.vtk"),
    ]
}

#[test]
fn meshes_written_by_meshio_and_vtk_read_alike() {
    // Six tetrahedra in physical group 11, then (after two triangles, which are skipped) six in
    // group 12. Gmsh files carry the groups through $Entities, VTK files as the cell array
    // gmsh:physical, after a float array that is not a label.
    let regions: Vec<u32> = [11; 6].into_iter().chain([12; 6]).collect();
    let points = foreign_points();
    for (file, mesh) in foreign_meshes() {
        let mesh = mesh.unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(mesh.vertices(), &points[..], "{file}");
        assert_eq!(mesh.tets(), &FOREIGN_TETS, "{file}");
        assert_eq!(mesh.regions(), &regions[..], "{file}");
    }
}

/// Every fixture read with `options`, with whether it is a Gmsh file.
fn foreign_meshes_with(
    options: &MeshOptions,
) -> Vec<(&'static str, bool, Result<MeshFile, incise_io::IoError>)> {
    macro_rules! read {
        ($decode:ident, $file:literal) => {
            (
                $file,
                $file.ends_with(".msh"),
                $decode(include_bytes!(concat!("data/foreign/", $file)), $file, options),
            )
        };
    }
    vec![
        read!(decode_gmsh_with, "meshio_binary.msh"),
        read!(decode_gmsh_with, "meshio_ascii.msh"),
        read!(decode_vtu_with, "meshio_ascii.vtu"),
        read!(decode_vtu_with, "meshio_zlib.vtu"),
        read!(decode_vtu_with, "meshio_uint64.vtu"),
        read!(decode_vtu_with, "vtk_appended_raw.vtu"),
        read!(decode_vtu_with, "vtk_appended_raw_zlib64.vtu"),
        read!(decode_vtu_with, "vtk_appended_base64_zlib.vtu"),
        read!(decode_vtu_with, "vtk_binary_bigendian.vtu"),
        read!(decode_vtk_legacy_with, "meshio_51_binary.vtk"),
        read!(decode_vtk_legacy_with, "meshio_42_binary.vtk"),
        read!(decode_vtk_legacy_with, "vtk_binary.vtk"),
    ]
}

#[test]
fn the_region_array_can_be_named_and_skipped_cells_are_counted() {
    // By default the regions are the physical groups (`gmsh:physical` comes after the float
    // array `quality` and before `gmsh:geometrical`, so the name decides, not the order).
    for (file, gmsh, read) in foreign_meshes_with(&MeshOptions::default()) {
        let read = read.unwrap_or_else(|e| panic!("{e}"));
        let source = if gmsh { "physical tags" } else { "cell array \"gmsh:physical\"" };
        assert_eq!(read.region_source.as_deref(), Some(source), "{file}");
        assert_eq!(read.skipped, [("triangle".to_owned(), 2)], "{file}");
        assert_eq!(
            read.skipped_note().as_deref(),
            Some("skipped 2 cells that are not tetrahedra (2 triangle)"),
            "{file}"
        );
    }
    // Named: the elementary entities 1 and 2, in every format.
    let geometrical = MeshOptions { region: Some("gmsh:geometrical".to_owned()) };
    let entities: Vec<u32> = [1; 6].into_iter().chain([2; 6]).collect();
    for (file, gmsh, read) in foreign_meshes_with(&geometrical) {
        let read = read.unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(read.mesh.regions(), &entities[..], "{file}");
        let source =
            if gmsh { "elementary entity tags" } else { "cell array \"gmsh:geometrical\"" };
        assert_eq!(read.region_source.as_deref(), Some(source), "{file}");
    }
    // A name the file lacks lists what it has; a float array cannot be regions.
    let missing = MeshOptions { region: Some("tissue".to_owned()) };
    let quality = MeshOptions { region: Some("quality".to_owned()) };
    for (file, gmsh, read) in foreign_meshes_with(&missing) {
        let e = read.err().unwrap_or_else(|| panic!("{file}: read")).to_string();
        let expected = if gmsh {
            "a Gmsh file's regions are \"gmsh:physical\""
        } else {
            "cell-data arrays are \"quality\", \"gmsh:physical\", \"gmsh:geometrical\""
        };
        assert!(e.starts_with(&format!("{file}: region array: ")) && e.contains(expected), "{e}");
    }
    for (file, gmsh, read) in foreign_meshes_with(&quality) {
        if !gmsh {
            let e = read.err().unwrap_or_else(|| panic!("{file}: read")).to_string();
            assert!(e.contains("cell array \"quality\" is") && e.contains("one integer"), "{e}");
        }
    }
}

#[test]
fn damaged_foreign_meshes_say_where() {
    let bytes: &[u8] = include_bytes!("data/foreign/vtk_appended_raw_zlib64.vtu");
    // Cut inside the appended data: the error names the array and the line of its tag.
    let end = bytes.windows(15).rposition(|w| w == b"</AppendedData>").unwrap();
    let mut cut = bytes[..end - 40].to_vec();
    cut.extend_from_slice(&bytes[end..]);
    let e = decode_vtu(&cut, "cut.vtu").unwrap_err().to_string();
    assert!(e.starts_with("cut.vtu: line ") && e.contains("DataArray \""), "{e}");

    let bytes: &[u8] = include_bytes!("data/foreign/meshio_binary.msh");
    let e = decode_gmsh(&bytes[..bytes.len() / 2], "cut.msh").unwrap_err().to_string();
    assert!(e.starts_with("cut.msh: byte "), "{e}");

    let bytes: &[u8] = include_bytes!("data/foreign/vtk_binary.vtk");
    let e = decode_vtk_legacy(&bytes[..300], "cut.vtk").unwrap_err().to_string();
    assert!(e.starts_with("cut.vtk: byte ") && e.contains("the file holds"), "{e}");
}
