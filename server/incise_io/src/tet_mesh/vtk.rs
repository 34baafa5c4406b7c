//! Legacy VTK, ASCII and `BINARY`.
//!
//! Both encodings share one reader: keywords and counts are text in either, and only the values
//! after a keyword line differ (whitespace-separated numbers, or big-endian bytes starting on
//! the next line). Reading every value through [`Vtk::number`] keeps the two in step, so a rule
//! checked for one (a cell running past `CELLS`' size, an offset that decreases) is checked for
//! the other. Binary errors give the byte offset, since a binary file has no useful lines.

use super::binary::{Scalar, Value};
use super::{
    Assembly, At, BOM, CellBlock, Labels, MeshFile, MeshOptions, Origin, RegionArray, check_wanted,
    error_at, is_integer_type, region_rank, shown, syntax, unusable_region_array,
};
use crate::error::{IoError, grouped};
use incise_mesh::TetMesh;
use std::borrow::Cow;
use std::fmt::Write as _;

/// Where the attribute arrays being read belong.
#[derive(Clone, Copy, Debug)]
enum Attach {
    None,
    /// `POINT_DATA n`.
    Points(usize),
    /// `CELL_DATA n`.
    Cells(usize),
}

/// The search for the region array among the cell-data arrays.
struct Regions<'w> {
    /// The array the caller named.
    wanted: Option<&'w str>,
    /// The best candidate so far.
    found: Option<RegionArray>,
    /// The names of the cell-data arrays seen.
    seen: Vec<String>,
}

impl Regions<'_> {
    /// Notes a cell-data array and returns the rank at which to keep it, `None` to skip it.
    /// `hint` is 1 for `SCALARS`, 0 for `FIELD` arrays. An array `wanted` names that cannot
    /// hold regions is an error.
    fn consider(
        &mut self,
        file: &str,
        name: &str,
        kind: &str,
        components: usize,
        hint: u8,
    ) -> Result<Option<u8>, IoError> {
        self.seen.push(name.to_owned());
        let usable = components == 1 && is_integer_type(kind);
        if !usable && self.wanted == Some(name) {
            return Err(unusable_region_array(file, name, kind, components));
        }
        Ok(region_rank(name, hint, self.wanted)
            .filter(|&rank| usable && RegionArray::wanted(self.found.as_ref(), rank)))
    }
}

/// A legacy VTK file being read, token by token and, in a binary file, value by value.
struct Vtk<'a> {
    file: &'a str,
    bytes: &'a [u8],
    pos: usize,
    /// The line `pos` is on (counted in ASCII files only).
    line: usize,
    binary: bool,
    /// The type of the binary values being read, between [`Vtk::begin_data`] and
    /// [`Vtk::end_data`].
    data: Option<Scalar>,
}

impl<'a> Vtk<'a> {
    /// Where `pos` is: its line in an ASCII file, the byte in a binary one.
    fn at(&self, pos: usize) -> At {
        if self.binary { At::Byte(pos) } else { At::Line(self.line) }
    }

    fn error(&self, at: At, what: impl Into<String>) -> IoError {
        error_at(self.file, at, what)
    }

    /// The next whitespace-separated token, and where it is.
    fn next_token(&mut self) -> Option<(Cow<'a, str>, At)> {
        let bytes = self.bytes;
        while let Some(&b) = bytes.get(self.pos).filter(|b| b.is_ascii_whitespace()) {
            if b == b'\n' {
                self.line += 1;
            }
            self.pos += 1;
        }
        let start = self.pos;
        while bytes.get(self.pos).is_some_and(|b| !b.is_ascii_whitespace()) {
            self.pos += 1;
        }
        let token = bytes.get(start..self.pos).filter(|t| !t.is_empty())?;
        Some((String::from_utf8_lossy(token), self.at(start)))
    }

