//! Every error variant, triggered on purpose: the message must name the file and the problem.

#![allow(clippy::float_cmp, reason = "exact values are written and must read back exactly")]

mod common;

use common::{Nifti, TempDir, assert_message, gz, inr_file, sample};
use incise_grid::VolumeError;
use incise_io::{IoError, decode_inr, decode_nifti, decode_volume, read_volume, write_volume};

const LIVER_FIELDS: &str = "XDIM=438\nYDIM=353\nZDIM=165\nVDIM=1\nTYPE=unsigned fixed\n\
                            PIXSIZE=8 bits\nSCALE=2**0\nCPU=decm\nVX=0.617188\nVY=0.617188\n\
                            VZ=1.33333\n";

#[test]
fn missing_file_is_an_io_error_naming_the_path() {
    let dir = TempDir::new("missing");
    let path = dir.join("nowhere.nii.gz");
    let err = read_volume(&path).unwrap_err();
    assert!(matches!(err, IoError::Io { .. }), "{err:?}");
    assert_message(&err, &path.display().to_string(), &[]);
}

#[test]
fn truncated_voxels_report_both_byte_counts() {
    let bytes = inr_file(LIVER_FIELDS, 256, &[0u8; 1000]);
    for (name, b) in [("liver.inr", bytes.clone()), ("liver.inr.gz", gz(&bytes))] {
        let err = decode_inr(&b, name).unwrap_err();
        assert!(matches!(err, IoError::Truncated { expected: 25_511_310, found: 1000, .. }));
        assert_message(
            &err,
            name,
            &["data truncated", "needs 25,511,310 bytes", "438×353×165 uint8", "holds 1,000"],
        );
    }
    let h = Nifti::new([10, 10, 10], 512, 16);
    let err = decode_nifti(&gz(&h.file(&[0; 100])), "scan.nii.gz").unwrap_err();
    assert_message(&err, "scan.nii.gz", &["data truncated", "needs 2,000 bytes", "holds 100"]);
}

#[test]
fn truncated_headers_are_reported() {
    let full = Nifti::new([1, 1, 1], 2, 8).file(&[1]);
    let err = decode_nifti(&full[..200], "short.nii").unwrap_err();
    assert_message(&err, "short.nii", &["needs 348 bytes of NIfTI-1 header", "holds 200"]);
    let err = decode_nifti(&[], "empty.nii").unwrap_err();
    assert!(matches!(err, IoError::Truncated { found: 0, .. }), "{err:?}");

    let inr = inr_file("XDIM=1\nYDIM=1\nZDIM=1\n", 256, &[1]);
    let err = decode_inr(&inr[..100], "short.inr").unwrap_err();
    assert_message(&err, "short.inr", &["data truncated", "INRIMAGE-4 header", "holds 100"]);
}

#[test]
fn header_claiming_2_to_the_60_voxels_is_an_error_not_an_allocation() {
    let fields = "XDIM=1048576\nYDIM=1048576\nZDIM=1048576\nTYPE=unsigned fixed\nPIXSIZE=8 bits\n";
    let bytes = inr_file(fields, 256, &[0u8; 64]);
    for b in [bytes.clone(), gz(&bytes)] {
        let err = decode_inr(&b, "huge.inr").unwrap_err();
        assert!(
            matches!(err, IoError::Truncated { expected, found: 64, .. } if expected == 1 << 60)
        );
    }
    // 2^60 voxels of 64 bits overflow the byte count itself.
    let fields = fields.replace("8 bits", "64 bits").replace("XDIM=1048576", "XDIM=1099511627776");
    let err = decode_inr(&inr_file(&fields, 256, &[]), "huger.inr").unwrap_err();
    assert_message(&err, "huger.inr", &["overflows"]);
    // The largest NIfTI-1 extent (32767³ float64, 2.8e14 bytes) is refused just as early.
    let h = Nifti::new([32767, 32767, 32767], 64, 64);
    let err = decode_nifti(&gz(&h.file(&[0; 8])), "big.nii.gz").unwrap_err();
    assert!(matches!(err, IoError::Truncated { found: 8, .. }), "{err:?}");
}

