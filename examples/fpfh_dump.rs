//! Runs mireg's geometry and FPFH on .npy inputs so `tools/fpfh_vs_open3d.py` can compare them
//! with Open3D, and times the feature pipeline.
//!
//! ```text
//! fpfh_dump fpfh IN.npy OUT.npy RADIUS_M MAX_NN      IN: N×6 f64 (xyz, normal) -> OUT: N×33 f32
//! fpfh_dump normals IN.npy OUT.npy RADIUS_M MAX_NN   IN: N×3+ f64 (xyz)        -> OUT: N×3 f64
//! fpfh_dump voxel IN.npy OUT.npy VOXEL_M             IN: N×3+ f64 (xyz)        -> OUT: M×3 f64
//! fpfh_dump pipeline IN.npy VOXEL_M REPEATS          voxel + normals(2v, 30) + FPFH(5v, 100);
//!                                                    prints one JSON line of timings [s]
//! ```

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, bail, ensure};
use mireg::features::compute_fpfh_with_tree;
use mireg::geometry::{KdTree, estimate_normals, estimate_normals_with_tree, voxel_downsample};
use nalgebra::{Point3, Vector3};

fn main() {
    if let Err(e) = run(std::env::args().skip(1).collect()) {
        eprintln!("{e:#}");
        std::process::exit(2);
    }
}

fn run(args: Vec<String>) -> anyhow::Result<()> {
    let arg = |i: usize| -> anyhow::Result<&str> {
        args.get(i)
            .map(String::as_str)
            .context("missing argument (see the file's doc comment)")
    };
    match arg(0)? {
        "fpfh" => {
            let (rows, cols, data) = read_npy_f64(Path::new(arg(1)?))?;
            ensure!(
                cols == 6,
                "fpfh input must be N×6 (xyz, normal), got N×{cols}"
            );
            let points: Vec<Point3<f64>> = (0..rows)
                .map(|r| Point3::new(data[r * 6], data[r * 6 + 1], data[r * 6 + 2]))
                .collect();
            let normals: Vec<Vector3<f64>> = (0..rows)
                .map(|r| Vector3::new(data[r * 6 + 3], data[r * 6 + 4], data[r * 6 + 5]))
                .collect();
            let f = mireg::features::compute_fpfh(
                &points,
                &normals,
                arg(3)?.parse()?,
                arg(4)?.parse()?,
            )?;
            let flat: Vec<f32> = f.iter().flatten().copied().collect();
            write_npy(Path::new(arg(2)?), "<f4", rows, 33, &bytes_f32(&flat))
        }
        "normals" => {
            let points = read_points(Path::new(arg(1)?))?;
            let n = estimate_normals(&points, arg(3)?.parse()?, arg(4)?.parse()?, None)?;
            let flat: Vec<f64> = n.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
            write_npy(Path::new(arg(2)?), "<f8", n.len(), 3, &bytes_f64(&flat))
        }
        "voxel" => {
            let points = read_points(Path::new(arg(1)?))?;
            let v = voxel_downsample(&points, arg(3)?.parse()?)?;
            let flat: Vec<f64> = v.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
            write_npy(Path::new(arg(2)?), "<f8", v.len(), 3, &bytes_f64(&flat))
        }
        "pipeline" => {
            let points = read_points(Path::new(arg(1)?))?;
            let voxel: f64 = arg(2)?.parse()?;
            let repeats: usize = arg(3)?.parse()?;
            let mut best = [f64::INFINITY; 4];
            let mut count = 0;
            for _ in 0..repeats {
                let t0 = Instant::now();
                let down = voxel_downsample(&points, voxel)?;
                let t1 = Instant::now();
                let tree = KdTree::new(&down)?;
                let normals = estimate_normals_with_tree(&down, &tree, 2.0 * voxel, 30, None)?;
                let t2 = Instant::now();
                let f = compute_fpfh_with_tree(&down, &normals, &tree, 5.0 * voxel, 100)?;
                let t3 = Instant::now();
                count = f.len();
                let times = [t1 - t0, t2 - t1, t3 - t2, t3 - t0].map(|d| d.as_secs_f64());
                for (b, t) in best.iter_mut().zip(times) {
                    *b = b.min(t);
                }
            }
            println!(
                "{{\"points\": {count}, \"voxel_s\": {:.6}, \"normals_s\": {:.6}, \"fpfh_s\": {:.6}, \"total_s\": {:.6}, \"threads\": {}}}",
                best[0],
                best[1],
                best[2],
                best[3],
                rayon::current_num_threads()
            );
            Ok(())
        }
        other => bail!("unknown mode {other:?}"),
    }
}

fn read_points(path: &Path) -> anyhow::Result<Vec<Point3<f64>>> {
    let (rows, cols, data) = read_npy_f64(path)?;
    ensure!(
        cols >= 3,
        "{}: need at least 3 columns, got {cols}",
        path.display()
    );
    Ok((0..rows)
        .map(|r| Point3::new(data[r * cols], data[r * cols + 1], data[r * cols + 2]))
        .collect())
}

/// Reads a C-order little-endian float64 (or float32, widened) 2-D .npy (format 1.x/2.x).
fn read_npy_f64(path: &Path) -> anyhow::Result<(usize, usize, Vec<f64>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    ensure!(
        bytes.starts_with(b"\x93NUMPY"),
        "{}: not an .npy file",
        path.display()
    );
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        _ => (u32::from_le_bytes(bytes[8..12].try_into()?) as usize, 12),
    };
    let header = std::str::from_utf8(&bytes[start..start + header_len])?;
    ensure!(
        header.contains("'fortran_order': False"),
        "{}: need C order",
        path.display()
    );
    let shape = header
        .split("'shape': (")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .context("no shape")?;
    let dims: Vec<usize> = shape
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let (rows, cols) = match dims[..] {
        [r, c] => (r, c),
        [r] => (r, 1),
        _ => bail!("{}: need a 2-D array, shape ({shape})", path.display()),
    };
    let body = &bytes[start + header_len..];
    let data: Vec<f64> = if header.contains("'<f8'") {
        body.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    } else if header.contains("'<f4'") {
        body.chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes(c.try_into().unwrap())))
            .collect()
    } else {
        bail!("{}: need '<f8' or '<f4' data: {header}", path.display());
    };
    ensure!(
        data.len() == rows * cols,
        "{}: {} values for shape ({shape})",
        path.display(),
        data.len()
    );
    Ok((rows, cols, data))
}

/// Writes a 2-D C-order .npy (format 1.0).
fn write_npy(
    path: &Path,
    descr: &str,
    rows: usize,
    cols: usize,
    body: &[u8],
) -> anyhow::Result<()> {
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(body);
    std::fs::write(path, out).with_context(|| format!("writing {}", path.display()))
}

fn bytes_f64(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn bytes_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}
