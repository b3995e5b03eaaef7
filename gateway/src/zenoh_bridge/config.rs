//! The `[zenoh]` section as the bridge uses it: the key prefix and the zenoh session's
//! configuration. The section's keys, defaults and checks are in [`crate::config::ZenohConfig`].

use std::path::Path;

pub use crate::config::{
    Endpoint, Mode, Prefix, ZenohConfig, DEFAULT_COMMAND_QUEUE, DEFAULT_EVENT_QUEUE,
    DEFAULT_MAX_PAYLOAD, DEFAULT_QUERY_QUEUE, DEFAULT_RESULT_QUEUE, DEFAULT_TAG_QUEUE,
    DEFAULT_TELEGRAM_QUEUE, MAX_MAX_PAYLOAD, PAYLOAD_HEADROOM,
};

use super::keys::{self, KeyError};
use super::BridgeError;

/// Where a peer listens when neither `[zenoh] listen` nor a zenoh file says: loopback, zenoh's
/// port. Other hosts reach the gateway only once an endpoint is configured.
pub const SAFE_LISTEN: &str = "tcp/127.0.0.1:7447";

/// zenoh's key for the largest message a link reassembles.
const MAX_MESSAGE_SIZE: &str = "transport/link/rx/max_message_size";

// === impl ZenohConfig ===

impl ZenohConfig {
    /// The prefix in use for a gateway named `gateway_name`.
    pub fn prefix_for(&self, gateway_name: &str) -> Result<String, KeyError> {
        match &self.prefix {
            Some(p) => Ok(p.as_str().to_owned()),
            None => keys::default_prefix(gateway_name),
        }
    }

    /// The zenoh configuration: the file (if any), then this section's keys on top. Without a
    /// file, what the section leaves unset is the safe default, not zenoh's: a peer listens on
    /// [`SAFE_LISTEN`] (loopback) only, and multicast scouting is off, so that an empty
    /// `[zenoh]` section opens nothing to the plant network. A file is taken as written, except
    /// that the largest message a link reassembles is at most [`Self::max_message_size`] (a
    /// smaller one in the file stays).
    pub fn to_zenoh(&self) -> Result<(zenoh::Config, Mode), BridgeError> {
        let (mut z, safe_defaults) = match &self.config_file {
            Some(path) => (read_file(path)?, false),
            None => (zenoh::Config::default(), true),
        };
        let mut set = |key: &str, value: String| {
            z.insert_json5(key, &value)
                .map_err(|e| BridgeError::Config(format!("zenoh config {key} = {value}: {e}")))
        };
        if let Some(mode) = self.mode {
            set("mode", json_string(mode.as_str()))?;
        }
        if let Some(listen) = &self.listen {
            set("listen/endpoints", json_list(listen))?;
        } else if safe_defaults && self.mode != Some(Mode::Client) {
            set(
                "listen/endpoints",
                format!("[{}]", json_string(SAFE_LISTEN)),
            )?;
        }
        if let Some(connect) = &self.connect {
            set("connect/endpoints", json_list(connect))?;
        }
        if let Some(lease) = self.lease {
            set("transport/link/tx/lease", lease.as_millis().to_string())?;
        }
        match self.multicast_scouting {
            Some(on) => set("scouting/multicast/enabled", on.to_string())?,
            None if safe_defaults => set("scouting/multicast/enabled", "false".to_owned())?,
            None => {}
        }
        let limit = self.max_message_size();
        let in_file = z
            .get_json(MAX_MESSAGE_SIZE)
            .ok()
            .and_then(|v| v.parse::<usize>().ok());
        if in_file.is_none_or(|n| n > limit) {
            z.insert_json5(MAX_MESSAGE_SIZE, &limit.to_string())
                .map_err(|e| {
                    BridgeError::Config(format!("zenoh config {MAX_MESSAGE_SIZE}: {e}"))
                })?;
        }
        let mode = match z.get_json("mode").ok().as_deref() {
            Some("\"client\"") => Mode::Client,
            Some("\"router\"") => Mode::Router,
            _ => Mode::Peer,
        };
        Ok((z, mode))
    }

    /// The largest message zenoh reassembles for the gateway: `max_payload` plus
    /// [`PAYLOAD_HEADROOM`] for the key, the attachment and the framing. A larger put is dropped
    /// by zenoh while its fragments arrive, so it never takes more memory than this.
    pub fn max_message_size(&self) -> usize {
        self.max_payload.get().saturating_add(PAYLOAD_HEADROOM)
    }
}

fn read_file(path: &Path) -> Result<zenoh::Config, BridgeError> {
    zenoh::Config::from_file(path).map_err(|e| BridgeError::ConfigFile {
        path: path.to_owned(),
        reason: e.to_string(),
    })
}

