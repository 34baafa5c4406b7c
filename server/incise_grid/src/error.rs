//! Errors of the grid crate. Each says what was wrong and where (axis, label, voxel).

use thiserror::Error;

/// A label volume or material table that cannot be used.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum VolumeError {
    /// An extent of zero or beyond [`crate::volume::MAX_DIM`].
    #[error("volume extent along axis {axis} is {value}; it must be between 1 and 2^20")]
    BadDimension {
        /// 0 = x, 1 = y, 2 = z.
        axis: usize,
        /// The extent given.
        value: usize,
    },
    /// A spacing that is zero, negative or not finite.
    #[error("voxel spacing along axis {axis} is {value} m; it must be finite and positive")]
    BadSpacing {
        /// 0 = x, 1 = y, 2 = z.
        axis: usize,
        /// The spacing given, in metres.
        value: f64,
    },
    /// The number of labels does not match the extent.
    #[error("volume holds {found} labels but its extent needs {expected}")]
    SizeMismatch {
        /// Product of the extents.
        expected: usize,
        /// Labels given.
        found: usize,
    },
    /// An origin or direction with a NaN or infinity.
    #[error("volume origin or orientation is not finite")]
    BadPlacement,
    /// A stride of zero.
    #[error("stride along axis {axis} is 0; it must be at least 1")]
    BadStride {
        /// 0 = x, 1 = y, 2 = z.
        axis: usize,
    },
    /// A crop box outside the volume.
    #[error("crop [{min}, {max}] along axis {axis} does not fit the extent {dim}")]
    BadCrop {
        /// 0 = x, 1 = y, 2 = z.
        axis: usize,
        /// First voxel kept.
        min: usize,
        /// Last voxel kept.
        max: usize,
        /// The volume's extent.
        dim: usize,
    },
    /// No voxel has a non-zero label (after filtering).
    #[error("the volume has no foreground voxel (every label is 0 after filtering)")]
    EmptyForeground,
    /// A label in the volume has no material.
    #[error(
        "label {label} occurs in the volume ({count} voxels) but the material table has no entry for it"
    )]
    UnknownLabel {
        /// The label without a material.
        label: u16,
        /// How many voxels carry it.
        count: usize,
    },
    /// A material with a non-physical parameter.
    #[error("material for label {label}: {what}")]
    BadMaterial {
        /// The label the material is for.
        label: u16,
        /// Which parameter is out of range, and its value.
        what: String,
    },
    /// A top level beyond what the grid supports.
    #[error("grid level {level} is too deep: at most {max} is supported (a level-{max} element already covers {}³ voxels)", 1u32 << max)]
    LevelTooDeep {
        /// The level asked for.
        level: u32,
        /// The deepest supported level.
        max: u32,
    },
    /// More distinct materials than the grid can index.
    #[error("{count} materials are in use; at most 65535 are supported")]
    TooManyMaterials {
        /// Materials in use.
        count: usize,
    },
}

/// A grid edit that names voxels or links that do not exist.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
pub enum EditError {
    /// A voxel index beyond the volume.
    #[error("voxel {voxel} is outside the grid's {count} voxels")]
    VoxelOutOfRange {
        /// The index given.
        voxel: u32,
        /// Voxels in the volume.
        count: usize,
    },
    /// A link whose two voxels are not face neighbours.
    #[error("voxels {a} and {b} do not share a face, so there is no link between them to sever")]
    NotALink {
        /// First voxel.
        a: u32,
        /// Second voxel.
        b: u32,
    },
}