    /// The next token, without consuming it.
    fn peek(&mut self) -> Option<Cow<'a, str>> {
        let (pos, line) = (self.pos, self.line);
        let token = self.next_token().map(|(t, _)| t);
        (self.pos, self.line) = (pos, line);
        token
    }

    fn token(&mut self, what: impl FnOnce() -> String) -> Result<(Cow<'a, str>, At), IoError> {
        let end = self.at(self.bytes.len());
        self.next_token().ok_or_else(|| self.error(end, format!("the file ends before {}", what())))
    }

    /// A text token parsed as a `T` (a count, a data type's parameter).
    fn value<T: Value>(&mut self, what: impl Fn() -> String) -> Result<(T, At), IoError> {
        let (token, at) = self.token(&what)?;
        match token.parse() {
            Ok(v) => Ok((v, at)),
            Err(_) => Err(self.error(at, format!("expected {}, found {}", what(), shown(&token)))),
        }
    }

    /// The next value of an array: a text token, or the next binary value after
    /// [`Vtk::begin_data`].
    fn number<T: Value>(&mut self, what: impl Fn() -> String) -> Result<(T, At), IoError> {
        let Some(scalar) = self.data else { return self.value(what) };
        let at = At::Byte(self.pos);
        let end = self.pos + scalar.size();
        let n = self.bytes.get(self.pos..end).and_then(|b| scalar.read(b, true));
        // `begin_data` checked that the values are there; this is only the fallback.
        let n = n.ok_or_else(|| self.error(at, format!("the file ends before {}", what())))?;
        self.pos = end;
        T::from_number(n)
            .map(|v| (v, at))
            .ok_or_else(|| self.error(at, format!("expected {}, found {n} ({scalar:?})", what())))
    }

    /// Starts `count` values of type `kind` (what `what` names). In a binary file they start on
    /// the line after the keyword and must all be there before any is read; in an ASCII file
    /// nothing needs doing.
    fn begin_data(&mut self, count: usize, kind: &str, what: &str) -> Result<(), IoError> {
        if !self.binary {
            return Ok(());
        }
        let here = At::Byte(self.pos);
        let scalar = Scalar::of_legacy(kind).ok_or_else(|| {
            self.error(
                here,
                format!("{what} has data type {}, which is not read in binary files", shown(kind)),
            )
        })?;
        while self.bytes.get(self.pos).is_some_and(|b| matches!(b, b' ' | b'\t' | b'\r')) {
            self.pos += 1;
        }
        match self.bytes.get(self.pos) {
            Some(b'\n') => self.pos += 1,
            None => {}
            Some(_) => {
                let rest = self.bytes.get(self.pos..).unwrap_or_default();
                let rest = String::from_utf8_lossy(&rest[..rest.len().min(20)]).into_owned();
                return Err(self.error(
                    At::Byte(self.pos),
                    format!("expected the line of {what} to end, found {}", shown(&rest)),
                ));
            }
        }
        let left = self.bytes.len() - self.pos;
        if count.checked_mul(scalar.size()).is_none_or(|n| n > left) {
            return Err(self.error(
                At::Byte(self.pos),
                format!(
                    "{what} announces {} values of {kind} ({} bytes each), the file holds {} \
                     more bytes",
                    grouped(count as u64),
                    scalar.size(),
                    grouped(left as u64)
                ),
            ));
        }
        self.data = Some(scalar);
        Ok(())
    }

    fn end_data(&mut self) {
        self.data = None;
    }

    /// Passes over `count` values of type `kind` that this reader does not use.
    fn skip_data(&mut self, count: usize, kind: &str, what: &str) -> Result<(), IoError> {
        if self.binary {
            self.begin_data(count, kind, what)?;
            // `begin_data` checked the bytes are there.
            self.pos += count * self.data.map_or(0, Scalar::size);
            self.end_data();
        } else {
            for k in 0..count {
                self.token(|| format!("value {k} of {count} of {what}"))?;
            }
        }
        Ok(())
    }

    /// Consumes `keyword` (any letter case), or errors.
    fn keyword(&mut self, keyword: &str, after: &str) -> Result<(), IoError> {
        let (token, at) = self.token(|| format!("{keyword} (after {after})"))?;
        if token.eq_ignore_ascii_case(keyword) {
            Ok(())
        } else {
            Err(self
                .error(at, format!("expected {keyword} after {after}, found {}", shown(&token))))
        }
    }

    /// Skips the rest of the current line and everything up to and including the next blank line
    /// (how legacy VTK ends a `METADATA` block, which is text in binary files too).
    fn skip_past_blank_line(&mut self) {
        let mut first = true;
        while let Some(end) =
            self.bytes.get(self.pos..).and_then(|r| r.iter().position(|&b| b == b'\n'))
        {
            let line = &self.bytes[self.pos..self.pos + end];
            self.pos += end + 1;
            self.line += 1;
            if !first && line.trim_ascii().is_empty() {
                return;
            }
            first = false;
        }
        self.pos = self.bytes.len();
    }

    /// `POINTS n type` (after the keyword) and its `3n` coordinates.
    fn points(&mut self) -> Result<(Vec<[f64; 3]>, Vec<At>), IoError> {
        let (count, at) = self.value::<usize>(|| "the number of POINTS".to_owned())?;
        let (kind, _) = self.token(|| "the data type of POINTS".to_owned())?;
        let values = count
            .checked_mul(3)
            .ok_or_else(|| self.error(at, format!("POINTS {count} is too many")))?;
        self.begin_data(values, &kind, "POINTS")?;
        let (mut coords, mut ats) = (Vec::new(), Vec::new());
        for i in 0..count {
            let mut p = [0.0; 3];
            let mut first = At::Line(0);
            for (a, c) in p.iter_mut().enumerate() {
                let (v, at) = self.number(|| format!("coordinate {a} of point {i} of {count}"))?;
                *c = v;
                if a == 0 {
                    first = at;
                }
            }
            coords.push(p);
            ats.push(first);
        }
        self.end_data();
        Ok((coords, ats))
    }

    /// `CELLS` (after the keyword): the classic `CELLS n size` with `k i1 … ik` per cell, or the
    /// VTK 5 `CELLS nOffsets nConnectivity` with `OFFSETS` and `CONNECTIVITY` arrays.
    fn cells(&mut self) -> Result<CellBlock, IoError> {
        let (a, header) = self.value::<usize>(|| "the number of CELLS".to_owned())?;
        let (b, _) = self.value::<usize>(|| "the size of CELLS".to_owned())?;
        let mut starts = vec![0usize];
        let mut ats = Vec::new();
        let mut connectivity = Vec::new();
        if self.peek().is_some_and(|t| t.eq_ignore_ascii_case("OFFSETS")) {
            self.next_token();
            let (kind, _) = self.token(|| "the data type of OFFSETS".to_owned())?;
            self.begin_data(a, &kind, "OFFSETS")?;
            for k in 0..a {
                let (offset, at) =
                    self.number::<usize>(|| format!("offset {k} of {a} (a non-negative integer)"))?;
                let last = starts.last().copied().unwrap_or_default();
                if k == 0 && offset != 0 {
                    return Err(self.error(at, format!("the first offset is {offset}, not 0")));
                }
                if offset < last || offset > b {
                    return Err(self.error(
                        at,
                        format!(
                            "offset {k} is {offset}: offsets must not decrease and must stay \
                             within the {b} connectivity entries"
                        ),
                    ));
                }
                if k > 0 {
                    starts.push(offset);
                }
                // Offset `k` starts cell `k`; where it is stands for the cell.
                ats.push(at);
            }
            self.end_data();
            // The last offset ends the last cell and starts none.
            ats.pop();
            if a > 0 && starts.last() != Some(&b) {
                return Err(self.error(
                    header,
                    format!(
                        "the last offset is {}, CELLS announces {b} connectivity entries",
                        starts.last().copied().unwrap_or_default()
                    ),
                ));
            }
            self.keyword("CONNECTIVITY", "the OFFSETS of CELLS")?;
            let (kind, _) = self.token(|| "the data type of CONNECTIVITY".to_owned())?;
            self.begin_data(b, &kind, "CONNECTIVITY")?;
            for k in 0..b {
                let (index, _) = self.number::<i64>(|| format!("connectivity entry {k} of {b}"))?;
                connectivity.push(index);
            }
            self.end_data();
        } else {
            // VTK writes the classic layout's point ids as 32-bit ints.
            self.begin_data(b, "int", "CELLS")?;
            for k in 0..a {
                let (n, at) =
                    self.number::<usize>(|| format!("the point count of cell {k} of {a}"))?;
                let used = connectivity.len() + k + 1;
                if n > b.saturating_sub(used) {
                    return Err(self.error(
                        at,
                        format!("cell {k} runs past the size {b} that CELLS announces"),
                    ));
                }
                for j in 0..n {
                    let (index, _) = self.number::<i64>(|| format!("point {j} of cell {k}"))?;
                    connectivity.push(index);
                }
                starts.push(connectivity.len());
                ats.push(at);
            }
            self.end_data();
            if connectivity.len() + a != b {
                return Err(self.error(
                    header,
                    format!("CELLS announces size {b}, its cells hold {}", connectivity.len() + a),
                ));
            }
        }
        Ok(CellBlock { starts, connectivity, ats, types: Vec::new(), labels: None })
    }

    /// `CELL_TYPES n` (after the keyword) and its values.
    fn cell_types(&mut self) -> Result<Vec<i64>, IoError> {
        let (count, _) = self.value::<usize>(|| "the number of CELL_TYPES".to_owned())?;
        self.begin_data(count, "int", "CELL_TYPES")?;
        let mut values = Vec::new();
        for k in 0..count {
            values.push(self.number::<i64>(|| format!("cell type {k} of {count}"))?.0);
        }
        self.end_data();
        Ok(values)
    }

    /// Reads `count` values of type `kind`: as labels when `keep`, else only consumed.
    fn array(
        &mut self,
        count: usize,
        kind: &str,
        keep: bool,
        name: &str,
    ) -> Result<Option<Labels>, IoError> {
        let what = format!("array {name}");
        if !keep {
            self.skip_data(count, kind, &what)?;
            return Ok(None);
        }
        self.begin_data(count, kind, &what)?;
        let mut labels = Labels::default();
        for k in 0..count {
            let (v, at) = self.number::<i64>(|| format!("integer {k} of {count} of {what}"))?;
            labels.values.push(v);
            labels.ats.push(at);
        }
        self.end_data();
        Ok(Some(labels))
    }

    /// The tuple count of the attribute arrays of `attach`, or an error naming `what` at `at`.
    fn tuples(&self, attach: Attach, at: At, what: &str) -> Result<usize, IoError> {
        match attach {
            Attach::Points(n) | Attach::Cells(n) => Ok(n),
            Attach::None => {
                Err(self.error(at, format!("{what} is outside POINT_DATA and CELL_DATA")))
            }
        }
    }

    /// `SCALARS name type [numComp]` (after the keyword), its `LOOKUP_TABLE` line and its values.
    fn scalars(&mut self, attach: Attach, regions: &mut Regions) -> Result<(), IoError> {
        let (name, at) = self.token(|| "the name of a SCALARS array".to_owned())?;
        let (kind, _) = self.token(|| format!("the data type of SCALARS {name}"))?;
        let mut components = 1usize;
        if self.peek().is_some_and(|t| t.eq_ignore_ascii_case("LOOKUP_TABLE")) {
            self.next_token();
        } else {
            (components, _) =
                self.value(|| format!("the component count or LOOKUP_TABLE of SCALARS {name}"))?;
            self.keyword("LOOKUP_TABLE", &format!("SCALARS {name}"))?;
        }
        self.token(|| format!("the lookup table name of SCALARS {name}"))?;
        let tuples = self.tuples(attach, at, &format!("SCALARS {name}"))?;
        let count = tuples
            .checked_mul(components)
            .ok_or_else(|| self.error(at, format!("SCALARS {name} announces too many values")))?;
        let rank = match attach {
            Attach::Cells(_) => regions.consider(self.file, &name, &kind, components, 1)?,
            _ => None,
        };
        if let Some(labels) = self.array(count, &kind, rank.is_some(), &name)? {
            let (name, rank) = (name.into_owned(), rank.unwrap_or_default());
            RegionArray::offer(&mut regions.found, RegionArray { labels, name, rank });
        }
        Ok(())
    }

    /// `FIELD name numArrays` (after the keyword) and its arrays.
    fn field(&mut self, attach: Attach, regions: &mut Regions) -> Result<(), IoError> {
        let (name, _) = self.token(|| "the name of a FIELD".to_owned())?;
        let (arrays, _) =
            self.value::<usize>(|| format!("the number of arrays of FIELD {name}"))?;
        for k in 0..arrays {
            let (array, at) =
                self.token(|| format!("the name of array {k} of {arrays} of FIELD {name}"))?;
            let (components, _) =
                self.value::<usize>(|| format!("the component count of array {array}"))?;
            let (tuples, _) =
                self.value::<usize>(|| format!("the tuple count of array {array}"))?;
            let (kind, _) = self.token(|| format!("the data type of array {array}"))?;
            let count = components.checked_mul(tuples).ok_or_else(|| {
                self.error(at, format!("array {array} announces too many values"))
            })?;
            let rank = match attach {
                Attach::Cells(n) if n == tuples => {
                    regions.consider(self.file, &array, &kind, components, 0)?
                }
                _ => None,
            };
            if let Some(labels) = self.array(count, &kind, rank.is_some(), &array)? {
                let (name, rank) = (array.into_owned(), rank.unwrap_or_default());
                RegionArray::offer(&mut regions.found, RegionArray { labels, name, rank });
            }
            if self.peek().is_some_and(|t| t.eq_ignore_ascii_case("METADATA")) {
                self.next_token();
                self.skip_past_blank_line();
            }
        }
        Ok(())
    }

    /// In a binary file, passes over an attribute array this reader does not use (`VECTORS`,
    /// `NORMALS`, `TENSORS`, …; the keyword is read). ASCII files skip such arrays token by
    /// token, but binary values have no separators to skip by.
    fn other_attribute(&mut self, keyword: &str, at: At, attach: Attach) -> Result<(), IoError> {
        let upper = keyword.to_ascii_uppercase();
        let name = |s: &mut Self| s.token(|| format!("the name of {upper}")).map(|(t, _)| t);
        let (components, kind): (usize, Cow<'a, str>) = match upper.as_str() {
            "VECTORS" | "NORMALS" | "TENSORS" | "TENSORS6" | "GLOBAL_IDS" | "PEDIGREE_IDS" => {
                name(self)?;
                let (kind, _) = self.token(|| format!("the data type of {upper}"))?;
                let components = match upper.as_str() {
                    "VECTORS" | "NORMALS" => 3,
                    "TENSORS" => 9,
                    "TENSORS6" => 6,
                    _ => 1,
                };
                (components, kind)
            }
            "TEXTURE_COORDINATES" => {
                name(self)?;
                let (dim, _) =
                    self.value::<usize>(|| "the dimension of TEXTURE_COORDINATES".to_owned())?;
                let (kind, _) = self.token(|| "the data type of TEXTURE_COORDINATES".to_owned())?;
                (dim, kind)
            }
            "COLOR_SCALARS" => {
                name(self)?;
                let (m, _) =
                    self.value::<usize>(|| "the value count of COLOR_SCALARS".to_owned())?;
                (m, Cow::Borrowed("unsigned_char"))
            }
            "LOOKUP_TABLE" => {
                name(self)?;
                let (size, _) = self.value::<usize>(|| "the size of LOOKUP_TABLE".to_owned())?;
                let count = size
                    .checked_mul(4)
                    .ok_or_else(|| self.error(at, "LOOKUP_TABLE is too large"))?;
                return self.skip_data(count, "unsigned_char", "LOOKUP_TABLE");
            }
            _ => {
                return Err(self.error(
                    at,
                    format!(
                        "unknown keyword {}: the binary data it may hold cannot be passed over",
                        shown(keyword)
                    ),
                ));
            }
        };
        let tuples = self.tuples(attach, at, &upper)?;
        let count = tuples
            .checked_mul(components)
            .ok_or_else(|| self.error(at, format!("{upper} announces too many values")))?;
        self.skip_data(count, &kind, &upper)
    }
}

