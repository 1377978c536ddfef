//! Faults at the bench, each once (the campaign, `scripts/faults.sh`, repeats
//! them at random moments and writes docs/faults/REPORT.md): every process
//! killed, a recorder killed and recovered, a full disk, bad sensor data in the
//! live loop, a second set in a namespace, another user, a short soak.
//!
//! Real processes, real signals and real files, through the experiments of
//! `jetbench_faults`; each test runs alone (a lock), so a set has the machine's
//! cores to itself. Hangs are caught by watchdogs; no test asserts a runtime.

use std::sync::Mutex;
use std::time::Duration;

use jetbench_faults::kill::{kill_trial, Victim};
use jetbench_faults::recorder::{disk_full, recorder_crash};
use jetbench_faults::Bench;
use jetbench_stack::config::OnRecordError;

mod common;

static ALONE: Mutex<()> = Mutex::new(());

fn bench() -> Bench {
    let exe = std::path::PathBuf::from(env!("CARGO_BIN_EXE_jetbench"));
    let scratch = common::scratch("faults", "x").parent().expect("scratch folder").to_path_buf();
    let mut bench = Bench::new(exe, "faults", scratch).expect("scratch folder");
    bench.python = Some(common::python());
    bench
}

/// Kills `victim` 2.5 s into a recorded run; every bound of [`kill_trial`] must hold.
fn killed(victim: Victim) {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    let trial = kill_trial(&bench(), victim, 2.5).expect("the experiment runs");
    println!(
        "{victim} killed at {:.1} s (throttle {:?} %): safe after {:?} ms, idle after {:?} missed cycles, named {}, \
         orphans {:?}, restart clean {}",
        trial.at_s,
        trial.throttle_at_kill_pct,
        trial.time_to_safe_ms,
        trial.idle_cycle,
        trial.named,
        trial.orphans,
        trial.restart_clean
    );
    assert!(trial.ok(), "{victim}: {:#?}", trial.problems);
    assert!(trial.time_to_safe_ms.is_some() && trial.readable && trial.restart_clean);
}

#[test]
fn killing_sensing_idles_actuation_acknowledged() {
    killed(Victim::Sensing);
}

#[test]
fn killing_estimation_idles_actuation_acknowledged() {
    killed(Victim::Estimation);
}

#[test]
fn killing_control_idles_actuation_acknowledged() {
    killed(Victim::Control);
}

#[test]
fn killing_actuation_lets_the_board_watchdog_idle_the_engine() {
    killed(Victim::Actuation);
}

#[test]
fn killing_sim_bench_idles_actuation() {
    killed(Victim::SimBench);
}

#[test]
fn killing_the_recorder_stops_the_set_safely() {
    killed(Victim::Recorder);
}

#[test]
fn killing_the_launcher_stops_every_service_with_the_board_disarmed() {
    killed(Victim::Launcher);
}

#[test]
fn a_recorder_killed_mid_run_loses_under_a_second_and_recovers() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    // After 10 s, and long enough for diagnose, one of the readers, with a margin for a loaded machine.
    let crash =
        recorder_crash(&bench(), jetbench_faults::campaign::READERS_CRASH_AT_S, true).expect("the experiment runs");
    println!(
        "recorder killed at {:.1} s: {:.3} s of data before the kill missing; recover exit {:?}, {} of {} messages; \
         Python: {:?}",
        crash.at_s, crash.lost_s, crash.recover_status, crash.recovered, crash.messages, crash.python
    );
    for r in &crash.readers {
        println!("  {} on the truncated file: exit {:?}, warned {}", r.command, r.status, r.warned);
    }
    assert!(crash.problems.is_empty(), "{:#?}", crash.problems);
    assert!(crash.lost_s <= jetbench_faults::recorder::MAX_LOSS_S);
    assert_eq!(crash.readers.len(), 5);
}

/// Root may mount a tmpfs; elsewhere the test says why it cannot run.
fn can_mount() -> bool {
    // SAFETY: geteuid has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    if !root {
        println!("SKIPPED: mounting the small tmpfs this test fills needs root; run the suite as root");
    }
    root
}

#[test]
fn a_full_disk_is_said_at_once_and_the_run_stops_safely() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    if !can_mount() {
        return;
    }
    let d = disk_full(&bench(), OnRecordError::Stop, 256).expect("the experiment runs");
    println!(
        "disk full after {:?} s; safe stop {:?} ms later; {} commands after it at {:.1} Hz, longest interval {:.1} ms; \
         recover exit {:?} with {} messages\n{}",
        d.full_after_s,
        d.stopped_after_ms,
        d.commands_after_full,
        d.rate_after_full_hz,
        d.max_interval_after_full_ms,
        d.recover_status,
        d.recovered,
        d.said
    );
    assert!(d.problems.is_empty(), "{:#?}", d.problems);
    assert!(d.disarmed);
}

#[test]
fn a_full_disk_with_on_error_continue_runs_on_unrecorded_at_rate() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    if !can_mount() {
        return;
    }
    let d = disk_full(&bench(), OnRecordError::Continue, 256).expect("the experiment runs");
    println!(
        "disk full after {:?} s; then {} commands at {:.1} Hz, longest interval {:.1} ms",
        d.full_after_s, d.commands_after_full, d.rate_after_full_hz, d.max_interval_after_full_ms
    );
    assert!(d.problems.is_empty(), "{:#?}", d.problems);
    assert!(d.commands_after_full > 500, "the run went on for several seconds after the disk filled");
}

