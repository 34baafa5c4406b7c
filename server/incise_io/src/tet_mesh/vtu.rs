//! VTK XML unstructured grids, with ASCII, inline binary and appended data arrays.
//!
//! Raw appended data may hold any bytes, `<` and line ends included, so it is cut out of the
//! file before the XML is scanned: from the `_` after `<AppendedData>` to the last
//! `</AppendedData>`. Only the arrays the mesh needs (points, cells, region labels) are decoded;
//! the others are never looked at, so their types and encodings do not matter. Errors about an
//! array's binary data name the array and the line of its tag.

use super::binary::{Base64, Scalar, Value, base64_encode, read_unsigned};
use super::vtk::region_type_fits_i32;
use super::{
    Assembly, At, BOM, CellBlock, Labels, MeshFile, MeshOptions, Origin, RegionArray, Tokens,
    check_wanted, error_at, find_bytes, is_integer_type, parse, region_rank, shown, syntax,
    unusable_region_array,
};
use crate::error::{IoError, grouped};
use flate2::read::ZlibDecoder;
use incise_mesh::TetMesh;
use std::borrow::Cow;
use std::fmt::Write as _;
use std::io::{Read as _, Write as _};

/// One piece of XML markup.
#[derive(Debug)]
enum Markup<'a> {
    /// `<name attrs>` or, when `empty`, `<name attrs/>`.
    Open { name: &'a str, attrs: &'a str, empty: bool },
    /// `</name>`.
    Close(&'a str),
    /// Text between tags (or a CDATA section's content).
    Text(&'a str),
}

/// A tolerant XML scanner: tags, their attributes and the text between them; declarations,
/// comments, processing instructions and `DOCTYPE` are skipped, entities are not expanded.
struct Xml<'a> {
    file: &'a str,
    text: &'a str,
    pos: usize,
    line: usize,
}

impl<'a> Xml<'a> {
    /// Moves to byte `to`, counting lines.
    fn advance(&mut self, to: usize) {
        let to = to.min(self.text.len());
        // Every position handed here is a character boundary: the end of the text, or next to
        // an ASCII `<`, `>` or the start of a found needle.
        self.line += self.text.get(self.pos..to).map_or(0, |s| s.matches('\n').count());
        self.pos = to;
    }

    /// Skips to just before `needle` (raw appended data, which may hold any bytes).
    fn skip_to(&mut self, needle: &str) -> Result<(), IoError> {
        let (file, text, line) = (self.file, self.text, self.line);
        let at = text[self.pos..]
            .find(needle)
            .ok_or_else(|| syntax(file, line, format!("the file ends before {needle}")))?;
        self.advance(self.pos + at);
        Ok(())
    }

    /// The next piece of markup and the line it starts on.
    fn next(&mut self) -> Result<Option<(Markup<'a>, usize)>, IoError> {
        let (file, text) = (self.file, self.text);
        loop {
            let rest = &text[self.pos..];
            let line = self.line;
            if rest.is_empty() {
                return Ok(None);
            }
            if !rest.starts_with('<') {
                let end = rest.find('<').unwrap_or(rest.len());
                self.advance(self.pos + end);
                return Ok(Some((Markup::Text(&rest[..end]), line)));
            }
            let unclosed = |what: &str| syntax(file, line, format!("{what} is not closed"));
            if let Some(inner) = rest.strip_prefix("<![CDATA[") {
                let end = inner.find("]]>").ok_or_else(|| unclosed("a CDATA section"))?;
                self.advance(self.pos + 9 + end + 3);
                return Ok(Some((Markup::Text(&inner[..end]), line)));
            }
            let skipped = [("<?", "?>"), ("<!--", "-->"), ("<!", ">")]
                .into_iter()
                .find(|(open, _)| rest.starts_with(open));
            if let Some((open, close)) = skipped {
                let end = rest[open.len()..].find(close).ok_or_else(|| unclosed(open))?;
                self.advance(self.pos + open.len() + end + close.len());
                continue;
            }
            // A tag: up to the first `>` outside quotes.
            let bytes = rest.as_bytes();
            let mut quote = None;
            let mut end = None;
            for (i, &b) in bytes.iter().enumerate().skip(1) {
                match (quote, b) {
                    (None, b'"' | b'\'') => quote = Some(b),
                    (Some(q), _) if b == q => quote = None,
                    (None, b'>') => {
                        end = Some(i);
                        break;
                    }
                    _ => {}
                }
            }
            let end = end.ok_or_else(|| unclosed("a tag"))?;
            let inner = &rest[1..end];
            self.advance(self.pos + end + 1);
            if let Some(name) = inner.strip_prefix('/') {
                return Ok(Some((Markup::Close(name.trim()), line)));
            }
            let (inner, empty) = match inner.strip_suffix('/') {
                Some(inner) => (inner, true),
                None => (inner, false),
            };
            let name_end = inner.find(|c: char| c.is_ascii_whitespace()).unwrap_or(inner.len());
            let name = &inner[..name_end];
            if name.is_empty() {
                return Err(syntax(file, line, "a tag without a name"));
            }
            return Ok(Some((Markup::Open { name, attrs: &inner[name_end..], empty }, line)));
        }
    }
}

