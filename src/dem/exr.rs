//! OpenEXR heightmaps (the `exr` crate): one float16 or float32 channel of
//! heights in metres, NaN for nodata. With several channels the height is
//! the one named `Y` (luminance), `Z` (depth), `R` or `height`, in that order;
//! several channels without one of these names are refused rather than
//! guessed at. One layer only. No georeference: 1 m spacing unless overridden.

use std::path::Path;

use ::exr::prelude::{AnyChannel, FlatSamples, ReadChannels, ReadLayers};

use super::{DemError, check_expansion, corrupt, file_name, io_error, sample_count, unsupported};
use crate::heightfield::Heightfield;

/// Channel names that mean "the height", most preferred first.
const PREFERRED: [&str; 4] = ["Y", "Z", "R", "height"];

/// Read an EXR heightmap.
pub(super) fn load(path: &Path) -> Result<Heightfield, DemError> {
    let file_len = std::fs::metadata(path).map_err(|e| io_error(path, e))?.len();
    // Check the sizes the headers promise before the decoder allocates for
    // them: no EXR compression shrinks data by more than a few thousand to
    // one, so a header promising more is corrupt.
    let meta = ::exr::meta::MetaData::read_from_file(path, true).map_err(|e| exr_error(path, e))?;
    for header in &meta.headers {
        let (w, h) = (header.layer_size.0, header.layer_size.1);
        sample_count(path, w, h)?;
        let bytes_per_pixel = header.channels.bytes_per_pixel as u64;
        check_expansion((w, h), bytes_per_pixel.max(4), file_len).map_err(|e| corrupt(path, e))?;
    }
    let image = ::exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .pedantic()
        .non_parallel()
        .from_file(path)
        .map_err(|e| exr_error(path, e))?;

    let layers = image.layer_data;
    if layers.len() != 1 {
        return Err(unsupported(path, format!("{} layers; a DEM needs one", layers.len())));
    }
    let layer = &layers[0];
    let (w, h) = (layer.size.0, layer.size.1);
    let n = sample_count(path, w, h)?;
    let channels = &layer.channel_data.list;
    let channel: &AnyChannel<FlatSamples> = match channels.len() {
        0 => return Err(corrupt(path, "the image has no channels")),
        1 => &channels[0],
        _ => PREFERRED
            .iter()
            .find_map(|want| {
                channels
                    .iter()
                    .find(|c| c.name.eq(want))
                    .or_else(|| channels.iter().find(|c| c.name.eq_case_insensitive(want)))
            })
            .ok_or_else(|| {
                let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
                unsupported(
                    path,
                    format!(
                        "{} channels ({}) and none named Y, Z, R or height; a DEM needs one",
                        channels.len(),
                        names.join(", ")
                    ),
                )
            })?,
    };
    if channel.sampling.0 != 1 || channel.sampling.1 != 1 {
        return Err(unsupported(path, format!("channel {} is subsampled", channel.name)));
    }
    let heights: Vec<f32> = match &channel.sample_data {
        FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::U32(_) => {
            return Err(unsupported(
                path,
                format!("channel {} holds 32-bit unsigned integers; heights need float16 or float32", channel.name),
            ));
        }
    };
    if heights.len() != n {
        return Err(corrupt(path, format!("expected {n} samples for {w} × {h}, found {}", heights.len())));
    }
    Ok(Heightfield::ungeoreferenced(w, h, heights, file_name(path)))
}

fn exr_error(path: &Path, e: ::exr::error::Error) -> DemError {
    use ::exr::error::Error;
    match e {
        Error::NotSupported(what) => unsupported(path, format!("OpenEXR: {what}")),
        Error::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            corrupt(path, format!("the OpenEXR file ends early (truncated?): {io}"))
        }
        Error::Io(io) => io_error(path, io),
        Error::Invalid(what) => corrupt(path, format!("OpenEXR: {what}")),
        Error::Aborted => corrupt(path, "OpenEXR: reading was aborted"),
    }
}
