//! NIfTI-1 single-file volumes (`.nii`, `.nii.gz`).
//!
//! The decoder reads the 348-byte header in either byte order (told apart by `sizeof_hdr`), skips
//! header extensions up to `vox_offset`, converts the voxels to labels (after `scl_slope` /
//! `scl_inter`) and places the volume from the `sform` when its code is set, else from the
//! `qform` quaternion, else at the origin with axis-aligned orientation. Lengths are in the unit
//! of `xyzt_units` (millimetres when unset) and come out in metres.
//!
//! The encoder writes little-endian `uint16` labels with both `sform` and `qform` describing the
//! volume's placement in millimetres, and `intent_code` 1002 (label map) so viewers colour it as
//! segmentation.

use crate::error::{IoError, grouped};
use crate::gzip::{self, Input};
use crate::samples::{ByteOrder, SampleType, Scaling, to_labels};
use incise_grid::LabelVolume;
use std::path::Path;

/// Bytes in the fixed NIfTI-1 header.
const HEADER_SIZE: usize = 348;
/// The header plus the 4-byte extension flag: where voxels start at the earliest in a `.nii`.
const MIN_VOX_OFFSET: u64 = 352;
/// `sizeof_hdr` of NIfTI-2, recognised only to say it is unsupported.
const NIFTI2_HEADER_SIZE: i32 = 540;
/// NIfTI-1 stores extents as `int16`.
const MAX_EXTENT: usize = i16::MAX as usize;
/// `NIFTI_INTENT_LABEL`: voxel values are indices into a label table.
const INTENT_LABEL: i16 = 1002;
/// `DT_UINT16`.
const DT_UINT16: i16 = 512;
/// `NIFTI_UNITS_MM`.
const UNITS_MM: u8 = 2;
/// `NIFTI_XFORM_SCANNER_ANAT`, written for both transforms.
const XFORM_SCANNER: i16 = 1;
/// Name used in errors by the in-memory encoder.
const MEMORY_NAME: &str = "<in-memory NIfTI>";
/// Largest |cosine| between two `sform` axes still read as perpendicular: `float32` rounding of
/// a rigid transform stays near 1e-7, a real shear (gantry tilt) is far above.
const MAX_SHEAR_COSINE: f64 = 1e-4;

/// Byte offsets of the header fields this crate reads or writes.
mod field {
    pub(super) const SIZEOF_HDR: usize = 0;
    pub(super) const DIM: usize = 40;
    pub(super) const INTENT_CODE: usize = 68;
    pub(super) const DATATYPE: usize = 70;
    pub(super) const BITPIX: usize = 72;
    pub(super) const PIXDIM: usize = 76;
    pub(super) const VOX_OFFSET: usize = 108;
    pub(super) const SCL_SLOPE: usize = 112;
    pub(super) const SCL_INTER: usize = 116;
    pub(super) const XYZT_UNITS: usize = 123;
    pub(super) const DESCRIP: usize = 148;
    pub(super) const QFORM_CODE: usize = 252;
    pub(super) const SFORM_CODE: usize = 254;
    pub(super) const QUATERN_B: usize = 256;
    pub(super) const QOFFSET_X: usize = 268;
    pub(super) const SROW_X: usize = 280;
    pub(super) const MAGIC: usize = 344;
}

/// Reads a `.nii` or `.nii.gz` file (gzip is recognised by its magic bytes, not the name).
pub fn read_nifti(path: &Path) -> Result<LabelVolume, IoError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| IoError::Io { file: file.clone(), source })?;
    decode_nifti(&bytes, &file)
}

/// Decodes a NIfTI-1 single-file image held in memory, gzip-compressed or not. `file` names the
/// bytes in errors.
pub fn decode_nifti(bytes: &[u8], file: &str) -> Result<LabelVolume, IoError> {
    let mut input = Input::new(bytes, file);
    let head = input.take(HEADER_SIZE)?;
    let header = Header::parse(&head, file)?;

    let gap = header.vox_offset - HEADER_SIZE as u64;
    let skipped = input.skip(gap)?;
    if skipped < gap {
        return Err(IoError::Truncated {
            file: file.to_owned(),
            what: format!("header extension before vox_offset={}", header.vox_offset),
            expected: gap,
            found: skipped,
        });
    }

    let [nx, ny, nz] = header.dims;
    let needed = header.data_bytes(file)?;
    let raw = input.take_voxels(
        needed,
        &format!("{nx}×{ny}×{nz} {}", header.sample.name()),
        &format!("dim ({nx}×{ny}×{nz}) and datatype ({})", header.sample.name()),
    )?;
    let labels = to_labels(&raw, header.sample, header.order, header.scaling, file)?;
    drop(raw);

    let volume = |source| IoError::Volume { file: file.to_owned(), source };
    LabelVolume::new(header.dims, header.spacing, labels)
        .map_err(volume)?
        .with_placement(header.origin, header.direction)
        .map_err(volume)
}

