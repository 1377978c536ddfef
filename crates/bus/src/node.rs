//! Node administration: who is on the bus, what exists, and cleaning up
//! after killed processes.

use iceoryx2::node::{NodeState, NodeView};
use iceoryx2::prelude::*;

use crate::iceoryx::{config, quiet_log};

/// Removes the shared-memory resources of dead processes' nodes, and the
/// doorbells no process holds. Returns how many dead nodes were cleaned.
pub fn cleanup_dead_nodes() -> usize {
    let bells = crate::bell::remove_unheld();
    if bells > 0 {
        tracing::debug!("removed {bells} doorbell file(s) nobody holds");
    }
    quiet_log();
    let mut cleaned = 0;
    let _ = Node::<ipc::Service>::list(config(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(_) => cleaned += 1,
                Err(e) => tracing::warn!("could not clean a dead bus node: {e:?}"),
            }
        }
        CallbackProgression::Continue
    });
    cleaned
}

/// Node names of the live bus participants of this namespace (every process
/// has one, whichever transport carries its samples).
pub fn list_nodes() -> Vec<String> {
    quiet_log();
    let mut names = Vec::new();
    let _ = Node::<ipc::Service>::list(config(), |state| {
        if let NodeState::<ipc::Service>::Alive(view) = state {
            if let Some(details) = view.details() {
                names.push(details.name().as_str().to_string());
            }
        }
        CallbackProgression::Continue
    });
    names.sort();
    names
}

/// Names of the channels that exist in this namespace, over either transport:
/// iceoryx2's publish-subscribe services, the jetbench channels whose doorbell
/// someone holds (every publisher and subscriber of either transport does), and
/// the channels with a live socket subscriber (any other by its folder's name).
pub fn list_channels() -> Vec<String> {
    quiet_log();
    let mut names = Vec::new();
    let _ = ipc::Service::list(config(), |service| {
        if matches!(
            service.static_details.messaging_pattern(),
            iceoryx2::service::static_config::messaging_pattern::MessagingPattern::PublishSubscribe(_)
        ) {
            names.push(service.static_details.name().as_str().to_string());
        }
        CallbackProgression::Continue
    });
    let namespace = crate::env::namespace().ok().flatten();
    names.extend(crate::uds::live_channels(namespace.as_deref()));
    let held = |name: &str| crate::bell::path_of(namespace.as_deref(), name).exists();
    names.extend(jetbench_msgs::channel_names().into_iter().filter(|n| held(n)).map(str::to_string));
    names.sort();
    names.dedup();
    names
}
