//! The one error type of the crate.
//!
//! Every variant carries the file it is about (the path, or the name given to a `decode_*`
//! function) and its message says what was wrong and where: the header field, the byte count, the
//! voxel.

use incise_grid::VolumeError;
use incise_mesh::{TetMeshError, TriMeshError};
use thiserror::Error;

/// Why a label volume, a tetrahedral mesh or a triangle mesh could not be read or written.
#[derive(Debug, Error)]
pub enum IoError {
    /// The operating system refused a read or write, or a gzip stream is corrupt.
    #[error("{file}: {source}")]
    Io {
        /// The file.
        file: String,
        /// What the operating system or the gzip decoder reported.
        source: std::io::Error,
    },
    /// The file ends before the part its header announces.
    #[error(
        "{file}: data truncated: needs {} bytes of {what}, file holds {}",
        grouped(*.expected),
        grouped(*.found)
    )]
    Truncated {
        /// The file.
        file: String,
        /// The part that is cut short ("voxels (438×353×165 uint8)", "NIfTI-1 header", …).
        what: String,
        /// Bytes that part needs.
        expected: u64,
        /// Bytes the file holds for it.
        found: u64,
    },
    /// A header that is malformed: a wrong magic number, a field that does not parse or is out of
    /// range.
    #[error("{file}: {what}")]
    BadHeader {
        /// The file.
        file: String,
        /// The field and what is wrong with it.
        what: String,
    },
    /// A well-formed header describing something this crate does not read (a voxel type, a
    /// two-file NIfTI, a 4-D series) or a volume the format cannot hold.
    #[error("{file}: unsupported: {what}")]
    UnsupportedType {
        /// The file.
        file: String,
        /// What is not supported.
        what: String,
    },
    /// Header fields that disagree with each other or with the file's length (bitpix against
    /// datatype, a header not ending on a 256-byte boundary, bytes after the voxels).
    #[error("{file}: header and sizes disagree: {what}")]
    HeaderSizeMismatch {
        /// The file.
        file: String,
        /// Which sizes disagree, with their values.
        what: String,
    },
    /// A voxel value that is not a tissue label (an integer in `0..=65535`).
    #[error(
        "{file}: voxel {voxel} holds {value}, which is not a tissue label (an integer in 0..=65535)"
    )]
    BadLabel {
        /// The file.
        file: String,
        /// Linear index of the voxel, `x` fastest.
        voxel: usize,
        /// The value found (and how it was computed when the header scales values).
        value: String,
    },
    /// Units or an orientation from which no voxel spacing or direction follows (a zero-length
    /// or sheared `sform` axis, an unknown unit code).
    #[error("{file}: bad voxel spacing or orientation: {what}")]
    BadSpacing {
        /// The file.
        file: String,
        /// The field and what is wrong with it.
        what: String,
    },
    /// The decoded extent, spacing or placement is refused by [`incise_grid::LabelVolume`]
    /// (a spacing of zero, an extent beyond 2^20).
    #[error("{file}: {source}")]
    Volume {
        /// The file.
        file: String,
        /// Why the volume was refused.
        source: VolumeError,
    },
    /// Neither the extension nor the content names a format this crate reads.
    #[error(
        "{file}: unknown format: neither the name (.nii, .nii.gz, .inr, .inr.gz) nor the content \
         says NIfTI-1 or INRIMAGE-4"
    )]
    UnknownFormat {
        /// The file.
        file: String,
    },
    /// A mesh file (Gmsh, legacy VTK, VTK XML, ASCII STL, OBJ) that does not parse where it is
    /// text: a missing section or keyword, a malformed number, a count that disagrees with the
    /// data, an element or face naming a node or vertex that does not exist, or a VTK XML
    /// `DataArray` (on the line of its tag) whose binary data does not decode.
    #[error("{file}: line {line}: {what}")]
    Syntax {
        /// The file.
        file: String,
        /// The line (1-based) where the problem shows.
        line: usize,
        /// What is wrong there.
        what: String,
    },
    /// Binary mesh data (binary MSH, `BINARY` legacy VTK, binary STL) that does not decode: a
    /// count beyond the bytes the file holds, a value out of range, a section that does not end
    /// where its counts say.
    #[error("{file}: byte {}: {what}", grouped(*.offset))]
    Binary {
        /// The file.
        file: String,
        /// Where the problem shows, in bytes from the start of the file.
        offset: u64,
        /// What is wrong there.
        what: String,
    },
    /// Tetrahedra that parse but do not form a valid mesh (degenerate, repeating a vertex, a
    /// triangle in three of them, a non-finite vertex), as [`incise_mesh::TetMesh::new`]
    /// reports them.
    #[error("{file}: {}{source}", located(.at.as_deref()))]
    Mesh {
        /// The file.
        file: String,
        /// The line and element (or vertex) the problem is about, where there is one.
        at: Option<String>,
        /// Why the mesh was refused; its tetrahedron index counts the file's tetrahedra only.
        source: TetMeshError,
    },
    /// Triangles that parse but do not bound a solid (an edge in one triangle or in more than
    /// two, neighbours wound in opposite senses, a triangle with no area, a non-finite vertex),
    /// as [`incise_mesh::TriMesh::new`] reports them.
    #[error("{file}: {}{source}", located(.at.as_deref()))]
    TriMesh {
        /// The file.
        file: String,
        /// The line or byte and the facet or face the problem is about, where there is one,
        /// with the other facets or faces it involves.
        at: Option<String>,
        /// Why the mesh was refused; its triangle indices count the file's triangles (after
        /// polygons are split into triangles) from 0. Boxed: the coordinates it carries would
        /// enlarge every `IoError`, and so every `Result` of this crate.
        source: Box<TriMeshError>,
    },
    /// The region array a caller named is not in the mesh file, or cannot hold region labels.
    #[error("{file}: region array: {what}")]
    RegionArray {
        /// The file.
        file: String,
        /// What was asked for and what the file has.
        what: String,
    },
}

