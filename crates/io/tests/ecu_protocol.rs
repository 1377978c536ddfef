//! The ECU's command set through the firmware and the decoder: echoes,
//! telemetry, status, start/stop/throttle acknowledged or refused; garbage
//! lines counted, never a panic.

use jetbench_io::ecu::emulator::{EcuCommand, EcuEmulator, EcuFaults, EcuParams};
use jetbench_io::ecu::state::{EcuState, OffCondition};
use jetbench_io::ecu::{parse_command, CommandError, EcuReading, EcuReply, LineDecoder, PcCommand};
use jetbench_io::emulate::{ClockedEmulator, EcuFirmware, FixedEcu};
use rand::{RngExt, SeedableRng};

fn exchange(
    fw: &mut EcuFirmware,
    device: &mut dyn jetbench_io::emulate::EcuDevice,
    d: &mut LineDecoder,
    cmd: PcCommand,
) -> Vec<EcuReply> {
    let mut wire = Vec::new();
    fw.receive(cmd.encode().as_bytes(), device, &mut wire);
    let mut replies = Vec::new();
    d.push_replies(&wire, |r| replies.push(r));
    replies
}

#[test]
fn commands_encode_and_parse_as_jetcat_writes_them() {
    for (cmd, line) in [
        (PcCommand::ReadActual, "1,RAC,1\r"),
        (PcCommand::ReadStatus, "1,RSS,1\r"),
        (PcCommand::ReadFuel, "1,RFI,1\r"),
        (PcCommand::Start, "1,TCO,1\r"),
        (PcCommand::Stop, "1,TCO,0\r"),
        (PcCommand::Throttle(42.5), "1,WPE,42.5\r"),
    ] {
        assert_eq!(cmd.encode(), line);
        assert_eq!(parse_command(line.trim_end().as_bytes()), Ok(cmd));
    }
    assert_eq!(parse_command(b"1,tco,1"), Ok(PcCommand::Start), "mnemonics in any case");
    assert_eq!(parse_command(b"1,XYZ,1").unwrap_err().code(), 1);
    assert_eq!(parse_command(b"1,TCO").unwrap_err().code(), 2);
    assert_eq!(parse_command(b"1,WPE,150").unwrap_err().code(), 4);
    assert_eq!(parse_command(b"1,TCO,7").unwrap_err().code(), 4);
    assert!(matches!(parse_command(b"1,HS,OK"), Err(CommandError::NotACommand(_))));
    assert!(matches!(parse_command(b"\xff\x00"), Err(CommandError::NotACommand(_))));
}

#[test]
fn the_emulated_ecu_is_started_polled_and_stopped_over_the_protocol() {
    let clock = std::sync::Arc::new(std::sync::Mutex::new(0.0f64));
    let c = clock.clone();
    let mut device = ClockedEmulator {
        emulator: EcuEmulator::new(EcuParams::default(), EcuFaults::default(), 0.0),
        clock: Box::new(move || *c.lock().unwrap()),
    };
    let mut fw = EcuFirmware::default();
    let mut d = LineDecoder::new();
    // Off: a start is refused with JetCat's "not allowed in this state" (3).
    assert_eq!(exchange(&mut fw, &mut device, &mut d, PcCommand::Start), [EcuReply::Refused(3)]);
    let mut t = 0.0;
    let mut advance = |device: &mut ClockedEmulator, to: f64, throttle: f64| {
        while t < to {
            t += 0.01;
            *clock.lock().unwrap() = t;
            device.emulator.throttle(throttle, t).unwrap();
            device.emulator.step(t, if device.emulator.state().is_running() { 10.0 } else { 0.0 });
        }
    };
    advance(&mut device, 1.5, 0.0);
    assert_eq!(exchange(&mut fw, &mut device, &mut d, PcCommand::Start), [EcuReply::Ack]);
    advance(&mut device, 20.0, 0.0);
    let [EcuReply::Actual(r)] = exchange(&mut fw, &mut device, &mut d, PcCommand::ReadActual)[..] else { panic!() };
    assert_eq!(EcuState::from_code(r.state), Some(EcuState::Run));
    assert_eq!(exchange(&mut fw, &mut device, &mut d, PcCommand::Throttle(30.0)), [EcuReply::Ack]);
    assert_eq!(exchange(&mut fw, &mut device, &mut d, PcCommand::Stop), [EcuReply::Ack]);
    let [EcuReply::Actual(r)] = exchange(&mut fw, &mut device, &mut d, PcCommand::ReadActual)[..] else { panic!() };
    assert_eq!(EcuState::from_code(r.state), Some(EcuState::SlowDown));
    assert_eq!(
        exchange(&mut fw, &mut device, &mut d, PcCommand::ReadStatus),
        [EcuReply::Status { off_condition: u32::from(OffCondition::ManualOff.code()) }]
    );
    let c = d.counters();
    assert_eq!((c.echoes, c.lines, c.statuses, c.acks, c.refusals, c.rejected()), (7, 2, 1, 3, 1, 0), "{c:?}");
    assert_eq!((fw.accepted, fw.refused, fw.polls), (3, 1, 2));
}

#[test]
fn a_fixed_ecu_queues_commands_for_its_owner() {
    let mut device = FixedEcu { reading: EcuReading { state: 11, ..EcuReading::default() }, ..FixedEcu::default() };
    let mut fw = EcuFirmware::default();
    let mut d = LineDecoder::new();
    assert_eq!(exchange(&mut fw, &mut device, &mut d, PcCommand::Throttle(12.0)), [EcuReply::Ack]);
    assert_eq!(exchange(&mut fw, &mut device, &mut d, PcCommand::Stop), [EcuReply::Ack]);
    assert_eq!(device.commands, [EcuCommand::Throttle(12.0), EcuCommand::Stop]);
    // An unknown command is echoed and refused (1); noise gets no reply.
    let mut wire = Vec::new();
    fw.receive(b"1,XYZ,1\r\x00\xffnoise\r", &mut device, &mut wire);
    assert_eq!(wire, b"1,XYZ,1\r1,HS,ERR,1\r");
    assert_eq!(fw.unknown_lines, 2);
}

