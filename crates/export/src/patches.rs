//! The per-patch CSV: `patch,area,r,g,b,var_r,var_g,var_b`, and optionally `face`.

use crate::ExportError;
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::io::Write;

/// One row of the per-patch CSV.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchRow {
    /// The patch's number: its index in mesh order, or with `--no-subdivide` its input face index.
    pub patch: u32,
    /// Area in scene units².
    pub area: f64,
    /// Radiosity `B` per RGB channel, W/m².
    pub radiosity: DVec3,
    /// Estimated variance of `B` per channel, (W/m²)²; `None` is written as blank fields.
    pub variance: Option<DVec3>,
    /// The input face the patch belongs to (its `source` index), written in a last column
    /// `face` when the first row has one ([`PATCH_CSV_FACE_HEADER`]); `None` in files without
    /// that column.
    pub face: Option<u32>,
}

/// The header of the per-patch CSV.
pub const PATCH_CSV_HEADER: [&str; 8] = ["patch", "area", "r", "g", "b", "var_r", "var_g", "var_b"];

/// The header of a per-patch CSV whose rows name their input face: [`PATCH_CSV_HEADER`] and
/// `face`.
pub const PATCH_CSV_FACE_HEADER: [&str; 9] = [
    "patch", "area", "r", "g", "b", "var_r", "var_g", "var_b", "face",
];

/// An `f64` written with Rust's shortest round-trip formatting (`Display`: no exponent,
/// `2` for 2.0), which the CSV files have always used.
struct Shortest(f64);

impl Serialize for Shortest {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(&self.0)
    }
}

/// One written row; field order is [`PATCH_CSV_HEADER`]'s.
#[derive(Serialize)]
struct WriteRow {
    patch: u32,
    area: Shortest,
    r: Shortest,
    g: Shortest,
    b: Shortest,
    var_r: Option<Shortest>,
    var_g: Option<Shortest>,
    var_b: Option<Shortest>,
    #[serde(skip_serializing_if = "Option::is_none")]
    face: Option<FaceField>,
}

/// The `face` column's field: the face number, or blank.
struct FaceField(Option<u32>);

impl Serialize for FaceField {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self.0 {
            Some(face) => serializer.serialize_u32(face),
            None => serializer.serialize_str(""),
        }
    }
}

impl From<PatchRow> for WriteRow {
    fn from(row: PatchRow) -> WriteRow {
        let (b, v) = (row.radiosity, row.variance);
        WriteRow {
            patch: row.patch,
            area: Shortest(row.area),
            r: Shortest(b.x),
            g: Shortest(b.y),
            b: Shortest(b.z),
            var_r: v.map(|v| Shortest(v.x)),
            var_g: v.map(|v| Shortest(v.y)),
            var_b: v.map(|v| Shortest(v.z)),
            face: None,
        }
    }
}

/// The rows of a solution on `mesh`: patch `i` numbered `patch[i]`, with its area, its
/// radiosity `radiosity[i]` (W/m²), its variance `variance[i]` ((W/m²)², where known) and its
/// input face; the back side of a two-sided face `f` has the face `f + N`
/// ([`mcrad_meshing::Mesh::back_face_offset`]), so [`per_face`] gives each side its own row. The slices have one entry per patch, in mesh order.
pub fn patch_rows<'a>(
    mesh: &'a mcrad_meshing::Mesh,
    patch: &'a [u32],
    radiosity: &'a [DVec3],
    variance: Option<&'a [DVec3]>,
) -> impl Iterator<Item = PatchRow> + 'a {
    let back = mesh.back_face_offset();
    mesh.patches()
        .iter()
        .enumerate()
        .map(move |(i, p)| PatchRow {
            patch: patch[i],
            area: p.area,
            radiosity: radiosity[i],
            variance: variance.map(|v| v[i]),
            face: Some(p.face + if p.back { back } else { 0 }),
        })
}

