//! `jetbench latency`: does the 100 Hz loop hold under load?
//!
//! One run, under one background load and one set of real-time settings,
//! measures three things:
//! 1. the service set on the simulated bench over iceoryx2 (real processes,
//!    the real bus, recorded), cycle by cycle from the samples' own stamps;
//! 2. the same service set with every sample copied through Unix domain
//!    sockets instead (`jetbench up --transport uds`): the copying baseline,
//!    measured the same way;
//! 3. the machine's floor: a bare eventfd ping chained through as many
//!    processes as the control path has, at the same priorities and CPUs.
//!
//! A virtual machine's speed drifts with its host's load, so measurements
//! taken one after the other would mix the transport with the time of day:
//! the duration is split into rounds, each measuring all three in turn (in
//! alternating order), and the rounds' histograms are merged. The report
//! states the pipeline's figures as ratios to the floor and to the baseline.

use std::io::IsTerminal;
use std::os::fd::AsFd;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};
use jetbench_bus::Transport;
use jetbench_record::Recording;
use jetbench_stack::chain::{run_chain, stage_rt_requests, ChainOptions, ChainRun, HOPS as FLOOR_HOPS};
use jetbench_stack::config::BenchConfig;
use jetbench_stack::latency::{analyse_pipeline, LatencyHistogram, Percentiles, PipelineAnalysis, HOPS};
use jetbench_stack::rt::RtOutcome;
use serde::Serialize;

use super::load::{Load, LoadKind};

/// Options of `jetbench latency`.
#[derive(Debug, clap::Args)]
pub struct LatencyArgs {
    /// Seconds to measure each of the three (the service set over iceoryx2,
    /// over Unix sockets, the floor), spread over the rounds.
    #[arg(long, value_name = "SECONDS", default_value_t = 60.0)]
    duration: f64,
    /// Background load on every core while measuring: none, cpu (computation),
    /// all (computation, memory traffic, file I/O). stress-ng where installed,
    /// else the built-in generator.
    #[arg(long, value_enum, default_value_t = LoadKind::Cpu)]
    load: LoadKind,
    /// Real-time settings (the config's `[rt]`): SCHED_FIFO priorities, CPU
    /// affinity, locked memory, for the services and the floor chain alike.
    #[arg(long)]
    rt: bool,
    /// Print the results as JSON on stdout (the progress goes to stderr).
    #[arg(long)]
    json: bool,
    /// Write a latency histogram plot (PNG and SVG beside it).
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
    /// Keep the service sets' recordings in this folder
    /// (`iceoryx2-<round>.mcap`, `uds-<round>.mcap`).
    #[arg(long, value_name = "DIR")]
    keep: Option<PathBuf>,
    /// Bench config of the simulated bench (default: the built-in one).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Seconds at the start of each service-set run left out (start-up).
    #[arg(long, value_name = "SECONDS", default_value_t = 2.0)]
    warmup: f64,
    /// Rounds the duration is split into; each measures all three in turn.
    #[arg(long, value_name = "N", default_value_t = 2)]
    rounds: u32,
}

/// One of the three measurements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Measurement {
    Pipeline(Transport),
    Floor,
}

impl Measurement {
    /// Round `r` measures in this order; odd rounds reverse it, so drift
    /// over the run favours none of them.
    fn order(round: u32) -> [Measurement; 3] {
        let forward = [
            Measurement::Pipeline(Transport::Iceoryx2),
            Measurement::Pipeline(Transport::UnixSockets),
            Measurement::Floor,
        ];
        if round.is_multiple_of(2) {
            forward
        } else {
            [forward[2], forward[1], forward[0]]
        }
    }

    fn describe(self) -> &'static str {
        match self {
            Measurement::Pipeline(Transport::Iceoryx2) => "service set over iceoryx2",
            Measurement::Pipeline(Transport::UnixSockets) => "service set over Unix sockets",
            Measurement::Floor => "floor: eventfd ping chain",
        }
    }
}

