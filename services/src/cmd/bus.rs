//! `jetbench list`, `echo` and `hz`: look inside a running service set.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::bail;
use jetbench_bus::{Bus, Flow};
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

/// Finds the channel called `name` and runs `action` with its type.
pub trait ChannelAction {
    fn act<T: Sample>(&mut self, bus: &Bus, channel: Channel<T>) -> anyhow::Result<()>;
}

pub fn with_channel<A: ChannelAction>(name: &str, action: A) -> anyhow::Result<ExitCode> {
    struct Find<A> {
        name: String,
        action: A,
        found: bool,
        result: anyhow::Result<()>,
    }
    impl<A: ChannelAction> ChannelVisitor for Find<A> {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            if !self.found && self.name.trim_start_matches('/') == channel.name {
                self.found = true;
                self.result = Bus::open(&format!("jetbench-cli-{}", std::process::id()))
                    .map_err(anyhow::Error::from)
                    .and_then(|bus| self.action.act(&bus, channel));
            }
        }
    }
    let mut find = Find { name: name.to_string(), action, found: false, result: Ok(()) };
    visit_channels(&mut find);
    if !find.found {
        bail!("unknown channel {name:?}; channels are: {}", jetbench_msgs::channel_names().join(", "));
    }
    find.result.map(|()| ExitCode::SUCCESS)
}

/// `jetbench echo`: print samples as they arrive.
pub struct Echo {
    pub count: Option<u64>,
}

impl ChannelAction for Echo {
    fn act<T: Sample>(&mut self, bus: &Bus, channel: Channel<T>) -> anyhow::Result<()> {
        let sub = bus.subscriber(channel, 256)?;
        let mut printed = 0;
        bus.run(&[(&sub, None)], None, |_| {
            while let Ok(Some(sample)) = sub.try_recv() {
                println!("{}", format_fields(&sample));
                printed += 1;
                if self.count.is_some_and(|n| printed >= n) {
                    return Flow::Stop;
                }
            }
            Flow::Continue
        })?;
        Ok(())
    }
}

/// `jetbench hz`: rate, period jitter and lost samples of a channel.
pub struct Hz {
    pub window: f64,
    pub duration: Option<f64>,
}

impl ChannelAction for Hz {
    fn act<T: Sample>(&mut self, bus: &Bus, channel: Channel<T>) -> anyhow::Result<()> {
        let sub = bus.subscriber(channel, 512)?;
        let start = Instant::now();
        let mut window_start = start;
        let mut last_arrival: Option<Instant> = None;
        let mut periods_ms: Vec<f64> = Vec::new();
        let window = Duration::from_secs_f64(self.window);
        bus.run(&[(&sub, None)], Some(Duration::from_millis(100)), |_| {
            while let Ok(Some(_)) = sub.try_recv() {
                let now = Instant::now();
                if let Some(last) = last_arrival {
                    periods_ms.push((now - last).as_secs_f64() * 1e3);
                }
                last_arrival = Some(now);
            }
            let now = Instant::now();
            if now - window_start >= window {
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
                        sub.gaps()
                    );
                }
                periods_ms.clear();
                window_start = now;
            }
            match self.duration {
                Some(d) if (now - start).as_secs_f64() >= d => Flow::Stop,
                _ => Flow::Continue,
            }
        })?;
        Ok(())
    }
}
