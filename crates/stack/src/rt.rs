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
    pub applied: Vec<String>,
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

/// Time the hypervisor took each CPU away ("steal" in `/proc/stat`), in ms
/// since boot; `None` where the kernel does not report it. On a virtual
/// machine a stolen CPU stalls every process on it, real-time or not, so a
/// latency run reports the steal it saw next to its outliers.
pub fn steal_ms_per_cpu() -> Option<Vec<f64>> {
    parse_steal_ms(&std::fs::read_to_string("/proc/stat").ok()?, clock_ticks_per_s())
}

/// Samples the hypervisor's steal on a thread of its own, every
/// [`StealTimeline::EVERY`], until stopped: when the host took a CPU, to set
/// beside the cycles that came late.
pub struct StealSampler {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<StealTimeline>>,
}

/// Steal over a run: `(CLOCK_MONOTONIC ns, steal ms per CPU since boot)`,
/// one entry at the start and one per change.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StealTimeline {
    pub points: Vec<(u64, Vec<f64>)>,
}

impl StealTimeline {
    /// How often the sampler reads `/proc/stat` (which counts in 10 ms ticks).
    pub const EVERY: std::time::Duration = std::time::Duration::from_millis(5);

    /// Steal on any CPU between `from_ns` and `to_ns`, ms.
    pub fn stolen_ms(&self, from_ns: u64, to_ns: u64) -> f64 {
        let total = |p: &(u64, Vec<f64>)| p.1.iter().sum::<f64>();
        let at = |ns: u64| self.points.iter().take_while(|p| p.0 <= ns).last().map_or(0.0, total);
        match self.points.first() {
            Some(first) => (at(to_ns) - at(from_ns.max(first.0))).max(0.0),
            None => 0.0,
        }
    }
}

impl StealSampler {
    /// Starts sampling; `None` where the kernel does not report steal.
    pub fn start() -> Option<StealSampler> {
        steal_ms_per_cpu()?;
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = std::sync::Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("steal-sampler".into())
            .spawn(move || {
                let mut timeline = StealTimeline::default();
                while !flag.load(std::sync::atomic::Ordering::Relaxed) {
                    if let Some(now) = steal_ms_per_cpu() {
                        if timeline.points.last().is_none_or(|p| p.1 != now) {
                            timeline.points.push((crate::clock::monotonic_ns(), now));
                        }
                    }
                    std::thread::sleep(StealTimeline::EVERY);
                }
                timeline
            })
            .ok()?;
        Some(StealSampler { stop, thread: Some(thread) })
    }

    /// Stops sampling and returns what was seen.
    pub fn finish(mut self) -> StealTimeline {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        self.thread.take().and_then(|t| t.join().ok()).unwrap_or_default()
    }
}

fn clock_ticks_per_s() -> f64 {
    // SAFETY: a plain query.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if ticks > 0 {
        ticks as f64
    } else {
        100.0
    }
}

/// The steal column (the 8th value) of each `cpuN` line, converted to ms.
fn parse_steal_ms(stat: &str, ticks_per_s: f64) -> Option<Vec<f64>> {
    let cpus: Vec<f64> = stat
        .lines()
        .filter(|l| l.starts_with("cpu") && l.as_bytes().get(3).is_some_and(u8::is_ascii_digit))
        .map(|l| l.split_whitespace().nth(8).and_then(|v| v.parse::<u64>().ok()).map(|t| t as f64 * 1e3 / ticks_per_s))
        .collect::<Option<_>>()?;
    (!cpus.is_empty()).then_some(cpus)
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
    #[test]
    fn steal_is_read_per_cpu_and_a_kernel_without_it_gives_none() {
        let stat = "cpu  10 0 5 100 1 0 2 30 0 0\ncpu0 5 0 2 50 1 0 1 12 0 0\ncpu1 5 0 3 50 0 0 1 18 0 0\nintr 1 2\n";
        assert_eq!(super::parse_steal_ms(stat, 100.0), Some(vec![120.0, 180.0]));
        assert_eq!(super::parse_steal_ms("cpu0 5 0 2 50 1 0 1\n", 100.0), None);
        assert_eq!(super::parse_steal_ms("intr 1 2\n", 100.0), None);
    }

    use super::*;

    #[test]
    fn steal_between_two_times_is_read_off_the_timeline() {
        let timeline = StealTimeline {
            points: vec![(1_000, vec![10.0, 20.0]), (5_000, vec![10.0, 30.0]), (9_000, vec![15.0, 30.0])],
        };
        assert_eq!(timeline.stolen_ms(0, 4_000), 0.0);
        assert_eq!(timeline.stolen_ms(4_000, 6_000), 10.0);
        assert_eq!(timeline.stolen_ms(2_000, 10_000), 15.0);
        assert_eq!(StealTimeline::default().stolen_ms(0, 10_000), 0.0);
    }

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