/// The floor chain's results, over every round.
#[derive(Default)]
struct FloorResult {
    e2e: LatencyHistogram,
    hops: [LatencyHistogram; FLOOR_HOPS],
    lost: u64,
    refused: Vec<String>,
}

impl FloorResult {
    fn add(&mut self, run: &ChainRun) {
        for cycle in &run.cycles {
            self.e2e.record(cycle.e2e_ns());
            for (h, ns) in self.hops.iter_mut().zip(cycle.hop_ns()) {
                h.record(ns);
            }
        }
        self.lost += run.lost;
        for r in run.stages.iter().flat_map(|s| &s.rt.refused) {
            if !self.refused.contains(r) {
                self.refused.push(r.clone());
            }
        }
    }
}

/// What the copying baseline measured, beside its end-to-end latency.
#[derive(Serialize)]
struct BaselineReport {
    cycles: u64,
    completed: u64,
    deadline_misses: u64,
    lost: u64,
    hops_us: std::collections::BTreeMap<&'static str, Percentiles>,
    period_jitter_us: Percentiles,
}

/// Everything one run measured.
#[derive(Serialize)]
struct Report {
    duration_s: f64,
    rounds: u32,
    load: String,
    rt_requested: bool,
    rt_refused: Vec<String>,
    cycles: u64,
    completed: u64,
    deadline_misses: u64,
    late_e2e: u64,
    late_periods: u64,
    superseded: u64,
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
    floor_lost: u64,
    /// The same service set over Unix domain sockets: its end-to-end latency.
    uds_us: Percentiles,
    uds: BaselineReport,
    /// CPU time the hypervisor took per CPU while measuring, ms
    /// (empty where the kernel does not report steal).
    steal_ms: Vec<f64>,
    /// Deadline misses of the iceoryx2 runs that came within 40 ms before to
    /// 20 ms after the hypervisor took a CPU (a bench PC has no hypervisor).
    misses_during_steal: u64,
    ratios: Ratios,
}

#[derive(Serialize)]
struct Ratios {
    /// Pipeline p99 / floor p99 (acceptance: at most 1.5).
    e2e_p99_over_floor_p99: f64,
    e2e_p50_over_floor_p50: f64,
    /// iceoryx2 / Unix sockets, the same service set (acceptance: at most 1).
    e2e_p50_over_uds_p50: f64,
    e2e_p99_over_uds_p99: f64,
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else {
        f64::NAN
    }
}

