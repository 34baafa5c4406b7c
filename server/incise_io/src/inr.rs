//! INRIMAGE-4 volumes (`.inr`, `.inr.gz`).
//!
//! The header is ASCII: `#INRIMAGE-4#{`, one `KEY=VALUE` per line, newline padding, and `##}`
//! plus a newline, the whole a multiple of 256 bytes long. Raw voxels follow, `x` fastest, in the
//! byte order named by `CPU`. Lengths (`VX`, `VY`, `VZ`, `TX`, `TY`, `TZ`) are millimetres. The
//! format has no orientation field: volumes read back axis-aligned, and the writer drops the
//! direction of the volume it is given (the origin and spacing are kept).

use crate::error::{IoError, grouped};
use crate::gzip::{self, Input};
use crate::samples::{ByteOrder, SampleType, to_labels};
use incise_grid::LabelVolume;
use std::fmt::Write as _;
use std::path::Path;

/// Start of every INRIMAGE-4 header.
const MAGIC: &[u8] = b"#INRIMAGE-4#{";
/// End of the header: the last four bytes of its last 256-byte block.
const END: &[u8] = b"##}\n";
/// Headers are whole blocks of this many bytes.
const BLOCK: usize = 256;
/// Real headers take one block, rarely four; a stream of padding beyond this is not a header.
const MAX_HEADER: usize = 256 * BLOCK;
/// Millimetres per metre.
const MM: f64 = 1e3;

/// Reads a `.inr` or `.inr.gz` file (gzip is recognised by its magic bytes, not the name).
pub fn read_inr(path: &Path) -> Result<LabelVolume, IoError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| IoError::Io { file: file.clone(), source })?;
    decode_inr(&bytes, &file)
}

/// Decodes an INRIMAGE-4 image held in memory, gzip-compressed or not. `file` names the bytes in
/// errors.
pub fn decode_inr(bytes: &[u8], file: &str) -> Result<LabelVolume, IoError> {
    let mut input = Input::new(bytes, file);
    let text = read_header(&mut input)?;
    let header = Header::parse(&text, file)?;

    let [nx, ny, nz] = header.dims;
    let needed = nx
        .checked_mul(ny)
        .and_then(|n| n.checked_mul(nz))
        .and_then(|n| n.checked_mul(header.sample.size()))
        .ok_or_else(|| IoError::BadHeader {
            file: file.to_owned(),
            what: format!("extent XDIM×YDIM×ZDIM = {nx}×{ny}×{nz} overflows the address space"),
        })?;
    let raw = input.take_voxels(
        needed,
        &format!("{nx}×{ny}×{nz} {}", header.sample.name()),
        &format!("XDIM×YDIM×ZDIM ({nx}×{ny}×{nz}) and PIXSIZE"),
    )?;
    let labels = to_labels(&raw, header.sample, header.order, None, file)?;
    drop(raw);

    let volume = |source| IoError::Volume { file: file.to_owned(), source };
    LabelVolume::new(header.dims, header.spacing, labels)
        .map_err(volume)?
        .with_placement(header.origin, IDENTITY)
        .map_err(volume)
}

/// Encodes `volume` as an uncompressed INRIMAGE-4 image: `uint8` when every label fits, else
/// little-endian `uint16`. The direction is not stored (the format has no field for it).
#[must_use]
pub fn encode_inr(volume: &LabelVolume) -> Vec<u8> {
    let labels = volume.labels();
    let narrow = labels.iter().all(|&l| u8::try_from(l).is_ok());
    let [nx, ny, nz] = volume.dims();
    let [vx, vy, vz] = volume.spacing().map(|h| h * MM);
    let [tx, ty, tz] = volume.origin().map(|o| o * MM);
    let bits = if narrow { 8 } else { 16 };
    let mut text = String::from("#INRIMAGE-4#{\n");
    // `{}` prints the shortest decimal that reads back as the same f64.
    let _ = write!(
        text,
        "XDIM={nx}\nYDIM={ny}\nZDIM={nz}\nVDIM=1\nTYPE=unsigned fixed\nPIXSIZE={bits} bits\n\
         SCALE=2**0\nCPU=decm\nVX={vx}\nVY={vy}\nVZ={vz}\n"
    );
    if [tx, ty, tz].iter().any(|&t| t != 0.0) {
        let _ = write!(text, "TX={tx}\nTY={ty}\nTZ={tz}\n");
    }
    let header_len = (text.len() + END.len()).div_ceil(BLOCK) * BLOCK;
    let mut out = Vec::with_capacity(header_len + labels.len() * bits / 8);
    out.extend_from_slice(text.as_bytes());
    out.resize(header_len - END.len(), b'\n');
    out.extend_from_slice(END);
    if narrow {
        out.extend(labels.iter().map(|&l| l as u8));
    } else {
        for l in labels {
            out.extend_from_slice(&l.to_le_bytes());
        }
    }
    out
}

