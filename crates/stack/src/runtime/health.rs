//! The per-cycle heartbeat every service publishes on `bench/health`.

use jetbench_bus::{Bus, BusError, Publisher};
use jetbench_msgs::{channels, health_flags, Health, ServiceId};

use crate::runtime::clock::PERIOD_NS;

/// Counts a service's cycles, misses and errors, and publishes them.
pub struct HealthReporter {
    publisher: Publisher<Health>,
    sample: Health,
    last_cycle_ns: Option<u64>,
}

impl HealthReporter {
    /// Publishes `service`'s heartbeats on `bench/health`.
    pub fn new(bus: &Bus, service: ServiceId) -> Result<Self, BusError> {
        Ok(HealthReporter {
            publisher: bus.publisher(channels::HEALTH)?,
            sample: Health { service_id: service as u32, ..Health::default() },
            last_cycle_ns: None,
        })
    }

    /// Records one cycle that started at `start_ns` and finished at `end_ns`
    /// and publishes the heartbeat. `late` marks a cycle whose input missed
    /// its deadline; work longer than the period counts as a miss too.
    pub fn cycle(&mut self, start_ns: u64, end_ns: u64, late: bool) -> Result<(), BusError> {
        let work_ns = end_ns.saturating_sub(start_ns);
        let s = &mut self.sample;
        s.cycles += 1;
        s.cycle_ns = self.last_cycle_ns.map_or(0, |last| start_ns.saturating_sub(last));
        s.work_ns = work_ns;
        s.max_work_ns = s.max_work_ns.max(work_ns);
        if late || work_ns > PERIOD_NS {
            s.deadline_misses += 1;
        }
        if late {
            s.flags |= health_flags::INPUT_OVERDUE;
        } else {
            s.flags &= !health_flags::INPUT_OVERDUE;
        }
        s.stamp_ns = end_ns;
        self.last_cycle_ns = Some(start_ns);
        self.publisher.publish(*s)?;
        Ok(())
    }

    /// Counts a rejected input or failed operation.
    pub fn error(&mut self) {
        self.sample.errors += 1;
    }

    /// Sets the total of samples lost on this service's inputs.
    pub fn set_input_gaps(&mut self, gaps: u64) {
        self.sample.input_gaps = gaps;
    }

    /// Marks or clears the fallback state (e.g. actuation at idle).
    pub fn set_fallback(&mut self, on: bool) {
        if on {
            self.sample.flags |= health_flags::FALLBACK;
        } else {
            self.sample.flags &= !health_flags::FALLBACK;
        }
    }

    /// The counters as last published (misses, gaps, flags).
    pub fn counters(&self) -> &Health {
        &self.sample
    }
}