/// One row per input face, in face order: the area-weighted means `sum A_i B_i / sum A_i` of
/// its patches' rows (W/m²), with the variance of that mean `k_f sum (A_i / A)² V_i` (unknown
/// when a patch's is) and the face's area `A` (scene units²). `k_f` is
/// `face_correlation[f]` per channel, the factor the correlation between the face's patches
/// puts on their independent sum (the solver's estimate, dimensionless, 1 for a face of one
/// patch); without it (`None`, or a face beyond the slice) the patches are taken as
/// independent, `k_f = 1`. A row's face is [`PatchRow::face`], or its `patch` without one;
/// the result's `patch` is the face number and its `face` is `None`.
pub fn per_face(
    rows: impl IntoIterator<Item = PatchRow>,
    face_correlation: Option<&[DVec3]>,
) -> Vec<PatchRow> {
    use std::collections::BTreeMap;
    // face -> (area, sum A B, sum A² V, every patch had a variance)
    let mut faces: BTreeMap<u32, (f64, DVec3, DVec3, bool)> = BTreeMap::new();
    for r in rows {
        let face = r.face.unwrap_or(r.patch);
        let e = faces
            .entry(face)
            .or_insert((0.0, DVec3::ZERO, DVec3::ZERO, true));
        e.0 += r.area;
        e.1 += r.area * r.radiosity;
        match r.variance {
            Some(v) => e.2 += r.area * r.area * v,
            None => e.3 = false,
        }
    }
    faces
        .into_iter()
        .map(|(face, (area, sum, var, has_var))| PatchRow {
            patch: face,
            area,
            radiosity: sum / area,
            variance: has_var.then(|| {
                let k = face_correlation
                    .and_then(|k| k.get(face as usize))
                    .copied()
                    .unwrap_or(DVec3::ONE);
                k * var / (area * area)
            }),
            face: None,
        })
        .collect()
}

