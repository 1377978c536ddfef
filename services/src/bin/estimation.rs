//! Estimation service: EKF of thrust and thrust rate, bench/thrust in, bench/state out.
//!
//! Started by `jetbench up`; see `jetbench-estimation --help`.

fn main() -> std::process::ExitCode {
    jetbench::service_main::<jetbench_stack::estimation::EstimationService>(
        "Estimation service: EKF of thrust and thrust rate, bench/thrust in, bench/state out.",
    )
}
