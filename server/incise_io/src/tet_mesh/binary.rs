//! Numbers stored as bytes and base64 text: what the binary variants of the mesh formats share.
//!
//! Every reader here is given its bytes by a caller that has already checked they are there, yet
//! still answers `None` rather than indexing past the end: a decoder must not panic on any
//! input, and a wrong length is easier to report than to rule out.

/// A numeric type of binary mesh data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

/// A value read from binary data: integers keep their exact value, whatever their width.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Number {
    Int(i128),
    Float(f64),
}

impl std::fmt::Display for Number {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Int(v) => write!(f, "{v}"),
            Self::Float(v) => write!(f, "{v:?}"),
        }
    }
}

/// A Rust type that values of a mesh file are read into, from text or from a [`Number`].
pub(super) trait Value: std::str::FromStr + Copy {
    /// `n` as `Self`, or `None` when it does not fit (a fraction or a negative count).
    fn from_number(n: Number) -> Option<Self>;
}

impl Value for f64 {
    fn from_number(n: Number) -> Option<Self> {
        Some(match n {
            Number::Int(v) => v as f64,
            Number::Float(v) => v,
        })
    }
}

impl Value for i64 {
    fn from_number(n: Number) -> Option<Self> {
        match n {
            Number::Int(v) => Self::try_from(v).ok(),
            Number::Float(_) => None,
        }
    }
}

impl Value for usize {
    fn from_number(n: Number) -> Option<Self> {
        match n {
            Number::Int(v) => Self::try_from(v).ok(),
            Number::Float(_) => None,
        }
    }
}

/// `N` bytes from the front of `bytes`, when there are that many.
fn array<const N: usize>(bytes: &[u8]) -> Option<[u8; N]> {
    bytes.get(..N)?.try_into().ok()
}

macro_rules! read_as {
    ($t:ty, $bytes:expr, $big:expr) => {{
        let a = array::<{ size_of::<$t>() }>($bytes)?;
        if $big { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }
    }};
}

impl Scalar {
    /// Bytes per value.
    pub(super) fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }

    /// The type a VTK XML `type` attribute names (`Int8` … `Float64`).
    pub(super) fn of_xml(name: &str) -> Option<Self> {
        Some(match name {
            "Int8" => Self::I8,
            "UInt8" => Self::U8,
            "Int16" => Self::I16,
            "UInt16" => Self::U16,
            "Int32" => Self::I32,
            "UInt32" => Self::U32,
            "Int64" => Self::I64,
            "UInt64" => Self::U64,
            "Float32" => Self::F32,
            "Float64" => Self::F64,
            _ => return None,
        })
    }

    /// The type a legacy VTK data type names, as VTK's own reader sizes it: `long` is 64-bit,
    /// and `vtkIdType` is written as a 32-bit `int`.
    pub(super) fn of_legacy(name: &str) -> Option<Self> {
        const NAMES: [(&str, Scalar); 22] = [
            ("char", Scalar::I8),
            ("unsigned_char", Scalar::U8),
            ("short", Scalar::I16),
            ("unsigned_short", Scalar::U16),
            ("int", Scalar::I32),
            ("unsigned_int", Scalar::U32),
            ("long", Scalar::I64),
            ("unsigned_long", Scalar::U64),
            ("vtkIdType", Scalar::I32),
            ("float", Scalar::F32),
            ("double", Scalar::F64),
            ("vtktypeint8", Scalar::I8),
            ("vtktypeuint8", Scalar::U8),
            ("vtktypeint16", Scalar::I16),
            ("vtktypeuint16", Scalar::U16),
            ("vtktypeint32", Scalar::I32),
            ("vtktypeuint32", Scalar::U32),
            ("vtktypeint64", Scalar::I64),
            ("vtktypeuint64", Scalar::U64),
            ("vtktypefloat32", Scalar::F32),
            ("vtktypefloat64", Scalar::F64),
            ("signed_char", Scalar::I8),
        ];
        NAMES.iter().find(|(n, _)| name.eq_ignore_ascii_case(n)).map(|&(_, s)| s)
    }

    /// The value at the front of `bytes` (at least [`Self::size`] of them), big-endian when
    /// `big`.
    pub(super) fn read(self, bytes: &[u8], big: bool) -> Option<Number> {
        Some(match self {
            Self::I8 => Number::Int(read_as!(i8, bytes, big).into()),
            Self::U8 => Number::Int(read_as!(u8, bytes, big).into()),
            Self::I16 => Number::Int(read_as!(i16, bytes, big).into()),
            Self::U16 => Number::Int(read_as!(u16, bytes, big).into()),
            Self::I32 => Number::Int(read_as!(i32, bytes, big).into()),
            Self::U32 => Number::Int(read_as!(u32, bytes, big).into()),
            Self::I64 => Number::Int(read_as!(i64, bytes, big).into()),
            Self::U64 => Number::Int(read_as!(u64, bytes, big).into()),
            Self::F32 => Number::Float(read_as!(f32, bytes, big).into()),
            Self::F64 => Number::Float(read_as!(f64, bytes, big)),
        })
    }
}

/// An unsigned integer of `size` bytes (4 or 8) at the front of `bytes`.
pub(super) fn read_unsigned(bytes: &[u8], size: usize, big: bool) -> Option<u64> {
    match size {
        4 => Some(read_as!(u32, bytes, big).into()),
        8 => Some(read_as!(u64, bytes, big)),
        _ => None,
    }
}

const BASE64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

