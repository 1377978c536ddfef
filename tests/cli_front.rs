//! The way in, as a new user meets it: ROS 2 habits (`echo --csv/--json`, `hz -w`,
//! `info`, `play` onto the bus, `--version`), files recognised by content, errors
//! said once with what to do, inputs checked like a test engineer would, reports on
//! standard output. Every test runs the real binary.

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::mpsc;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use common::{jetbench, repo_root, run_jetbench, scratch, wait_with_watchdog};
use jetbench_msgs::channels;
use jetbench_record::Recording;

const SUITE: &str = "clifront";

fn path_str(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

/// One 4 s live run of the simulated bench, recorded; shared by the tests.
fn live_recording() -> &'static Path {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| {
        let out = scratch(SUITE, "run.mcap");
        let (code, _, err) =
            run_jetbench(SUITE, &["up", "--sim", "--duration", "4", "--quiet", "--record", path_str(&out)], LIMIT);
        assert_eq!(code, 0, "jetbench up failed: {err}");
        out
    })
}

const LIMIT: Duration = Duration::from_secs(120);

/// The first `rows` rows of a scenario CSV (100 Hz, `time_s,throttle_pct,thrust_n`),
/// each row passed through `edit` (throttle, thrust) -> (throttle, thrust).
fn scenario_rows(name: &str, rows: usize, edit: impl Fn(f64, f64) -> (f64, f64)) -> PathBuf {
    let text = std::fs::read_to_string(repo_root().join("recordings/scenarios/delay-p100.csv")).expect("scenario");
    let mut out = String::from("time_s,throttle_pct,thrust_n\n");
    for line in text.lines().skip(1).take(rows) {
        let v: Vec<f64> = line.split(',').map(|x| x.parse().expect("a number")).collect();
        let (u, y) = edit(v[1], v[2]);
        out.push_str(&format!("{},{u},{y}\n", v[0]));
    }
    let path = scratch(SUITE, name);
    std::fs::write(&path, out).expect("write CSV");
    path
}

/// A child's stdout lines with the moment each arrived.
fn timed_lines(child: &mut Child) -> mpsc::Receiver<(Instant, String)> {
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send((Instant::now(), line)).is_err() {
                break;
            }
        }
    });
    rx
}

fn spawn(args: &[&str]) -> Child {
    spawn_in(SUITE, args)
}

/// `jetbench ARGS` in the bus namespace of `suite` (tests that play run in parallel, each on its own bus).
fn spawn_in(suite: &str, args: &[&str]) -> Child {
    jetbench(suite)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start jetbench")
}

