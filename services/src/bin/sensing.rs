//! Sensing service: force sensor frames in, calibrated thrust out on bench/thrust.
//!
//! Started by `jetbench up`; see `jetbench-sensing --help`.

fn main() -> std::process::ExitCode {
    jetbench::service_main::<jetbench_stack::sensing::SensingService>(
        "Sensing service: force sensor frames in, calibrated thrust out on bench/thrust.",
    )
}
