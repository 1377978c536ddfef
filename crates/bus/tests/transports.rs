//! The bus behaves the same over both transports: iceoryx2 shared memory and
//! Unix domain sockets. Each test runs once per transport, on channels of its
//! own (named after the test and this process), so tests run in parallel.

use std::time::{Duration, Instant};

use jetbench_bus::{Bus, Flow, LoopExit, Transport, Wake};
use jetbench_msgs::{Channel, Thrust};

const TRANSPORTS: [Transport; 2] = [Transport::Iceoryx2, Transport::UnixSockets];

fn channel(test: &str, transport: Transport) -> Channel<Thrust> {
    let name = format!("test/{}/{test}-{transport}", std::process::id());
    Channel::new(Box::leak(name.into_boxed_str()))
}

fn sample(i: u64) -> Thrust {
    Thrust { thrust_n: i as f64, stamp_ns: i + 1, ..Thrust::default() }
}

/// The test's own channel on `transport`, a bus, and a publisher on it.
fn publishing(test: &str, transport: Transport) -> (Channel<Thrust>, Bus, jetbench_bus::Publisher<Thrust>) {
    let channel = channel(test, transport);
    let bus = Bus::open_with(&format!("bus-test-{test}"), transport).expect("bus");
    let publisher = bus.publisher(channel).expect("publisher");
    (channel, bus, publisher)
}

/// Takes everything queued now; returns how many.
fn drain_count(reader: &jetbench_bus::Subscriber<Thrust>) -> u64 {
    let mut n = 0;
    while reader.try_recv().expect("receive").is_some() {
        n += 1;
    }
    n
}

#[test]
fn a_woken_consumer_gets_every_sample_in_order() {
    for transport in TRANSPORTS {
        let channel = channel("woken", transport);
        let bus = Bus::open_with("bus-test-consumer", transport).expect("bus");
        let subscriber = bus.subscriber(channel, 64).expect("subscriber");
        let producer = std::thread::spawn(move || {
            let bus = Bus::open_with("bus-test-producer", transport).expect("bus");
            let mut publisher = bus.publisher(channel).expect("publisher");
            for i in 0..50 {
                publisher.publish(sample(i)).expect("publish");
                std::thread::sleep(Duration::from_micros(300));
            }
            // Stay until the consumer is done: a departing publisher may take its samples along.
            std::thread::sleep(Duration::from_millis(500));
        });
        let mut got = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(20);
        let exit = bus
            .run(&[(&subscriber, Some(Duration::from_millis(100)))], None, |wake| {
                if let Wake::Input(0) = wake {
                    while let Some(s) = subscriber.try_recv().expect("receive") {
                        got.push(s.thrust_n as u64);
                    }
                }
                if got.len() >= 50 || Instant::now() > deadline {
                    Flow::Stop
                } else {
                    Flow::Continue
                }
            })
            .expect("run");
        producer.join().expect("producer");
        assert_eq!(exit, LoopExit::Stopped);
        assert_eq!(got, (0..50).collect::<Vec<_>>(), "{transport}: every sample, in order");
        assert_eq!(subscriber.gaps(), 0, "{transport}");
        assert_eq!(subscriber.received(), 50, "{transport}");
    }
}

