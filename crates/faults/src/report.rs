//! The campaign's report (`docs/faults/REPORT.md`): the bounds each trial of
//! [`crate::campaign::run`] held or broke, and the tables of what it measured.

use std::fmt::Write;

use jetbench_stack::config::OnRecordError;

use crate::campaign::{Campaign, ALL_KINDS, CRASH_AT_S, DISK_KIB, KILL_WINDOW_S, READERS_CRASH_AT_S};
use crate::kill::{KillTrial, Victim};
use crate::p50_max;

impl Campaign {
    /// Every bound broken, one line each (empty: all held).
    pub fn problems(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for t in &self.kills {
            out.extend(t.problems.iter().map(|p| format!("kill {} at {:.2} s: {p}", t.victim, t.at_s)));
        }
        for r in &self.crashes {
            out.extend(r.problems.iter().map(|p| format!("recorder crash at {:.2} s: {p}", r.at_s)));
        }
        for d in &self.disk {
            out.extend(d.problems.iter().map(|p| format!("disk full ({:?}): {p}", d.on_error)));
        }
        for b in &self.bad_data {
            out.extend(b.problems.iter().map(|p| format!("inject {:?}: {p}", b.inject)));
        }
        if let Some(s) = &self.second_up {
            if s.status == Some(0) || !s.names_the_first || !s.side_by_side {
                out.push(format!("second up: {s:?}"));
            }
        }
        if let Some(a) = &self.access {
            if !a.open_to_others.is_empty() || !a.loose_modes.is_empty() || a.echo_status == Some(0) {
                out.push(format!("access: {a:?}"));
            }
        }
        for h in &self.healthy {
            out.extend(h.problems.iter().map(|p| format!("healthy engine ({}): {p}", h.profile)));
        }
        out.extend(self.not_run.iter().map(|n| format!("not run: {n}")));
        out
    }

    /// The report for `--report FILE`: the whole report, or, when only some
    /// parts ran (`--only`) and `existing` is the report of an earlier whole
    /// campaign, that report with the sections of the parts that ran replaced
    /// (or added before "Bounds broken"), and their broken bounds added, so a
    /// part can be measured again without the rest.
    pub fn report(&self, existing: Option<&str>, machine: &str) -> String {
        let whole = self.markdown(machine);
        let Some(existing) = existing.filter(|e| !self.only.is_empty() && e.contains("\n## Bounds broken")) else {
            return whole;
        };
        let sections = |text: &str| -> Vec<String> {
            let mut out: Vec<String> = Vec::new();
            for (i, part) in text.split("\n## ").enumerate() {
                out.push(if i == 0 { part.to_string() } else { format!("## {part}") });
            }
            out
        };
        let heading = |section: &str| section.lines().next().unwrap_or_default().to_string();
        let mut merged = sections(existing);
        for new in sections(&whole).into_iter().skip(1) {
            let h = heading(&new);
            if h == "## Bounds broken" {
                continue;
            }
            match merged.iter().position(|old| heading(old) == h) {
                Some(i) => merged[i] = format!("{}\n", new.trim_end()),
                None => {
                    let at = merged.iter().position(|old| heading(old) == "## Bounds broken").unwrap_or(merged.len());
                    merged.insert(at, format!("{}\n", new.trim_end()));
                }
            }
        }
        let problems = self.problems();
        if let (false, Some(bounds)) =
            (problems.is_empty(), merged.iter_mut().find(|s| heading(s) == "## Bounds broken"))
        {
            if bounds.contains("None: every bound of the campaign held.") {
                *bounds = "## Bounds broken\n".into();
            }
            for p in problems {
                bounds.push_str(&format!("\n- {}", p.lines().next().unwrap_or_default()));
            }
        }
        let mut out = merged.join("\n");
        if !out.ends_with('\n') {
            out.push('\n');
        }
        out
    }

    /// The report, in Markdown.
    pub fn markdown(&self, machine: &str) -> String {
        let mut md = String::new();
        let _ = self.write_markdown(&mut md, machine);
        md
    }

