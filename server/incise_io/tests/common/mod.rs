//! Test helpers: hand-built NIfTI-1 and INRIMAGE-4 files (independent of the crate's encoders),
//! temporary folders, and sample volumes.

#![allow(dead_code)] // Each test binary uses a different subset.

use incise_grid::LabelVolume;
use std::path::PathBuf;

/// A NIfTI-1 header laid out field by field, in either byte order.
#[derive(Clone, Debug)]
pub struct Nifti {
    pub big_endian: bool,
    pub sizeof_hdr: i32,
    pub dim: [i16; 8],
    pub datatype: i16,
    pub bitpix: i16,
    pub pixdim: [f32; 8],
    pub vox_offset: f32,
    pub scl_slope: f32,
    pub scl_inter: f32,
    pub xyzt_units: u8,
    pub qform_code: i16,
    pub sform_code: i16,
    pub quatern: [f32; 3],
    pub qoffset: [f32; 3],
    pub srow: [[f32; 4]; 3],
    pub magic: [u8; 4],
}

impl Nifti {
    /// A 3-D header with 1 mm voxels, no transform, little-endian.
    pub fn new(dims: [i16; 3], datatype: i16, bitpix: i16) -> Self {
        Self {
            big_endian: false,
            sizeof_hdr: 348,
            dim: [3, dims[0], dims[1], dims[2], 1, 1, 1, 1],
            datatype,
            bitpix,
            pixdim: [1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            vox_offset: 352.0,
            scl_slope: 0.0,
            scl_inter: 0.0,
            xyzt_units: 2,
            qform_code: 0,
            sform_code: 0,
            quatern: [0.0; 3],
            qoffset: [0.0; 3],
            srow: [[0.0; 4]; 3],
            magic: *b"n+1\0",
        }
    }

    /// Header, zero padding up to `vox_offset`, then `data` as given.
    pub fn file(&self, data: &[u8]) -> Vec<u8> {
        let len = (self.vox_offset as usize).max(348);
        let mut out = vec![0u8; len];
        let big = self.big_endian;
        let mut put = |at: usize, le: &[u8]| {
            let mut bytes = le.to_vec();
            if big {
                bytes.reverse();
            }
            out[at..at + bytes.len()].copy_from_slice(&bytes);
        };
        put(0, &self.sizeof_hdr.to_le_bytes());
        for (i, d) in self.dim.iter().enumerate() {
            put(40 + 2 * i, &d.to_le_bytes());
        }
        put(70, &self.datatype.to_le_bytes());
        put(72, &self.bitpix.to_le_bytes());
        for (i, p) in self.pixdim.iter().enumerate() {
            put(76 + 4 * i, &p.to_le_bytes());
        }
        put(108, &self.vox_offset.to_le_bytes());
        put(112, &self.scl_slope.to_le_bytes());
        put(116, &self.scl_inter.to_le_bytes());
        put(123, &[self.xyzt_units]);
        put(252, &self.qform_code.to_le_bytes());
        put(254, &self.sform_code.to_le_bytes());
        for (i, q) in self.quatern.iter().chain(&self.qoffset).enumerate() {
            put(256 + 4 * i, &q.to_le_bytes());
        }
        for (r, row) in self.srow.iter().enumerate() {
            for (c, v) in row.iter().enumerate() {
                put(280 + 16 * r + 4 * c, &v.to_le_bytes());
            }
        }
        out[344..348].copy_from_slice(&self.magic);
        out.extend_from_slice(data);
        out
    }
}

/// An INRIMAGE-4 file: the magic, `fields` (one `KEY=VALUE` per line), newline padding to
/// `header_len - 4` bytes, `##}\n`, then `data`.
pub fn inr_file(fields: &str, header_len: usize, data: &[u8]) -> Vec<u8> {
    let mut out = format!("#INRIMAGE-4#{{\n{fields}").into_bytes();
    assert!(out.len() + 4 <= header_len, "fields do not fit the header");
    out.resize(header_len - 4, b'\n');
    out.extend_from_slice(b"##}\n");
    out.extend_from_slice(data);
    out
}

/// `bytes` gzip-compressed.
pub fn gz(bytes: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// A fresh empty folder under the system temp dir, removed again when dropped.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> Self {
        let path = std::env::temp_dir().join(format!("incise_io_{}_{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path).unwrap();
        Self(path)
    }

    pub fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Rotation by `angle` about the unit `axis` (Rodrigues).
pub fn rotation(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let [x, y, z] = axis;
    let t = 1.0 - c;
    [
        [c + x * x * t, x * y * t - z * s, x * z * t + y * s],
        [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
        [z * x * t - y * s, z * y * t + x * s, c + z * z * t],
    ]
}

/// A 5×4×3 volume with anisotropic spacing, an offset origin, and labels up to `max_label`.
pub fn sample(max_label: u16, direction: [[f64; 3]; 3]) -> LabelVolume {
    let labels = (0..60u32).map(|i| ((i * 37 + 11) % (u32::from(max_label) + 1)) as u16).collect();
    LabelVolume::new([5, 4, 3], [0.8e-3, 0.55e-3, 2.5e-3], labels)
        .unwrap()
        .with_placement([-0.112, 0.0385, 0.2041], direction)
        .unwrap()
}

pub const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// Asserts `a` and `b` agree element by element within `rel` of the largest magnitude in `b`
/// (direction entries near zero carry float32 noise of the size of the other entries).
pub fn assert_close(a: &[f64], b: &[f64], rel: f64, what: &str) {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (x, y) in a.iter().zip(b) {
        assert!((x - y).abs() <= rel * scale, "{what}: {a:?} vs {b:?}");
    }
}

/// Asserts that two volumes have the same labels, extent, spacing, origin and direction (the
/// last three to float32 precision, as NIfTI stores them).
pub fn assert_same_volume(got: &LabelVolume, want: &LabelVolume, rel: f64) {
    assert_eq!(got.dims(), want.dims());
    assert_eq!(got.labels(), want.labels());
    assert_close(&got.spacing(), &want.spacing(), rel, "spacing");
    assert_close(&got.origin(), &want.origin(), rel, "origin");
    assert_close(got.direction().as_flattened(), want.direction().as_flattened(), rel, "direction");
}

/// Asserts `err`'s message starts with `file` and contains every one of `parts`.
pub fn assert_message(err: &incise_io::IoError, file: &str, parts: &[&str]) {
    let msg = err.to_string();
    assert!(msg.starts_with(&format!("{file}: ")), "message does not name {file}: {msg}");
    assert_eq!(err.file(), file);
    for p in parts {
        assert!(msg.contains(p), "message lacks {p:?}: {msg}");
    }
}
