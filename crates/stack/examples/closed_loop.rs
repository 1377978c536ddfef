//! The whole loop in one process with the services' step code, on a synthetic clock:
//! a quick way to tune a controller before running the service set.
//!
//! `cargo run --release -p jetbench-stack --example closed_loop -- mpc p100-diesel p100-diesel steps 27`
//! (controller, plant, controller model, profile, seconds; `noshape` as a sixth argument
//! turns reference shaping off). `JETBENCH_SEED` picks the sensor noise draw (default 3),
//! `JETBENCH_ESTIMATOR="accel_noise,disturbance_drift"` the estimator's tuning.

use jetbench_control::{tracking_metrics, Controller, MetricsOptions, Profile, ThrottleLimit, TrackingSample};
use jetbench_msgs::command_flags;
use jetbench_stack::actuation::ActuationStep;
use jetbench_stack::config::BenchConfig;
use jetbench_stack::control::ControlStep;
use jetbench_stack::estimation::EstimationStep;
use jetbench_stack::sensing::SensingStep;
use jetbench_stack::sim_bench::{SimBenchStep, SimForceSensor};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.to_string());
    let kind: Controller = arg(0, "fbl").parse()?;
    let mut config = BenchConfig::default_sim()?;
    config.plant.model = arg(1, "p100-diesel");
    config.model.model = arg(2, "p100-diesel");
    config.control.controller = kind;
    config.control.shaping.enabled = arg(5, "shape") != "noshape";
    // Gains to try without editing a file: JETBENCH_SMC="a1,beta,k", JETBENCH_MPC_MOVE_WEIGHT.
    if let Ok(smc) = std::env::var("JETBENCH_SMC") {
        let v: Vec<f64> = smc.split(',').map(str::parse).collect::<Result<_, _>>()?;
        config.control.smc = jetbench_control::SmcGains { a1: v[0], beta: v[1], k: v[2] };
    }
    // The estimator's tuning: JETBENCH_ESTIMATOR="accel_noise,disturbance_drift" (N/s²).
    if let Ok(e) = std::env::var("JETBENCH_ESTIMATOR") {
        let v: Vec<f64> = e.split(',').map(str::parse).collect::<Result<_, _>>()?;
        (config.estimator.accel_noise_n_per_s2, config.estimator.disturbance_drift_n_per_s2) = (v[0], v[1]);
    }
    if let Ok(v) = std::env::var("JETBENCH_NOISE_VAR") {
        config.plant.noise_var_n2 = v.parse()?;
    }
    if std::env::var_os("JETBENCH_NO_PREVIEW").is_some() {
        config.control.mpc.preview = false;
    }
    if let Ok(h) = std::env::var("JETBENCH_MPC_HORIZON") {
        config.control.mpc.horizon_s = h.parse()?;
    }
    if let Ok(w) = std::env::var("JETBENCH_MPC_MOVE_WEIGHT") {
        config.control.mpc.move_weight = w.parse()?;
    }
    let (params, observer) = config.estimator()?;
    let idle = params.stable_equilibrium(25.0).unwrap_or(0.0);
    let max = params.stable_equilibrium(100.0).unwrap_or(100.0);
    config.reference = Profile::builtin(&arg(3, "steps"), idle, max).ok_or("unknown profile")?;
    let seconds: f64 = arg(4, "27").parse()?;

    // The sensor noise seed: JETBENCH_SEED, so a result can be checked against other draws.
    let seed: u64 = std::env::var("JETBENCH_SEED").map_or(Ok(3), |s| s.parse())?;
    let mut sim = SimBenchStep::new(
        &config.plant()?,
        SimForceSensor::new(config.plant.noise_var_n2, config.plant.sensor_zero, seed)?,
        25.0,
    );
    let mut sensing = SensingStep::new(&config.sensor)?;
    let mut estimation = EstimationStep::new(params, observer);
    let mut control = ControlStep::with_law(config.control_law()?, config.reference.clone());
    let mut actuator = ActuationStep::new(3);
    let mut throttle = None;
    let mut samples = Vec::new();
    for k in 0..(seconds * 100.0) as u64 {
        let now_ns = k * 10_000_000;
        let (reading, truth) = sim.step(now_ns, throttle)?;
        let thrust = sensing.step(&reading, now_ns)?;
        let state = estimation.step(&thrust)?;
        let (reference, command) = control.step(&state)?;
        let applied = actuator.on_command(&command);
        estimation.set_applied(applied.applied_pct);
        throttle = Some(applied.applied_pct);
        samples.push(TrackingSample {
            time_s: k as f64 * 0.01,
            reference_n: reference.thrust_n,
            reference_rate_n_per_s: reference.thrust_rate_n_per_s,
            thrust_n: truth.thrust_n,
            throttle_pct: command.throttle_pct,
            saturated: match command.flags & 3 {
                0 => None,
                1 => Some(ThrottleLimit::Low),
                _ => Some(ThrottleLimit::High),
            },
            fallback: command.flags & command_flags::FALLBACK != 0,
            solve_us: command.solve_us,
        });
    }
    let m = tracking_metrics(&samples, &MetricsOptions { skip_s: 1.0, ..MetricsOptions::default() })?;
    println!(
        "{kind} plant {} model {}: MAE {:.2} N, worst SS error {:.2} %, TV {:.0} %/s, at a limit {:.0} %, \
         fallbacks {}, solve p99 {} µs",
        config.plant.model,
        config.model.model,
        m.mae_n,
        m.holds.iter().skip(1).map(|h| h.steady_state_error_pct.abs()).fold(0.0, f64::max),
        m.throttle_tv_pct_per_s,
        m.saturation_pct,
        m.fallbacks,
        m.solve_us.p99
    );
    let settling: Vec<String> = m
        .steps
        .iter()
        .map(|s| {
            format!(
                "{}{}",
                s.settling_time_s.map_or("-".into(), |t| format!("{t:.2}")),
                if s.saturated { "*" } else { "" }
            )
        })
        .collect();
    println!("  settling s per step (* saturated): {}", settling.join(" "));
    let overshoot: Vec<String> = m.steps.iter().map(|s| format!("{:.1}", s.overshoot_pct)).collect();
    println!("  overshoot % per step: {}", overshoot.join(" "));
    let ss: Vec<String> = m.holds.iter().map(|h| format!("{:+.2}", h.steady_state_error_n)).collect();
    println!("  steady-state error N per hold: {}", ss.join(" "));
    Ok(())
}
