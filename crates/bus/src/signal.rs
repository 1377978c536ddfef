//! SIGINT/SIGTERM: a flag every wait of the process checks.
//!
//! iceoryx2's own signal handling is turned off: its latch is reset on read
//! and overwritten by any other signal (e.g. SIGCHLD in the launcher). The
//! bus installs a SIGINT/SIGTERM flag instead; every wait returns within
//! [`SIGNAL_POLL`] of it being set, and [`stop_requested`] tells loops to end.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use crate::error::OpenError;

/// The longest any single wait blocks before the stop flag is checked again.
pub const SIGNAL_POLL: Duration = Duration::from_millis(50);

fn stop_flag() -> &'static Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    FLAG.get_or_init(|| Arc::new(AtomicBool::new(false)))
}

/// Installs the SIGINT/SIGTERM flag once per process.
pub fn install_signal_flag() -> Result<(), OpenError> {
    static INSTALLED: OnceLock<Result<(), (std::io::ErrorKind, String)>> = OnceLock::new();
    let result = INSTALLED.get_or_init(|| {
        for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            signal_hook::flag::register(signal, Arc::clone(stop_flag())).map_err(|e| (e.kind(), e.to_string()))?;
        }
        Ok(())
    });
    result.clone().map_err(|(kind, message)| OpenError::Signal(std::io::Error::new(kind, message)))
}

/// True once SIGINT or SIGTERM arrived (or [`request_stop`] was called).
pub fn stop_requested() -> bool {
    stop_flag().load(Ordering::Relaxed)
}

/// Asks every loop of this process to end, as a signal would.
pub fn request_stop() {
    stop_flag().store(true, Ordering::Relaxed);
}

/// Sleeps until `until` (monotonic), waking early only for a stop request.
/// Returns false if a stop was requested.
pub fn sleep_until(until: Instant) -> bool {
    loop {
        if stop_requested() {
            return false;
        }
        let now = Instant::now();
        if now >= until {
            return true;
        }
        std::thread::sleep((until - now).min(SIGNAL_POLL));
    }
}
