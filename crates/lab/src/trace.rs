//! The error of a solution against a reference solution, and its trace as a run goes.
//!
//! The error is `rms_rel` ([`mcrad_combine::rms_rel`]): the area-weighted relative RMS error
//! over the reflected light, dimensionless. A [`Reference`] holds what it needs per patch (area,
//! emission, reference radiosity in W/m²) in mesh order; a [`Trace`] writes one
//! `seconds,rays,rms_rel` line per solution it is given.

use glam::DVec3;
use mcrad_export::PatchRow;
use mcrad_meshing::Mesh;
use std::collections::HashMap;
use std::io::Write;

/// How the `patch` column of a reference's rows names the mesh's patches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Numbering {
    /// The patch's index in mesh order (a subdivided mesh).
    Index,
    /// The patch's input face index (`--no-subdivide`: one patch per face).
    Face,
}

/// Why a reference does not fit a mesh, or a trace could not be written.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// The reference has another number of patches than the mesh.
    #[error(
        "the reference has {rows} patches but the mesh has {patches}: solve both with the same subdivision"
    )]
    PatchCount {
        /// Patches in the reference.
        rows: usize,
        /// Patches in the mesh.
        patches: usize,
    },
    /// A reference row names a patch the mesh does not have.
    #[error("patch {patch} of the reference is not in the mesh")]
    UnknownPatch {
        /// The patch number of the row.
        patch: u32,
    },
    /// The trace could not be written.
    #[error("could not write the trace: {0}")]
    Io(std::io::Error),
}

// (not `#[from]`: that would also make the I/O error the `source()`, which the message
// already says)
impl From<std::io::Error> for TraceError {
    fn from(e: std::io::Error) -> TraceError {
        TraceError::Io(e)
    }
}

/// The relative difference between a reference row's area and its patch's beyond which
/// [`Reference::from_rows`] warns ([`AreaWarning`]): files written by other tools round areas
/// to 6-7 significant digits.
pub const AREA_TOLERANCE: f64 = 1e-5;

/// Reference rows whose areas differ from their patches' by more than [`AREA_TOLERANCE`]
/// (relative): a hint that the reference belongs to another mesh. The reference is still
/// used; the caller decides whether to print this.
#[derive(Debug, Clone, PartialEq)]
pub struct AreaWarning {
    /// How many rows differ beyond the tolerance.
    pub rows: usize,
    /// The patch number of the row that differs most (relatively).
    pub patch: u32,
    /// That row's area (scene units²).
    pub reference: f64,
    /// That patch's area in the mesh (scene units²).
    pub mesh: f64,
}

impl std::fmt::Display for AreaWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} of the reference's patch areas differ from the mesh's by more than {:e} \
             (relative), the most patch {}: {} in the reference, {} in the mesh: a different mesh?",
            self.rows, AREA_TOLERANCE, self.patch, self.reference, self.mesh
        )
    }
}

/// A reference solution of one mesh, for measuring the error of other solutions of it.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    area: Vec<f64>,
    emission: Vec<DVec3>,
    radiosity: Vec<DVec3>,
    warning: Option<AreaWarning>,
}

impl Reference {
    /// The reference radiosity `radiosity` (W/m², mesh order) of `mesh`.
    pub fn new(mesh: &Mesh, radiosity: Vec<DVec3>) -> Result<Reference, TraceError> {
        let patches = mesh.patches();
        if radiosity.len() != patches.len() {
            return Err(TraceError::PatchCount {
                rows: radiosity.len(),
                patches: patches.len(),
            });
        }
        Ok(Reference {
            area: patches.iter().map(|p| p.area).collect(),
            emission: patches.iter().map(|p| p.emission.as_dvec3()).collect(),
            radiosity,
            warning: None,
        })
    }