/// `jetbench play run.mcap --rate 2` while `jetbench echo bench/thrust --csv` and
/// `jetbench hz -w 50` run: every recorded sample arrives, equal to the
/// recording, at twice its recorded pace; the CSV header comes once.
#[test]
fn play_onto_the_bus_at_rate_2_is_echoed_as_recorded_at_twice_the_pace() {
    let record = live_recording();
    let recording = Recording::open(record).expect("read the recording");
    let thrust = recording.samples(channels::THRUST);
    assert!(thrust.len() > 200, "{} thrust samples", thrust.len());
    let n = thrust.len().to_string();

    let mut echo = spawn(&["echo", "bench/thrust", "--csv", "-n", &n]);
    let mut hz = spawn(&["hz", "bench/thrust", "-w", "50", "--duration", "6"]);
    let lines = timed_lines(&mut echo);
    let (_, header) = lines.recv_timeout(Duration::from_secs(30)).expect("echo prints its CSV header at once");
    assert!(header.starts_with("seq,stamp_ns,publish_ns,frame_seq,thrust_n,force_n_0"), "{header}");
    let (code, out, err) = run_jetbench(SUITE, &["play", path_str(record), "--rate", "2"], LIMIT);
    assert_eq!(code, 0, "play failed: {err}");
    assert!(out.contains("publishing") && out.contains("on bus namespace"), "{out}");

    let mut rows = Vec::new();
    while rows.len() < thrust.len() {
        match lines.recv_timeout(Duration::from_secs(20)) {
            Ok(row) => rows.push(row),
            Err(_) => break,
        }
    }
    let status = wait_with_watchdog(&mut echo, LIMIT, "jetbench echo");
    assert!(status.success(), "echo: {status}");
    assert_eq!(rows.len(), thrust.len(), "every recorded thrust sample echoed");
    assert!(rows.iter().all(|(_, r)| !r.starts_with("seq,")), "the header is printed once");
    // Equal to the recording: every field but seq, which each publisher numbers itself.
    for (k, ((_, row), sample)) in rows.iter().zip(&thrust).enumerate() {
        let fields: Vec<&str> = row.split(',').collect();
        assert_eq!(fields[1], sample.stamp_ns.to_string(), "row {k}: {row}");
        assert_eq!(fields[3], sample.frame_seq.to_string(), "row {k}: {row}");
        assert_eq!(fields[4].parse::<f64>().expect("thrust_n"), sample.thrust_n, "row {k}: {row}");
    }
    // At twice the recorded pace: the recorded span over the arrival span. An
    // overloaded two-core machine delays a few samples by tens of ms, not the
    // whole run by a tenth.
    let recorded_s = (thrust[thrust.len() - 1].stamp_ns - thrust[0].stamp_ns) as f64 * 1e-9;
    let arrived_s = (rows[rows.len() - 1].0 - rows[0].0).as_secs_f64();
    let speed = recorded_s / arrived_s;
    eprintln!("{} samples: recorded over {recorded_s:.3} s, arrived over {arrived_s:.3} s: {speed:.3}x", rows.len());
    assert!((speed - 2.0).abs() < 0.2, "played at {speed:.3}x, not 2x");

    let hz_lines = timed_lines(&mut hz);
    wait_with_watchdog(&mut hz, LIMIT, "jetbench hz");
    let hz_out: Vec<String> = hz_lines.try_iter().map(|(_, l)| l).collect();
    let rates: Vec<&String> = hz_out.iter().filter(|l| l.contains(" Hz ")).collect();
    assert!(!rates.is_empty(), "hz printed no rate: {hz_out:?}");
    // 100 Hz recorded, played at 2x: 200 Hz, over at most the 50 latest messages.
    assert!(rates.iter().any(|l| l.contains("window 50")), "{rates:?}");
    let best = rates
        .iter()
        .filter_map(|l| l.split(": ").nth(1)?.split(" Hz").next()?.trim().parse::<f64>().ok())
        .fold(0.0, f64::max);
    assert!((best - 200.0).abs() < 40.0, "hz says {best} Hz: {rates:?}");
}

/// `echo --json`: one JSON object per sample per line, numbers as numbers.
#[test]
fn echo_json_prints_one_object_per_line() {
    let record = live_recording();
    let mut echo = spawn_in("clifrontjson", &["echo", "bench/state", "--json", "-n", "5"]);
    let lines = timed_lines(&mut echo);
    std::thread::sleep(Duration::from_millis(500));
    let (code, _, err) = run_jetbench("clifrontjson", &["play", path_str(record), "--rate", "4"], LIMIT);
    assert_eq!(code, 0, "{err}");
    let status = wait_with_watchdog(&mut echo, LIMIT, "jetbench echo");
    assert!(status.success());
    let got: Vec<String> = lines.try_iter().map(|(_, l)| l).collect();
    assert_eq!(got.len(), 5, "{got:?}");
    for line in got {
        let v: serde_json::Value = serde_json::from_str(&line).expect("one JSON object per line");
        assert!(v["thrust_n"].is_number() && v["seq"].is_u64(), "{line}");
    }
}

