//! Sequential reading of a file's bytes, gzip-compressed or not, with bounded memory.
//!
//! Decoders ask for the header first and then for exactly as many voxel bytes as the header
//! announces. A plain buffer hands out sub-slices without copying; a gzip stream is inflated only
//! as far as asked, into a buffer that grows with the bytes actually produced and never beyond the
//! request. A header claiming 2^60 voxels therefore costs nothing more than the data that is
//! really there, and a gzip bomb cannot make the decoder allocate more than its header announces.

use crate::error::IoError;
use flate2::read::MultiGzDecoder;
use std::borrow::Cow;
use std::io::{self, Read};

/// The first two bytes of every gzip member (RFC 1952).
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// First allocation for inflated data; later ones double, capped at the request.
const FIRST_CHUNK: usize = 64 * 1024;

/// Whether `bytes` start like a gzip stream.
pub(crate) fn is_gzip(bytes: &[u8]) -> bool {
    bytes.starts_with(&GZIP_MAGIC)
}

/// The decoded bytes of a file, read front to back.
pub(crate) struct Input<'a> {
    file: &'a str,
    source: Source<'a>,
}

enum Source<'a> {
    /// The bytes not yet handed out.
    Plain(&'a [u8]),
    /// The inflater, and how far its stream has got.
    Gzip { decoder: Box<MultiGzDecoder<&'a [u8]>>, state: State },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Open,
    /// The stream ended with its trailer, CRC checked.
    Ended,
    /// The compressed bytes ran out before the stream's end.
    CutShort,
}

impl<'a> Input<'a> {
    /// Reads `bytes`, inflating them when they start with the gzip magic. `file` names them in
    /// errors.
    pub(crate) fn new(bytes: &'a [u8], file: &'a str) -> Self {
        let source = if is_gzip(bytes) {
            Source::Gzip { decoder: Box::new(MultiGzDecoder::new(bytes)), state: State::Open }
        } else {
            Source::Plain(bytes)
        };
        Self { file, source }
    }

    /// The file name used in errors.
    pub(crate) fn file(&self) -> &'a str {
        self.file
    }

    /// The next `n` bytes, or all that remain when fewer do: callers compare the length with what
    /// they asked for to report truncation with both counts.
    pub(crate) fn take(&mut self, n: usize) -> Result<Cow<'a, [u8]>, IoError> {
        match &mut self.source {
            Source::Plain(rest) => {
                let (head, tail) = rest.split_at(n.min(rest.len()));
                *rest = tail;
                Ok(Cow::Borrowed(head))
            }
            Source::Gzip { .. } => {
                let mut buf = Vec::new();
                let mut filled = 0;
                while filled < n {
                    if filled == buf.len() {
                        // Grow geometrically with what the stream really yields, never past `n`.
                        let grow = buf.len().max(FIRST_CHUNK).min(n - buf.len());
                        buf.try_reserve_exact(grow).map_err(|_| self.out_of_memory(n))?;
                        buf.resize(buf.len() + grow, 0);
                    }
                    let got = self.read_some(&mut buf[filled..])?;
                    if got == 0 {
                        break;
                    }
                    filled += got;
                }
                buf.truncate(filled);
                Ok(Cow::Owned(buf))
            }
        }
    }

    /// Discards up to `n` bytes and returns how many there were.
    pub(crate) fn skip(&mut self, n: u64) -> Result<u64, IoError> {
        match &mut self.source {
            Source::Plain(rest) => {
                let k = usize::try_from(n).unwrap_or(usize::MAX).min(rest.len());
                *rest = &rest[k..];
                Ok(k as u64)
            }
            Source::Gzip { .. } => {
                let mut scratch = [0u8; 8192];
                let mut skipped = 0u64;
                while skipped < n {
                    let want =
                        usize::try_from(n - skipped).unwrap_or(usize::MAX).min(scratch.len());
                    let got = self.read_some(&mut scratch[..want])?;
                    if got == 0 {
                        break;
                    }
                    skipped += got as u64;
                }
                Ok(skipped)
            }
        }
    }

    /// Counts (and discards) the bytes left. Inflating to the end also checks the gzip CRC, so a
    /// corrupt or cut stream is reported even when every voxel before the damage came through.
    /// Takes exactly the `needed` voxel bytes that end the file: fewer is a truncation, more is a
    /// header/size mismatch. `what` describes the voxels (`"438×353×165 uint8"`), `announced_by`
    /// names the header fields that fix their size.
    pub(crate) fn take_voxels(
        &mut self,
        needed: usize,
        what: &str,
        announced_by: &str,
    ) -> Result<Cow<'a, [u8]>, IoError> {
        let file = self.file();
        let raw = self.take(needed)?;
        if raw.len() < needed {
            return Err(IoError::Truncated {
                file: file.to_owned(),
                what: format!("voxels ({what})"),
                expected: needed as u64,
                found: raw.len() as u64,
            });
        }
        let extra = self.rest_len()?;
        if extra > 0 {
            return Err(IoError::HeaderSizeMismatch {
                file: file.to_owned(),
                what: format!(
                    "{} bytes follow the {} bytes of voxels that {announced_by} announce",
                    crate::error::grouped(extra),
                    crate::error::grouped(needed as u64)
                ),
            });
        }
        Ok(raw)
    }

    pub(crate) fn rest_len(&mut self) -> Result<u64, IoError> {
        let rest = self.skip(u64::MAX)?;
        if let Source::Gzip { state: State::CutShort, .. } = self.source {
            return Err(IoError::Io {
                file: self.file.to_owned(),
                source: io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    "gzip stream is cut short: it ends before its CRC-32 trailer",
                ),
            });
        }
        Ok(rest)
    }

    /// One read from the inflater. A stream that is cut short reads as ending there, so that the
    /// caller reports the truncation with byte counts rather than a bare "unexpected end of file".
    fn read_some(&mut self, buf: &mut [u8]) -> Result<usize, IoError> {
        let file = self.file;
        let Source::Gzip { decoder, state } = &mut self.source else {
            return Ok(0);
        };
        if *state != State::Open {
            return Ok(0);
        }
        loop {
            match decoder.read(buf) {
                Ok(0) => {
                    *state = State::Ended;
                    return Ok(0);
                }
                Ok(got) => return Ok(got),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => {
                    *state = State::CutShort;
                    return Ok(0);
                }
                Err(e) => {
                    return Err(IoError::Io {
                        file: file.to_owned(),
                        source: io::Error::new(e.kind(), format!("corrupt gzip stream: {e}")),
                    });
                }
            }
        }
    }

    fn out_of_memory(&self, n: usize) -> IoError {
        IoError::Io {
            file: self.file.to_owned(),
            source: io::Error::new(
                io::ErrorKind::OutOfMemory,
                format!("cannot allocate {n} bytes for the decompressed data"),
            ),
        }
    }
}