fn json_string(s: &str) -> String {
    serde_json::Value::String(s.to_owned()).to_string()
}

fn json_list(endpoints: &[Endpoint]) -> String {
    serde_json::Value::Array(
        endpoints
            .iter()
            .map(|e| serde_json::Value::String(e.as_str().to_owned()))
            .collect(),
    )
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<ZenohConfig, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn empty_section_gives_the_defaults() {
        let c = parse("").unwrap();
        assert_eq!(c, ZenohConfig::default());
        assert!(c.enabled);
        assert_eq!(c.telegram_queue.get(), DEFAULT_TELEGRAM_QUEUE);
        assert_eq!(c.prefix_for("demo").unwrap(), "gw/demo");
        let (z, mode) = c.to_zenoh().unwrap();
        assert_eq!(mode, Mode::Peer);
        // Safe defaults: loopback only, no multicast scouting.
        assert_eq!(
            z.get_json("listen/endpoints").unwrap().replace(' ', ""),
            r#"["tcp/127.0.0.1:7447"]"#
        );
        assert_eq!(z.get_json("scouting/multicast/enabled").unwrap(), "false");
        assert_eq!(c.max_payload.get(), 65_536);
        assert_eq!(z.get_json(MAX_MESSAGE_SIZE).unwrap(), "131072");
    }

    #[test]
    fn every_key_parses() {
        let c = parse(
            r#"
            enabled = true
            mode = "client"
            listen = ["tcp/127.0.0.1:7447"]
            connect = ["tcp/10.0.0.1:7447", "tcp/[::1]:7448"]
            multicast_scouting = false
            prefix = "plant/hall2/gw1"
            telegram_queue = 10
            event_queue = 11
            tag_queue = 12
            result_queue = 13
            command_queue = 14
            query_queue = 15
            max_payload = 1000
            lease = "3s"
            "#,
        )
        .unwrap();
        assert_eq!(c.mode, Some(Mode::Client));
        assert_eq!(c.prefix_for("x").unwrap(), "plant/hall2/gw1");
        assert_eq!(c.query_queue.get(), 15);
        assert_eq!(c.max_payload.get(), 1000);
        let (z, mode) = c.to_zenoh().unwrap();
        assert_eq!(mode, Mode::Client);
        assert_eq!(
            z.get_json("connect/endpoints").unwrap().replace(' ', ""),
            r#"["tcp/10.0.0.1:7447","tcp/[::1]:7448"]"#
        );
        assert_eq!(
            z.get_json(MAX_MESSAGE_SIZE).unwrap(),
            (1000 + PAYLOAD_HEADROOM).to_string()
        );
        assert_eq!(z.get_json("scouting/multicast/enabled").unwrap(), "false");
        assert_eq!(z.get_json("transport/link/tx/lease").unwrap(), "3000");
        let router = parse("mode = \"router\"").unwrap();
        assert_eq!(router.to_zenoh().unwrap().1, Mode::Router);
    }

    #[test]
    fn bad_values_are_refused_when_read() {
        for text in [
            "bogus = 1",
            "mode = \"broker\"",
            "listen = [\"nonsense\"]",
            "connect = [\"tcp\"]",
            "prefix = \"gw/*\"",
            "prefix = \"gw//x\"",
            "telegram_queue = 0",
            "max_payload = 0",
            "lease = \"1ms\"",
            "max_payload = 16777217",
            "max_payload = \"64k\"",
        ] {
            assert!(parse(text).is_err(), "{text}");
        }
    }

    #[test]
    fn roundtrip_through_toml() {
        let c = ZenohConfig::loopback_peer("tcp/127.0.0.1:7447").unwrap();
        let text = toml::to_string(&c).unwrap();
        assert_eq!(parse(&text).unwrap(), c);
    }

    #[test]
    fn section_overrides_the_file() {
        let dir = std::env::temp_dir().join(format!("zenoh-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("zenoh.json5");
        std::fs::write(
            &file,
            r#"{ mode: "client", connect: { endpoints: ["tcp/10.1.1.1:7447"] },
                 scouting: { multicast: { enabled: false } } }"#,
        )
        .unwrap();
        let mut c = ZenohConfig {
            config_file: Some(file.clone()),
            ..ZenohConfig::default()
        };
        let (z, mode) = c.to_zenoh().unwrap();
        assert_eq!(mode, Mode::Client);
        assert!(z
            .get_json("connect/endpoints")
            .unwrap()
            .contains("10.1.1.1"));
        c.mode = Some(Mode::Peer);
        let (_, mode) = c.to_zenoh().unwrap();
        assert_eq!(mode, Mode::Peer);
        // The file's own limit stays when it is smaller, and is lowered when it is larger.
        std::fs::write(
            &file,
            r#"{ transport: { link: { rx: { max_message_size: 4096 } } } }"#,
        )
        .unwrap();
        let (z, _) = c.to_zenoh().unwrap();
        assert_eq!(z.get_json(MAX_MESSAGE_SIZE).unwrap(), "4096");
        std::fs::write(
            &file,
            r#"{ transport: { link: { rx: { max_message_size: 1073741824 } } } }"#,
        )
        .unwrap();
        let (z, _) = c.to_zenoh().unwrap();
        assert_eq!(z.get_json(MAX_MESSAGE_SIZE).unwrap(), "131072");
        c.config_file = Some(dir.join("missing.json5"));
        assert!(matches!(c.to_zenoh(), Err(BridgeError::ConfigFile { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A gateway listening on a TLS endpoint with mutual authentication: a client with a
    /// certificate of the CA gets the gateway's answers, a client without one is refused.
    #[cfg(feature = "zenoh-tls")]
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn tls_endpoints_with_mutual_authentication() {
        use std::time::Duration;
        let _ = tracing_subscriber::fmt().with_test_writer().try_init();
        let dir = tempfile::tempdir().unwrap();
        let ca_key = rcgen::KeyPair::generate().unwrap();
        let mut ca_params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
        ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
        let ca = ca_params.self_signed(&ca_key).unwrap();
        let issuer = rcgen::Issuer::from_params(&ca_params, &ca_key);
        let path = |name: &str| dir.path().join(name).display().to_string();
        std::fs::write(path("ca.pem"), ca.pem()).unwrap();
        for name in ["gw", "app"] {
            let key = rcgen::KeyPair::generate().unwrap();
            let cert = rcgen::CertificateParams::new(vec!["127.0.0.1".to_owned()])
                .unwrap()
                .signed_by(&key, &issuer)
                .unwrap();
            std::fs::write(path(&format!("{name}.pem")), cert.pem()).unwrap();
            std::fs::write(path(&format!("{name}.key")), key.serialize_pem()).unwrap();
        }
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let file = path("zenoh.json5");
        std::fs::write(
            &file,
            format!(
                r#"{{ transport: {{ link: {{ tls: {{
                    root_ca_certificate: "{ca}", listen_certificate: "{cert}",
                    listen_private_key: "{key}", enable_mtls: true }} }} }} }}"#,
                ca = path("ca.pem"),
                cert = path("gw.pem"),
                key = path("gw.key"),
            ),
        )
        .unwrap();
        let gw = ZenohConfig {
            mode: Some(Mode::Peer),
            listen: Some(vec![
                Endpoint::try_from(format!("tls/127.0.0.1:{port}")).unwrap()
            ]),
            connect: Some(Vec::new()),
            multicast_scouting: Some(false),
            config_file: Some(file.into()),
            ..ZenohConfig::default()
        };
        let (zcfg, _) = gw.to_zenoh().unwrap();
        let server = zenoh::open(zcfg).await.expect("a TLS listener");
        let _q = server
            .declare_queryable("gw/tls/status")
            .callback(|q| {
                let _ = zenoh::Wait::wait(q.reply("gw/tls/status", "{\"ok\":true}"));
            })
            .await
            .unwrap();
        let client = |with_cert: bool| {
            let mut c = zenoh::Config::default();
            c.insert_json5("mode", r#""client""#).unwrap();
            c.insert_json5("connect/endpoints", &format!(r#"["tls/127.0.0.1:{port}"]"#))
                .unwrap();
            c.insert_json5("scouting/multicast/enabled", "false")
                .unwrap();
            c.insert_json5(
                "transport/link/tls/root_ca_certificate",
                &format!("{:?}", path("ca.pem")),
            )
            .unwrap();
            if with_cert {
                c.insert_json5("transport/link/tls/enable_mtls", "true")
                    .unwrap();
                c.insert_json5(
                    "transport/link/tls/connect_certificate",
                    &format!("{:?}", path("app.pem")),
                )
                .unwrap();
                c.insert_json5(
                    "transport/link/tls/connect_private_key",
                    &format!("{:?}", path("app.key")),
                )
                .unwrap();
            }
            c
        };
        let app = zenoh::open(client(true))
            .await
            .expect("a client with a certificate");
        let replies = app
            .get("gw/tls/status")
            .timeout(Duration::from_secs(5))
            .await
            .unwrap();
        let reply = replies.recv_async().await.expect("an answer over TLS");
        assert!(reply.result().is_ok());
        assert!(
            zenoh::open(client(false)).await.is_err(),
            "a client without a certificate is refused"
        );
        app.close().await.unwrap();
        server.close().await.unwrap();
    }
}