/// Encodes `volume` as an uncompressed NIfTI-1 image with `uint16` labels. Fails only when an
/// extent exceeds NIfTI-1's limit of 32,767 voxels.
pub fn encode_nifti(volume: &LabelVolume) -> Result<Vec<u8>, IoError> {
    encode(volume, MEMORY_NAME)
}

/// Writes `volume` as NIfTI-1, gzip-compressed when `path` ends in `.gz`.
pub fn write_nifti(path: &Path, volume: &LabelVolume) -> Result<(), IoError> {
    let file = path.display().to_string();
    let bytes = encode(volume, &file)?;
    let bytes = if crate::ends_with_gz(path) { gzip::compress(&bytes) } else { Ok(bytes) };
    bytes.and_then(|b| std::fs::write(path, b)).map_err(|source| IoError::Io { file, source })
}

/// What the decoder needs from the header, already converted to metres and checked.
#[derive(Debug)]
struct Header {
    order: ByteOrder,
    dims: [usize; 3],
    sample: SampleType,
    vox_offset: u64,
    scaling: Option<Scaling>,
    spacing: [f64; 3],
    origin: [f64; 3],
    direction: [[f64; 3]; 3],
}

/// Typed access to the raw header bytes in the file's byte order.
struct Fields<'a> {
    bytes: &'a [u8; HEADER_SIZE],
    order: ByteOrder,
    file: &'a str,
}

impl Fields<'_> {
    fn array<const N: usize>(&self, offset: usize) -> [u8; N] {
        std::array::from_fn(|i| self.bytes[offset + i])
    }

    fn i16(&self, offset: usize) -> i16 {
        match self.order {
            ByteOrder::Little => i16::from_le_bytes(self.array(offset)),
            ByteOrder::Big => i16::from_be_bytes(self.array(offset)),
        }
    }

    fn f32(&self, offset: usize) -> f64 {
        f64::from(match self.order {
            ByteOrder::Little => f32::from_le_bytes(self.array(offset)),
            ByteOrder::Big => f32::from_be_bytes(self.array(offset)),
        })
    }

    /// `count` consecutive `float32` values starting at `offset`, which must all be finite.
    fn finite_f32s<const N: usize>(&self, offset: usize, name: &str) -> Result<[f64; N], IoError> {
        let values: [f64; N] = std::array::from_fn(|i| self.f32(offset + 4 * i));
        match values.iter().position(|v| !v.is_finite()) {
            None => Ok(values),
            Some(i) => {
                Err(self.bad(format!("header field {name}[{i}]={} is not finite", values[i])))
            }
        }
    }

    fn bad(&self, what: String) -> IoError {
        IoError::BadHeader { file: self.file.to_owned(), what }
    }

    fn bad_spacing(&self, what: String) -> IoError {
        IoError::BadSpacing { file: self.file.to_owned(), what }
    }

    fn unsupported(&self, what: String) -> IoError {
        IoError::UnsupportedType { file: self.file.to_owned(), what }
    }

    fn mismatch(&self, what: String) -> IoError {
        IoError::HeaderSizeMismatch { file: self.file.to_owned(), what }
    }
}

