//! A map file (`.ply`, `.pcd` or `.npy`, as `mireg map` writes them) as the prior of
//! [`super::localize`]: the map cut into overlapping tiles, each a keyframe of a session that has
//! no trajectory of its own.
//!
//! A tile is the map's points within [`Tiling::radius_m`] of a centre, in a frame at that centre
//! (the map's axes): about what a sensor there would see, so that the log's keyframes find their
//! tiles by appearance (the loop descriptors) and register to them prior-free, as two sessions'
//! keyframes do. The radius is the log's own reach (the median over its keyframes of their 90th
//! percentile range), the centres the mean points of the occupied cells of a grid whose edge is
//! half the radius, so that any place of the map lies well inside some tile.
//!
//! A link to a tile is verified as a loop is, but for the overlap the other way (the tile on the
//! scan), which asks less ([`MAP_MIN_REVERSE_FITNESS`]).
//!
//! NOTE: a map is rigid: its tiles have no drift between them, so their path length is 0 (the
//! links' agreement test allows no drift on the map's side, [`super::links::links_agree`]).
//! Every tile is prepared once and held while the log is linked; a map too large for that
//! (more than [`MAX_TILES`] tiles even at a coarser grid) is refused, not truncated.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Translation3, Vector3};
use rayon::prelude::*;

use super::session::Session;
use crate::geometry::floor_i64;
use crate::io::cloud_file::read_points;
use crate::io::format_err;
use crate::loops::Descriptor;
use crate::pipeline::{PairConfig, PreparedFrame, prepare_frame};
use crate::register::{SegFrame, Segment};
use crate::{Error, Result};

/// The most tiles a map is cut into: 2 000 (the grid's edge grows until they fit).
pub const MAX_TILES: usize = 2_000;

/// [`crate::loops::VerifyConfig::min_reverse_fitness`] of a link to a tile: 0.25. A tile holds
/// what every scan of the map saw, so one scan covers less of it than of another scan of the
/// place: on the KAIST03 keyframes, right links to tiles of a map of 10 of them fitted 0.87–0.97
/// forward and 0.35–0.44 the other way. The forward test (0.5), the inliers and the agreement
/// of [`super::MergeConfig::min_links`] links still apply.
pub const MAP_MIN_REVERSE_FITNESS: f64 = 0.25;

/// Fewest map points a tile needs to be kept: 100.
pub const MIN_TILE_POINTS: usize = 100;

/// How a map is cut into tiles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tiling {
    /// Points within this distance of a tile's centre belong to it \[m\].
    pub radius_m: f64,
    /// Edge of the grid whose occupied cells give the tiles' centres \[m\].
    pub spacing_m: f64,
}

/// Whether `path` names a map file (by extension: `.ply`, `.pcd`, `.npy`; any case) rather than a
/// `register` output.
pub(super) fn is_map_file(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| ["ply", "pcd", "npy"].contains(&e.to_ascii_lowercase().as_str()))
}

/// The points of the map file at `path`, read before anything else runs so that a bad map fails
/// at once.
pub(super) fn read_map(path: &Path) -> Result<Vec<Point3<f64>>> {
    let points = read_points(path)?;
    if points.len() < MIN_TILE_POINTS {
        return Err(format_err(
            path,
            format!(
                "the map holds {} points, fewer than a tile needs ({MIN_TILE_POINTS}); \
                 make one with `mireg map RUN.mcap -o MAP.ply`",
                points.len()
            ),
        ));
    }
    Ok(points)
}

/// The tiling that fits `log`'s keyframes (prepared): the radius their points reach (the median
/// over keyframes of each one's 90th percentile range), the grid at half of it.
pub(super) fn tiling_for(log: &Session) -> Result<Tiling> {
    let mut reach: Vec<f64> = log
        .frames
        .iter()
        .flatten()
        .filter_map(|f| percentile_range(&f.points, 0.9))
        .collect();
    if reach.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: no keyframe of the log kept a cloud to measure its range by",
            log.output.path.display()
        )));
    }
    reach.sort_by(f64::total_cmp);
    let radius_m = reach[reach.len() / 2];
    Ok(Tiling {
        radius_m,
        spacing_m: 0.5 * radius_m,
    })
}

