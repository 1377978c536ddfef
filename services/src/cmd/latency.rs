//! `jetbench latency`: does the 100 Hz loop hold under load?
//!
//! One run, under one background load and one set of real-time settings:
//! 1. the full service set on the simulated bench (real processes, the real
//!    bus, recorded), measured cycle by cycle from the samples' own stamps;
//! 2. the machine's floor: a bare eventfd ping chained through as many
//!    processes as the control path has, at the same priorities and CPUs;
//! 3. a copying baseline: the same stages with the services' step code,
//!    samples sent over Unix domain sockets;
//! 4. the same stages over iceoryx2, the like-for-like partner of 3.
//!
//! The report states the pipeline's figures as ratios to the floor and to
//! the Unix-socket baseline.

use std::io::IsTerminal;
use std::os::fd::AsFd;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};
use jetbench_record::Recording;
use jetbench_stack::chain::{run_chain, stage_rt_requests, ChainOptions, ChainRun, Transport};
use jetbench_stack::config::BenchConfig;
use jetbench_stack::latency::{analyse_pipeline, LatencyHistogram, Percentiles, PipelineAnalysis, HOPS};
use jetbench_stack::rt::RtOutcome;
use serde::Serialize;

use super::load::{Load, LoadKind};

/// Options of `jetbench latency`.
#[derive(Debug, clap::Args)]
pub struct LatencyArgs {
    /// Seconds to measure the service set; each reference chain runs as long.
    #[arg(long, value_name = "SECONDS", default_value_t = 60.0)]
    duration: f64,
    /// Background load on every core while measuring: none, cpu (computation),
    /// all (computation, memory traffic, file I/O). stress-ng where installed,
    /// else the built-in generator.
    #[arg(long, value_enum, default_value_t = LoadKind::Cpu)]
    load: LoadKind,
    /// Real-time settings (the config's `[rt]`): SCHED_FIFO priorities, CPU
    /// affinity, locked memory, for the services and the reference chains alike.
    #[arg(long)]
    rt: bool,
    /// Print the results as JSON on stdout (the progress goes to stderr).
    #[arg(long)]
    json: bool,
    /// Write a latency histogram plot (PNG and SVG beside it).
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
    /// Keep the service set's recording here.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Bench config of the simulated bench (default: the built-in one).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Seconds at the start of the service set's run left out (start-up).
    #[arg(long, value_name = "SECONDS", default_value_t = 2.0)]
    warmup: f64,
}

/// One reference chain's results.
struct ChainResult {
    transport: Transport,
    run: ChainRun,
    e2e: LatencyHistogram,
    hops: [LatencyHistogram; 3],
}

impl ChainResult {
    fn new(transport: Transport, run: ChainRun) -> Self {
        let mut e2e = LatencyHistogram::new();
        let mut hops: [LatencyHistogram; 3] = Default::default();
        for cycle in &run.cycles {
            e2e.record(cycle.e2e_ns());
            for (h, ns) in hops.iter_mut().zip(cycle.hop_ns()) {
                h.record(ns);
            }
        }
        ChainResult { transport, run, e2e, hops }
    }
}

/// Everything one run measured.
#[derive(Serialize)]
struct Report {
    duration_s: f64,
    load: String,
    rt_requested: bool,
    rt_refused: Vec<String>,
    cycles: u64,
    completed: u64,
    deadline_misses: u64,
    late_e2e: u64,
    late_periods: u64,
    lost: u64,
    frames_lost: u64,
    unfinished: u64,
    seq_gaps: std::collections::BTreeMap<String, u64>,
    service_deadline_misses: std::collections::BTreeMap<String, u64>,
    e2e_us: Percentiles,
    hops_us: std::collections::BTreeMap<&'static str, Percentiles>,
    period_jitter_us: Percentiles,
    floor_us: Percentiles,
    floor_hops_us: Vec<Percentiles>,
    uds_us: Percentiles,
    iceoryx2_chain_us: Percentiles,
    chain_lost: std::collections::BTreeMap<String, u64>,
    /// CPU time the hypervisor took per CPU while the service set ran, ms
    /// (empty where the kernel does not report steal).
    steal_ms: Vec<f64>,
    ratios: Ratios,
}

