//! End-to-end tests of the floor chain of `jetbench latency`: four real
//! `jetbench latency-stage` processes per run passing an eventfd ping on.
//!
//! The tests check what a chain delivers (every cycle through every stage,
//! stamps in causal order, the real-time settings set or refused with a
//! reason), never how fast: timing belongs to `jetbench latency` itself.
//! They run one at a time (a lock), and a watchdog turns a hang into a failure.

use std::path::PathBuf;
use std::sync::{mpsc, Mutex};
use std::time::Duration;

use jetbench_latency::chain::{run_chain, stage_rt_requests, ChainError, ChainOptions, ChainRun, STAGES};
use jetbench_stack::config::BenchConfig;

static MACHINE: Mutex<()> = Mutex::new(());

const PERIOD: Duration = Duration::from_millis(10);

fn options() -> ChainOptions {
    ChainOptions::new(PathBuf::from(env!("CARGO_BIN_EXE_jetbench")))
}

/// Runs a chain under a watchdog (the chain's own time-outs end a stuck
/// stage; this catches a hang in the parent).
fn run(options: ChainOptions) -> Result<ChainRun, ChainError> {
    let _machine = MACHINE.lock().unwrap_or_else(|e| e.into_inner());
    let limit = options.duration + Duration::from_secs(90);
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(run_chain(&options));
    });
    rx.recv_timeout(limit).unwrap_or_else(|_| panic!("the chain run hung for {limit:?}"))
}

/// Every cycle the source sent went through all four stages, in order, with
/// causally ordered stamps, and the hops add up to the end-to-end latency.
fn check_complete(run: &ChainRun, duration: Duration) {
    let expected = (duration.as_nanos() / PERIOD.as_nanos()) as u64;
    assert_eq!(run.sent, expected, "the source sends duration / period cycles");
    assert_eq!(run.lost, 0, "{} of {} cycles lost", run.lost, run.sent);
    assert_eq!(run.cycles.len() as u64, run.sent);
    for (i, c) in run.cycles.iter().enumerate() {
        assert_eq!(c.cycle, i as u64, "cycles in order, none missing");
        assert!(c.e2e_ns() > 0, "cycle {}: {c:?}", c.cycle);
        assert_eq!(c.e2e_ns(), c.hop_ns().iter().sum::<u64>() + c.actuate_ns(), "cycle {}: {c:?}", c.cycle);
        for k in 0..STAGES {
            assert!(c.wake_ns[k] <= c.sent_ns[k], "cycle {} stage {k}: sent before woken: {c:?}", c.cycle);
            if k > 0 {
                assert!(c.wake_ns[k - 1] <= c.wake_ns[k], "cycle {} stage {k} woke before its input: {c:?}", c.cycle);
            }
        }
        assert!(c.scheduled_ns > 0 && c.t0_ns() >= c.scheduled_ns, "cycle {}: woke before schedule: {c:?}", c.cycle);
    }
    for pair in run.cycles.windows(2) {
        assert!(pair[0].t0_ns() < pair[1].t0_ns(), "t0 strictly increasing: {pair:?}");
    }
    assert_eq!(run.period_jitter_ns.len() as u64, run.sent - 1);
    assert_eq!(run.stages.len(), STAGES);
    for s in &run.stages {
        assert_eq!(s.handled, run.sent, "stage {} ({}) handled every cycle", s.stage, s.service.name());
    }
}

#[test]
fn the_floor_chain_passes_every_cycle() {
    let mut options = options();
    options.duration = Duration::from_millis(2500);
    let duration = options.duration;
    let run = run(options).unwrap_or_else(|e| panic!("floor chain: {e}"));
    check_complete(&run, duration);
    for s in &run.stages {
        assert_eq!(s.requested, None);
        assert!(s.rt.applied.is_empty() && s.rt.refused.is_empty(), "{:?}", s.rt);
        assert!(!s.fifo(), "stage {} runs {} without being asked", s.stage, s.policy);
    }
}

/// With `--rt`, every stage runs at its service's priority, or says why it could not.
#[test]
fn the_floor_chain_runs_at_the_services_real_time_settings() {
    let config = BenchConfig::default_sim().expect("built-in config");
    let mut options = options();
    options.duration = Duration::from_secs(1);
    options.rt = stage_rt_requests(&config.rt, true);
    let requested = options.rt.clone().expect("forced");
    let duration = options.duration;
    let run = run(options).unwrap_or_else(|e| panic!("floor chain with --rt: {e}"));
    check_complete(&run, duration);
    for (s, asked) in run.stages.iter().zip(&requested) {
        assert_eq!(s.requested.as_ref(), Some(asked));
        let priority = i32::from(asked.priority.expect("a priority"));
        let set = s.fifo() && s.priority == priority && s.rt.applied.iter().any(|a| a.contains("SCHED_FIFO"));
        let refused = !s.fifo() && s.rt.refused.iter().any(|r| r.contains("SCHED_FIFO"));
        assert!(
            set || refused,
            "stage {}: neither SCHED_FIFO {priority} set nor refused: {} {:?}",
            s.stage,
            s.policy,
            s.rt
        );
        if set {
            assert!(s.rt.applied.iter().any(|a| a.contains("CPUs")) || s.rt.refused.iter().any(|r| r.contains("CPU")));
        }
    }
}

#[test]
fn a_stage_that_dies_at_start_is_named() {
    let mut options = options();
    options.exe = PathBuf::from("/bin/true");
    options.duration = Duration::from_millis(100);
    let e = run(options).expect_err("/bin/true is no stage");
    assert!(matches!(e, ChainError::StageDied { .. }), "{e}");
    assert!(e.to_string().contains("exited normally before the run ended"), "{e}");
}

#[test]
fn a_missing_binary_is_a_spawn_error() {
    let mut options = options();
    options.exe = PathBuf::from("/nonexistent/jetbench");
    let e = run(options).expect_err("no binary");
    assert!(matches!(e, ChainError::Spawn { .. }), "{e}");
}
