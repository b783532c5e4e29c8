//! PCD reader and writer ([`write_pcd`]) (Point Cloud Library format, v0.7 header).
//!
//! Supports `DATA ascii`, `DATA binary` (little-endian, point-major records) and
//! `DATA binary_compressed` (LZF-compressed, field-major). Reads the `x`, `y`, `z` fields (any
//! numeric type, `COUNT` 1) among arbitrary other fields.

use std::path::Path;

use nalgebra::Point3;

use super::{
    Endian, Scalar, ascii_tokens, bounded_capacity, format_err, next_line, push_finite, show,
};
use crate::Result;

/// Largest expansion one LZF byte can produce (a 3-byte back-reference copies up to 264
/// bytes): a `binary_compressed` header claiming more than this ratio is corrupt.
const LZF_MAX_EXPANSION: usize = 88;

#[derive(Debug)]
struct Field {
    name: String,
    ty: Scalar,
    count: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Data {
    Ascii,
    Binary,
    BinaryCompressed,
}

struct Header<'a> {
    fields: Vec<Field>,
    points: usize,
    data: Data,
    body: &'a [u8],
}

fn parse_header<'a>(bytes: &'a [u8], path: &Path) -> Result<Header<'a>> {
    let (lines, data, body) = read_header_lines(bytes, path)?;
    let declared = (lines.points, lines.width, lines.height);
    let fields = fields_of(lines, path)?;
    Ok(Header {
        fields,
        points: point_count(declared, path)?,
        data,
        body,
    })
}

/// An error in the PCD header of `path`.
fn header_err(path: &Path, detail: String) -> crate::Error {
    format_err(path, format!("PCD header: {detail}"))
}

/// The header's values, as its lines give them.
#[derive(Default)]
struct HeaderLines {
    names: Option<Vec<String>>,
    sizes: Option<Vec<usize>>,
    types: Option<Vec<String>>,
    counts: Option<Vec<usize>>,
    width: Option<usize>,
    height: Option<usize>,
    points: Option<usize>,
}

/// Reads the header's lines up to and including `DATA`: their values, the data's encoding, and
/// the bytes after the header.
fn read_header_lines<'a>(bytes: &'a [u8], path: &Path) -> Result<(HeaderLines, Data, &'a [u8])> {
    let err = |d: String| header_err(path, d);
    let mut rest = bytes;
    let mut h = HeaderLines::default();
    let mut line_no = 0;
    let data = loop {
        let (raw, after) =
            next_line(rest).ok_or_else(|| err("no DATA line before end of file".into()))?;
        rest = after;
        line_no += 1;
        let line = std::str::from_utf8(raw)
            .map_err(|_| err(format!("line {line_no} is not valid text")))?;
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        if key.starts_with('#') {
            continue;
        }
        let values: Vec<&str> = words.collect();
        let one_usize = |what: &str| -> Result<usize> {
            match values.as_slice() {
                [v] => v
                    .parse()
                    .map_err(|_| err(format!("{what} value '{v}' is not a count"))),
                _ => Err(err(format!("{what} needs one value, got {}", values.len()))),
            }
        };
        let counts = |what: &str| -> Result<Vec<usize>> {
            let v: Option<Vec<usize>> = values.iter().map(|s| s.parse().ok()).collect();
            v.ok_or_else(|| err(format!("bad {what} line '{line}'")))
        };
        match key.to_ascii_uppercase().as_str() {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => h.names = Some(values.iter().map(|s| s.to_string()).collect()),
            "SIZE" => h.sizes = Some(counts("SIZE")?),
            "TYPE" => h.types = Some(values.iter().map(|s| s.to_string()).collect()),
            "COUNT" => h.counts = Some(counts("COUNT")?),
            "WIDTH" => h.width = Some(one_usize("WIDTH")?),
            "HEIGHT" => h.height = Some(one_usize("HEIGHT")?),
            "POINTS" => h.points = Some(one_usize("POINTS")?),
            "DATA" => {
                break match values.as_slice() {
                    ["ascii"] => Data::Ascii,
                    ["binary"] => Data::Binary,
                    ["binary_compressed"] => Data::BinaryCompressed,
                    _ => return Err(err(format!("unsupported DATA '{}'", values.join(" ")))),
                };
            }
            other => return Err(err(format!("line {line_no}: unknown key '{other}'"))),
        }
    };
    Ok((h, data, rest))
}

