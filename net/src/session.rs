//! The zenoh session of a neuspike node, safe by default.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use zenoh::Wait;

/// How long a put with congestion control `block` waits for room in the link's queue before
/// zenoh gives the link up, seconds. zenoh's own default is 5 s, which a receiver that is busy
/// with its backlog on a loaded machine can exceed, and giving the link up loses the queued
/// messages; a receiver that takes nothing for this long is gone rather than slow.
pub const BLOCK_WAIT_S: i64 = 60;

/// The zenoh settings of a node (flattened into its `args:`).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct ZenohArgs {
    /// zenoh endpoints to listen on (default: an ephemeral port on loopback). Repeatable.
    #[arg(long = "listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// zenoh endpoints to dial (default: `tcp/127.0.0.1:7447`, a local router such as
    /// `rmw_zenohd`, if one runs). Repeatable.
    #[arg(long = "connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// A zenoh JSON5 configuration file, used instead of the settings above (mode, endpoints,
    /// TLS: see `docs/robots.md`).
    #[arg(long)]
    pub zenoh_config: Option<PathBuf>,
    /// The largest message the session takes from the network, bytes (default
    /// [`MAX_MESSAGE_BYTES`], 64 MiB): a larger one is dropped by zenoh before it is assembled.
    #[arg(long)]
    pub max_message_bytes: Option<usize>,
}

/// The largest message a session takes from the network unless `--max-message-bytes` says
/// otherwise: 64 MiB, five 400 x 250 chunks of 1,000 spike planes, or seventeen float frames of
/// 1280 x 720 (zenoh's own default is 1 GiB, which one forged message could make a node hold).
pub const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// The session could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The configuration file cannot be read or is not zenoh's.
    #[error("{path}: not a zenoh configuration: {reason}")]
    File {
        /// The file.
        path: PathBuf,
        /// zenoh's reason.
        reason: String,
    },
    /// A setting was refused.
    #[error("zenoh setting {key} = {value}: {reason}")]
    Setting {
        /// The key.
        key: String,
        /// The value.
        value: String,
        /// zenoh's reason.
        reason: String,
    },
    /// The session did not open (an endpoint that cannot be bound).
    #[error("cannot open the zenoh session: {0}")]
    Open(String),
}

/// A JSON list of strings.
fn json_list(v: &[String]) -> String {
    let items: Vec<String> = v
        .iter()
        .map(|s| format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\"")))
        .collect();
    format!("[{}]", items.join(","))
}

impl ZenohArgs {
    /// The zenoh configuration: the file, or the safe defaults with the endpoints given.
    ///
    /// # Errors
    /// The file cannot be read or is not a zenoh configuration; an endpoint is malformed.
    pub fn config(&self) -> Result<zenoh::Config, SessionError> {
        let set = |c: &mut zenoh::Config, k: &str, v: &str| {
            c.insert_json5(k, v).map_err(|e| SessionError::Setting {
                key: k.to_string(),
                value: v.to_string(),
                reason: e.to_string(),
            })
        };
        let max_message = "transport/link/rx/max_message_size";
        let max_message_bytes = self
            .max_message_bytes
            .unwrap_or(MAX_MESSAGE_BYTES)
            .to_string();
        if let Some(path) = &self.zenoh_config {
            let mut c = zenoh::Config::from_file(path).map_err(|e| SessionError::File {
                path: path.clone(),
                reason: e.to_string(),
            })?;
            // The file's own limit on a message stands, unless it is zenoh's default (1 GiB) or
            // --max-message-bytes says otherwise.
            let zenoh_default = zenoh::Config::default().get_json(max_message).ok();
            if self.max_message_bytes.is_some() || c.get_json(max_message).ok() == zenoh_default {
                set(&mut c, max_message, &max_message_bytes)?;
            }
            return Ok(c);
        }
        let list = |v: &[String], default: &str| -> String {
            if v.is_empty() {
                json_list(&[default.to_string()])
            } else {
                json_list(v)
            }
        };
        let mut c = zenoh::Config::default();
        set(&mut c, "mode", "\"peer\"")?;
        set(
            &mut c,
            "listen/endpoints",
            &list(&self.listen, "tcp/127.0.0.1:0"),
        )?;
        set(
            &mut c,
            "connect/endpoints",
            &list(&self.connect, "tcp/127.0.0.1:7447"),
        )?;
        set(&mut c, "scouting/multicast/enabled", "false")?;
        set(&mut c, max_message, &max_message_bytes)?;
        set(
            &mut c,
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            &(BLOCK_WAIT_S * 1_000_000).to_string(),
        )?;
        Ok(c)
    }

