//! A recording of the closed loop, simulated faster than real time with the
//! live step structs, laid out exactly as the recorder writes one: for tests,
//! benchmarks and examples.
//!
//! ```
//! use jetbench_stack::config::BenchConfig;
//! use jetbench_stack::synthetic::synthetic_recording;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let recording = synthetic_recording(&BenchConfig::default_sim()?, 200)?;
//! assert_eq!(recording.samples(jetbench_msgs::channels::THRUST).len(), 200);
//! # Ok(())
//! # }
//! ```

use jetbench_model::ModelError;
use jetbench_msgs::channels;
use jetbench_record::meta::RunMetadata;
use jetbench_record::{RecordedMessage, Recording};

use crate::actuation::ActuationStep;
use crate::config::BenchConfig;
use crate::control::ControlStep;
use crate::estimation::EstimationStep;
use crate::replay::run_metadata;
use crate::runtime::clock::PERIOD_NS;
use crate::sensing::SensingStep;
use crate::sim_bench::{SimBenchStep, SimError};

/// Why [`synthetic_recording`] failed.
#[derive(Debug, thiserror::Error)]
pub enum SyntheticError {
    /// The config's model or plant does not load, or the plant diverged.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The simulated sensor's settings are unusable.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The control law or its throttle profile cannot be set up.
    #[error(transparent)]
    ControlSetup(#[from] crate::config::ControlSetupError),
    /// A step refused what the previous one gave it.
    #[error("cycle {cycle}: {service} rejected its input: {message}")]
    Step {
        /// The cycle, from 0.
        cycle: usize,
        /// The service whose step refused.
        service: &'static str,
        /// Its reason.
        message: String,
    },
}

/// A recording of `cycles` cycles of the closed loop, simulated with the live
/// step structs ([`SimBench`], [`Sensing`], [`Estimation`], [`Control`],
/// [`Actuator`]) on a synthetic 100 Hz clock and laid out as the recorder
/// writes it: `bench/thrust`, `bench/state`, `bench/reference`,
/// `bench/command` and `bench/actuation`, plus the `jetbench` metadata.
/// For tests, benchmarks and examples; a replay of it is bit-exact.
///
/// Timing per cycle `k` (`t = 1 s + k·10 ms`): the thrust sample is stamped
/// `t`, the actuation of its command is published at `t + 600 µs`, so the
/// estimator predicts cycle `k + 1` with the actuation of cycle `k` (and the
/// first cycle with none: `INPUT_ASSUMED`), as a live run does.
pub fn synthetic_recording(config: &BenchConfig, cycles: usize) -> Result<Recording, SyntheticError> {
    const T0_NS: u64 = 1_000_000_000;
    let mut sim = SimBenchStep::new(&config.plant()?, config.plant.sensor()?, config.plant.initial_throttle_pct);
    let mut sensing = SensingStep::new(&config.sensor).map_err(|e| SyntheticError::Step {
        cycle: 0,
        service: "sensing",
        message: e.to_string(),
    })?;
    let (model, observer) = config.estimator()?;
    let mut estimation = EstimationStep::new(model, observer);
    let mut control = ControlStep::with_law(config.control_law()?, config.reference.clone());
    let mut actuator = ActuationStep::new(config.actuation.idle_after_missed_cycles);

    let step_error = |cycle: usize, service: &'static str, e: &dyn std::fmt::Display| SyntheticError::Step {
        cycle,
        service,
        message: e.to_string(),
    };
    let mut messages = Vec::with_capacity(5 * cycles);
    let mut throttle_frame = None;
    for k in 0..cycles {
        let t = T0_NS + k as u64 * PERIOD_NS;
        let seq = k as u64;
        let (reading, _truth) = sim.step(t, throttle_frame)?;
        let mut thrust = sensing.step(&reading, t).map_err(|e| step_error(k, "sensing", &e))?;
        (thrust.seq, thrust.publish_ns) = (seq, t + 1_000);
        messages.push(RecordedMessage::of_sample(channels::THRUST, t + 30_000, &thrust));

        let mut state = estimation.step(&thrust).map_err(|e| step_error(k, "estimation", &e))?;
        (state.seq, state.publish_ns) = (seq, t + 40_000);
        messages.push(RecordedMessage::of_sample(channels::STATE, t + 70_000, &state));

        let (mut reference, mut command) = control.step(&state).map_err(|e| step_error(k, "control", &e))?;
        (reference.seq, reference.publish_ns) = (seq, t + 80_000);
        (command.seq, command.publish_ns) = (seq, t + 80_000);
        messages.push(RecordedMessage::of_sample(channels::REFERENCE, t + 110_000, &reference));
        messages.push(RecordedMessage::of_sample(channels::COMMAND, t + 110_000, &command));

        let mut applied = actuator.on_command(&command);
        (applied.seq, applied.publish_ns) = (seq, t + 600_000);
        messages.push(RecordedMessage::of_sample(channels::ACTUATION, t + 630_000, &applied));
        estimation.set_applied(applied.applied_pct);
        throttle_frame = Some(applied.applied_pct);
    }
    let run = RunMetadata {
        clock: "synthetic: jetbench_stack::synthetic::synthetic_recording".into(),
        ..run_metadata(config)?
    };
    Ok(Recording { messages, truncated: false, metadata: [run.record()].into() })
}