/// `bytes` compressed as one gzip member.
pub(crate) fn compress(bytes: &[u8]) -> io::Result<Vec<u8>> {
    use std::io::Write;
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    encoder.write_all(bytes)?;
    encoder.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn payload() -> Vec<u8> {
        (0..200_000u32).map(|i| (i * 7 % 251) as u8).collect()
    }

    #[test]
    fn plain_and_gzip_read_the_same_bytes() {
        let data = payload();
        let packed = compress(&data).unwrap();
        assert!(is_gzip(&packed) && !is_gzip(&data));
        for bytes in [&data, &packed] {
            let mut input = Input::new(bytes, "t");
            assert_eq!(input.take(10).unwrap().as_ref(), &data[..10]);
            assert_eq!(input.skip(90).unwrap(), 90);
            assert_eq!(input.take(150_000).unwrap().as_ref(), &data[100..150_100]);
            assert_eq!(input.rest_len().unwrap(), 49_900);
            assert!(input.take(5).unwrap().is_empty());
        }
    }

    #[test]
    fn huge_request_returns_what_is_there() {
        let data = payload();
        let packed = compress(&data).unwrap();
        for bytes in [&data, &packed] {
            let mut input = Input::new(bytes, "t");
            assert_eq!(input.take(usize::MAX).unwrap().len(), data.len());
        }
    }

    #[test]
    fn cut_gzip_stream_reads_as_short() {
        let data = payload();
        let packed = compress(&data).unwrap();
        let cut = &packed[..packed.len() / 2];
        let mut input = Input::new(cut, "t");
        let got = input.take(data.len()).unwrap();
        assert!(got.len() < data.len());
        assert_eq!(got.as_ref(), &data[..got.len()]);

        // Cut inside the trailer: every byte comes through, but the stream is still incomplete.
        let cut = &packed[..packed.len() - 3];
        let mut input = Input::new(cut, "t.gz");
        assert_eq!(input.take(data.len()).unwrap().len(), data.len());
        let err = input.rest_len().unwrap_err();
        assert!(err.to_string().starts_with("t.gz: gzip stream is cut short"), "{err}");
    }

    #[test]
    fn corrupt_gzip_stream_is_an_io_error_naming_the_file() {
        let mut packed = compress(&payload()).unwrap();
        let n = packed.len();
        packed[n - 6] ^= 0xff; // inside the CRC-32 trailer
        let mut input = Input::new(&packed, "vol.nii.gz");
        let err = input.rest_len().unwrap_err();
        assert!(matches!(err, IoError::Io { .. }));
        assert!(err.to_string().starts_with("vol.nii.gz: corrupt gzip stream"), "{err}");
    }
}