/// With no set running, echo says so after a second instead of waiting silently.
#[test]
fn echo_without_a_running_set_says_so() {
    let mut command = jetbench(SUITE);
    command.env(jetbench_bus::NAMESPACE_ENV, format!("clifrontidle{}", std::process::id()));
    let mut echo = command
        .args(["echo", "bench/thrust"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start echo");
    let stderr = common::lines_of(echo.stderr.take().expect("stderr"));
    let said = common::wait_for_line(&stderr, "no service set is running on namespace", Duration::from_secs(30));
    let _ = echo.kill();
    let _ = echo.wait();
    let line = said.unwrap_or_else(|seen| panic!("echo said nothing of the missing set: {seen:?}")).pop().unwrap();
    assert!(
        line.contains(&format!("clifrontidle{}", std::process::id())) && line.contains("jetbench up --sim"),
        "{line}"
    );
}

/// `info` like `ros2 bag info`: duration, dates, size, compression, types, the run's config and model.
#[test]
fn info_shows_what_ros2_bag_info_shows_and_the_run() {
    let record = live_recording();
    let (code, out, err) = run_jetbench(SUITE, &["info", path_str(record), "--schemas"], LIMIT);
    assert_eq!(code, 0, "{err}");
    for expected in [
        " s, ",
        "KiB",
        "zstd compressed",
        "written by  jetbench",
        "  start 20",
        "  end   20",
        "bench/thrust",
        "jetbench_msgs/msg/Thrust",
        "float64 thrust_n",
        "devices     sim",
        "model       p100-diesel",
        "parameters  ",
    ] {
        assert!(out.contains(expected), "no {expected:?} in\n{out}");
    }
    let duration_s: f64 = out
        .lines()
        .next()
        .and_then(|l| l.split(" messages, ").nth(1)?.split(" s,").next()?.parse().ok())
        .expect("a duration on the first line");
    assert!((3.0..6.0).contains(&duration_s), "4 s run lasted {duration_s} s?\n{out}");
}

#[test]
fn version_names_the_commit_and_the_build_date() {
    let (code, out, _) = run_jetbench(SUITE, &["--version"], LIMIT);
    assert_eq!(code, 0);
    let line = out.trim();
    assert!(line.starts_with(&format!("jetbench {} (", env!("CARGO_PKG_VERSION"))), "{line}");
    assert!(line.contains("commit ") && line.contains(", built 20"), "{line}");
}

/// A binary file named `.mcap` is "not an MCAP file" for every command that reads
/// recordings, said the same way; never a CSV parse error.
#[test]
fn a_binary_file_named_mcap_is_not_an_mcap_file_for_every_command() {
    let path = scratch(SUITE, "garbage.mcap");
    let bytes: Vec<u8> = (0..4096u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    std::fs::write(&path, bytes).expect("write");
    let p = path_str(&path);
    for args in [
        vec!["info", p],
        vec!["identify", p],
        vec!["diagnose", "--model", "p100-diesel", p],
        vec!["export", p],
        vec!["simulate", "--model", "p100-diesel", "--input", p],
        vec!["replay", p],
        vec!["metrics", p],
    ] {
        let (code, out, err) = run_jetbench(SUITE, &args, LIMIT);
        assert_ne!(code, 0, "{args:?} accepted garbage: {out}");
        assert!(err.contains(&format!("{p} is not an MCAP file")), "{args:?}: {err}");
        assert!(!err.contains("CSV") || err.contains("nor is it text"), "{args:?}: {err}");
        assert!(!err.to_lowercase().contains("utf-8"), "{args:?}: {err}");
        assert_eq!(err.matches("is not an MCAP file").count(), 1, "{args:?}: said twice: {err}");
    }
}

/// A CSV named `.mcap` is read as the CSV it is.
#[test]
fn a_csv_named_mcap_is_read_as_csv() {
    let csv = scenario_rows("real.csv", 500, |u, y| (u, y));
    let named = scratch(SUITE, "actually-csv.mcap");
    std::fs::copy(&csv, &named).expect("copy");
    let (code, out, err) = run_jetbench(SUITE, &["export", path_str(&named)], LIMIT);
    assert_eq!(code, 0, "{err}");
    let (code, expected, err) = run_jetbench(SUITE, &["export", path_str(&csv)], LIMIT);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, expected);
    assert_eq!(out.lines().count(), 501);
}

/// A missing file: one line, the cause said once.
#[test]
fn a_missing_file_is_said_once() {
    for args in [
        vec!["identify", "no-such-run.mcap"],
        vec!["info", "no-such-run.mcap"],
        vec!["export", "no-such-run.mcap"],
        vec!["play", "no-such-run.mcap"],
        vec!["diagnose", "--model", "p100-diesel", "no-such-run.mcap"],
        vec!["simulate", "--model", "p100-diesel", "--input", "no-such-run.mcap"],
        vec!["replay", "no-such-run.mcap"],
        vec!["metrics", "no-such-run.mcap"],
    ] {
        let (code, _, err) = run_jetbench(SUITE, &args, LIMIT);
        assert_ne!(code, 0);
        assert!(err.contains("no-such-run.mcap"), "{args:?}: {err}");
        assert_eq!(err.matches("No such file or directory").count(), 1, "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: not one line: {err}");
    }
}

/// An unreachable `--remote`: what failed and where, once, without a path inside
/// a dependency's source.
#[test]
fn an_unreachable_remote_is_one_clean_error() {
    let port = std::net::TcpListener::bind("127.0.0.1:0").expect("bind").local_addr().expect("addr").port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let (code, _, err) = run_jetbench(SUITE, &["echo", "bench/thrust", "--remote", &endpoint, "-n", "1"], LIMIT);
    assert_ne!(code, 0);
    assert!(err.contains(&endpoint), "{err}");
    assert!(!err.contains(".cargo") && !err.contains(".rs:"), "a dependency's source path: {err}");
    let error: Vec<&str> = err.lines().filter(|l| l.contains("error")).collect();
    assert_eq!(error.len(), 1, "{err}");
    assert!(error[0].contains("cannot reach the bench bridged at"), "{err}");
    assert_eq!(error[0].matches("Unable to connect").count(), 1, "a cause said twice: {err}");
    assert!(!err.contains("WARN"), "the dependency's own warnings: {err}");
}

/// A throttle column given as a fraction (0–1) is refused by every command that
/// reads identification data, saying to multiply by 100.
#[test]
fn a_throttle_given_as_a_fraction_is_refused_with_the_fix() {
    let path = scenario_rows("fraction.csv", 3000, |u, y| (u / 100.0, y));
    let p = path_str(&path);
    for args in [
        vec!["identify", "--method", "ls", p],
        vec!["diagnose", "--model", "p100-diesel", p],
        vec!["export", p],
        vec!["simulate", "--model", "p100-diesel", "--input", p],
    ] {
        let (code, _, err) = run_jetbench(SUITE, &args, LIMIT);
        assert_ne!(code, 0, "{args:?} accepted a fraction");
        assert!(err.contains("looks like a fraction") && err.contains("multiply the column by 100"), "{args:?}: {err}");
    }
    let path = scenario_rows("over-100.csv", 3000, |u, y| (u * 1.5, y));
    let (code, _, err) = run_jetbench(SUITE, &["export", path_str(&path)], LIMIT);
    assert_ne!(code, 0);
    assert!(err.contains("outside 0–100 %") && err.contains("row "), "{err}");
    let path = scenario_rows("idle.csv", 3000, |_, y| (10.0, y));
    let (code, _, err) = run_jetbench(SUITE, &["identify", path_str(&path)], LIMIT);
    assert_ne!(code, 0);
    assert!(err.contains("below idle") && err.contains("jetbench excite"), "{err}");
}

/// A CSV with lost samples (a thrust of `NaN`, an empty throttle) and a last line cut
/// short, as a writer killed mid-line leaves it, is read by every command with the rows
/// left out counted in a warning; the export holds every other row. Text where a number
/// belongs is still refused with its line.
#[test]
fn lost_samples_and_a_cut_last_line_are_counted_never_silently_dropped() {
    let clean = scenario_rows("lost-clean.csv", 3000, |u, y| (u, y));
    let mut text = std::fs::read_to_string(&clean).expect("CSV");
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    // Data rows 500 and 1500 (lines 502 and 1502) lost, one each way.
    let edit = |line: &str, f: &dyn Fn(&[&str]) -> String| f(&line.split(',').collect::<Vec<_>>());
    lines[501] = edit(&lines[501], &|v| format!("{},{},NaN", v[0], v[1]));
    lines[1501] = edit(&lines[1501], &|v| format!("{},,{}", v[0], v[2]));
    text = lines.join("\n") + "\n30.0,4";
    let lost = scratch(SUITE, "lost.csv");
    std::fs::write(&lost, &text).expect("write CSV");
    let p = path_str(&lost);
    for args in [
        vec!["identify", "--method", "ls", p],
        vec!["export", p],
        vec!["simulate", "--model", "p100-diesel", "--input", p],
    ] {
        let (code, _, err) = run_jetbench(SUITE, &args, LIMIT);
        assert_eq!(code, 0, "{args:?}: {err}");
        assert!(err.contains("2 row(s) (0.1 %) left out, the first at line 502"), "{args:?}: {err}");
        assert!(err.contains("the last line (3002) ends the file with no line break"), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    let (_, out, _) = run_jetbench(SUITE, &["export", p], LIMIT);
    assert_eq!(out.lines().count(), 1 + 2998, "the header and every row but the two lost");
    let (code, out, err) = run_jetbench(SUITE, &["diagnose", "--model", "p100-diesel", p], LIMIT);
    assert_eq!(code, 0, "{err}");
    let report = format!("{out}{err}");
    assert!(report.contains("left out, the first at line 502") && report.contains("2 gap(s)"), "{report}");
    std::fs::write(&lost, text.replace("NaN", "abc")).expect("write CSV");
    let (code, _, err) = run_jetbench(SUITE, &["export", p], LIMIT);
    assert_ne!(code, 0);
    assert!(err.contains("line 502") && err.contains("\"abc\" is not a number"), "{err}");
}

/// Thrust with its sign reversed, or not in newtons, is refused saying how to fix it.
#[test]
fn thrust_in_the_wrong_sign_or_unit_is_refused() {
    let reversed = scenario_rows("reversed.csv", 3000, |u, y| (u, -y));
    let (code, _, err) = run_jetbench(SUITE, &["identify", path_str(&reversed)], LIMIT);
    assert_ne!(code, 0);
    assert!(err.contains("sign is reversed") && err.contains("−1"), "{err}");
    let grams = scenario_rows("grams.csv", 3000, |u, y| (u, y * 1000.0 / 9.81));
    let (code, _, err) = run_jetbench(SUITE, &["export", path_str(&grams)], LIMIT);
    assert_ne!(code, 0);
    assert!(err.contains("not in newtons") && err.contains("0.00981"), "{err}");
}

/// `jetbench identify run > report.txt` writes the report; with too little data it
/// says how much there is and how much is needed; no figure is NaN.
#[test]
fn identify_reports_on_stdout_and_says_when_the_data_is_too_short() {
    let short = scenario_rows("short.csv", 2500, |u, y| (u, y));
    let (code, out, err) = run_jetbench(SUITE, &["identify", "--method", "ls", path_str(&short)], LIMIT);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("noise floor") && out.contains("val MAE N"), "the report is on stdout:\n{out}");
    assert!(!err.contains("noise floor"), "the report is on stderr too:\n{err}");
    assert!(
        out.contains(" s of calibration data (17") && out.contains("needs 300 s"),
        "no word on the amount of data:\n{out}"
    );
    assert!(!out.contains("NaN") && !err.contains("NaN"), "{out}\n{err}");
    // With --json, stdout is the JSON alone.
    let (code, out, _) = run_jetbench(SUITE, &["identify", "--method", "ls", "--json", path_str(&short)], LIMIT);
    assert_eq!(code, 0);
    serde_json::from_str::<serde_json::Value>(&out).expect("stdout is JSON only");
}

/// `simulate --out`: the figures against the measured thrust are the report, on stdout.
#[test]
fn simulate_with_out_reports_on_stdout() {
    let short = scenario_rows("sim-in.csv", 1000, |u, y| (u, y));
    let out_csv = scratch(SUITE, "sim-out.csv");
    let (code, out, err) = run_jetbench(
        SUITE,
        &["simulate", "--model", "p100-diesel", "--input", path_str(&short), "--out", path_str(&out_csv)],
        LIMIT,
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("against the measured thrust: MAE") && !out.contains("NaN"), "{out}");
}

/// What a terminal shows of `bytes`: every row as it was each time it was left,
/// rewritten (`\r`), cleared (`ESC[K`) or the cursor moved off it, in order. A
/// row that ever holds two things at once (a log line run into the status line)
/// is among them.
fn terminal_rows(bytes: &[u8]) -> Vec<String> {
    let text = String::from_utf8_lossy(bytes);
    let mut rows: Vec<Vec<char>> = vec![Vec::new()];
    let (mut row, mut col) = (0usize, 0usize);
    let mut seen = Vec::new();
    let snapshot = |rows: &Vec<Vec<char>>, row: usize, seen: &mut Vec<String>| {
        let line: String = rows[row].iter().collect::<String>().trim_end().to_string();
        if !line.is_empty() && seen.last() != Some(&line) {
            seen.push(line);
        }
    };
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\r' => {
                snapshot(&rows, row, &mut seen);
                col = 0;
            }
            '\n' => {
                snapshot(&rows, row, &mut seen);
                row += 1;
                if rows.len() <= row {
                    rows.push(Vec::new());
                }
            }
            '\x1b' => {
                // CSI: ESC [ params final.
                if chars.peek() != Some(&'[') {
                    chars.next();
                    continue;
                }
                chars.next();
                let mut params = String::new();
                let mut last = ' ';
                for p in chars.by_ref() {
                    if p.is_ascii_alphabetic() || p == '~' {
                        last = p;
                        break;
                    }
                    params.push(p);
                }
                let n: usize = params.trim_start_matches('?').parse().unwrap_or(0);
                match last {
                    'K' => {
                        snapshot(&rows, row, &mut seen);
                        match n {
                            0 => rows[row].truncate(col),
                            1 => rows[row].iter_mut().take(col + 1).for_each(|c| *c = ' '),
                            _ => rows[row].clear(),
                        }
                    }
                    'A' => {
                        snapshot(&rows, row, &mut seen);
                        row = row.saturating_sub(n.max(1));
                    }
                    'B' => {
                        snapshot(&rows, row, &mut seen);
                        row += n.max(1);
                        while rows.len() <= row {
                            rows.push(Vec::new());
                        }
                    }
                    'G' => col = n.max(1) - 1,
                    'J' => {
                        snapshot(&rows, row, &mut seen);
                        rows[row].truncate(col);
                        rows.truncate(row + 1);
                    }
                    _ => {}
                }
            }
            c if !c.is_control() => {
                let line = &mut rows[row];
                if line.len() <= col {
                    line.resize(col, ' ');
                    line.push(c);
                } else {
                    line[col] = c;
                }
                col += 1;
            }
            _ => {}
        }
    }
    snapshot(&rows, row, &mut seen);
    seen
}