    /// Whether every link of the session authenticates its peer, so that whoever may publish
    /// on a key was let in by name: a configuration file with mutual TLS
    /// (`transport.link.tls.enable_mtls`), every endpoint it listens on or dials a TLS one
    /// (`tls/`, `quic/`), and access control that denies what it does not allow
    /// (`access_control`: `enabled`, `default_permission: "deny"`), as `examples/mtls/` sets.
    /// A remote stream then follows a new publisher at once (a restarted camera rejoins without
    /// waiting for [`crate::remote::REJOIN_AFTER`]).
    ///
    /// # Errors
    /// As [`ZenohArgs::config`].
    pub fn authenticates(&self) -> Result<bool, SessionError> {
        if self.zenoh_config.is_none() {
            return Ok(false);
        }
        let c = self.config()?;
        let get = |k: &str| c.get_json(k).unwrap_or_default();
        let endpoints = format!("{} {}", get("listen/endpoints"), get("connect/endpoints"));
        // The quoted strings holding a `/` are endpoints (a per-mode map's keys are not).
        let all_tls = endpoints
            .split('"')
            .skip(1)
            .step_by(2)
            .filter(|e| e.contains('/'))
            .all(|e| e.starts_with("tls/") || e.starts_with("quic/"));
        Ok(get("transport/link/tls/enable_mtls") == "true"
            && all_tls
            && get("access_control/enabled") == "true"
            && get("access_control/default_permission") == "\"deny\"")
    }

    /// How long a followed publisher must be silent before another may take its stream: zero
    /// where the links authenticate every publisher ([`Self::authenticates`]), else
    /// [`crate::remote::REJOIN_AFTER`].
    ///
    /// # Errors
    /// As [`ZenohArgs::config`].
    pub fn rejoin_after(&self) -> Result<Duration, SessionError> {
        Ok(if self.authenticates()? {
            Duration::ZERO
        } else {
            crate::remote::REJOIN_AFTER
        })
    }

    /// Opens the session.
    ///
    /// # Errors
    /// As [`ZenohArgs::config`], or the session could not open.
    pub fn open(&self) -> Result<zenoh::Session, SessionError> {
        zenoh::open(self.config()?)
            .wait()
            .map_err(|e| SessionError::Open(e.to_string()))
    }
}