/// Checks the three header lines of a legacy VTK file; returns whether it is binary and where
/// its body starts.
fn vtk_header(bytes: &[u8], file: &str) -> Result<(bool, usize), IoError> {
    let mut pos = 0;
    let mut lines: [Cow<str>; 3] = Default::default();
    for (i, slot) in lines.iter_mut().enumerate() {
        let rest = bytes.get(pos..).unwrap_or_default();
        let Some(end) = rest.iter().position(|&b| b == b'\n') else {
            return Err(syntax(
                file,
                i + 1,
                "the file ends inside the header (version line, title, ASCII or BINARY)",
            ));
        };
        *slot = String::from_utf8_lossy(rest[..end].trim_ascii());
        pos += end + 1;
    }
    if !lines[0].get(..14).is_some_and(|s| s.eq_ignore_ascii_case("# vtk DataFile")) {
        return Err(syntax(
            file,
            1,
            format!(
                "expected \"# vtk DataFile Version …\" (a legacy VTK file), found {}",
                shown(&lines[0])
            ),
        ));
    }
    if lines[2].eq_ignore_ascii_case("BINARY") {
        Ok((true, pos))
    } else if lines[2].eq_ignore_ascii_case("ASCII") {
        Ok((false, pos))
    } else {
        Err(syntax(file, 3, format!("expected ASCII or BINARY, found {}", shown(&lines[2]))))
    }
}

