//! Load: every supported DEM format into one [`Heightfield`].
//!
//! Each format lives in its own file and returns a `Heightfield` with NaN for
//! nodata, spacing in metres (geographic grids go through
//! [`Heightfield::apply_local_tangent`]) and the georeference it found.
//! Errors name the file and what is wrong with it; nothing here panics on
//! user input.

use std::path::{Path, PathBuf};

use crate::heightfield::Heightfield;

/// Options that override what a file says.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// Multiply every height by this (e.g. 0.3048 for feet). Default 1.
    pub vertical_scale: Option<f64>,
    /// Force the ground spacing in metres, `[s_x, s_z]`.
    pub spacing_m: Option<[f64; 2]>,
}

/// What can go wrong while loading a DEM. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum DemError {
    /// The file could not be opened or read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file's format is not one terrachunk reads.
    #[error("{path}: unsupported format: {what}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What was found.
        what: String,
    },
    /// The file is truncated or its contents contradict its header.
    #[error("{path}: corrupt: {what}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// The data are readable but unusable (NaN heights, all nodata, 1 × N...).
    #[error("{path}: {what}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

/// Load one DEM, or several `.hgt` tiles (or a folder of them) as a mosaic.
pub fn load(paths: &[PathBuf], opts: &LoadOptions) -> Result<Heightfield, DemError> {
    todo_loader(paths, opts)
}

#[allow(dead_code)]
fn todo_loader(paths: &[PathBuf], _opts: &LoadOptions) -> Result<Heightfield, DemError> {
    Err(DemError::Unsupported {
        path: paths.first().cloned().unwrap_or_default(),
        what: "loaders not written yet".into(),
    })
}

#[allow(dead_code)]
fn display(path: &Path) -> String {
    path.display().to_string()
}
