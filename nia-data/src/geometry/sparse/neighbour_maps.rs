//! A rulebook as two dense maps, for kernels that walk the output sites (the forward and the
//! input gradient read each output's 27 neighbours) or the input sites (the inverse) in order:
//! the host sparse convolution of nia-model. Built once per rulebook and kept with it
//! ([`super::Rulebook::neighbour_maps`]), so the loader's workers can build them with the
//! pyramid ([`super::SitePyramid::warm_neighbour_maps`]) instead of the training step.

use super::rulebook::{Rulebook, KERNEL_VOLUME};

/// The neighbour map of a rulebook and its inverse.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NeighbourMaps {
    /// `[P_out * 27]` the input site read by output `o` at offset `k` (`o * 27 + k`); `P_in`
    /// where that input is inactive.
    pub neighbours: Vec<u32>,
    /// `[P_in * 27]` the output site that reads input `i` at offset `k` (`i * 27 + k`); `P_out`
    /// where none does (for a fixed offset an input is read by at most one output).
    pub inverse: Vec<u32>,
}

impl NeighbourMaps {
    /// The maps of `rulebook`.
    pub fn new(rulebook: &Rulebook) -> Self {
        let mut inverse = vec![rulebook.n_out as u32; rulebook.n_in * KERNEL_VOLUME];
        for k in 0..KERNEL_VOLUME {
            for (i, o) in rulebook.pairs(k) {
                inverse[i as usize * KERNEL_VOLUME + k] = o;
            }
        }
        NeighbourMaps {
            neighbours: rulebook.neighbour_map(),
            inverse,
        }
    }
}