/// The `q`-th quantile of the distances of `points` to the origin (`None` when empty).
fn percentile_range(points: &[Point3<f64>], q: f64) -> Option<f64> {
    let mut r: Vec<f64> = points.iter().map(|p| p.coords.norm()).collect();
    if r.is_empty() {
        return None;
    }
    r.sort_by(f64::total_cmp);
    Some(r[((r.len() - 1) as f64 * q).round() as usize])
}

/// The tiles' centres: the mean point of each occupied cell of a grid of `spacing` \[m\], in the
/// cells' order (the same on any thread count).
fn tile_centres(points: &[Point3<f64>], spacing: f64) -> Vec<Point3<f64>> {
    let mut cells: BTreeMap<[i64; 3], (Vector3<f64>, usize)> = BTreeMap::new();
    for p in points {
        let key = [p.x / spacing, p.y / spacing, p.z / spacing].map(floor_i64);
        let cell = cells.entry(key).or_insert((Vector3::zeros(), 0));
        cell.0 += p.coords;
        cell.1 += 1;
    }
    cells
        .values()
        .map(|(sum, n)| Point3::from(sum / *n as f64))
        .collect()
}

/// The map's points within `radius` of each centre, in the centre's frame, each tile's points in
/// map order; a bucket grid of edge `radius` answers each centre from its 27 cells.
fn tile_points(
    points: &[Point3<f64>],
    centres: &[Point3<f64>],
    radius: f64,
) -> Vec<Vec<Point3<f64>>> {
    let key = |p: &Point3<f64>| [p.x / radius, p.y / radius, p.z / radius].map(floor_i64);
    let mut buckets: BTreeMap<[i64; 3], Vec<u32>> = BTreeMap::new();
    for (i, p) in points.iter().enumerate() {
        buckets.entry(key(p)).or_default().push(i as u32);
    }
    let r2 = radius * radius;
    centres
        .par_iter()
        .map(|c| {
            let k = key(c);
            let mut ids: Vec<u32> = Vec::new();
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        if let Some(b) = buckets.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                            ids.extend(
                                b.iter()
                                    .filter(|&&i| (points[i as usize] - c).norm_squared() <= r2),
                            );
                        }
                    }
                }
            }
            ids.sort_unstable();
            ids.iter().map(|&i| points[i as usize] - c.coords).collect()
        })
        .collect()
}

/// The map `points` (read from `path`) as the prior session of a localisation: tiles by
/// `tiling` (its grid coarsened until at most [`MAX_TILES`] cells are occupied), each prepared
/// with `pair` (the log's registration settings) and kept, with its descriptor. The session's
/// world is the map's frame, named `map`.
///
/// # Errors
/// [`Error::InvalidInput`] naming the file when no tile prepares (too few points per tile) or
/// the map needs more than [`MAX_TILES`] tiles.
pub(super) fn map_session(
    path: &Path,
    points: &[Point3<f64>],
    tiling: Tiling,
    voxels: (f64, f64),
    pair: &PairConfig,
) -> Result<Session> {
    let mut spacing = tiling.spacing_m;
    let mut centres = tile_centres(points, spacing);
    for _ in 0..8 {
        if centres.len() <= MAX_TILES {
            break;
        }
        spacing *= 1.5;
        centres = tile_centres(points, spacing);
    }
    if centres.len() > MAX_TILES {
        return Err(format_err(
            path,
            format!(
                "the map needs {} tiles of {:.1} m, more than {MAX_TILES}: localise in a map of \
                 the part the log covers",
                centres.len(),
                tiling.radius_m
            ),
        ));
    }
    let clouds = tile_points(points, &centres, tiling.radius_m);
    let prepared: Vec<Option<PreparedFrame>> = clouds
        .par_iter()
        .map(|cloud| {
            (cloud.len() >= MIN_TILE_POINTS)
                .then(|| prepare_frame(cloud, pair).ok())
                .flatten()
                .filter(|f| !f.features.is_empty() && f.icp.is_some())
        })
        .collect();
    let tiles: Vec<(Point3<f64>, PreparedFrame)> = centres
        .into_iter()
        .zip(prepared)
        .filter_map(|(c, f)| f.map(|f| (c, f)))
        .collect();
    if tiles.is_empty() {
        return Err(format_err(
            path,
            format!(
                "no tile of the map ({:.2} m around each centre) holds enough points to register \
                 to",
                tiling.radius_m
            ),
        ));
    }
    Ok(tiled_session(path, tiles, voxels))
}

