//! The per-patch CSV: `patch,area,r,g,b,var_r,var_g,var_b`.

use crate::ExportError;
use glam::DVec3;
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
}

/// Writes the header `patch,area,r,g,b,var_r,var_g,var_b` and one line per row. Numbers are
/// written with Rust's shortest round-trip formatting, so reading them back gives the same f64.
pub fn write_patch_csv<W: Write>(
    mut out: W,
    rows: impl IntoIterator<Item = PatchRow>,
) -> Result<(), ExportError> {
    let io = |source| ExportError::Io {
        what: "the patch CSV",
        source,
    };
    writeln!(out, "patch,area,r,g,b,var_r,var_g,var_b").map_err(io)?;
    for row in rows {
        let b = row.radiosity;
        match row.variance {
            Some(v) => writeln!(
                out,
                "{},{},{},{},{},{},{},{}",
                row.patch, row.area, b.x, b.y, b.z, v.x, v.y, v.z
            ),
            None => writeln!(out, "{},{},{},{},{},,,", row.patch, row.area, b.x, b.y, b.z),
        }
        .map_err(io)?;
    }
    out.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_round_trip_exactly() {
        let rows = [
            PatchRow {
                patch: 7,
                area: 0.1 + 0.2,
                radiosity: DVec3::new(1.0 / 3.0, 2.5e-12, 0.0),
                variance: Some(DVec3::splat(1e-7)),
            },
            PatchRow {
                patch: 9,
                area: 2.0,
                radiosity: DVec3::ONE,
                variance: None,
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
    }
}

/// Why a patch CSV could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadCsvError {
    /// The file could not be read.
    #[error("could not read {path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A line is not a patch row.
    #[error("{path} line {line}: {reason}")]
    Parse {
        /// The file.
        path: std::path::PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
}

/// Reads a patch CSV written by [`write_patch_csv`] (blank variances read as `None`).
pub fn read_patch_csv(path: &std::path::Path) -> Result<Vec<PatchRow>, ReadCsvError> {
    let text = std::fs::read_to_string(path).map_err(|source| ReadCsvError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let parse_err = |line: usize, reason: String| ReadCsvError::Parse {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == "patch,area,r,g,b,var_r,var_g,var_b" => {}
        _ => {
            return Err(parse_err(
                1,
                "the header must be patch,area,r,g,b,var_r,var_g,var_b".into(),
            ));
        }
    }
    let mut rows = Vec::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != 8 {
            return Err(parse_err(
                i + 1,
                format!("expected 8 fields, found {}", f.len()),
            ));
        }
        let num = |k: usize| -> Result<f64, ReadCsvError> {
            f[k].parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| parse_err(i + 1, format!("'{}' is not a finite number", f[k])))
        };
        let patch = f[0]
            .parse::<u32>()
            .map_err(|_| parse_err(i + 1, format!("'{}' is not a patch number", f[0])))?;
        let variance = if f[5..].iter().all(|x| x.is_empty()) {
            None
        } else {
            Some(DVec3::new(num(5)?, num(6)?, num(7)?))
        };
        rows.push(PatchRow {
            patch,
            area: num(1)?,
            radiosity: DVec3::new(num(2)?, num(3)?, num(4)?),
            variance,
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
            },
            PatchRow {
                patch: 4,
                area: 1.5,
                radiosity: DVec3::ONE,
                variance: None,
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
        std::fs::write(&path, "a,b\n").unwrap();
        assert!(
            read_patch_csv(&path)
                .unwrap_err()
                .to_string()
                .contains("header")
        );
    }
}
