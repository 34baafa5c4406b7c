//! Fuzz-style properties: no byte string makes a decoder panic.
//!
//! Inputs are random bytes, valid encodings cut at random lengths, and valid encodings with a few
//! bytes changed, each fed to both decoders plain and gzip-compressed. Every case must come back
//! as `Ok` or `Err`; a panic fails the property. Volumes are tiny so that 256 cases per property
//! run in well under a second.

use crate::{decode_inr, decode_nifti, decode_volume, encode_inr, encode_nifti};
use incise_grid::LabelVolume;
use proptest::prelude::*;

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
