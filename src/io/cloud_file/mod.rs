//! Point cloud file readers: PLY, PCD (v0.7), NumPy `.npy` and KITTI velodyne `.bin`; and
//! writers of PLY, PCD and `.npy` ([`CloudFileFormat::write`]: binary `f32` `x y z`, with an
//! optional `intensity`), used by `mireg map`.
//!
//! Every reader returns the x, y, z coordinates as `Point3<f64>` in the file's own units
//! (metres for all the data sets mireg is used with) and in file order.
//!
//! **Non-finite points are dropped:** a point with a NaN or ±Inf coordinate (PCL writes NaN
//! for invalid returns in organised clouds) is skipped silently, so the result can be shorter
//! than the point count in the header.
//!
//! **Far points are dropped and counted** by [`read_cloud`] (and [`read_points`]): a point with a
//! coordinate of magnitude [`crate::io::codec::MAX_COORDINATE_M`] (10⁶ m) or more, as every log
//! decoder drops it, so that one glitch cannot stretch a cloud past what the voxel grids index.
//!
//! Malformed input — a bad header, a missing `x`/`y`/`z`, an unsupported type, truncated data,
//! or counts larger than the data could hold — is reported as [`Error::Format`] naming the file
//! and the problem. Allocation is bounded by the input size, never by a count in a header.

use std::path::Path;

use nalgebra::Point3;

use super::format_err;
use super::scalar::Scalar;
use crate::{Error, Result};

mod kitti;
mod npy;
mod pcd;
mod ply;

pub use kitti::parse_kitti_bin;
pub use npy::{parse_npy, write_npy};
pub use pcd::{lzf_decompress, parse_pcd, write_pcd};
pub use ply::{parse_ply, write_ply};

/// A point cloud file format mireg writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CloudFileFormat {
    /// `.ply`: binary little-endian PLY, `float` vertex properties.
    Ply,
    /// `.pcd`: PCD v0.7, `DATA binary`, `F 4` fields.
    Pcd,
    /// `.npy`: NumPy format 1.0, `<f4`, shape (N, 3) or (N, 4).
    Npy,
}

impl CloudFileFormat {
    /// The format of `path` by its extension (case-insensitive).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] naming the file for any other extension.
    pub fn from_path(path: &Path) -> Result<Self> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        match ext.as_str() {
            "ply" => Ok(Self::Ply),
            "pcd" => Ok(Self::Pcd),
            "npy" => Ok(Self::Npy),
            _ => Err(Error::InvalidInput(format!(
                "{}: unsupported output extension '.{ext}' (expected .ply, .pcd or .npy)",
                path.display()
            ))),
        }
    }

    /// Writes `rows` (flat `f32`: `x y z` in metres, then intensity when `cols` is 4).
    ///
    /// # Errors
    /// The writer's I/O errors.
    ///
    /// # Panics
    /// If `cols` is not 3 or 4 (a programming error).
    pub fn write(
        self,
        rows: &[f32],
        cols: usize,
        out: &mut impl std::io::Write,
    ) -> std::io::Result<()> {
        assert!(cols == 3 || cols == 4, "3 or 4 columns");
        match self {
            Self::Ply => write_ply(rows, cols, out),
            Self::Pcd => write_pcd(rows, cols, out),
            Self::Npy => write_npy(rows, cols, out),
        }
    }
}

/// Writes `values` as little-endian `f32`, buffered in blocks.
fn write_f32_le(values: &[f32], out: &mut impl std::io::Write) -> std::io::Result<()> {
    let mut buf = Vec::with_capacity(4096 * 4);
    for block in values.chunks(4096) {
        buf.clear();
        block.iter().for_each(|v| buf.extend(v.to_le_bytes()));
        out.write_all(&buf)?;
    }
    Ok(())
}

/// The points of a cloud file ([`read_cloud`]).
#[derive(Debug, Clone, PartialEq)]
pub struct CloudFilePoints {
    /// Finite points within the bound, in file order (the file's units: metres).
    pub points: Vec<Point3<f64>>,
    /// Points dropped because a coordinate's magnitude was at least
    /// [`crate::io::codec::MAX_COORDINATE_M`].
    pub num_dropped_far: usize,
}

/// [`read_points`], with the number of far points dropped.
///
/// # Errors
/// As [`read_points`].
pub fn read_cloud(path: &Path) -> Result<CloudFilePoints> {
    let mut points = read_points_unbounded(path)?;
    let before = points.len();
    points.retain(|p| crate::io::codec::within_bound(p.x, p.y, p.z));
    Ok(CloudFilePoints {
        num_dropped_far: before - points.len(),
        points,
    })
}

