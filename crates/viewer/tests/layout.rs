//! The bench layout for the Foxglove app (docs/foxglove/jetbench-layout.json)
//! names only topics and fields that exist: a renamed field fails here, not
//! as an empty plot in the control room.

use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample};
use serde_json::Value;

/// Topic -> field names, for every channel.
fn fields_by_topic() -> Vec<(String, Vec<&'static str>)> {
    struct Collect(Vec<(String, Vec<&'static str>)>);
    impl ChannelVisitor for Collect {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            self.0.push((channel.topic(), T::FIELDS.iter().map(|f| f.name).collect()));
        }
    }
    let mut collect = Collect(Vec::new());
    visit_channels(&mut collect);
    collect.0
}

/// Every message path (`value` of a plot or state-transition series, `topicPath` of a raw-messages panel).
fn message_paths(value: &Value, out: &mut Vec<String>) {
    match value {
        Value::Object(map) => {
            for (key, v) in map {
                match (key.as_str(), v) {
                    ("value" | "topicPath", Value::String(path)) => out.push(path.clone()),
                    _ => message_paths(v, out),
                }
            }
        }
        Value::Array(items) => items.iter().for_each(|v| message_paths(v, out)),
        _ => {}
    }
}

#[test]
fn every_path_of_the_bench_layout_names_a_real_topic_and_field() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/foxglove/jetbench-layout.json");
    let layout: Value = serde_json::from_str(&std::fs::read_to_string(path).expect("read the layout")).expect("JSON");
    let panels = layout["configById"].as_object().expect("configById");
    let mut paths = Vec::new();
    message_paths(&layout["configById"], &mut paths);
    assert!(paths.len() >= 15, "{paths:?}");
    let known = fields_by_topic();
    for p in &paths {
        // `/topic{filter_field==N}.field` or `/topic`
        let end = p.find(['{', '.']).unwrap_or(p.len());
        let (topic, rest) = p.split_at(end);
        let (_, fields) = known.iter().find(|(t, _)| t == topic).unwrap_or_else(|| panic!("{p}: no topic {topic}"));
        let (filter, field) = match rest.strip_prefix('{') {
            Some(r) => {
                let (filter, after) = r.split_once('}').unwrap_or_else(|| panic!("{p}: unclosed filter"));
                (filter.split("==").next(), after)
            }
            None => (None, rest),
        };
        for name in filter.into_iter().chain(field.strip_prefix('.')) {
            assert!(fields.contains(&name), "{p}: {topic} has no field {name}; it has {fields:?}");
        }
    }
    // The control room's buttons call services the viewer offers to anyone: a
    // view without the operator's token shows no button that cannot work, and
    // the two stops are there.
    let safe: Vec<String> = jetbench_viewer::operator::SAFE_SERVICES
        .iter()
        .map(|(n, _)| jetbench_viewer::operator::service_name(n))
        .collect();
    let buttons: Vec<&str> = panels
        .iter()
        .filter(|(id, _)| id.starts_with("CallService!"))
        .map(|(id, p)| p["serviceName"].as_str().unwrap_or_else(|| panic!("{id} calls no service")))
        .collect();
    for service in &buttons {
        assert!(safe.iter().any(|s| s == service), "{service} is not offered to everyone; the safe ones are {safe:?}");
    }
    for stop in ["jetbench/stop", "jetbench/estop"] {
        assert!(buttons.contains(&stop), "no {stop} button in {buttons:?}");
    }
    // Every panel the arrangement shows is configured.
    let shown = layout["layout"].to_string();
    for id in panels.keys() {
        assert!(shown.contains(&format!("\"{id}\"")), "panel {id} is configured but not placed");
    }
}
