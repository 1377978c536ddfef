//! The emulated ECU's lifecycle: the start sequence with its timing and
//! temperatures, run, stop and cool-down, and each way the ECU shuts the
//! engine down on its own, with its off condition; the fault specification.

use jetbench_io::ecu::emulator::{EcuCommand, EcuEmulator, EcuFaults, EcuParams, Refused};
use jetbench_io::ecu::state::{EcuState, OffCondition};
use jetbench_io::ecu::EcuReading;

const DT: f64 = 0.01;

/// A bench around the emulator: 100 Hz steps, the throttle signal fed every
/// step, thrust from a crude engine that follows the throttle in run.
struct Bench {
    ecu: EcuEmulator,
    t: f64,
    throttle_pct: f64,
    readings: Vec<(f64, EcuReading)>,
}

impl Bench {
    fn new(faults: &str) -> Self {
        let faults = if faults.is_empty() { EcuFaults::default() } else { faults.parse().expect("fault spec") };
        Bench { ecu: EcuEmulator::new(EcuParams::default(), faults, 0.0), t: 0.0, throttle_pct: 0.0, readings: vec![] }
    }

    fn thrust_n(&self) -> f64 {
        if self.ecu.state().is_running() {
            2.0 + 0.8 * self.throttle_pct
        } else {
            0.0
        }
    }

    fn step(&mut self) {
        self.t += DT;
        let _ = self.ecu.throttle(self.throttle_pct, self.t);
        let thrust = self.thrust_n();
        self.ecu.step(self.t, thrust);
        self.readings.push((self.t, self.ecu.reading()));
    }

    /// Steps until `until` holds, at most `limit_s`; the time it took.
    fn run_until(&mut self, limit_s: f64, until: impl Fn(&EcuEmulator) -> bool) -> f64 {
        let start = self.t;
        while !until(&self.ecu) {
            assert!(self.t - start < limit_s, "not within {limit_s} s; state {}", self.ecu.state());
            self.step();
        }
        self.t - start
    }

    fn start_and_run(&mut self) {
        self.run_until(2.0, |e| e.state() == EcuState::Standby);
        self.ecu.command(EcuCommand::Start, self.t).expect("start in standby");
        self.run_until(30.0, |e| e.state() == EcuState::Run);
    }

    fn states(&self) -> Vec<EcuState> {
        let mut out: Vec<EcuState> = self.ecu.transitions().iter().map(|(_, s, _)| *s).collect();
        out.dedup();
        out
    }
}

#[test]
fn the_start_sequence_goes_through_its_phases_with_rising_egt_and_reaches_idle() {
    let mut b = Bench::new("");
    assert_eq!(b.ecu.state(), EcuState::Off);
    // A start before standby is refused, by name.
    assert_eq!(b.ecu.command(EcuCommand::Start, 0.0), Err(Refused::NotInState(EcuState::Off)));
    let armed = b.run_until(2.0, |e| e.state() == EcuState::Standby);
    assert!((armed - 1.0).abs() < 0.02, "standby after the 1 s self-test: {armed}");
    b.ecu.command(EcuCommand::Start, b.t).unwrap();
    let start_t = b.t;
    let took = b.run_until(30.0, |e| e.state() == EcuState::Run);
    println!("start to run: {took:.2} s");
    assert!((13.5..=14.5).contains(&took), "a kerosene start of about 14 s: {took:.2}");
    assert_eq!(
        b.states(),
        [
            EcuState::Standby,
            EcuState::Ignite,
            EcuState::Preheat1,
            EcuState::Preheat2,
            EcuState::KeroseneFullOn,
            EcuState::Accelerate,
            EcuState::Stabilise,
            EcuState::Run
        ]
    );
    // The exhaust warms through ignition and preheat, peaks while
    // accelerating, and settles towards idle; the rotor reaches idle speed.
    let egt_at = |t: f64| b.readings.iter().find(|(tt, _)| *tt >= t).unwrap().1.egt_c;
    let phase_end = |state: EcuState| {
        let i = b.ecu.transitions().iter().position(|(_, s, _)| *s == state).unwrap();
        b.ecu.transitions()[i + 1].0 - DT
    };
    assert!(egt_at(start_t + 0.1) < 40.0, "cold at ignition: {}", egt_at(start_t + 0.1));
    let (ig, p1, p2, fuel) = (
        egt_at(phase_end(EcuState::Ignite)),
        egt_at(phase_end(EcuState::Preheat1)),
        egt_at(phase_end(EcuState::Preheat2)),
        egt_at(phase_end(EcuState::KeroseneFullOn)),
    );
    println!("EGT at the end of ignite {ig}, preheat 1 {p1}, preheat 2 {p2}, fuel ramp {fuel} °C");
    assert!(ig > 100.0 && ig < p1 && p1 < p2 && p2 < fuel, "{ig} {p1} {p2} {fuel}");
    let peak = b.readings.iter().map(|(_, r)| r.egt_c).fold(0.0, f64::max);
    assert!(peak > 550.0 && peak < 700.0, "peak {peak}");
    let last = b.readings.last().unwrap().1;
    assert!((last.rpm - 35_000.0).abs() < 1_500.0, "at idle speed: {}", last.rpm);
    assert_eq!(last.state, 11);
    // Telemetry is always within the codec's ranges.
    for (_, r) in &b.readings {
        assert!(r.rpm >= 0.0 && r.egt_c >= -50.0 && r.egt_c <= 1200.0 && r.pump_v >= 0.0, "{r:?}");
    }
}

