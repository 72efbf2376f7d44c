//! The crate's tests of its estimators and schedules, which reach the estimators the public
//! interface keeps private (shooting, gathering, direct light, the ambient term, the surface
//! sampler). Monte Carlo tests use fixed seeds and tolerances of a stated number of standard
//! errors.

#![allow(dead_code)]

mod adaptive;
mod bias;
mod calibration;
mod combined;
mod common;
mod control;
mod far;
mod figure2;
mod gathering;
mod qmc;
mod reference;
mod shadowed;
mod shooting;