/// Reads the points of a cloud file, choosing the format by extension (case-insensitive):
/// `.ply`, `.pcd`, `.npy`, or `.bin` (KITTI velodyne: little-endian f32 x, y, z, intensity).
///
/// The whole file is read into memory first. Non-finite points and far points (a coordinate of
/// magnitude 10⁶ m or more) are dropped (see the module docs; [`read_cloud`] counts the far
/// ones).
///
/// # Errors
/// [`Error::Io`] if the file cannot be read; [`Error::Format`] for an unknown extension or
/// malformed content.
pub fn read_points(path: &Path) -> Result<Vec<Point3<f64>>> {
    read_cloud(path).map(|c| c.points)
}

/// [`read_points`] keeping far points.
fn read_points_unbounded(path: &Path) -> Result<Vec<Point3<f64>>> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let parse: Parser = match ext.as_str() {
        "ply" => parse_ply,
        "pcd" => parse_pcd,
        "npy" => parse_npy,
        "bin" => parse_kitti_bin,
        _ => {
            return Err(format_err(
                path,
                format!(
                    "unsupported point cloud extension '.{ext}' (expected .ply, .pcd, .npy or .bin)"
                ),
            ));
        }
    };
    let bytes = crate::io::input_file::read_regular(path)?;
    parse(&bytes, path)
}

/// A format parser: bytes and the path for error messages in, points out.
type Parser = fn(&[u8], &Path) -> Result<Vec<Point3<f64>>>;

/// Appends `(x, y, z)` unless a coordinate is NaN or infinite.
fn push_finite(points: &mut Vec<Point3<f64>>, x: f64, y: f64, z: f64) {
    if x.is_finite() && y.is_finite() && z.is_finite() {
        points.push(Point3::new(x, y, z));
    }
}

/// Byte order of binary data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Endian {
    Little,
    Big,
}

impl Scalar {
    /// Decodes one value from exactly `self.size()` bytes.
    fn decode(self, b: &[u8], endian: Endian) -> f64 {
        self.read(b, endian == Endian::Big)
    }

    /// Parses one ASCII value of this type (integers must be integers in range).
    fn parse_ascii(self, token: &[u8]) -> Option<f64> {
        let s = std::str::from_utf8(token).ok()?;
        if self.is_float() {
            return s.parse::<f64>().ok();
        }
        let v: i128 = s.parse().ok()?;
        let (lo, hi): (i128, i128) = match self {
            Scalar::I8 => (i8::MIN.into(), i8::MAX.into()),
            Scalar::U8 => (0, u8::MAX.into()),
            Scalar::I16 => (i16::MIN.into(), i16::MAX.into()),
            Scalar::U16 => (0, u16::MAX.into()),
            Scalar::I32 => (i32::MIN.into(), i32::MAX.into()),
            Scalar::U32 => (0, u32::MAX.into()),
            Scalar::I64 => (i64::MIN.into(), i64::MAX.into()),
            _ => (0, u64::MAX.into()),
        };
        (lo..=hi).contains(&v).then_some(v as f64)
    }
}

/// Splits a byte slice into whitespace-separated tokens.
fn ascii_tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace())
        .filter(|t| !t.is_empty())
}

/// Splits `bytes` at the first `\n`: returns (line without `\r\n`/`\n`, rest), or `None` at
/// the end of input.
fn next_line(bytes: &[u8]) -> Option<(&[u8], &[u8])> {
    if bytes.is_empty() {
        return None;
    }
    let (line, rest) = match bytes.iter().position(|&b| b == b'\n') {
        Some(i) => (&bytes[..i], &bytes[i + 1..]),
        None => (bytes, &bytes[bytes.len()..]),
    };
    Some((line.strip_suffix(b"\r").unwrap_or(line), rest))
}

/// Lossy rendering of a short piece of input for error messages.
fn show(bytes: &[u8]) -> String {
    let cut = &bytes[..bytes.len().min(60)];
    let mut s = String::from_utf8_lossy(cut).into_owned();
    if bytes.len() > cut.len() {
        s.push('…');
    }
    s
}

