//! NumPy `.npy` reader (format versions 1.0, 2.0 and 3.0) for float arrays of shape (N, 3)
//! or (N, 4); the fourth column (intensity, colour, ...) is ignored. [`write_npy`] writes
//! format 1.0 `<f4` arrays of shape (N, 3) or (N, 4).

use std::path::Path;

use nalgebra::Point3;

use super::{Endian, Scalar, format_err, push_finite, show};
use crate::Result;

const MAGIC: &[u8] = b"\x93NUMPY";

/// The parsed `.npy` header dictionary.
struct NpyHeader {
    endian: Endian,
    ty: Scalar,
    fortran_order: bool,
    rows: usize,
    cols: usize,
}

/// Finds `'key':` in the header dictionary and returns the text after the colon.
fn value_of<'a>(dict: &'a str, key: &str) -> Option<&'a str> {
    let at = dict
        .find(&format!("'{key}'"))
        .or_else(|| dict.find(&format!("\"{key}\"")))?;
    let rest = dict[at + key.len() + 2..].trim_start();
    Some(rest.strip_prefix(':')?.trim_start())
}

fn parse_dict(dict: &str, path: &Path) -> Result<NpyHeader> {
    let err = |d: String| format_err(path, format!("npy header: {d} (header: {dict})"));
    let descr = value_of(dict, "descr").ok_or_else(|| err("no 'descr'".into()))?;
    let quote = descr.chars().next().filter(|c| *c == '\'' || *c == '"');
    let descr = quote
        .and_then(|q| descr[1..].split(q).next())
        .ok_or_else(|| err("'descr' is not a string".into()))?;
    let (endian, ty) = match descr {
        "<f4" => (Endian::Little, Scalar::F32),
        "<f8" => (Endian::Little, Scalar::F64),
        ">f4" => (Endian::Big, Scalar::F32),
        ">f8" => (Endian::Big, Scalar::F64),
        other => {
            return Err(err(format!(
                "unsupported dtype '{other}' (expected <f4, <f8, >f4 or >f8)"
            )));
        }
    };
    let fo = value_of(dict, "fortran_order").ok_or_else(|| err("no 'fortran_order'".into()))?;
    let fortran_order = if fo.starts_with("True") {
        true
    } else if fo.starts_with("False") {
        false
    } else {
        return Err(err("'fortran_order' is not True or False".into()));
    };
    let shape = value_of(dict, "shape").ok_or_else(|| err("no 'shape'".into()))?;
    let inner = shape
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| err("'shape' is not a tuple".into()))?;
    let dims: Option<Vec<usize>> = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().ok())
        .collect();
    let dims = dims.ok_or_else(|| err(format!("bad shape ({inner})")))?;
    match dims.as_slice() {
        &[rows, cols @ (3 | 4)] => Ok(NpyHeader {
            endian,
            ty,
            fortran_order,
            rows,
            cols,
        }),
        _ => Err(err(format!("shape ({inner}) is not (N, 3) or (N, 4)"))),
    }
}