#[derive(Serialize)]
struct Ratios {
    /// Pipeline p99 / floor p99 (acceptance: at most 1.5).
    e2e_p99_over_floor_p99: f64,
    e2e_p50_over_floor_p50: f64,
    /// Pipeline / Unix-socket baseline (acceptance: at most 1).
    e2e_p50_over_uds_p50: f64,
    e2e_p99_over_uds_p99: f64,
    /// The like-for-like chains: iceoryx2 / Unix sockets.
    iceoryx2_chain_p50_over_uds_p50: f64,
    iceoryx2_chain_p99_over_uds_p99: f64,
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else {
        f64::NAN
    }
}

/// A progress bar on stderr for a phase of known length (hidden when stderr is not a terminal).
fn phase_bar(what: &str, seconds: f64) -> ProgressBar {
    let bar = if std::io::stderr().is_terminal() {
        ProgressBar::new((seconds * 10.0).ceil() as u64)
    } else {
        eprintln!("{what} ({seconds:.0} s)");
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{msg:<44} [{bar:30}] {elapsed}/{duration}")
            .unwrap_or(ProgressStyle::default_bar()),
    );
    bar.set_message(what.to_string());
    bar
}

pub fn run(args: LatencyArgs) -> anyhow::Result<ExitCode> {
    if !(args.duration.is_finite() && args.duration >= 1.0) {
        bail!("--duration {} must be at least 1 second", args.duration);
    }
    if !(args.warmup.is_finite() && args.warmup >= 0.0) {
        bail!("--warmup {} must be a number of seconds >= 0", args.warmup);
    }
    let config = BenchConfig::load_or_default(args.config.as_deref())?;
    if config.bench.devices != jetbench_stack::config::Devices::Sim {
        bail!("`jetbench latency` runs the simulated bench: the config must have [bench] devices = \"sim\"");
    }
    let exe = std::env::current_exe().context("cannot locate the jetbench binary")?;
    let work = tempdir()?;
    let recording = args.record.clone().unwrap_or_else(|| work.join("pipeline.mcap"));
    if let Some(dir) = recording.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            bail!("cannot record to {}: folder {} does not exist", recording.display(), dir.display());
        }
    }

    let rt_refused = if args.rt { probe_rt(&config) } else { Vec::new() };
    for refusal in &rt_refused {
        eprintln!("warning: {refusal}; measuring without it");
    }
    let mut load = Load::start(args.load, &exe)?;
    eprintln!("load: {}", load.description);
    // Let the load reach every core before measuring.
    std::thread::sleep(Duration::from_secs(1));

    let steal_before = jetbench_stack::rt::steal_ms_per_cpu();
    run_pipeline(&args, &exe, &recording)?;
    let steal_ms: Vec<f64> = match (steal_before, jetbench_stack::rt::steal_ms_per_cpu()) {
        (Some(a), Some(b)) if a.len() == b.len() => b.iter().zip(&a).map(|(b, a)| (b - a).max(0.0)).collect(),
        _ => Vec::new(),
    };
    let mut chains = Vec::new();
    for transport in [Transport::EventFd, Transport::Uds, Transport::Iceoryx] {
        let bar = phase_bar(&format!("reference chain over {transport}"), args.duration);
        let mut options = ChainOptions::new(transport, &exe);
        options.duration = Duration::from_secs_f64(args.duration);
        options.rt = stage_rt_requests(&config.rt, args.rt);
        options.config = args.config.clone();
        let started = Instant::now();
        let handle = std::thread::spawn(move || run_chain(&options));
        while !handle.is_finished() {
            bar.set_position((started.elapsed().as_secs_f64() * 10.0) as u64);
            std::thread::sleep(Duration::from_millis(100));
        }
        bar.finish_and_clear();
        let run = handle.join().map_err(|_| anyhow::anyhow!("the {transport} chain's thread panicked"))??;
        chains.push(ChainResult::new(transport, run));
    }
    if !load.running() {
        eprintln!("warning: the load `{}` ended before the measurements did", load.description);
    }
    let load_description = load.description.clone();
    drop(load);

    let rec = Recording::open(&recording).with_context(|| format!("cannot read back {}", recording.display()))?;
    let pipeline = analyse_pipeline(&rec, args.warmup);
    if pipeline.completed == 0 {
        bail!("the service set's recording {} has no complete cycle to measure", recording.display());
    }
    let report = build_report(&args, &load_description, rt_refused, &pipeline, &chains, steal_ms);
    if let Some(plot) = &args.plot {
        let files = write_plot(plot, &pipeline, &chains)?;
        eprintln!("plot: {}", files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(", "));
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report, &chains);
    }
    if args.record.is_none() {
        let _ = std::fs::remove_dir_all(&work);
    }
    Ok(ExitCode::SUCCESS)
}

