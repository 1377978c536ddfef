//! The hypervisor's steal: on a virtual machine the host sometimes takes a
//! CPU away for tens of ms, which stalls every process on it, real-time or
//! not. A latency run samples it and sets it beside the cycles that came late.

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
    /// `(CLOCK_MONOTONIC ns, steal ms per CPU since boot)`, in time order.
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
                            timeline.points.push((jetbench_stack::runtime::clock::monotonic_ns(), now));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steal_is_read_per_cpu_and_a_kernel_without_it_gives_none() {
        let stat = "cpu  10 0 5 100 1 0 2 30 0 0\ncpu0 5 0 2 50 1 0 1 12 0 0\ncpu1 5 0 3 50 0 0 1 18 0 0\nintr 1 2\n";
        assert_eq!(super::parse_steal_ms(stat, 100.0), Some(vec![120.0, 180.0]));
        assert_eq!(super::parse_steal_ms("cpu0 5 0 2 50 1 0 1\n", 100.0), None);
        assert_eq!(super::parse_steal_ms("intr 1 2\n", 100.0), None);
    }

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
}