impl Header {
    fn parse(head: &[u8], file: &str) -> Result<Self, IoError> {
        let truncated = || IoError::Truncated {
            file: file.to_owned(),
            what: "NIfTI-1 header".to_owned(),
            expected: HEADER_SIZE as u64,
            found: head.len() as u64,
        };
        let order = byte_order(head, file)?.ok_or_else(truncated)?;
        let bytes: &[u8; HEADER_SIZE] = head.try_into().map_err(|_| truncated())?;
        let f = Fields { bytes, order, file };

        match &bytes[field::MAGIC..] {
            b"n+1\0" => {}
            b"ni1\0" => {
                return Err(f.unsupported(
                    "two-file NIfTI (.hdr/.img pair, magic \"ni1\"); convert it to a single .nii"
                        .to_owned(),
                ));
            }
            other => {
                return Err(f.bad(format!(
                    "bad magic {:?} at byte 344: a single-file NIfTI-1 has \"n+1\\0\"",
                    String::from_utf8_lossy(other)
                )));
            }
        }

        let dims = parse_dims(&f)?;
        let sample = parse_datatype(&f)?;

        let vox_offset = f.f32(field::VOX_OFFSET);
        if !(vox_offset.is_finite() && vox_offset >= 0.0 && vox_offset.fract() == 0.0) {
            return Err(f.bad(format!("header field vox_offset={vox_offset} is not a byte offset")));
        }
        // Saturates for offsets beyond u64, which then read as truncated.
        let vox_offset = vox_offset as u64;
        if vox_offset < MIN_VOX_OFFSET {
            return Err(f.mismatch(format!(
                "vox_offset={vox_offset} points inside the {MIN_VOX_OFFSET}-byte header of a \
                 single-file NIfTI"
            )));
        }

        let scaling = parse_scaling(&f)?;
        let unit = spatial_unit(&f)?;
        let placement = parse_placement(&f, dims, unit)?;
        Ok(Self {
            order,
            dims: dims.extent,
            sample,
            vox_offset,
            scaling,
            spacing: placement.spacing,
            origin: placement.origin,
            direction: placement.direction,
        })
    }

    /// Bytes of voxel data the header announces.
    fn data_bytes(&self, file: &str) -> Result<usize, IoError> {
        let [nx, ny, nz] = self.dims;
        nx.checked_mul(ny)
            .and_then(|n| n.checked_mul(nz))
            .and_then(|n| n.checked_mul(self.sample.size()))
            .ok_or_else(|| IoError::BadHeader {
                file: file.to_owned(),
                what: format!("extent {nx}×{ny}×{nz} overflows the address space"),
            })
    }
}

/// The byte order in which `sizeof_hdr` reads 348, or `None` when fewer than 4 bytes are there.
fn byte_order(head: &[u8], file: &str) -> Result<Option<ByteOrder>, IoError> {
    let Some(&first) = head.first_chunk::<4>() else {
        return Ok(None);
    };
    let (le, be) = (i32::from_le_bytes(first), i32::from_be_bytes(first));
    let size = HEADER_SIZE as i32;
    if le == size {
        Ok(Some(ByteOrder::Little))
    } else if be == size {
        Ok(Some(ByteOrder::Big))
    } else if le == NIFTI2_HEADER_SIZE || be == NIFTI2_HEADER_SIZE {
        Err(IoError::UnsupportedType {
            file: file.to_owned(),
            what: "NIfTI-2 (sizeof_hdr 540); only NIfTI-1 is read".to_owned(),
        })
    } else {
        Err(IoError::BadHeader {
            file: file.to_owned(),
            what: format!(
                "bad magic: not a NIfTI-1 file (sizeof_hdr at byte {} is {le}, expected 348)",
                field::SIZEOF_HDR
            ),
        })
    }
}

/// Whether `head` starts with a NIfTI `sizeof_hdr` (1 or 2, either byte order).
pub(crate) fn sniff(head: &[u8]) -> bool {
    head.first_chunk::<4>().is_some_and(|&b| {
        [i32::from_le_bytes(b), i32::from_be_bytes(b)]
            .iter()
            .any(|&n| n == HEADER_SIZE as i32 || n == NIFTI2_HEADER_SIZE)
    })
}

#[derive(Clone, Copy, Debug)]
struct Dims {
    /// `dim[0]`: how many of the extents are meaningful.
    count: usize,
    extent: [usize; 3],
}

fn parse_dims(f: &Fields) -> Result<Dims, IoError> {
    let dim: [i16; 8] = std::array::from_fn(|i| f.i16(field::DIM + 2 * i));
    let count = dim[0];
    if !(1..=7).contains(&count) {
        return Err(f.bad(format!("header field dim[0]={count} is not a dimension count in 1..=7")));
    }
    let count = count as usize;
    if let Some(i) = (1..=count).find(|&i| dim[i] < 1) {
        return Err(f.bad(format!("header field dim[{i}]={} is not a positive extent", dim[i])));
    }
    if count > 4 {
        return Err(f.unsupported(format!(
            "{count}-D image (dim[0]={count}); only 3-D label volumes are read"
        )));
    }
    if count == 4 && dim[4] != 1 {
        return Err(f.unsupported(format!(
            "4-D series of {} volumes (dim[4]={}); only a single 3-D label volume is read",
            dim[4], dim[4]
        )));
    }
    let extent = std::array::from_fn(|a| if a < count { dim[a + 1] as usize } else { 1 });
    Ok(Dims { count, extent })
}

