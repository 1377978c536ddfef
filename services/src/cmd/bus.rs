//! `jetbench list`, `echo` and `hz`: look inside a running service set, on this
//! machine's bus or, with `--remote ENDPOINT`, over Zenoh from another machine.

use std::io::Write;
use std::os::fd::AsRawFd;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use jetbench_bridge::{Endpoint, RemoteBench, RemoteSubscriber};
use jetbench_bus::{stop_requested, Bus, Subscriber};
use jetbench_msgs::{format_fields, visit_channels, Channel, ChannelVisitor, RosType, Sample};

/// `jetbench list`: the channels and nodes of the running service sets.
pub fn list() -> anyhow::Result<ExitCode> {
    let known = jetbench_msgs::channel_names();
    let live = jetbench_bus::list_channels();
    println!("channels:");
    if live.is_empty() {
        println!("  (none: is `jetbench up` running?)");
    }
    for name in &live {
        let note = if known.contains(&name.as_str()) { "" } else { "  (not a jetbench channel)" };
        println!("  {name}{note}");
    }
    println!("nodes:");
    for node in jetbench_bus::list_nodes() {
        println!("  {node}");
    }
    Ok(ExitCode::SUCCESS)
}

/// The samples of one channel, from this machine's bus or a remote bench.
pub trait Samples<T> {
    /// The next sample, waiting at most `timeout` (less on a stop request).
    fn next(&mut self, timeout: Duration) -> anyhow::Result<Option<T>>;
    /// Samples lost so far (`seq` gaps).
    fn lost(&self) -> u64;
}

impl<T: Sample> Samples<T> for Subscriber<T> {
    fn next(&mut self, timeout: Duration) -> anyhow::Result<Option<T>> {
        Ok(self.recv_timeout(timeout)?)
    }

    fn lost(&self) -> u64 {
        self.gaps()
    }
}

impl<T: Sample> Samples<T> for RemoteSubscriber<T> {
    fn next(&mut self, timeout: Duration) -> anyhow::Result<Option<T>> {
        Ok(self.recv_timeout(timeout))
    }

    fn lost(&self) -> u64 {
        self.counts().0.gaps
    }
}

/// What to do with the samples of one channel.
pub trait ChannelAction {
    /// How many samples may queue on the way.
    const DEPTH: usize;
    fn act<T: Sample>(&mut self, channel: Channel<T>, samples: &mut dyn Samples<T>) -> anyhow::Result<()>;
}

/// Finds the channel called `name` and runs `action` on its samples, from the
/// local bus, or from the bench bridged at `remote`.
pub fn with_channel<A: ChannelAction>(name: &str, remote: Option<&str>, action: A) -> anyhow::Result<ExitCode> {
    struct Find<'a, A> {
        name: String,
        remote: Option<&'a str>,
        action: A,
        found: bool,
        result: anyhow::Result<()>,
    }
    impl<A: ChannelAction> Find<'_, A> {
        fn run<T: Sample>(&mut self, channel: Channel<T>) -> anyhow::Result<()> {
            match self.remote {
                Some(endpoint) => {
                    let endpoint: Endpoint = endpoint.parse()?;
                    let namespace = jetbench_bus::namespace_name()?;
                    jetbench_bus::install_signal_flag()?;
                    let bench = RemoteBench::connect(&endpoint, &namespace)
                        .with_context(|| format!("cannot reach the bench bridged at {endpoint}"))?;
                    eprintln!("reading {} of {}", channel.name, bench.describe());
                    self.action.act(channel, &mut bench.subscribe(channel, A::DEPTH)?)
                }
                None => {
                    let bus = Bus::open(&format!("jetbench-cli-{}", std::process::id()))?;
                    self.action.act(channel, &mut bus.subscriber(channel, A::DEPTH)?)
                }
            }
        }
    }
    impl<A: ChannelAction> ChannelVisitor for Find<'_, A> {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            if !self.found && self.name.trim_start_matches('/') == channel.name {
                self.found = true;
                self.result = self.run(channel);
            }
        }
    }
    let mut find = Find { name: name.to_string(), remote, action, found: false, result: Ok(()) };
    visit_channels(&mut find);
    if !find.found {
        bail!("unknown channel {name:?}; channels are: {}", jetbench_msgs::channel_names().join(", "));
    }
    find.result.map(|()| ExitCode::SUCCESS)
}