#[test]
fn in_run_rpm_and_egt_follow_thrust_and_a_stop_cools_down_to_off() {
    let mut b = Bench::new("");
    b.start_and_run();
    b.throttle_pct = 80.0;
    b.run_until(10.0, |e| e.reading().egt_c > 550.0);
    for _ in 0..500 {
        b.step();
    }
    let r = b.ecu.reading();
    let thrust = 2.0 + 0.8 * 80.0;
    assert!((r.rpm - (35_000.0 + 8_000.0 * f64::sqrt(thrust))).abs() < 500.0, "{r:?}");
    assert!((r.egt_c - (450.0 + 3.0 * thrust)).abs() < 30.0, "{r:?}");
    assert_eq!(r.throttle_pct, 80.0);

    b.ecu.command(EcuCommand::Stop, b.t).unwrap();
    assert_eq!((b.ecu.state(), b.ecu.off_condition()), (EcuState::SlowDown, OffCondition::ManualOff));
    let hot = b.ecu.reading().egt_c;
    let cooled = b.run_until(60.0, |e| e.state() == EcuState::Off);
    let r = b.ecu.reading();
    println!("cool-down from {hot} °C: {cooled:.1} s to off at {} °C", r.egt_c);
    assert!(cooled > 5.0, "a cool-down takes time: {cooled}");
    assert!(r.egt_c <= 100.0, "reported to 0.1 °C: {}", r.egt_c);
    // The starter turned the rotor while cooling, and the fuel was off.
    let slow: Vec<_> = b.readings.iter().filter(|(_, r)| r.state == 8).collect();
    assert!(slow.iter().all(|(_, r)| r.throttle_pct == 0.0));
    assert!(slow[slow.len() / 2].1.rpm > 2_000.0);
    // Standby again, and a new start clears the off condition.
    b.run_until(2.0, |e| e.state() == EcuState::Standby);
    assert_eq!(b.ecu.off_condition(), OffCondition::ManualOff);
    b.ecu.command(EcuCommand::Start, b.t).unwrap();
    assert_eq!(b.ecu.off_condition(), OffCondition::None);
    // A stop during the start sequence also cools down.
    b.run_until(5.0, |e| e.state() == EcuState::Preheat1);
    b.ecu.command(EcuCommand::Stop, b.t).unwrap();
    assert_eq!(b.ecu.state(), EcuState::SlowDown);
    b.run_until(60.0, |e| e.state() == EcuState::Off);
}

/// Runs to run, injects at `at_s` on the emulator's clock, and returns the
/// reason and how long after the fault time the ECU shut down.
fn shutdown_after(spec_key: &str, setup: impl Fn(&mut Bench)) -> (OffCondition, f64, Bench) {
    let at_s = 20.0;
    let mut b = Bench::new(&format!("ecu:{spec_key}={at_s}"));
    b.start_and_run();
    b.throttle_pct = 40.0;
    setup(&mut b);
    assert!(b.t < at_s, "in run before the fault: {}", b.t);
    b.run_until(30.0, |e| e.state() != EcuState::Run);
    let after = b.t - at_s;
    assert_eq!(b.ecu.state(), EcuState::SlowDown, "the fuel is cut");
    b.run_until(60.0, |e| e.state() == EcuState::Off);
    assert_eq!(b.ecu.transitions().last().expect("a transition").2, b.ecu.off_condition(), "off keeps the reason");
    (b.ecu.off_condition(), after, b)
}

