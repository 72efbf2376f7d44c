//! SIGINT (Ctrl-C) and SIGTERM: the first asks the solve to stop at the next step boundary and
//! write its outputs from the last complete solution (exit status 130); the second stops the
//! process at once (exit status 130, nothing more written).
//!
//! The handler runs on `ctrlc`'s own thread; the solve's observer polls [`requested`] after
//! every step and stops the run there.

use std::sync::atomic::{AtomicU32, Ordering};

/// The exit status of a run stopped by a signal (128 + SIGINT, the shell's convention).
pub const EXIT_INTERRUPTED: u8 = 130;

/// Signals received so far.
static SIGNALS: AtomicU32 = AtomicU32::new(0);

/// Installs the handler. A failure (another handler already installed) leaves the default
/// behaviour, which kills the process: the run still works, only without the graceful stop,
/// so it is a warning, not an error.
pub fn install() {
    let result = ctrlc::set_handler(|| {
        if SIGNALS.fetch_add(1, Ordering::SeqCst) == 0 {
            eprintln!(
                "\ninterrupted: stopping after the current step and writing the outputs of the \
                 last complete solution (signal again to stop at once)"
            );
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