/// How long one wait for a sample lasts before the stop flag and the clock are looked at.
const POLL: Duration = Duration::from_millis(100);

/// How `echo` prints a sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum EchoFormat {
    /// `name=value, ...`, one sample per line.
    #[default]
    Fields,
    /// CSV: a header line once, then one line per sample; an array is one column per element.
    Csv,
    /// One JSON object per line (JSON Lines); a value that is not a number is null.
    Json,
}

/// `jetbench echo`: print samples as they arrive.
pub struct Echo {
    pub count: Option<u64>,
    pub format: EchoFormat,
    /// Reading this machine's bus (not a remote bench): say so when no set runs.
    pub local: bool,
}

impl ChannelAction for Echo {
    const DEPTH: usize = 256;

    fn act<T: Sample>(&mut self, channel: Channel<T>, samples: &mut dyn Samples<T>) -> anyhow::Result<()> {
        let mut printed = 0;
        let mut idle = IdleNotice::new(self.local);
        let mut out = std::io::stdout().lock();
        if self.format == EchoFormat::Csv {
            writeln!(out, "{}", csv_header::<T>())?;
            out.flush()?;
        }
        while !stop_requested() && self.count.is_none_or(|n| printed < n) {
            match samples.next(POLL)? {
                Some(sample) => {
                    let line = match self.format {
                        EchoFormat::Fields => format_fields(&sample),
                        EchoFormat::Csv => csv_row(&sample),
                        EchoFormat::Json => json_line(&sample),
                    };
                    writeln!(out, "{line}")?;
                    out.flush()?;
                    printed += 1;
                    idle.heard();
                }
                None => idle.check(channel.name),
            }
        }
        Ok(())
    }
}

/// The values of a sample's fields as text, arrays one element each, with their column names.
fn columns<T: Sample>(sample: &T) -> Vec<(String, String)> {
    let bytes = sample.as_bytes();
    let mut out = Vec::new();
    for field in T::FIELDS {
        let p = field.ros_type.primitive();
        match field.ros_type {
            RosType::Scalar(_) => {
                out.push((field.name.to_string(), RosType::Scalar(p).format_value(&bytes[field.offset..])))
            }
            RosType::Array(_, n) => {
                for i in 0..n {
                    out.push((
                        format!("{}_{i}", field.name),
                        RosType::Scalar(p).format_value(&bytes[field.offset + i * p.size()..]),
                    ));
                }
            }
        }
    }
    out
}

/// The CSV header of `T`'s samples (an array field `f` of n elements is `f_0..f_{n-1}`).
fn csv_header<T: Sample>() -> String {
    columns(&T::default()).into_iter().map(|(name, _)| name).collect::<Vec<_>>().join(",")
}

fn csv_row<T: Sample>(sample: &T) -> String {
    columns(sample).into_iter().map(|(_, value)| value).collect::<Vec<_>>().join(",")
}

/// A sample as one JSON object, arrays as JSON arrays; NaN and infinities (not JSON) as null.
fn json_line<T: Sample>(sample: &T) -> String {
    let bytes = sample.as_bytes();
    let number = |text: String| -> serde_json::Value {
        if let Ok(i) = text.parse::<i64>() {
            return i.into();
        }
        if let Ok(u) = text.parse::<u64>() {
            return u.into();
        }
        match text.parse::<f64>() {
            Ok(x) if x.is_finite() => serde_json::Number::from_f64(x).map_or(serde_json::Value::Null, Into::into),
            _ => serde_json::Value::Null,
        }
    };
    let mut object = serde_json::Map::new();
    for field in T::FIELDS {
        let p = field.ros_type.primitive();
        let value = match field.ros_type {
            RosType::Scalar(_) => number(RosType::Scalar(p).format_value(&bytes[field.offset..])),
            RosType::Array(_, n) => (0..n)
                .map(|i| number(RosType::Scalar(p).format_value(&bytes[field.offset + i * p.size()..])))
                .collect::<Vec<_>>()
                .into(),
        };
        object.insert(field.name.to_string(), value);
    }
    serde_json::Value::Object(object).to_string()
}