/// The fields of the header: `FIELDS`, `SIZE` and `TYPE` (required) and `COUNT` (default 1),
/// of equal lengths, each a supported type and size.
fn fields_of(h: HeaderLines, path: &Path) -> Result<Vec<Field>> {
    let err = |d: String| header_err(path, d);
    let names = h.names.ok_or_else(|| err("missing FIELDS".into()))?;
    let sizes = h.sizes.ok_or_else(|| err("missing SIZE".into()))?;
    let types = h.types.ok_or_else(|| err("missing TYPE".into()))?;
    let counts = h.counts.unwrap_or_else(|| vec![1; names.len()]);
    if sizes.len() != names.len() || types.len() != names.len() || counts.len() != names.len() {
        return Err(err(format!(
            "FIELDS has {} entries but SIZE {}, TYPE {}, COUNT {}",
            names.len(),
            sizes.len(),
            types.len(),
            counts.len()
        )));
    }
    let mut fields = Vec::with_capacity(names.len());
    for (((name, size), ty), count) in names.into_iter().zip(sizes).zip(types).zip(counts) {
        let scalar = match (ty.as_str(), size) {
            ("F", 4) => Scalar::F32,
            ("F", 8) => Scalar::F64,
            ("I", 1) => Scalar::I8,
            ("I", 2) => Scalar::I16,
            ("I", 4) => Scalar::I32,
            ("I", 8) => Scalar::I64,
            ("U", 1) => Scalar::U8,
            ("U", 2) => Scalar::U16,
            ("U", 4) => Scalar::U32,
            ("U", 8) => Scalar::U64,
            _ => {
                return Err(err(format!(
                    "field '{name}': unsupported TYPE {ty} with SIZE {size}"
                )));
            }
        };
        fields.push(Field {
            name,
            ty: scalar,
            count,
        });
    }
    Ok(fields)
}

/// The header's point count from its `(POINTS, WIDTH, HEIGHT)`: `POINTS` (equal to
/// `WIDTH × HEIGHT` when both are given), else `WIDTH × HEIGHT`, else `WIDTH`.
fn point_count(
    declared: (Option<usize>, Option<usize>, Option<usize>),
    path: &Path,
) -> Result<usize> {
    let err = |d: String| header_err(path, d);
    Ok(match declared {
        (Some(p), Some(w), Some(h)) if w.checked_mul(h) != Some(p) => {
            return Err(err(format!("POINTS {p} != WIDTH {w} × HEIGHT {h}")));
        }
        (Some(p), _, _) => p,
        (None, Some(w), Some(h)) => w
            .checked_mul(h)
            .ok_or_else(|| err(format!("WIDTH {w} × HEIGHT {h} overflows")))?,
        (None, Some(w), None) => w,
        _ => return Err(err("missing POINTS (and WIDTH/HEIGHT)".into())),
    })
}

