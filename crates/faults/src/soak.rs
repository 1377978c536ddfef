//! The soak test: the set recording for minutes under background load, each
//! process's resident memory sampled over time (flat: no leak), and at the
//! end the samples lost, the deadlines missed and the recording's size.

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::time::{Duration, Instant};

use jetbench_latency::load::{Load, LoadKind};
use jetbench_msgs::{Health, Sample, ServiceId};

use crate::set::RunningSet;
use crate::{Bench, FaultsError};

/// One process's resident memory over the run.
#[derive(Clone, Debug, PartialEq)]
pub struct Memory {
    /// The service's name, e.g. `recorder`.
    pub process: String,
    /// (s since ready, RSS KiB), one per sample.
    pub rss_kib: Vec<(f64, u64)>,
}

impl Memory {
    /// RSS at the first sample after the first fifth of the run (the set has
    /// settled: buffers allocated, queues full), and at the last, KiB.
    pub fn settled_and_last_kib(&self) -> (u64, u64) {
        let end = self.rss_kib.last().map_or(0.0, |s| s.0);
        let settled = self.rss_kib.iter().find(|s| s.0 >= end / 5.0).map_or(0, |s| s.1);
        (settled, self.rss_kib.last().map_or(0, |s| s.1))
    }

    /// Least-squares slope of RSS over the settled part of the run, KiB per minute.
    pub fn slope_kib_per_min(&self) -> f64 {
        let end = self.rss_kib.last().map_or(0.0, |s| s.0);
        let pts: Vec<(f64, f64)> =
            self.rss_kib.iter().filter(|s| s.0 >= end / 5.0).map(|&(t, r)| (t / 60.0, r as f64)).collect();
        let n = pts.len() as f64;
        if pts.len() < 2 {
            return 0.0;
        }
        let (mt, mr) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
        let var: f64 = pts.iter().map(|p| (p.0 - mt).powi(2)).sum();
        if var == 0.0 {
            0.0
        } else {
            pts.iter().map(|p| (p.0 - mt) * (p.1 - mr)).sum::<f64>() / var
        }
    }
}

/// What a soak run showed.
#[derive(Clone, Debug)]
pub struct Soak {
    /// Length of the run, min.
    pub minutes: f64,
    /// The load beside it, as given (`none`, `cpu`, ...).
    pub load: String,
    /// The services ran with their real-time settings (SCHED_FIFO, affinity, mlockall).
    pub rt: bool,
    /// Every process's resident memory over the run.
    pub memory: Vec<Memory>,
    /// Samples lost between the services and the recorder (`seq` gaps), per channel.
    pub gaps: BTreeMap<String, u64>,
    /// Deadline misses per service, from its last heartbeat.
    pub misses: BTreeMap<String, u64>,
    /// Messages in the recording.
    pub messages: u64,
    /// Size of the recording, bytes.
    pub recording_bytes: u64,
    /// The launcher exited 0.
    pub exit_ok: bool,
}

/// Runs the set for `minutes` under `load` (with its real-time settings when
/// `rt`, as a bench under load should run), recording, and samples every
/// process's RSS every `every`.
pub fn soak(bench: &Bench, minutes: f64, load: LoadKind, rt: bool, every: Duration) -> Result<Soak, FaultsError> {
    let namespace = bench.fresh_namespace();
    let record = bench.scratch(&format!("soak-{namespace}.mcap"));
    let duration_s = (minutes * 60.0).round().max(1.0);
    let background = Load::start(load, &bench.exe)
        .map_err(|e| FaultsError::Failed { what: "the background load".into(), message: e.to_string() })?;
    let record_arg = record.display().to_string();
    let duration = duration_s.to_string();
    let mut args = vec!["--duration", &duration, "--record", &record_arg];
    if rt {
        args.push("--rt");
    }
    let mut set = RunningSet::start(bench, &namespace, &args)?;
    let ready = Instant::now();
    let mut processes: Vec<(String, u32)> = set.service_pids();
    processes.push(("launcher".into(), set.launcher_pid()));
    let mut memory: Vec<Memory> =
        processes.iter().map(|(name, _)| Memory { process: name.clone(), rss_kib: Vec::new() }).collect();
    let end = ready + Duration::from_secs_f64(duration_s);
    let mut next = ready;
    while Instant::now() < end {
        for ((_, pid), m) in processes.iter().zip(&mut memory) {
            if let Some(kib) = rss_kib(*pid) {
                m.rss_kib.push((ready.elapsed().as_secs_f64(), kib));
            }
        }
        next += every;
        std::thread::sleep(next.min(end).saturating_duration_since(Instant::now()));
    }
    let (status, _) = set.wait_exit(Duration::from_secs(120))?;
    let load = background.description.clone();
    drop(background);
    let (gaps, misses, messages) = tally(&record)?;
    Ok(Soak {
        minutes,
        load,
        rt,
        memory,
        gaps,
        misses,
        messages,
        recording_bytes: std::fs::metadata(&record).map_or(0, |m| m.len()),
        exit_ok: status.success(),
    })
}