/// Waits until none of `publishers` has a subscriber, or `limit` passed; whether they all left.
///
/// Closing a session drops what is still queued on its links, and a subscriber working through
/// its backlog may hold seconds of it. A subscriber that ends with its stream leaves once it
/// has taken the end-of-stream marker, so a publisher that waits for this before closing loses
/// nothing; one that keeps listening (a viewer) holds it for `limit`. A publisher whose status
/// cannot be read counts as left.
pub fn wait_unmatched(publishers: &[&zenoh::pubsub::Publisher<'_>], limit: Duration) -> bool {
    let deadline = Instant::now() + limit;
    loop {
        let matched = publishers
            .iter()
            .any(|p| p.matching_status().wait().is_ok_and(|m| m.matching()));
        if !matched {
            return true;
        }
        if Instant::now() >= deadline {
            return false;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The endpoints `session` listens on (`tcp/127.0.0.1:41234`).
pub fn locators(session: &zenoh::Session) -> Vec<String> {
    session
        .info()
        .locators()
        .wait()
        .iter()
        .map(ToString::to_string)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_session_is_a_peer_on_loopback_without_multicast() {
        let c = ZenohArgs::default().config().expect("config");
        let get = |k: &str| c.get_json(k).expect(k);
        assert_eq!(get("mode"), "\"peer\"");
        assert_eq!(get("listen/endpoints"), "[\"tcp/127.0.0.1:0\"]");
        assert_eq!(get("connect/endpoints"), "[\"tcp/127.0.0.1:7447\"]");
        assert_eq!(get("scouting/multicast/enabled"), "false");
        assert_eq!(get("transport/link/rx/max_message_size"), "67108864");
        assert_eq!(
            get("transport/link/tx/queue/congestion_control/block/wait_before_close"),
            "60000000"
        );
        let e = ZenohArgs {
            zenoh_config: Some("/nonexistent/z.json5".into()),
            ..ZenohArgs::default()
        }
        .config()
        .expect_err("no file")
        .to_string();
        assert!(
            e.starts_with("/nonexistent/z.json5: not a zenoh configuration"),
            "{e}"
        );
    }

    #[test]
    fn only_mutual_tls_on_every_link_with_access_control_authenticates() {
        let args = |path: &std::path::Path| ZenohArgs {
            zenoh_config: Some(path.to_path_buf()),
            ..ZenohArgs::default()
        };
        let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/mtls");
        for f in ["camera.json5", "compute.json5"] {
            let a = args(&examples.join(f));
            assert!(a.authenticates().expect(f), "{f}");
            assert_eq!(a.rejoin_after().expect(f), Duration::ZERO);
        }
        assert!(!ZenohArgs::default().authenticates().expect("default"));
        assert_eq!(
            ZenohArgs::default().rejoin_after().expect("default"),
            crate::remote::REJOIN_AFTER
        );
        // The camera's file with one plain TCP endpoint more, or without access control.
        let camera = std::fs::read_to_string(examples.join("camera.json5")).expect("camera");
        let dir = tempfile::tempdir().expect("tempdir");
        for (name, text) in [
            (
                "tcp.json5",
                camera.replace(
                    "[\"tls/0.0.0.0:7450\"]",
                    "[\"tls/0.0.0.0:7450\", \"tcp/0.0.0.0:7451\"]",
                ),
            ),
            (
                "open.json5",
                camera.replace(
                    "enabled: true,\n    default",
                    "enabled: false,\n    default",
                ),
            ),
            (
                "no-mtls.json5",
                camera.replace("enable_mtls: true", "enable_mtls: false"),
            ),
        ] {
            assert_ne!(text, camera, "{name}: the change applies");
            let path = dir.path().join(name);
            std::fs::write(&path, text).expect("write");
            assert!(!args(&path).authenticates().expect(name), "{name}");
        }
    }

    /// A configuration file that leaves zenoh's 1 GiB limit on a message gets neuspike's;
    /// one that sets its own keeps it, unless `--max-message-bytes` is given.
    #[test]
    fn a_configuration_file_gets_the_message_limit_unless_it_sets_one() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (bare, own) = (dir.path().join("bare.json5"), dir.path().join("own.json5"));
        std::fs::write(&bare, "{ mode: \"peer\" }").expect("write");
        std::fs::write(
            &own,
            "{ mode: \"peer\", transport: { link: { rx: { max_message_size: 1000 } } } }",
        )
        .expect("write");
        let limit = |path: &std::path::Path, flag: Option<usize>| {
            ZenohArgs {
                zenoh_config: Some(path.to_path_buf()),
                max_message_bytes: flag,
                ..ZenohArgs::default()
            }
            .config()
            .expect("config")
            .get_json("transport/link/rx/max_message_size")
            .expect("limit")
        };
        assert_eq!(limit(&bare, None), MAX_MESSAGE_BYTES.to_string());
        assert_eq!(limit(&own, None), "1000");
        assert_eq!(limit(&own, Some(5000)), "5000");
        assert_eq!(limit(&bare, Some(5000)), "5000");
    }

    /// Two sessions on loopback, the second dialling the first.
    fn pair() -> (zenoh::Session, zenoh::Session) {
        let a = ZenohArgs {
            connect: vec!["tcp/127.0.0.1:1".into()],
            ..ZenohArgs::default()
        }
        .open()
        .expect("first session");
        let b = ZenohArgs {
            connect: locators(&a),
            ..ZenohArgs::default()
        }
        .open()
        .expect("second session");
        (a, b)
    }

    #[test]
    fn a_publisher_waits_for_its_subscriber_to_leave_and_no_longer_than_the_limit() {
        let (a, b) = pair();
        let p = a
            .declare_publisher("test/linger")
            .wait()
            .expect("publisher");
        let short = Duration::from_millis(300);
        assert!(wait_unmatched(&[&p], short), "nobody listens yet");

        let sub = b
            .declare_subscriber("test/linger")
            .wait()
            .expect("subscriber");
        let deadline = Instant::now() + Duration::from_secs(10);
        while !p.matching_status().wait().expect("status").matching() {
            assert!(Instant::now() < deadline, "the subscriber never matched");
            std::thread::sleep(Duration::from_millis(20));
        }
        let start = Instant::now();
        assert!(!wait_unmatched(&[&p], short), "a subscriber still listens");
        assert!(start.elapsed() >= short);

        let leaving = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(200));
            drop(sub);
        });
        let start = Instant::now();
        assert!(wait_unmatched(&[&p], Duration::from_secs(10)), "it left");
        assert!(start.elapsed() < Duration::from_secs(10));
        leaving.join().expect("thread");
    }
}