#[test]
fn a_polled_reader_drains_what_was_published_and_finds_nothing_more() {
    for transport in TRANSPORTS {
        let (channel, bus, mut publisher) = publishing("polled", transport);
        let reader = bus.polled_subscriber(channel, 64).expect("subscriber");
        for i in 0..20 {
            publisher.publish(sample(i)).expect("publish");
        }
        let drain = || {
            let mut got = Vec::new();
            // A polled socket reader looks for new publishers on its own clock.
            let deadline = Instant::now() + Duration::from_secs(2);
            while got.is_empty() && Instant::now() < deadline {
                while let Some(s) = reader.try_recv().expect("receive") {
                    got.push(s.thrust_n as u64);
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            got
        };
        assert_eq!(drain(), (0..20).collect::<Vec<_>>(), "{transport}");
        assert_eq!(reader.try_recv().expect("receive").map(|s| s.seq), None, "{transport}: nothing more");
        assert_eq!(reader.try_recv().expect("receive").map(|s| s.seq), None, "{transport}: still nothing");
        publisher.publish(sample(20)).expect("publish");
        assert_eq!(drain(), [20], "{transport}: a later sample is found");
        assert_eq!((reader.received(), reader.gaps(), reader.publishers_seen()), (21, 0, 1), "{transport}");
    }
}

#[test]
fn a_full_queue_loses_samples_as_counted_gaps() {
    for transport in TRANSPORTS {
        // A subscriber that comes after its publisher is found by it.
        let (channel, bus, mut publisher) = publishing("overflow", transport);
        let reader = bus.polled_subscriber(channel, 4).expect("subscriber");
        std::thread::sleep(Duration::from_millis(150));
        // Gaps are counted from the first sample a subscriber sees.
        publisher.publish(sample(0)).expect("publish");
        assert_eq!(reader.try_recv().expect("receive").map(|s| s.seq), Some(0), "{transport}");
        let flood = 3000;
        for i in 1..flood {
            publisher.publish(sample(i)).expect("a full queue is no error");
        }
        let received = drain_count(&reader);
        assert!(received >= 1 && received < flood / 2, "{transport}: {received} of {flood} kept in a queue of 4");
        // One more, read at once: the gaps before it count everything dropped.
        publisher.publish(sample(flood)).expect("publish");
        let last = reader.try_recv().expect("receive").expect("the last sample");
        assert_eq!(last.seq, flood, "{transport}");
        assert_eq!(reader.received() + reader.gaps(), flood + 1, "{transport}: every sample received or counted lost");
    }
}

#[test]
fn a_departed_subscriber_costs_its_publisher_nothing() {
    for transport in TRANSPORTS {
        let (channel, bus, mut publisher) = publishing("departed", transport);
        let keeper = bus.polled_subscriber(channel, 64).expect("subscriber");
        let leaver = bus.polled_subscriber(channel, 64).expect("subscriber");
        std::thread::sleep(Duration::from_millis(150));
        publisher.publish(sample(0)).expect("publish");
        drop(leaver);
        for i in 1..10 {
            publisher.publish(sample(i)).expect("publishing after a subscriber left");
        }
        assert_eq!((drain_count(&keeper), keeper.gaps()), (10, 0), "{transport}");
    }
}

#[test]
fn a_sample_that_is_not_a_number_is_refused_and_takes_no_seq() {
    for transport in TRANSPORTS {
        let channel = channel("nan", transport);
        let bus = Bus::open_with("bus-test-nan", transport).expect("bus");
        let subscriber = bus.subscriber(channel, 16).expect("subscriber");
        let mut publisher = bus.publisher(channel).expect("publisher");
        assert_eq!(publisher.publish(sample(1)).expect("publish"), 0);
        for bad in [
            Thrust { thrust_n: f64::NAN, ..sample(2) },
            Thrust { force_n: [0.0, f64::INFINITY, 0.0], ..sample(2) },
            Thrust { torque_nm: [0.0, 0.0, f64::NEG_INFINITY], ..sample(2) },
        ] {
            let err = publisher.publish(bad).expect_err("a non-finite sample must be refused");
            assert!(matches!(err, jetbench_bus::SendError::NonFinite { .. }), "{err}");
            assert!(err.to_string().contains("is not a finite number"), "{err}");
        }
        assert_eq!(publisher.publish(sample(3)).expect("publish"), 1, "the refused samples took no seq");
        let deadline = Instant::now() + Duration::from_secs(10);
        let mut got = Vec::new();
        while got.len() < 2 && Instant::now() < deadline {
            while let Some(s) = subscriber.try_recv().expect("receive") {
                got.push((s.seq, s.thrust_n));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(got, [(0, 1.0), (1, 3.0)], "{transport}: only the finite samples arrive, gap-free");
        assert_eq!(subscriber.gaps(), 0);
    }
}

#[test]
fn a_subscriber_that_comes_while_its_publisher_sends_is_always_found() {
    // While the publisher sends without pause, other subscribers come and go
    // all the time, so the publisher looks for subscribers again at nearly
    // every send, whatever stage of setting up the next one is at. Every one
    // of them must be found.
    const SUBSCRIBERS: usize = 60;
    for transport in TRANSPORTS {
        let channel = channel("joining", transport);
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let running = |stop: &std::sync::Arc<std::sync::atomic::AtomicBool>| {
            let stop = stop.clone();
            move || !stop.load(std::sync::atomic::Ordering::Relaxed)
        };
        let sending = running(&stop);
        let producer = std::thread::spawn(move || {
            let bus = Bus::open_with("bus-test-joining-producer", transport).expect("bus");
            let mut publisher = bus.publisher(channel).expect("publisher");
            let mut i = 0;
            while sending() {
                publisher.publish(sample(i)).expect("publish");
                i += 1;
                std::thread::sleep(Duration::from_micros(20));
            }
        });
        let churning = running(&stop);
        let churn = std::thread::spawn(move || {
            let bus = Bus::open_with("bus-test-joining-churn", transport).expect("bus");
            while churning() {
                drop(bus.polled_subscriber(channel, 4).expect("subscriber"));
            }
        });
        let bus = Bus::open_with("bus-test-joining", transport).expect("bus");
        let mut unheard = Vec::new();
        for k in 0..SUBSCRIBERS {
            let reader = bus.polled_subscriber(channel, 4).expect("subscriber");
            // A polled socket reader looks for new publishers every 100 ms.
            let deadline = Instant::now() + Duration::from_secs(2);
            while drain_count(&reader) == 0 {
                if Instant::now() > deadline {
                    unheard.push(k);
                    break;
                }
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        producer.join().expect("producer");
        churn.join().expect("churn");
        assert!(unheard.is_empty(), "{transport}: subscribers {unheard:?} of {SUBSCRIBERS} never heard the publisher");
    }
}
