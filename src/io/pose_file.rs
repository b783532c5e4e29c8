//! Pose file readers: a 4×4 text matrix, Redwood/3DMatch `.log` files (`gt.log`,
//! `trajectory.log`) and the Stanford bunny `bun.conf`.
//!
//! Every pose is returned as an `Isometry3<f64>` (translation in the file's units, metres for
//! all data sets mireg uses). Rotations are validated: every entry of RᵀR − I must be within
//! [`ROTATION_TOLERANCE`] and det R must be
//! positive; the nearest rotation (polar decomposition) is then used.

use std::path::Path;

use nalgebra::{
    Isometry3, Matrix3, Matrix4, Matrix6, Quaternion, Rotation3, Translation3, UnitQuaternion,
    Vector3,
};

use super::{format_err, read_text};
use crate::Result;

/// Largest allowed |RᵀR − I| entry for a rotation read from a pose file (unitless). Accepted
/// rotations are snapped to the nearest true rotation.
///
/// NOTE: loose because published ground truth is not orthonormal to 1e-6: over the 8 3DMatch +
/// 8 3DLoMatch scenes, 3364 of 3625 `gt.log` records exceed 1e-6 and the worst
/// (7-scenes-redkitchen, pair 0 39) reaches 5.1e-4; the redkitchen `gt.npy` reaches 7.1e-5.
pub const ROTATION_TOLERANCE: f64 = 1e-3;

/// Largest allowed deviation of a `bun.conf` quaternion's norm from 1 (unitless); the file
/// stores six significant digits.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-4;

fn parse_numbers(line: &str) -> std::result::Result<Vec<f64>, String> {
    line.split_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .map_err(|_| format!("'{t}' is not a number"))
        })
        .collect()
}

/// Converts a homogeneous 4×4 matrix into an isometry, checking the bottom row is `0 0 0 1`,
/// the translation is finite and the rotation block is a proper rotation.
fn isometry_from_matrix(
    m: &Matrix4<f64>,
    tolerance: f64,
) -> std::result::Result<Isometry3<f64>, String> {
    let bottom = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)]];
    if bottom
        .iter()
        .zip([0.0, 0.0, 0.0, 1.0])
        .any(|(a, b)| (a - b).abs() > 1e-12)
    {
        return Err(format!("bottom row is {bottom:?}, expected [0, 0, 0, 1]"));
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let t: Vector3<f64> = m.fixed_view::<3, 1>(0, 3).into_owned();
    isometry_from_rotation_translation(&r, &t, tolerance)
}

/// `[R | t]` as an isometry: entries finite, `R` orthonormal within `tolerance` with det > 0,
/// then snapped to the nearest rotation. The error text names what is wrong.
pub(crate) fn isometry_from_rotation_translation(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    tolerance: f64,
) -> std::result::Result<Isometry3<f64>, String> {
    if !r.iter().chain(t.iter()).all(|v| v.is_finite()) {
        return Err("matrix has a non-finite entry".into());
    }
    let err = (r.transpose() * r - Matrix3::identity()).abs().max();
    if err > tolerance {
        return Err(format!(
            "rotation block is not orthonormal: max |RᵀR − I| = {err:.3e} > {tolerance:e}"
        ));
    }
    if r.determinant() <= 0.0 {
        return Err("rotation block has negative determinant (a reflection)".into());
    }
    // Nearest rotation in the Frobenius norm: U·Vᵀ of the SVD (det > 0 was checked above).
    let svd = r.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err("rotation block: SVD failed".into());
    };
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(u * v_t));
    let q = UnitQuaternion::new_normalize(q.into_inner());
    Ok(Isometry3::from_parts(Translation3::from(*t), q))
}