/// Decodes a legacy VTK `DATASET UNSTRUCTURED_GRID`, ASCII or `BINARY` (big-endian, as VTK
/// writes it), classic or VTK 5 cell layout. `name` names the bytes in errors.
pub fn decode_vtk_legacy(bytes: &[u8], name: &str) -> Result<TetMesh, IoError> {
    decode_vtk_legacy_with(bytes, name, &MeshOptions::default()).map(|file| file.mesh)
}

/// Decodes a legacy VTK file as [`decode_vtk_legacy`] does, with `options`.
pub fn decode_vtk_legacy_with(
    bytes: &[u8],
    name: &str,
    options: &MeshOptions,
) -> Result<MeshFile, IoError> {
    let bytes = bytes.strip_prefix(BOM).unwrap_or(bytes);
    let (binary, body) = vtk_header(bytes, name)?;
    let mut r = Vtk { file: name, bytes, pos: body, line: 4, binary, data: None };
    r.keyword("DATASET", "the header")?;
    let (kind, _) = r.token(|| "the DATASET type".to_owned())?;
    if !kind.eq_ignore_ascii_case("UNSTRUCTURED_GRID") {
        return Err(IoError::UnsupportedType {
            file: name.to_owned(),
            what: format!("DATASET {kind}; this reader takes UNSTRUCTURED_GRID"),
        });
    }
    let mut points = None;
    let mut cells: Option<CellBlock> = None;
    let mut types: Option<(Vec<i64>, At)> = None;
    let mut cell_data: Option<(usize, At)> = None;
    let mut attach = Attach::None;
    let mut regions = Regions { wanted: options.region.as_deref(), found: None, seen: Vec::new() };
    let twice =
        |at: At, section: &str| Err(error_at(name, at, format!("a second {section} section")));
    while let Some((token, at)) = r.next_token() {
        let is = |keyword: &str| token.eq_ignore_ascii_case(keyword);
        if is("POINTS") {
            if points.is_some() {
                return twice(at, "POINTS");
            }
            points = Some(r.points()?);
        } else if is("CELLS") {
            if cells.is_some() {
                return twice(at, "CELLS");
            }
            cells = Some(r.cells()?);
        } else if is("CELL_TYPES") {
            if types.is_some() {
                return twice(at, "CELL_TYPES");
            }
            types = Some((r.cell_types()?, at));
        } else if is("POINT_DATA") {
            attach = Attach::Points(r.value(|| "the number of POINT_DATA values".to_owned())?.0);
        } else if is("CELL_DATA") {
            if cell_data.is_some() {
                return twice(at, "CELL_DATA");
            }
            let (count, _) = r.value(|| "the number of CELL_DATA values".to_owned())?;
            attach = Attach::Cells(count);
            cell_data = Some((count, at));
        } else if is("SCALARS") {
            r.scalars(attach, &mut regions)?;
        } else if is("FIELD") {
            r.field(attach, &mut regions)?;
        } else if is("METADATA") {
            r.skip_past_blank_line();
        } else if binary {
            r.other_attribute(&token, at, attach)?;
        }
        // In an ASCII file anything else (VECTORS, NORMALS, LOOKUP_TABLE, their values) is
        // skipped token by token: none of it is a keyword above.
    }
    let end = r.at(bytes.len());
    let missing = |section: &str| error_at(name, end, format!("the file has no {section} section"));
    let (coords, point_ats) = points.ok_or_else(|| missing("POINTS"))?;
    let mut block = cells.ok_or_else(|| missing("CELLS"))?;
    let (types, types_at) = types.ok_or_else(|| missing("CELL_TYPES"))?;
    let cell_count = block.ats.len();
    if types.len() != cell_count {
        return Err(error_at(
            name,
            types_at,
            format!("CELL_TYPES has {} entries for {cell_count} cells", types.len()),
        ));
    }
    if let Some((count, at)) = cell_data
        && count != cell_count
    {
        return Err(error_at(
            name,
            at,
            format!("CELL_DATA announces {count} values for {cell_count} cells"),
        ));
    }
    block.types = types;
    let found_wanted =
        regions.found.as_ref().is_some_and(|r| Some(r.name.as_str()) == regions.wanted);
    check_wanted(name, regions.wanted, found_wanted, &regions.seen)?;
    let mut mesh = Assembly::new("point", "cell");
    if let Some(array) = regions.found {
        mesh.region_source = Some(format!("cell array {:?}", array.name));
        block.labels = Some(array.labels);
    }
    block.append_tets(name, coords.len(), 0, 0, &mut mesh)?;
    mesh.vertex_origins =
        point_ats.iter().enumerate().map(|(i, &at)| Origin { id: i as u64, at }).collect();
    mesh.vertices = coords;
    mesh.finish(name)
}

