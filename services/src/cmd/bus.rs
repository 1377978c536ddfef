//! `jetbench list`, `echo` and `hz`: look inside a running service set, on this
//! machine's bus or, with `--remote ENDPOINT`, over Zenoh from another machine.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use jetbench_bridge::{Endpoint, RemoteBench, RemoteSubscriber};
use jetbench_bus::{stop_requested, Bus, Subscriber};
use jetbench_msgs::{format_fields, visit_channels, Channel, ChannelVisitor, Sample};

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

/// `jetbench echo`: print samples as they arrive.
pub struct Echo {
    pub count: Option<u64>,
}

impl ChannelAction for Echo {
    const DEPTH: usize = 256;

    fn act<T: Sample>(&mut self, _channel: Channel<T>, samples: &mut dyn Samples<T>) -> anyhow::Result<()> {
        let mut printed = 0;
        while !stop_requested() && self.count.is_none_or(|n| printed < n) {
            if let Some(sample) = samples.next(POLL)? {
                println!("{}", format_fields(&sample));
                printed += 1;
            }
        }
        Ok(())
    }
}

/// `jetbench hz`: rate, period jitter and lost samples of a channel.
pub struct Hz {
    pub window: f64,
    pub duration: Option<f64>,
}

impl ChannelAction for Hz {
    const DEPTH: usize = 512;

    fn act<T: Sample>(&mut self, channel: Channel<T>, samples: &mut dyn Samples<T>) -> anyhow::Result<()> {
        let start = Instant::now();
        let mut window_start = start;
        let mut last_arrival: Option<Instant> = None;
        let mut periods_ms: Vec<f64> = Vec::new();
        let window = Duration::from_secs_f64(self.window);
        while !stop_requested() && self.duration.is_none_or(|d| start.elapsed().as_secs_f64() < d) {
            if samples.next(POLL.min(window))?.is_some() {
                let now = Instant::now();
                if let Some(last) = last_arrival {
                    periods_ms.push((now - last).as_secs_f64() * 1e3);
                }
                last_arrival = Some(now);
            }
            if window_start.elapsed() < window {
                continue;
            }
            let n = periods_ms.len();
            if n == 0 {
                println!("{}: no samples", channel.name);
            } else {
                let mean = periods_ms.iter().sum::<f64>() / n as f64;
                let std = (periods_ms.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
                let (min, max) = periods_ms.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(*p), b.max(*p)));
                println!(
                    "{}: {:.2} Hz  period mean {mean:.3} ms  min {min:.3}  max {max:.3}  std {std:.3}  lost {}",
                    channel.name,
                    1e3 / mean,
                    samples.lost()
                );
            }
            periods_ms.clear();
            window_start = Instant::now();
        }
        Ok(())
    }
}
