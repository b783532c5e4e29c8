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
//! Every tile is prepared once for its descriptor; the prepared tiles are held while they fit the
//! keyframe memory budget ([`super::MergeConfig::keyframe_memory_bytes`]), as a run's keyframes
//! are, and the others cut and prepared again for the candidates that need them. The map's
//! points stay in memory (bucketed, [`TileIndex`]). A map needing more than [`MAX_TILES`] tiles
//! even at a coarser grid is refused, not truncated.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Translation3, Vector3};
use rayon::prelude::*;

use super::session::{Session, keep_within};
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
    let mut reach: Vec<f64> = log.reach_m.iter().copied().flatten().collect();
    if reach.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: no keyframe of the log has a cloud to measure its range by",
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
pub(super) fn percentile_range(points: &[Point3<f64>], q: f64) -> Option<f64> {
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

/// A map's points bucketed for cutting tiles: a grid of edge [`Tiling::radius_m`], so that a
/// tile's points are in the 27 cells about its centre. Held by the map's session, which cuts and
/// prepares again the tiles it did not keep ([`Session::load`]).
pub(super) struct TileIndex {
    points: Vec<Point3<f64>>,
    buckets: BTreeMap<[i64; 3], Vec<u32>>,
    radius: f64,
    spacing: f64,
}

impl TileIndex {
    /// `points` bucketed for tiles of `radius` \[m\], their centres on a grid of `spacing` \[m\].
    fn new(points: Vec<Point3<f64>>, radius: f64, spacing: f64) -> Self {
        let mut buckets: BTreeMap<[i64; 3], Vec<u32>> = BTreeMap::new();
        for (i, p) in points.iter().enumerate() {
            buckets.entry(key(p, radius)).or_default().push(i as u32);
        }
        Self {
            points,
            buckets,
            radius,
            spacing,
        }
    }

    /// The edge of the grid whose occupied cells gave the tiles' centres \[m\]: a place of the
    /// map lies within about this distance of a tile's centre.
    pub(super) fn spacing_m(&self) -> f64 {
        self.spacing
    }

    /// The map's points within the radius of `centre`, in the centre's frame, in map order.
    fn cloud(&self, centre: &Point3<f64>) -> Vec<Point3<f64>> {
        let k = key(centre, self.radius);
        let r2 = self.radius * self.radius;
        let mut ids: Vec<u32> = Vec::new();
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(b) = self.buckets.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        ids.extend(
                            b.iter().filter(|&&i| {
                                (self.points[i as usize] - centre).norm_squared() <= r2
                            }),
                        );
                    }
                }
            }
        }
        ids.sort_unstable();
        ids.iter()
            .map(|&i| self.points[i as usize] - centre.coords)
            .collect()
    }

    /// The tile at `centre` prepared with `pair`; `None` when it has fewer than
    /// [`MIN_TILE_POINTS`] points or prepares without features or an ICP cloud.
    pub(super) fn prepare(&self, centre: &Point3<f64>, pair: &PairConfig) -> Option<PreparedFrame> {
        let cloud = self.cloud(centre);
        (cloud.len() >= MIN_TILE_POINTS)
            .then(|| prepare_frame(&cloud, pair).ok())
            .flatten()
            .filter(|f| f.has_features() && f.icp.is_some())
    }
}

/// The grid cell of `p` at edge `edge`.
fn key(p: &Point3<f64>, edge: f64) -> [i64; 3] {
    [p.x / edge, p.y / edge, p.z / edge].map(floor_i64)
}

/// Tiles prepared at a time while a map is cut: each is dropped (its descriptor kept) once the
/// kept ones fill the budget, so at most this many more are held: 16.
const TILES_AT_A_TIME: usize = 16;

/// The map `points` (read from `path`) as the prior session of a localisation: tiles by
/// `tiling` (its grid coarsened until at most [`MAX_TILES`] cells are occupied), each prepared
/// with `pair` (the log's registration settings), with its descriptor; the prepared tiles are
/// kept while they fit `budget_bytes` (by [`PreparedFrame::idle_bytes`]), the others cut and
/// prepared again when a candidate needs them. The session's
/// world is the map's frame, named `map`.
///
/// # Errors
/// [`Error::InvalidInput`] naming the file when no tile prepares (too few points per tile) or
/// the map needs more than [`MAX_TILES`] tiles.
pub(super) fn map_session(
    path: &Path,
    points: Vec<Point3<f64>>,
    tiling: Tiling,
    voxels: (f64, f64),
    (pair, budget_bytes): (&PairConfig, usize),
) -> Result<Session> {
    let mut spacing = tiling.spacing_m;
    let mut centres = tile_centres(&points, spacing);
    for _ in 0..8 {
        if centres.len() <= MAX_TILES {
            break;
        }
        spacing *= 1.5;
        centres = tile_centres(&points, spacing);
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
    let index = TileIndex::new(points, tiling.radius_m, spacing);
    let mut tiles: Vec<Tile> = Vec::new();
    let mut bytes = 0usize;
    for chunk in centres.chunks(TILES_AT_A_TIME) {
        let prepared: Vec<Option<PreparedFrame>> =
            chunk.par_iter().map(|c| index.prepare(c, pair)).collect();
        for (c, frame) in chunk.iter().zip(prepared) {
            let Some(frame) = frame else { continue };
            let descriptor = Descriptor::from_prepared(&frame);
            tiles.push((*c, keep_within(&mut bytes, budget_bytes, frame), descriptor));
        }
    }
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
    Ok(tiled_session(path, tiles, voxels, index))
}

/// A tile of a map: its centre, its prepared cloud while the budget held it, its descriptor.
type Tile = (Point3<f64>, Option<PreparedFrame>, Descriptor);

/// The session of `tiles`: one frame per tile at its centre, every one a keyframe; `index` cuts
/// again those not kept.
fn tiled_session(
    path: &Path,
    tiles: Vec<Tile>,
    (voxel_m, feature_voxel_m): (f64, f64),
    index: TileIndex,
) -> Session {
    let poses: Vec<Isometry3<f64>> = tiles
        .iter()
        .map(|(c, ..)| Isometry3::from_parts(Translation3::from(c.coords), Default::default()))
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
    let n = tiles.len();
    let (prepared, descriptors) = tiles.into_iter().map(|(_, f, d)| (f, d)).unzip();
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
        frames: prepared,
        descriptors,
        reach_m: vec![None; n],
        tiles: Some(index),
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
        let index = TileIndex::new(points.clone(), 3.0, 1.5);
        for c in &centres {
            let tile = index.cloud(c);
            let expected: Vec<Point3<f64>> = points
                .iter()
                .filter(|p| (*p - c).norm() <= 3.0)
                .map(|p| p - c.coords)
                .collect();
            assert_eq!(tile, expected);
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
