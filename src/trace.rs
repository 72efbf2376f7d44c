//! `--reference R.csv --trace T.csv`: the error of each step against a reference, as the run goes.

use anyhow::{Context, Result, bail};
use glam::DVec3;
use mcrad_combine::rms_rel;
use mcrad_export::read_patch_csv;
use mcrad_meshing::Mesh;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

/// Writes `seconds,rays,rms_rel` rows, flushed after each so a stopped run keeps its trace.
pub struct Tracer {
    out: BufWriter<File>,
    area: Vec<f64>,
    emission: Vec<DVec3>,
    reference: Vec<DVec3>,
}

impl Tracer {
    /// Reads the reference and matches it to `mesh` patch by patch: by input face number with
    /// `--no-subdivide`, by mesh index otherwise. The areas must agree.
    pub fn new(mesh: &Mesh, reference: &Path, trace: &Path, by_face: bool) -> Result<Tracer> {
        let rows = read_patch_csv(reference)?;
        let patches = mesh.patches();
        if rows.len() != patches.len() {
            bail!(
                "--reference {} has {} patches but this mesh has {}: solve it with the same --no-subdivide / --max-edge",
                reference.display(),
                rows.len(),
                patches.len()
            );
        }
        let mut values = vec![None; patches.len()];
        let index: std::collections::HashMap<u32, usize> = patches
            .iter()
            .enumerate()
            .map(|(i, p)| (if by_face { p.face } else { i as u32 }, i))
            .collect();
        for row in rows {
            let Some(&i) = index.get(&row.patch) else {
                bail!(
                    "--reference {}: patch {} is not in this mesh",
                    reference.display(),
                    row.patch
                );
            };
            let area = patches[i].area;
            if (row.area - area).abs() > 1e-6 * area.max(1e-30) {
                bail!(
                    "--reference {}: patch {} has area {} but this mesh's has {area}: a different mesh?",
                    reference.display(),
                    row.patch,
                    row.area
                );
            }
            values[i] = Some(row.radiosity);
        }
        let reference_values = values
            .into_iter()
            .map(|v| v.unwrap_or(DVec3::NAN))
            .collect();
        let file =
            File::create(trace).with_context(|| format!("could not create {}", trace.display()))?;
        let mut out = BufWriter::new(file);
        writeln!(out, "seconds,rays,rms_rel")?;
        Ok(Tracer {
            out,
            area: patches.iter().map(|p| p.area).collect(),
            emission: patches.iter().map(|p| p.emission.as_dvec3()).collect(),
            reference: reference_values,
        })
    }

    /// Appends the error of `radiosity` after `seconds` and `rays`.
    pub fn record(&mut self, seconds: f64, rays: u64, radiosity: &[DVec3]) -> Result<()> {
        let e = rms_rel(&self.area, &self.emission, radiosity, &self.reference);
        writeln!(self.out, "{seconds},{rays},{e}")?;
        self.out.flush().context("could not write the trace")
    }
}
