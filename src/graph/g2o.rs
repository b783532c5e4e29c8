//! g2o text format for 3-D pose graphs (`VERTEX_SE3:QUAT`, `EDGE_SE3:QUAT`), as read by g2o and by
//! GTSAM's `readG2o`.
//!
//! ```text
//! VERTEX_SE3:QUAT id x y z qx qy qz qw
//! EDGE_SE3:QUAT id_from id_to x y z qx qy qz qw I11 I12 … I16 I22 … I66
//! ```
//!
//! The 21 information entries are the upper triangle, row by row, in g2o's **(translation,
//! rotation)** order; [`Edge::information`] is in (rotation, translation) order, so rows and
//! columns are permuted on the way in and out.
//! NOTE: like GTSAM's `readG2o`, the rotation block is taken as is — g2o's own EDGE_SE3 error uses
//! the quaternion's vector part (≈ half the angle), so a g2o solver reads the same numbers as 4×
//! weaker rotation information.
//!
//! Vertex ids may be any distinct non-negative integers; node `k` of the [`PoseGraph`] is the `k`-th
//! vertex in the file. `write_g2o` numbers vertices `0..n`. `FIX id` is accepted for the first vertex
//! only (the solver always fixes node 0). Empty lines and lines starting with `#` are skipped.
//! The g2o format has no robust flag: every edge is read with `robust = false`.

use std::collections::HashMap;
use std::fmt::Write as _;

use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};

use super::{Edge, PoseGraph};
use crate::{Error, Result};

/// A quaternion whose norm is further than this from 1 is rejected (g2o files print ~6–9 digits).
const QUATERNION_NORM_TOL: f64 = 1e-3;

/// Maps a (rotation, translation) index to the (translation, rotation) one and back (an involution).
const fn swap_halves(i: usize) -> usize {
    (i + 3) % 6
}

fn parse_error(line: usize, field: &str, detail: impl Into<String>) -> Error {
    Error::Parse {
        line,
        field: field.to_owned(),
        detail: detail.into(),
    }
}

/// Tokens of one record with the line number, for field-named errors.
struct Record<'a> {
    line: usize,
    tokens: std::str::SplitWhitespace<'a>,
}

impl<'a> Record<'a> {
    fn next(&mut self, field: &str) -> Result<&'a str> {
        self.tokens
            .next()
            .ok_or_else(|| parse_error(self.line, field, "missing"))
    }

    fn f64(&mut self, field: &str) -> Result<f64> {
        let token = self.next(field)?;
        match token.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(parse_error(
                self.line,
                field,
                format!("`{token}` is not a finite number"),
            )),
        }
    }

    fn id(&mut self, field: &str) -> Result<u64> {
        let token = self.next(field)?;
        token.parse::<u64>().map_err(|_| {
            parse_error(
                self.line,
                field,
                format!("`{token}` is not a non-negative integer id"),
            )
        })
    }

    fn pose(&mut self) -> Result<Isometry3<f64>> {
        let [x, y, z] = [self.f64("x")?, self.f64("y")?, self.f64("z")?];
        let [qx, qy, qz, qw] = [
            self.f64("qx")?,
            self.f64("qy")?,
            self.f64("qz")?,
            self.f64("qw")?,
        ];
        let q = Quaternion::new(qw, qx, qy, qz);
        if (q.norm() - 1.0).abs() > QUATERNION_NORM_TOL {
            return Err(parse_error(
                self.line,
                "qw",
                format!("quaternion norm {} is not 1", q.norm()),
            ));
        }
        Ok(Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_quaternion(q),
        ))
    }

    fn finish(mut self) -> Result<()> {
        match self.tokens.next() {
            None => Ok(()),
            Some(extra) => Err(parse_error(
                self.line,
                "end of line",
                format!("unexpected extra token `{extra}`"),
            )),
        }
    }
}

