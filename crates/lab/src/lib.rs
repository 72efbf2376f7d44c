//! mcrad's laboratory: what the command line's `--trace`, `cargo xtask` and the workspace tests
//! share to judge results, not to produce them.
//!
//! - [`trace`]: the error of a solution against a reference solution, `rms_rel` (see
//!   [`mcrad_combine::rms_rel`]), matched patch by patch, and the `seconds,rays,rms_rel` trace
//!   of a run;
//! - [`compare`]: golden-image comparison of two renders tile by tile, and the image error of
//!   a render against a converged picture ([`compare::image_error`]);
//! - [`pathtrace`]: an independent diffuse path tracer, the ground truth of pictures, with a
//!   standard error per pixel;
//! - [`recipe`]: the golden-image recipes `scenes/golden/<name>.json`;
//! - `plot` (cargo feature `plot`): line plots as PNG with an embedded font.
//!
//! Not published; nothing below it in the workspace depends on it. The `mcrad` binary uses it
//! without the `plot` feature, so it does not link plotters.

pub mod compare;
pub mod pathtrace;
#[cfg(feature = "plot")]
pub mod plot;
pub mod recipe;
pub mod split;
pub mod trace;