/// The value of attribute `key` in a tag's attribute text.
fn attr<'a>(attrs: &'a str, key: &str) -> Option<&'a str> {
    let mut rest = attrs;
    loop {
        let (k, after) = rest.split_once('=')?;
        let after = after.trim_start();
        let quote = after.chars().next().filter(|&q| q == '"' || q == '\'')?;
        let value_and_rest = &after[1..];
        let close = value_and_rest.find(quote)?;
        if k.trim() == key {
            return Some(&value_and_rest[..close]);
        }
        rest = &value_and_rest[close + 1..];
    }
}

/// What a `DataArray` of a piece holds, as far as this reader cares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Points,
    Connectivity,
    Offsets,
    Types,
    /// An integer cell array, a region label candidate of this rank ([`region_rank`]).
    Labels {
        rank: u8,
    },
}

/// Where a `DataArray`'s values are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    /// Whitespace-separated numbers between its tags.
    Ascii,
    /// Base64 between its tags.
    Binary,
    /// In `<AppendedData>`, from this offset.
    Appended(usize),
}

/// A `DataArray` being read: its role, where it starts, and its text.
struct DataArray<'a> {
    role: Role,
    name: &'a str,
    /// The `type` attribute.
    kind: &'a str,
    format: Format,
    /// Open elements outside it.
    depth: usize,
    line: usize,
    text: Vec<(&'a str, usize)>,
}

/// A `Piece` being read.
#[derive(Default)]
struct Piece<'a> {
    line: usize,
    points: usize,
    cells: usize,
    /// The array `CellData Scalars="…"` names.
    scalars: Option<&'a str>,
    coords: Option<(Vec<[f64; 3]>, Vec<At>)>,
    connectivity: Option<Vec<i64>>,
    offsets: Option<Labels>,
    types: Option<Vec<i64>>,
    labels: Option<RegionArray>,
}

/// Decodes a VTK XML `UnstructuredGrid` (`.vtu`), all pieces. Data arrays may be ASCII,
/// `binary` (base64) or `appended` (raw or base64), uncompressed or zlib-compressed
/// (`vtkZLibDataCompressor`), with `UInt32` or `UInt64` headers in either byte order. `name`
/// names the bytes in errors.
pub fn decode_vtu(bytes: &[u8], name: &str) -> Result<TetMesh, IoError> {
    decode_vtu_with(bytes, name, &MeshOptions::default()).map(|file| file.mesh)
}

/// Decodes a `.vtu` as [`decode_vtu`] does, with `options`.
pub fn decode_vtu_with(
    bytes: &[u8],
    name: &str,
    options: &MeshOptions,
) -> Result<MeshFile, IoError> {
    let bytes = bytes.strip_prefix(BOM).unwrap_or(bytes);
    let (text, appended) = split_appended(bytes, name)?;
    decode_xml(&text, appended, name, options.region.as_deref())
}

