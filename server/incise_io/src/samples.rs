//! Raw voxel samples to tissue labels, shared by both formats.
//!
//! A label is an integer in `0..=65535`. Integer samples must lie in that range; float samples
//! (and scaled values) must also be integral: a label volume whose values are not is an
//! intensity image, and silently rounding it would invent tissue boundaries.

use crate::error::IoError;

/// Storage type of one voxel in a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum SampleType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    U64,
    I64,
    F32,
    F64,
}

impl SampleType {
    /// Bytes per voxel.
    pub(crate) fn size(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::U32 | Self::I32 | Self::F32 => 4,
            Self::U64 | Self::I64 | Self::F64 => 8,
        }
    }

    /// Name for messages, as the C type is usually called.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Self::U8 => "uint8",
            Self::I8 => "int8",
            Self::U16 => "uint16",
            Self::I16 => "int16",
            Self::U32 => "uint32",
            Self::I32 => "int32",
            Self::U64 => "uint64",
            Self::I64 => "int64",
            Self::F32 => "float32",
            Self::F64 => "float64",
        }
    }
}

/// Byte order of multi-byte samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ByteOrder {
    Little,
    Big,
}

/// `value * slope + inter`, applied before the label check.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Scaling {
    pub(crate) slope: f64,
    pub(crate) inter: f64,
}

/// One decoded sample before it becomes a label.
trait Sample: Copy + std::fmt::Display {
    /// The label when the raw value is one.
    fn label(self) -> Option<u16>;
    /// The value as a float, for scaling. Integers beyond 2^53 round, but those are far outside
    /// the label range whatever the rounding.
    fn to_f64(self) -> f64;
}

macro_rules! integer_sample {
    ($($t:ty),*) => {$(
        impl Sample for $t {
            fn label(self) -> Option<u16> {
                u16::try_from(self).ok()
            }
            fn to_f64(self) -> f64 {
                self as f64
            }
        }
    )*};
}
integer_sample!(u8, i8, u16, i16, u32, i32, u64, i64);

impl Sample for f32 {
    fn label(self) -> Option<u16> {
        exact_label(f64::from(self))
    }
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}

impl Sample for f64 {
    fn label(self) -> Option<u16> {
        exact_label(self)
    }
    fn to_f64(self) -> f64 {
        self
    }
}

/// `v` as a label when it is exactly an integer in range.
fn exact_label(v: f64) -> Option<u16> {
    (v.fract() == 0.0 && (0.0..=65535.0).contains(&v)).then_some(v as u16)
}

/// A scaled value as a label. Slope and intercept are stored as `float32`, so `raw * 0.1f32`
/// lands a few parts in 10^8 off the integer it encodes; one part in a million is far below the
/// distance between two labels and far above that rounding.
fn scaled_label(v: f64) -> Option<u16> {
    let r = v.round();
    ((v - r).abs() <= 1e-6 * r.abs().max(1.0) && (0.0..=65535.0).contains(&r)).then_some(r as u16)
}

/// Converts `raw` (a whole number of samples of type `ty`) to labels, naming `file` and the first
/// offending voxel on error.
pub(crate) fn to_labels(
    raw: &[u8],
    ty: SampleType,
    order: ByteOrder,
    scaling: Option<Scaling>,
    file: &str,
) -> Result<Vec<u16>, IoError> {
    use ByteOrder::{Big, Little};
    let c = Converter { scaling, file };
    match (ty, order) {
        (SampleType::U8, _) => c.run(raw, |[b]: [u8; 1]| b),
        (SampleType::I8, _) => c.run(raw, |[b]: [u8; 1]| b as i8),
        (SampleType::U16, Little) => c.run(raw, u16::from_le_bytes),
        (SampleType::U16, Big) => c.run(raw, u16::from_be_bytes),
        (SampleType::I16, Little) => c.run(raw, i16::from_le_bytes),
        (SampleType::I16, Big) => c.run(raw, i16::from_be_bytes),
        (SampleType::U32, Little) => c.run(raw, u32::from_le_bytes),
        (SampleType::U32, Big) => c.run(raw, u32::from_be_bytes),
        (SampleType::I32, Little) => c.run(raw, i32::from_le_bytes),
        (SampleType::I32, Big) => c.run(raw, i32::from_be_bytes),
        (SampleType::U64, Little) => c.run(raw, u64::from_le_bytes),
        (SampleType::U64, Big) => c.run(raw, u64::from_be_bytes),
        (SampleType::I64, Little) => c.run(raw, i64::from_le_bytes),
        (SampleType::I64, Big) => c.run(raw, i64::from_be_bytes),
        (SampleType::F32, Little) => c.run(raw, f32::from_le_bytes),
        (SampleType::F32, Big) => c.run(raw, f32::from_be_bytes),
        (SampleType::F64, Little) => c.run(raw, f64::from_le_bytes),
        (SampleType::F64, Big) => c.run(raw, f64::from_be_bytes),
    }
}

