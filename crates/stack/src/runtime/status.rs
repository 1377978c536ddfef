//! The live status line of `jetbench up`, and the console it shares with the
//! run's log.
//!
//! The line says, at a glance: the engine (the ECU's state by name, RPM,
//! EGT), whether the throttle path is armed, how thrust tracks its target,
//! the health of every control-path channel as one judgement with the worst
//! channel named, and the latest trip. Deadline misses are explained once, in
//! a log line, when they rise.
//!
//! On a terminal the line is an indicatif bar redrawn in place; every log line
//! of the run (the services' output, events, the launcher's own tracing) is
//! printed above it through [`say`], [`say_err`] or [`ConsoleStderr`], which
//! take the bar away, print, and draw it again, so a log line never runs
//! through it. Without a terminal the line is printed as a line of its own
//! every few seconds.
//!
//! The formatting is pure ([`StatusView::line`], [`judge_health`],
//! [`MissWatch`]) and tested sample by sample.

use std::fmt::Write as _;
use std::io::Write;
use std::sync::Mutex;
use std::time::Duration;

use jetbench_msgs::{actuation_flags, command_flags, health_flags, ServiceId};

use crate::runtime::clock::PERIOD_NS;

/// The rate every control-path channel runs at, Hz.
pub const WANT_HZ: f64 = 1e9 / PERIOD_NS as f64;

/// A channel's measured rate below this fraction of [`WANT_HZ`] is unhealthy
/// (a window of one second counts 100 ± 2 samples on a healthy bus).
const RATE_OK_FRACTION: f64 = 0.9;

/// How long after a first explanation of deadline misses further rises are
/// only summed up, at most once per this period.
pub const MISS_REMINDER: Duration = Duration::from_secs(30);

/// The engine as the ECU reports it.
#[derive(Clone, Debug, PartialEq)]
pub struct EngineView {
    /// The ECU's state by name (`run`, `ignition`, ...).
    pub state: String,
    /// Shaft speed, rpm.
    pub rpm: f64,
    /// Exhaust gas temperature, °C.
    pub egt_c: f64,
}

/// What the status line shows, gathered by the launcher.
#[derive(Clone, Debug, Default)]
pub struct StatusView {
    /// Seconds since the engine ran (since the status line started).
    pub elapsed_s: f64,
    /// `None` until the ECU's first fresh reading.
    pub engine: Option<EngineView>,
    /// The newest actuation sample's flags.
    pub actuation_flags: Option<u32>,
    /// The newest command's flags.
    pub command_flags: Option<u64>,
    /// Estimated thrust, N.
    pub thrust_n: Option<f64>,
    /// The thrust the controller aims at (`bench/reference`), N.
    pub target_n: Option<f64>,
    /// Throttle applied by the board, %.
    pub throttle_pct: Option<f64>,
    /// The health judgement, from [`judge_health`].
    pub health: String,
    /// The newest trip, in words (`TRIP egt_max ...`).
    pub last_trip: Option<String>,
}

/// Whether the throttle reaches the engine, from actuation's and control's flags.
pub fn throttle_path(actuation: Option<u32>, command: Option<u64>) -> &'static str {
    let Some(a) = actuation else { return "throttle -" };
    if a & actuation_flags::DISARMED != 0 {
        "DISARMED"
    } else if a & actuation_flags::BOARD_SILENT != 0 {
        "board silent (its watchdog idles)"
    } else if a & actuation_flags::BOARD_IDLE != 0 {
        "board idles (its watchdog)"
    } else if a & actuation_flags::IDLE_FALLBACK != 0 {
        "idle: no fresh command"
    } else if command.is_some_and(|c| c & command_flags::GATED != 0) {
        "armed, held by control"
    } else {
        "armed"
    }
}

/// A number with its unit, or `-` when there is none (never NaN).
fn figure(value: Option<f64>, decimals: usize, unit: &str) -> String {
    match value.filter(|v| v.is_finite()) {
        Some(v) => format!("{v:.decimals$} {unit}"),
        None => "-".into(),
    }
}