#[test]
fn bad_header_fields_are_named() {
    let err = decode_inr(&inr_file(&LIVER_FIELDS.replace("438", "abc"), 256, &[]), "liver.inr")
        .unwrap_err();
    assert!(matches!(err, IoError::BadHeader { .. }));
    assert_eq!(err.to_string(), "liver.inr: header field XDIM=abc is not a positive integer");

    let cases = [
        (LIVER_FIELDS.replace("YDIM=353", "YDIM=0"), "YDIM=0 is not a positive integer"),
        (LIVER_FIELDS.replace("ZDIM=165\n", ""), "ZDIM is missing"),
        (LIVER_FIELDS.replace("VX=0.617188", "VX=wide"), "VX=wide is not a finite number"),
        (LIVER_FIELDS.replace("PIXSIZE=8 bits", "PIXSIZE=eight"), "PIXSIZE=eight"),
        (format!("{LIVER_FIELDS}garbage line\n"), "\"garbage line\" is not KEY=VALUE"),
    ];
    for (fields, part) in cases {
        let err = decode_inr(&inr_file(&fields, 256, &[]), "liver.inr").unwrap_err();
        assert!(matches!(err, IoError::BadHeader { .. }), "{err:?}");
        assert_message(&err, "liver.inr", &[part]);
    }

    let mut h = Nifti::new([2, 2, 2], 2, 8);
    h.dim[2] = -4;
    let err = decode_nifti(&h.file(&[0; 8]), "d.nii").unwrap_err();
    assert_message(&err, "d.nii", &["dim[2]=-4 is not a positive extent"]);
    h.dim = [0; 8];
    let err = decode_nifti(&h.file(&[0; 8]), "d.nii").unwrap_err();
    assert_message(&err, "d.nii", &["dim[0]=0"]);
    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.vox_offset = 352.5;
    assert_message(
        &decode_nifti(&h.file(&[0]), "v.nii").unwrap_err(),
        "v.nii",
        &["vox_offset=352.5"],
    );
}

#[test]
fn bad_magic_is_reported_for_both_formats() {
    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.magic = *b"xyz\0";
    let err = decode_nifti(&h.file(&[1]), "m.nii").unwrap_err();
    assert!(matches!(err, IoError::BadHeader { .. }));
    assert_message(&err, "m.nii", &["bad magic", "\"n+1\\0\""]);

    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.sizeof_hdr = 1234;
    let err = decode_nifti(&h.file(&[1]), "m.nii").unwrap_err();
    assert_message(&err, "m.nii", &["bad magic", "sizeof_hdr", "1234", "348"]);

    let err = decode_inr(b"#INRIMAGE-5#{\nXDIM=1\n", "m.inr").unwrap_err();
    assert!(matches!(err, IoError::BadHeader { .. }));
    assert_message(&err, "m.inr", &["bad magic", "#INRIMAGE-5#{"]);
}

#[test]
fn unsupported_types_are_named() {
    let h = Nifti::new([1, 1, 1], 32, 64);
    let err = decode_nifti(&h.file(&[0; 8]), "c.nii").unwrap_err();
    assert!(matches!(err, IoError::UnsupportedType { .. }));
    assert_message(&err, "c.nii", &["unsupported: datatype 32 (complex64)"]);

    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.magic = *b"ni1\0";
    let err = decode_nifti(&h.file(&[]), "pair.hdr").unwrap_err();
    assert_message(&err, "pair.hdr", &["unsupported: two-file NIfTI"]);

    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.dim = [4, 1, 1, 1, 5, 1, 1, 1];
    let err = decode_nifti(&h.file(&[0; 5]), "t.nii").unwrap_err();
    assert_message(&err, "t.nii", &["unsupported: 4-D series of 5 volumes"]);

    let mut nifti2 = vec![0u8; 600];
    nifti2[..4].copy_from_slice(&540i32.to_le_bytes());
    assert_message(&decode_volume(&nifti2, "n2").unwrap_err(), "n2", &["unsupported: NIfTI-2"]);

    for (from, to, part) in [
        ("VDIM=1", "VDIM=3", "VDIM=3"),
        ("TYPE=unsigned fixed", "TYPE=packed", "TYPE=packed"),
        ("PIXSIZE=8 bits", "PIXSIZE=12 bits", "PIXSIZE=12 bits"),
        ("CPU=decm", "CPU=vax", "CPU=vax"),
    ] {
        let err = decode_inr(&inr_file(&LIVER_FIELDS.replace(from, to), 256, &[]), "liver.inr")
            .unwrap_err();
        assert!(matches!(err, IoError::UnsupportedType { .. }), "{err:?}");
        assert_message(&err, "liver.inr", &["unsupported", part]);
    }
}

