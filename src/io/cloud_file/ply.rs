//! PLY reader (Turk's format, as written by the Stanford scanners, Open3D, PCL, CloudCompare)
//! and writer ([`write_ply`]).
//!
//! Supports `ascii`, `binary_little_endian` and `binary_big_endian`; reads `x`, `y`, `z` of
//! `element vertex` (any scalar type), skipping every other property, including list
//! properties. Elements before `vertex` are skipped; reading stops after `vertex`, so faces
//! and range grids that follow are never parsed. ASCII data must hold one element per line.

use std::path::Path;

use nalgebra::Point3;

use super::{
    Endian, Scalar, ascii_tokens, bounded_capacity, format_err, next_line, push_finite, show,
};
use crate::Result;

#[derive(Debug, Clone, Copy)]
enum Encoding {
    Ascii,
    Binary(Endian),
}

#[derive(Debug, Clone, Copy)]
enum PropKind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: PropKind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

impl Element {
    /// Bytes per binary record, or `None` if a list property makes it variable.
    fn fixed_stride(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.kind {
                PropKind::Scalar(s) => Some(s.size()),
                PropKind::List { .. } => None,
            })
            .sum()
    }
}

fn scalar_type(name: &str) -> Option<Scalar> {
    Some(match name {
        "char" | "int8" => Scalar::I8,
        "uchar" | "uint8" => Scalar::U8,
        "short" | "int16" => Scalar::I16,
        "ushort" | "uint16" => Scalar::U16,
        "int" | "int32" => Scalar::I32,
        "uint" | "uint32" => Scalar::U32,
        "float" | "float32" => Scalar::F32,
        "double" | "float64" => Scalar::F64,
        _ => return None,
    })
}