    fn write_markdown(&self, md: &mut String, machine: &str) -> std::fmt::Result {
        writeln!(md, "# Faults at the bench: the campaign")?;
        writeln!(md)?;
        writeln!(
            md,
            "Measured by `scripts/faults.sh` (`jetbench faults --repeat {} --seed {} --report docs/faults/REPORT.md`) \
             on {machine}. Real processes, real signals (SIGKILL), real files; the simulated bench behind the same \
             drivers as the real one. Times to a safe state are from the kill to the first sample that shows it, on the \
             samples' own `CLOCK_MONOTONIC` stamps. Each line of a table can be run again with the command beside it.",
            self.repeat, self.seed
        )?;
        self.write_kills(md)?;
        self.write_crashes(md)?;
        self.write_disk(md)?;
        self.write_bad_data(md)?;
        self.write_set(md)?;
        self.write_limits(md)?;
        writeln!(md, "\n## Bounds broken\n")?;
        let problems = self.problems();
        if problems.is_empty() {
            writeln!(md, "None: every bound of the campaign held.")?;
        }
        for p in problems {
            writeln!(md, "- {}", p.lines().next().unwrap_or_default())?;
        }
        Ok(())
    }

    fn write_kills(&self, md: &mut String) -> std::fmt::Result {
        // No kills (`--only` other parts): no section, so a spliced report
        // keeps its earlier table instead of an empty one.
        if self.kills.is_empty() {
            return Ok(());
        }
        writeln!(md, "\n## Every process killed\n")?;
        writeln!(
            md,
            "SIGKILL at a random moment {}–{} s into a recorded run. After each, a new `jetbench up` in the same \
             namespace runs 2 s and must record from its first sample, gap-free (\"restart clean\").\n",
            KILL_WINDOW_S.0, KILL_WINDOW_S.1
        )?;
        writeln!(
            md,
            "| killed | kills | safe state | time to safe state p50 / max (ms) | idle after (missed cycles) | \
             named by the launcher | orphans | restart clean | recording | samples lost | reproduce |"
        )?;
        writeln!(md, "|---|---:|---|---:|---:|---:|---:|---:|---|---:|---|")?;
        for victim in Victim::ALL {
            let trials: Vec<&KillTrial> = self.kills.iter().filter(|t| t.victim == victim).collect();
            if trials.is_empty() {
                continue;
            }
            let times: Vec<f64> = trials.iter().filter_map(|t| t.time_to_safe_ms).collect();
            let (p50, max) = p50_max(&times);
            let cycles: Vec<String> = {
                let mut c: Vec<u32> = trials.iter().filter_map(|t| t.idle_cycle).collect();
                c.sort_unstable();
                c.dedup();
                c.iter().map(u32::to_string).collect()
            };
            let count = |f: &dyn Fn(&KillTrial) -> bool| trials.iter().filter(|t| f(t)).count();
            let recording = if victim == Victim::Recorder {
                format!("{}/{} readable, truncated (see below)", count(&|t| t.readable), trials.len())
            } else {
                format!("{}/{} readable and closed", count(&|t| t.readable && !t.truncated), trials.len())
            };
            writeln!(
                md,
                "| {victim} | {} | {} | {p50:.1} / {max:.1} | {} | {}/{} | {} | {}/{} | {recording} | {} | \
                 `jetbench faults --only kill:{victim} --repeat 10` |",
                trials.len(),
                victim.safe_state(),
                if cycles.is_empty() { "–".into() } else { cycles.join(", ") },
                count(&|t| t.named),
                trials.len(),
                trials.iter().map(|t| t.orphans.len()).sum::<usize>(),
                count(&|t| t.restart_clean),
                trials.len(),
                trials.iter().map(|t| t.seq_gaps).sum::<u64>(),
            )?;
        }
        writeln!(
            md,
            "\nFor the recorder the time is from the kill until the launcher had stopped the whole set safely (control \
             first, actuation idling and then disarming the board, sim-bench running its engine down to idle). The \
             board dies with sim-bench, so no acknowledgement is possible there: actuation idles for lack of commands \
             and flags the board silent. Killing actuation leaves the throttle where it was until the board's own \
             watchdog (100 ms) idles it: the time is to the first `sim/truth` step at idle throttle."
        )
    }