/// Decodes the XML of a `.vtu` file, its appended data cut out; `wanted` names the region
/// array.
fn decode_xml(
    text: &str,
    appended: Option<Appended>,
    name: &str,
    wanted: Option<&str>,
) -> Result<MeshFile, IoError> {
    let mut xml = Xml { file: name, text, pos: 0, line: 1 };
    let mut encoding = Encoding { appended, ..Encoding::default() };
    let mut stack: Vec<&str> = Vec::new();
    let mut mesh = Assembly::new("point", "cell");
    let mut cells_so_far = 0usize;
    let mut pieces = 0usize;
    let mut piece: Option<Piece> = None;
    let mut array: Option<DataArray> = None;
    let mut cell_arrays: Vec<String> = Vec::new();
    let mut found_wanted = false;
    while let Some((markup, line)) = xml.next()? {
        match markup {
            Markup::Open { name: tag, attrs, empty } => {
                let parent = stack.last().copied();
                match (parent, tag) {
                    (None, "VTKFile") => {
                        match attr(attrs, "type") {
                            Some("UnstructuredGrid") | None => {}
                            Some(other) => {
                                return Err(IoError::UnsupportedType {
                                    file: name.to_owned(),
                                    what: format!(
                                        "VTKFile type=\"{other}\"; this reader takes \
                                         UnstructuredGrid"
                                    ),
                                });
                            }
                        }
                        encoding.read_attributes(name, line, attrs)?;
                    }
                    (None, _) => {
                        return Err(syntax(
                            name,
                            line,
                            format!("expected <VTKFile> (a VTK XML file), found <{tag}>"),
                        ));
                    }
                    (Some("UnstructuredGrid"), "Piece") => {
                        let count = |key: &str| -> Result<usize, IoError> {
                            let value = attr(attrs, key).ok_or_else(|| {
                                syntax(name, line, format!("<Piece> has no {key}"))
                            })?;
                            value.trim().parse().map_err(|_| {
                                syntax(name, line, format!("{key}={} is not a count", shown(value)))
                            })
                        };
                        piece = Some(Piece {
                            line,
                            points: count("NumberOfPoints")?,
                            cells: count("NumberOfCells")?,
                            ..Piece::default()
                        });
                    }
                    (Some("Piece"), "CellData") => {
                        if let Some(p) = &mut piece {
                            p.scalars = attr(attrs, "Scalars");
                        }
                    }
                    (Some(parent), "DataArray") if array.is_none() => {
                        if parent == "CellData" {
                            let array_name = attr(attrs, "Name").unwrap_or("");
                            if !cell_arrays.iter().any(|a| a == array_name) {
                                cell_arrays.push(array_name.to_owned());
                            }
                            found_wanted |= wanted == Some(array_name);
                        }
                        let role = match &piece {
                            Some(p) => role_of(name, parent, attrs, p, wanted)?,
                            None => None,
                        };
                        if let Some(role) = role {
                            let a = DataArray {
                                role,
                                name: attr(attrs, "Name").unwrap_or(""),
                                kind: attr(attrs, "type").unwrap_or(""),
                                format: data_format(name, line, attrs)?,
                                depth: stack.len(),
                                line,
                                text: Vec::new(),
                            };
                            if empty {
                                finish_array(name, &a, &encoding, piece.as_mut())?;
                            } else {
                                array = Some(a);
                            }
                        }
                    }
                    (_, "AppendedData") if !empty => xml.skip_to("</AppendedData")?,
                    _ => {}
                }
                if !empty {
                    stack.push(tag);
                }
            }
            Markup::Close(tag) => {
                let Some(open) = stack.pop() else {
                    return Err(syntax(name, line, format!("</{tag}> closes nothing")));
                };
                if open != tag {
                    return Err(syntax(name, line, format!("</{tag}> closes <{open}>")));
                }
                if tag == "DataArray"
                    && let Some(a) = array.take_if(|a| a.depth == stack.len())
                {
                    finish_array(name, &a, &encoding, piece.as_mut())?;
                }
                if tag == "Piece"
                    && let Some(p) = piece.take()
                {
                    cells_so_far += finish_piece(name, p, cells_so_far, &mut mesh)?;
                    pieces += 1;
                }
            }
            Markup::Text(content) => {
                if let Some(a) = &mut array
                    && stack.len() == a.depth + 1
                {
                    a.text.push((content, line));
                }
            }
        }
    }
    if let Some(open) = stack.last() {
        return Err(syntax(name, xml.line, format!("the file ends inside <{open}>")));
    }
    if pieces == 0 {
        return Err(syntax(name, xml.line, "the file has no <UnstructuredGrid><Piece>"));
    }
    check_wanted(name, wanted, found_wanted, &cell_arrays)?;
    mesh.finish(name)
}

/// What a `DataArray` under `parent` with `attrs` holds, if this reader needs it; `wanted`
/// names the region array. An array `wanted` names that cannot hold regions is an error.
fn role_of(
    file: &str,
    parent: &str,
    attrs: &str,
    piece: &Piece,
    wanted: Option<&str>,
) -> Result<Option<Role>, IoError> {
    Ok(match (parent, attr(attrs, "Name")) {
        ("Points", _) if piece.coords.is_none() => Some(Role::Points),
        ("Cells", Some("connectivity")) => Some(Role::Connectivity),
        ("Cells", Some("offsets")) => Some(Role::Offsets),
        ("Cells", Some("types")) => Some(Role::Types),
        ("CellData", name) => {
            let name = name.unwrap_or("");
            let kind = attr(attrs, "type").unwrap_or("");
            let components = attr(attrs, "NumberOfComponents").unwrap_or("1").trim();
            let usable = is_integer_type(kind) && components == "1";
            if !usable && wanted == Some(name) {
                let components = components.parse().unwrap_or(0);
                return Err(unusable_region_array(file, name, kind, components));
            }
            let hint = u8::from(Some(name) == piece.scalars);
            region_rank(name, hint, wanted)
                .filter(|&rank| usable && RegionArray::wanted(piece.labels.as_ref(), rank))
                .map(|rank| Role::Labels { rank })
        }
        _ => None,
    })
}

