//! Recorder service: every bus channel into one MCAP file (cdr + ros2msg, zstd chunks).
//!
//! Started by `jetbench up --record FILE`; see `jetbench-recorder --help`.

fn main() -> std::process::ExitCode {
    jetbench::service_main::<jetbench_stack::runtime::Reader<jetbench_stack::recorder::RecorderService>>(
        "Recorder service: every bus channel into one MCAP file (cdr + ros2msg, zstd chunks).",
    )
}