/// Parses a PCD file held in memory; `path` is used only in error messages.
///
/// Returns the finite `x`, `y`, `z` in file order, in the file's units.
///
/// # Errors
/// [`crate::Error::Format`] for a bad header, a missing `x`/`y`/`z`, unsupported types, corrupt
/// LZF data, or data that is truncated or does not match the header.
pub fn parse_pcd(bytes: &[u8], path: &Path) -> Result<Vec<Point3<f64>>> {
    let h = parse_header(bytes, path)?;
    let mut xyz = [0usize; 3];
    for (slot, axis) in xyz.iter_mut().zip(["x", "y", "z"]) {
        let i = h
            .fields
            .iter()
            .position(|f| f.name == axis)
            .ok_or_else(|| format_err(path, format!("PCD has no field '{axis}'")))?;
        if h.fields[i].count != 1 {
            return Err(format_err(
                path,
                format!(
                    "PCD field '{axis}' has COUNT {}, expected 1",
                    h.fields[i].count
                ),
            ));
        }
        *slot = i;
    }
    // Byte offset of each field inside a point-major record.
    let mut offsets = Vec::with_capacity(h.fields.len());
    let mut stride = 0usize;
    for f in &h.fields {
        offsets.push(stride);
        stride = f
            .ty
            .size()
            .checked_mul(f.count)
            .and_then(|s| s.checked_add(stride))
            .ok_or_else(|| format_err(path, format!("PCD field '{}' COUNT too large", f.name)))?;
    }
    match h.data {
        Data::Ascii => parse_ascii(&h, xyz, path),
        Data::Binary => {
            let body = checked_body(h.body, h.points, stride, path)?;
            let mut points = Vec::with_capacity(h.points);
            for rec in body.chunks_exact(stride) {
                let get = |i: usize| {
                    let f = &h.fields[xyz[i]];
                    f.ty.decode(&rec[offsets[xyz[i]]..], Endian::Little)
                };
                push_finite(&mut points, get(0), get(1), get(2));
            }
            Ok(points)
        }
        Data::BinaryCompressed => {
            let raw = decompress_body(h.body, h.points, stride, path)?;
            // Field-major layout: all points' values of field 0, then field 1, ...
            let column = |i: usize| h.points * offsets[xyz[i]];
            let ty = |i: usize| h.fields[xyz[i]].ty;
            let mut points = Vec::with_capacity(h.points);
            for k in 0..h.points {
                let get = |i: usize| {
                    let at = column(i) + k * ty(i).size();
                    ty(i).decode(&raw[at..], Endian::Little)
                };
                push_finite(&mut points, get(0), get(1), get(2));
            }
            Ok(points)
        }
    }
}

fn checked_body<'a>(body: &'a [u8], n: usize, stride: usize, path: &Path) -> Result<&'a [u8]> {
    match n.checked_mul(stride) {
        Some(need) if need <= body.len() => Ok(&body[..need]),
        _ => Err(format_err(
            path,
            format!(
                "PCD binary data truncated: {n} points of {stride} bytes need more than the {} bytes present",
                body.len()
            ),
        )),
    }
}

fn decompress_body(body: &[u8], n: usize, stride: usize, path: &Path) -> Result<Vec<u8>> {
    let word = |at: usize| -> Option<usize> {
        let b: [u8; 4] = body.get(at..at + 4)?.try_into().ok()?;
        Some(u32::from_le_bytes(b) as usize)
    };
    let (Some(compressed), Some(uncompressed)) = (word(0), word(4)) else {
        return Err(format_err(
            path,
            "PCD binary_compressed: missing size words",
        ));
    };
    let expected = n.checked_mul(stride);
    if expected != Some(uncompressed) {
        return Err(format_err(
            path,
            format!(
                "PCD binary_compressed: uncompressed size {uncompressed} != {n} points × {stride} bytes"
            ),
        ));
    }
    let input = body.get(8..8 + compressed).ok_or_else(|| {
        format_err(
            path,
            format!(
                "PCD binary_compressed: {compressed} compressed bytes claimed, {} present",
                body.len().saturating_sub(8)
            ),
        )
    })?;
    if uncompressed > compressed.saturating_mul(LZF_MAX_EXPANSION) + 32 {
        return Err(format_err(
            path,
            format!(
                "PCD binary_compressed: {compressed} bytes cannot expand to {uncompressed} bytes"
            ),
        ));
    }
    lzf_decompress(input, uncompressed)
        .map_err(|d| format_err(path, format!("PCD binary_compressed: {d}")))
}