/// The region labels' VTK type: `int` when every label fits, else `unsigned_int`.
pub(super) fn region_type_fits_i32(mesh: &TetMesh) -> bool {
    mesh.regions().iter().all(|&r| i32::try_from(r).is_ok())
}

/// Encodes `mesh` as an ASCII legacy VTK unstructured grid (classic cell layout) with the
/// regions as the `int` cell scalars `region`.
#[must_use]
pub fn encode_vtk_legacy(mesh: &TetMesh) -> String {
    let (v, t) = (mesh.vertices().len(), mesh.tets().len());
    let mut out = format!(
        "# vtk DataFile Version 3.0\nincise tetrahedral mesh\nASCII\nDATASET UNSTRUCTURED_GRID\n\
         POINTS {v} double\n"
    );
    for [x, y, z] in mesh.vertices() {
        let _ = writeln!(out, "{x:?} {y:?} {z:?}");
    }
    let _ = writeln!(out, "CELLS {t} {}", 5 * t);
    for [a, b, c, d] in mesh.tets() {
        let _ = writeln!(out, "4 {a} {b} {c} {d}");
    }
    let _ = writeln!(out, "CELL_TYPES {t}");
    for _ in 0..t {
        out.push_str("10\n");
    }
    let kind = if region_type_fits_i32(mesh) { "int" } else { "unsigned_int" };
    let _ = write!(out, "CELL_DATA {t}\nSCALARS region {kind} 1\nLOOKUP_TABLE default\n");
    for r in mesh.regions() {
        let _ = writeln!(out, "{r}");
    }
    out
}