/// Parses a 4×4 homogeneous transform written as 16 whitespace-separated numbers in
/// row-major order (line breaks are not significant); `path` is used only in errors.
///
/// # Errors
/// [`crate::Error::Format`] if there are not exactly 16 numbers, the bottom row is not `0 0 0 1`, or
/// the rotation block is not a rotation within [`ROTATION_TOLERANCE`].
pub fn parse_matrix4(text: &str, path: &Path) -> Result<Isometry3<f64>> {
    let v = parse_numbers(text).map_err(|d| format_err(path, format!("4×4 matrix: {d}")))?;
    if v.len() != 16 {
        return Err(format_err(
            path,
            format!("4×4 matrix: expected 16 numbers, found {}", v.len()),
        ));
    }
    isometry_from_matrix(&Matrix4::from_row_slice(&v), ROTATION_TOLERANCE)
        .map_err(|d| format_err(path, format!("4×4 matrix: {d}")))
}

/// Reads a 4×4 text matrix file (see [`parse_matrix4`]).
///
/// # Errors
/// [`crate::Error::Io`] if the file cannot be read, else as [`parse_matrix4`].
pub fn read_matrix4(path: &Path) -> Result<Isometry3<f64>> {
    parse_matrix4(&read_text(path)?, path)
}

/// One record of a Redwood/3DMatch `.log` file: a header line `i j n` and a 4×4 matrix.
///
/// The meaning of `pose` depends on the file: in a 3DMatch `gt.log` it maps fragment `j` into
/// fragment `i` (`i_from_j`, i.e. target = `i`, source = `j`); in a Redwood
/// `trajectory.log` (header `k k k+1`) it is camera `k`'s pose, `world_from_camera_k`.
#[derive(Debug, Clone, PartialEq)]
pub struct LogRecord {
    /// First id of the header line (the target fragment in `gt.log`).
    pub i: usize,
    /// Second id of the header line (the source fragment in `gt.log`).
    pub j: usize,
    /// Third number of the header line (number of fragments in `gt.log`).
    pub n: usize,
    /// The record's transform (see the type docs for its frames).
    pub pose: Isometry3<f64>,
}

/// A record as read: header ids `i j n`, the header's line number, the matrix row-major.
type RawRecord = ([usize; 3], usize, Vec<f64>);

/// Records of a Redwood/3DMatch `.log`-style file: a header line of three integers followed by
/// `rows` lines of `rows` numbers each (a 4×4 transform in `gt.log`, a 6×6 information matrix in
/// `gt.info`). Blank lines are ignored; `what` names the matrix and `path` the file in errors.
fn parse_records(text: &str, path: &Path, rows: usize, what: &str) -> Result<Vec<RawRecord>> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l))
        .filter(|(_, l)| !l.trim().is_empty());
    let mut records = Vec::new();
    while let Some((header_no, header)) = lines.next() {
        let ids: Option<Vec<usize>> = header.split_whitespace().map(|t| t.parse().ok()).collect();
        let [i, j, n] = ids.as_deref().unwrap_or_default() else {
            return Err(format_err(
                path,
                format!(
                    "log line {header_no}: expected a record header of 3 integers, got '{header}'"
                ),
            ));
        };
        let mut m = Vec::with_capacity(rows * rows);
        for row in 0..rows {
            let (no, line) = lines.next().ok_or_else(|| {
                format_err(
                    path,
                    format!("log record '{i} {j} {n}' (line {header_no}): file ends after {row} of {rows} {what} rows"),
                )
            })?;
            let v =
                parse_numbers(line).map_err(|d| format_err(path, format!("log line {no}: {d}")))?;
            if v.len() != rows {
                return Err(format_err(
                    path,
                    format!(
                        "log line {no}: expected {rows} numbers in {what} row, found {}",
                        v.len()
                    ),
                ));
            }
            m.extend(v);
        }
        records.push(([*i, *j, *n], header_no, m));
    }
    Ok(records)
}

/// Parses a Redwood/3DMatch `.log` file: records of a header line of three integers followed
/// by four lines of four numbers. Blank lines are ignored; `path` is used only in errors.
///
/// # Errors
/// [`crate::Error::Format`] naming the line for a malformed header or matrix row, a file that ends
/// inside a record, or an invalid transform (rotation checked within
/// [`ROTATION_TOLERANCE`]).
pub fn parse_log(text: &str, path: &Path) -> Result<Vec<LogRecord>> {
    parse_records(text, path, 4, "matrix")?
        .into_iter()
        .map(|([i, j, n], header_no, m)| {
            let pose = isometry_from_matrix(&Matrix4::from_row_slice(&m), ROTATION_TOLERANCE)
                .map_err(|d| {
                    format_err(
                        path,
                        format!("log record '{i} {j} {n}' (line {header_no}): {d}"),
                    )
                })?;
            Ok(LogRecord { i, j, n, pose })
        })
        .collect()
}

