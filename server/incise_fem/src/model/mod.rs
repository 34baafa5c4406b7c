//! The mechanical model: the hexahedral elements of a grid's top level with their condensed
//! matrices and masses ([`HexModel`]), the mass an integrator sees ([`Mass`]), the external
//! loads ([`Loads`]) and the state ([`State`]), carried across a cut by [`State::across_cut`].

mod hex_model;
mod loads;
mod mass;
mod state;
mod transfer;

pub use hex_model::{ElementKind, HexElement, HexModel, Renumbering};
pub use loads::Loads;
pub use mass::Mass;
pub use state::State;
pub use transfer::CarriedState;
