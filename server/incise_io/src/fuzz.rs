//! Fuzz-style properties: no byte string makes a decoder panic.
//!
//! Inputs are random bytes, valid encodings cut at random lengths, and valid encodings with a few
//! bytes changed, each fed to both decoders plain and gzip-compressed. Every case must come back
//! as `Ok` or `Err`; a panic fails the property. Volumes are tiny so that 256 cases per property
//! run in well under a second.
//!
//! The mesh decoders (Gmsh 2.2 and 4.1, legacy VTK, VTK XML) get the same treatment from a
//! deterministic generator: valid encodings of a small cylinder with bytes changed, cut short,
//! lines deleted, duplicated or swapped, and numbers replaced by extreme ones, a few hundred
//! cases per decoder. Every binary variant (MSH 4.1, legacy VTK in both cell layouts, VTK XML
//! inline, appended raw and base64, zlib-compressed or not, both header types and byte orders)
//! also has aligned 4- and 8-byte words overwritten with extreme values, which is where its
//! counts and sizes are: a decoder that trusted one for an allocation would abort the test
//! (a capacity overflow or an allocation of terabytes), not merely fail it. The files written
//! by meshio and VTK under `tests/data/foreign` are damaged the same way, and so are the
//! triangle-mesh encodings: ASCII STL, binary STL (also with a header that starts with `solid`,
//! so that a damaged size sends it to the ASCII reader first) and OBJ, with a hand-written OBJ
//! of quads and relative indices.

use crate::tri_mesh::tests::{CUBE_OBJ, icosphere, in_appearance_order, rounded_to_f32};
use crate::{
    VtkCells, VtuBinary, VtuData, decode_gmsh, decode_inr, decode_nifti, decode_volume,
    decode_vtk_legacy, decode_vtu, encode_gmsh22, encode_gmsh41_binary, encode_inr, encode_nifti,
    encode_vtk_legacy, encode_vtk_legacy_binary, encode_vtu, encode_vtu_binary,
};
use crate::{decode_obj, decode_stl, encode_obj, encode_stl_ascii, encode_stl_binary};
use incise_grid::LabelVolume;
use incise_mesh::TetMesh;
use incise_mesh::generate::cylinder;
use proptest::prelude::*;
use std::fmt::Write as _;

/// A small volume with a rotated, offset placement; `wide` puts a label above 255 in it so that
/// the INR encoder writes 16-bit voxels.
fn sample(wide: bool) -> LabelVolume {
    let mut labels: Vec<u16> = (0..3 * 2 * 2).map(|i| (i % 4) as u16).collect();
    if wide {
        labels[5] = 700;
    }
    let (s, c) = (0.6f64.sin(), 0.6f64.cos());
    LabelVolume::new([3, 2, 2], [0.5e-3, 0.7e-3, 1.5e-3], labels)
        .and_then(|v| {
            v.with_placement([0.01, -0.02, 0.03], [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        })
        .expect("the sample volume is valid")
}

/// The four valid encodings: NIfTI and INR, each with narrow and wide labels.
fn encodings() -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for wide in [false, true] {
        let v = sample(wide);
        out.push(encode_nifti(&v).expect("small volumes encode"));
        out.push(encode_inr(&v));
    }
    out
}

fn gz(bytes: &[u8]) -> Vec<u8> {
    crate::gzip::compress(bytes).expect("compressing into memory cannot fail")
}

/// Runs every decoder on `bytes`; the results do not matter, only that they return.
fn decode_all(bytes: &[u8]) {
    let _ = decode_nifti(bytes, "fuzz.nii");
    let _ = decode_inr(bytes, "fuzz.inr");
    let _ = decode_volume(bytes, "fuzz");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..1200)) {
        decode_all(&bytes);
        decode_all(&gz(&bytes));
    }

    #[test]
    fn truncated_encodings_never_panic(
        which in 0usize..4,
        gzipped in any::<bool>(),
        cut in any::<prop::sample::Index>(),
    ) {
        let plain = &encodings()[which];
        let bytes = if gzipped { gz(plain) } else { plain.clone() };
        let cut = cut.index(bytes.len());
        let result_nifti = decode_nifti(&bytes[..cut], "cut.nii");
        let result_inr = decode_inr(&bytes[..cut], "cut.inr");
        // A cut encoding is never a valid volume: something announced is missing.
        prop_assert!(result_nifti.is_err() && result_inr.is_err());
    }

    #[test]
    fn mutated_headers_never_panic(
        which in 0usize..4,
        edits in proptest::collection::vec((0usize..352, any::<u8>()), 1..5),
    ) {
        let mut bytes = encodings()[which].clone();
        let header_len = if which % 2 == 0 { 352 } else { 256 };
        for (at, value) in edits {
            bytes[at % header_len] = value;
        }
        decode_all(&bytes);
        decode_all(&gz(&bytes));
    }

    #[test]
    fn mutated_gzip_streams_never_panic(
        which in 0usize..4,
        at in any::<prop::sample::Index>(),
        value in any::<u8>(),
    ) {
        let mut bytes = gz(&encodings()[which]);
        let i = at.index(bytes.len());
        bytes[i] = value;
        decode_all(&bytes);
    }
}

