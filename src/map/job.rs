//! [`map_runs`]: the `mireg map` job, from its inputs to the file written: the checks on the
//! paths before anything is read, the map built ([`build_map_of_runs`]), refused when empty,
//! and written ([`write_map`]).

use std::path::{Path, PathBuf};

use super::build::{MapOptions, MapSummary, build_map_of_runs, write_map};
use crate::evaluate::registered_log;
use crate::io::atomic_file::{check_not_an_input, check_target};
use crate::io::cloud_file::CloudFileFormat;
use crate::{Error, Result};

/// Builds the map of `inputs` (`register` outputs; several: the outputs of one `mireg merge`)
/// and writes it to `output` (`.ply`, `.pcd` or `.npy`, by its extension), replacing an
/// existing file only when `force`. Returns what went into it.
///
/// # Errors
/// [`Error::InvalidInput`], before anything is read, for an output that is an input, exists
/// without `force`, or has no known extension, and for an input that is not a `register`
/// output; then [`build_map_of_runs`]'s errors; [`Error::InvalidInput`] naming the inputs when
/// the map would be empty (every point beyond the voxel grid: a larger voxel is needed; or no
/// cloud with a pose); the writer's errors, naming `output`.
pub fn map_runs(
    inputs: &[PathBuf],
    output: &Path,
    force: bool,
    opts: &MapOptions,
) -> Result<MapSummary> {
    let format = CloudFileFormat::from_path(output)?;
    check_not_an_input(output, inputs.iter().map(PathBuf::as_path), "the input")?;
    // Fail before reading the whole log, not after.
    check_target(output, force)?;
    for input in inputs {
        registered_log(input, "map", false)?;
    }
    let (map, summary) = build_map_of_runs(inputs, opts)?;
    if map.is_empty() {
        let input = inputs
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ");
        return Err(Error::InvalidInput(
            if summary.clouds_used > 0 && summary.points_out_of_range > 0 {
                format!(
                    "{input}: every point of the {} clouds with a pose ({} points) is out of the \
                     map's voxel grid at voxel {} m: choose a larger --voxel",
                    summary.clouds_used, summary.points_out_of_range, summary.voxel_m
                )
            } else {
                format!(
                    "{input}: no cloud on {} has a pose on {} ({} clouds without one): the map \
                     would be empty",
                    summary.cloud_topic, summary.pose_topic, summary.clouds_without_pose
                )
            },
        ));
    }
    // Written beside the target and moved into place when complete.
    write_map(map, summary.intensity, format, output, force)?;
    Ok(summary)
}
