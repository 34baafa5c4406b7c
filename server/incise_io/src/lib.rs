//! Reading and writing segmented label volumes: NIfTI-1 single-file images (`.nii`, `.nii.gz`)
//! and INRIMAGE-4 images (`.inr`, `.inr.gz`); reading tetrahedral meshes
//! ([`read_tet_mesh`]) as meshing tools write them by default: Gmsh MSH 2.2 (ASCII) and 4.1
//! (ASCII or binary) (`.msh`), legacy VTK, ASCII or `BINARY` (`.vtk`), and VTK XML unstructured
//! grids (`.vtu`) with ASCII, base64 or appended raw data, zlib-compressed or not; and reading
//! closed triangle meshes, the shapes of surgical tools ([`read_tri_mesh`]), as CAD tools export
//! them: STL, binary or ASCII (`.stl`), and Wavefront OBJ (`.obj`).
//!
//! Every volume reader returns an [`incise_grid::LabelVolume`] in metres, and every error names the
//! file and what in it is wrong. Decoders never panic and never allocate more than the header says
//! the data needs: a header announcing more voxels than the file holds is reported as truncated
//! before the label vector is allocated, and gzip streams are inflated only as far as the header
//! asks. Gzip is recognised by its magic bytes, whatever the file is called. Mesh readers name
//! the line (text) or byte offset (binary) or `DataArray` (VTU) of every error, and allocate only
//! for data actually present, whatever counts a header announces. Triangle meshes must be closed
//! and consistently wound ([`incise_mesh::TriMesh`]); an open surface or a flipped facet is an
//! error naming the facet or face and its line or byte. They keep the file's coordinates, since
//! STL and OBJ carry no unit.
//!
//! This crate knows geometry (`incise_grid`'s volumes, `incise_mesh`'s tetrahedra and triangle
//! meshes), not mechanics: scene files, which name a volume and configure a simulation, are read
//! by `incise_scene`.

mod error;
mod gzip;
mod inr;
mod nifti;
mod samples;
mod tet_mesh;
mod tri_mesh;

#[cfg(test)]
mod fuzz;

pub use error::IoError;
pub use inr::{decode_inr, encode_inr, read_inr, write_inr};
pub use nifti::{decode_nifti, encode_nifti, read_nifti, write_nifti};
pub use tet_mesh::{
    MeshFile, MeshOptions, VtkCells, VtuBinary, VtuData, decode_gmsh, decode_gmsh_with,
    decode_vtk_legacy, decode_vtk_legacy_with, decode_vtu, decode_vtu_with, encode_gmsh22,
    encode_gmsh41_binary, encode_vtk_legacy, encode_vtk_legacy_binary, encode_vtu,
    encode_vtu_binary, read_tet_mesh, read_tet_mesh_with,
};
pub use tri_mesh::{
    decode_obj, decode_stl, encode_obj, encode_stl_ascii, encode_stl_binary, read_tri_mesh,
};

use incise_grid::LabelVolume;
use std::path::Path;

/// The two formats, as told by a file name or by content.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Nifti,
    Inr,
}

/// The format named by the extension of `path` (`.nii`, `.nii.gz`, `.inr`, `.inr.gz`, in any
/// letter case).
fn format_of_name(path: &Path) -> Option<Format> {
    let name = Path::new(path.file_name()?);
    let inner = if ends_with_gz(name) { Path::new(name.file_stem()?) } else { name };
    let ext = inner.extension()?;
    if ext.eq_ignore_ascii_case("nii") {
        Some(Format::Nifti)
    } else if ext.eq_ignore_ascii_case("inr") {
        Some(Format::Inr)
    } else {
        None
    }
}

/// The format the first bytes of `bytes` (inflated when gzip) belong to.
fn format_of_content(bytes: &[u8], file: &str) -> Result<Option<Format>, IoError> {
    let mut input = gzip::Input::new(bytes, file);
    let head = input.take(16)?;
    Ok(if inr::sniff(&head) {
        Some(Format::Inr)
    } else if nifti::sniff(&head) {
        Some(Format::Nifti)
    } else {
        None
    })
}

/// Whether `path` names a gzip file, which the writers then compress.
fn ends_with_gz(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("gz"))
}

/// Reads a label volume, choosing the format by extension (`.nii`, `.nii.gz`, `.inr`,
/// `.inr.gz`) or, for any other name, by content.
pub fn read_volume(path: &Path) -> Result<LabelVolume, IoError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| IoError::Io { file: file.clone(), source })?;
    match format_of_name(path) {
        Some(Format::Nifti) => decode_nifti(&bytes, &file),
        Some(Format::Inr) => decode_inr(&bytes, &file),
        None => decode_volume(&bytes, &file),
    }
}

/// Decodes a label volume held in memory, choosing the format by content (gzip-compressed or
/// not). `file` names the bytes in errors.
pub fn decode_volume(bytes: &[u8], file: &str) -> Result<LabelVolume, IoError> {
    match format_of_content(bytes, file)? {
        Some(Format::Nifti) => decode_nifti(bytes, file),
        Some(Format::Inr) => decode_inr(bytes, file),
        None => Err(IoError::UnknownFormat { file: file.to_owned() }),
    }
}

/// Writes a label volume in the format named by the extension of `path` (`.nii`, `.nii.gz`,
/// `.inr`, `.inr.gz`), gzip-compressed when it ends in `.gz`.
pub fn write_volume(path: &Path, volume: &LabelVolume) -> Result<(), IoError> {
    match format_of_name(path) {
        Some(Format::Nifti) => write_nifti(path, volume),
        Some(Format::Inr) => write_inr(path, volume),
        None => Err(IoError::UnknownFormat { file: path.display().to_string() }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extensions_pick_the_format() {
        let f = |s: &str| format_of_name(Path::new(s));
        assert_eq!(f("a/liver.inr.gz"), Some(Format::Inr));
        assert_eq!(f("LIVER.INR"), Some(Format::Inr));
        assert_eq!(f("scan.nii"), Some(Format::Nifti));
        assert_eq!(f("scan.Nii.GZ"), Some(Format::Nifti));
        assert_eq!(f("scan.gz"), None);
        assert_eq!(f("scan.hdr"), None);
        assert!(ends_with_gz(Path::new("x.nii.gz")) && !ends_with_gz(Path::new("x.nii")));
    }
}