/// Decompresses LZF data (the format of liblzf, used by PCD `binary_compressed`) whose
/// decompressed length is known to be exactly `expected_len` bytes.
///
/// # Errors
/// A description of the corruption: a back-reference before the start of the output, a
/// literal run or reference past the end of the input, or output longer or shorter than
/// `expected_len`.
pub fn lzf_decompress(input: &[u8], expected_len: usize) -> std::result::Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(expected_len);
    let mut ip = 0;
    while ip < input.len() {
        let ctrl = usize::from(input[ip]);
        ip += 1;
        if ctrl < 32 {
            // Literal run of ctrl + 1 bytes.
            let run = input
                .get(ip..ip + ctrl + 1)
                .ok_or_else(|| format!("literal run at byte {} past end of input", ip - 1))?;
            if out.len() + run.len() > expected_len {
                return Err(format!("output exceeds the expected {expected_len} bytes"));
            }
            out.extend_from_slice(run);
            ip += ctrl + 1;
        } else {
            // Back-reference: length in the top 3 bits (7 = extended), offset in 13 bits.
            let mut len = ctrl >> 5;
            if len == 7 {
                len += usize::from(*input.get(ip).ok_or("back-reference past end of input")?);
                ip += 1;
            }
            len += 2;
            let low = usize::from(*input.get(ip).ok_or("back-reference past end of input")?);
            ip += 1;
            let distance = ((ctrl & 0x1f) << 8) + low + 1;
            let start = out
                .len()
                .checked_sub(distance)
                .ok_or_else(|| format!("back-reference {distance} bytes before start of output"))?;
            if out.len() + len > expected_len {
                return Err(format!("output exceeds the expected {expected_len} bytes"));
            }
            // Byte by byte: the source may overlap the bytes being written.
            for k in 0..len {
                out.push(out[start + k]);
            }
        }
    }
    if out.len() != expected_len {
        return Err(format!(
            "decompressed {} bytes, expected {expected_len}",
            out.len()
        ));
    }
    Ok(out)
}

fn parse_ascii(h: &Header, xyz: [usize; 3], path: &Path) -> Result<Vec<Point3<f64>>> {
    let tokens_per_point: usize = h.fields.iter().map(|f| f.count).sum();
    let mut points = Vec::with_capacity(bounded_capacity(
        h.points,
        h.body.len(),
        2 * tokens_per_point,
    ));
    let mut rest = h.body;
    let mut k = 0;
    let mut values = [0.0; 3];
    while k < h.points {
        let Some((line, after)) = next_line(rest) else {
            return Err(format_err(
                path,
                format!("PCD ascii data ends after {k} of {} points", h.points),
            ));
        };
        rest = after;
        if line.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        let mut tokens = ascii_tokens(line);
        for (i, f) in h.fields.iter().enumerate() {
            for _ in 0..f.count {
                let t = tokens.next().ok_or_else(|| {
                    format_err(
                        path,
                        format!(
                            "PCD point {k}: line '{}' ends before field '{}'",
                            show(line),
                            f.name
                        ),
                    )
                })?;
                // PCL writes "nan" for invalid points, including in integer fields.
                let v = f.ty.parse_ascii(t).or_else(|| {
                    std::str::from_utf8(t)
                        .ok()
                        .filter(|s| s.eq_ignore_ascii_case("nan"))
                        .map(|_| f64::NAN)
                });
                let v = v.ok_or_else(|| {
                    format_err(
                        path,
                        format!(
                            "PCD point {k}: bad value '{}' for field '{}'",
                            show(t),
                            f.name
                        ),
                    )
                })?;
                if let Some(axis) = xyz.iter().position(|&x| x == i) {
                    values[axis] = v;
                }
            }
        }
        if tokens.next().is_some() {
            return Err(format_err(
                path,
                format!("PCD point {k}: extra values on line '{}'", show(line)),
            ));
        }
        push_finite(&mut points, values[0], values[1], values[2]);
        k += 1;
    }
    Ok(points)
}