/// The `DataArray`'s `format`.
fn data_format(file: &str, line: usize, attrs: &str) -> Result<Format, IoError> {
    match attr(attrs, "format") {
        None | Some("ascii") => Ok(Format::Ascii),
        Some("binary") => Ok(Format::Binary),
        Some("appended") => {
            let offset = attr(attrs, "offset")
                .ok_or_else(|| syntax(file, line, "DataArray format=\"appended\" has no offset"))?;
            offset.trim().parse().map(Format::Appended).map_err(|_| {
                syntax(file, line, format!("DataArray offset={} is not an offset", shown(offset)))
            })
        }
        Some(other) => Err(syntax(
            file,
            line,
            format!("DataArray format={} is not ascii, binary or appended", shown(other)),
        )),
    }
}

/// The data of `<AppendedData>`, from just after its `_`.
#[derive(Clone, Copy, Debug)]
enum Appended<'a> {
    Raw(&'a [u8]),
    Base64(&'a [u8]),
}

/// How the file's binary arrays are stored: the `VTKFile` attributes and the appended data.
#[derive(Default)]
struct Encoding<'a> {
    big_endian: bool,
    /// `header_type="UInt64"`.
    header64: bool,
    /// The `compressor` attribute, when there is one.
    compressor: Option<String>,
    appended: Option<Appended<'a>>,
}

impl Encoding<'_> {
    /// Reads `byte_order`, `header_type` and `compressor` from the `VTKFile` tag.
    fn read_attributes(&mut self, file: &str, line: usize, attrs: &str) -> Result<(), IoError> {
        self.big_endian = match attr(attrs, "byte_order") {
            None | Some("LittleEndian") => false,
            Some("BigEndian") => true,
            Some(other) => {
                return Err(syntax(
                    file,
                    line,
                    format!("byte_order={} is not LittleEndian or BigEndian", shown(other)),
                ));
            }
        };
        self.header64 = match attr(attrs, "header_type") {
            None | Some("UInt32") => false,
            Some("UInt64") => true,
            Some(other) => {
                return Err(syntax(
                    file,
                    line,
                    format!("header_type={} is not UInt32 or UInt64", shown(other)),
                ));
            }
        };
        self.compressor = attr(attrs, "compressor").filter(|c| !c.is_empty()).map(str::to_owned);
        Ok(())
    }

    /// The bytes a binary or appended array holds, headers removed and blocks inflated; errors
    /// say what is wrong, for the caller to name the array.
    fn array_bytes(&self, format: Format, inline: &str) -> Result<Vec<u8>, String> {
        let zlib = match self.compressor.as_deref() {
            None => false,
            Some("vtkZLibDataCompressor") => true,
            Some(other) => {
                return Err(format!(
                    "compressor {} is not supported (only vtkZLibDataCompressor is)",
                    shown(other)
                ));
            }
        };
        let mut source = match (format, self.appended) {
            (Format::Ascii, _) => return Err("not binary".to_owned()),
            (Format::Binary, _) => Source::Base64(Base64::new(inline.as_bytes())),
            (Format::Appended(_), None) => {
                return Err("format=\"appended\" but the file has no <AppendedData>".to_owned());
            }
            (Format::Appended(offset), Some(appended)) => {
                let (data, kind) = match appended {
                    Appended::Raw(data) => (data, "bytes"),
                    Appended::Base64(data) => (data, "characters of base64"),
                };
                let data = data.get(offset..).ok_or_else(|| {
                    format!(
                        "offset {offset} is beyond the {} {kind} of the appended data",
                        grouped(data.len() as u64)
                    )
                })?;
                match appended {
                    Appended::Raw(_) => Source::Raw(data),
                    Appended::Base64(_) => Source::Base64(Base64::new(data)),
                }
            }
        };
        let size = if self.header64 { 8 } else { 4 };
        let big = self.big_endian;
        let header = |source: &mut Source, what: &str| -> Result<u64, String> {
            let bytes = source.take(size).map_err(|e| format!("the header ({what}): {e}"))?;
            Ok(read_unsigned(&bytes, size, big).unwrap_or_default())
        };
        if !zlib {
            let n = header(&mut source, "byte count")?;
            let n =
                usize::try_from(n).ok().filter(|&n| n <= source.available()).ok_or_else(|| {
                    format!(
                        "the header announces {} bytes, at most {} follow",
                        grouped(n),
                        grouped(source.available() as u64)
                    )
                })?;
            return Ok(source.take(n)?.into_owned());
        }
        let blocks = header(&mut source, "block count")?;
        let block_size = header(&mut source, "block size")?;
        let last = header(&mut source, "last block size")?;
        if blocks.checked_mul(size as u64).is_none_or(|n| n > source.available() as u64) {
            return Err(format!(
                "the zlib header announces {} blocks, whose sizes alone need more than the {} \
                 bytes that follow",
                grouped(blocks),
                grouped(source.available() as u64)
            ));
        }
        if last > block_size {
            return Err(format!("the last block size {last} exceeds the block size {block_size}"));
        }
        let mut sizes = Vec::new();
        for _ in 0..blocks {
            sizes.push(header(&mut source, "compressed block size")?);
        }
        let compressed = sizes.iter().try_fold(0u64, |sum, &s| sum.checked_add(s));
        if compressed.is_none_or(|n| n > source.available() as u64) {
            return Err(format!(
                "the zlib blocks announce {} compressed bytes, at most {} follow",
                grouped(compressed.unwrap_or(u64::MAX)),
                grouped(source.available() as u64)
            ));
        }
        let mut out = Vec::new();
        for (k, &n) in sizes.iter().enumerate() {
            // VTK writes 0 for a last block that is not partial; meshio writes its size.
            let expected = if k + 1 == sizes.len() && last != 0 { last } else { block_size };
            let block = source.take(n as usize)?;
            let before = out.len();
            // Inflate one byte past the size announced, to tell a block that is too long; the
            // buffer grows only with what the stream really yields.
            ZlibDecoder::new(&block[..])
                .take(expected.saturating_add(1))
                .read_to_end(&mut out)
                .map_err(|e| format!("zlib block {} of {blocks} does not inflate: {e}", k + 1))?;
            let got = out.len() - before;
            if got as u64 != expected {
                return Err(format!(
                    "zlib block {} of {blocks} inflates to {} bytes, the header says {}",
                    k + 1,
                    grouped(got as u64),
                    grouped(expected)
                ));
            }
        }
        Ok(out)
    }
}

