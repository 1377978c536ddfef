//! Bridge service: every bus channel on Zenoh under `jetbench/<namespace>/<channel>`, the
//! payloads the samples' CDR messages (as recorded).
//!
//! Started by `jetbench up --zenoh ENDPOINT`; alone: `jetbench-bridge --listen tcp/0.0.0.0:7447`.

fn main() -> std::process::ExitCode {
    jetbench::service_main::<jetbench_stack::runtime::Reader<jetbench_bridge::ZenohBridge>>(
        "Bridge service: every bus channel on Zenoh under jetbench/<namespace>/<channel>.",
    )
}