/// Parses the header; returns the encoding, the elements and the data after `end_header`.
fn parse_header<'a>(bytes: &'a [u8], path: &Path) -> Result<(Encoding, Vec<Element>, &'a [u8])> {
    let err = |d: String| format_err(path, format!("PLY header: {d}"));
    let (first, mut rest) = next_line(bytes).ok_or_else(|| err("empty file".into()))?;
    if first != b"ply" {
        return Err(err(format!(
            "first line is '{}', expected 'ply'",
            show(first)
        )));
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_no = 1;
    loop {
        let (raw, after) =
            next_line(rest).ok_or_else(|| err("no 'end_header' line before end of file".into()))?;
        rest = after;
        line_no += 1;
        let line = std::str::from_utf8(raw)
            .map_err(|_| err(format!("line {line_no} is not valid text")))?;
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] => {}
            ["end_header"] => break,
            ["comment", ..] | ["obj_info", ..] => {}
            ["format", fmt, _version] => {
                encoding = Some(match *fmt {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Binary(Endian::Little),
                    "binary_big_endian" => Encoding::Binary(Endian::Big),
                    other => return Err(err(format!("unknown format '{other}'"))),
                });
            }
            ["element", name, count] => {
                let count: usize = count.parse().map_err(|_| {
                    err(format!(
                        "line {line_no}: bad count '{count}' for element '{name}'"
                    ))
                })?;
                elements.push(Element {
                    name: (*name).to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            ["property", "list", count_t, item_t, name] => {
                let count = scalar_type(count_t)
                    .filter(|s| !s.is_float())
                    .ok_or_else(|| {
                        err(format!(
                            "line {line_no}: bad list count type '{count_t}' for '{name}'"
                        ))
                    })?;
                let item = scalar_type(item_t).ok_or_else(|| {
                    err(format!(
                        "line {line_no}: unknown type '{item_t}' for '{name}'"
                    ))
                })?;
                let el = elements.last_mut().ok_or_else(|| {
                    err(format!(
                        "line {line_no}: property '{name}' before any element"
                    ))
                })?;
                el.props.push(Property {
                    name: (*name).to_string(),
                    kind: PropKind::List { count, item },
                });
            }
            ["property", ty, name] => {
                let s = scalar_type(ty).ok_or_else(|| {
                    err(format!(
                        "line {line_no}: unknown type '{ty}' for property '{name}'"
                    ))
                })?;
                let el = elements.last_mut().ok_or_else(|| {
                    err(format!(
                        "line {line_no}: property '{name}' before any element"
                    ))
                })?;
                el.props.push(Property {
                    name: (*name).to_string(),
                    kind: PropKind::Scalar(s),
                });
            }
            _ => return Err(err(format!("line {line_no}: cannot parse '{}'", show(raw)))),
        }
    }
    let encoding = encoding.ok_or_else(|| err("missing 'format' line".into()))?;
    Ok((encoding, elements, rest))
}

/// Parses a PLY file held in memory; `path` is used only in error messages.
///
/// Returns the finite `x`, `y`, `z` of `element vertex`, in file order, in the file's units.
///
/// # Errors
/// [`crate::Error::Format`] for a bad header, no `vertex` element, a missing or list-typed
/// `x`/`y`/`z`, or data that is truncated or does not match the header.
pub fn parse_ply(bytes: &[u8], path: &Path) -> Result<Vec<Point3<f64>>> {
    let (encoding, elements, mut data) = parse_header(bytes, path)?;
    let vi = elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| format_err(path, "PLY header has no 'element vertex'"))?;
    let vertex = &elements[vi];
    let mut xyz = [0usize; 3];
    for (slot, axis) in xyz.iter_mut().zip(["x", "y", "z"]) {
        let p = vertex
            .props
            .iter()
            .position(|p| p.name == axis)
            .ok_or_else(|| {
                format_err(path, format!("PLY element vertex has no property '{axis}'"))
            })?;
        if matches!(vertex.props[p].kind, PropKind::List { .. }) {
            return Err(format_err(
                path,
                format!("PLY vertex property '{axis}' is a list, expected a scalar"),
            ));
        }
        *slot = p;
    }
    let mut values = vec![0.0; vertex.props.len()];
    for el in &elements[..vi] {
        if el.props.is_empty() {
            continue; // occupies no data, whatever its count
        }
        if let (Encoding::Binary(_), Some(stride)) = (encoding, el.fixed_stride()) {
            let skip = el.count.checked_mul(stride).filter(|&n| n <= data.len());
            let skip = skip.ok_or_else(|| {
                format_err(
                    path,
                    format!("PLY element {} ({} records) truncated", el.name, el.count),
                )
            })?;
            data = &data[skip..];
            continue;
        }
        for k in 0..el.count {
            read_record(&mut data, el, encoding, &mut values)
                .map_err(|d| format_err(path, format!("PLY element {} {k}: {d}", el.name)))?;
        }
    }
    if let (Encoding::Binary(_), Some(stride)) = (encoding, vertex.fixed_stride()) {
        let need = vertex.count.checked_mul(stride);
        if need.is_none_or(|n| n > data.len()) {
            return Err(format_err(
                path,
                format!(
                    "PLY vertex data truncated: {} vertices of {stride} bytes need more than the {} bytes left",
                    vertex.count,
                    data.len()
                ),
            ));
        }
    }
    let min_bytes = match encoding {
        Encoding::Ascii => 2 * vertex.props.len(),
        Encoding::Binary(_) => vertex
            .props
            .iter()
            .map(|p| match p.kind {
                PropKind::Scalar(s) => s.size(),
                PropKind::List { count, .. } => count.size(),
            })
            .sum(),
    };
    let mut points = Vec::with_capacity(bounded_capacity(vertex.count, data.len(), min_bytes));
    for k in 0..vertex.count {
        read_record(&mut data, vertex, encoding, &mut values)
            .map_err(|d| format_err(path, format!("PLY vertex {k} of {}: {d}", vertex.count)))?;
        push_finite(&mut points, values[xyz[0]], values[xyz[1]], values[xyz[2]]);
    }
    Ok(points)
}

/// Reads one record of `el`, storing each scalar property in `values` (lists are skipped).
fn read_record(
    data: &mut &[u8],
    el: &Element,
    encoding: Encoding,
    values: &mut [f64],
) -> std::result::Result<(), String> {
    match encoding {
        Encoding::Binary(endian) => read_binary_record(data, el, endian, values),
        Encoding::Ascii => read_ascii_record(data, el, values),
    }
}

fn take<'a>(data: &mut &'a [u8], n: usize) -> std::result::Result<&'a [u8], String> {
    if data.len() < n {
        return Err("data ends early".into());
    }
    let (head, tail) = data.split_at(n);
    *data = tail;
    Ok(head)
}

fn list_len(v: f64, name: &str) -> std::result::Result<usize, String> {
    if v < 0.0 {
        return Err(format!("negative list length {v} in property '{name}'"));
    }
    Ok(v as usize)
}

fn read_binary_record(
    data: &mut &[u8],
    el: &Element,
    endian: Endian,
    values: &mut [f64],
) -> std::result::Result<(), String> {
    for (p, slot) in el.props.iter().zip(values.iter_mut()) {
        match p.kind {
            PropKind::Scalar(s) => *slot = s.decode(take(data, s.size())?, endian),
            PropKind::List { count, item } => {
                let n = list_len(count.decode(take(data, count.size())?, endian), &p.name)?;
                let bytes = n
                    .checked_mul(item.size())
                    .ok_or_else(|| format!("list '{}' length {n} too large", p.name))?;
                take(data, bytes)?;
            }
        }
    }
    Ok(())
}