    fn write_crashes(&self, md: &mut String) -> std::fmt::Result {
        if self.crashes.is_empty() {
            return Ok(());
        }
        writeln!(md, "\n## Recorder killed mid-run, then recovered\n")?;
        let lost: Vec<f64> = self.crashes.iter().map(|c| c.lost_s).collect();
        let (p50, max) = p50_max(&lost);
        let statuses: Vec<String> =
            self.crashes.iter().map(|c| format!("{:?}", c.recover_status.unwrap_or(-1))).collect();
        let python = self.crashes.iter().filter(|c| matches!(c.python, Some(Ok(_)))).count();
        writeln!(
            md,
            "SIGKILL of the recorder {}–{} s into a run ({}–{} s for the first, whose file every offline command \
             reads), {} times (`jetbench faults --only recorder --repeat 10`). Chunks are flushed every 0.5 s.\n",
            CRASH_AT_S.0,
            CRASH_AT_S.1,
            READERS_CRASH_AT_S,
            READERS_CRASH_AT_S + CRASH_AT_S.1 - CRASH_AT_S.0,
            self.crashes.len()
        )?;
        writeln!(md, "| figure | value |\n|---|---|")?;
        writeln!(md, "| data missing before the kill (newest message in the file to the kill), p50 / max | {p50:.3} s / {max:.3} s |")?;
        writeln!(md, "| `jetbench recover` exit status (0 nothing lost, 3 data lost) | {} |", statuses.join(", "))?;
        writeln!(
            md,
            "| recovered messages / messages in the truncated file | {} |",
            self.crashes.iter().map(|c| format!("{}/{}", c.recovered, c.messages)).collect::<Vec<_>>().join(", ")
        )?;
        writeln!(
            md,
            "| Python `mcap` reads the recovered file with its chunk indexes | {python}/{} |",
            self.crashes.len()
        )?;
        if let Some(first) = self.crashes.iter().find(|c| !c.readers.is_empty()) {
            for r in &first.readers {
                writeln!(
                    md,
                    "| `{} crashed.mcap` on the truncated file | exit {}, {} |",
                    r.command,
                    r.status.map_or("killed".into(), |s| s.to_string()),
                    if r.warned { "warns that it is truncated" } else { "NO WARNING" }
                )?;
            }
        }
        Ok(())
    }

    fn write_disk(&self, md: &mut String) -> std::fmt::Result {
        if self.disk.is_empty() {
            return Ok(());
        }
        writeln!(md, "\n## Disk full\n")?;
        writeln!(
            md,
            "The recording goes to a tmpfs of {DISK_KIB} KiB mounted for the run, which fills a few seconds in \
             (`jetbench faults --only disk`). The loop is watched from outside by `jetbench echo bench/command` in \
             the same namespace: the commands published after the recorder's message, on their own stamps.\n"
        )?;
        writeln!(
            md,
            "| `[recorder] on_error` | full after (s) | then | commands after it: count, rate (Hz), longest interval \
             (ms) | board disarmed | recovered (exit, messages) |"
        )?;
        writeln!(md, "|---|---:|---|---|---|---|")?;
        for d in &self.disk {
            let then = match d.on_error {
                OnRecordError::Stop => format!(
                    "safe stop {:.0} ms after the message, exit {:?}",
                    d.stopped_after_ms.unwrap_or(f64::NAN),
                    d.exit_status
                ),
                OnRecordError::Continue => format!("ran on unrecorded, exit {:?}", d.exit_status),
            };
            writeln!(
                md,
                "| {} | {:.1} | {then} | {}, {:.1}, {:.1} | {} | {}, {} |",
                if d.on_error == OnRecordError::Stop { "stop" } else { "continue" },
                d.full_after_s.unwrap_or(f64::NAN),
                d.commands_after_full,
                d.rate_after_full_hz,
                d.max_interval_after_full_ms,
                if d.disarmed { "yes" } else { "no" },
                d.recover_status.unwrap_or(-1),
                d.recovered
            )?;
        }
        if let Some(d) = self.disk.first() {
            writeln!(md, "\nThe recorder's message: `{}`", d.said.trim())?;
        }
        Ok(())
    }