/// `SplitMix64`: a fixed stream of pseudo-random numbers, so every mesh case reproduces.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// A number in `0..n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// A small cylinder whose tetrahedra carry regions 1, 2 and 3.
fn small_mesh() -> TetMesh {
    let base = cylinder(0.01, 0.03, 2, 3);
    let regions = (0..base.tets().len()).map(|t| (t % 3) as u32 + 1).collect();
    TetMesh::new(base.vertices().to_vec(), base.tets().to_vec(), regions)
        .expect("the cylinder with regions is valid")
}

/// `mesh` as Gmsh MSH 4.1: one volume entity per region, with physical tag `10 + region`,
/// nodes in two blocks with tags from 101 in steps of 3. Returns the text and the mesh it
/// decodes to (tetrahedra grouped by region, regions the physical tags).
fn encode_gmsh41(mesh: &TetMesh) -> (String, TetMesh) {
    let mut regions: Vec<u32> = mesh.regions().to_vec();
    regions.sort_unstable();
    regions.dedup();
    let tag = |i: u32| 101 + 3 * u64::from(i);
    let mut out = String::from("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Entities\n");
    let _ = writeln!(out, "0 0 0 {}", regions.len());
    for r in &regions {
        let _ = writeln!(out, "{r} -1 -1 -1 1 1 1 1 {} 0", 10 + r);
    }
    let n = mesh.vertices().len();
    let half = n / 2;
    let _ = write!(out, "$EndEntities\n$Nodes\n2 {n} {} {}\n", tag(0), tag(n as u32 - 1));
    for (start, end) in [(0, half), (half, n)] {
        let _ = writeln!(out, "3 1 0 {}", end - start);
        for i in start..end {
            let _ = writeln!(out, "{}", tag(i as u32));
        }
        for [x, y, z] in &mesh.vertices()[start..end] {
            let _ = writeln!(out, "{x:?} {y:?} {z:?}");
        }
    }
    let t = mesh.tets().len();
    let _ = write!(out, "$EndNodes\n$Elements\n{} {t} 1 {t}\n", regions.len());
    let mut element = 0;
    for &r in &regions {
        let inside: Vec<&[u32; 4]> = mesh
            .tets()
            .iter()
            .zip(mesh.regions())
            .filter(|&(_, &q)| q == r)
            .map(|(t, _)| t)
            .collect();
        let _ = writeln!(out, "3 {r} 4 {}", inside.len());
        for nodes in inside {
            element += 1;
            let [a, b, c, d] = nodes.map(tag);
            let _ = writeln!(out, "{element} {a} {b} {c} {d}");
        }
    }
    out.push_str("$EndElements\n");
    let mut order: Vec<usize> = (0..t).collect();
    order.sort_by_key(|&i| mesh.regions()[i]);
    let expected = TetMesh::new(
        mesh.vertices().to_vec(),
        order.iter().map(|&i| mesh.tets()[i]).collect(),
        order.iter().map(|&i| 10 + mesh.regions()[i]).collect(),
    )
    .expect("reordering tetrahedra keeps the mesh valid");
    (out, expected)
}