fn tempdir() -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("jetbench-latency-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}

/// What the kernel would refuse of each service's `[rt]` request.
fn probe_rt(config: &BenchConfig) -> Vec<String> {
    let mut refused: Vec<String> = Vec::new();
    for id in jetbench_msgs::ServiceId::ALL {
        let Some(request) = config.rt.request(id, true) else { continue };
        let outcome: RtOutcome = jetbench_stack::rt::probe(&request);
        for r in outcome.refused {
            if !refused.contains(&r) {
                refused.push(r);
            }
        }
    }
    refused
}

/// Runs `jetbench up --sim` for warm-up + duration, recording every channel.
fn run_pipeline(args: &LatencyArgs, exe: &Path, recording: &Path) -> anyhow::Result<()> {
    let seconds = args.warmup + args.duration;
    let mut command = Command::new(exe);
    command.args(["up", "--sim", "--quiet", "--duration", &seconds.to_string(), "--record"]).arg(recording);
    if let Some(config) = &args.config {
        command.arg("--config").arg(config);
    }
    if args.rt {
        command.arg("--rt");
    }
    // The launcher's own output goes to stderr, so `--json` keeps stdout for the results.
    let stderr = std::io::stderr().as_fd().try_clone_to_owned().context("cannot pass stderr on")?;
    let bar = phase_bar("service set on the simulated bench", seconds);
    let mut child = command
        .stdin(Stdio::null())
        .stdout(Stdio::from(stderr))
        .stderr(if bar.is_hidden() { Stdio::inherit() } else { Stdio::null() })
        .spawn()
        .context("cannot start `jetbench up`")?;
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        bar.set_position((started.elapsed().as_secs_f64() * 10.0) as u64);
        std::thread::sleep(Duration::from_millis(100));
    };
    bar.finish_and_clear();
    if !status.success() {
        bail!("the service set failed ({}); its log is above", jetbench_stack::launch::describe_exit(status));
    }
    Ok(())
}

fn build_report(
    args: &LatencyArgs,
    load: &str,
    rt_refused: Vec<String>,
    pipeline: &PipelineAnalysis,
    chains: &[ChainResult],
    steal_ms: Vec<f64>,
) -> Report {
    let chain = |t: Transport| chains.iter().find(|c| c.transport == t);
    let p = |t: Transport| chain(t).map(|c| c.e2e.percentiles()).unwrap_or_default();
    let (floor, uds, iox) = (p(Transport::EventFd), p(Transport::Uds), p(Transport::Iceoryx));
    let e2e = pipeline.e2e.percentiles();
    let mut rt_refused = rt_refused;
    for c in chains {
        for r in c.run.stages.iter().flat_map(|s| &s.rt.refused) {
            if !rt_refused.contains(r) {
                rt_refused.push(r.clone());
            }
        }
    }
    Report {
        duration_s: args.duration,
        load: load.to_string(),
        rt_requested: args.rt,
        rt_refused,
        cycles: pipeline.cycles,
        completed: pipeline.completed,
        deadline_misses: pipeline.deadline_misses(),
        late_e2e: pipeline.late_e2e,
        late_periods: pipeline.late_periods,
        lost: pipeline.lost(),
        frames_lost: pipeline.frames_lost,
        unfinished: pipeline.unfinished,
        seq_gaps: pipeline.seq_gaps.clone(),
        service_deadline_misses: pipeline.service_deadline_misses.clone(),
        e2e_us: e2e,
        hops_us: HOPS.iter().copied().zip(pipeline.hops.iter().map(LatencyHistogram::percentiles)).collect(),
        period_jitter_us: pipeline.period_jitter.percentiles(),
        floor_us: floor,
        floor_hops_us: chain(Transport::EventFd)
            .map(|c| c.hops.iter().map(LatencyHistogram::percentiles).collect())
            .unwrap_or_default(),
        uds_us: uds,
        iceoryx2_chain_us: iox,
        chain_lost: chains.iter().map(|c| (c.transport.to_string(), c.run.lost)).collect(),
        steal_ms,
        ratios: Ratios {
            e2e_p99_over_floor_p99: ratio(e2e.p99, floor.p99),
            e2e_p50_over_floor_p50: ratio(e2e.p50, floor.p50),
            e2e_p50_over_uds_p50: ratio(e2e.p50, uds.p50),
            e2e_p99_over_uds_p99: ratio(e2e.p99, uds.p99),
            iceoryx2_chain_p50_over_uds_p50: ratio(iox.p50, uds.p50),
            iceoryx2_chain_p99_over_uds_p99: ratio(iox.p99, uds.p99),
        },
    }
}

