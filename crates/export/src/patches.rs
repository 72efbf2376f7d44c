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
