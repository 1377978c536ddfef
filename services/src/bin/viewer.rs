//! Viewer service: every bus channel served live to Foxglove (cdr + ros2msg, as recorded).
//!
//! Started by `jetbench up --foxglove [HOST:PORT]`; alone: `jetbench-viewer --listen 0.0.0.0:8765`,
//! then in the Foxglove app: Open connection, Foxglove WebSocket, `ws://BENCH-PC:8765`.

fn main() -> std::process::ExitCode {
    jetbench::service_main::<jetbench_stack::runtime::Reader<jetbench_viewer::Viewer>>(
        "Viewer service: every bus channel served live to Foxglove (cdr + ros2msg, as recorded).",
    )
}