/// Writes `volume` as INRIMAGE-4, gzip-compressed when `path` ends in `.gz`. The direction is not
/// stored (the format has no field for it).
pub fn write_inr(path: &Path, volume: &LabelVolume) -> Result<(), IoError> {
    let file = path.display().to_string();
    let bytes = encode_inr(volume);
    let bytes = if crate::ends_with_gz(path) { gzip::compress(&bytes) } else { Ok(bytes) };
    bytes.and_then(|b| std::fs::write(path, b)).map_err(|source| IoError::Io { file, source })
}

/// Whether `head` starts with the INRIMAGE-4 magic.
pub(crate) fn sniff(head: &[u8]) -> bool {
    head.starts_with(MAGIC)
}

/// Reads whole 256-byte blocks until one ends the header, and returns the text between the magic
/// and the end marker.
fn read_header(input: &mut Input) -> Result<String, IoError> {
    let file = input.file();
    let mut header: Vec<u8> = Vec::new();
    loop {
        let block = input.take(BLOCK)?;
        if header.is_empty() && block.len() < MAGIC.len() && MAGIC.starts_with(&block) {
            return Err(IoError::Truncated {
                file: file.to_owned(),
                what: "INRIMAGE-4 header".to_owned(),
                expected: BLOCK as u64,
                found: block.len() as u64,
            });
        }
        if header.is_empty() && !block.starts_with(MAGIC) {
            let start = &block[..block.len().min(MAGIC.len())];
            return Err(IoError::BadHeader {
                file: file.to_owned(),
                what: format!(
                    "bad magic {:?}: an INRIMAGE-4 file starts with \"#INRIMAGE-4#{{\"",
                    String::from_utf8_lossy(start)
                ),
            });
        }
        let searched_from = header.len().saturating_sub(END.len() - 1);
        header.extend_from_slice(&block);
        if let Some(at) = find(&header[searched_from..], END) {
            let end = searched_from + at + END.len();
            if end != header.len() || !end.is_multiple_of(BLOCK) {
                return Err(IoError::HeaderSizeMismatch {
                    file: file.to_owned(),
                    what: format!(
                        "the header ends at byte {end} (after \"##}}\"), which is not a \
                         multiple of 256"
                    ),
                });
            }
            let body = header.get(MAGIC.len()..end - END.len()).unwrap_or_default();
            return String::from_utf8(body.to_vec()).map_err(|e| IoError::BadHeader {
                file: file.to_owned(),
                what: format!(
                    "header byte {} is not text",
                    MAGIC.len() + e.utf8_error().valid_up_to()
                ),
            });
        }
        if block.len() < BLOCK {
            return Err(IoError::Truncated {
                file: file.to_owned(),
                what: "INRIMAGE-4 header (whole 256-byte blocks ending in \"##}\")".to_owned(),
                expected: (header.len() - block.len() + BLOCK) as u64,
                found: header.len() as u64,
            });
        }
        if header.len() >= MAX_HEADER {
            return Err(IoError::BadHeader {
                file: file.to_owned(),
                what: format!(
                    "no \"##}}\" ends the header within its first {} bytes",
                    grouped(MAX_HEADER as u64)
                ),
            });
        }
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

#[derive(Debug)]
struct Header {
    dims: [usize; 3],
    sample: SampleType,
    order: ByteOrder,
    spacing: [f64; 3],
    origin: [f64; 3],
}

impl Header {
    fn parse(text: &str, file: &str) -> Result<Self, IoError> {
        let bad = |what: String| IoError::BadHeader { file: file.to_owned(), what };
        let unsupported = |what: String| IoError::UnsupportedType { file: file.to_owned(), what };

        let mut fields: Vec<(&str, &str)> = Vec::new();
        for line in text.lines().map(str::trim) {
            // Blank lines are padding; `#` lines are comments (some writers add `#GEOMETRY=…`).
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let Some((key, value)) = line.split_once('=') else {
                return Err(bad(format!("header line {line:?} is not KEY=VALUE")));
            };
            fields.push((key.trim(), value.trim()));
        }
        // A repeated key counts by its last occurrence, as the reference reader does.
        let get = |key: &str| fields.iter().rev().find(|(k, _)| *k == key).map(|&(_, v)| v);

        let extent = |key: &str| -> Result<usize, IoError> {
            let value = get(key).ok_or_else(|| bad(format!("header field {key} is missing")))?;
            match value.parse::<usize>() {
                Ok(n) if n > 0 => Ok(n),
                _ => Err(bad(format!("header field {key}={value} is not a positive integer"))),
            }
        };
        let dims = [extent("XDIM")?, extent("YDIM")?, extent("ZDIM")?];
        if let Some(v) = get("VDIM") {
            match v.parse::<usize>() {
                Ok(1) => {}
                Ok(n) if n > 1 => {
                    return Err(unsupported(format!(
                        "VDIM={n} (vector voxels); label volumes have one value per voxel"
                    )));
                }
                _ => return Err(bad(format!("header field VDIM={v} is not a positive integer"))),
            }
        }

        let kind = get("TYPE").ok_or_else(|| bad("header field TYPE is missing".to_owned()))?;
        let pixsize =
            get("PIXSIZE").ok_or_else(|| bad("header field PIXSIZE is missing".to_owned()))?;
        let bits = pixsize
            .strip_suffix("bits")
            .and_then(|n| n.trim().parse::<u32>().ok())
            .ok_or_else(|| bad(format!("header field PIXSIZE={pixsize} is not \"<n> bits\"")))?;
        let normalized_kind = kind.split_whitespace().collect::<Vec<_>>().join(" ");
        let sample = match (normalized_kind.to_ascii_lowercase().as_str(), bits) {
            ("unsigned fixed", 8) => SampleType::U8,
            ("unsigned fixed", 16) => SampleType::U16,
            ("unsigned fixed", 32) => SampleType::U32,
            ("unsigned fixed", 64) => SampleType::U64,
            ("signed fixed", 8) => SampleType::I8,
            ("signed fixed", 16) => SampleType::I16,
            ("signed fixed", 32) => SampleType::I32,
            ("signed fixed", 64) => SampleType::I64,
            ("float", 32) => SampleType::F32,
            ("float", 64) => SampleType::F64,
            _ => {
                return Err(unsupported(format!(
                    "voxel type TYPE={kind}, PIXSIZE={pixsize}; expected unsigned fixed or signed \
                     fixed of 8, 16, 32 or 64 bits, or float of 32 or 64 bits"
                )));
            }
        };

        // Files without CPU come from the little-endian PCs that wrote nearly all of them.
        let order = match get("CPU").map(str::to_ascii_lowercase).as_deref() {
            None | Some("decm" | "pc" | "alpha") => ByteOrder::Little,
            Some("sun" | "sgi") => ByteOrder::Big,
            Some(_) => {
                return Err(unsupported(format!(
                    "CPU={}; known byte orders are decm, pc, alpha (little-endian) and sun, sgi \
                     (big-endian)",
                    get("CPU").unwrap_or_default()
                )));
            }
        };

        let length = |key: &str, default: f64| -> Result<f64, IoError> {
            match get(key) {
                None => Ok(default / MM),
                Some(value) => match value.parse::<f64>() {
                    Ok(v) if v.is_finite() => Ok(v / MM),
                    _ => Err(bad(format!("header field {key}={value} is not a finite number"))),
                },
            }
        };
        let spacing = [length("VX", 1.0)?, length("VY", 1.0)?, length("VZ", 1.0)?];
        let origin = [length("TX", 0.0)?, length("TY", 0.0)?, length("TZ", 0.0)?];
        Ok(Self { dims, sample, order, spacing, origin })
    }
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
