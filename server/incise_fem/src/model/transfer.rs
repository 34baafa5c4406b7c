//! The state carried across a cut: after the grid changed, each node of the new model takes the
//! position and velocity of the node it is (surviving nodes) or was split from (new nodes with an
//! origin); any other new node takes its element's mean displacement and velocity over the nodes
//! that are known, so a new piece starts where the tissue around it was, moving with it.

use super::{HexModel, Renumbering, State};
use incise_grid::GridChanges;

/// What [`State::across_cut`] returns: the new state, and for each new node the old node whose
/// state it took (`None` for a node placed from its element), which the integrators use to carry
/// their own per-node history.
#[derive(Clone, Debug, PartialEq)]
pub struct CarriedState {
    /// Positions and velocities on the new model's nodes.
    pub state: State,
    /// Per new node, the old node it took its state from.
    pub old_of_new: Vec<Option<usize>>,
}

impl State {
    /// This state (of `old`) carried to `new`, the model after `changes` (see the module doc).
    #[must_use]
    pub fn across_cut(
        &self,
        old: &HexModel,
        new: &HexModel,
        changes: &GridChanges,
    ) -> CarriedState {
        // Grid node id → index in the old model (ids beyond the old ones are new nodes).
        let mut old_index =
            vec![u32::MAX; old.grid_node.iter().map(|&g| g as usize + 1).max().unwrap_or(0)];
        for (i, &g) in old.grid_node.iter().enumerate() {
            old_index[g as usize] = i as u32;
        }
        let added: std::collections::BTreeMap<u32, Option<u32>> =
            changes.top.nodes_added.iter().copied().collect();
        let n = new.node_count();
        let mut state = State { x: new.rest.clone(), v: vec![[0.0; 3]; n] };
        let mut known = vec![false; n];
        let mut old_of_new: Vec<Option<usize>> = vec![None; n];
        for (i, &g) in new.grid_node.iter().enumerate() {
            let source = match added.get(&g) {
                Some(origin) => *origin,
                None => Some(g),
            };
            if let Some(j) =
                source.and_then(|s| old_index.get(s as usize).copied()).filter(|&j| j != u32::MAX)
            {
                state.x[i] = self.x[j as usize];
                state.v[i] = self.v[j as usize];
                known[i] = true;
                old_of_new[i] = Some(j as usize);
            }
        }
        fill_unknown(new, &mut state, &mut known);
        CarriedState { state, old_of_new }
    }

    /// This state carried in place across the edit `changes` that [`HexModel::update`] brought
    /// `model` through (`renumbering`, what it returned): [`State::across_cut`] without the old
    /// model. Returns, per node, the old node whose state it took (`old_of_new`). An edit that
    /// added and removed no node leaves the state as it was.
    pub fn carry(
        &mut self,
        model: &HexModel,
        renumbering: &Renumbering,
        changes: &GridChanges,
    ) -> Vec<Option<usize>> {
        let n = model.node_count();
        if renumbering.same_nodes() {
            return (0..n).map(Some).collect();
        }
        let mut added: Vec<(u32, Option<u32>)> = changes.top.nodes_added.clone();
        added.sort_unstable();
        let mut state = State { x: model.rest.clone(), v: vec![[0.0; 3]; n] };
        let mut known = vec![false; n];
        let mut old_of_new: Vec<Option<usize>> = vec![None; n];
        for (i, &g) in model.grid_node.iter().enumerate() {
            let source = match added.binary_search_by_key(&g, |&(id, _)| id) {
                Ok(k) => added[k].1,
                Err(_) => Some(g),
            };
            if let Some(j) = source.and_then(|s| renumbering.node_before_by_grid_id(s)) {
                state.x[i] = self.x[j];
                state.v[i] = self.v[j];
                known[i] = true;
                old_of_new[i] = Some(j);
            }
        }
        fill_unknown(model, &mut state, &mut known);
        *self = state;
        old_of_new
    }
}

/// Places each node not `known` at the mean displacement and velocity of the known nodes of the
/// first element (in element order) that has it and has any, marking it known.
fn fill_unknown(model: &HexModel, state: &mut State, known: &mut [bool]) {
    if known.iter().all(|&k| k) {
        return;
    }
    for e in &model.elements {
        // An element whose nodes are all known places nothing.
        if e.nodes.iter().all(|&k| known[k as usize]) {
            continue;
        }
        let mut have = [0usize; 8];
        let mut count = 0;
        for &k in &e.nodes {
            if known[k as usize] {
                have[count] = k as usize;
                count += 1;
            }
        }
        let have = &have[..count];
        if have.is_empty() {
            continue;
        }
        let mut du = [0.0; 3];
        let mut v = [0.0; 3];
        for &k in have {
            for a in 0..3 {
                du[a] += (state.x[k][a] - model.rest[k][a]) / have.len() as f64;
                v[a] += state.v[k][a] / have.len() as f64;
            }
        }
        for &k in &e.nodes {
            let k = k as usize;
            if !known[k] {
                state.x[k] = std::array::from_fn(|a| model.rest[k][a] + du[a]);
                state.v[k] = v;
                known[k] = true;
            }
        }
    }
}
