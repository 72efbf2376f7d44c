//! The state file of `--save` and `--resume`: a [`RunState`] (the library's), written
//! atomically, and read back with messages that name the file.

use anyhow::{Context, Result};
use mcrad_export::PatchRow;
use mcrad_solve::{Error as SolveError, RunState};
use std::path::Path;

/// Reads the state `path` (written by [`save`]).
pub fn load(path: &Path) -> Result<RunState> {
    let file = std::fs::File::open(path)
        .with_context(|| format!("could not read the saved state {}", path.display()))?;
    RunState::read(std::io::BufReader::new(file)).map_err(|e| match e {
        SolveError::NotAState => anyhow::anyhow!(
            "{} is not a state saved by mcrad --save (or it is damaged)",
            path.display()
        ),
        SolveError::StateIo(e) => {
            anyhow::anyhow!("could not read the saved state {}: {e}", path.display())
        }
        e => anyhow::anyhow!("{}: {e}", path.display()),
    })
}

/// Writes `state` to `path` atomically: to a temporary file in `path`'s folder, flushed to
/// disk, then renamed over `path` (a state on disk is always a complete one).
pub fn save(state: &RunState, path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let fail = || format!("could not write the state {}", path.display());
    let mut builder = tempfile::Builder::new();
    // A temporary file is private (0600); the state is an ordinary file (0666 less the
    // umask, as `File::create` makes it), readable where the outputs are.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    let mut tmp = builder
        .prefix(".mcrad-state")
        .tempfile_in(dir)
        .with_context(fail)?;
    {
        let mut out = std::io::BufWriter::new(tmp.as_file_mut());
        state.write(&mut out).with_context(fail)?;
        std::io::Write::flush(&mut out).with_context(fail)?;
    }
    tmp.as_file().sync_all().with_context(fail)?;
    tmp.persist(path).map_err(|e| e.error).with_context(fail)?;
    Ok(())
}

/// A saved state's solution as patch rows (`mcrad merge` reads states as runs).
pub fn rows(state: &RunState) -> Result<Vec<PatchRow>> {
    let estimate = state.estimate()?;
    Ok((0..state.patch_numbers().len())
        .map(|i| PatchRow {
            patch: state.patch_numbers()[i],
            area: state.areas()[i],
            radiosity: estimate.radiosity()[i],
            variance: estimate.variance().map(|v| v[i]),
            // A state keeps patch numbers, not input faces.
            face: None,
        })
        .collect())
}