/// Writes the header `patch,area,r,g,b,var_r,var_g,var_b` and one line per row (`\n` line
/// ends, no quoting). Numbers are written with Rust's shortest round-trip formatting, so reading
/// them back gives the same f64; a `None` variance is three blank fields. When the first row
/// has a [`PatchRow::face`], the header and every line end in a column `face`
/// ([`PATCH_CSV_FACE_HEADER`]; a later row without one writes it blank).
pub fn write_patch_csv<W: Write>(
    out: W,
    rows: impl IntoIterator<Item = PatchRow>,
) -> Result<(), ExportError> {
    let fail = |e: csv::Error| ExportError::Io {
        what: "the patch CSV",
        reason: e.into(),
    };
    let mut csv = csv::WriterBuilder::new()
        .has_headers(false)
        .from_writer(out);
    let mut rows = rows.into_iter().peekable();
    let with_face = rows.peek().is_some_and(|r| r.face.is_some());
    if with_face {
        csv.write_record(PATCH_CSV_FACE_HEADER).map_err(fail)?;
    } else {
        csv.write_record(PATCH_CSV_HEADER).map_err(fail)?;
    }
    for row in rows {
        let mut written = WriteRow::from(row);
        written.face = with_face.then_some(FaceField(row.face));
        csv.serialize(written).map_err(fail)?;
    }
    csv.flush().map_err(|source| ExportError::Io {
        what: "the patch CSV",
        reason: source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_face_row_is_the_area_weighted_mean_with_its_correlation_factor() {
        let row = |area: f64, b: f64, v: f64, face: u32| PatchRow {
            patch: 0,
            area,
            radiosity: DVec3::splat(b),
            variance: Some(DVec3::splat(v)),
            face: Some(face),
        };
        // Face 0: patches of areas 1 and 3; face 1: one patch.
        let rows = [
            row(1.0, 2.0, 4.0, 0),
            row(3.0, 6.0, 8.0, 0),
            row(2.0, 1.0, 3.0, 1),
        ];
        let independent = per_face(rows, None);
        assert_eq!(independent.len(), 2);
        assert_eq!(independent[0].radiosity, DVec3::splat(5.0));
        // (1/4)² 4 + (3/4)² 8 = 4.75
        assert_eq!(independent[0].variance, Some(DVec3::splat(4.75)));
        assert_eq!(independent[1].variance, Some(DVec3::splat(3.0)));
        // The solver's factors scale each face's independent sum, per channel; a face beyond
        // them keeps it.
        let k = [DVec3::new(2.0, 0.5, 1.0)];
        let correlated = per_face(rows, Some(&k));
        assert_eq!(correlated[0].variance, Some(DVec3::new(9.5, 2.375, 4.75)));
        assert_eq!(correlated[1].variance, Some(DVec3::splat(3.0)));
    }

    #[test]
    fn rows_round_trip_exactly() {
        let rows = [
            PatchRow {
                patch: 7,
                area: 0.1 + 0.2,
                radiosity: DVec3::new(1.0 / 3.0, 2.5e-12, 0.0),
                variance: Some(DVec3::splat(1e-7)),
                face: None,
            },
            PatchRow {
                patch: 9,
                area: 2.0,
                radiosity: DVec3::ONE,
                variance: None,
                face: None,
            },
        ];
        let mut buf = Vec::new();
        write_patch_csv(&mut buf, rows).unwrap();
        let text = String::from_utf8(buf).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], "patch,area,r,g,b,var_r,var_g,var_b");
        let f: Vec<&str> = lines[1].split(',').collect();
        assert_eq!(f[0], "7");
        assert_eq!(f[1].parse::<f64>().unwrap(), 0.1 + 0.2);
        assert_eq!(f[2].parse::<f64>().unwrap(), 1.0 / 3.0);
        assert_eq!(f[6].parse::<f64>().unwrap(), 1e-7);
        assert_eq!(lines[2], "9,2,1,1,1,,,");
        // The bytes of the format: `Display` numbers (no exponent), `\n` line ends.
        let mut buf = Vec::new();
        write_patch_csv(
            &mut buf,
            [PatchRow {
                patch: 0,
                area: 0.1 + 0.2,
                radiosity: DVec3::new(1e-7, 2.0, 1e21),
                variance: Some(DVec3::new(0.5, 0.0, 3.25)),
                face: None,
            }],
        )
        .unwrap();
        assert_eq!(
            String::from_utf8(buf).unwrap(),
            "patch,area,r,g,b,var_r,var_g,var_b\n\
             0,0.30000000000000004,0.0000001,2,1000000000000000000000,0.5,0,3.25\n"
        );
    }
}

/// Why a patch CSV could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadCsvError {
    /// The file could not be read.
    #[error("could not read {path}: {reason}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The underlying error.
        reason: std::io::Error,
    },
    /// The path is not a regular file (a device, pipe or directory).
    #[error("{} is not a regular file (a device, pipe or directory): only regular files are read",
        path.display())]
    NotAFile {
        /// The path.
        path: std::path::PathBuf,
    },
    /// A line is not a patch row.
    #[error("{path} line {line}: {reason}")]
    Parse {
        /// The file.
        path: std::path::PathBuf,
        /// 1-based line number.
        line: u64,
        /// What is wrong.
        reason: String,
    },
}

/// One read row; fields are matched to [`PATCH_CSV_HEADER`] by name.
#[derive(Deserialize)]
struct ReadRow {
    patch: u32,
    area: f64,
    r: f64,
    g: f64,
    b: f64,
    var_r: Option<f64>,
    var_g: Option<f64>,
    var_b: Option<f64>,
    #[serde(default)]
    face: Option<u32>,
}

