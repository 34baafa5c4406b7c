//! Volume contact (Faure et al. 2008; paper 1 §3, Fig. 10): the intersection volume of closed
//! surfaces from layered depth images, and its gradient with respect to their vertices, the
//! direction that separates them. The CPU reference of the GPU kernels.
//!
//! - [`ldi`]: layered depth images of a closed triangle surface along one axis;
//! - [`mod@intersection`]: the intersection volume of two surfaces, or of one surface with itself,
//!   and its gradient.

pub mod intersection;
pub mod ldi;

pub use intersection::{
    Intersection, SelfIntersection, intersection, intersection_in, self_intersection,
};
pub use ldi::{Fragment, Ldi, TriangleSurface, View};
