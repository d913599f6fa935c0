//! SIGINT (Ctrl-C) and SIGTERM (what schedulers send before they kill):
//! the first asks the running command to stop and save what it has; a
//! second ends the process at once. The process then exits with 128 + the
//! signal's number, as shells report a process a signal ended: 130 after
//! SIGINT, 143 after SIGTERM, so that a script can tell an interrupted
//! render from a finished one.
//!
//! `render` installs the handlers once the scene is loaded (while loading
//! there is nothing to save, and a signal ends kalos at once) and hands
//! [`cancel_flag`] to the driver, which stops after the current pass. A
//! command that installs them must watch the flag: `bake` can, once the
//! density bake takes a cancel flag.
//!
//! On Unix the handler is installed with the C library's `signal`, which
//! every Unix C library has and which `std` already links: the `ctrlc`
//! crate's handler runs the same closure for SIGINT and SIGTERM and cannot
//! tell them apart. Elsewhere `ctrlc` handles Ctrl-C.

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

static CANCEL: AtomicBool = AtomicBool::new(false);
/// The number of the first signal received (0: none).
static SIGNAL: AtomicI32 = AtomicI32::new(0);

/// SIGINT's number (the same on every Unix, and Ctrl-C elsewhere).
const SIGINT: i32 = 2;
/// SIGTERM's number (the same on every Unix).
#[cfg(unix)]
const SIGTERM: i32 = 15;

/// The flag the first signal sets.
pub fn cancel_flag() -> &'static AtomicBool {
    &CANCEL
}

/// 128 + the number of the signal received, when one was.
pub fn exit_code() -> Option<i32> {
    match SIGNAL.load(Ordering::SeqCst) {
        0 => None,
        s => Some(128 + s),
    }
}

/// Records the first signal and sets the flag; only atomics, so that it is
/// safe inside a signal handler.
fn record(sig: i32) {
    let _ = SIGNAL.compare_exchange(0, sig, Ordering::SeqCst, Ordering::SeqCst);
    CANCEL.store(true, Ordering::SeqCst);
}

#[cfg(unix)]
mod os {
    use std::os::raw::c_int;

    extern "C" {
        /// POSIX `signal`: `handler` is a `sighandler_t` (a function
        /// pointer, or SIG_DFL = 0); returns the previous one or SIG_ERR.
        fn signal(signum: c_int, handler: usize) -> usize;
    }
    const SIG_DFL: usize = 0;
    const SIG_ERR: usize = usize::MAX;

    extern "C" fn on_signal(sig: c_int) {
        super::record(sig);
        // The next SIGINT or SIGTERM takes the default action and ends the
        // process at once. `signal` is async-signal-safe (POSIX.1-2008,
        // §2.4.3).
        for s in [super::SIGINT, super::SIGTERM] {
            // SAFETY: restores the default disposition; no Rust state is touched.
            unsafe { signal(s, SIG_DFL) };
        }
    }

    pub fn install() -> Result<(), String> {
        let handler = on_signal as extern "C" fn(c_int) as usize;
        for s in [super::SIGINT, super::SIGTERM] {
            // SAFETY: `on_signal` is an `extern "C" fn(c_int)`, the type C
            // expects of a handler, and only stores to atomics and calls
            // `signal`, both safe in a handler.
            if unsafe { signal(s, handler) } == SIG_ERR {
                return Err(format!("cannot install the handler of signal {s}"));
            }
        }
        Ok(())
    }
}

#[cfg(not(unix))]
mod os {
    pub fn install() -> Result<(), String> {
        ctrlc::set_handler(|| {
            if super::CANCEL.load(std::sync::atomic::Ordering::SeqCst) {
                std::process::exit(130);
            }
            super::record(super::SIGINT);
        })
        .map_err(|e| format!("cannot handle Ctrl-C: {e}"))
    }
}

/// Installs the handlers; a failure is reported as a warning, since the
/// command works without them (a signal then ends it without saving).
pub fn install() {
    if let Err(e) = os::install() {
        eprintln!("warning: {e}; an interrupted render will not be saved");
    }
}