/// Parses a g2o 3-D pose graph.
///
/// # Errors
/// [`Error::Parse`] naming the 1-based line and the field for an unknown record type, a missing,
/// non-numeric or non-finite field, a non-unit quaternion, a duplicate vertex id, an edge to an
/// unknown vertex or to itself, an information matrix with a non-positive diagonal, `FIX` of any
/// vertex but the first, or extra tokens.
pub fn read_g2o(text: &str) -> Result<PoseGraph> {
    let mut graph = PoseGraph::default();
    let mut index_of: HashMap<u64, usize> = HashMap::new();
    let mut first_id = None;
    for (k, raw) in text.lines().enumerate() {
        let line = k + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let mut rec = Record {
            line,
            tokens: content.split_whitespace(),
        };
        let tag = rec.next("tag")?;
        match tag {
            "VERTEX_SE3:QUAT" => {
                let id = rec.id("id")?;
                let pose = rec.pose()?;
                rec.finish()?;
                if index_of.insert(id, graph.poses.len()).is_some() {
                    return Err(parse_error(line, "id", format!("duplicate vertex id {id}")));
                }
                first_id.get_or_insert(id);
                graph.poses.push(pose);
            }
            "EDGE_SE3:QUAT" => {
                let mut ends = [0; 2];
                for (end, field) in ends.iter_mut().zip(["id_from", "id_to"]) {
                    let id = rec.id(field)?;
                    *end = *index_of.get(&id).ok_or_else(|| {
                        parse_error(line, field, format!("vertex {id} is not defined above"))
                    })?;
                }
                if ends[0] == ends[1] {
                    return Err(parse_error(line, "id_to", "edge joins a vertex to itself"));
                }
                let measurement = rec.pose()?;
                let mut information = Matrix6::zeros();
                let mut n = 0;
                for r in 0..6 {
                    for c in r..6 {
                        let v = rec.f64(&format!("info[{n}]"))?;
                        let (i, j) = (swap_halves(r), swap_halves(c));
                        information[(i, j)] = v;
                        information[(j, i)] = v;
                        n += 1;
                    }
                }
                rec.finish()?;
                if let Some(d) = (0..6).find(|&d| information[(d, d)] <= 0.0) {
                    return Err(parse_error(
                        line,
                        &format!("info diagonal {}", swap_halves(d) + 1),
                        "information diagonal must be positive",
                    ));
                }
                graph.edges.push(Edge {
                    from: ends[0],
                    to: ends[1],
                    measurement,
                    information,
                    robust: false,
                });
            }
            "FIX" => {
                let id = rec.id("id")?;
                rec.finish()?;
                if Some(id) != first_id {
                    return Err(parse_error(
                        line,
                        "id",
                        "only the first vertex can be fixed (the solver fixes node 0)",
                    ));
                }
            }
            other => {
                return Err(parse_error(
                    line,
                    "tag",
                    format!(
                        "unsupported record `{other}` (expected VERTEX_SE3:QUAT, EDGE_SE3:QUAT or FIX)"
                    ),
                ));
            }
        }
    }
    Ok(graph)
}

fn write_pose(out: &mut String, pose: &Isometry3<f64>) {
    let t = pose.translation.vector;
    let q = pose.rotation.quaternion();
    // `{}` prints the shortest representation that parses back to the same f64.
    let _ = write!(
        out,
        " {} {} {} {} {} {} {}",
        t.x, t.y, t.z, q.i, q.j, q.k, q.w
    );
}

/// Writes `graph` as g2o text (vertex ids `0..n`, full f64 precision, one record per line).
#[must_use]
pub fn write_g2o(graph: &PoseGraph) -> String {
    let mut out = String::new();
    for (k, pose) in graph.poses.iter().enumerate() {
        let _ = write!(out, "VERTEX_SE3:QUAT {k}");
        write_pose(&mut out, pose);
        out.push('\n');
    }
    for e in &graph.edges {
        let _ = write!(out, "EDGE_SE3:QUAT {} {}", e.from, e.to);
        write_pose(&mut out, &e.measurement);
        for r in 0..6 {
            for c in r..6 {
                let _ = write!(out, " {}", e.information[(swap_halves(r), swap_halves(c))]);
            }
        }
        out.push('\n');
    }
    out
}