    /// The reference read from patch-CSV rows, matched to `mesh` patch by patch as `numbering`
    /// says. Areas that differ by more than [`AREA_TOLERANCE`] (relative) do not refuse the
    /// reference but are reported by [`Reference::warning`]. A patch no row names (only
    /// possible with repeated rows) gets a NaN reference.
    pub fn from_rows(
        mesh: &Mesh,
        rows: &[PatchRow],
        numbering: Numbering,
    ) -> Result<Reference, TraceError> {
        let patches = mesh.patches();
        if rows.len() != patches.len() {
            return Err(TraceError::PatchCount {
                rows: rows.len(),
                patches: patches.len(),
            });
        }
        let index: HashMap<u32, usize> = patches
            .iter()
            .enumerate()
            .map(|(i, p)| match numbering {
                Numbering::Face => (p.face, i),
                Numbering::Index => (i as u32, i),
            })
            .collect();
        let mut values = vec![DVec3::NAN; patches.len()];
        let mut warning: Option<(AreaWarning, f64)> = None;
        for row in rows {
            let Some(&i) = index.get(&row.patch) else {
                return Err(TraceError::UnknownPatch { patch: row.patch });
            };
            let area = patches[i].area;
            let relative = (row.area - area).abs() / area.max(1e-30);
            if relative > AREA_TOLERANCE {
                let w = warning.get_or_insert((
                    AreaWarning {
                        rows: 0,
                        patch: row.patch,
                        reference: row.area,
                        mesh: area,
                    },
                    relative,
                ));
                w.0.rows += 1;
                if relative > w.1 {
                    *w = (
                        AreaWarning {
                            rows: w.0.rows,
                            patch: row.patch,
                            reference: row.area,
                            mesh: area,
                        },
                        relative,
                    );
                }
            }
            values[i] = row.radiosity;
        }
        let mut reference = Reference::new(mesh, values)?;
        reference.warning = warning.map(|w| w.0);
        Ok(reference)
    }

    /// Rows whose areas differ from the mesh's beyond [`AREA_TOLERANCE`], if any (set by
    /// [`Reference::from_rows`]).
    pub fn warning(&self) -> Option<&AreaWarning> {
        self.warning.as_ref()
    }

    /// The reference radiosity per patch (W/m², mesh order).
    pub fn radiosity(&self) -> &[DVec3] {
        &self.radiosity
    }

    /// Patch areas (scene units², mesh order).
    pub fn area(&self) -> &[f64] {
        &self.area
    }

    /// Emitted radiosity per patch (W/m², mesh order).
    pub fn emission(&self) -> &[DVec3] {
        &self.emission
    }

    /// `rms_rel` of `radiosity` (W/m², mesh order, one value per patch) against the reference.
    pub fn rms_rel(&self, radiosity: &[DVec3]) -> f64 {
        mcrad_combine::rms_rel(&self.area, &self.emission, radiosity, &self.radiosity)
    }
}

/// A trace of a run's error: the header `seconds,rays,rms_rel`, then one line per
/// [`Trace::record`], flushed at once so a stopped run keeps what it has. Numbers are written
/// with Rust's shortest round-trip formatting.
#[derive(Debug)]
pub struct Trace<W: Write> {
    out: W,
    reference: Reference,
}

impl<W: Write> Trace<W> {
    /// Starts a trace against `reference` on `out` (writes the header).
    pub fn new(mut out: W, reference: Reference) -> Result<Trace<W>, TraceError> {
        writeln!(out, "seconds,rays,rms_rel")?;
        out.flush()?;
        Ok(Trace { out, reference })
    }

    /// Appends the error of `radiosity` (W/m², mesh order) reached after `seconds` of wall
    /// clock and `rays` rays; returns it.
    pub fn record(
        &mut self,
        seconds: f64,
        rays: u64,
        radiosity: &[DVec3],
    ) -> Result<f64, TraceError> {
        let e = self.reference.rms_rel(radiosity);
        writeln!(self.out, "{seconds},{rays},{e}")?;
        self.out.flush()?;
        Ok(e)
    }

