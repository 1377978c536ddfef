//! The bus channels as Foxglove channels, advertised exactly as recorded.

use std::sync::Arc;

use foxglove::{ChannelBuilder, Context, RawChannel, Schema};
use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample, CDR_HEADER};
use jetbench_record::{MESSAGE_ENCODING, SCHEMA_ENCODING};

use crate::ViewerError;

/// One bus channel on the server.
struct Advertised {
    /// Bus channel name, e.g. `bench/thrust`.
    name: &'static str,
    topic: String,
    /// Length of a well-formed CDR message: header plus the sample's bytes.
    message_len: usize,
    raw: Arc<RawChannel>,
}

/// Every bus channel, advertised in one Foxglove context.
pub struct BenchChannels {
    channels: Vec<Advertised>,
}

impl BenchChannels {
    /// Advertises every channel of the service set in `context`.
    pub fn advertise(context: &Arc<Context>) -> Result<BenchChannels, ViewerError> {
        struct Register<'a> {
            context: &'a Arc<Context>,
            channels: Vec<Advertised>,
            error: Option<ViewerError>,
        }
        impl ChannelVisitor for Register<'_> {
            fn visit<T: Sample>(&mut self, channel: Channel<T>) {
                let topic = channel.topic();
                let schema = Schema::new(T::schema_name(), SCHEMA_ENCODING, T::schema_text().into_bytes());
                let built = ChannelBuilder::new(&topic)
                    .message_encoding(MESSAGE_ENCODING)
                    .schema(schema)
                    .context(self.context)
                    .build_raw();
                match built {
                    Ok(raw) => self.channels.push(Advertised {
                        name: channel.name,
                        topic,
                        message_len: CDR_HEADER.len() + std::mem::size_of::<T>(),
                        raw,
                    }),
                    Err(source) => self.error = self.error.take().or(Some(ViewerError::Channel { topic, source })),
                }
            }
        }
        let mut register = Register { context, channels: Vec::new(), error: None };
        visit_channels(&mut register);
        match register.error {
            Some(e) => Err(e),
            None => Ok(BenchChannels { channels: register.channels }),
        }
    }

    /// Index of the bus channel `name` (`bench/thrust`).
    pub fn by_name(&self, name: &str) -> Option<usize> {
        self.channels.iter().position(|c| c.name == name)
    }

    /// Index of the recorded topic `topic` (`/bench/thrust`).
    pub fn by_topic(&self, topic: &str) -> Option<usize> {
        self.channels.iter().position(|c| c.topic == topic)
    }

    /// True if `message` is a CDR message of channel `index`'s type: the
    /// header and exactly the sample's length.
    pub fn well_formed(&self, index: usize, message: &[u8]) -> bool {
        self.channels.get(index).is_some_and(|c| message.len() == c.message_len && message.starts_with(&CDR_HEADER))
    }

    /// Sends `message` on channel `index` to every subscribed client, stamped
    /// `log_time_ns` (ns since the Unix epoch). Never waits: a client whose
    /// backlog is full loses its oldest messages. True if any client was subscribed.
    pub fn log(&self, index: usize, message: &[u8], log_time_ns: u64) -> bool {
        let Some(channel) = self.channels.get(index) else { return false };
        if !channel.raw.has_sinks() {
            return false;
        }
        channel.raw.log_with_meta(message, foxglove::PartialMetadata { log_time: Some(log_time_ns) });
        true
    }

    /// Bus channel names, in index order.
    pub fn names(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.channels.iter().map(|c| c.name)
    }
}