#[test]
fn garbage_between_replies_is_counted_never_a_panic() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(25);
    let good = "1,RAC,1\r1,HS,OK,61250,612.5,3.05,11,42\r1,RSS,1\r1,HS,OK,2,0,0,0,0\r1,TCO,0\r1,HS,OK\r";
    let mut d = LineDecoder::new();
    let mut replies = 0u64;
    let mut garbage_lines = 0u64;
    for _ in 0..2_000 {
        // A garbage line: random bytes (no `\r`), or a mangled reply.
        let line: Vec<u8> = match rng.random_range(0..3) {
            0 => (0..rng.random_range(1..200))
                .map(|_| rng.random::<u8>())
                .filter(|b| *b != b'\r' && *b != b'\n')
                .collect(),
            1 => b"1,HS,OK,"
                .iter()
                .copied()
                .chain((0..rng.random_range(0..40)).map(|_| rng.random_range(b' '..=b'~')))
                .collect(),
            _ => b"1,HS,ERR,"
                .iter()
                .copied()
                .chain((0..rng.random_range(0..6)).map(|_| rng.random_range(b'0'..=b'z')))
                .collect(),
        };
        if line.iter().all(|b| b.is_ascii_whitespace()) {
            continue;
        }
        garbage_lines += 1;
        d.push_replies(&line, |_| {});
        d.push_replies(b"\r", |_| {});
        d.push_replies(good.as_bytes(), |_| replies += 1);
    }
    let c = *d.counters();
    println!("{garbage_lines} garbage lines: {c:?}");
    // Every good exchange decoded (3 replies each), whatever came before it.
    assert_eq!(replies, 3 * 2_000);
    assert_eq!(c.lines, 2_000);
    // Every garbage line is counted exactly once: rejected, or (by chance) a
    // valid reply or echo.
    let chance = (c.lines + c.statuses + c.acks + c.refusals + c.echoes) - 6 * 2_000;
    assert_eq!(c.rejected() + chance, garbage_lines, "{c:?}");
    assert!(c.rejected() > garbage_lines * 9 / 10, "{c:?}");
}

#[test]
fn the_recording_names_every_state_and_off_condition_by_its_code() {
    use jetbench_msgs::Sample;
    let text = jetbench_msgs::Event::schema_text();
    for s in EcuState::ALL {
        let line = format!("int32 ECU_{}={}", s.name().to_uppercase().replace([' ', '-'], "_"), s.code());
        assert!(text.contains(&line), "{line}");
    }
    let mut recorded: Vec<i64> =
        jetbench_msgs::EVENT_CONSTANTS.iter().filter(|c| c.name.starts_with("OFF_")).map(|c| c.value).collect();
    let mut ours: Vec<i64> = OffCondition::ALL.iter().map(|o| i64::from(o.code())).collect();
    recorded.sort_unstable();
    ours.sort_unstable();
    assert_eq!(recorded, ours);
}

#[test]
fn the_battery_voltage_is_read_with_rfi_and_sags_on_request() {
    let clock = std::sync::Arc::new(std::sync::Mutex::new(0.0f64));
    let c = clock.clone();
    let faults: EcuFaults = "ecu:lowbattery_at_s=2".parse().unwrap();
    let mut device = ClockedEmulator {
        emulator: EcuEmulator::running(EcuParams::default(), faults, 0.0),
        clock: Box::new(move || *c.lock().unwrap()),
    };
    let mut fw = EcuFirmware::default();
    let mut d = LineDecoder::new();
    let battery = |device: &mut ClockedEmulator, fw: &mut EcuFirmware, d: &mut LineDecoder| match exchange(
        fw,
        device,
        d,
        PcCommand::ReadFuel,
    )[..]
    {
        [EcuReply::Fuel { battery_v }] => battery_v,
        ref other => panic!("{other:?}"),
    };
    assert_eq!(battery(&mut device, &mut fw, &mut d), 7.4, "a charged pack");
    let mut t = 0.0;
    let mut low_at = None;
    while t < 6.0 {
        t += 0.01;
        *clock.lock().unwrap() = t;
        device.emulator.throttle(30.0, t).unwrap();
        device.emulator.step(t, 20.0);
        let v = battery(&mut device, &mut fw, &mut d);
        if v < 6.4 {
            low_at.get_or_insert(t);
        }
    }
    let low_at = low_at.expect("the battery sags below 6.4 V");
    // The ECU shuts the engine down 1 s after the voltage fell below its limit.
    let down = device.emulator.transitions().iter().find(|(_, s, _)| *s == EcuState::SlowDown).copied();
    let (at, _, off) = down.expect("the ECU shut the engine down");
    assert_eq!(off, OffCondition::LowBattery);
    assert!((at - low_at - 1.0).abs() < 0.02, "shut down {:.2} s after the sag", at - low_at);
    // A garbled battery field is counted, not misread.
    let mut wire = b"1,RFI,1\r1,HS,OK,0,0,0,x7.4,0\r".to_vec();
    wire.extend_from_slice(b"1,RFI,1\r1,HS,OK,0,0,0,99,0\r");
    let mut replies = Vec::new();
    d.push_replies(&wire, |r| replies.push(r));
    assert!(replies.is_empty(), "{replies:?}");
    assert_eq!(d.counters().rejected(), 2);
}