impl StatusView {
    /// The status line, e.g.
    /// `  12.0 s | ECU run 98400 rpm 612 °C | armed | thrust 50.1 N target 50.0 N, throttle 72.8 % | health ok | no trip`.
    pub fn line(&self) -> String {
        let engine = match &self.engine {
            Some(e) => format!("ECU {} {} {}", e.state, figure(Some(e.rpm), 0, "rpm"), figure(Some(e.egt_c), 0, "°C")),
            None => "ECU -".into(),
        };
        let trip = match &self.last_trip {
            Some(t) => format!("last trip: {}", t.strip_prefix("TRIP ").unwrap_or(t)),
            None => "no trip".into(),
        };
        format!(
            "{:>6.1} s | {engine} | {} | thrust {} target {}, throttle {} | {} | {trip}",
            self.elapsed_s,
            throttle_path(self.actuation_flags, self.command_flags),
            figure(self.thrust_n, 1, "N"),
            figure(self.target_n, 1, "N"),
            figure(self.throttle_pct, 1, "%"),
            self.health,
        )
    }
}

/// One control-path channel's rate over the last window.
#[derive(Clone, Copy, Debug)]
pub struct ChannelRate {
    /// The channel's topic.
    pub channel: &'static str,
    /// Samples per second over the window.
    pub hz: f64,
}

/// One service's state over the last window, from its `bench/health` heartbeats.
#[derive(Clone, Copy, Debug)]
pub struct ServiceWindow {
    /// Which service.
    pub service: ServiceId,
    /// Deadline misses in the window.
    pub new_misses: u64,
    /// Samples lost on its inputs in the window.
    pub new_gaps: u64,
    /// Its newest heartbeat's flags.
    pub flags: u32,
}

/// The health of the run as one judgement, the worst first: a channel below
/// its rate (the slowest named, with what it should be), a service in its
/// fallback, samples lost, deadlines missed; otherwise `health ok`.
pub fn judge_health(rates: &[ChannelRate], services: &[ServiceWindow]) -> String {
    // A rate that is not a number counts as silent.
    let hz = |r: &ChannelRate| if r.hz.is_nan() { 0.0 } else { r.hz };
    let slowest = rates.iter().min_by(|a, b| hz(a).total_cmp(&hz(b)));
    if let Some(slow) = slowest.filter(|r| hz(r) < RATE_OK_FRACTION * WANT_HZ) {
        let how = if hz(slow) > 0.0 { format!("{:.0} Hz", slow.hz) } else { "silent".into() };
        return format!("health: {} {how} (want {WANT_HZ:.0})", slow.channel);
    }
    if let Some(s) = services.iter().find(|s| s.flags & health_flags::FALLBACK != 0) {
        return format!("health: {} in its fallback", s.service.name());
    }
    if let Some(s) = services.iter().filter(|s| s.new_gaps > 0).max_by_key(|s| s.new_gaps) {
        return format!("health: {} lost {} input samples", s.service.name(), s.new_gaps);
    }
    if let Some(s) = services.iter().filter(|s| s.new_misses > 0).max_by_key(|s| s.new_misses) {
        let n = s.new_misses;
        return format!("health: {} missed {n} deadline{}", s.service.name(), if n == 1 { "" } else { "s" });
    }
    "health ok".into()
}

/// Follows each service's deadline misses and says, once, what rising misses
/// mean and what to do; later rises are summed up at most every
/// [`MISS_REMINDER`].
#[derive(Debug, Default)]
pub struct MissWatch {
    /// Total misses per service when last said.
    said: Vec<(ServiceId, u64)>,
    /// When the explanation was last given (seconds of the run).
    last_said_s: Option<f64>,
    explained: bool,
}

impl MissWatch {
    /// Given each service's total misses at `now_s` (seconds of the run), the
    /// log line to print, if any.
    pub fn update(&mut self, now_s: f64, totals: &[(ServiceId, u64)]) -> Option<String> {
        let before = |id: ServiceId| self.said.iter().find(|(s, _)| *s == id).map_or(0, |(_, n)| *n);
        let mut rises: Vec<(ServiceId, u64, u64)> =
            totals.iter().filter(|(id, n)| *n > before(*id)).map(|&(id, n)| (id, n - before(id), n)).collect();
        if rises.is_empty() {
            return None;
        }
        if self.last_said_s.is_some_and(|t| now_s - t < MISS_REMINDER.as_secs_f64()) {
            return None;
        }
        let since = match self.last_said_s {
            Some(t) => format!("in the last {:.0} s", now_s - t),
            None => "since the start".into(),
        };
        rises.sort_by_key(|&(_, new, _)| std::cmp::Reverse(new));
        let mut who = String::new();
        for (i, (id, new, total)) in rises.iter().enumerate() {
            let sep = if i == 0 { "" } else { ", " };
            let _ = write!(who, "{sep}{} {new} ({total} in all)", id.name());
        }
        let line = if self.explained {
            format!("deadline misses {since}: {who}")
        } else {
            format!(
                "deadline misses {since}: {who}. A miss is a cycle whose input came later \
                 than its deadline or whose work took longer than the {:.0} ms period: that cycle acted on \
                 an older sample, so the loop's delay grew. They should stay at 0: run with --rt (SCHED_FIFO \
                 and pinned CPUs), keep other work off this machine, and measure the margin with \
                 `jetbench latency`.",
                PERIOD_NS as f64 / 1e6
            )
        };
        self.explained = true;
        self.last_said_s = Some(now_s);
        self.said = totals.to_vec();
        Some(line)
    }
}