impl IoError {
    /// The file (path or in-memory name) the error is about.
    #[must_use]
    pub fn file(&self) -> &str {
        match self {
            Self::Io { file, .. }
            | Self::Truncated { file, .. }
            | Self::BadHeader { file, .. }
            | Self::UnsupportedType { file, .. }
            | Self::HeaderSizeMismatch { file, .. }
            | Self::BadLabel { file, .. }
            | Self::BadSpacing { file, .. }
            | Self::Volume { file, .. }
            | Self::Syntax { file, .. }
            | Self::Binary { file, .. }
            | Self::Mesh { file, .. }
            | Self::TriMesh { file, .. }
            | Self::RegionArray { file, .. }
            | Self::UnknownFormat { file } => file,
        }
    }
}

/// `at` followed by a colon, or nothing.
fn located(at: Option<&str>) -> String {
    at.map(|at| format!("{at}: ")).unwrap_or_default()
}

/// `n` with thousands separators, because byte counts of volumes run to eight digits.
pub(crate) fn grouped(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::with_capacity(digits.len() + digits.len() / 3);
    for (i, ch) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(ch);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grouped_inserts_separators() {
        assert_eq!(grouped(0), "0");
        assert_eq!(grouped(999), "999");
        assert_eq!(grouped(1000), "1,000");
        assert_eq!(grouped(25_511_310), "25,511,310");
        assert_eq!(grouped(u64::MAX), "18,446,744,073,709,551,615");
    }

    #[test]
    fn truncated_message_reads_naturally() {
        let e = IoError::Truncated {
            file: "scan.nii.gz".into(),
            what: "voxels".into(),
            expected: 25_511_310,
            found: 1000,
        };
        assert_eq!(
            e.to_string(),
            "scan.nii.gz: data truncated: needs 25,511,310 bytes of voxels, file holds 1,000"
        );
        assert_eq!(e.file(), "scan.nii.gz");
    }
}