#[test]
fn header_and_size_mismatches_are_reported() {
    let h = Nifti::new([2, 1, 1], 512, 8);
    let err = decode_nifti(&h.file(&[0; 4]), "b.nii").unwrap_err();
    assert!(matches!(err, IoError::HeaderSizeMismatch { .. }));
    assert_message(&err, "b.nii", &["bitpix=8", "datatype 512 (uint16) has 16 bits"]);

    let h = Nifti::new([2, 1, 1], 2, 8);
    for (name, bytes) in [("x.nii", h.file(&[1, 2, 3])), ("x.nii.gz", gz(&h.file(&[1, 2, 3])))] {
        let err = decode_nifti(&bytes, name).unwrap_err();
        assert!(matches!(err, IoError::HeaderSizeMismatch { .. }), "{err:?}");
        assert_message(&err, name, &["1 bytes follow the 2 bytes of voxels"]);
    }

    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.vox_offset = 348.0;
    assert_message(
        &decode_nifti(&h.file(&[1]), "o.nii").unwrap_err(),
        "o.nii",
        &["vox_offset=348"],
    );

    // "##}" halfway through the first block: the header is not a whole number of blocks.
    let mut bytes = b"#INRIMAGE-4#{\nXDIM=1\nYDIM=1\nZDIM=1\n##}\n".to_vec();
    bytes.resize(300, 0);
    let err = decode_inr(&bytes, "h.inr").unwrap_err();
    assert!(matches!(err, IoError::HeaderSizeMismatch { .. }), "{err:?}");
    assert_message(&err, "h.inr", &["header ends at byte 39", "not a multiple of 256"]);

    let bytes = inr_file(
        "XDIM=2\nYDIM=1\nZDIM=1\nTYPE=unsigned fixed\nPIXSIZE=8 bits\n",
        256,
        &[1, 2, 3, 4],
    );
    assert_message(&decode_inr(&bytes, "t.inr").unwrap_err(), "t.inr", &["2 bytes follow"]);
}

#[test]
fn bad_labels_name_the_voxel_and_value() {
    let data: Vec<u8> = [4i16, 2, -3].iter().flat_map(|v| v.to_le_bytes()).collect();
    let err = decode_nifti(&Nifti::new([3, 1, 1], 4, 16).file(&data), "neg.nii").unwrap_err();
    assert!(matches!(&err, IoError::BadLabel { voxel: 2, value, .. } if value == "-3"), "{err:?}");
    assert_message(&err, "neg.nii", &["voxel 2 holds -3", "not a tissue label"]);

    let data: Vec<u8> = [1.0f32, 2.5].iter().flat_map(|v| v.to_le_bytes()).collect();
    let err = decode_nifti(&Nifti::new([2, 1, 1], 16, 32).file(&data), "frac.nii").unwrap_err();
    assert_message(&err, "frac.nii", &["voxel 1 holds 2.5"]);

    let data: Vec<u8> = [f32::NAN].iter().flat_map(|v| v.to_le_bytes()).collect();
    let err = decode_nifti(&Nifti::new([1, 1, 1], 16, 32).file(&data), "nan.nii").unwrap_err();
    assert_message(&err, "nan.nii", &["voxel 0 holds NaN"]);

    let fields = "XDIM=2\nYDIM=1\nZDIM=1\nTYPE=unsigned fixed\nPIXSIZE=32 bits\n";
    let data: Vec<u8> = [7u32, 70_000].iter().flat_map(|v| v.to_le_bytes()).collect();
    let err = decode_inr(&inr_file(fields, 256, &data), "big.inr").unwrap_err();
    assert_message(&err, "big.inr", &["voxel 1 holds 70000"]);

    let mut h = Nifti::new([2, 1, 1], 2, 8);
    h.scl_slope = 0.5;
    let err = decode_nifti(&h.file(&[2, 3]), "scaled.nii").unwrap_err();
    assert_message(&err, "scaled.nii", &["voxel 1 holds 3 × scl_slope 0.5", "= 1.5"]);
}