/// The live line on a terminal: shown by indicatif, which takes it away for
/// every log line and draws it again below.
static BAR: Mutex<Option<indicatif::ProgressBar>> = Mutex::new(None);

/// The status line on the terminal while it lives; dropped, the line goes.
pub struct LiveLine {
    bar: indicatif::ProgressBar,
}

impl LiveLine {
    /// A live line on standard error when it is a terminal; `None` otherwise.
    pub fn start() -> Option<LiveLine> {
        let target = indicatif::ProgressDrawTarget::stderr();
        if target.is_hidden() {
            return None;
        }
        let bar = indicatif::ProgressBar::with_draw_target(None, target)
            .with_style(indicatif::ProgressStyle::with_template("{wide_msg}").expect("a valid template"));
        *BAR.lock().unwrap_or_else(|e| e.into_inner()) = Some(bar.clone());
        Some(LiveLine { bar })
    }

    /// Shows `line`.
    pub fn set(&self, line: String) {
        self.bar.set_message(line);
    }
}

impl Drop for LiveLine {
    fn drop(&mut self) {
        *BAR.lock().unwrap_or_else(|e| e.into_inner()) = None;
        self.bar.finish_and_clear();
    }
}

/// Runs `print` with the live line (if any) taken off the terminal.
fn above_the_line(print: impl FnOnce()) {
    let bar = BAR.lock().unwrap_or_else(|e| e.into_inner()).clone();
    match bar {
        Some(bar) => bar.suspend(print),
        None => print(),
    }
}

/// Prints a log line on standard output, above the live line.
pub fn say(line: &str) {
    above_the_line(|| {
        let mut out = std::io::stdout().lock();
        let _ = out.write_all(format!("{line}\n").as_bytes());
        let _ = out.flush();
    });
}

/// Prints a log line on standard error, above the live line.
pub fn say_err(line: &str) {
    above_the_line(|| {
        let _ = std::io::stderr().lock().write_all(format!("{line}\n").as_bytes());
    });
}

/// Standard error for a log writer (tracing's): each write is printed above
/// the live line. `tracing_subscriber::fmt().with_writer(|| ConsoleStderr)`.
#[derive(Clone, Copy, Debug, Default)]
pub struct ConsoleStderr;