fn hops_of(pipeline: &PipelineAnalysis) -> std::collections::BTreeMap<&'static str, Percentiles> {
    HOPS.iter().copied().zip(pipeline.hops.iter().map(LatencyHistogram::percentiles)).collect()
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
    if args.rounds == 0 || args.duration / f64::from(args.rounds) < 1.0 {
        bail!("--rounds {} must be at least 1 and leave each round 1 s of --duration {}", args.rounds, args.duration);
    }
    let config = BenchConfig::load_or_default(args.config.as_deref())?;
    if config.bench.devices != jetbench_stack::config::Devices::Sim {
        bail!("`jetbench latency` runs the simulated bench: the config must have [bench] devices = \"sim\"");
    }
    let exe = std::env::current_exe().context("cannot locate the jetbench binary")?;
    let work = match &args.keep {
        Some(dir) => {
            std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
            dir.clone()
        }
        None => tempdir()?,
    };

    let rt_refused = if args.rt { probe_rt(&config) } else { Vec::new() };
    for refusal in &rt_refused {
        eprintln!("warning: {refusal}; measuring without it");
    }
    let mut load = Load::start(args.load, &exe)?;
    eprintln!("load: {}", load.description);
    // Let the load reach every core before measuring.
    std::thread::sleep(Duration::from_secs(1));

    let segment_s = args.duration / f64::from(args.rounds);
    let steal_before = jetbench_stack::rt::steal_ms_per_cpu();
    let steal_sampler = jetbench_stack::rt::StealSampler::start();
    let (mut iceoryx2, mut uds, mut floor) =
        (PipelineAnalysis::default(), PipelineAnalysis::default(), FloorResult::default());
    for round in 0..args.rounds {
        for measurement in Measurement::order(round) {
            let what = format!("round {}/{}: {}", round + 1, args.rounds, measurement.describe());
            match measurement {
                Measurement::Pipeline(transport) => {
                    let recording = work.join(format!("{transport}-{}.mcap", round + 1));
                    run_pipeline(&args, &exe, &recording, transport, segment_s, &what)?;
                    let rec = Recording::open(&recording)
                        .with_context(|| format!("cannot read back {}", recording.display()))?;
                    let analysis = analyse_pipeline(&rec, args.warmup);
                    if analysis.completed == 0 {
                        bail!("the {} run's recording {} has no complete cycle", transport, recording.display());
                    }
                    let total = if transport == Transport::Iceoryx2 { &mut iceoryx2 } else { &mut uds };
                    total.merge(&analysis);
                    if args.keep.is_none() {
                        let _ = std::fs::remove_file(&recording);
                    }
                }
                Measurement::Floor => floor.add(&run_floor(&args, &exe, &config, segment_s, &what)?),
            }
        }
    }
    let steal_ms: Vec<f64> = match (steal_before, jetbench_stack::rt::steal_ms_per_cpu()) {
        (Some(a), Some(b)) if a.len() == b.len() => b.iter().zip(&a).map(|(b, a)| (b - a).max(0.0)).collect(),
        _ => Vec::new(),
    };
    let steal = steal_sampler.map(|s| s.finish()).unwrap_or_default();
    let misses_during_steal = iceoryx2
        .miss_stamps_ns
        .iter()
        .filter(|&&t| steal.stolen_ms(t.saturating_sub(40_000_000), t + 20_000_000) > 0.0)
        .count() as u64;
    if !load.running() {
        eprintln!("warning: the load `{}` ended before the measurements did", load.description);
    }
    let load_description = load.description.clone();
    drop(load);

    let mut rt_refused = rt_refused;
    for r in &floor.refused {
        if !rt_refused.contains(r) {
            rt_refused.push(r.clone());
        }
    }
    let report =
        build_report(&args, &load_description, rt_refused, &iceoryx2, &uds, &floor, (steal_ms, misses_during_steal));
    if let Some(plot) = &args.plot {
        let files = write_plot(plot, &iceoryx2, &uds, &floor)?;
        eprintln!("plot: {}", files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(", "));
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report);
    }
    if args.keep.is_none() {
        let _ = std::fs::remove_dir_all(&work);
    }
    Ok(ExitCode::SUCCESS)
}

