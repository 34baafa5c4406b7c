//! The mechanical state: node positions and velocities.

use crate::model::HexModel;
use incise_math::Vec3;

/// Positions and velocities of every node.
#[derive(Clone, Debug, PartialEq)]
pub struct State {
    /// Positions (m).
    pub x: Vec<Vec3>,
    /// Velocities (m/s).
    pub v: Vec<Vec3>,
}

impl State {
    /// At rest in the rest configuration.
    #[must_use]
    pub fn at_rest(model: &HexModel) -> Self {
        Self { x: model.rest.clone(), v: vec![[0.0; 3]; model.node_count()] }
    }
}