/// Writes `rows` (flat `f32`, `cols` = 3 for `x y z` or 4 for `x y z intensity`) as a PCD v0.7
/// with `DATA binary` (little-endian `F 4` fields, `HEIGHT 1`, identity viewpoint).
///
/// # Errors
/// The writer's I/O errors.
pub fn write_pcd(rows: &[f32], cols: usize, out: &mut impl std::io::Write) -> std::io::Result<()> {
    let n = rows.len() / cols;
    let (fields, size, ty, count) = if cols == 4 {
        ("x y z intensity", "4 4 4 4", "F F F F", "1 1 1 1")
    } else {
        ("x y z", "4 4 4", "F F F", "1 1 1")
    };
    write!(
        out,
        "# .PCD v0.7 - Point Cloud Data file format (written by mireg)\nVERSION 0.7\n\
         FIELDS {fields}\nSIZE {size}\nTYPE {ty}\nCOUNT {count}\nWIDTH {n}\nHEIGHT 1\n\
         VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )?;
    super::write_f32_le(&rows[..n * cols], out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Error;

    fn p() -> &'static Path {
        Path::new("test.pcd")
    }

    fn expect_format_err(bytes: &[u8], needle: &str) {
        match parse_pcd(bytes, p()) {
            Err(e @ Error::Format { .. }) => {
                let msg = e.to_string();
                assert!(msg.contains("test.pcd"), "{msg}");
                assert!(msg.contains(needle), "expected '{needle}' in '{msg}'");
            }
            other => panic!("expected a format error containing '{needle}', got {other:?}"),
        }
    }

    const HEADER: &str = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n\
                          FIELDS intensity x y z normal\nSIZE 2 4 4 8 4\nTYPE U F F F F\nCOUNT 1 1 1 1 3\n\
                          WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\n";

    /// The three points used by the binary tests: (intensity, x, y, z).
    const PTS: [(u16, f32, f32, f64); 3] = [
        (7, 1.0, 2.0, 3.0),
        (8, f32::NAN, 0.0, 0.0),
        (9, -0.5, 0.25, 1e-3),
    ];

    fn expected() -> Vec<Point3<f64>> {
        vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-0.5, 0.25, 1e-3)]
    }

    #[test]
    fn ascii_with_extra_and_multi_count_fields() {
        let text = format!(
            "{HEADER}DATA ascii\n7 1 2 3 0 0 1\n8 nan nan nan 0 0 1\n\n9 -0.5 0.25 1e-3 1 0 0\n"
        );
        assert_eq!(parse_pcd(text.as_bytes(), p()).unwrap(), expected());
    }

    #[test]
    fn binary_point_major() {
        let mut b = format!("{HEADER}DATA binary\n").into_bytes();
        for (i, x, y, z) in PTS {
            b.extend(i.to_le_bytes());
            b.extend(x.to_le_bytes());
            b.extend(y.to_le_bytes());
            b.extend(z.to_le_bytes());
            for n in [0.0f32, 0.0, 1.0] {
                b.extend(n.to_le_bytes());
            }
        }
        assert_eq!(parse_pcd(&b, p()).unwrap(), expected());
        b.truncate(b.len() - 1);
        expect_format_err(&b, "truncated");
    }

    /// Field-major bytes of `PTS` as `binary_compressed` expects them before compression.
    fn field_major() -> Vec<u8> {
        let mut raw = Vec::new();
        PTS.iter().for_each(|p| raw.extend(p.0.to_le_bytes()));
        PTS.iter().for_each(|p| raw.extend(p.1.to_le_bytes()));
        PTS.iter().for_each(|p| raw.extend(p.2.to_le_bytes()));
        PTS.iter().for_each(|p| raw.extend(p.3.to_le_bytes()));
        raw.extend([0u8; 3 * 12]); // normals: all zero
        raw
    }

    /// LZF-encodes `raw` with literal runs only, except that a trailing run of zeros is encoded
    /// with back-references to exercise them.
    fn lzf_literal_then_zero_refs(raw: &[u8], zeros: usize) -> Vec<u8> {
        let lit = &raw[..raw.len() - zeros];
        let mut c = Vec::new();
        for chunk in lit.chunks(32) {
            c.push((chunk.len() - 1) as u8);
            c.extend_from_slice(chunk);
        }
        // One literal zero, then references to the previous byte (distance 1).
        c.push(0);
        c.push(0);
        let mut left = zeros - 1;
        while left > 0 {
            let len = left.min(8);
            if len >= 3 {
                // Short form: len - 2 in the top 3 bits (at most 6 → len 8), offset 0.
                c.push(((len - 2) << 5) as u8);
                c.push(0);
            } else {
                c.push((len - 1) as u8);
                c.extend(std::iter::repeat_n(0u8, len));
            }
            left -= len;
        }
        c
    }

    #[test]
    fn binary_compressed_field_major() {
        let raw = field_major();
        let comp = lzf_literal_then_zero_refs(&raw, 36);
        let mut b = format!("{HEADER}DATA binary_compressed\n").into_bytes();
        b.extend((comp.len() as u32).to_le_bytes());
        b.extend((raw.len() as u32).to_le_bytes());
        b.extend(&comp);
        assert_eq!(parse_pcd(&b, p()).unwrap(), expected());

        // Uncompressed size that does not match the header.
        let mut bad = format!("{HEADER}DATA binary_compressed\n").into_bytes();
        bad.extend((comp.len() as u32).to_le_bytes());
        bad.extend((raw.len() as u32 + 1).to_le_bytes());
        bad.extend(&comp);
        expect_format_err(&bad, "uncompressed size");

        // Compressed data cut short.
        let mut cut = format!("{HEADER}DATA binary_compressed\n").into_bytes();
        cut.extend((comp.len() as u32).to_le_bytes());
        cut.extend((raw.len() as u32).to_le_bytes());
        cut.extend(&comp[..comp.len() - 5]);
        expect_format_err(&cut, "compressed bytes claimed");
    }

    #[test]
    fn lzf_back_references_and_corruption() {
        // "abc" literal, then copy 4 bytes from distance 3 (overlapping): "abcabca".
        assert_eq!(
            lzf_decompress(&[2, b'a', b'b', b'c', 0x40, 2], 7).unwrap(),
            b"abcabca"
        );
        // Extended length: 7 + 3 + 2 = 12 copies of 'z'.
        assert_eq!(
            lzf_decompress(&[0, b'z', 0xE0, 3, 0], 13).unwrap(),
            vec![b'z'; 13]
        );
        assert!(
            lzf_decompress(&[0x40, 5], 4)
                .unwrap_err()
                .contains("before start")
        );
        assert!(
            lzf_decompress(&[5, 1, 2], 6)
                .unwrap_err()
                .contains("past end")
        );
        assert!(
            lzf_decompress(&[1, 1, 2], 3)
                .unwrap_err()
                .contains("expected 3")
        );
        assert!(
            lzf_decompress(&[2, 1, 2, 3], 2)
                .unwrap_err()
                .contains("exceeds")
        );
    }

    #[test]
    fn missing_fields_and_bad_headers() {
        expect_format_err(
            b"FIELDS x y\nSIZE 4 4\nTYPE F F\nPOINTS 0\nDATA ascii\n",
            "no field 'z'",
        );
        expect_format_err(
            b"FIELDS x y z\nSIZE 4 4 2\nTYPE F F F\nPOINTS 0\nDATA ascii\n",
            "unsupported TYPE F with SIZE 2",
        );
        expect_format_err(
            b"FIELDS x y z\nSIZE 4 4\nTYPE F F F\nPOINTS 0\nDATA ascii\n",
            "SIZE 2",
        );
        expect_format_err(
            b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 0\nDATA lzma\n",
            "unsupported DATA 'lzma'",
        );
        expect_format_err(
            b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 2\nPOINTS 3\nDATA ascii\n",
            "POINTS 3 != WIDTH 2",
        );
        expect_format_err(b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n", "no DATA line");
        expect_format_err(
            b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 2 1\nPOINTS 0\nDATA ascii\n",
            "'y' has COUNT 2",
        );
        expect_format_err(
            b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n1 2\n",
            "ends before field 'z'",
        );
        expect_format_err(
            b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 2\nDATA ascii\n1 2 3\n",
            "ends after 1 of 2",
        );
    }

    #[test]
    fn absurd_point_count_fails_without_allocating() {
        let mut b =
            b"FIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nPOINTS 999999999999999999\nDATA binary\n"
                .to_vec();
        b.extend([0u8; 48]);
        expect_format_err(&b, "truncated");
        let mut c =
            b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 100000000000\nDATA binary_compressed\n"
                .to_vec();
        c.extend(2u32.to_le_bytes());
        c.extend(1_200_000_000u32.to_le_bytes());
        c.extend([0u8, 0]);
        expect_format_err(&c, "uncompressed size");
    }
}