/// Runs the floor chain for `seconds` at the services' real-time settings.
fn run_floor(
    args: &LatencyArgs,
    exe: &Path,
    config: &BenchConfig,
    seconds: f64,
    what: &str,
) -> anyhow::Result<ChainRun> {
    let bar = phase_bar(what, seconds);
    let mut options = ChainOptions::new(exe);
    options.duration = Duration::from_secs_f64(seconds);
    options.rt = stage_rt_requests(&config.rt, args.rt);
    let started = Instant::now();
    let handle = std::thread::spawn(move || run_chain(&options));
    while !handle.is_finished() {
        bar.set_position((started.elapsed().as_secs_f64() * 10.0) as u64);
        std::thread::sleep(Duration::from_millis(100));
    }
    bar.finish_and_clear();
    Ok(handle.join().map_err(|_| anyhow::anyhow!("the floor chain's thread panicked"))??)
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

/// Runs `jetbench up --sim` over `transport` for warm-up + `seconds`, recording every channel.
fn run_pipeline(
    args: &LatencyArgs,
    exe: &Path,
    recording: &Path,
    transport: Transport,
    seconds: f64,
    what: &str,
) -> anyhow::Result<()> {
    let seconds = args.warmup + seconds;
    let mut command = Command::new(exe);
    command
        .args(["up", "--sim", "--quiet", "--transport", transport.name(), "--duration", &seconds.to_string()])
        .arg("--record")
        .arg(recording);
    if let Some(config) = &args.config {
        command.arg("--config").arg(config);
    }
    if args.rt {
        command.arg("--rt");
    }
    let bar = phase_bar(what, seconds);
    // Under a progress bar the launcher's output goes to a log beside the
    // recording; in a log it goes to stderr, so `--json` keeps stdout for the results.
    let log = recording.with_extension("log");
    let (out, err) = if bar.is_hidden() {
        let stderr = std::io::stderr().as_fd().try_clone_to_owned().context("cannot pass stderr on")?;
        (Stdio::from(stderr), Stdio::inherit())
    } else {
        let file = std::fs::File::create(&log).with_context(|| format!("cannot create {}", log.display()))?;
        (Stdio::from(file.try_clone()?), Stdio::from(file))
    };
    let mut child =
        command.stdin(Stdio::null()).stdout(out).stderr(err).spawn().context("cannot start `jetbench up`")?;
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
        if let Ok(text) = std::fs::read_to_string(&log) {
            let lines: Vec<&str> = text.lines().collect();
            eprintln!("{}", lines[lines.len().saturating_sub(30)..].join("\n"));
        }
        bail!(
            "the service set over {transport} failed ({}); its log is above{}",
            jetbench_stack::launch::describe_exit(status),
            if bar.is_hidden() { String::new() } else { format!(" and in {}", log.display()) }
        );
    }
    let _ = std::fs::remove_file(&log);
    Ok(())
}

fn build_report(
    args: &LatencyArgs,
    load: &str,
    rt_refused: Vec<String>,
    pipeline: &PipelineAnalysis,
    uds: &PipelineAnalysis,
    floor: &FloorResult,
    (steal_ms, misses_during_steal): (Vec<f64>, u64),
) -> Report {
    let (e2e, uds_e2e, floor_e2e) = (pipeline.e2e.percentiles(), uds.e2e.percentiles(), floor.e2e.percentiles());
    Report {
        duration_s: args.duration,
        rounds: args.rounds,
        load: load.to_string(),
        rt_requested: args.rt,
        rt_refused,
        cycles: pipeline.cycles,
        completed: pipeline.completed,
        deadline_misses: pipeline.deadline_misses(),
        late_e2e: pipeline.late_e2e,
        late_periods: pipeline.late_periods,
        superseded: pipeline.superseded,
        lost: pipeline.lost(),
        frames_lost: pipeline.frames_lost,
        unfinished: pipeline.unfinished,
        seq_gaps: pipeline.seq_gaps.clone(),
        service_deadline_misses: pipeline.service_deadline_misses.clone(),
        e2e_us: e2e,
        hops_us: hops_of(pipeline),
        period_jitter_us: pipeline.period_jitter.percentiles(),
        floor_us: floor_e2e,
        floor_hops_us: floor.hops.iter().map(LatencyHistogram::percentiles).collect(),
        floor_lost: floor.lost,
        uds_us: uds_e2e,
        uds: BaselineReport {
            cycles: uds.cycles,
            completed: uds.completed,
            deadline_misses: uds.deadline_misses(),
            lost: uds.lost(),
            hops_us: hops_of(uds),
            period_jitter_us: uds.period_jitter.percentiles(),
        },
        steal_ms,
        misses_during_steal,
        ratios: Ratios {
            e2e_p99_over_floor_p99: ratio(e2e.p99, floor_e2e.p99),
            e2e_p50_over_floor_p50: ratio(e2e.p50, floor_e2e.p50),
            e2e_p50_over_uds_p50: ratio(e2e.p50, uds_e2e.p50),
            e2e_p99_over_uds_p99: ratio(e2e.p99, uds_e2e.p99),
        },
    }
}