/// The encoded bytes of one binary array.
enum Source<'a> {
    /// Raw appended data from the array's offset.
    Raw(&'a [u8]),
    Base64(Base64<'a>),
}

impl<'a> Source<'a> {
    /// The most bytes that can still be taken.
    fn available(&self) -> usize {
        match self {
            Self::Raw(rest) => rest.len(),
            Self::Base64(b) => b.available(),
        }
    }

    fn take(&mut self, n: usize) -> Result<Cow<'a, [u8]>, String> {
        match self {
            Self::Raw(rest) => {
                if n > rest.len() {
                    return Err(format!(
                        "needs {} bytes, {} are left",
                        grouped(n as u64),
                        grouped(rest.len() as u64)
                    ));
                }
                let (head, tail) = rest.split_at(n);
                *rest = tail;
                Ok(Cow::Borrowed(head))
            }
            Self::Base64(b) => {
                let at = b.position();
                b.take(n).map(Cow::Owned).map_err(|e| format!("{e} (from character {at})"))
            }
        }
    }
}

/// Splits a `.vtu` file into its XML, as text, and its appended data, which may be raw bytes:
/// everything from the `_` that starts the data to the last `</AppendedData>` is cut out.
fn split_appended<'a>(
    bytes: &'a [u8],
    file: &str,
) -> Result<(Cow<'a, str>, Option<Appended<'a>>), IoError> {
    let Some(tag) = find_bytes(bytes, b"<AppendedData", 0) else {
        return Ok((String::from_utf8_lossy(bytes), None));
    };
    let line = 1 + bytes[..tag].split(|&b| b == b'\n').count() - 1;
    let close = find_bytes(bytes, b">", tag)
        .ok_or_else(|| syntax(file, line, "the <AppendedData> tag is not closed"))?;
    if bytes.get(close.wrapping_sub(1)) == Some(&b'/') {
        return Ok((String::from_utf8_lossy(bytes), None));
    }
    let attrs = String::from_utf8_lossy(&bytes[tag + "<AppendedData".len()..close]);
    let raw = match attr(&attrs, "encoding") {
        None | Some("raw") => true,
        Some("base64") => false,
        Some(other) => {
            return Err(syntax(
                file,
                line,
                format!("AppendedData encoding={} is not raw or base64", shown(other)),
            ));
        }
    };
    let rest = &bytes[close + 1..];
    let underscore = rest
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .filter(|&i| rest[i] == b'_')
        .ok_or_else(|| syntax(file, line, "the appended data does not start with \"_\""))?;
    let start = close + 1 + underscore + 1;
    let end = bytes
        .windows(b"</AppendedData".len())
        .rposition(|w| w == b"</AppendedData")
        .filter(|&end| end >= start)
        .ok_or_else(|| {
            syntax(file, line, "the file ends inside <AppendedData> (no </AppendedData>)")
        })?;
    let data = &bytes[start..end];
    let mut text = String::from_utf8_lossy(&bytes[..start]).into_owned();
    text.push_str(&String::from_utf8_lossy(&bytes[end..]));
    let appended = if raw { Appended::Raw(data) } else { Appended::Base64(data) };
    Ok((Cow::Owned(text), Some(appended)))
}

/// How a `DataArray` is named in messages.
fn array_label(array: &DataArray) -> String {
    match array.role {
        Role::Points if array.name.is_empty() => "the <Points> DataArray".to_owned(),
        _ => format!("DataArray {:?}", array.name),
    }
}

