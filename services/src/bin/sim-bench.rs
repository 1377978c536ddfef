//! Simulated bench: engine, force sensor, throttle board and ECU in real time at 100 Hz.
//!
//! Started by `jetbench up`; see `jetbench-sim-bench --help`.

fn main() -> std::process::ExitCode {
    jetbench::service_main::<jetbench_stack::sim_bench::SimBenchService>(
        "Simulated bench: engine, force sensor, throttle board and ECU in real time at 100 Hz.",
    )
}