/// After a second without a sample on this machine's bus, says once (on stderr)
/// when no service set holds the namespace, instead of waiting silently.
struct IdleNotice {
    since: Instant,
    armed: bool,
}

/// How long without a sample before looking for a running set.
const IDLE_NOTICE: Duration = Duration::from_secs(1);

impl IdleNotice {
    fn new(local: bool) -> IdleNotice {
        IdleNotice { since: Instant::now(), armed: local }
    }

    fn heard(&mut self) {
        self.armed = false;
    }

    fn check(&mut self, channel: &str) {
        if !self.armed || self.since.elapsed() < IDLE_NOTICE {
            return;
        }
        self.armed = false;
        if set_running() == Some(false) {
            let namespace = jetbench_bus::namespace_name().unwrap_or_else(|_| "(default)".into());
            eprintln!(
                "no service set is running on namespace {namespace} (start one with `jetbench up --sim`, or play a \
                 recording with `jetbench play FILE`); waiting for {channel}"
            );
        }
    }
}

/// Whether a service set (`jetbench up`, `jetbench play`) holds this namespace's
/// lock now; `None` when that cannot be told.
fn set_running() -> Option<bool> {
    let path = jetbench_bus::lock::lock_path().ok()?;
    let file = match std::fs::File::open(&path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Some(false),
        Err(_) => return None,
    };
    // SAFETY: flock on a descriptor this function owns; a shared, non-blocking
    // try that is released when `file` closes.
    let taken = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_SH | libc::LOCK_NB) } == 0;
    Some(!taken)
}

/// `jetbench hz`: rate, period jitter and lost samples of a channel, like
/// `ros2 topic hz`: printed every second over the last `window` messages.
pub struct Hz {
    /// Messages the statistics are computed over (`-w`), the latest ones.
    pub window: usize,
    pub duration: Option<f64>,
    /// Reading this machine's bus (not a remote bench): say so when no set runs.
    pub local: bool,
}

/// How often `hz` prints.
const HZ_EVERY: Duration = Duration::from_secs(1);

impl ChannelAction for Hz {
    const DEPTH: usize = 512;

    fn act<T: Sample>(&mut self, channel: Channel<T>, samples: &mut dyn Samples<T>) -> anyhow::Result<()> {
        let start = Instant::now();
        let mut last_print = start;
        let mut last_arrival: Option<Instant> = None;
        let mut periods_ms: std::collections::VecDeque<f64> = std::collections::VecDeque::new();
        let mut new_since_print = 0usize;
        let mut idle = IdleNotice::new(self.local);
        while !stop_requested() && self.duration.is_none_or(|d| start.elapsed().as_secs_f64() < d) {
            if samples.next(POLL)?.is_some() {
                let now = Instant::now();
                if let Some(last) = last_arrival {
                    periods_ms.push_back((now - last).as_secs_f64() * 1e3);
                    if periods_ms.len() > self.window {
                        periods_ms.pop_front();
                    }
                }
                last_arrival = Some(now);
                new_since_print += 1;
                idle.heard();
            } else {
                idle.check(channel.name);
            }
            if last_print.elapsed() < HZ_EVERY {
                continue;
            }
            last_print = Instant::now();
            let n = periods_ms.len();
            if new_since_print == 0 {
                println!("{}: no new messages", channel.name);
            } else if n > 0 {
                let mean = periods_ms.iter().sum::<f64>() / n as f64;
                let std = (periods_ms.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
                let (min, max) = periods_ms.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(*p), b.max(*p)));
                println!(
                    "{}: {:.2} Hz  period mean {mean:.3} ms  min {min:.3}  max {max:.3}  std {std:.3}  window {n}  \
                     lost {}",
                    channel.name,
                    1e3 / mean,
                    samples.lost()
                );
            }
            new_since_print = 0;
        }
        Ok(())
    }
}