impl Write for ConsoleStderr {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let mut result = Ok(0);
        above_the_line(|| result = std::io::stderr().lock().write_all(buf).map(|()| buf.len()));
        result
    }

    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rates(hz: [f64; 5]) -> Vec<ChannelRate> {
        ["bench/thrust", "bench/state", "bench/reference", "bench/command", "bench/actuation"]
            .iter()
            .zip(hz)
            .map(|(&channel, hz)| ChannelRate { channel, hz })
            .collect()
    }

    fn quiet(service: ServiceId) -> ServiceWindow {
        ServiceWindow { service, new_misses: 0, new_gaps: 0, flags: 0 }
    }

    #[test]
    fn a_healthy_run_reads_ok_and_names_no_channel() {
        let services = [quiet(ServiceId::Sensing), quiet(ServiceId::Control)];
        assert_eq!(judge_health(&rates([100.0, 99.0, 100.0, 101.0, 98.0]), &services), "health ok");
    }

    #[test]
    fn the_slowest_channel_is_named_with_its_wanted_rate() {
        let judged = judge_health(&rates([100.0, 71.0, 85.0, 100.0, 100.0]), &[]);
        assert_eq!(judged, "health: bench/state 71 Hz (want 100)");
        let silent = judge_health(&rates([100.0, 100.0, 100.0, 0.0, 100.0]), &[]);
        assert_eq!(silent, "health: bench/command silent (want 100)");
        let nan = judge_health(&rates([100.0, f64::NAN, 100.0, 100.0, 100.0]), &[]);
        assert_eq!(nan, "health: bench/state silent (want 100)");
    }

    #[test]
    fn a_slow_channel_outranks_a_fallback_which_outranks_gaps_and_misses() {
        let mut actuation = quiet(ServiceId::Actuation);
        actuation.flags = health_flags::FALLBACK;
        let mut control = quiet(ServiceId::Control);
        control.new_misses = 3;
        let mut estimation = quiet(ServiceId::Estimation);
        estimation.new_gaps = 2;
        let ok = rates([100.0; 5]);
        assert_eq!(
            judge_health(&rates([100.0, 50.0, 100.0, 100.0, 100.0]), &[actuation, control]),
            "health: bench/state 50 Hz (want 100)"
        );
        assert_eq!(judge_health(&ok, &[control, actuation, estimation]), "health: actuation in its fallback");
        assert_eq!(judge_health(&ok, &[control, estimation]), "health: estimation lost 2 input samples");
        assert_eq!(judge_health(&ok, &[control]), "health: control missed 3 deadlines");
    }

    #[test]
    fn the_line_names_engine_armed_tracking_health_and_trip_and_ref_means_one_thing() {
        let view = StatusView {
            elapsed_s: 19.2,
            engine: Some(EngineView { state: "run".into(), rpm: 98_412.4, egt_c: 611.6 }),
            actuation_flags: Some(0),
            command_flags: Some(0),
            thrust_n: Some(50.04),
            target_n: Some(50.0),
            throttle_pct: Some(72.84),
            health: "health: bench/state 71 Hz (want 100)".into(),
            last_trip: None,
        };
        assert_eq!(
            view.line(),
            "  19.2 s | ECU run 98412 rpm 612 °C | armed | thrust 50.0 N target 50.0 N, throttle 72.8 % \
             | health: bench/state 71 Hz (want 100) | no trip"
        );
        assert!(!view.line().contains("ref"), "no abbreviation with two meanings");
    }

    #[test]
    fn missing_figures_are_dashes_and_the_trip_is_shown() {
        let view = StatusView {
            elapsed_s: 3.0,
            engine: None,
            actuation_flags: Some(actuation_flags::DISARMED),
            thrust_n: Some(f64::NAN),
            health: "health ok".into(),
            last_trip: Some("TRIP egt_max (exhaust too hot): 812.0 °C against 800.0 °C, response idle".into()),
            ..StatusView::default()
        };
        let line = view.line();
        assert_eq!(
            line,
            "   3.0 s | ECU - | DISARMED | thrust - target -, throttle - | health ok \
             | last trip: egt_max (exhaust too hot): 812.0 °C against 800.0 °C, response idle"
        );
        assert!(!line.contains("NaN"));
    }

    #[test]
    fn the_throttle_path_reads_from_the_flags() {
        assert_eq!(throttle_path(None, None), "throttle -");
        assert_eq!(throttle_path(Some(0), Some(command_flags::GATED)), "armed, held by control");
        assert_eq!(throttle_path(Some(actuation_flags::IDLE_FALLBACK), Some(0)), "idle: no fresh command");
        assert_eq!(
            throttle_path(Some(actuation_flags::BOARD_SILENT | actuation_flags::IDLE_FALLBACK), None),
            "board silent (its watchdog idles)"
        );
        assert_eq!(throttle_path(Some(actuation_flags::STALE), Some(command_flags::SATURATED_HIGH)), "armed");
    }

    #[test]
    fn misses_are_explained_once_then_summed_up_at_most_every_reminder() {
        let mut watch = MissWatch::default();
        assert_eq!(watch.update(1.0, &[(ServiceId::Control, 0), (ServiceId::Estimation, 0)]), None);
        let first = watch.update(5.0, &[(ServiceId::Control, 12), (ServiceId::Estimation, 3)]).expect("said");
        assert!(first.starts_with("deadline misses since the start: control 12 (12 in all), estimation 3 (3 in all)."));
        assert!(first.contains("--rt") && first.contains("jetbench latency"), "what to do: {first}");
        // Rising again soon after: not said on every tick.
        assert_eq!(watch.update(6.0, &[(ServiceId::Control, 20), (ServiceId::Estimation, 3)]), None);
        assert_eq!(watch.update(34.0, &[(ServiceId::Control, 25), (ServiceId::Estimation, 3)]), None);
        // Past the reminder: summed up, without the explanation again.
        let later = watch.update(36.0, &[(ServiceId::Control, 26), (ServiceId::Estimation, 3)]).expect("said");
        assert_eq!(later, "deadline misses in the last 31 s: control 14 (26 in all)");
        // No rise, nothing said.
        assert_eq!(watch.update(90.0, &[(ServiceId::Control, 26), (ServiceId::Estimation, 3)]), None);
    }
}
