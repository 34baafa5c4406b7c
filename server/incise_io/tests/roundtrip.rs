//! Volumes written by the encoders read back with the same labels and placement, in memory and
//! through files, plain and gzip-compressed.

#![allow(clippy::float_cmp, reason = "exact values are written and must read back exactly")]

mod common;

use common::{IDENTITY, TempDir, assert_close, assert_same_volume, rotation, sample};
use incise_io::{
    decode_inr, decode_nifti, decode_volume, encode_inr, encode_nifti, read_inr, read_nifti,
    read_volume, write_inr, write_nifti, write_volume,
};

/// Float32 storage of millimetre values keeps about seven digits.
const F32_REL: f64 = 1e-6;

fn tilted() -> [[f64; 3]; 3] {
    let n = (1.0f64 + 4.0 + 9.0).sqrt();
    rotation([1.0 / n, -2.0 / n, 3.0 / n], 0.83)
}

#[test]
fn nifti_round_trip_in_memory_keeps_labels_and_placement() {
    for max_label in [9, 255, 65535] {
        let v = sample(max_label, tilted());
        let bytes = encode_nifti(&v).unwrap();
        assert_eq!(bytes.len(), 352 + 2 * 60);
        assert_same_volume(&decode_nifti(&bytes, "mem.nii").unwrap(), &v, F32_REL);
        assert_same_volume(&decode_volume(&bytes, "mem").unwrap(), &v, F32_REL);
    }
}

#[test]
fn nifti_round_trip_keeps_a_reflection() {
    // A left-handed voxel grid: the quaternion needs qfac = -1, the sform carries it directly.
    let mut d = tilted();
    for row in &mut d {
        row[1] = -row[1];
    }
    let v = sample(40, d);
    assert_same_volume(&decode_nifti(&encode_nifti(&v).unwrap(), "m").unwrap(), &v, F32_REL);
}

#[test]
fn nifti_qform_written_alongside_the_sform_places_the_volume_alike() {
    // Zero sform_code: the reader must fall back to the quaternion written next to it.
    for d in [tilted(), IDENTITY, rotation([0.0, 0.0, 1.0], std::f64::consts::PI)] {
        let v = sample(7, d);
        let mut bytes = encode_nifti(&v).unwrap();
        bytes[254..256].copy_from_slice(&0i16.to_le_bytes());
        assert_same_volume(&decode_nifti(&bytes, "q.nii").unwrap(), &v, 1e-5);
    }
}

#[test]
fn nifti_header_fields_follow_the_standard() {
    let v = sample(3, IDENTITY);
    let b = encode_nifti(&v).unwrap();
    let i16_at = |o: usize| i16::from_le_bytes([b[o], b[o + 1]]);
    let f32_at = |o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    assert_eq!(i32::from_le_bytes([b[0], b[1], b[2], b[3]]), 348);
    assert_eq!((i16_at(40), i16_at(42), i16_at(44), i16_at(46)), (3, 5, 4, 3));
    assert_eq!((i16_at(70), i16_at(72)), (512, 16), "uint16 labels");
    assert_eq!(f32_at(108).to_bits(), 352f32.to_bits(), "vox_offset");
    assert_eq!(b[123], 2, "millimetres");
    assert_eq!((i16_at(252), i16_at(254)), (1, 1), "qform and sform set");
    assert_eq!(&b[344..348], b"n+1\0");
    assert_close(&[f64::from(f32_at(80)), f64::from(f32_at(296 + 12))], &[0.8, 38.5], 1e-6, "mm");
}

#[test]
fn nifti_round_trip_through_files_plain_and_gzip() {
    let dir = TempDir::new("nifti_files");
    let v = sample(1000, tilted());
    for (name, gzipped) in [("vol.nii", false), ("vol.nii.gz", true)] {
        let path = dir.join(name);
        write_nifti(&path, &v).unwrap();
        let on_disk = std::fs::read(&path).unwrap();
        assert_eq!(on_disk.starts_with(&[0x1f, 0x8b]), gzipped, "{name}");
        assert_same_volume(&read_nifti(&path).unwrap(), &v, F32_REL);
        assert_same_volume(&read_volume(&path).unwrap(), &v, F32_REL);
    }
}

