//! The whole loop in one process with the services' step code, on a synthetic clock:
//! a quick way to tune a controller before running the service set.
//!
//! `cargo run --release -p jetbench-stack --example closed_loop -- mpc p100-diesel p100-diesel steps 27`
//! (controller, plant, controller model, profile, seconds; `noshape` as a sixth argument
//! turns reference shaping off).

use jetbench_control::{ControllerKind, Profile};
use jetbench_stack::config::BenchConfig;
use jetbench_stack::step::{Actuator, Control, Estimation, Sensing, SimBench};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.to_string());
    let kind: ControllerKind = arg(0, "fbl").parse()?;
    let mut config = BenchConfig::default_sim()?;
    config.plant.model = arg(1, "p100-diesel");
    config.model.model = arg(2, "p100-diesel");
    config.control.controller = kind.into();
    config.control.shaping.enabled = arg(5, "shape") != "noshape";
    // Gains to try without editing a file: JETBENCH_SMC="a1,beta,k", JETBENCH_MPC_MOVE_WEIGHT.
    if let Ok(smc) = std::env::var("JETBENCH_SMC") {
        let v: Vec<f64> = smc.split(',').map(str::parse).collect::<Result<_, _>>()?;
        config.control.smc = jetbench_control::SmcGains { a1: v[0], beta: v[1], k: v[2] };
    }
    if let Ok(v) = std::env::var("JETBENCH_NOISE_VAR") {
        config.plant.noise_var_n2 = v.parse()?;
    }
    if std::env::var_os("JETBENCH_NO_PREVIEW").is_some() {
        config.control.mpc.preview = false;
    }
    if let Ok(w) = std::env::var("JETBENCH_MPC_MOVE_WEIGHT") {
        config.control.mpc.move_weight = w.parse()?;
    }
    let params = config.model_params()?;
    let idle = params.stable_equilibrium(25.0).unwrap_or(0.0);
    let max = params.stable_equilibrium(100.0).unwrap_or(100.0);
    config.reference = Profile::builtin(&arg(3, "steps"), idle, max).ok_or("unknown profile")?;
    let seconds: f64 = arg(4, "27").parse()?;

    let mut sim = SimBench::new(&config.plant()?, config.plant.noise_var_n2, 3, 25.0)?;
    let mut sensing = Sensing::new(&config.sensor);
    let mut estimation = Estimation::new(params, config.estimator.observer_config());
    let mut control = Control::with_law(config.control_law()?, config.reference.clone());
    let mut actuator = Actuator::new(3);
    let mut throttle = None;
    let (mut abs_n, mut n, mut tv, mut last_u, mut sat) = (0.0, 0usize, 0.0, 25.0, 0usize);
    let mut solve_us = Vec::new();
    let mut hold: Vec<(f64, f64, f64)> = Vec::new();
    let mut holds = Vec::new();
    for k in 0..(seconds * 100.0) as u64 {
        let now_ns = k * 10_000_000;
        let (reading, truth) = sim.step(now_ns, throttle)?;
        let thrust = sensing.step(&reading, now_ns)?;
        let state = estimation.step(&thrust)?;
        let (reference, command) = control.step(&state)?;
        let applied = actuator.on_command(&command);
        estimation.set_applied(applied.applied_pct);
        throttle = Some(applied.applied_pct);
        abs_n += (reference.thrust_n - truth.thrust_n).abs();
        n += 1;
        tv += (command.throttle_pct - last_u).abs();
        last_u = command.throttle_pct;
        sat += (command.flags & 3 != 0) as usize;
        solve_us.push(command.solve_us);
        // The built-in steps hold each level 4 s.
        if k > 0 && k % 500 == 0 {
            holds.push(std::mem::take(&mut hold));
        }
        hold.push((reference.thrust_n, truth.thrust_n, state.thrust_n));
    }
    holds.push(hold);
    solve_us.sort();
    print!(
        "{kind} plant {} model {}: MAE {:.2} N, TV {:.0} %/s, saturated {:.0} %, fallbacks {}, solve p99 {} µs; SS error %:",
        config.plant.model,
        config.model.model,
        abs_n / n as f64,
        tv / seconds,
        100.0 * sat as f64 / n as f64,
        control.fallbacks(),
        solve_us[solve_us.len() * 99 / 100]
    );
    for h in holds.iter().filter(|h| h.len() >= 200) {
        // Settled, and before a controller with preview starts on the next step.
        let tail = &h[h.len() / 2..h.len() - 100];
        let err: f64 = tail.iter().map(|(r, t, _)| t - r).sum::<f64>() / tail.len() as f64;
        let est: f64 = tail.iter().map(|(r, _, e)| e - r).sum::<f64>() / tail.len() as f64;
        print!(" {:+.1}({:+.1})", 100.0 * err / tail[0].0, 100.0 * est / tail[0].0);
    }
    println!();
    Ok(())
}