fn print_report(r: &Report) {
    println!(
        "jetbench latency: {:.0} s per measurement in {} rounds, load {}, real-time settings {}",
        r.duration_s,
        r.rounds,
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
    println!("latency, µs                                   p50      p90      p99    p99.9       max");
    println!("service set over iceoryx2, frame → board {}", r.e2e_us.row());
    for (name, p) in &r.hops_us {
        println!("  hop {name:<37}{}", p.row());
    }
    println!("  sensing period jitter                  {}", r.period_jitter_us.row());
    println!("same service set over Unix sockets      {}", r.uds_us.row());
    for (name, p) in &r.uds.hops_us {
        println!("  hop {name:<37}{}", p.row());
    }
    println!("floor: eventfd ping, {FLOOR_HOPS} hops               {}", r.floor_us.row());
    println!();
    println!(
        "iceoryx2: cycles {} (completed {}), deadline misses {} (late cycles {}, late sensor periods {}, \
         commands superseded {}), lost {} (sensor frames {}, bus/recorder gaps {}, unfinished cycles {})",
        r.cycles,
        r.completed,
        r.deadline_misses,
        r.late_e2e,
        r.late_periods,
        r.superseded,
        r.lost,
        r.frames_lost,
        r.seq_gaps.values().sum::<u64>(),
        r.unfinished
    );
    println!(
        "Unix sockets: cycles {} (completed {}), deadline misses {}, lost {}; floor chain lost {}",
        r.uds.cycles, r.uds.completed, r.uds.deadline_misses, r.uds.lost, r.floor_lost
    );
    if r.steal_ms.iter().any(|&ms| ms > 0.0) {
        let per_cpu: Vec<String> = r.steal_ms.iter().enumerate().map(|(i, ms)| format!("cpu{i} {ms:.0} ms")).collect();
        println!(
            "hypervisor steal while measuring: {} (a stolen CPU stalls even SCHED_FIFO); \
             of the iceoryx2 deadline misses, {} came while the hypervisor took a CPU",
            per_cpu.join(", "),
            r.misses_during_steal
        );
    }
    println!(
        "ratios: iceoryx2 to the floor p99 {:.2} (p50 {:.2}); iceoryx2 to Unix sockets p50 {:.2}, p99 {:.2}",
        r.ratios.e2e_p99_over_floor_p99,
        r.ratios.e2e_p50_over_floor_p50,
        r.ratios.e2e_p50_over_uds_p50,
        r.ratios.e2e_p99_over_uds_p99,
    );
}

fn write_plot(
    plot: &Path,
    pipeline: &PipelineAnalysis,
    uds: &PipelineAnalysis,
    floor: &FloorResult,
) -> anyhow::Result<Vec<PathBuf>> {
    let dir = plot.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let stem = plot.file_stem().and_then(|s| s.to_str()).context("--plot needs a file name, e.g. latency.png")?;
    let named: [(&str, &LatencyHistogram); 3] = [
        ("service set over iceoryx2", &pipeline.e2e),
        ("service set over Unix sockets", &uds.e2e),
        ("floor: eventfd ping chain", &floor.e2e),
    ];
    // Up to the largest p99.9, with room: the longest tail values land in the last bin.
    let upper = named.iter().map(|(_, h)| h.percentiles().p999).fold(0.0, f64::max) * 1.25;
    let series: Vec<(String, Vec<f64>, Vec<f64>)> = named
        .iter()
        .map(|(name, h)| {
            let bins = h.bins(upper.max(1.0), 150);
            (name.to_string(), bins.iter().map(|b| b.0).collect(), bins.iter().map(|b| b.1 as f64).collect())
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