/// `text` damaged one way: bytes changed, cut short, a line deleted, duplicated or swapped with
/// another, a token replaced by an extreme one, or an aligned word overwritten with an extreme
/// value.
fn damage(text: &[u8], rng: &mut SplitMix) -> Vec<u8> {
    const BYTES: &[u8] = b"0123456789-+.eE \n\t$<>/\"'=_xX\0\xff";
    const TOKENS: [&str; 12] = [
        "-1",
        "0",
        "4294967295",
        "4294967296",
        "18446744073709551616",
        "1e308",
        "nan",
        "-inf",
        "",
        "$EndNodes",
        "</DataArray>",
        "<DataArray format=\"binary\">",
    ];
    const WORDS: [u64; 8] =
        [0, 1, 0xff, 0x7fff_ffff, 0xffff_ffff, 1 << 40, 0x7fff_ffff_ffff_ffff, u64::MAX];
    let mut bytes = text.to_vec();
    let line_starts: Vec<usize> = std::iter::once(0)
        .chain(bytes.iter().enumerate().filter(|&(_, &b)| b == b'\n').map(|(i, _)| i + 1))
        .filter(|&i| i < bytes.len())
        .collect();
    let line = |k: usize| {
        let start = line_starts[k];
        let end = line_starts.get(k + 1).copied().unwrap_or(bytes.len());
        start..end
    };
    match rng.below(8) {
        0 => {
            for _ in 0..=rng.below(4) {
                let at = rng.below(bytes.len());
                bytes[at] = if rng.below(4) == 0 {
                    rng.next() as u8
                } else {
                    BYTES[rng.below(BYTES.len())]
                };
            }
        }
        1 => bytes.truncate(rng.below(bytes.len())),
        2 => {
            let range = line(rng.below(line_starts.len()));
            bytes.drain(range);
        }
        3 => {
            let range = line(rng.below(line_starts.len()));
            let copy = bytes[range.clone()].to_vec();
            bytes.splice(range.start..range.start, copy);
        }
        4 => {
            let (a, b) = (rng.below(line_starts.len()), rng.below(line_starts.len()));
            let (a, b) = (line(a.min(b)), line(a.max(b)));
            if a != b {
                let (first, second) = (bytes[a.clone()].to_vec(), bytes[b.clone()].to_vec());
                bytes.splice(b, first);
                bytes.splice(a, second);
            }
        }
        6 | 7 => {
            // Overwrite an aligned word, in either byte order.
            let width = if rng.below(2) == 0 { 4 } else { 8 };
            let at = rng.below(bytes.len()) / width * width;
            let word = WORDS[rng.below(WORDS.len())];
            let le = word.to_le_bytes();
            let be = word.to_be_bytes();
            let value = if rng.below(2) == 0 { &le[..width] } else { &be[8 - width..] };
            let end = (at + width).min(bytes.len());
            bytes[at..end].copy_from_slice(&value[..end - at]);
        }
        _ => {
            // Replace the token around a random byte.
            let at = rng.below(bytes.len());
            let is_space = |b: u8| b.is_ascii_whitespace() || b == b'<' || b == b'>';
            let start = bytes[..at].iter().rposition(|&b| is_space(b)).map_or(0, |i| i + 1);
            let end = bytes[at..].iter().position(|&b| is_space(b)).map_or(bytes.len(), |i| at + i);
            let token = TOKENS[rng.below(TOKENS.len())].as_bytes().to_vec();
            bytes.splice(start..end.max(start), token);
        }
    }
    bytes
}

/// A decoder of meshes, tetrahedral unless said otherwise.
type Decode<M = TetMesh> = fn(&[u8], &str) -> Result<M, crate::IoError>;

/// Feeds 400 damaged versions of `valid`, which decodes to `mesh`, to `decode`; none may panic,
/// and the damage must make at least a quarter of them errors (else it is not reaching the
/// parser).
fn fuzz_mesh_decoder<M: PartialEq + std::fmt::Debug>(
    seed: u64,
    (valid, mesh): (impl AsRef<[u8]>, M),
    decode: Decode<M>,
) {
    let valid = valid.as_ref();
    assert_eq!(decode(valid, "valid").expect("the valid encoding decodes"), mesh);
    let mut rng = SplitMix(seed);
    let cases = 400;
    let mut errors = 0;
    for case in 0..cases {
        let bytes = damage(valid, &mut rng);
        let result = std::panic::catch_unwind(|| decode(&bytes, "fuzz")).unwrap_or_else(|_| {
            panic!("case {case} of seed {seed} panicked on:\n{}", String::from_utf8_lossy(&bytes))
        });
        if let Err(e) = result {
            assert_eq!(e.file(), "fuzz");
            errors += 1;
        }
    }
    assert!(errors * 4 >= cases, "only {errors} of {cases} damaged encodings were refused");
}

/// The decoders with a named region array: the arrays the encoders write are `region` (VTK)
/// and the physical tags (Gmsh).
fn named_region(name: &str) -> crate::MeshOptions {
    crate::MeshOptions { region: Some(name.to_owned()) }
}

#[test]
fn damaged_meshes_read_with_a_named_region_never_panic() {
    let mesh = small_mesh();
    fuzz_mesh_decoder(11, (encode_gmsh22(&mesh), mesh.clone()), |b, n| {
        crate::decode_gmsh_with(b, n, &named_region("gmsh:physical")).map(|f| f.mesh)
    });
    fuzz_mesh_decoder(12, (encode_vtk_legacy(&mesh), mesh.clone()), |b, n| {
        crate::decode_vtk_legacy_with(b, n, &named_region("region")).map(|f| f.mesh)
    });
    fuzz_mesh_decoder(13, (encode_vtu(&mesh), mesh), |b, n| {
        crate::decode_vtu_with(b, n, &named_region("region")).map(|f| f.mesh)
    });
}