/// The cell layout [`encode_vtk_legacy_binary`] writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VtkCells {
    /// `CELLS n size` with a point count before each cell's 32-bit point ids (VTK before 5.1).
    Classic,
    /// `CELLS` with 64-bit `OFFSETS` and `CONNECTIVITY` arrays (VTK 5.1 and later).
    OffsetsConnectivity,
}

/// Encodes `mesh` as a `BINARY` (big-endian) legacy VTK unstructured grid in the cell layout
/// `cells`, with the regions as the cell scalars `region` (`int`, or `unsigned_int` when a
/// label needs it).
#[must_use]
pub fn encode_vtk_legacy_binary(mesh: &TetMesh, cells: VtkCells) -> Vec<u8> {
    let (v, t) = (mesh.vertices().len(), mesh.tets().len());
    let version = if cells == VtkCells::Classic { "3.0" } else { "5.1" };
    let mut out = format!(
        "# vtk DataFile Version {version}\nincise tetrahedral mesh\nBINARY\n\
         DATASET UNSTRUCTURED_GRID\nPOINTS {v} double\n"
    )
    .into_bytes();
    for p in mesh.vertices() {
        for c in p {
            out.extend(c.to_be_bytes());
        }
    }
    match cells {
        VtkCells::Classic => {
            out.extend(format!("\nCELLS {t} {}\n", 5 * t).bytes());
            for tet in mesh.tets() {
                out.extend(4i32.to_be_bytes());
                for &i in tet {
                    out.extend((i as i32).to_be_bytes());
                }
            }
        }
        VtkCells::OffsetsConnectivity => {
            out.extend(format!("\nCELLS {} {}\nOFFSETS vtktypeint64\n", t + 1, 4 * t).bytes());
            for k in 0..=t {
                out.extend((4 * k as i64).to_be_bytes());
            }
            out.extend(b"\nCONNECTIVITY vtktypeint64\n");
            for tet in mesh.tets() {
                for &i in tet {
                    out.extend(i64::from(i).to_be_bytes());
                }
            }
        }
    }
    out.extend(format!("\nCELL_TYPES {t}\n").bytes());
    for _ in 0..t {
        out.extend(10i32.to_be_bytes());
    }
    let kind = if region_type_fits_i32(mesh) { "int" } else { "unsigned_int" };
    out.extend(format!("\nCELL_DATA {t}\nSCALARS region {kind} 1\nLOOKUP_TABLE default\n").bytes());
    for r in mesh.regions() {
        out.extend(r.to_be_bytes());
    }
    out.push(b'\n');
    out
}
