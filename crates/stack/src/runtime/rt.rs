//! Real-time settings of a service process: SCHED_FIFO priority, CPU
//! affinity and locked memory.
//!
//! Each setting is tried on its own; what the kernel refuses (no root, no
//! `rtprio`/`memlock` limit, a CPU that does not exist) is reported with the
//! reason and the process runs on without it, so a bench without real-time
//! permission still runs and says what it could not set.
//!
//! Threads created after [`apply`] inherit the policy and the affinity
//! (glibc's default `PTHREAD_INHERIT_SCHED`), so call it before the bus and
//! the device threads start. No loop of the service set busy-waits: every
//! one blocks in a futex wait, a sleep or a read with a timeout, which is what
//! makes SCHED_FIFO safe on a two-core machine.

use std::fmt;

/// What one process asks for.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RtRequest {
    /// SCHED_FIFO priority, 1–99; `None` leaves the normal scheduler.
    pub priority: Option<u8>,
    /// CPUs to run on; empty leaves the affinity alone.
    pub cpus: Vec<usize>,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)`: no page fault stalls a cycle.
    pub lock_memory: bool,
}

/// What [`apply`] set, and what it could not set and why.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RtOutcome {
    /// Each setting applied, in words (`SCHED_FIFO 80`).
    pub applied: Vec<String>,
    /// Each setting refused, with the reason.
    pub refused: Vec<String>,
}

impl RtOutcome {
    /// True when every requested setting took effect.
    pub fn complete(&self) -> bool {
        self.refused.is_empty()
    }

    /// Logs the outcome: applied settings at info, each refusal as a warning
    /// with what to do about it.
    pub fn log(&self, who: &str) {
        if !self.applied.is_empty() {
            tracing::info!("{who}: real-time settings: {}", self.applied.join(", "));
        }
        for refusal in &self.refused {
            tracing::warn!("{who}: {refusal}; running without it");
        }
    }
}

impl fmt::Display for RtOutcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "set: [{}]", self.applied.join(", "))?;
        if !self.refused.is_empty() {
            write!(f, "; not set: [{}]", self.refused.join("; "))?;
        }
        Ok(())
    }
}

/// A hint for an `EPERM`-style refusal.
fn permission_hint(error: &std::io::Error, limit: &str) -> String {
    if error.raw_os_error() == Some(libc::EPERM) {
        format!("{error} (run as root, or raise `{limit}` for this user in /etc/security/limits.conf)")
    } else {
        error.to_string()
    }
}

/// Applies `request` to the calling process (its current thread and every
/// thread started afterwards).
pub fn apply(request: &RtRequest) -> RtOutcome {
    let mut outcome = RtOutcome::default();
    if request.lock_memory {
        // SAFETY: mlockall has no memory-safety preconditions.
        if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } == 0 {
            outcome.applied.push("memory locked".into());
        } else {
            let e = std::io::Error::last_os_error();
            outcome.refused.push(format!("cannot lock memory: {}", permission_hint(&e, "memlock")));
        }
    }
    if !request.cpus.is_empty() {
        match set_affinity(&request.cpus) {
            Ok(()) => outcome.applied.push(format!("CPUs {:?}", request.cpus)),
            Err(e) => outcome.refused.push(format!("cannot pin to CPUs {:?}: {e}", request.cpus)),
        }
    }
    if let Some(priority) = request.priority {
        match set_fifo(priority) {
            Ok(()) => outcome.applied.push(format!("SCHED_FIFO {priority}")),
            Err(e) => outcome
                .refused
                .push(format!("cannot set SCHED_FIFO priority {priority}: {}", permission_hint(&e, "rtprio"))),
        }
    }
    outcome
}

/// What [`apply`] would set and refuse for `request`, found out on a
/// short-lived thread (priority and affinity are per thread) and by locking
/// and unlocking memory, so the calling process is left as it was.
pub fn probe(request: &RtRequest) -> RtOutcome {
    let thread_request = RtRequest { lock_memory: false, ..request.clone() };
    let mut outcome = std::thread::spawn(move || apply(&thread_request)).join().unwrap_or_default();
    if request.lock_memory {
        // SAFETY: mlockall/munlockall have no memory-safety preconditions.
        if unsafe { libc::mlockall(libc::MCL_CURRENT) } == 0 {
            // SAFETY: as above; undoes the probe's lock.
            unsafe { libc::munlockall() };
            outcome.applied.insert(0, "memory locked".into());
        } else {
            let e = std::io::Error::last_os_error();
            outcome.refused.insert(0, format!("cannot lock memory: {}", permission_hint(&e, "memlock")));
        }
    }
    outcome
}

/// Puts one thread of this process (not the caller) at SCHED_FIFO `priority`.
pub fn set_thread_fifo(thread: libc::pthread_t, priority: u8) -> std::io::Result<()> {
    if !(1..=99).contains(&priority) {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "priority must be 1 to 99"));
    }
    let param = libc::sched_param { sched_priority: i32::from(priority) };
    // SAFETY: `thread` is a live thread of this process (the caller holds its
    // handle); `param` is a valid sched_param.
    match unsafe { libc::pthread_setschedparam(thread, libc::SCHED_FIFO, &param) } {
        0 => Ok(()),
        e => Err(std::io::Error::from_raw_os_error(e)),
    }
}

fn set_fifo(priority: u8) -> std::io::Result<()> {
    if !(1..=99).contains(&priority) {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "priority must be 1 to 99"));
    }
    let param = libc::sched_param { sched_priority: i32::from(priority) };
    // SAFETY: `param` is a valid sched_param; pid 0 is the calling thread.
    if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

fn set_affinity(cpus: &[usize]) -> std::io::Result<()> {
    let online = online_cpus();
    if let Some(bad) = cpus.iter().find(|&&c| c >= online || c >= libc::CPU_SETSIZE as usize) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("CPU {bad} does not exist (this machine has {online})"),
        ));
    }
    // SAFETY: a zeroed cpu_set_t is the empty set; CPU_SET stays in bounds
    // (checked above); pid 0 is the calling thread.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for &cpu in cpus {
            libc::CPU_SET(cpu, &mut set);
        }
        if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error())
        }
    }
}

/// CPUs online on this machine.
pub fn online_cpus() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

/// The calling thread's scheduling policy and priority, e.g. `("SCHED_FIFO", 80)`.
pub fn current_policy() -> (&'static str, i32) {
    // SAFETY: plain queries of the calling thread.
    let (policy, param) = unsafe {
        let mut param = libc::sched_param { sched_priority: 0 };
        let policy = libc::sched_getscheduler(0);
        libc::sched_getparam(0, &mut param);
        (policy, param.sched_priority)
    };
    let name = match policy {
        libc::SCHED_FIFO => "SCHED_FIFO",
        libc::SCHED_RR => "SCHED_RR",
        libc::SCHED_OTHER => "SCHED_OTHER",
        libc::SCHED_BATCH => "SCHED_BATCH",
        libc::SCHED_IDLE => "SCHED_IDLE",
        _ => "unknown",
    };
    (name, param)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nothing_requested_sets_nothing() {
        let outcome = apply(&RtRequest::default());
        assert!(outcome.applied.is_empty() && outcome.refused.is_empty());
    }

    #[test]
    fn a_cpu_that_does_not_exist_is_refused_with_the_reason() {
        let outcome = apply(&RtRequest { cpus: vec![4096], ..RtRequest::default() });
        assert_eq!(outcome.refused.len(), 1, "{outcome}");
        assert!(outcome.refused[0].contains("does not exist"), "{outcome}");
    }

    #[test]
    fn an_out_of_range_priority_is_refused() {
        let outcome = apply(&RtRequest { priority: Some(0), ..RtRequest::default() });
        assert!(!outcome.complete());
        assert!(outcome.refused[0].contains("1 to 99"), "{outcome}");
    }
}