#[test]
fn damaged_gmsh22_never_panics() {
    let mesh = small_mesh();
    fuzz_mesh_decoder(1, (encode_gmsh22(&mesh), mesh), decode_gmsh);
}

#[test]
fn damaged_gmsh41_never_panics() {
    fuzz_mesh_decoder(2, encode_gmsh41(&small_mesh()), decode_gmsh);
}

#[test]
fn damaged_vtk_legacy_never_panics() {
    let mesh = small_mesh();
    fuzz_mesh_decoder(3, (encode_vtk_legacy(&mesh), mesh), decode_vtk_legacy);
}

#[test]
fn damaged_vtu_never_panics() {
    let mesh = small_mesh();
    fuzz_mesh_decoder(4, (encode_vtu(&mesh), mesh), decode_vtu);
}

#[test]
fn damaged_gmsh41_binary_never_panics() {
    let mesh = small_mesh();
    let bytes = encode_gmsh41_binary(&mesh).expect("small regions fit");
    fuzz_mesh_decoder(5, (bytes, mesh), decode_gmsh);
}

#[test]
fn damaged_vtk_legacy_binary_never_panics() {
    let mesh = small_mesh();
    for (seed, cells) in [(6, VtkCells::Classic), (7, VtkCells::OffsetsConnectivity)] {
        let bytes = encode_vtk_legacy_binary(&mesh, cells);
        fuzz_mesh_decoder(seed, (bytes, mesh.clone()), decode_vtk_legacy);
    }
}

#[test]
fn damaged_vtu_binary_never_panics() {
    let mesh = small_mesh();
    let variants = [
        VtuBinary::default(),
        VtuBinary { zlib: true, block_size: 100, ..VtuBinary::default() },
        VtuBinary { data: VtuData::AppendedRaw, ..VtuBinary::default() },
        VtuBinary {
            data: VtuData::AppendedRaw,
            zlib: true,
            header64: true,
            big_endian: true,
            block_size: 64,
        },
        VtuBinary { data: VtuData::AppendedBase64, zlib: true, ..VtuBinary::default() },
    ];
    for (seed, options) in (8..).zip(variants) {
        fuzz_mesh_decoder(seed, (encode_vtu_binary(&mesh, options), mesh.clone()), decode_vtu);
    }
}

#[test]
fn damaged_foreign_files_never_panic() {
    macro_rules! foreign {
        ($file:literal) => {
            ($file, include_bytes!(concat!("../tests/data/foreign/", $file)).as_slice())
        };
    }
    let files: [(&str, &[u8]); 12] = [
        foreign!("meshio_binary.msh"),
        foreign!("meshio_ascii.msh"),
        foreign!("meshio_ascii.vtu"),
        foreign!("meshio_zlib.vtu"),
        foreign!("meshio_uint64.vtu"),
        foreign!("meshio_51_binary.vtk"),
        foreign!("meshio_42_binary.vtk"),
        foreign!("vtk_appended_raw.vtu"),
        foreign!("vtk_appended_raw_zlib64.vtu"),
        foreign!("vtk_appended_base64_zlib.vtu"),
        foreign!("vtk_binary_bigendian.vtu"),
        foreign!("vtk_binary.vtk"),
    ];
    for (seed, (file, bytes)) in (20..).zip(files) {
        let decode: Decode = match file.rsplit('.').next() {
            Some("msh") => decode_gmsh,
            Some("vtk") => decode_vtk_legacy,
            _ => decode_vtu,
        };
        let mesh = decode(bytes, file).unwrap_or_else(|e| panic!("{e}"));
        fuzz_mesh_decoder(seed, (bytes, mesh), decode);
    }
}

#[test]
fn damaged_stl_ascii_never_panics() {
    let mesh = icosphere(1);
    fuzz_mesh_decoder(40, (encode_stl_ascii(&mesh), in_appearance_order(&mesh)), decode_stl);
}

#[test]
fn damaged_stl_binary_never_panics() {
    let mesh = rounded_to_f32(&icosphere(1));
    let plain = encode_stl_binary(&mesh);
    fuzz_mesh_decoder(41, (plain.clone(), in_appearance_order(&mesh)), decode_stl);
    let mut solid = plain;
    solid[..12].copy_from_slice(b"solid tool \n");
    fuzz_mesh_decoder(42, (solid, in_appearance_order(&mesh)), decode_stl);
}

#[test]
fn damaged_obj_never_panics() {
    let mesh = icosphere(1);
    fuzz_mesh_decoder(43, (encode_obj(&mesh), mesh), decode_obj);
    let quads = decode_obj(CUBE_OBJ.as_bytes(), "cube.obj").unwrap_or_else(|e| panic!("{e}"));
    fuzz_mesh_decoder(44, (CUBE_OBJ, quads), decode_obj);
}