/// A binary array's values as `T`, each located on the line of the array's tag.
fn binary_values<T: Value>(
    file: &str,
    array: &DataArray,
    encoding: &Encoding,
) -> Result<Vec<T>, IoError> {
    let label = array_label(array);
    let fail = |what: String| syntax(file, array.line, format!("{label}: {what}"));
    let scalar = Scalar::of_xml(array.kind).ok_or_else(|| {
        fail(format!("type={} is not a numeric type (Int8 … Float64)", shown(array.kind)))
    })?;
    let inline: String = array.text.iter().map(|&(text, _)| text).collect();
    let bytes = encoding.array_bytes(array.format, &inline).map_err(|e| match array.format {
        Format::Appended(offset) => fail(format!("appended data from offset {offset}: {e}")),
        _ => fail(e),
    })?;
    let size = scalar.size();
    if bytes.len() % size != 0 {
        return Err(fail(format!(
            "{} bytes are not a whole number of {} values",
            bytes.len(),
            array.kind
        )));
    }
    bytes
        .chunks_exact(size)
        .enumerate()
        .map(|(k, chunk)| {
            let n = scalar.read(chunk, encoding.big_endian);
            n.and_then(T::from_number).ok_or_else(|| {
                let n = n.map_or_else(String::new, |n| n.to_string());
                fail(format!("value {k}, {n}, is out of range here"))
            })
        })
        .collect()
}

/// Parses a finished array's data into its piece.
fn finish_array(
    file: &str,
    array: &DataArray,
    encoding: &Encoding,
    piece: Option<&mut Piece>,
) -> Result<(), IoError> {
    let Some(piece) = piece else { return Ok(()) };
    let binary = array.format != Format::Ascii;
    let tokens = array.text.iter().flat_map(|&(text, line)| Tokens::new(text, line));
    let label = array.name;
    match array.role {
        Role::Points => {
            let (mut coords, mut ats) = (Vec::new(), Vec::new());
            let mut p = [0.0; 3];
            let mut push = |k: usize, v: f64, at: At| {
                p[k % 3] = v;
                if k.is_multiple_of(3) {
                    ats.push(at);
                }
                if k % 3 == 2 {
                    coords.push(p);
                }
            };
            if binary {
                let at = At::Line(array.line);
                for (k, v) in binary_values::<f64>(file, array, encoding)?.into_iter().enumerate() {
                    push(k, v, at);
                }
            } else {
                for (k, (token, line)) in tokens.enumerate() {
                    push(k, parse(file, line, Some(token), "a point coordinate")?, At::Line(line));
                }
            }
            if ats.len() != coords.len() {
                return Err(syntax(
                    file,
                    array.line,
                    "the Points array does not hold whole (x, y, z) triples",
                ));
            }
            piece.coords = Some((coords, ats));
        }
        Role::Connectivity | Role::Offsets | Role::Types | Role::Labels { .. } => {
            let mut values = Labels::default();
            if binary {
                values.values = binary_values::<i64>(file, array, encoding)?;
                values.ats = vec![At::Line(array.line); values.values.len()];
            } else {
                let what = format!("an integer in array {label:?}");
                for (token, line) in tokens {
                    values.values.push(parse(file, line, Some(token), &what)?);
                    values.ats.push(At::Line(line));
                }
            }
            match array.role {
                Role::Connectivity => piece.connectivity = Some(values.values),
                Role::Offsets => piece.offsets = Some(values),
                Role::Types => piece.types = Some(values.values),
                Role::Labels { rank } => RegionArray::offer(
                    &mut piece.labels,
                    RegionArray { labels: values, name: label.to_owned(), rank },
                ),
                Role::Points => {}
            }
        }
    }
    Ok(())
}