    fn write_bad_data(&self, md: &mut String) -> std::fmt::Result {
        if self.bad_data.is_empty() {
            return Ok(());
        }
        writeln!(md, "\n## Bad sensor data in the live loop\n")?;
        writeln!(md, "| `--inject` | run (s) | spikes rejected | other rejections | tracking MAE (N), without faults | a spike's effect on the throttle p50 / max (%) | throttle step at a spike p50 / max (%) | every other step p50 / max (%) | stuck flagged after (s) | NaN frames reaching the bus | non-finite samples recorded | idle while silent |")?;
        writeln!(md, "|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---|")?;
        for b in &self.bad_data {
            writeln!(
                md,
                "| `{}` | {:.0} | {}/{} | {} | {} | {} | {:.2} / {:.2} | {:.2} / {:.2} | {} | {}/{} | {} | {} |",
                b.inject.join(" "),
                b.duration_s,
                b.spikes_rejected,
                b.spikes,
                b.other_rejections,
                if b.baseline_mae_n.is_nan() {
                    format!("{:.3}", b.mae_n)
                } else {
                    format!(
                        "{:.3}, {:.3} ({:+.1} %)",
                        b.mae_n,
                        b.baseline_mae_n,
                        100.0 * (b.mae_n / b.baseline_mae_n - 1.0)
                    )
                },
                b.spike_effect,
                b.step_at_spike_pct.0,
                b.step_at_spike_pct.1,
                b.step_elsewhere_pct.0,
                b.step_elsewhere_pct.1,
                b.stuck_flagged_after_s.map_or("–".into(), |s| format!("{s:.2}")),
                b.nan_published,
                b.nan_frames,
                b.non_finite_samples,
                if b.silent_frames == 0 {
                    "–"
                } else if b.idled_in_silence {
                    "yes"
                } else {
                    "no"
                },
            )?;
        }
        for b in self.bad_data.iter().filter(|b| !b.trips.is_empty()) {
            writeln!(md, "\nLimits that tripped with `{}`: {}.", b.inject.join(" "), b.trips.join(", "))?;
        }
        writeln!(
            md,
            "\nReproduce: `jetbench up --sim --duration 32 --record bad.mcap --inject {}`, or `jetbench faults --only \
             inject`. A spike's effect is measured on the recording: the estimator and the controller are replayed \
             (each must reproduce its recorded output bit for bit), and at each spike the command is computed again \
             from the clean reading (the reading less the spike `sim/truth` records); the effect is the distance \
             between the two commands. The throttle step at a spike is the loop's own step in that cycle, reference \
             transitions included; a rejected measurement leaves the estimate at the prediction whatever the \
             spike's size.",
            ALL_KINDS.join(" --inject ")
        )
    }

    fn write_set(&self, md: &mut String) -> std::fmt::Result {
        if let Some(s) = &self.second_up {
            writeln!(md, "\n## One set per namespace\n")?;
            writeln!(
                md,
                "A second `jetbench up` in a namespace in use exited {:?}{}: `{}`. A set in another namespace ran \
                 beside it: {}. (`jetbench faults --only second-up`)",
                s.status,
                if s.names_the_first { ", naming the first set's pid" } else { " WITHOUT naming the first set" },
                s.message.trim(),
                if s.side_by_side { "yes" } else { "NO" }
            )?;
        }
        if let Some(a) = &self.access {
            writeln!(md, "\n## Only the bench user\n")?;
            writeln!(
                md,
                "As user `nobody` (through `setpriv`), against a running set's {} files and sockets (shared memory, \
                 doorbells, the namespace lock, the CAN sockets, their folders): {} could be read or written; files \
                 with any permission for group or others: {}. `jetbench echo bench/thrust` as `nobody` exited {:?}: \
                 `{}`. (`jetbench faults --only access`)",
                a.tried,
                a.open_to_others.len(),
                a.loose_modes.len(),
                a.echo_status,
                a.echo_said.trim()
            )?;
        }
        Ok(())
    }

