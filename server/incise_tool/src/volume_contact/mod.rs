//! Volume contact (Faure et al. 2008; paper 1 §3, Fig. 10): the intersection volume of closed
//! surfaces from layered depth images, and its gradient with respect to their vertices, the
//! direction that separates them. The CPU reference of the GPU kernels.
//!
//! - [`ldi`]: layered depth images of a closed triangle surface along one axis;
//! - [`mod@intersection`]: the intersection volume of two surfaces, or of one surface with itself,
//!   and its gradient;
//! - [`passes`]: the views' rasterisation and ray intervals behind both, with what a frame's
//!   passes share;
//! - [`regions`]: the same split into connected overlaps, each with its own volume and gradient
//!   (what the contact's penalty pushes apart);
//! - [`device`]: the trait a device (a GPU) implements to run the per-frame passes instead.

pub mod device;
pub mod intersection;
pub mod ldi;
pub mod passes;
pub mod regions;

pub use device::ContactDevice;
pub use intersection::{
    Intersection, SelfIntersection, Side, intersection, intersection_in, overlap_intervals,
    self_intersection, self_overlap_intervals,
};
pub use ldi::{Fragment, Ldi, TriangleSurface, View};
pub use passes::Passes;
pub use regions::{
    Overlap, OverlapInterval, overlaps, regions_of, self_overlaps, self_overlaps_in,
};