/// Checks a finished piece and adds its points and tetrahedra to `mesh`; returns its cell count.
fn finish_piece(
    file: &str,
    piece: Piece,
    first_cell: usize,
    mesh: &mut Assembly,
) -> Result<usize, IoError> {
    let line = piece.line;
    let (coords, ats) = piece.coords.unwrap_or_default();
    if coords.len() != piece.points {
        return Err(syntax(
            file,
            line,
            format!(
                "<Piece NumberOfPoints=\"{}\"> but its Points array holds {} points",
                piece.points,
                coords.len()
            ),
        ));
    }
    let missing = |name: &str| {
        syntax(file, line, format!("<Piece> has cells but no <Cells><DataArray Name=\"{name}\">"))
    };
    let n = piece.cells;
    let block = if n == 0 {
        CellBlock {
            starts: vec![0],
            connectivity: Vec::new(),
            ats: Vec::new(),
            types: Vec::new(),
            labels: None,
        }
    } else {
        let connectivity = piece.connectivity.ok_or_else(|| missing("connectivity"))?;
        let offsets = piece.offsets.ok_or_else(|| missing("offsets"))?;
        let types = piece.types.ok_or_else(|| missing("types"))?;
        let count_error = |what: &str, found: usize| {
            syntax(
                file,
                line,
                format!("<Piece NumberOfCells=\"{n}\"> but its {what} array holds {found} values"),
            )
        };
        if offsets.values.len() != n {
            return Err(count_error("offsets", offsets.values.len()));
        }
        if types.len() != n {
            return Err(count_error("types", types.len()));
        }
        let labels = match piece.labels {
            Some(array) if array.labels.values.len() != n => {
                return Err(count_error("region label", array.labels.values.len()));
            }
            Some(array) => {
                mesh.region_source.get_or_insert_with(|| format!("cell array {:?}", array.name));
                Some(array.labels)
            }
            None => None,
        };
        let mut starts = vec![0usize];
        for (k, (&offset, &at)) in offsets.values.iter().zip(&offsets.ats).enumerate() {
            let previous = starts.last().copied().unwrap_or_default();
            match usize::try_from(offset) {
                Ok(o) if o >= previous && o <= connectivity.len() => starts.push(o),
                _ => {
                    return Err(error_at(
                        file,
                        at,
                        format!(
                            "offset {k} is {offset}: offsets must not decrease and must stay \
                             within the {} connectivity entries",
                            connectivity.len()
                        ),
                    ));
                }
            }
        }
        CellBlock { starts, connectivity, ats: offsets.ats, types, labels }
    };
    let base = mesh.vertices.len();
    block.append_tets(file, coords.len(), base, first_cell, mesh)?;
    mesh.vertex_origins
        .extend(ats.iter().enumerate().map(|(i, &at)| Origin { id: (base + i) as u64, at }));
    mesh.vertices.extend(coords);
    Ok(n)
}

/// Encodes `mesh` as an ASCII VTK XML unstructured grid with the regions as the cell array
/// `region`.
#[must_use]
pub fn encode_vtu(mesh: &TetMesh) -> String {
    let (v, t) = (mesh.vertices().len(), mesh.tets().len());
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n\
         <VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\">\n\
         <UnstructuredGrid>\n<Piece NumberOfPoints=\"{v}\" NumberOfCells=\"{t}\">\n\
         <Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n"
    );
    for [x, y, z] in mesh.vertices() {
        let _ = writeln!(out, "{x:?} {y:?} {z:?}");
    }
    out.push_str(
        "</DataArray>\n</Points>\n<Cells>\n\
         <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n",
    );
    for [a, b, c, d] in mesh.tets() {
        let _ = writeln!(out, "{a} {b} {c} {d}");
    }
    out.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for k in 1..=t {
        let _ = writeln!(out, "{}", 4 * k);
    }
    out.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in 0..t {
        out.push_str("10\n");
    }
    let kind = if region_type_fits_i32(mesh) { "Int32" } else { "UInt32" };
    let _ = write!(
        out,
        "</DataArray>\n</Cells>\n<CellData Scalars=\"region\">\n\
         <DataArray type=\"{kind}\" Name=\"region\" format=\"ascii\">\n"
    );
    for r in mesh.regions() {
        let _ = writeln!(out, "{r}");
    }
    out.push_str("</DataArray>\n</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    out
}

/// Where [`encode_vtu_binary`] puts the data arrays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VtuData {
    /// `format="binary"`: base64 inside each `DataArray`.
    Inline,
    /// `format="appended"` in `<AppendedData encoding="base64">`.
    AppendedBase64,
    /// `format="appended"` in `<AppendedData encoding="raw">`, the bytes as they are.
    AppendedRaw,
}

/// The encoding [`encode_vtu_binary`] writes: every variant VTK's own writer can produce.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VtuBinary {
    /// Where the arrays go.
    pub data: VtuData,
    /// Compress with `vtkZLibDataCompressor`.
    pub zlib: bool,
    /// `header_type="UInt64"` rather than `UInt32`.
    pub header64: bool,
    /// `byte_order="BigEndian"` rather than `LittleEndian`.
    pub big_endian: bool,
    /// Uncompressed bytes per zlib block (VTK writes 32 KiB).
    pub block_size: usize,
}

impl Default for VtuBinary {
    fn default() -> Self {
        Self {
            data: VtuData::Inline,
            zlib: false,
            header64: false,
            big_endian: false,
            block_size: 32 * 1024,
        }
    }
}

impl VtuBinary {
    /// A header value in the header type and byte order.
    fn header(self, v: usize, out: &mut Vec<u8>) {
        match (self.header64, self.big_endian) {
            (true, true) => out.extend((v as u64).to_be_bytes()),
            (true, false) => out.extend((v as u64).to_le_bytes()),
            (false, true) => out.extend((v as u32).to_be_bytes()),
            (false, false) => out.extend((v as u32).to_le_bytes()),
        }
    }