    /// The reference the trace measures against.
    pub fn reference(&self) -> &Reference {
        &self.reference
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcrad_meshing::Subdivision;

    /// Two unit squares (faces 0 and 1), the second emitting.
    fn mesh(dir: &std::path::Path, subdivide: bool) -> Mesh {
        std::fs::write(
            dir.join("q.mtl"),
            "newmtl grey\nKd 0.5 0.5 0.5\nnewmtl lamp\nKd 0.5 0.5 0.5\nKe 1 1 1\n",
        )
        .unwrap();
        let obj = "mtllib q.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
                   v 0 0 1\nv 0 1 1\nv 1 1 1\nv 1 0 1\n\
                   usemtl grey\nf 1 2 3 4\nusemtl lamp\nf 5 6 7 8\n";
        std::fs::write(dir.join("q.obj"), obj).unwrap();
        let scene = mcrad_scene_io::load(&dir.join("q.obj")).unwrap().scene;
        let sub = if subdivide {
            Subdivision::MaxEdge(0.6)
        } else {
            Subdivision::None
        };
        Mesh::build(&scene, sub).unwrap()
    }

    fn rows(mesh: &Mesh, b: &[DVec3], numbering: Numbering) -> Vec<PatchRow> {
        mesh.patches()
            .iter()
            .zip(b)
            .enumerate()
            .map(|(i, (p, b))| PatchRow {
                patch: match numbering {
                    Numbering::Face => p.face,
                    Numbering::Index => i as u32,
                },
                area: p.area,
                radiosity: *b,
                variance: None,
                face: None,
            })
            .collect()
    }

    #[test]
    fn rows_match_by_number_and_the_trace_measures_rms_rel() {
        let dir = tempfile::tempdir().unwrap();
        let m = mesh(dir.path(), false);
        let b: Vec<DVec3> = m
            .patches()
            .iter()
            .map(|p| p.emission.as_dvec3() + DVec3::splat(0.2))
            .collect();
        let mut reversed = rows(&m, &b, Numbering::Face);
        reversed.reverse();
        let r = Reference::from_rows(&m, &reversed, Numbering::Face).unwrap();
        assert_eq!(r.radiosity(), b.as_slice());
        // 10% more reflected light everywhere: rms_rel 0.1.
        let brighter: Vec<DVec3> = m
            .patches()
            .iter()
            .map(|p| p.emission.as_dvec3() + DVec3::splat(0.22))
            .collect();
        let mut out = Vec::new();
        let mut t = Trace::new(&mut out, r.clone()).unwrap();
        assert_eq!(t.record(1.5, 100, &b).unwrap(), 0.0);
        let e = t.record(3.0, 200, &brighter).unwrap();
        assert!((e - 0.1).abs() < 1e-12, "{e}");
        let text = String::from_utf8(out).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[..2], ["seconds,rays,rms_rel", "1.5,100,0"]);
        assert!(lines[2].starts_with("3,200,0.1"), "{text}");
    }

    #[test]
    fn a_reference_of_another_mesh_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let (coarse, fine) = (mesh(dir.path(), false), mesh(dir.path(), true));
        let b = vec![DVec3::ONE; coarse.patches().len()];
        let coarse_rows = rows(&coarse, &b, Numbering::Index);
        assert!(matches!(
            Reference::from_rows(&fine, &coarse_rows, Numbering::Index),
            Err(TraceError::PatchCount { .. })
        ));
        let mut unknown = coarse_rows.clone();
        unknown[0].patch = 9;
        assert!(matches!(
            Reference::from_rows(&coarse, &unknown, Numbering::Index),
            Err(TraceError::UnknownPatch { patch: 9 })
        ));
        // A 7th-digit difference (as another tool's rounding makes) passes silently; one
        // beyond the relative tolerance is a warning, not a refusal.
        let mut rounded = coarse_rows.clone();
        rounded[1].area *= 1.0 + 2e-6;
        let r = Reference::from_rows(&coarse, &rounded, Numbering::Index).unwrap();
        assert_eq!(r.warning(), None);
        let mut wrong_area = coarse_rows;
        wrong_area[1].area *= 1.01;
        wrong_area[0].area *= 1.001;
        let r = Reference::from_rows(&coarse, &wrong_area, Numbering::Index).unwrap();
        let w = r.warning().expect("areas 0.1% and 1% off warn");
        assert_eq!((w.rows, w.patch), (2, 1));
        assert!(
            w.to_string()
                .starts_with("2 of the reference's patch areas"),
            "{w}"
        );
    }
}
