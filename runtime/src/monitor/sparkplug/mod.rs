//! `--mqtt URL --sparkplug GROUP/EDGE[/DEVICE]`: a PLC's signals as the
//! metrics of a Sparkplug B edge node (or of one of its devices), read from
//! an MQTT broker, and the flags written back as commands.
//!
//! The plant's signals are the level's metrics of the same names, declared
//! in its birth (NBIRTH, or DBIRTH with a device) and changed in its data
//! (NDATA, DDATA), by alias or by name. Times are the metrics' own
//! timestamps (Sparkplug's milliseconds), so the verdicts are those of
//! `diagnose` on the same changes. Sequence numbers, deaths and births
//! decide when the plant is lost; [`session`] says how.
//!
//! Topics read: `spBv1.0/GROUP/+/EDGE` and `spBv1.0/GROUP/+/EDGE/+` (every
//! message of the edge node carries its sequence number). Topics written:
//! `spBv1.0/GROUP/NCMD/EDGE` (the rebirth request, and the flags without a
//! device) and `spBv1.0/GROUP/DCMD/EDGE/DEVICE` (the flags), at QoS 1.

pub mod payload;
pub mod session;

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use diagnoser::{Failure, Plant, Time, TimeFormat};
use prost::Message;
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::time::{Instant, MissedTickBehavior};

use self::payload::{Metric, NAMESPACE, Payload, REBIRTH, command_topic};
use self::session::{Command, Session, Target};
use super::source::{Item, Link, Source};

/// Wait between attempts to reach a broker that refused or dropped the
/// connection.
pub const RECONNECT_EVERY: Duration = Duration::from_secs(1);
/// Largest MQTT packet taken or sent: a birth of many thousand metrics fits,
/// and a runaway message does not eat the memory.
const MAX_PACKET: usize = 1 << 20;

/// A Sparkplug B edge node's metrics, through an MQTT broker.
pub struct SparkplugSource {
    plant: Plant,
    host: String,
    port: u16,
    target: Target,
    speed: f64,
    lateness: Time,
}

impl SparkplugSource {
    /// The source for `plant` from the broker at `url` (`mqtt://HOST:PORT`,
    /// `tcp://HOST:PORT` or `HOST[:PORT]`, port 1883 by default) and the
    /// target `GROUP/EDGE[/DEVICE]`; fails on either malformed.
    pub fn new(
        url: &str,
        target: &str,
        plant: &Plant,
        speed: f64,
        lateness: Time,
    ) -> Result<SparkplugSource, Failure> {
        let (host, port) = parse_broker(url).map_err(|e| Failure::bad(format!("--mqtt: {e}")))?;
        let target = parse_target(target).map_err(|e| Failure::bad(format!("--sparkplug: {e}")))?;
        Ok(SparkplugSource {
            plant: plant.clone(),
            host,
            port,
            target,
            speed,
            lateness,
        })
    }
}

/// `mqtt://HOST:PORT`, `tcp://HOST:PORT` or `HOST[:PORT]`.
pub fn parse_broker(url: &str) -> Result<(String, u16), String> {
    let rest = url
        .strip_prefix("mqtt://")
        .or_else(|| url.strip_prefix("tcp://"))
        .unwrap_or(url);
    if rest.contains("://") {
        return Err(format!("'{url}': only mqtt:// (plain TCP) is read"));
    }
    let rest = rest.trim_end_matches('/');
    let (host, port) = match rest.rsplit_once(':') {
        Some((h, p)) => {
            let port = p
                .parse()
                .map_err(|_| format!("'{url}': port '{p}' is not a number from 1 to 65535"))?;
            (h, port)
        }
        None => (rest, 1883),
    };
    if host.is_empty() || port == 0 {
        return Err(format!("'{url}': expected mqtt://HOST:PORT"));
    }
    Ok((host.trim_matches(['[', ']']).to_string(), port))
}

/// `GROUP/EDGE[/DEVICE]`, each a non-empty topic level without wildcards.
pub fn parse_target(text: &str) -> Result<Target, String> {
    let parts: Vec<&str> = text.split('/').collect();
    let fit = |p: &&str| !p.is_empty() && !p.contains(['+', '#']);
    if !(2..=3).contains(&parts.len()) || !parts.iter().all(fit) {
        return Err(format!(
            "'{text}': expected GROUP/EDGE or GROUP/EDGE/DEVICE (no wildcards)"
        ));
    }
    Ok(Target {
        group: parts[0].to_string(),
        edge: parts[1].to_string(),
        device: parts.get(2).map(|d| d.to_string()),
    })
}

impl Source for SparkplugSource {
    fn time_format(&self) -> TimeFormat {
        Session::time_format()
    }

    fn spawn(self: Box<Self>, link: Link) {
        tokio::spawn(run(*self, link));
    }
}

