//! `--reference R.csv --trace T.csv`: the error of each step against a reference, as the run goes
//! (the matching and the trace format are `mcrad_lab::trace`'s).

use anyhow::{Context, Result};
use glam::DVec3;
use mcrad_export::read_patch_csv;
use mcrad_lab::trace::{Numbering, Reference, Trace};
use mcrad_meshing::Mesh;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// Writes `seconds,rays,rms_rel` rows, flushed after each so a stopped run keeps its trace.
pub struct Tracer(Trace<BufWriter<File>>);

impl Tracer {
    /// Reads the reference and matches it to `mesh` patch by patch: by input face number with
    /// `--no-subdivide`, by mesh index otherwise. Areas that differ beyond a relative 1e-5 are
    /// a warning on stderr.
    pub fn new(mesh: &Mesh, reference: &Path, trace: &Path, by_face: bool) -> Result<Tracer> {
        let rows = read_patch_csv(reference)?;
        let numbering = if by_face {
            Numbering::Face
        } else {
            Numbering::Index
        };
        let reference_file = reference;
        let reference = Reference::from_rows(mesh, &rows, numbering).with_context(|| {
            format!(
                "--reference {} (solve it with the same --no-subdivide / --max-edge)",
                reference_file.display()
            )
        })?;
        if let Some(w) = reference.warning() {
            eprintln!("warning: --reference {}: {w}", reference_file.display());
        }
        let file =
            File::create(trace).with_context(|| format!("could not create {}", trace.display()))?;
        let trace = Trace::new(BufWriter::new(file), reference)
            .with_context(|| format!("could not write {}", trace.display()))?;
        Ok(Tracer(trace))
    }

    /// Appends the error of `radiosity` after `seconds` and `rays`.
    pub fn record(&mut self, seconds: f64, rays: u64, radiosity: &[DVec3]) -> Result<()> {
        self.0.record(seconds, rays, radiosity)?;
        Ok(())
    }
}