#[cfg(test)]
mod tests {
    use jetbench_control::{Controller, Law};
    use jetbench_model::{Effects, Plant, Preset};

    use crate::actuation::ActuationStep;
    use crate::control::ControlStep;
    use crate::estimation::EstimationStep;
    use crate::sensing::SensingStep;
    use crate::sim_bench::{SimBenchStep, SimForceSensor};

    /// The whole loop on the model, with the same step code the services run:
    /// sim-bench -> sensing -> estimation -> control -> actuation -> sim-bench.
    #[test]
    fn closed_loop_tracks_the_reference_with_every_law() {
        for kind in Controller::LAWS {
            closed_loop_tracks_the_reference(kind);
        }
    }

    fn closed_loop_tracks_the_reference(kind: Controller) {
        let params = Preset::P100Diesel.params();
        let plant = Plant::new(params, Effects::none());
        let config = crate::config::BenchConfig::default_sim().unwrap();
        let mut sim = SimBenchStep::new(&plant, SimForceSensor::new(7.0, [0.0; 6], 3).unwrap(), 25.0);
        let mut sensing = SensingStep::new(&config.sensor).unwrap();
        let mut estimation = EstimationStep::new(params, config.estimator.observer_config(0.0));
        let law = Law::new(kind, &plant, &config.control.law_settings()).unwrap();
        let mut control = ControlStep::new(law, config.reference.clone());
        let mut actuator = ActuationStep::new(3);
        let mut throttle = None;
        let mut errors = Vec::new();
        let steps = 3000; // 30 s
        for k in 0..steps {
            let now_ns = k * 10_000_000;
            let (reading, truth) = sim.step(now_ns, throttle).unwrap();
            let thrust = sensing.step(&reading, now_ns).unwrap();
            let state = estimation.step(&thrust).unwrap();
            let (reference, command) = control.step(&state).unwrap();
            let applied = actuator.on_command(&command);
            estimation.set_applied(applied.applied_pct);
            throttle = Some(applied.applied_pct);
            if k >= steps / 2 {
                errors.push((truth.thrust_n - reference.thrust_n).abs());
            }
        }
        errors.sort_by(f64::total_cmp);
        let median = errors[errors.len() / 2];
        let (lo, hi) = config.reference.span_n();
        assert!(median < 0.05 * (hi - lo), "{kind}: median error {median:.2} N over span {:.1} N", hi - lo);
        assert_eq!(control.fallbacks(), 0, "{kind}");
    }
}