fn parse_datatype(f: &Fields) -> Result<SampleType, IoError> {
    let code = f.i16(field::DATATYPE);
    let sample = match code {
        2 => SampleType::U8,
        4 => SampleType::I16,
        8 => SampleType::I32,
        16 => SampleType::F32,
        64 => SampleType::F64,
        256 => SampleType::I8,
        512 => SampleType::U16,
        768 => SampleType::U32,
        1024 => SampleType::I64,
        1280 => SampleType::U64,
        _ => {
            let name = match code {
                0 => "unknown",
                1 => "binary",
                32 => "complex64",
                128 => "RGB24",
                1536 => "float128",
                1792 => "complex128",
                2048 => "complex256",
                2304 => "RGBA32",
                _ => "not a NIfTI-1 type",
            };
            return Err(f.unsupported(format!(
                "datatype {code} ({name}); labels must be stored as int8..int64, uint8..uint64, \
                 float32 or float64"
            )));
        }
    };
    let bitpix = f.i16(field::BITPIX);
    let bits = 8 * sample.size();
    if i64::from(bitpix) != bits as i64 {
        return Err(f.mismatch(format!(
            "bitpix={bitpix} but datatype {code} ({}) has {bits} bits per voxel",
            sample.name()
        )));
    }
    Ok(sample)
}

/// The value transform, or `None` when it is the identity. A slope of 0 means "unset" in the
/// standard; NaN is how some writers say the same, and readers commonly treat it so.
#[expect(clippy::float_cmp, reason = "the identity is stored exactly as slope 1, intercept 0")]
fn parse_scaling(f: &Fields) -> Result<Option<Scaling>, IoError> {
    let slope = f.f32(field::SCL_SLOPE);
    let inter = f.f32(field::SCL_INTER);
    if slope == 0.0 || slope.is_nan() || (slope == 1.0 && inter == 0.0) {
        return Ok(None);
    }
    if !slope.is_finite() || !inter.is_finite() {
        return Err(f.bad(format!(
            "header fields scl_slope={slope}, scl_inter={inter} do not give finite values"
        )));
    }
    Ok(Some(Scaling { slope, inter }))
}

/// How many file length units make a metre.
fn spatial_unit(f: &Fields) -> Result<f64, IoError> {
    let units = f.bytes[field::XYZT_UNITS];
    match units & 0x07 {
        // Unknown units: NIfTI data in the wild is millimetres.
        0 | 2 => Ok(1e3),
        1 => Ok(1.0),
        3 => Ok(1e6),
        code => Err(f.bad_spacing(format!(
            "xyzt_units={units} has spatial unit code {code}; expected 1 (m), 2 (mm), 3 (µm) or \
             0 (unknown, read as mm)"
        ))),
    }
}

struct Placement {
    spacing: [f64; 3],
    origin: [f64; 3],
    direction: [[f64; 3]; 3],
}

fn parse_placement(f: &Fields, dims: Dims, unit: f64) -> Result<Placement, IoError> {
    let pixdim: [f64; 8] = std::array::from_fn(|i| f.f32(field::PIXDIM + 4 * i));
    // Axes beyond dim[0] have no meaningful pixdim; any positive length keeps LabelVolume happy.
    let spacing: [f64; 3] = std::array::from_fn(|a| {
        let h = pixdim[a + 1];
        if a >= dims.count && !(h.is_finite() && h > 0.0) { unit * 1e-3 } else { h }
    });
    let spacing = spacing.map(|h| h / unit);
    let qform_code = f.i16(field::QFORM_CODE);
    if f.i16(field::SFORM_CODE) > 0 {
        match sform_placement(f, unit) {
            Ok(p) => return Ok(p),
            // A sheared or degenerate sform cannot be represented, but a qform is rigid by
            // construction and describes the same scanner space.
            Err(e) if qform_code <= 0 => return Err(e),
            Err(_) => {}
        }
    }
    if qform_code > 0 {
        return qform_placement(f, pixdim[0], spacing, unit);
    }
    Ok(Placement { spacing, origin: [0.0; 3], direction: IDENTITY })
}