/// `VmRSS` of a process, KiB.
fn rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status.lines().find_map(|l| l.strip_prefix("VmRSS:")?.trim().strip_suffix("kB")?.trim().parse().ok())
}

/// Reads a long recording message by message (without holding it in memory):
/// `seq` gaps per topic (per publisher on `bench/health`), each service's last
/// deadline-miss count, and the number of messages.
type Tally = (BTreeMap<String, u64>, BTreeMap<String, u64>, u64);

fn tally(path: &Path) -> Result<Tally, FaultsError> {
    let bytes = std::fs::read(path).map_err(|source| FaultsError::Io { path: path.into(), source })?;
    let stream = mcap::MessageStream::new(&bytes)
        .map_err(|source| jetbench_record::RecordError::Mcap { path: path.into(), source })?;
    let mut next_seq: BTreeMap<(String, u32), u64> = BTreeMap::new();
    let (mut gaps, mut misses, mut messages) = (BTreeMap::new(), BTreeMap::new(), 0);
    for message in stream.map_while(Result::ok) {
        messages += 1;
        let body = message.data.get(4..).unwrap_or_default();
        let seq = body.first_chunk::<8>().map_or(0, |b| u64::from_le_bytes(*b));
        let topic = message.channel.topic.clone();
        let mut publisher = 0;
        if let Some(h) = (topic == "/bench/health").then(|| Health::from_bytes(body)).flatten() {
            publisher = h.service_id;
            let name = ServiceId::from_u32(h.service_id).map_or("?", ServiceId::name);
            misses.insert(name.to_string(), h.deadline_misses);
        }
        let expected = next_seq.entry((topic.clone(), publisher)).or_insert(seq);
        *gaps.entry(topic).or_insert(0) += seq.saturating_sub(*expected);
        *expected = seq + 1;
    }
    Ok((gaps, misses, messages))
}

impl fmt::Display for Soak {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "Soak: {:.1} min{} under `{}`; jetbench up exited {}",
            self.minutes,
            if self.rt { " with --rt" } else { "" },
            self.load,
            if self.exit_ok { "cleanly" } else { "WITH AN ERROR" }
        )?;
        writeln!(f, "\n| process | RSS settled (KiB) | RSS at the end (KiB) | max (KiB) | slope (KiB/min) |")?;
        writeln!(f, "|---|---:|---:|---:|---:|")?;
        for m in &self.memory {
            let (settled, last) = m.settled_and_last_kib();
            let max = m.rss_kib.iter().map(|s| s.1).max().unwrap_or(0);
            writeln!(f, "| {} | {settled} | {last} | {max} | {:+.1} |", m.process, m.slope_kib_per_min())?;
        }
        let lost: u64 = self.gaps.values().sum();
        let missed: Vec<String> = self.misses.iter().map(|(s, n)| format!("{s} {n}")).collect();
        writeln!(f, "\nsamples lost (seq gaps): {lost}; deadline misses: {}", missed.join(", "))?;
        writeln!(
            f,
            "recording: {} messages, {:.1} MB ({:.1} kB/s)",
            self.messages,
            self.recording_bytes as f64 / 1e6,
            self.recording_bytes as f64 / 1e3 / (self.minutes * 60.0)
        )
    }
}