/// Parses a `.npy` file held in memory; `path` is used only in error messages.
///
/// Accepts dtypes `<f4`, `<f8`, `>f4`, `>f8`, shape (N, 3) or (N, 4), C or Fortran order.
/// Returns the finite rows' first three columns as points, in row order.
///
/// # Errors
/// [`crate::Error::Format`] for a bad magic/version/header, an unsupported dtype or shape,
/// or a data length that does not match the shape.
pub fn parse_npy(bytes: &[u8], path: &Path) -> Result<Vec<Point3<f64>>> {
    let err = |d: String| format_err(path, format!("npy: {d}"));
    if !bytes.starts_with(MAGIC) || bytes.len() < 10 {
        return Err(err(format!(
            "bad magic '{}'",
            show(&bytes[..bytes.len().min(8)])
        )));
    }
    let (header_start, header_len) = match bytes[6] {
        1 => (10, usize::from(u16::from_le_bytes([bytes[8], bytes[9]]))),
        2 | 3 => {
            let b = bytes
                .get(8..12)
                .ok_or_else(|| err("header length truncated".into()))?;
            (12, u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        }
        v => return Err(err(format!("unsupported format version {v}.{}", bytes[7]))),
    };
    let dict = bytes
        .get(header_start..header_start + header_len)
        .ok_or_else(|| err(format!("header of {header_len} bytes truncated")))?;
    let dict = std::str::from_utf8(dict).map_err(|_| err("header is not valid text".into()))?;
    let h = parse_dict(dict, path)?;
    let data = &bytes[header_start + header_len..];
    let size = h.ty.size();
    let need = h.rows.checked_mul(h.cols * size);
    if need != Some(data.len()) {
        return Err(err(format!(
            "shape ({}, {}) of {size}-byte values needs {} bytes of data, file has {}",
            h.rows,
            h.cols,
            need.map_or("too many".to_string(), |n| n.to_string()),
            data.len()
        )));
    }
    let get = |row: usize, col: usize| {
        let index = if h.fortran_order {
            col * h.rows + row
        } else {
            row * h.cols + col
        };
        h.ty.decode(&data[index * size..], h.endian)
    };
    let mut points = Vec::with_capacity(h.rows);
    for r in 0..h.rows {
        push_finite(&mut points, get(r, 0), get(r, 1), get(r, 2));
    }
    Ok(points)
}

/// Writes `rows` (flat `f32`, `cols` columns: 3 for `x y z`, 4 with intensity) as a NumPy
/// format 1.0 `.npy`: `'<f4'`, C order, shape `(N, cols)`, header padded with spaces to a
/// multiple of 64 bytes and ended by `\n`.
///
/// # Errors
/// The writer's I/O errors.
pub fn write_npy(rows: &[f32], cols: usize, out: &mut impl std::io::Write) -> std::io::Result<()> {
    let n = rows.len() / cols;
    let mut dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({n}, {cols}), }}");
    // magic (6) + version (2) + header length (2) + dict + padding + '\n' ≡ 0 (mod 64)
    let unpadded = 10 + dict.len() + 1;
    dict.extend(std::iter::repeat_n(
        ' ',
        unpadded.next_multiple_of(64) - unpadded,
    ));
    dict.push('\n');
    let len = u16::try_from(dict.len()).map_err(std::io::Error::other)?;
    out.write_all(b"\x93NUMPY\x01\x00")?;
    out.write_all(&len.to_le_bytes())?;
    out.write_all(dict.as_bytes())?;
    super::write_f32_le(&rows[..n * cols], out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Error;

    /// Builds a `.npy` file by hand: magic, version, padded header, data.
    fn npy(version: u8, dict: &str, data: &[u8]) -> Vec<u8> {
        let mut b = MAGIC.to_vec();
        b.extend([version, 0]);
        let prefix = if version == 1 { 10 } else { 12 };
        let mut header = dict.to_string();
        while !(prefix + header.len() + 1).is_multiple_of(64) {
            header.push(' ');
        }
        header.push('\n');
        if version == 1 {
            b.extend((header.len() as u16).to_le_bytes());
        } else {
            b.extend((header.len() as u32).to_le_bytes());
        }
        b.extend(header.as_bytes());
        b.extend(data);
        b
    }

    fn expect_format_err(bytes: &[u8], needle: &str) {
        match parse_npy(bytes, Path::new("a.npy")) {
            Err(e @ Error::Format { .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.contains("a.npy") && msg.contains(needle),
                    "expected '{needle}' in '{msg}'"
                );
            }
            other => panic!("expected a format error containing '{needle}', got {other:?}"),
        }
    }

    #[test]
    fn little_endian_f8_c_order_v1() {
        let mut d = Vec::new();
        for v in [1.0f64, 2.0, 3.0, -4.0, 5.5, 6.25] {
            d.extend(v.to_le_bytes());
        }
        let b = npy(
            1,
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }",
            &d,
        );
        let pts = parse_npy(&b, Path::new("a.npy")).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-4.0, 5.5, 6.25)]
        );
    }

    #[test]
    fn big_endian_f4_n_by_4_v2_drops_fourth_column_and_nan() {
        let mut d = Vec::new();
        for v in [
            1.0f32,
            2.0,
            3.0,
            99.0,
            f32::NAN,
            0.0,
            0.0,
            99.0,
            7.0,
            8.0,
            9.0,
            99.0,
        ] {
            d.extend(v.to_be_bytes());
        }
        let b = npy(
            2,
            "{'descr': '>f4', 'fortran_order': False, 'shape': (3, 4), }",
            &d,
        );
        let pts = parse_npy(&b, Path::new("a.npy")).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(7.0, 8.0, 9.0)]
        );
    }

    #[test]
    fn fortran_order_v3_and_other_dtypes() {
        // Column-major (2, 3): x column, then y column, then z column.
        let mut d = Vec::new();
        for v in [1.0f64, 4.0, 2.0, 5.0, 3.0, 6.0] {
            d.extend(v.to_be_bytes());
        }
        let b = npy(
            3,
            "{'descr': '>f8', 'fortran_order': True, 'shape': (2, 3), }",
            &d,
        );
        let pts = parse_npy(&b, Path::new("a.npy")).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
        );

        let mut d = Vec::new();
        for v in [0.5f32, 0.25, 0.125] {
            d.extend(v.to_le_bytes());
        }
        let b = npy(
            1,
            "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 3), }",
            &d,
        );
        assert_eq!(
            parse_npy(&b, Path::new("a.npy")).unwrap(),
            vec![Point3::new(0.5, 0.25, 0.125)]
        );
    }

    #[test]
    fn malformed_inputs_are_errors() {
        expect_format_err(b"\x93NUMPX\x01\x00\x00\x00", "bad magic");
        expect_format_err(b"\x93NUMPY\x04\x00\x10\x00", "unsupported format version 4");
        expect_format_err(b"\x93NUMPY\x01\x00\xff\x00{'descr'", "truncated");
        let d = [0u8; 24];
        expect_format_err(
            &npy(
                1,
                "{'descr': '<i8', 'fortran_order': False, 'shape': (1, 3), }",
                &d,
            ),
            "unsupported dtype '<i8'",
        );
        expect_format_err(
            &npy(
                1,
                "{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }",
                &d,
            ),
            "not (N, 3) or (N, 4)",
        );
        expect_format_err(
            &npy(
                1,
                "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }",
                &d,
            ),
            "needs 48 bytes of data, file has 24",
        );
        expect_format_err(
            &npy(1, "{'descr': '<f8', 'shape': (1, 3), }", &d),
            "no 'fortran_order'",
        );
        // A count that would need exabytes: rejected before any allocation.
        expect_format_err(
            &npy(
                1,
                "{'descr': '<f8', 'fortran_order': False, 'shape': (9999999999999999999, 3), }",
                &d,
            ),
            "too many",
        );
    }
}
