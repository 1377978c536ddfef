//! Every sample type is laid out exactly as CDR encodes its schema text.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_msgs::{
    cdr_layout, channel_names, parse_schema, visit_channels, Channel, ChannelVisitor, Sample, CDR_HEADER,
};

/// Checks one type; collects failures instead of stopping at the first.
struct LayoutCheck {
    checked: Vec<&'static str>,
    failures: Vec<String>,
}

impl ChannelVisitor for LayoutCheck {
    fn visit<T: Sample>(&mut self, channel: Channel<T>) {
        self.checked.push(T::NAME);
        let parsed = match parse_schema(&T::schema_text()) {
            Ok(p) => p,
            Err(e) => return self.failures.push(format!("{}: {e}", T::NAME)),
        };
        let (cdr, cdr_len) = cdr_layout(&parsed);
        if cdr_len != std::mem::size_of::<T>() {
            self.failures.push(format!(
                "{}: CDR body is {cdr_len} bytes, struct is {}",
                T::NAME,
                std::mem::size_of::<T>()
            ));
        }
        if cdr.len() != T::FIELDS.len() {
            self.failures.push(format!("{}: schema has {} fields, struct {}", T::NAME, cdr.len(), T::FIELDS.len()));
        }
        for (c, f) in cdr.iter().zip(T::FIELDS) {
            if c.name != f.name || c.offset != f.offset || c.ros_type != f.ros_type {
                self.failures.push(format!("{}.{}: CDR {:?} vs struct {:?}", T::NAME, f.name, c, f));
            }
        }
        // Starts with seq and stamp_ns, both u64.
        let head: Vec<_> = T::FIELDS.iter().take(2).map(|f| (f.name, f.ros_type.to_string())).collect();
        if head != [("seq", "uint64".to_string()), ("stamp_ns", "uint64".to_string())] {
            self.failures.push(format!("{}: must start with uint64 seq, uint64 stamp_ns", T::NAME));
        }
        // Fields are ordered by decreasing primitive size.
        let sizes: Vec<usize> = T::FIELDS.iter().map(|f| f.ros_type.primitive().size()).collect();
        if sizes.windows(2).any(|w| w[0] < w[1]) {
            self.failures.push(format!("{}: fields not ordered by decreasing size: {sizes:?}", T::NAME));
        }
        // The iceoryx2 type name is the recorded schema name.
        // SAFETY: `type_name` only reads the name the sample type's `#[type_name]` declares.
        let type_name = unsafe { <T as iceoryx2::prelude::ZeroCopySend>::type_name() };
        if type_name != T::schema_name() {
            self.failures.push(format!("{}: type_name {type_name:?} != {:?}", T::NAME, T::schema_name()));
        }
        if !channel.topic().starts_with('/') {
            self.failures.push(format!("{}: topic must start with /", channel.name));
        }
    }
}

#[test]
fn every_sample_is_its_cdr_encoding() {
    let mut check = LayoutCheck { checked: vec![], failures: vec![] };
    visit_channels(&mut check);
    assert_eq!(check.checked.len(), channel_names().len());
    assert!(check.failures.is_empty(), "{:#?}", check.failures);
}

/// Encodes field values by the CDR rules from the parsed schema and compares
/// with the struct bytes: the same values, independently serialised.
#[test]
fn cdr_encoder_reproduces_struct_bytes() {
    let mut t = jetbench_msgs::Thrust {
        seq: 3,
        stamp_ns: 1_234_567_890,
        publish_ns: 1_234_600_000,
        frame_seq: 250,
        thrust_n: 41.25,
        force_n: [41.25, -0.5, 0.125],
        torque_nm: [0.001, -0.002, 0.003],
        status: 4,
        flags: 1,
    };
    t.set_seq(9);
    let parsed = parse_schema(&jetbench_msgs::Thrust::schema_text()).unwrap();
    let (layout, len) = cdr_layout(&parsed);
    let mut encoded = vec![0u8; len];
    let values: Vec<Vec<u8>> = vec![
        9u64.to_le_bytes().to_vec(),
        1_234_567_890u64.to_le_bytes().to_vec(),
        1_234_600_000u64.to_le_bytes().to_vec(),
        250u64.to_le_bytes().to_vec(),
        41.25f64.to_le_bytes().to_vec(),
        [41.25f64, -0.5, 0.125].iter().flat_map(|v| v.to_le_bytes()).collect(),
        [0.001f64, -0.002, 0.003].iter().flat_map(|v| v.to_le_bytes()).collect(),
        4u32.to_le_bytes().to_vec(),
        1u32.to_le_bytes().to_vec(),
    ];
    assert_eq!(values.len(), layout.len());
    for (field, value) in layout.iter().zip(&values) {
        encoded[field.offset..field.offset + value.len()].copy_from_slice(value);
    }
    assert_eq!(t.as_bytes(), &encoded[..]);
    let mut message = CDR_HEADER.to_vec();
    message.extend_from_slice(&encoded);
    assert_eq!(jetbench_msgs::Thrust::from_cdr(&message), Some(t));
}