#[test]
fn inr_round_trip_in_memory_keeps_labels_origin_and_spacing() {
    // INRIMAGE-4 has no orientation field, so only axis-aligned volumes survive unchanged.
    for max_label in [9, 255, 65535] {
        let v = sample(max_label, IDENTITY);
        let bytes = encode_inr(&v);
        let bytes_per_voxel = if max_label <= 255 { 1 } else { 2 };
        assert_eq!(bytes.len(), 256 + bytes_per_voxel * 60);
        let header = String::from_utf8_lossy(&bytes[..256]).into_owned();
        assert!(header.contains(&format!("PIXSIZE={} bits\n", 8 * bytes_per_voxel)), "{header}");
        assert_same_volume(&decode_inr(&bytes, "mem.inr").unwrap(), &v, 1e-12);
        assert_same_volume(&decode_volume(&bytes, "mem").unwrap(), &v, 1e-12);
    }
}

#[test]
fn inr_drops_the_direction_but_keeps_the_rest() {
    let v = sample(200, tilted());
    let back = decode_inr(&encode_inr(&v), "m.inr").unwrap();
    assert_eq!(back.direction(), IDENTITY);
    assert_eq!(back.labels(), v.labels());
    assert_close(&back.origin(), &v.origin(), 1e-12, "origin");
}

#[test]
fn inr_round_trip_through_files_plain_and_gzip() {
    let dir = TempDir::new("inr_files");
    let v = sample(300, IDENTITY);
    for (name, gzipped) in [("vol.inr", false), ("vol.inr.gz", true)] {
        let path = dir.join(name);
        write_inr(&path, &v).unwrap();
        let on_disk = std::fs::read(&path).unwrap();
        assert_eq!(on_disk.starts_with(&[0x1f, 0x8b]), gzipped, "{name}");
        assert_same_volume(&read_inr(&path).unwrap(), &v, 1e-12);
        assert_same_volume(&read_volume(&path).unwrap(), &v, 1e-12);
    }
}

#[test]
fn format_and_compression_are_found_by_content() {
    let dir = TempDir::new("sniffing");
    let v = sample(12, IDENTITY);
    // Unknown extensions: the reader looks inside, through gzip if needed.
    for (name, bytes) in [
        ("a.img3d", encode_nifti(&v).unwrap()),
        ("b.dat.gz", common::gz(&encode_nifti(&v).unwrap())),
        ("c", encode_inr(&v)),
        ("d.gz", common::gz(&encode_inr(&v))),
        // Gzip content under a plain name is still inflated.
        ("e.nii", common::gz(&encode_nifti(&v).unwrap())),
        ("f.inr", common::gz(&encode_inr(&v))),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        assert_same_volume(&read_volume(&path).unwrap(), &v, F32_REL);
    }
}

#[test]
fn write_volume_picks_the_format_by_extension() {
    let dir = TempDir::new("write_volume");
    let v = sample(90, IDENTITY);
    for name in ["w.nii", "w.nii.gz", "w.inr", "w.INR.GZ"] {
        let path = dir.join(name);
        write_volume(&path, &v).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let plain = if bytes.starts_with(&[0x1f, 0x8b]) {
            let mut out = Vec::new();
            std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&bytes[..]), &mut out)
                .unwrap();
            out
        } else {
            bytes
        };
        let is_inr = name.to_lowercase().contains(".inr");
        assert_eq!(plain.starts_with(b"#INRIMAGE-4#{"), is_inr, "{name}");
        assert_same_volume(&read_volume(&path).unwrap(), &v, F32_REL);
    }
}
