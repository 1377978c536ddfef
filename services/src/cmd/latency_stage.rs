//! `jetbench latency-stage`: one process of the floor chain of `jetbench
//! latency` (hidden: only `jetbench_latency::chain::run_chain` starts it, with
//! the descriptors it passes).

use std::process::ExitCode;
use std::time::Duration;

use jetbench_latency::chain::{inherited_fd, run_stage, StageOptions};
use jetbench_stack::runtime::rt::RtRequest;

#[derive(clap::Args)]
pub struct LatencyStageArgs {
    /// 0 = sensing (the clocked source), 1 = estimation, 2 = control, 3 = actuation.
    #[arg(long)]
    stage: usize,
    /// Cycles the source sends.
    #[arg(long)]
    cycles: u64,
    #[arg(long)]
    period_ns: u64,
    /// Inherited descriptors: the input eventfd, the output eventfd, the result pipe.
    #[arg(long)]
    input_fd: Option<i32>,
    #[arg(long)]
    output_fd: Option<i32>,
    #[arg(long)]
    result_fd: i32,
    /// Real-time request: SCHED_FIFO priority, CPUs, locked memory.
    #[arg(long)]
    priority: Option<u8>,
    #[arg(long, value_delimiter = ',')]
    cpus: Vec<usize>,
    #[arg(long)]
    lock_memory: bool,
}

pub fn run(args: LatencyStageArgs) -> anyhow::Result<ExitCode> {
    let rt = (args.priority.is_some() || !args.cpus.is_empty() || args.lock_memory).then(|| RtRequest {
        priority: args.priority,
        cpus: args.cpus.clone(),
        lock_memory: args.lock_memory,
    });
    // SAFETY: the numbers are the descriptors the parent left open for this
    // process; each is claimed once, here, before anything else could own it.
    let claim = |fd: i32| unsafe { inherited_fd(fd) };
    let options = StageOptions {
        stage: args.stage,
        cycles: args.cycles,
        period: Duration::from_nanos(args.period_ns),
        input: args.input_fd.map(claim).transpose()?,
        output: args.output_fd.map(claim).transpose()?,
        results: claim(args.result_fd)?,
        rt,
    };
    run_stage(options)?;
    Ok(ExitCode::SUCCESS)
}