/// The placement given by `srow_x/y/z`.
fn sform_placement(f: &Fields, unit: f64) -> Result<Placement, IoError> {
    let rows: [[f64; 4]; 3] = [
        f.finite_f32s(field::SROW_X, "srow_x")?,
        f.finite_f32s(field::SROW_X + 16, "srow_y")?,
        f.finite_f32s(field::SROW_X + 32, "srow_z")?,
    ];
    let mut columns = [[0.0; 3]; 3];
    let mut spacing = [0.0; 3];
    for c in 0..3 {
        let column = [rows[0][c], rows[1][c], rows[2][c]];
        let norm = length(column);
        if norm == 0.0 {
            return Err(f.bad_spacing(format!(
                "sform axis {c} (column {c} of srow_x/y/z) has zero length"
            )));
        }
        spacing[c] = norm / unit;
        columns[c] = column.map(|v| v / norm);
    }
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        let cosine = dot(columns[a], columns[b]);
        if cosine.abs() > MAX_SHEAR_COSINE {
            return Err(f.bad_spacing(format!(
                "sform axes {a} and {b} are not perpendicular (cosine {cosine:.6}); a sheared \
                 volume cannot be represented and the header has no qform to fall back on"
            )));
        }
    }
    // Remove the float32 rounding so that the direction is orthonormal to double precision.
    let c0 = columns[0];
    let c1 = normalized(sub(columns[1], scale(c0, dot(columns[1], c0))));
    let c2 = columns[2];
    let c2 = normalized(sub(sub(c2, scale(c0, dot(c2, c0))), scale(c1, dot(c2, c1))));
    let direction = std::array::from_fn(|r| [c0[r], c1[r], c2[r]]);
    let origin = std::array::from_fn(|r| rows[r][3] / unit);
    Ok(Placement { spacing, origin, direction })
}

fn qform_placement(
    f: &Fields,
    qfac: f64,
    spacing: [f64; 3],
    unit: f64,
) -> Result<Placement, IoError> {
    let [b, c, d]: [f64; 3] = f.finite_f32s(field::QUATERN_B, "quatern_b/c/d")?;
    let offset: [f64; 3] = f.finite_f32s(field::QOFFSET_X, "qoffset_x/y/z")?;
    let mut r = rotation(b, c, d);
    // pixdim[0] is qfac: -1 flips the third axis (left-handed voxel grid), anything else is 1.
    if qfac < 0.0 {
        for row in &mut r {
            row[2] = -row[2];
        }
    }
    Ok(Placement { spacing, origin: offset.map(|v| v / unit), direction: r })
}

/// The rotation of the unit quaternion `(a, b, c, d)` with `a` implied (NIfTI-1 `qform`).
fn rotation(b: f64, c: f64, d: f64) -> [[f64; 3]; 3] {
    let s = b * b + c * c + d * d;
    // Float32 storage can push |(b, c, d)| just past 1: that is a 180° turn, a = 0.
    let (a, b, c, d) = if s > 1.0 {
        let n = s.sqrt();
        (0.0, b / n, c / n, d / n)
    } else {
        ((1.0 - s).sqrt(), b, c, d)
    };
    [
        [a * a + b * b - c * c - d * d, 2.0 * (b * c - a * d), 2.0 * (b * d + a * c)],
        [2.0 * (b * c + a * d), a * a + c * c - b * b - d * d, 2.0 * (c * d - a * b)],
        [2.0 * (b * d - a * c), 2.0 * (c * d + a * b), a * a + d * d - b * b - c * c],
    ]
}

