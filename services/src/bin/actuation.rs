//! Actuation service: applies bench/command to the throttle board, idles when commands stop.
//!
//! Started by `jetbench up`; see `jetbench-actuation --help`.

fn main() -> std::process::ExitCode {
    jetbench::service_main::<jetbench_stack::actuation::ActuationService>(
        "Actuation service: applies bench/command to the throttle board, idles when commands stop.",
    )
}