/// The session of `tiles` (centre, prepared cloud in the centre's frame): one frame per tile at
/// its centre, every one a keyframe, kept.
fn tiled_session(
    path: &Path,
    tiles: Vec<(Point3<f64>, PreparedFrame)>,
    (voxel_m, feature_voxel_m): (f64, f64),
) -> Session {
    let poses: Vec<Isometry3<f64>> = tiles
        .iter()
        .map(|(c, _)| Isometry3::from_parts(Translation3::from(c.coords), Default::default()))
        .collect();
    let frames: Vec<SegFrame> = poses
        .iter()
        .enumerate()
        .map(|(k, pose)| SegFrame {
            stamp_ns: k as i64,
            log_time: 0,
            publish_time: 0,
            pose: *pose,
            child_frame: format!("tile_{k}"),
            stats: serde_json::Value::Null,
        })
        .collect();
    let descriptors = tiles
        .iter()
        .map(|(_, f)| Descriptor::from_prepared(f))
        .collect();
    let n = tiles.len();
    Session {
        output: Segment {
            path: PathBuf::from(path),
            meta: BTreeMap::new(),
            kind: crate::register::CloudKind::Ros2,
            world_frame: "map".to_string(),
            frames,
        },
        name: path
            .file_stem()
            .map_or_else(|| "map".to_string(), |s| s.to_string_lossy().into_owned()),
        pose_topic: String::new(),
        namespace: String::new(),
        travelled_m: vec![0.0; n],
        poses,
        voxel_m,
        feature_voxel_m,
        keyframes: (0..n).collect(),
        frames: tiles.into_iter().map(|(_, f)| Some(f)).collect(),
        descriptors,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_hold_the_points_within_their_radius_in_their_own_frame() {
        // A 10 × 10 m floor, 0.25 m apart, and a brute-force oracle.
        let points: Vec<Point3<f64>> = (0..40)
            .flat_map(|i| (0..40).map(move |j| Point3::new(0.25 * i as f64, 0.25 * j as f64, 0.0)))
            .collect();
        let centres = tile_centres(&points, 2.5);
        assert_eq!(centres.len(), 16);
        let tiles = tile_points(&points, &centres, 3.0);
        for (c, tile) in centres.iter().zip(&tiles) {
            let expected: Vec<Point3<f64>> = points
                .iter()
                .filter(|p| (*p - c).norm() <= 3.0)
                .map(|p| p - c.coords)
                .collect();
            assert_eq!(tile, &expected);
        }
    }

    #[test]
    fn map_files_are_told_by_extension() {
        for (name, map) in [
            ("a.ply", true),
            ("a.PCD", true),
            ("dir/a.npy", true),
            ("a.mcap", false),
            ("bag", false),
        ] {
            assert_eq!(is_map_file(Path::new(name)), map, "{name}");
        }
    }

    #[test]
    fn the_range_quantile_is_of_the_distances_to_the_origin() {
        let points: Vec<Point3<f64>> = (1..=10).map(|k| Point3::new(0.0, k as f64, 0.0)).collect();
        assert_eq!(percentile_range(&points, 0.9), Some(9.0));
        assert_eq!(percentile_range(&[], 0.9), None);
    }
}