    /// How often the telemetry paused on the healthy engine, against the
    /// silence limits: every gap over a floor, binned, over the time in run.
    fn write_gaps(&self, md: &mut String) -> std::fmt::Result {
        use crate::limits::{ECU_GAP_FLOOR_S, SENSOR_GAP_FLOOR_S};
        let running_s: f64 = self.healthy.iter().map(|h| h.running_s).sum();
        if running_s <= 0.0 {
            return Ok(());
        }
        let limits = jetbench_stack::limits::Limits::preset("p100").expect("the p100 preset");
        let limit_of = |kind| limits.get(kind).map_or(f64::INFINITY, |l| l.limit + l.hold_s);
        let ecu_limit = limit_of(jetbench_stack::limits::LimitKind::EcuSilent);
        let sensor_limit = limit_of(jetbench_stack::limits::LimitKind::SensorSilent);
        writeln!(
            md,
            "\nPauses in the telemetry over the same {} runs ({:.1} min in run), against the silence limits: every \
             gap between fresh ECU readings (67 ms at 15 Hz when on time), between force samples (10 ms), and the \
             sensor's age as control's limit monitor can see it (an estimate's publish time less the stamp of the \
             estimate before it: the monitor judges the silence with every waiting estimate taken, so control's own \
             lateness is not the sensor's).\n",
            self.healthy.len(),
            running_s / 60.0,
        )?;
        writeln!(
            md,
            "| telemetry | gaps by length | runs with one over the floor / over the limit | longest | limit |"
        )?;
        writeln!(md, "|---|---|---|---|---|")?;
        let ecu_bins = [ECU_GAP_FLOOR_S, 0.15, 0.2, 0.3, ecu_limit];
        let sensor_bins = [SENSOR_GAP_FLOOR_S, 0.03, 0.05, 0.075, sensor_limit];
        #[allow(clippy::type_complexity, reason = "a local table of three rows, read right below")]
        let rows: [(&str, &[f64], Vec<&Vec<f64>>); 3] = [
            ("ECU (`bench/ecu`, fresh readings)", &ecu_bins, self.healthy.iter().map(|h| &h.ecu_gaps).collect()),
            (
                "force sensor (`bench/thrust` stamps)",
                &sensor_bins,
                self.healthy.iter().map(|h| &h.sensor_gaps).collect(),
            ),
            (
                "force sensor as control's monitor sees it",
                &sensor_bins,
                self.healthy.iter().map(|h| &h.monitor_ages).collect(),
            ),
        ];
        for (name, bins, per_run) in rows {
            let all: Vec<f64> = per_run.iter().flat_map(|g| g.iter().copied()).collect();
            let mut by_length = Vec::new();
            for w in bins.windows(2) {
                let n = all.iter().filter(|g| **g > w[0] && **g <= w[1]).count();
                by_length.push(format!("{}–{} s: {n}", w[0], w[1]));
            }
            let last = bins[bins.len() - 1];
            by_length.push(format!("over {last} s: {}", all.iter().filter(|g| **g > last).count()));
            let longest = all.iter().copied().reduce(f64::max).map_or("–".into(), |g| format!("{g:.3} s"));
            writeln!(
                md,
                "| {name} | {} | {} / {} | {longest} | {last} s |",
                by_length.join(", "),
                per_run.iter().filter(|g| !g.is_empty()).count(),
                per_run.iter().filter(|g| g.iter().any(|x| *x > last)).count(),
            )?;
        }
        let stale: u32 = self.healthy.iter().map(|h| h.ecu_stale).sum();
        writeln!(md, "\nPolls the ECU did not answer within their poll (flagged stale) in that time: {stale}.")?;
        Ok(())
    }