    /// One array's data as stored: header, then the bytes or their zlib blocks. Base64 encodes
    /// the header and the data separately, as VTK does.
    fn encode(self, data: &[u8]) -> Vec<u8> {
        let mut header = Vec::new();
        let body = if self.zlib {
            let block_size = self.block_size.max(1);
            let blocks: Vec<Vec<u8>> = data
                .chunks(block_size)
                .map(|block| {
                    let mut z =
                        flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
                    // Writing into a vector cannot fail.
                    let _ = z.write_all(block);
                    z.finish().unwrap_or_default()
                })
                .collect();
            self.header(blocks.len(), &mut header);
            self.header(block_size, &mut header);
            self.header(data.len() % block_size, &mut header);
            for b in &blocks {
                self.header(b.len(), &mut header);
            }
            blocks.concat()
        } else {
            self.header(data.len(), &mut header);
            data.to_vec()
        };
        if self.data == VtuData::AppendedRaw {
            header.extend(body);
            header
        } else {
            let mut text = base64_encode(&header);
            text.push_str(&base64_encode(&body));
            text.into_bytes()
        }
    }
}

/// Encodes `mesh` as a VTK XML unstructured grid with binary data arrays laid out as `options`
/// says, the regions as the cell array `region`.
#[must_use]
pub fn encode_vtu_binary(mesh: &TetMesh, options: VtuBinary) -> Vec<u8> {
    let big = options.big_endian;
    let (v, t) = (mesh.vertices().len(), mesh.tets().len());
    let f64s = |values: &mut dyn Iterator<Item = f64>| -> Vec<u8> {
        values.flat_map(|x| if big { x.to_be_bytes() } else { x.to_le_bytes() }).collect()
    };
    let i64s = |values: &mut dyn Iterator<Item = i64>| -> Vec<u8> {
        values.flat_map(|x| if big { x.to_be_bytes() } else { x.to_le_bytes() }).collect()
    };
    let fits = region_type_fits_i32(mesh);
    let regions: Vec<u8> = mesh
        .regions()
        .iter()
        .flat_map(|&r| if big { r.to_be_bytes() } else { r.to_le_bytes() })
        .collect();
    let arrays: [(&str, &str, &str, Vec<u8>); 5] = [
        (
            "Points",
            "Float64\" NumberOfComponents=\"3",
            "",
            f64s(&mut mesh.vertices().iter().flatten().copied()),
        ),
        (
            "Cells",
            "Int64",
            "connectivity",
            i64s(&mut mesh.tets().iter().flatten().map(|&i| i.into())),
        ),
        ("Cells", "Int64", "offsets", i64s(&mut (1..=t).map(|k| 4 * k as i64))),
        ("Cells", "UInt8", "types", vec![10; t]),
        ("CellData", if fits { "Int32" } else { "UInt32" }, "region", regions),
    ];
    let byte_order = if big { "BigEndian" } else { "LittleEndian" };
    let header_type = if options.header64 { "UInt64" } else { "UInt32" };
    let compressor = if options.zlib { " compressor=\"vtkZLibDataCompressor\"" } else { "" };
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" \
         byte_order=\"{byte_order}\" header_type=\"{header_type}\"{compressor}>\n\
         <UnstructuredGrid>\n<Piece NumberOfPoints=\"{v}\" NumberOfCells=\"{t}\">\n"
    )
    .into_bytes();
    let mut appended = Vec::new();
    let mut parent = "";
    for (group, kind, name, data) in arrays {
        if group != parent {
            if !parent.is_empty() {
                out.extend(format!("</{parent}>\n").bytes());
            }
            let scalars = if group == "CellData" { " Scalars=\"region\"" } else { "" };
            out.extend(format!("<{group}{scalars}>\n").bytes());
            parent = group;
        }
        let name = if name.is_empty() { String::new() } else { format!(" Name=\"{name}\"") };
        let encoded = options.encode(&data);
        if options.data == VtuData::Inline {
            out.extend(format!("<DataArray type=\"{kind}\"{name} format=\"binary\">\n").bytes());
            out.extend(encoded);
            out.extend(b"\n</DataArray>\n");
        } else {
            out.extend(
                format!(
                    "<DataArray type=\"{kind}\"{name} format=\"appended\" offset=\"{}\"/>\n",
                    appended.len()
                )
                .bytes(),
            );
            appended.extend(encoded);
        }
    }
    out.extend(format!("</{parent}>\n</Piece>\n</UnstructuredGrid>\n").bytes());
    if options.data != VtuData::Inline {
        let encoding = if options.data == VtuData::AppendedRaw { "raw" } else { "base64" };
        out.extend(format!("<AppendedData encoding=\"{encoding}\">\n_").bytes());
        out.extend(appended);
        out.extend(b"\n</AppendedData>\n");
    }
    out.extend(b"</VTKFile>\n");
    out
}