/// One record of a Redwood/3DMatch `gt.info` file: the information matrix of pair `(i, j)`.
#[derive(Debug, Clone, PartialEq)]
pub struct InfoRecord {
    /// Target fragment id (as in `gt.log`).
    pub i: usize,
    /// Source fragment id.
    pub j: usize,
    /// Number of fragments.
    pub n: usize,
    /// Choi et al.'s 6×6 information matrix Λ, ordered (translation, rotation as the quaternion's
    /// vector part); Λ₁₁ is the number of point correspondences it was built from.
    pub information: Matrix6<f64>,
}

/// Parses a Redwood/3DMatch `gt.info` file: records of a header line `i j n` followed by six
/// lines of six numbers. Blank lines are ignored; `path` is used only in errors.
///
/// # Errors
/// [`crate::Error::Format`] naming the line for a malformed header or row, a file that ends
/// inside a record, a non-finite entry, an asymmetric matrix or Λ₁₁ ≤ 0 (it divides the error).
pub fn parse_info(text: &str, path: &Path) -> Result<Vec<InfoRecord>> {
    parse_records(text, path, 6, "information matrix")?
        .into_iter()
        .map(|([i, j, n], header_no, m)| {
            let information = Matrix6::from_row_slice(&m);
            let bad = |d: &str| {
                format_err(
                    path,
                    format!("info record '{i} {j} {n}' (line {header_no}): {d}"),
                )
            };
            if !m.iter().all(|v| v.is_finite()) {
                return Err(bad("matrix has a non-finite entry"));
            }
            let scale = information.abs().max();
            if (information - information.transpose()).abs().max() > 1e-6 * scale {
                return Err(bad("matrix is not symmetric"));
            }
            if information[(0, 0)] <= 0.0 {
                return Err(bad(&format!(
                    "Λ₁₁ = {} is not positive (it is the number of correspondences)",
                    information[(0, 0)]
                )));
            }
            Ok(InfoRecord {
                i,
                j,
                n,
                information,
            })
        })
        .collect()
}

/// Reads a Redwood/3DMatch `gt.info` file (see [`parse_info`]).
///
/// # Errors
/// [`crate::Error::Io`] if the file cannot be read, else as [`parse_info`].
pub fn read_info(path: &Path) -> Result<Vec<InfoRecord>> {
    parse_info(&read_text(path)?, path)
}

/// Reads a Redwood/3DMatch `.log` file (see [`parse_log`]).
///
/// # Errors
/// [`crate::Error::Io`] if the file cannot be read, else as [`parse_log`].
pub fn read_log(path: &Path) -> Result<Vec<LogRecord>> {
    parse_log(&read_text(path)?, path)
}

/// The first record whose header starts with `i j`, or `None` if the pair is absent.
/// For a 3DMatch `gt.log`, its `pose` is `i_from_j` (fragment `j` into fragment `i`).
pub fn find_log_pair(records: &[LogRecord], i: usize, j: usize) -> Option<&LogRecord> {
    records.iter().find(|r| r.i == i && r.j == j)
}

/// One `bmesh` line of a Stanford `bun.conf`.
#[derive(Debug, Clone, PartialEq)]
pub struct BunnyScan {
    /// The scan's file name as written in the conf file, e.g. `bun045.ply`.
    pub file: String,
    /// Maps scan coordinates into the common (world) frame, metres.
    pub world_from_scan: Isometry3<f64>,
}