/// Reads a patch CSV written by [`write_patch_csv`] (blank variances read as `None`; blank
/// lines and spaces around fields are ignored), with or without its last column `face`, or one
/// with the header `patch,area,r,g,b` and no variance columns, as other tools write them
/// (variances `None`). Every number must be finite, and the three
/// variances all given or all blank.
///
/// Only a regular file is read (a device such as `/dev/zero` would never end).
pub fn read_patch_csv(path: &std::path::Path) -> Result<Vec<PatchRow>, ReadCsvError> {
    let io = |source| ReadCsvError::Io {
        path: path.to_path_buf(),
        reason: source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    if !file.metadata().map_err(io)?.is_file() {
        return Err(ReadCsvError::NotAFile {
            path: path.to_path_buf(),
        });
    }
    read_rows(std::io::BufReader::new(file), path)
}

fn read_rows<R: std::io::Read>(
    input: R,
    path: &std::path::Path,
) -> Result<Vec<PatchRow>, ReadCsvError> {
    let parse_err = |line: u64, reason: String| ReadCsvError::Parse {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let from_csv = |e: csv::Error| {
        let line = e.position().map_or(0, csv::Position::line);
        match e.into_kind() {
            csv::ErrorKind::Io(source) => ReadCsvError::Io {
                path: path.to_path_buf(),
                reason: source,
            },
            csv::ErrorKind::UnequalLengths {
                expected_len, len, ..
            } => parse_err(line, format!("expected {expected_len} fields, found {len}")),
            other => parse_err(line, format!("{other:?}")),
        }
    };
    let mut csv = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_reader(input);
    let header = csv.headers().map_err(from_csv)?.clone();
    // The full header with or without `face`, or its first five columns (other tools write
    // no variances).
    let columns = header.len();
    if !(columns == PATCH_CSV_FACE_HEADER.len()
        || columns == PATCH_CSV_HEADER.len()
        || columns == 5)
        || header
            .iter()
            .ne(PATCH_CSV_FACE_HEADER[..columns].iter().copied())
    {
        return Err(parse_err(
            1,
            "the header must be patch,area,r,g,b,var_r,var_g,var_b[,face] or patch,area,r,g,b"
                .into(),
        ));
    }
    let mut rows = Vec::new();
    for record in csv.records() {
        let record = record.map_err(from_csv)?;
        let line = record.position().map_or(0, csv::Position::line);
        let row: ReadRow = record.deserialize(Some(&header)).map_err(|e| {
            let field = match e.kind() {
                csv::ErrorKind::Deserialize { err, .. } => err.field().map_or(0, |f| f as usize),
                _ => 0,
            };
            let what = if field == 0 {
                "a patch number"
            } else {
                "a number"
            };
            parse_err(
                line,
                format!(
                    "'{}' in column {} is not {what}",
                    record.get(field).unwrap_or(""),
                    PATCH_CSV_FACE_HEADER[field.min(8)]
                ),
            )
        })?;
        let values = [
            row.area,
            row.r,
            row.g,
            row.b,
            row.var_r.unwrap_or(0.0),
            row.var_g.unwrap_or(0.0),
            row.var_b.unwrap_or(0.0),
        ];
        if let Some(x) = values.iter().find(|x| !x.is_finite()) {
            return Err(parse_err(line, format!("'{x}' is not a finite number")));
        }
        let variance = match (row.var_r, row.var_g, row.var_b) {
            (Some(r), Some(g), Some(b)) => Some(DVec3::new(r, g, b)),
            (None, None, None) => None,
            _ => {
                return Err(parse_err(
                    line,
                    "the variances must be all given or all blank".into(),
                ));
            }
        };
        rows.push(PatchRow {
            patch: row.patch,
            area: row.area,
            radiosity: DVec3::new(row.r, row.g, row.b),
            variance,
            face: row.face,
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod read_tests {
    use super::*;

    #[test]
    fn written_rows_read_back_and_bad_files_name_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.csv");
        let rows = vec![
            PatchRow {
                patch: 3,
                area: 0.25,
                radiosity: DVec3::new(1.0 / 3.0, 2.0, 0.0),
                variance: Some(DVec3::splat(1e-9)),
                face: None,
            },
            PatchRow {
                patch: 4,
                area: 1.5,
                radiosity: DVec3::ONE,
                variance: None,
                face: None,
            },
        ];
        write_patch_csv(std::fs::File::create(&path).unwrap(), rows.clone()).unwrap();
        assert_eq!(read_patch_csv(&path).unwrap(), rows);
        std::fs::write(
            &path,
            "patch,area,r,g,b,var_r,var_g,var_b\n0,1,2,3,4,,,\n1,1,x,3,4,,,\n",
        )
        .unwrap();
        let err = read_patch_csv(&path).unwrap_err().to_string();
        assert!(err.contains("p.csv line 3") && err.contains("'x'"), "{err}");
        std::fs::write(
            &path,
            "patch,area,r,g,b,var_r,var_g,var_b\n 0 , 1,2,3,4,5,6,7\n1,1,2,3,4,,6,\n\n",
        )
        .unwrap();
        let err = read_patch_csv(&path).unwrap_err().to_string();
        assert!(err.contains("line 3") && err.contains("all given"), "{err}");
        std::fs::write(&path, "patch,area,r,g,b,var_r,var_g,var_b\n0,1,2,3\n").unwrap();
        let err = read_patch_csv(&path).unwrap_err().to_string();
        assert!(err.contains("line 2") && err.contains("8 fields"), "{err}");
        std::fs::write(
            &path,
            "patch,area,r,g,b,var_r,var_g,var_b\n0,inf,2,3,4,,,\n",
        )
        .unwrap();
        let err = read_patch_csv(&path).unwrap_err().to_string();
        assert!(err.contains("not a finite number"), "{err}");
        // Other tools' files: the first five columns, no variances.
        std::fs::write(&path, "patch,area,r,g,b\n3,0.25,1,2,0\n4, 1.5 ,1,1,1\n").unwrap();
        let short = read_patch_csv(&path).unwrap();
        assert_eq!(short.len(), 2);
        assert_eq!(short[1].radiosity, DVec3::ONE);
        assert!(short.iter().all(|r| r.variance.is_none()));
        std::fs::write(&path, "patch,area,r,g,b\n0,1,2,3,4,5\n").unwrap();
        let err = read_patch_csv(&path).unwrap_err().to_string();
        assert!(err.contains("line 2") && err.contains("5 fields"), "{err}");
        std::fs::write(&path, "patch,area,r,g\n0,1,2,3\n").unwrap();
        assert!(
            read_patch_csv(&path)
                .unwrap_err()
                .to_string()
                .contains("header")
        );
        std::fs::write(&path, "a,b\n").unwrap();
        assert!(
            read_patch_csv(&path)
                .unwrap_err()
                .to_string()
                .contains("header")
        );
    }

    #[test]
    fn the_face_column_is_written_when_rows_have_faces_and_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.csv");
        let rows = vec![
            PatchRow {
                patch: 0,
                area: 0.5,
                radiosity: DVec3::ONE,
                variance: Some(DVec3::splat(0.25)),
                face: Some(7),
            },
            PatchRow {
                patch: 1,
                area: 0.5,
                radiosity: DVec3::ONE,
                variance: None,
                face: None,
            },
        ];
        write_patch_csv(std::fs::File::create(&path).unwrap(), rows.clone()).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            text,
            "patch,area,r,g,b,var_r,var_g,var_b,face\n0,0.5,1,1,1,0.25,0.25,0.25,7\n1,0.5,1,1,1,,,,\n"
        );
        assert_eq!(read_patch_csv(&path).unwrap(), rows);
        // Rows without faces keep today's header and columns.
        let plain: Vec<PatchRow> = rows.iter().map(|r| PatchRow { face: None, ..*r }).collect();
        write_patch_csv(std::fs::File::create(&path).unwrap(), plain.clone()).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            text.starts_with("patch,area,r,g,b,var_r,var_g,var_b\n0,0.5,1,1,1,0.25,0.25,0.25\n")
        );
        assert_eq!(read_patch_csv(&path).unwrap(), plain);
    }
}
