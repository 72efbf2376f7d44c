//! SIGINT (Ctrl-C) and SIGTERM: the first asks the solve to stop and write its outputs from
//! the last complete step (exit status 130); the second stops the process at once (exit status
//! 130, nothing more written).
//!
//! After the first signal the observer stops the run at the next step boundary. A step that
//! has not ended [`GRACE`] later is abandoned through the run's cancellation flag
//! ([`cancel_flag`], `schedule::run_cancellable`), once a complete step has been kept
//! ([`step_kept`]); before the first complete step there is nothing to write, and the run goes
//! on to it. The handler runs on `ctrlc`'s own thread and never blocks it, so a second signal
//! is always heard.

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::time::Duration;

/// The exit status of a run stopped by a signal (128 + SIGINT, the shell's convention).
pub const EXIT_INTERRUPTED: u8 = 130;

/// How long the step in progress may go on after the first signal before it is abandoned,
/// unless the environment variable `MCRAD_INTERRUPT_GRACE` gives other seconds (the tests
/// give 0: abandon at once).
pub const GRACE: Duration = Duration::from_secs(1);

/// [`GRACE`], or `MCRAD_INTERRUPT_GRACE` seconds when that is a number `>= 0`.
fn grace() -> Duration {
    std::env::var("MCRAD_INTERRUPT_GRACE")
        .ok()
        .and_then(|s| s.parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0 && *s < 1e9)
        .map_or(GRACE, Duration::from_secs_f64)
}

/// Signals received so far.
static SIGNALS: AtomicU32 = AtomicU32::new(0);
/// Set to abandon the step in progress.
static CANCEL: AtomicBool = AtomicBool::new(false);
/// Set once the solve holds a complete step it can write.
static STEP_KEPT: AtomicBool = AtomicBool::new(false);

/// Installs the handler. A failure (another handler already installed) leaves the default
/// behaviour, which kills the process: the run still works, only without the graceful stop,
/// so it is a warning, not an error.
pub fn install() {
    let result = ctrlc::set_handler(|| {
        if SIGNALS.fetch_add(1, Ordering::SeqCst) == 0 {
            let grace = grace();
            eprintln!(
                "\ninterrupted: stopping at the end of the current step (abandoned after {} s) \
                 and writing the outputs of the last complete step (signal again to stop at once)",
                grace.as_secs_f64()
            );
            std::thread::spawn(move || {
                std::thread::sleep(grace);
                while !STEP_KEPT.load(Ordering::SeqCst) {
                    std::thread::sleep(Duration::from_millis(10));
                }
                CANCEL.store(true, Ordering::SeqCst);
            });
        } else {
            eprintln!("interrupted again: stopped at once, outputs not written");
            std::process::exit(i32::from(EXIT_INTERRUPTED));
        }
    });
    if let Err(e) = result {
        eprintln!("warning: Ctrl-C will stop the run without writing its outputs: {e}");
    }
}

/// True once a first SIGINT or SIGTERM has arrived.
pub fn requested() -> bool {
    SIGNALS.load(Ordering::SeqCst) > 0
}

/// The flag that cancels the run (`schedule::run_cancellable`).
pub fn cancel_flag() -> &'static AtomicBool {
    &CANCEL
}

/// Records that the solve holds a complete step: from now on an abandoned step loses no
/// answer.
pub fn step_kept() {
    STEP_KEPT.store(true, Ordering::SeqCst);
}