/// Parses a Stanford `bun.conf`: lines `bmesh FILE tx ty tz qx qy qz qw`; `camera` lines and
/// blank lines are ignored; `path` is used only in errors.
///
/// Convention (checked on the real scans, see the `io_real_data` test): a scan point x maps
/// to `world = R(q)ᵀ·x + t`, with R the rotation of the unit quaternion (qx, qy, qz, qw) —
/// *not* the obvious `R·x + t`. So `world_from_scan` has rotation q⁻¹ and translation t.
///
/// # Errors
/// [`crate::Error::Format`] naming the line for an unknown keyword, a wrong number of values, or a
/// quaternion whose norm is not 1 within [`QUATERNION_NORM_TOLERANCE`].
pub fn parse_bunny_conf(text: &str, path: &Path) -> Result<Vec<BunnyScan>> {
    let mut scans = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let no = k + 1;
        let mut words = line.split_whitespace();
        match words.next() {
            None | Some("camera") => continue,
            Some("bmesh") => {}
            Some(other) => {
                return Err(format_err(
                    path,
                    format!("conf line {no}: unknown keyword '{other}'"),
                ));
            }
        }
        let file = words.next().ok_or_else(|| {
            format_err(path, format!("conf line {no}: bmesh without a file name"))
        })?;
        let rest: Vec<&str> = words.collect();
        let v = parse_numbers(&rest.join(" "))
            .map_err(|d| format_err(path, format!("conf line {no} ({file}): {d}")))?;
        let [tx, ty, tz, qx, qy, qz, qw] = v[..] else {
            return Err(format_err(
                path,
                format!(
                    "conf line {no} ({file}): expected 7 numbers (tx ty tz qx qy qz qw), found {}",
                    v.len()
                ),
            ));
        };
        let q = Quaternion::new(qw, qx, qy, qz);
        if (q.norm() - 1.0).abs() > QUATERNION_NORM_TOLERANCE || !q.norm().is_finite() {
            return Err(format_err(
                path,
                format!(
                    "conf line {no} ({file}): quaternion norm {} is not 1",
                    q.norm()
                ),
            ));
        }
        let r = UnitQuaternion::from_quaternion(q);
        scans.push(BunnyScan {
            file: file.to_string(),
            world_from_scan: Isometry3::from_parts(Translation3::new(tx, ty, tz), r.inverse()),
        });
    }
    Ok(scans)
}

