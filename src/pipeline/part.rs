//! A part of one build's tree, as a sharded build's jobs each make one: the
//! fixed plan they share, which chunks a job builds, and what it returns.

use serde::{Deserialize, Serialize};

use super::Report;
use crate::config::Config;
use crate::output::tileset::{TileRecord, TilesetExtras};
use crate::quadtree::{ChunkKey, ChunkTree};

/// The tree every job of one sharded build builds: what [`super::build`]
/// plans for the same input and settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FixedPlan {
    /// Grid size, samples `[width, height]`.
    pub grid: [usize; 2],
    /// The widest a deepest-level chunk may be, cells.
    pub leaf_cells: u32,
    /// Levels below the leaves' footprint that only halve δ.
    pub refine_levels: u32,
    /// Whether lone chunks fill by parts (the pipeline's `lone_parts`).
    pub lone_parts: bool,
}

impl FixedPlan {
    /// The tree itself.
    pub fn tree(&self, cfg: &Config) -> ChunkTree {
        let [w, h] = self.grid;
        super::chunk_tree(cfg, [w, h], self.leaf_cells, self.refine_levels)
    }
}

/// Which chunks of the tree one job builds.
#[derive(Clone, Debug, PartialEq)]
pub enum TreePart {
    /// Every chunk above this level.
    Above(u32),
    /// These chunks (all of one level) and everything below them.
    Under(Vec<ChunkKey>),
}

/// What one job built: its chunks' records for the index, the tileset's
/// extras (the same in every job) and its report.
#[derive(Debug)]
pub struct PartBuilt {
    /// The job's figures.
    pub report: Report,
    /// One per chunk written, in key order.
    pub records: Vec<TileRecord>,
    /// The index's top-level extras.
    pub extras: TilesetExtras,
}
