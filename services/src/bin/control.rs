//! Control service: reference profile and control law (FBL, SMC or MPC), bench/state in, bench/reference and bench/command out.
//!
//! Started by `jetbench up`; see `jetbench-control --help`.

fn main() -> std::process::ExitCode {
    jetbench::service_main::<jetbench_stack::control::ControlService>("Control service: reference profile and control law (FBL, SMC or MPC), bench/state in, bench/reference and bench/command out.")
}