/// Capacity to reserve for `claimed` points when each needs at least `min_bytes` of `avail`
/// input bytes: never more than the input could possibly hold.
fn bounded_capacity(claimed: usize, avail: usize, min_bytes: usize) -> usize {
    claimed.min(avail / min_bytes.max(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_extension_is_a_format_error_naming_the_file() {
        let err = read_points(Path::new("cloud.xyz")).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, Error::Format { .. }), "{msg}");
        assert!(msg.contains("cloud.xyz") && msg.contains(".xyz"), "{msg}");
    }

    #[test]
    fn read_points_dispatches_on_case_insensitive_extension() {
        let dir = std::env::temp_dir().join(format!("mireg-io-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("cloud.PCD");
        let text = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n0.5 -1 2\n";
        std::fs::write(&path, text).unwrap();
        let pts = read_points(&path);
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(pts.unwrap(), vec![Point3::new(0.5, -1.0, 2.0)]);
    }

    #[test]
    fn missing_file_is_an_io_error() {
        let err = read_points(Path::new("/nonexistent/dir/cloud.ply")).unwrap_err();
        assert!(matches!(err, Error::Io { .. }), "{err}");
    }

    /// Small valid files of each binary format, built by hand.
    fn sample_files() -> Vec<(&'static str, Vec<u8>)> {
        let mut ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n\
                        property list uchar int n\nproperty float y\nproperty float z\nend_header\n"
            .to_vec();
        for k in 0..2u8 {
            ply.extend(1.0f32.to_le_bytes());
            ply.push(1);
            ply.extend(i32::from(k).to_le_bytes());
            ply.extend(2.0f32.to_le_bytes());
            ply.extend(3.0f32.to_le_bytes());
        }
        let mut pcd = b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 1\nPOINTS 2\n\
                        DATA binary_compressed\n"
            .to_vec();
        let raw: Vec<u8> = [1.0f32, 4.0, 2.0, 5.0, 3.0, 6.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        pcd.extend(25u32.to_le_bytes());
        pcd.extend(24u32.to_le_bytes());
        pcd.push(23);
        pcd.extend(&raw);
        let mut npy = b"\x93NUMPY\x01\x00".to_vec();
        let dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (1, 3), }\n";
        npy.extend((dict.len() as u16).to_le_bytes());
        npy.extend(dict.as_bytes());
        [1.0f64, 2.0, 3.0]
            .iter()
            .for_each(|v| npy.extend(v.to_le_bytes()));
        vec![("a.ply", ply), ("a.pcd", pcd), ("a.npy", npy)]
    }

    fn parse_by_name(name: &str, bytes: &[u8]) -> Result<Vec<Point3<f64>>> {
        let path = Path::new(name);
        match name {
            "a.ply" => parse_ply(bytes, path),
            "a.pcd" => parse_pcd(bytes, path),
            _ => parse_npy(bytes, path),
        }
    }

    #[test]
    fn truncation_and_byte_corruption_never_panic() {
        for (name, bytes) in sample_files() {
            let full = parse_by_name(name, &bytes).unwrap();
            assert_eq!(full.len(), if name == "a.npy" { 1 } else { 2 }, "{name}");
            for cut in 0..bytes.len() {
                // Every strict prefix of a binary file lacks data: it must be an error.
                let r = parse_by_name(name, &bytes[..cut]);
                assert!(
                    matches!(r, Err(Error::Format { .. })),
                    "{name} cut at {cut}: {r:?}"
                );
            }
            for at in 0..bytes.len() {
                for v in [0x00, 0xff, b'9', b' ', b'\n'] {
                    let mut b = bytes.clone();
                    b[at] = v;
                    let _ = parse_by_name(name, &b); // any result but a panic
                }
            }
        }
    }

    #[test]
    fn written_files_read_back() {
        let rows = [1.0f32, -2.0, 3.5, 7.0, 0.25, 0.5, -0.75, 9.0];
        for format in [
            CloudFileFormat::Ply,
            CloudFileFormat::Pcd,
            CloudFileFormat::Npy,
        ] {
            for cols in [3, 4] {
                let rows = &rows[..2 * cols];
                let mut bytes = Vec::new();
                format.write(rows, cols, &mut bytes).unwrap();
                let path = Path::new("map");
                let pts = match format {
                    CloudFileFormat::Ply => parse_ply(&bytes, path),
                    CloudFileFormat::Pcd => parse_pcd(&bytes, path),
                    CloudFileFormat::Npy => parse_npy(&bytes, path),
                }
                .unwrap();
                let want: Vec<Point3<f64>> = rows
                    .chunks(cols)
                    .map(|r| Point3::new(r[0].into(), r[1].into(), r[2].into()))
                    .collect();
                assert_eq!(pts, want, "{format:?} {cols}");
                // Data is the last 4·N·cols bytes, intensity included.
                let tail: Vec<u8> = rows.iter().flat_map(|v| v.to_le_bytes()).collect();
                assert!(bytes.ends_with(&tail), "{format:?} {cols}");
                if format == CloudFileFormat::Npy {
                    assert_eq!((bytes.len() - tail.len()) % 64, 0);
                }
            }
        }
        assert!(CloudFileFormat::from_path(Path::new("m.xyz")).is_err());
        assert_eq!(
            CloudFileFormat::from_path(Path::new("m.PLY")).unwrap(),
            CloudFileFormat::Ply
        );
    }

    #[test]
    fn scalar_decoding_matches_construction() {
        let b = (-2.5f32).to_be_bytes();
        assert_eq!(Scalar::F32.decode(&b, Endian::Big), -2.5);
        let b = 40000u16.to_le_bytes();
        assert_eq!(Scalar::U16.decode(&b, Endian::Little), 40000.0);
        assert_eq!(Scalar::I8.decode(&[0xff], Endian::Little), -1.0);
        assert_eq!(Scalar::U8.parse_ascii(b"256"), None);
        assert_eq!(Scalar::I16.parse_ascii(b"-7"), Some(-7.0));
        assert_eq!(Scalar::F64.parse_ascii(b"1e-3"), Some(0.001));
    }
}