#[test]
fn from_bytes_rejects_wrong_length() {
    let bytes = jetbench_msgs::Command::default().as_bytes().to_vec();
    assert!(jetbench_msgs::Command::from_bytes(&bytes[1..]).is_none());
    assert!(jetbench_msgs::Command::from_cdr(&bytes).is_none(), "missing CDR header must be rejected");
}

#[test]
fn schema_parser_rejects_garbage() {
    assert!(parse_schema("float64 a b").is_err());
    assert!(parse_schema("string name").is_err());
    assert!(parse_schema("float64[x] a").is_err());
    assert_eq!(parse_schema("# comment\n\nuint8[4] raw # trailing").unwrap().len(), 1);
}

#[test]
fn a_non_finite_field_is_found_by_name() {
    use jetbench_msgs::{Sample, StateEstimate, Thrust};
    assert_eq!(Thrust::default().non_finite_field(), None);
    let t = Thrust { force_n: [1.0, 2.0, f64::NAN], ..Thrust::default() };
    assert_eq!(t.non_finite_field(), Some("force_n"));
    let s = StateEstimate { thrust_rate_var_n2_per_s2: f64::INFINITY, ..StateEstimate::default() };
    assert_eq!(s.non_finite_field(), Some("thrust_rate_var_n2_per_s2"));
    // Integers are never "not a number", whatever their bits.
    let h = jetbench_msgs::Health { cycles: u64::MAX, ..Default::default() };
    assert_eq!(h.non_finite_field(), None);
}

#[test]
fn the_event_schema_names_its_codes_and_is_96_bytes() {
    use jetbench_msgs::{channels, event_kinds, Event};
    assert_eq!(std::mem::size_of::<Event>(), 96);
    assert_eq!(channels::EVENTS.name, "bench/events");
    assert!(channel_names().contains(&"bench/events"));
    let text = Event::schema_text();
    for line in ["uint32 KIND_TRIP=1", "int32 OFF_OVER_TEMPERATURE=2", "int32 ECU_RUN=11", "int32 LIMIT_MAX_EGT=2"] {
        assert!(text.contains(line), "{line} in\n{text}");
    }
    assert_eq!(event_kinds::SHUTDOWN, 4);
    // Constants take no room: the parsed fields are the struct's.
    assert_eq!(parse_schema(&text).unwrap().len(), Event::FIELDS.len());
    // Every constant name is unique.
    let mut names: Vec<_> = jetbench_msgs::EVENT_CONSTANTS.iter().map(|c| c.name).collect();
    let n = names.len();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), n);
}

#[test]
fn the_operator_command_is_80_bytes_with_named_codes_and_an_identity() {
    use jetbench_msgs::{authorities, channels, identity, identity_text, operator_commands, origins, OperatorCommand};
    assert_eq!(std::mem::size_of::<OperatorCommand>(), 80);
    assert_eq!(channels::OPERATOR.name, "bench/operator");
    assert!(channel_names().contains(&"bench/operator"));
    let text = OperatorCommand::schema_text();
    for line in [
        "uint8[32] identity",
        "int32 COMMAND_STOP_NOW=3",
        "int32 COMMAND_HEARTBEAT=12",
        "uint32 ORIGIN_LOCAL=1",
        "uint32 ORIGIN_FOXGLOVE=3",
        "uint32 AUTHORITY_OPERATOR=1",
    ] {
        assert!(text.contains(line), "{line} in\n{text}");
    }
    assert_eq!(parse_schema(&text).unwrap().len(), OperatorCommand::FIELDS.len());
    assert!(jetbench_msgs::Event::schema_text().contains("int32 COMMAND_RUN_PROFILE=7"));
    assert_eq!(origins::LOCAL, 1);
    assert_eq!(authorities::ANYONE, 0);
    assert_eq!(operator_commands::name(operator_commands::CLEAR_TRIPS), Some("CLEAR_TRIPS"));
    assert_eq!(operator_commands::name(99), None);

    // Identities round-trip, and a long one is cut at a character boundary.
    let c = OperatorCommand { identity: identity("local:ana"), ..Default::default() };
    assert_eq!(identity_text(&c.identity), "local:ana");
    let long = "é".repeat(20); // 40 bytes
    let cut = identity_text(&identity(&long));
    assert_eq!(cut, "é".repeat(16));
    let mut garbage = [0xffu8; 32];
    garbage[3] = 0;
    assert_eq!(identity_text(&garbage).chars().count(), 3);
    let bytes = c.as_bytes().to_vec();
    assert_eq!(OperatorCommand::from_bytes(&bytes), Some(c));
}