#[test]
fn spikes_in_the_live_loop_are_rejected_without_hurting_the_tracking() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    let b = jetbench_faults::inject::bad_data(&bench(), &["spikes:rate_per_s=2,size_n=30"], 12, true)
        .expect("the experiment runs");
    println!(
        "{} s: {}/{} spikes rejected, {} other rejections; MAE {:.3} N vs {:.3} N without; a spike's effect on \
         the throttle p50/max {} %; throttle step at a spike p50/max {:?} %, elsewhere {:?} %",
        b.duration_s,
        b.spikes_rejected,
        b.spikes,
        b.other_rejections,
        b.mae_n,
        b.baseline_mae_n,
        b.spike_effect,
        b.step_at_spike_pct,
        b.step_elsewhere_pct
    );
    assert!(b.spikes >= 10, "only {} spikes in {} s", b.spikes, b.duration_s);
    assert!(b.problems.is_empty(), "{:#?}", b.problems);
    // The problems include a spike moving the throttle past the bounds, and a spike
    // effect the recording cannot measure; so it was measured, and within them.
    use jetbench_faults::inject::{SpikeEffect, SPIKE_EFFECT_MAX_PCT, SPIKE_EFFECT_P50_PCT};
    assert!(
        matches!(b.spike_effect, SpikeEffect::Measured { p50_pct, max_pct }
            if p50_pct < SPIKE_EFFECT_P50_PCT && max_pct < SPIKE_EFFECT_MAX_PCT),
        "{}",
        b.spike_effect
    );
}

#[test]
fn stuck_nan_and_silence_at_once_are_flagged_refused_and_survived() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    let inject = ["spikes:rate_per_s=2,size_n=30", "stuck:at_s=3,for_s=1.5", "nan:at_s=5", "silence:at_s=7,for_s=0.5"];
    let b = jetbench_faults::inject::bad_data(&bench(), &inject, 9, false).expect("the experiment runs");
    println!(
        "{}/{} spikes rejected ({} on other faults' frames); stuck flagged after {:?} s; {} NaN frames, {} published, \
         {} non-finite samples; {} silent frames, idle meanwhile {}",
        b.spikes_rejected,
        b.spikes,
        b.spikes_in_other_faults,
        b.stuck_flagged_after_s,
        b.nan_frames,
        b.nan_published,
        b.non_finite_samples,
        b.silent_frames,
        b.idled_in_silence
    );
    assert!(b.problems.is_empty(), "{:#?}", b.problems);
    assert!(b.stuck_flagged_after_s.is_some() && b.nan_frames == 1 && b.silent_frames == 50);
}

#[test]
fn a_second_set_in_a_namespace_is_refused_naming_the_first() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    let s = jetbench_faults::set::second_up(&bench()).expect("the experiment runs");
    println!("{s:?}");
    assert!(s.status.is_some_and(|c| c != 0), "the second up must fail");
    assert!(s.names_the_first, "{}", s.message);
    assert!(s.side_by_side, "a set in another namespace must run beside it");
}

#[test]
fn another_user_can_neither_read_nor_write_a_running_set() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        println!("SKIPPED: switching to another user (setpriv) needs root; run the suite as root");
        return;
    }
    let a = jetbench_faults::set::access_as_another_user(&bench()).expect("the experiment runs");
    println!(
        "{} files and sockets tried; open to others: {:?}; echo as nobody: {:?} {}",
        a.tried, a.open_to_others, a.echo_status, a.echo_said
    );
    assert!(a.tried >= 20, "too few of the set's files found: {a:?}");
    assert!(a.open_to_others.is_empty() && a.loose_modes.is_empty(), "{a:#?}");
    assert!(a.echo_status.is_some_and(|c| c != 0), "another user watched a channel: {a:?}");
}

#[test]
fn a_short_soak_under_load_keeps_memory_flat_and_loses_nothing() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    let load = jetbench_latency::load::LoadKind::All;
    let soak = jetbench_faults::soak::soak(&bench(), 0.5, load, true, Duration::from_secs(3)).expect("the soak runs");
    print!("{soak}");
    assert!(soak.exit_ok);
    assert_eq!(soak.gaps.values().sum::<u64>(), 0, "samples lost: {:?}", soak.gaps);
    assert!(soak.memory.len() >= 7 && soak.memory.iter().all(|m| m.rss_kib.len() >= 5), "{:?}", soak.memory);
    assert!(soak.recording_bytes > 0 && soak.messages > 20_000);
}

/// The CI-sized draw of the campaign's healthy-engine rows (the campaign runs
/// 10 × 60 s of each profile): a healthy engine on the campaign and steps
/// profiles, every P100 limit on, must not trip one.
#[test]
fn a_healthy_engine_trips_no_limit() {
    let _alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    let bench = bench();
    let keys: Vec<&str> = jetbench_stack::limits::LimitKind::ALL.iter().map(|k| k.key()).collect();
    for profile in jetbench_faults::limits::PROFILES {
        let run = jetbench_faults::limits::healthy_run(&bench, profile, 20, false).expect("the run");
        let fmt = |v: &[Option<f64>; 8]| -> String {
            keys.iter()
                .zip(v)
                .map(|(k, v)| format!("{k} {}", v.map_or("-".into(), |v| format!("{v:.2}"))))
                .collect::<Vec<_>>()
                .join(", ")
        };
        println!("{profile}: trips {:?}\n  held: {}\n  peak: {}", run.trips, fmt(&run.held), fmt(&run.peak));
        assert!(run.problems.is_empty(), "{profile}: {:#?}", run.problems);
        let peak_n = run.peak[jetbench_stack::limits::LimitKind::MaxThrust as usize].unwrap_or(0.0);
        assert!(peak_n > 40.0, "{profile}: the profile ran (peak thrust {peak_n:.1} N)");
        assert!(run.held.iter().all(Option::is_some), "{profile}: every limit's quantity measured: {:?}", run.held);
    }
}