fn print_report(r: &Report, chains: &[ChainResult]) {
    println!(
        "jetbench latency: {:.0} s per measurement, load {}, real-time settings {}",
        r.duration_s,
        r.load,
        if !r.rt_requested {
            "off".to_string()
        } else if r.rt_refused.is_empty() {
            "on".to_string()
        } else {
            format!("asked for, partly refused ({})", r.rt_refused.join("; "))
        }
    );
    println!();
    println!("latency, µs                                 p50      p90      p99    p99.9       max");
    println!("service set, sensor frame → board write {}", r.e2e_us.row());
    for (name, p) in &r.hops_us {
        println!("  hop {name:<36}{}", p.row());
    }
    println!("sensing period jitter                    {}", r.period_jitter_us.row());
    for c in chains {
        let label = match c.transport {
            Transport::EventFd => "floor: eventfd ping, 3 hops",
            Transport::Uds => "baseline: same stages over Unix sockets",
            Transport::Iceoryx => "same stages over iceoryx2",
        };
        println!("{label:<41}{}", c.e2e.percentiles().row());
    }
    println!();
    println!(
        "cycles {} (completed {}), deadline misses {} (late cycles {}, late sensor periods {}), lost {} \
         (sensor frames {}, bus/recorder gaps {}, unfinished cycles {})",
        r.cycles,
        r.completed,
        r.deadline_misses,
        r.late_e2e,
        r.late_periods,
        r.lost,
        r.frames_lost,
        r.seq_gaps.values().sum::<u64>(),
        r.unfinished
    );
    if r.steal_ms.iter().any(|&ms| ms > 0.0) {
        let per_cpu: Vec<String> = r.steal_ms.iter().enumerate().map(|(i, ms)| format!("cpu{i} {ms:.0} ms")).collect();
        println!(
            "hypervisor steal while the service set ran: {} (a stolen CPU stalls even SCHED_FIFO)",
            per_cpu.join(", ")
        );
    }
    println!(
        "ratios: p99 to the floor {:.2} (p50 {:.2}); to the Unix-socket baseline p50 {:.2}, p99 {:.2}; \
         iceoryx2 against Unix sockets on the same stages p50 {:.2}, p99 {:.2}",
        r.ratios.e2e_p99_over_floor_p99,
        r.ratios.e2e_p50_over_floor_p50,
        r.ratios.e2e_p50_over_uds_p50,
        r.ratios.e2e_p99_over_uds_p99,
        r.ratios.iceoryx2_chain_p50_over_uds_p50,
        r.ratios.iceoryx2_chain_p99_over_uds_p99
    );
}

fn write_plot(plot: &Path, pipeline: &PipelineAnalysis, chains: &[ChainResult]) -> anyhow::Result<Vec<PathBuf>> {
    let dir = plot.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let stem = plot.file_stem().and_then(|s| s.to_str()).context("--plot needs a file name, e.g. latency.png")?;
    let mut named: Vec<(String, &LatencyHistogram)> = vec![("service set (iceoryx2)".into(), &pipeline.e2e)];
    for c in chains {
        let name = match c.transport {
            Transport::EventFd => "floor: eventfd ping".to_string(),
            Transport::Uds => "stages over Unix sockets".to_string(),
            Transport::Iceoryx => "stages over iceoryx2".to_string(),
        };
        named.push((name, &c.e2e));
    }
    // Up to the largest p99.9, with room: the longest tail values land in the last bin.
    let upper = named.iter().map(|(_, h)| h.percentiles().p999).fold(0.0, f64::max) * 1.25;
    let series: Vec<(String, Vec<f64>, Vec<f64>)> = named
        .iter()
        .map(|(name, h)| {
            let bins = h.bins(upper.max(1.0), 150);
            (name.clone(), bins.iter().map(|b| b.0).collect(), bins.iter().map(|b| b.1 as f64).collect())
        })
        .collect();
    let refs: Vec<(&str, &[f64], &[f64])> = series.iter().map(|(n, x, y)| (n.as_str(), &x[..], &y[..])).collect();
    let title = "Control path latency: sensor frame to board write (3 process hops)";
    Ok(jetbench_ident::plot::write_line_plot(
        dir,
        stem,
        &jetbench_ident::plot::LinePlot {
            title,
            x_label: "latency (µs); the last bin holds everything beyond",
            y_label: "cycles",
            series: &refs,
            hlines: &[],
            log_y: true,
        },
    )?)
}