#[test]
fn terminal_rows_show_a_log_line_run_into_a_status_line() {
    let into = terminal_rows(b"   1.0 s | ECU run\r\x1b[2K   2.0 s | ECU runsensing: WARN rejected\r\n");
    assert!(into.iter().any(|r| r.contains("s | ECU") && r.contains("rejected")), "{into:?}");
    let above = terminal_rows(b"   1.0 s | ECU run\r\x1b[2Ksensing: WARN rejected\r\n   2.0 s | ECU run");
    assert_eq!(above, ["   1.0 s | ECU run", "sensing: WARN rejected", "   2.0 s | ECU run"]);
}

/// `jetbench up` on a terminal (a real pty): the status line names the engine,
/// the throttle path, thrust against its target and one health judgement; a
/// service's log line (sensing rejecting the NaN readings injected) and an
/// event are printed above it, never run into it.
#[test]
fn up_on_a_terminal_prints_log_lines_above_the_status_line() {
    let (mut master, mut slave) = (0, 0);
    let size = libc::winsize { ws_row: 50, ws_col: 250, ws_xpixel: 0, ws_ypixel: 0 };
    // SAFETY: openpty writes two descriptors; null name and termios are allowed, size is valid.
    let rc = unsafe { libc::openpty(&mut master, &mut slave, std::ptr::null_mut(), std::ptr::null(), &size) };
    assert_eq!(rc, 0, "openpty: {}", std::io::Error::last_os_error());
    // SAFETY: both descriptors are fresh and owned here alone.
    let (master, slave) = unsafe {
        use std::os::fd::FromRawFd;
        (std::fs::File::from_raw_fd(master), std::os::fd::OwnedFd::from_raw_fd(slave))
    };
    // A bus namespace of its own: the shared recording's set runs at the same time.
    const PTY: &str = "clifrontpty";
    let mut child = jetbench(PTY)
        .args(["up", "--sim", "--duration", "8", "--inject", "nan:at_s=3,for_s=0.03"])
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(slave.try_clone().expect("dup"))
        .stderr(slave)
        .spawn()
        .expect("start jetbench up");
    let reader = std::thread::spawn(move || {
        let mut bytes = Vec::new();
        // Ends with EIO once the last holder of the pty's other end is gone.
        let _ = std::io::Read::read_to_end(&mut &master, &mut bytes);
        bytes
    });
    // An operator command mid-run: its event is a log line of the launcher's own.
    std::thread::sleep(Duration::from_secs(6));
    let (code, _, err) = run_jetbench(PTY, &["hold"], LIMIT);
    assert_eq!(code, 0, "jetbench hold: {err}");
    let status = wait_with_watchdog(&mut child, LIMIT, "jetbench up on a pty");
    let bytes = reader.join().expect("pty reader");
    let rows = terminal_rows(&bytes);
    let shown = rows.join("\n");
    assert!(status.success(), "jetbench up failed:\n{shown}");
    let is_status = |r: &str| r.contains(" s | ECU ");
    let status_rows: Vec<&String> = rows.iter().filter(|r| is_status(r)).collect();
    assert!(status_rows.len() >= 3, "the status line was shown every second:\n{shown}");
    let last = status_rows.last().expect("a status line");
    for part in [" s | ECU run ", " rpm ", " °C | armed", " | thrust ", " N target ", " N, throttle ", " % | health"] {
        assert!(last.contains(part), "no {part:?} in the status line {last:?}");
    }
    assert!(!last.contains("ref ") && !last.contains("NaN"), "{last}");
    let logs: Vec<&String> = rows.iter().filter(|r| r.contains("rejected") || r.contains("event: ")).collect();
    assert!(logs.iter().any(|r| r.starts_with("sensing: ") && r.contains("rejected")), "no sensing log:\n{shown}");
    assert!(logs.iter().any(|r| r.starts_with("event: HOLD")), "no event line:\n{shown}");
    for row in &rows {
        let log = row.contains("rejected") || row.contains("event: ") || row.contains("started ");
        assert!(!(is_status(row) && log), "a log line ran into the status line: {row:?}\n{shown}");
    }
}