#[test]
fn each_documented_failure_shuts_down_with_its_reason() {
    let p = EcuParams::default();
    let (why, after, _) = shutdown_after("overtemp_at_s", |_| {});
    println!("over-temperature: {after:.2} s after the cause");
    assert_eq!(why, OffCondition::OverTemperature);
    assert!(after >= p.over_temp_hold_s && after < 5.0, "{after}");

    let (why, after, _) = shutdown_after("overrpm_at_s", |_| {});
    println!("over-RPM: {after:.2} s after the cause");
    assert_eq!(why, OffCondition::OverRpm);
    assert!(after >= p.over_rpm_hold_s && after < 3.0, "{after}");

    let (why, after, b) = shutdown_after("flameout_at_s", |_| {});
    println!("flame-out: {after:.2} s after the cause");
    assert_eq!(why, OffCondition::LowRpm);
    // The hold counts from RPM falling below 90 % of idle, about 0.6 s after the flame went out.
    assert!(after >= p.low_rpm_hold_s && after < p.low_rpm_hold_s + 1.0, "{after}");
    assert_eq!(why.telemetry_code(), -7);
    assert!(b.readings.iter().any(|(_, r)| r.rpm < 20_000.0 && r.state == 11), "RPM fell while still in run");

    let (why, after, b) = shutdown_after("lowbattery_at_s", |_| {});
    println!("low battery: {after:.2} s after the cause");
    assert_eq!(why, OffCondition::LowBattery);
    assert!(after >= p.low_battery_hold_s && after < 4.0, "{after}");
    assert!(b.ecu.battery_v() < p.low_battery_v);

    let (why, after, _) = shutdown_after("failsafe_at_s", |_| {});
    println!("fail-safe: {after:.2} s after the cause");
    assert_eq!(why, OffCondition::FailSafe);
    assert!((after - p.failsafe_s).abs() < 0.05, "{after}");
    for why in [
        OffCondition::OverTemperature,
        OffCondition::OverRpm,
        OffCondition::LowRpm,
        OffCondition::LowBattery,
        OffCondition::FailSafe,
    ] {
        assert!(why.is_fault(), "{why}");
    }
}

#[test]
fn a_throttle_signal_that_stops_trips_the_fail_safe_without_injection() {
    let mut b = Bench::new("");
    b.start_and_run();
    // The owner stops feeding the throttle: no call to `throttle` for 1 s.
    let t0 = b.t;
    while b.ecu.state() == EcuState::Run {
        b.t += DT;
        b.ecu.step(b.t, 10.0);
        assert!(b.t - t0 < 2.0);
    }
    assert_eq!(b.ecu.off_condition(), OffCondition::FailSafe);
    // A throttle out of range is refused, and NaN time or thrust change nothing.
    assert_eq!(b.ecu.throttle(120.0, b.t), Err(Refused::OutOfRange));
    assert_eq!(b.ecu.throttle(f64::NAN, b.t), Err(Refused::OutOfRange));
    let before = b.ecu.reading();
    b.ecu.step(f64::NAN, 1.0);
    b.ecu.step(b.t - 1.0, 1.0);
    assert_eq!(b.ecu.reading(), before);
    b.ecu.step(b.t + DT, f64::INFINITY);
    assert!(b.ecu.reading().rpm.is_finite());
}

#[test]
fn no_fault_no_shutdown_over_a_long_run() {
    let mut b = Bench::new("");
    b.start_and_run();
    for k in 0..12_000 {
        // Steps between idle and full throttle every 5 s.
        b.throttle_pct = if (k / 500) % 2 == 0 { 0.0 } else { 100.0 };
        b.step();
    }
    assert_eq!(b.ecu.state(), EcuState::Run);
    assert_eq!(b.ecu.off_condition(), OffCondition::None);
}

#[test]
fn fault_specifications_parse_or_say_what_is_wrong() {
    let f: EcuFaults = "ecu:overtemp_at_s=20".parse().unwrap();
    assert_eq!(f.overtemp_at_s, Some(20.0));
    let f: EcuFaults = "ecu:flameout_at_s=15, lowbattery_at_s=2.5".parse().unwrap();
    assert_eq!((f.flameout_at_s, f.lowbattery_at_s), (Some(15.0), Some(2.5)));
    assert!(EcuFaults::is_ecu_spec("ecu:overrpm_at_s=1") && !EcuFaults::is_ecu_spec("spikes:rate_per_s=2"));
    for (bad, says) in [
        ("spikes:rate_per_s=2", "ecu:"),
        ("ecu:", "no fault"),
        ("ecu:overheat_at_s=3", "unknown key `overheat_at_s`"),
        ("ecu:overtemp_at_s", "KEY=VALUE"),
        ("ecu:overtemp_at_s=soon", "not a number"),
        ("ecu:overtemp_at_s=-1", ">= 0"),
        ("ecu:overtemp_at_s=inf", ">= 0"),
        ("ecu:overtemp_at_s=1,overtemp_at_s=2", "twice"),
    ] {
        let e = bad.parse::<EcuFaults>().expect_err(bad).to_string();
        assert!(e.contains(says), "{bad}: {e}");
        assert!(e.contains("overtemp_at_s, overrpm_at_s"), "lists the keys: {e}");
    }
}