/// Follows the edge node until the monitor goes.
async fn run(source: SparkplugSource, mut link: Link) {
    let client_id = format!("gardefou-{}-{}", std::process::id(), source.target.edge);
    let mut options = MqttOptions::new(client_id, source.host.clone(), source.port);
    options
        .set_keep_alive(Duration::from_secs(5))
        .set_clean_session(true)
        .set_max_packet_size(MAX_PACKET, MAX_PACKET);
    let (client, mut events) = AsyncClient::new(options, 64);
    let target = source.target.clone();
    let mut session = Session::new(&source.plant, target.clone(), source.speed, source.lateness);
    let period = source.plant.scan_period.max(1) as f64 / source.speed / 2.0;
    let mut ticker = tokio::time::interval(Duration::from_nanos(period.max(1e6) as u64));
    ticker.set_missed_tick_behavior(MissedTickBehavior::Delay);
    let (mut out, mut send) = (Vec::new(), Vec::new());
    let mut connected = false;
    let mut told_unreachable = false;
    loop {
        tokio::select! {
            event = events.poll() => match event {
                Ok(Event::Incoming(Packet::ConnAck(_))) => {
                    connected = true;
                    told_unreachable = false;
                    eprintln!("monitor: sparkplug {target}: connected to {}:{}", source.host, source.port);
                    for filter in filters(&target) {
                        let _ = client.try_subscribe(filter, QoS::AtLeastOnce);
                    }
                    session.connected(now(), &mut send);
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    session.message(&p.topic, &p.payload, now(), &mut out, &mut send);
                }
                Ok(_) => {}
                Err(e) => {
                    if connected {
                        session.disconnected(&format!("MQTT broker lost ({e})"), &mut out);
                    } else if !told_unreachable {
                        told_unreachable = true;
                        let m = format!("sparkplug {target}: cannot reach the MQTT broker {}:{} ({e}); trying again every {} s", source.host, source.port, RECONNECT_EVERY.as_secs());
                        out.push(Item::Warning(m));
                    }
                    connected = false;
                    if !deliver(&link, &mut out).await {
                        return;
                    }
                    tokio::time::sleep(RECONNECT_EVERY).await;
                }
            },
            _ = ticker.tick() => session.tick(now(), &mut out, &mut send),
            changed = link.flags.changed() => {
                if changed.is_err() {
                    return;
                }
                let image = link.flags.borrow_and_update().clone();
                session.flags(&image, now(), &mut out, &mut send);
            }
        }
        for command in send.drain(..) {
            if connected {
                publish(&client, &target, command, &mut out);
            }
        }
        if !deliver(&link, &mut out).await {
            return;
        }
    }
}

/// The instant now, as the session takes it.
fn now() -> std::time::Instant {
    Instant::now().into_std()
}

/// The subscriptions: every message of the edge node and of its devices.
fn filters(target: &Target) -> [String; 2] {
    let (g, e) = (&target.group, &target.edge);
    [
        format!("{NAMESPACE}/{g}/+/{e}"),
        format!("{NAMESPACE}/{g}/+/{e}/+"),
    ]
}

/// Queues one command for the broker. The event loop runs in this task, so
/// waiting for room could wait for ever: a full queue is a warning, and
/// the session sends the flags again.
fn publish(client: &AsyncClient, target: &Target, command: Command, out: &mut Vec<Item>) {
    let (topic, metrics) = match command {
        Command::Rebirth => (
            command_topic(&target.group, &target.edge, None),
            vec![Metric::new_boolean(REBIRTH, true)],
        ),
        Command::Flags(flags) => (
            command_topic(&target.group, &target.edge, target.device.as_deref()),
            flags
                .iter()
                .map(|(n, v)| Metric::new_boolean(n, *v))
                .collect(),
        ),
    };
    let payload = Payload {
        timestamp: Some(wall_ms()),
        metrics,
        seq: None,
    };
    if let Err(e) = client.try_publish(
        topic.clone(),
        QoS::AtLeastOnce,
        false,
        payload.encode_to_vec(),
    ) {
        out.push(Item::Warning(format!(
            "sparkplug {target}: {topic} not sent ({e})"
        )));
    }
}

/// Wall time in milliseconds since the epoch.
fn wall_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// Sends the items gathered; false once the monitor has gone or a fatal
/// item went out.
async fn deliver(link: &Link, out: &mut Vec<Item>) -> bool {
    for item in out.drain(..) {
        let fatal = matches!(item, Item::Fatal(_));
        if link.items.send(item).await.is_err() || fatal {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn brokers_and_targets_are_read() {
        assert_eq!(
            parse_broker("mqtt://127.0.0.1:1884"),
            Ok(("127.0.0.1".into(), 1884))
        );
        assert_eq!(parse_broker("broker"), Ok(("broker".into(), 1883)));
        assert_eq!(parse_broker("tcp://[::1]:1883/"), Ok(("::1".into(), 1883)));
        assert!(
            parse_broker("mqtts://broker:8883")
                .unwrap_err()
                .contains("only mqtt://")
        );
        assert!(
            parse_broker("mqtt://broker:http")
                .unwrap_err()
                .contains("port 'http'")
        );
        assert!(parse_broker("mqtt://:1883").is_err());
        let t = parse_target("line/plc7/io").expect("a device target");
        assert_eq!(t.device.as_deref(), Some("io"));
        assert_eq!(t.to_string(), "line/plc7/io");
        assert!(
            parse_target("line/plc7")
                .expect("a node target")
                .device
                .is_none()
        );
        for bad in ["line", "line//io", "line/+/io", "a/b/c/d", "line/#"] {
            assert!(parse_target(bad).is_err(), "{bad}");
        }
    }
}