#[test]
fn bad_units_and_sheared_sforms_are_spacing_errors() {
    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.xyzt_units = 5;
    let err = decode_nifti(&h.file(&[1]), "u.nii").unwrap_err();
    assert!(matches!(err, IoError::BadSpacing { .. }));
    assert_message(&err, "u.nii", &["xyzt_units=5", "spatial unit code 5"]);

    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.sform_code = 1;
    h.srow = [[1.0, 0.5, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];
    let err = decode_nifti(&h.file(&[1]), "shear.nii").unwrap_err();
    assert!(matches!(err, IoError::BadSpacing { .. }));
    assert_message(&err, "shear.nii", &["sform axes 0 and 1 are not perpendicular"]);
    // With a qform beside it, the rigid qform is used instead.
    h.qform_code = 1;
    assert_eq!(decode_nifti(&h.file(&[1]), "shear.nii").unwrap().direction(), common::IDENTITY);

    h.qform_code = 0;
    h.srow[2][2] = 0.0;
    h.srow[0][1] = 0.0;
    let err = decode_nifti(&h.file(&[1]), "flat.nii").unwrap_err();
    assert_message(&err, "flat.nii", &["sform axis 2", "zero length"]);
}

#[test]
fn zero_spacing_comes_back_from_the_volume() {
    let mut h = Nifti::new([1, 1, 1], 2, 8);
    h.pixdim[2] = 0.0;
    let err = decode_nifti(&h.file(&[1]), "z.nii").unwrap_err();
    assert!(
        matches!(err, IoError::Volume { source: VolumeError::BadSpacing { axis: 1, .. }, .. }),
        "{err:?}"
    );
    assert_message(&err, "z.nii", &["spacing along axis 1 is 0"]);

    let fields = LIVER_FIELDS.replace("VZ=1.33333", "VZ=0").replace("XDIM=438", "XDIM=1");
    let fields = fields.replace("YDIM=353", "YDIM=1").replace("ZDIM=165", "ZDIM=1");
    let err = decode_inr(&inr_file(&fields, 256, &[1]), "z.inr").unwrap_err();
    assert!(matches!(err, IoError::Volume { .. }), "{err:?}");
    assert_message(&err, "z.inr", &["spacing along axis 2 is 0"]);
}

#[test]
fn unknown_formats_are_reported() {
    let dir = TempDir::new("unknown");
    let path = dir.join("notes.txt");
    std::fs::write(&path, "not a volume").unwrap();
    let err = read_volume(&path).unwrap_err();
    assert!(matches!(err, IoError::UnknownFormat { .. }));
    assert_message(&err, &path.display().to_string(), &["unknown format"]);
    assert!(matches!(decode_volume(&gz(b"plain text"), "t"), Err(IoError::UnknownFormat { .. })));

    let out = dir.join("out.png");
    let err = write_volume(&out, &sample(3, common::IDENTITY)).unwrap_err();
    assert_message(&err, &out.display().to_string(), &["unknown format"]);
}

#[test]
fn nifti_cannot_hold_extents_beyond_int16() {
    let v = incise_grid::LabelVolume::new([40_000, 1, 1], [1e-3; 3], vec![0; 40_000]).unwrap();
    let err = incise_io::encode_nifti(&v).unwrap_err();
    assert!(matches!(err, IoError::UnsupportedType { .. }));
    assert!(
        err.to_string().contains("extent 40000 along axis 0 exceeds NIfTI-1's limit of 32,767")
    );
    // INR has no such limit.
    assert_eq!(decode_inr(&incise_io::encode_inr(&v), "w.inr").unwrap().dims(), [40_000, 1, 1]);
}

#[test]
fn corrupt_gzip_is_an_io_error() {
    let mut bytes = gz(&Nifti::new([4, 4, 4], 2, 8).file(&[3; 64]));
    let n = bytes.len();
    bytes[n - 7] ^= 0x55; // CRC-32
    let err = decode_nifti(&bytes, "crc.nii.gz").unwrap_err();
    assert!(matches!(err, IoError::Io { .. }), "{err:?}");
    assert_message(&err, "crc.nii.gz", &["corrupt gzip stream"]);
}