/// `jetbench identify run.mcap > report.txt`: the report is in the file (stdout),
/// the progress and logs are not.
#[test]
fn identify_of_a_recording_redirected_to_a_file_writes_the_report() {
    let record = live_recording();
    let report = scratch(SUITE, "report.txt");
    let file = std::fs::File::create(&report).expect("create report.txt");
    let out = jetbench(SUITE)
        .args(["identify", "--method", "ls", path_str(record)])
        .stdin(Stdio::null())
        .stdout(file)
        .stderr(Stdio::piped())
        .output()
        .expect("run jetbench identify");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let text = std::fs::read_to_string(&report).expect("read report.txt");
    assert!(text.contains("noise floor") && text.contains("val MAE N"), "report.txt holds no report:\n{text}");
    assert!(text.contains("needs 300 s"), "a 4 s recording is said to be too short:\n{text}");
    assert!(!text.contains("NaN"), "{text}");
}

/// `identify --plot`: every method's figure has the throttle in a panel of its own.
#[test]
fn identify_plots_show_the_throttle() {
    let csv = scenario_rows("plot-in.csv", 6000, |u, y| (u, y));
    let dir = scratch(SUITE, "plots");
    let _ = std::fs::remove_dir_all(&dir);
    let (code, _, err) =
        run_jetbench(SUITE, &["identify", "--method", "ls", path_str(&csv), "--plot", path_str(&dir)], LIMIT);
    assert_eq!(code, 0, "{err}");
    let svgs: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("the plot folder")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "svg"))
        .collect();
    assert!(!svgs.is_empty(), "no SVG written: {err}");
    for svg in svgs {
        let text = std::fs::read_to_string(&svg).expect("read SVG");
        assert!(text.contains("throttle (%)") && text.contains("thrust (N)"), "no throttle panel in {}", svg.display());
    }
}

/// The software that wrote a recording is in its MCAP header, as `jetbench
/// --version` names it (the commit included), read back by the reference
/// Python reader, and `info` shows it.
#[test]
fn the_recording_names_the_software_and_commit_that_wrote_it() {
    let record = live_recording();
    let (code, version, _) = run_jetbench(SUITE, &["--version"], LIMIT);
    assert_eq!(code, 0);
    let version = version.trim();
    assert!(version.contains("commit "), "{version}");
    let script = "import sys\nfrom mcap.reader import make_reader\n\
                  with open(sys.argv[1], 'rb') as f:\n    print(make_reader(f).get_header().library)\n";
    let out = std::process::Command::new(common::python())
        .args(["-c", script])
        .arg(record)
        .output()
        .expect("run the Python MCAP reader");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), version, "the header's library");
    let (code, info, err) = run_jetbench(SUITE, &["info", path_str(record)], LIMIT);
    assert_eq!(code, 0, "{err}");
    assert!(info.contains(&format!("written by  {version}")), "{info}");
}