    fn write_limits(&self, md: &mut String) -> std::fmt::Result {
        if self.healthy.is_empty() {
            return Ok(());
        }
        let runs = |profile: &str| self.healthy.iter().filter(|h| h.profile == profile).count();
        let seconds = self.healthy.first().map_or(0, |h| h.duration_s);
        let rt = self.healthy.iter().all(|h| h.rt);
        let (up_rt, faults_rt) = if rt { (" --rt", " --limits-rt") } else { ("", "") };
        writeln!(md, "\n## No false trips on a healthy engine\n")?;
        writeln!(
            md,
            "`jetbench up --sim{up_rt} --profile P --duration {seconds}` with every limit of the P100 preset on \
             (`[limits] preset = \"p100\"`, the sensor's silence too) and nothing injected: {} runs of the campaign \
             profile and {} of the steps profile. Trips are counted from `bench/events`. The margin is the worst \
             value each limit's quantity held for the limit's hold time while the ECU said run (a trip needs that), \
             recomputed from the recording as the monitor sees it (the thrust estimate; the ECU's readings; a silence \
             is the longest gap between samples), worst over the runs; the peak is the worst single value. \
             Real-time settings (SCHED_FIFO, affinity, locked memory) {}. \
             (`jetbench faults --only limits --limits-runs {} --limits-seconds {seconds}{faults_rt}`)",
            runs("campaign"),
            runs("steps"),
            if rt { "on, as at the bench" } else { "off" },
            runs("steps"),
        )?;
        writeln!(md)?;
        writeln!(
            md,
            "| limit | P100 limit, hold | trips (campaign / steps) | worst held | worst peak | margin held |"
        )?;
        writeln!(md, "|---|---|---|---|---|---|")?;
        let limits = jetbench_stack::limits::Limits::preset("p100").expect("the p100 preset");
        for kind in jetbench_stack::limits::LimitKind::ALL {
            let i = kind as usize;
            let trips = |profile: &str| -> u32 {
                self.healthy.iter().filter(|h| h.profile == profile).map(|h| h.trips[i]).sum()
            };
            let low = kind == jetbench_stack::limits::LimitKind::MinRpm;
            let worst = |values: Vec<f64>| -> Option<f64> {
                values.into_iter().reduce(|a, b| if low { a.min(b) } else { a.max(b) })
            };
            let held = worst(self.healthy.iter().filter_map(|h| h.held[i]).collect());
            let peak = worst(self.healthy.iter().filter_map(|h| h.peak[i]).collect());
            let unit = kind.unit();
            let value = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.2} {unit}"));
            let (limit, margin) = match limits.get(kind) {
                Some(l) => (
                    format!("{} {unit}, {} s", l.limit, l.hold_s),
                    held.map_or("–".into(), |h| {
                        let m = if low { h - l.limit } else { l.limit - h };
                        format!("{m:.2} {unit} ({:.0} %)", 100.0 * m / l.limit)
                    }),
                ),
                None => ("off".into(), "–".into()),
            };
            writeln!(
                md,
                "| `{}` | {limit} | {} / {} | {} | {} | {margin} |",
                kind.key(),
                trips("campaign"),
                trips("steps"),
                value(held),
                value(peak)
            )?;
        }
        let without: Option<f64> = self.healthy.iter().filter_map(|h| h.band_without_lag).reduce(f64::max);
        if let (Some(w), Some(band)) = (without, limits.get(jetbench_stack::limits::LimitKind::ThrustRpmBand)) {
            let lag_s = limits.rpm_map.map_or(0.0, |m| m.lag_s);
            writeln!(
                md,
                "\nThe thrust-against-RPM check compares the RPM's thrust with the thrust estimate passed through \
                 the RPM's lag ({lag_s} s, `lag_s`; the emulated ECU's RPM lags the thrust so). Without the lag the \
                 worst disagreement held for {} s would have been {w:.2} N against the {} N band.",
                band.hold_s, band.limit
            )?;
        }
        self.write_gaps(md)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::Part;
    use crate::limits::HealthyRun;

    #[test]
    fn a_part_run_again_replaces_its_section_and_keeps_every_other() {
        let existing = "# Faults at the bench: the campaign\n\nintro\n\n## Every process killed\n\n| killed |\n|---|\n\
                        | sensing |\n\n## Disk full\n\nfull rows\n\n## No false trips on a healthy engine\n\nold rows\n\n\
                        ## Bounds broken\n\nNone: every bound of the campaign held.\n";
        let run = HealthyRun { profile: "steps".into(), duration_s: 60, running_s: 55.0, ..HealthyRun::default() };
        let campaign = Campaign { only: vec![Part::Limits], healthy: vec![run], ..Campaign::default() };
        let report = campaign.report(Some(existing), "2 CPUs");
        assert!(report.contains("| sensing |"), "the kills table is kept:\n{report}");
        assert!(report.contains("full rows"), "{report}");
        assert!(!report.contains("old rows"), "the healthy-engine section is replaced:\n{report}");
        assert!(report.contains("No false trips on a healthy engine") && report.contains("Pauses in the telemetry"));
        assert!(report.contains("None: every bound of the campaign held."), "{report}");
    }
}