struct Converter<'a> {
    scaling: Option<Scaling>,
    file: &'a str,
}

impl Converter<'_> {
    /// One monomorphised loop per sample type and byte order: the liver fixture alone has 25
    /// million voxels.
    fn run<const N: usize, T: Sample>(
        &self,
        raw: &[u8],
        decode: impl Fn([u8; N]) -> T,
    ) -> Result<Vec<u16>, IoError> {
        let (samples, _partial) = raw.as_chunks::<N>();
        let mut labels = Vec::new();
        labels.try_reserve_exact(samples.len()).map_err(|_| IoError::Io {
            file: self.file.to_owned(),
            source: std::io::Error::new(
                std::io::ErrorKind::OutOfMemory,
                format!("cannot allocate {} labels", samples.len()),
            ),
        })?;
        for (voxel, &bytes) in samples.iter().enumerate() {
            let v = decode(bytes);
            let label = match self.scaling {
                None => v.label(),
                Some(s) => scaled_label(v.to_f64() * s.slope + s.inter),
            };
            match label {
                Some(l) => labels.push(l),
                None => return Err(self.bad_label(voxel, v)),
            }
        }
        Ok(labels)
    }

    fn bad_label(&self, voxel: usize, v: impl Sample) -> IoError {
        let value = match self.scaling {
            None => v.to_string(),
            Some(s) => format!(
                "{v} × scl_slope {} + scl_inter {} = {}",
                s.slope,
                s.inter,
                v.to_f64() * s.slope + s.inter
            ),
        };
        IoError::BadLabel { file: self.file.to_owned(), voxel, value }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bad_voxel(r: Result<Vec<u16>, IoError>) -> (usize, String) {
        match r {
            Err(IoError::BadLabel { voxel, value, .. }) => (voxel, value),
            other => panic!("expected BadLabel, got {other:?}"),
        }
    }

    #[test]
    fn integer_types_in_both_orders() {
        let le: Vec<u8> = [1u16, 300, 65535].iter().flat_map(|v| v.to_le_bytes()).collect();
        let be: Vec<u8> = [1u16, 300, 65535].iter().flat_map(|v| v.to_be_bytes()).collect();
        let l = to_labels(&le, SampleType::U16, ByteOrder::Little, None, "f").unwrap();
        let b = to_labels(&be, SampleType::U16, ByteOrder::Big, None, "f").unwrap();
        assert_eq!(l, [1, 300, 65535]);
        assert_eq!(b, l);
        let wide: Vec<u8> = [7i64, 65535].iter().flat_map(|v| v.to_be_bytes()).collect();
        assert_eq!(
            to_labels(&wide, SampleType::I64, ByteOrder::Big, None, "f").unwrap(),
            [7, 65535]
        );
    }

    #[test]
    fn out_of_range_and_negative_values_name_the_voxel() {
        let raw: Vec<u8> = [3i32, 65536].iter().flat_map(|v| v.to_le_bytes()).collect();
        let r = to_labels(&raw, SampleType::I32, ByteOrder::Little, None, "f");
        assert_eq!(bad_voxel(r), (1, "65536".to_owned()));
        let r = to_labels(&[5, 0xff], SampleType::I8, ByteOrder::Little, None, "f");
        assert_eq!(bad_voxel(r), (1, "-1".to_owned()));
    }

    #[test]
    fn floats_must_be_integral() {
        let ok: Vec<u8> = [0.0f32, -0.0, 12.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert_eq!(
            to_labels(&ok, SampleType::F32, ByteOrder::Little, None, "f").unwrap(),
            [0, 0, 12]
        );
        for (bad, text) in [(2.5f64, "2.5"), (f64::NAN, "NaN"), (-1.0, "-1"), (70000.0, "70000")] {
            let raw: Vec<u8> = [1.0f64, bad].iter().flat_map(|v| v.to_be_bytes()).collect();
            let r = to_labels(&raw, SampleType::F64, ByteOrder::Big, None, "f");
            assert_eq!(bad_voxel(r), (1, text.to_owned()));
        }
    }

    #[test]
    fn scaling_tolerates_float32_rounding_only() {
        let slope = f64::from(0.1f32);
        let s = Some(Scaling { slope, inter: 0.0 });
        let raw: Vec<u8> = [30u16, 10].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert_eq!(to_labels(&raw, SampleType::U16, ByteOrder::Little, s, "f").unwrap(), [3, 1]);
        let raw: Vec<u8> = [30u16, 15].iter().flat_map(|v| v.to_le_bytes()).collect();
        let (voxel, value) = bad_voxel(to_labels(&raw, SampleType::U16, ByteOrder::Little, s, "f"));
        assert_eq!(voxel, 1);
        assert!(value.starts_with("15 × scl_slope"), "{value}");
    }
}