/// `bytes` in standard base64 with padding.
pub(super) fn base64_encode(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], chunk.get(1).copied().unwrap_or(0), chunk.get(2).copied().unwrap_or(0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(BASE64[(n >> (18 - 6 * k)) as usize & 63]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A base64 text decoded on demand, four characters at a time.
///
/// Padding may end any group, not only the last: VTK encodes an array's header and its data as
/// two base64 texts written back to back, while meshio encodes them as one; reading group by
/// group decodes both. Whitespace between characters is skipped.
pub(super) struct Base64<'a> {
    text: &'a [u8],
    pos: usize,
    /// Bytes of the last group not yet handed out.
    pending: Vec<u8>,
}

impl<'a> Base64<'a> {
    pub(super) fn new(text: &'a [u8]) -> Self {
        Self { text, pos: 0, pending: Vec::new() }
    }

    /// The most bytes the rest of the text can decode to.
    pub(super) fn available(&self) -> usize {
        (self.text.len() - self.pos.min(self.text.len())) / 4 * 3 + self.pending.len()
    }

    /// How far into the text decoding has got, in characters.
    pub(super) fn position(&self) -> usize {
        self.pos
    }

    /// The next `n` decoded bytes.
    pub(super) fn take(&mut self, n: usize) -> Result<Vec<u8>, String> {
        if n > self.available() {
            return Err(format!(
                "needs {n} bytes, the rest of the base64 text holds at most {}",
                self.available()
            ));
        }
        let mut out = Vec::with_capacity(n);
        while out.len() < n {
            if self.pending.is_empty() {
                let at = self.pos;
                match self.group()? {
                    Some(bytes) => self.pending = bytes,
                    None => {
                        return Err(format!(
                            "the base64 text ends at character {at}, after {} of {n} bytes",
                            out.len()
                        ));
                    }
                }
            }
            let k = self.pending.len().min(n - out.len());
            out.extend(self.pending.drain(..k));
        }
        Ok(out)
    }

    /// Decodes the next group of four characters into one to three bytes; `None` at the end.
    fn group(&mut self) -> Result<Option<Vec<u8>>, String> {
        let mut sextets = [0u32; 4];
        let mut count = 0;
        let mut padding = 0;
        while count < 4 {
            let Some(&c) = self.text.get(self.pos) else {
                return if count == 0 {
                    Ok(None)
                } else {
                    Err(format!("the base64 text ends inside a group, at character {}", self.pos))
                };
            };
            let at = self.pos;
            self.pos += 1;
            if c.is_ascii_whitespace() {
                continue;
            }
            let value = match c {
                b'A'..=b'Z' => c - b'A',
                b'a'..=b'z' => c - b'a' + 26,
                b'0'..=b'9' => c - b'0' + 52,
                b'+' => 62,
                b'/' => 63,
                b'=' if count >= 2 => {
                    padding += 1;
                    0
                }
                _ => {
                    return Err(format!(
                        "character {at} of the base64 text, {:?}, is not base64 here",
                        char::from(c)
                    ));
                }
            };
            if padding > 0 && c != b'=' {
                return Err(format!("character {at} of the base64 text follows padding"));
            }
            sextets[count] = u32::from(value);
            count += 1;
        }
        let n = (sextets[0] << 18) | (sextets[1] << 12) | (sextets[2] << 6) | sextets[3];
        let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
        Ok(Some(bytes[..3 - padding].to_vec()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trips_and_reads_back_to_back_texts() {
        for len in 0..10 {
            let bytes: Vec<u8> = (0..len).map(|i| (i * 37 + 200) as u8).collect();
            let text = base64_encode(&bytes);
            let mut d = Base64::new(text.as_bytes());
            assert_eq!(d.take(len).unwrap(), bytes);
            assert_eq!(d.take(0).unwrap(), Vec::<u8>::new());
            assert!(d.take(1).is_err());
        }
        assert_eq!(base64_encode(b"Man"), "TWFu");
        assert_eq!(base64_encode(b"Ma"), "TWE=");
        // Two texts back to back, the first padded, with whitespace.
        let text = format!("{}\n  {}", base64_encode(&[1, 2, 3, 4]), base64_encode(&[5, 6]));
        let mut d = Base64::new(text.as_bytes());
        assert_eq!(d.take(3).unwrap(), [1, 2, 3]);
        assert_eq!(d.take(3).unwrap(), [4, 5, 6]);
        for bad in ["TW!u", "T===", "TW=u", "TWF"] {
            assert!(Base64::new(bad.as_bytes()).take(1).is_err() || bad == "TWF", "{bad}");
        }
        assert!(Base64::new(b"TWF").take(2).is_err());
    }

    #[test]
    fn scalars_read_both_byte_orders() {
        assert_eq!(Scalar::I16.read(&[0xff, 0xfe], true), Some(Number::Int(-2)));
        assert_eq!(Scalar::U16.read(&[0xfe, 0xff], false), Some(Number::Int(65534)));
        assert_eq!(Scalar::U64.read(&[0xff; 8], false), Some(Number::Int(u64::MAX.into())));
        assert_eq!(Scalar::F32.read(&1.5f32.to_be_bytes(), true), Some(Number::Float(1.5)));
        assert_eq!(Scalar::F64.read(&[0; 7], true), None);
        assert_eq!(read_unsigned(&7u32.to_be_bytes(), 4, true), Some(7));
        assert_eq!(read_unsigned(&[0; 8], 2, true), None);
        assert_eq!(i64::from_number(Number::Int(u64::MAX.into())), None);
        assert_eq!(usize::from_number(Number::Int(-1)), None);
        assert_eq!(f64::from_number(Number::Int(3)), Some(3.0));
    }
}