/// `(b, c, d, qfac)` of an orthonormal `direction`: `qfac = -1` when it is a reflection, whose
/// third column is flipped to leave a rotation. Non-orthonormal input (which `LabelVolume` does
/// not forbid) gives some unit quaternion; readers use the `sform`, written exactly.
fn quaternion(direction: [[f64; 3]; 3]) -> ([f64; 3], f64) {
    let mut r = direction;
    let qfac = if det(r) < 0.0 { -1.0 } else { 1.0 };
    if qfac < 0.0 {
        for row in &mut r {
            row[2] = -row[2];
        }
    }
    // Shepperd's method: divide by the largest of the four diagonal combinations.
    let trace = r[0][0] + r[1][1] + r[2][2];
    let q = if trace > 0.0 {
        let s = 2.0 * (trace + 1.0).sqrt();
        [s / 4.0, (r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = 2.0 * (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt();
        [(r[2][1] - r[1][2]) / s, s / 4.0, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s]
    } else if r[1][1] > r[2][2] {
        let s = 2.0 * (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt();
        [(r[0][2] - r[2][0]) / s, (r[0][1] + r[1][0]) / s, s / 4.0, (r[1][2] + r[2][1]) / s]
    } else {
        let s = 2.0 * (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt();
        [(r[1][0] - r[0][1]) / s, (r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, s / 4.0]
    };
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(n.is_finite() && n > 0.0) {
        return ([0.0; 3], qfac);
    }
    // NIfTI derives a = sqrt(1 - b² - c² - d²) ≥ 0, so the stored sign must make a non-negative.
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    ([q[1], q[2], q[3]].map(|v| sign * v / n), qfac)
}

fn encode(volume: &LabelVolume, file: &str) -> Result<Vec<u8>, IoError> {
    let dims = volume.dims();
    if let Some(axis) = (0..3).find(|&a| dims[a] > MAX_EXTENT) {
        return Err(IoError::UnsupportedType {
            file: file.to_owned(),
            what: format!(
                "extent {} along axis {axis} exceeds NIfTI-1's limit of {} voxels",
                dims[axis],
                grouped(MAX_EXTENT as u64)
            ),
        });
    }
    let mm = |m: f64| (m * 1e3) as f32;
    let spacing = volume.spacing().map(mm);
    let origin = volume.origin().map(mm);
    let direction = volume.direction();
    let (bcd, qfac) = quaternion(direction);

    let labels = volume.labels();
    let mut out = vec![0u8; MIN_VOX_OFFSET as usize];
    let mut put =
        |offset: usize, bytes: &[u8]| out[offset..offset + bytes.len()].copy_from_slice(bytes);
    put(field::SIZEOF_HDR, &(HEADER_SIZE as i32).to_le_bytes());
    let dim: [i16; 8] = [3, dims[0] as i16, dims[1] as i16, dims[2] as i16, 1, 1, 1, 1];
    for (i, d) in dim.iter().enumerate() {
        put(field::DIM + 2 * i, &d.to_le_bytes());
    }
    put(field::INTENT_CODE, &INTENT_LABEL.to_le_bytes());
    put(field::DATATYPE, &DT_UINT16.to_le_bytes());
    put(field::BITPIX, &16i16.to_le_bytes());
    let pixdim = [qfac as f32, spacing[0], spacing[1], spacing[2], 0.0, 0.0, 0.0, 0.0];
    for (i, p) in pixdim.iter().enumerate() {
        put(field::PIXDIM + 4 * i, &p.to_le_bytes());
    }
    put(field::VOX_OFFSET, &(MIN_VOX_OFFSET as f32).to_le_bytes());
    put(field::SCL_SLOPE, &1f32.to_le_bytes());
    put(field::SCL_INTER, &0f32.to_le_bytes());
    put(field::XYZT_UNITS, &[UNITS_MM]);
    put(field::DESCRIP, b"incise label volume");
    put(field::QFORM_CODE, &XFORM_SCANNER.to_le_bytes());
    put(field::SFORM_CODE, &XFORM_SCANNER.to_le_bytes());
    for (i, v) in bcd.iter().enumerate() {
        put(field::QUATERN_B + 4 * i, &(*v as f32).to_le_bytes());
    }
    for (i, v) in origin.iter().enumerate() {
        put(field::QOFFSET_X + 4 * i, &v.to_le_bytes());
    }
    for r in 0..3 {
        let row = [
            (direction[r][0] * 1e3 * volume.spacing()[0]) as f32,
            (direction[r][1] * 1e3 * volume.spacing()[1]) as f32,
            (direction[r][2] * 1e3 * volume.spacing()[2]) as f32,
            origin[r],
        ];
        for (c, v) in row.iter().enumerate() {
            put(field::SROW_X + 16 * r + 4 * c, &v.to_le_bytes());
        }
    }
    put(field::MAGIC, b"n+1\0");
    out.reserve_exact(2 * labels.len());
    for l in labels {
        out.extend_from_slice(&l.to_le_bytes());
    }
    Ok(out)
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn length(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    a.map(|v| v * s)
}

fn normalized(a: [f64; 3]) -> [f64; 3] {
    let n = length(a);
    if n > 0.0 { scale(a, 1.0 / n) } else { a }
}

fn det(m: [[f64; 3]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}