fn read_ascii_record(
    data: &mut &[u8],
    el: &Element,
    values: &mut [f64],
) -> std::result::Result<(), String> {
    let line = loop {
        let (line, rest) = next_line(data).ok_or("data ends early")?;
        *data = rest;
        if line.iter().any(|b| !b.is_ascii_whitespace()) {
            break line;
        }
    };
    let mut tokens = ascii_tokens(line);
    let mut next = |ty: Scalar, name: &str| -> std::result::Result<f64, String> {
        let t = tokens
            .next()
            .ok_or_else(|| format!("line '{}' ends before property '{name}'", show(line)))?;
        ty.parse_ascii(t)
            .ok_or_else(|| format!("bad value '{}' for property '{name}'", show(t)))
    };
    for (p, slot) in el.props.iter().zip(values.iter_mut()) {
        match p.kind {
            PropKind::Scalar(s) => *slot = next(s, &p.name)?,
            PropKind::List { count, item } => {
                let n = list_len(next(count, &p.name)?, &p.name)?;
                for _ in 0..n {
                    next(item, &p.name)?;
                }
            }
        }
    }
    if tokens.next().is_some() {
        return Err(format!("extra values on line '{}'", show(line)));
    }
    Ok(())
}

/// Writes `rows` (flat `f32`, `cols` = 3 for `x y z` or 4 for `x y z intensity`) as a
/// `binary_little_endian` PLY with one `element vertex` of `float` properties.
///
/// # Errors
/// The writer's I/O errors.
pub fn write_ply(rows: &[f32], cols: usize, out: &mut impl std::io::Write) -> std::io::Result<()> {
    let n = rows.len() / cols;
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment written by mireg\nelement vertex {n}\n\
         property float x\nproperty float y\nproperty float z\n{}end_header\n",
        if cols == 4 {
            "property float intensity\n"
        } else {
            ""
        }
    )?;
    super::write_f32_le(&rows[..n * cols], out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Error;

    fn p() -> &'static Path {
        Path::new("test.ply")
    }

    fn expect_format_err(bytes: &[u8], needle: &str) {
        match parse_ply(bytes, p()) {
            Err(e @ Error::Format { .. }) => {
                let msg = e.to_string();
                assert!(msg.contains("test.ply"), "{msg}");
                assert!(msg.contains(needle), "expected '{needle}' in '{msg}'");
            }
            other => panic!("expected a format error containing '{needle}', got {other:?}"),
        }
    }

    #[test]
    fn ascii_with_comments_extra_properties_and_trailing_faces() {
        let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nobj_info scanner 1\r\n\
                    element vertex 3\r\nproperty uchar red\r\nproperty float x\r\nproperty double y\r\n\
                    property list uchar int idx\r\nproperty int z\r\n\
                    element face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n\
                    255 1.5 -2 2 7 8 3\r\n0 nan 0 0 4\r\n1 0.25 1e-3 1 9 -5\r\n3 0 1 2\r\n";
        let pts = parse_ply(text.as_bytes(), p()).unwrap();
        // The NaN vertex is dropped.
        assert_eq!(
            pts,
            vec![Point3::new(1.5, -2.0, 3.0), Point3::new(0.25, 0.001, -5.0)]
        );
    }

    fn binary_ply(endian: Endian) -> Vec<u8> {
        let name = match endian {
            Endian::Little => "binary_little_endian",
            Endian::Big => "binary_big_endian",
        };
        let header = format!(
            "ply\nformat {name} 1.0\nelement camera 1\nproperty list uchar float k\n\
             element vertex 2\nproperty float32 x\nproperty float y\nproperty float64 z\n\
             property ushort intensity\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        );
        let mut b = header.into_bytes();
        let f32b = |v: f32| match endian {
            Endian::Little => v.to_le_bytes(),
            Endian::Big => v.to_be_bytes(),
        };
        let f64b = |v: f64| match endian {
            Endian::Little => v.to_le_bytes(),
            Endian::Big => v.to_be_bytes(),
        };
        let u16b = |v: u16| match endian {
            Endian::Little => v.to_le_bytes(),
            Endian::Big => v.to_be_bytes(),
        };
        // camera element before vertex: a 2-item float list.
        b.push(2);
        b.extend(f32b(9.0));
        b.extend(f32b(8.0));
        for (x, y, z, i) in [(1.0f32, 2.0f32, 3.0f64, 7u16), (-0.5, 0.125, 1e-3, 65535)] {
            b.extend(f32b(x));
            b.extend(f32b(y));
            b.extend(f64b(z));
            b.extend(u16b(i));
        }
        // A face whose content is garbage: never read.
        b.extend([200u8, 1, 2]);
        b
    }

    #[test]
    fn binary_little_and_big_endian() {
        for endian in [Endian::Little, Endian::Big] {
            let pts = parse_ply(&binary_ply(endian), p()).unwrap();
            assert_eq!(
                pts,
                vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-0.5, 0.125, 1e-3)],
                "{endian:?}"
            );
        }
    }

    #[test]
    fn binary_vertex_with_list_property_and_int_coordinates() {
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty list uint8 int32 n\n\
                      property int16 x\nproperty int y\nproperty char z\nend_header\n"
            .to_vec();
        b.push(1);
        b.extend(77i32.to_le_bytes());
        b.extend((-3i16).to_le_bytes());
        b.extend(4i32.to_le_bytes());
        b.push((-5i8) as u8);
        b.push(0);
        b.extend(10i16.to_le_bytes());
        b.extend(20i32.to_le_bytes());
        b.push(30);
        let pts = parse_ply(&b, p()).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(-3.0, 4.0, -5.0), Point3::new(10.0, 20.0, 30.0)]
        );
    }

    #[test]
    fn truncated_binary_is_an_error() {
        let mut b = binary_ply(Endian::Little);
        let end = b.len() - 3 - 10; // cut into the second vertex
        b.truncate(end);
        expect_format_err(&b, "truncated");
    }

    #[test]
    fn truncated_ascii_is_an_error() {
        let text = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                     property float z\nend_header\n1 2 3\n4 5 6\n";
        expect_format_err(text, "vertex 2 of 3: data ends early");
        let short_line =
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                           property float z\nend_header\n1 2\n";
        expect_format_err(short_line, "ends before property 'z'");
        let bad_number =
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                           property float z\nend_header\n1 2 zz\n";
        expect_format_err(bad_number, "bad value 'zz' for property 'z'");
    }

    #[test]
    fn missing_coordinate_is_an_error() {
        let text = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float z\n\
                     end_header\n1 2\n";
        expect_format_err(text, "no property 'y'");
        let no_vertex = b"ply\nformat ascii 1.0\nelement face 0\nend_header\n";
        expect_format_err(no_vertex, "no 'element vertex'");
        let list_x = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\n\
                       property float y\nproperty float z\nend_header\n1 1 2 3\n";
        expect_format_err(list_x, "'x' is a list");
    }

    #[test]
    fn bad_headers_are_errors() {
        expect_format_err(b"", "empty file");
        expect_format_err(b"PLY\nformat ascii 1.0\n", "expected 'ply'");
        expect_format_err(
            b"ply\nformat ascii 1.0\nelement vertex 1\n",
            "no 'end_header'",
        );
        expect_format_err(
            b"ply\nformat binary_middle_endian 1.0\nend_header\n",
            "unknown format 'binary_middle_endian'",
        );
        expect_format_err(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty half x\nend_header\n",
            "unknown type 'half'",
        );
        expect_format_err(b"ply\nelement vertex 0\nend_header\n", "missing 'format'");
        expect_format_err(
            b"ply\nformat ascii 1.0\nelement vertex -1\nend_header\n",
            "bad count '-1'",
        );
    }

    #[test]
    fn elements_before_vertex_are_skipped_even_when_huge_or_empty() {
        let mut b = b"ply\nformat binary_big_endian 1.0\nelement marker 18446744073709551615\n\
                      element grid 2\nproperty short a\nproperty double b\n\
                      element vertex 1\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
            .to_vec();
        b.extend([0xAAu8; 20]); // two grid records of 10 bytes
        for v in [0.5f64, -1.0, 2.0] {
            b.extend(v.to_be_bytes());
        }
        assert_eq!(
            parse_ply(&b, p()).unwrap(),
            vec![Point3::new(0.5, -1.0, 2.0)]
        );
        let huge_grid = b"ply\nformat binary_little_endian 1.0\nelement grid 999999999999999999\n\
                          property int a\nelement vertex 0\nproperty float x\nproperty float y\n\
                          property float z\nend_header\n";
        expect_format_err(
            huge_grid,
            "element grid (999999999999999999 records) truncated",
        );
    }

    #[test]
    fn absurd_vertex_count_fails_without_allocating() {
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 999999999999999\n\
                      property float x\nproperty float y\nproperty float z\nend_header\n"
            .to_vec();
        b.extend([0u8; 24]);
        expect_format_err(&b, "truncated");
        let ascii =
            b"ply\nformat ascii 1.0\nelement vertex 18446744073709551615\nproperty float x\n\
                      property float y\nproperty float z\nend_header\n1 2 3\n";
        expect_format_err(ascii, "data ends early");
        // A list length that would need terabytes.
        let mut l =
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty list uint float n\n\
                      property float x\nproperty float y\nproperty float z\nend_header\n"
                .to_vec();
        l.extend(u32::MAX.to_le_bytes());
        expect_format_err(&l, "data ends early");
    }
}