/// `world_from_scan` for `scan_file` (e.g. `"bun045.ply"`) from the text of a `bun.conf`
/// (convention in [`parse_bunny_conf`]); errors name the file `bun.conf`.
///
/// To register scan A (source) onto scan B (target), the ground truth is
/// `target_from_source = bunny_pose(conf, B)?.inverse() * bunny_pose(conf, A)?`.
///
/// # Errors
/// As [`parse_bunny_conf`], or [`crate::Error::Format`] if the conf has no `bmesh` line for the scan.
pub fn bunny_pose(conf_text: &str, scan_file: &str) -> Result<Isometry3<f64>> {
    let path = Path::new("bun.conf");
    parse_bunny_conf(conf_text, path)?
        .into_iter()
        .find(|s| s.file == scan_file)
        .map(|s| s.world_from_scan)
        .ok_or_else(|| format_err(path, format!("no bmesh line for '{scan_file}'")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Error;
    use nalgebra::Point3;

    fn p() -> &'static Path {
        Path::new("pose.txt")
    }

    fn expect_format_err<T: std::fmt::Debug>(r: Result<T>, needle: &str) {
        match r {
            Err(e @ Error::Format { .. }) => {
                let msg = e.to_string();
                assert!(msg.contains(needle), "expected '{needle}' in '{msg}'");
            }
            other => panic!("expected a format error containing '{needle}', got {other:?}"),
        }
    }

    /// A 90° rotation about z (x → y) and translation (1, 2, 3), written row-major.
    const ROT_Z90: &str = "0 -1 0 1\n1 0 0 2\n0 0 1 3\n0 0 0 1\n";

    #[test]
    fn matrix4_maps_points_as_written() {
        let iso = parse_matrix4(ROT_Z90, p()).unwrap();
        // R·(1, 0, 0) + t = (0, 1, 0) + (1, 2, 3)
        let q = iso * Point3::new(1.0, 0.0, 0.0);
        assert!((q - Point3::new(1.0, 3.0, 3.0)).norm() < 1e-12, "{q}");
        // Same numbers on one line work too.
        let one_line = ROT_Z90.replace('\n', " ");
        assert_eq!(parse_matrix4(&one_line, p()).unwrap(), iso);
    }

    #[test]
    fn matrix4_rejections() {
        expect_format_err(
            parse_matrix4("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0", p()),
            "expected 16 numbers, found 15",
        );
        expect_format_err(
            parse_matrix4("1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1", p()),
            "bottom row",
        );
        expect_format_err(
            parse_matrix4("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 x", p()),
            "'x' is not a number",
        );
        // Scaled: not orthonormal.
        expect_format_err(
            parse_matrix4("1.001 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", p()),
            "not orthonormal",
        );
        // Reflection: orthonormal but det = −1.
        expect_format_err(
            parse_matrix4("1 0 0 0 0 1 0 0 0 0 -1 0 0 0 0 1", p()),
            "reflection",
        );
        // Within tolerance: accepted, and re-normalised.
        let iso = parse_matrix4("1.0000001 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", p()).unwrap();
        assert!((iso.rotation.into_inner().norm() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn log_records_and_pair_lookup() {
        let text =
            format!("0\t 1\t 3\t\n{ROT_Z90}\n\n2 5 3\n1 0 0 0.5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
        let recs = parse_log(&text, Path::new("gt.log")).unwrap();
        assert_eq!(recs.len(), 2);
        assert_eq!((recs[1].i, recs[1].j, recs[1].n), (2, 5, 3));
        let r = find_log_pair(&recs, 2, 5).unwrap();
        assert_eq!(r.pose.translation.vector, Vector3::new(0.5, 0.0, 0.0));
        let r = find_log_pair(&recs, 0, 1).unwrap();
        let q = r.pose * Point3::new(0.0, 1.0, 0.0);
        assert!((q - Point3::new(0.0, 2.0, 3.0)).norm() < 1e-12, "{q}");
        assert!(find_log_pair(&recs, 1, 0).is_none());
    }

    #[test]
    fn log_rejections_name_the_line() {
        let g = Path::new("gt.log");
        expect_format_err(
            parse_log("0 1\n", g),
            "gt.log: log line 1: expected a record header",
        );
        expect_format_err(
            parse_log("0 1 2\n1 0 0 0\n0 1 0 0\n", g),
            "ends after 2 of 4",
        );
        expect_format_err(
            parse_log("0 1 2\n1 0 0 0\n0 1 0\n0 0 1 0\n0 0 0 1\n", g),
            "log line 3: expected 4 numbers",
        );
        expect_format_err(
            parse_log("0 1 2\n2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", g),
            "(line 1): rotation block is not orthonormal",
        );
        expect_format_err(
            parse_log("0 1 2\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 2\n", g),
            "bottom row",
        );
    }

    /// The first record of 3DMatch 7-scenes-redkitchen `gt.info`, as the file writes it.
    const INFO_0_1: &str = "0\t 1\t 60\t
 5.00000000e+03\t  0.00000000e+00\t  0.00000000e+00\t  0.00000000e+00\t  1.08436729e+04\t  1.26195044e+03\t
 0.00000000e+00\t  5.00000000e+03\t  0.00000000e+00\t -1.08436729e+04\t  0.00000000e+00\t -1.24858826e+03\t
 0.00000000e+00\t  0.00000000e+00\t  5.00000000e+03\t -1.26195044e+03\t  1.24858826e+03\t  0.00000000e+00\t
 0.00000000e+00\t -1.08436729e+04\t -1.26195044e+03\t  2.66481113e+04\t -3.41289291e+01\t  2.59759790e+03\t
 1.08436729e+04\t  0.00000000e+00\t  1.24858826e+03\t -3.41289291e+01\t  2.71010840e+04\t  3.71150854e+03\t
 1.26195044e+03\t -1.24858826e+03\t  0.00000000e+00\t  2.59759790e+03\t  3.71150854e+03\t  3.56940430e+03\t
";

    #[test]
    fn info_records_read_row_major() {
        let text = format!("{INFO_0_1}\n{}", INFO_0_1.replacen("0\t 1\t", "2\t 7\t", 1));
        let recs = parse_info(&text, Path::new("gt.info")).unwrap();
        assert_eq!(recs.len(), 2);
        assert_eq!((recs[0].i, recs[0].j, recs[0].n), (0, 1, 60));
        assert_eq!((recs[1].i, recs[1].j), (2, 7));
        let m = &recs[0].information;
        assert_eq!(m[(0, 0)], 5000.0);
        assert_eq!(m[(0, 4)], 1.08436729e+04);
        assert_eq!(m[(1, 3)], -1.08436729e+04);
        assert_eq!(m[(5, 5)], 3.56940430e+03);
    }

    #[test]
    fn info_rejections_name_the_record() {
        let g = Path::new("gt.info");
        let rows: Vec<&str> = INFO_0_1.lines().collect();
        expect_format_err(
            parse_info(&rows[..4].join("\n"), g),
            "ends after 3 of 6 information matrix rows",
        );
        let short = INFO_0_1.replacen("5.00000000e+03\t  0.00000000e+00\t", "5.0e+03\t", 1);
        expect_format_err(
            parse_info(&short, g),
            "log line 2: expected 6 numbers in information matrix row, found 5",
        );
        let asymmetric = INFO_0_1.replacen("1.08436729e+04", "1.0e+04", 1);
        expect_format_err(
            parse_info(&asymmetric, g),
            "info record '0 1 60' (line 1): matrix is not symmetric",
        );
        let zero = INFO_0_1.replacen(" 5.00000000e+03", " 0.00000000e+00", 1);
        expect_format_err(parse_info(&zero, g), "is not positive");
        let nan = INFO_0_1.replacen("3.56940430e+03", "nan", 1);
        expect_format_err(parse_info(&nan, g), "non-finite");
    }

    #[test]
    fn bunny_conf_uses_transposed_rotation() {
        // q = (qx, qy, qz, qw) = (0, 0, sin 45°, cos 45°): R(q) rotates +90° about z.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let conf = format!(
            "camera 0 0 0 0 0 0 1\nbmesh a.ply 0 0 0 0 0 0 1\nbmesh b.ply 1 2 3 0 0 {s} {s}\n"
        );
        let a = bunny_pose(&conf, "a.ply").unwrap();
        assert_eq!(a, Isometry3::identity());
        let b = bunny_pose(&conf, "b.ply").unwrap();
        // world = R(q)ᵀ·x + t: Rᵀ rotates −90° about z, so (1, 0, 0) → (0, −1, 0).
        let w = b * Point3::new(1.0, 0.0, 0.0);
        assert!((w - Point3::new(1.0, 1.0, 3.0)).norm() < 1e-12, "{w}");
        // target_from_source between the two scans.
        let a_from_b = a.inverse() * b;
        assert!((a_from_b * Point3::origin() - Point3::new(1.0, 2.0, 3.0)).norm() < 1e-12);
    }

    #[test]
    fn bunny_conf_rejections() {
        let c = Path::new("bun.conf");
        expect_format_err(
            bunny_pose("bmesh a.ply 0 0 0 0 0 0 1\n", "z.ply"),
            "bun.conf: no bmesh line for 'z.ply'",
        );
        expect_format_err(
            parse_bunny_conf("bmesh a.ply 0 0 0 0 0 1\n", c),
            "(a.ply): expected 7 numbers",
        );
        expect_format_err(
            parse_bunny_conf("bmesh a.ply 0 0 0 0 0 0.5 0.5\n", c),
            "quaternion norm",
        );
        expect_format_err(
            parse_bunny_conf("mesh a.ply 0 0 0 0 0 0 1\n", c),
            "unknown keyword 'mesh'",
        );
        expect_format_err(parse_bunny_conf("bmesh\n", c), "without a file name");
    }
}
