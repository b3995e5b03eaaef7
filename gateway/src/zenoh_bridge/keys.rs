//! The key expressions of the bridge: pure mapping between gateway names and zenoh keys.
//!
//! ```text
//! <prefix>/status                          gateway status (queryable)
//! <prefix>/<line>/status                   line status (queryable)
//! <prefix>/<line>/rx                       received telegrams (publication)
//! <prefix>/<line>/tx                       telegrams to send (subscription; queryable form)
//! <prefix>/<line>/tx/result                result of a send (publication)
//! <prefix>/<line>/ack                      acknowledge a received telegram, payload its
//!                                          sequence number (subscription; queryable form,
//!                                          whose reply is the result)
//! <prefix>/<line>/events                   diagnostic events (publication)
//! <prefix>/<line>/frames                   the line's frame monitor, one JSON sample per frame
//!                                          (publication)
//! <prefix>/<line>/<device>/<tag>           tag values (publication on change; queryable)
//! <prefix>/<line>/<device>/<tag>/set       writes (subscription; queryable form)
//! <prefix>/<line>/<device>/<tag>/set/result  result of a write (publication)
//! liveliness: <prefix>                     the gateway, while its bridge runs
//! liveliness: <prefix>/<line>              one line while its port is open
//! liveliness: <prefix>/<line>/<device>     one device while it is online
//! <parent of prefix>/*                     the fleet: the gateway tokens of the gateways
//!                                          beside this one (`gw/*` for the default prefix)
//! ```
//!
//! Each of line, device and tag names is exactly one key chunk. The only structural clash is a
//! device named `tx` (its tag `result` would be `<line>/tx/result`), so that name is reserved.
//! Nothing here touches a session: every function is pure and tested below.

use std::fmt;

use zenoh::key_expr::{keyexpr, OwnedKeyExpr};

/// The first chunk of the default prefix `gw/<gateway name>`.
pub const DEFAULT_PREFIX_ROOT: &str = "gw";
/// Device names that would make a tag key collide with a line key.
pub const RESERVED_DEVICE_NAMES: [&str; 1] = [TX];

const RX: &str = "rx";
const TX: &str = "tx";
const ACK: &str = "ack";
const RESULT: &str = "result";
const EVENTS: &str = "events";
const FRAMES: &str = "frames";
const STATUS: &str = "status";
const SET: &str = "set";
/// The chunk under which zenoh-ext's advanced publishers answer history queries.
const ADV: &str = "@adv";

/// A name that cannot be one key chunk, or a prefix that is not a plain key expression.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    /// Empty name.
    #[error("{what} name is empty")]
    Empty {
        /// `"line"`, `"device"`, `"tag"` or `"gateway"`.
        what: &'static str,
    },
    /// A character that zenoh treats specially: `/`, `*`, `$`, `?`, `#`.
    #[error("{what} name {name:?} contains {found:?}; a name is one key chunk without `/*$?#`")]
    BadChar {
        /// `"line"`, `"device"`, `"tag"` or `"gateway"`.
        what: &'static str,
        /// The name.
        name: String,
        /// The first offending character.
        found: char,
    },
    /// A device name the key layout reserves.
    #[error("device name {0:?} is reserved (it would collide with <line>/tx/result)")]
    Reserved(String),
    /// The prefix is not a canonical key expression without wildcards.
    #[error("key prefix {prefix:?} is not a canonical key expression without wildcards: {reason}")]
    BadPrefix {
        /// The prefix as given.
        prefix: String,
        /// Why.
        reason: String,
    },
}

/// Checks that `name` can be one key chunk: non-empty, none of `/ * $ ? #`.
///
/// `what` names the kind in the error (`"line"`, `"device"`, `"tag"`, `"gateway"`).
pub fn check_chunk(what: &'static str, name: &str) -> Result<(), KeyError> {
    if name.is_empty() {
        return Err(KeyError::Empty { what });
    }
    if let Some(found) = name
        .chars()
        .find(|c| matches!(c, '/' | '*' | '$' | '?' | '#'))
    {
        return Err(KeyError::BadChar {
            what,
            name: name.to_owned(),
            found,
        });
    }
    Ok(())
}

/// Checks a configured prefix: a canonical key expression without wildcards.
pub fn check_prefix(prefix: &str) -> Result<OwnedKeyExpr, KeyError> {
    crate::config::check_prefix(prefix).map_err(|reason| KeyError::BadPrefix {
        prefix: prefix.to_owned(),
        reason,
    })
}

/// The default prefix `gw/<gateway name>`.
pub fn default_prefix(gateway_name: &str) -> Result<String, KeyError> {
    check_chunk("gateway", gateway_name)?;
    Ok(format!("{DEFAULT_PREFIX_ROOT}/{gateway_name}"))
}

/// What a tag query asks for, as far as its key expression names literal chunks. `None` means
/// "any": the bridge asks the backend for all such tags and keeps those whose key intersects the
/// query.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TagFilter {
    /// The line, when the query names it literally.
    pub line: Option<String>,
    /// The device, when the query names it literally.
    pub device: Option<String>,
    /// The tag, when the query names it literally.
    pub tag: Option<String>,
}

/// The keys of one gateway under its prefix.
#[derive(Clone, PartialEq, Eq)]
pub struct Keys {
    prefix: String,
}

// === impl Keys ===

impl Keys {
    /// Keys under `prefix`, which must pass [`check_prefix`].
    pub fn new(prefix: &str) -> Result<Self, KeyError> {
        let ke = check_prefix(prefix)?;
        Ok(Self {
            prefix: ke.as_str().to_owned(),
        })
    }

    /// The prefix.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// `<prefix>`: the gateway's liveliness token.
    pub fn gateway_token(&self) -> String {
        self.prefix.clone()
    }

    /// `<prefix>/status`.
    pub fn gateway_status(&self) -> String {
        format!("{}/{STATUS}", self.prefix)
    }

    /// `<prefix>/<line>/status`.
    pub fn line_status(&self, line: &str) -> String {
        format!("{}/{line}/{STATUS}", self.prefix)
    }

    /// `<prefix>/*/status`: the line status queryable.
    pub fn line_status_pattern(&self) -> String {
        format!("{}/*/{STATUS}", self.prefix)
    }

    /// `<prefix>/<line>/rx`.
    pub fn rx(&self, line: &str) -> String {
        format!("{}/{line}/{RX}", self.prefix)
    }

    /// `<prefix>/<line>/tx/result`.
    pub fn tx_result(&self, line: &str) -> String {
        format!("{}/{line}/{TX}/{RESULT}", self.prefix)
    }

    /// `<prefix>/*/tx`: the send subscription and queryable.
    pub fn tx_pattern(&self) -> String {
        format!("{}/*/{TX}", self.prefix)
    }

    /// `<prefix>/*/ack`: the acknowledge subscription and queryable.
    pub fn ack_pattern(&self) -> String {
        format!("{}/*/{ACK}", self.prefix)
    }

    /// The line of a concrete `<prefix>/<line>/ack` key; `None` for any other key and for keys
    /// with wildcards.
    pub fn parse_ack(&self, key: &str) -> Option<String> {
        match self.rest(key)?.as_slice() {
            [line, ACK] if check_chunk("line", line).is_ok() => Some((*line).to_owned()),
            _ => None,
        }
    }

    /// `<prefix>/<line>/frames`.
    pub fn frames(&self, line: &str) -> String {
        format!("{}/{line}/{FRAMES}", self.prefix)
    }

    /// `<prefix>/<line>/events`.
    pub fn events(&self, line: &str) -> String {
        format!("{}/{line}/{EVENTS}", self.prefix)
    }

    /// `<prefix>/<line>/<device>/<tag>`.
    pub fn tag(&self, line: &str, device: &str, tag: &str) -> String {
        format!("{}/{line}/{device}/{tag}", self.prefix)
    }

    /// `<prefix>/*/*/*`: the tag queryable.
    pub fn tag_pattern(&self) -> String {
        format!("{}/*/*/*", self.prefix)
    }

    /// `<prefix>/*/*/*/@adv/**`: the history queryable. An advanced subscriber (zenoh-ext) with
    /// history asks `<its key expression>/@adv/**` for the cached samples of the advanced
    /// publishers under it; the gateway answers that query with the current value of every tag
    /// the subscriber's key expression matches.
    pub fn history_pattern(&self) -> String {
        format!("{}/*/*/*/{ADV}/**", self.prefix)
    }

    /// The key expression a history query asks about: the query's key without the `/@adv/**`
    /// that the advanced subscriber appends; `None` for a key without it.
    pub fn history_subject(query: &str) -> Option<&str> {
        let at = query.find(&format!("/{ADV}/")).or_else(|| {
            query
                .ends_with(&format!("/{ADV}"))
                .then(|| query.len() - ADV.len() - 1)
        })?;
        Some(&query[..at])
    }

    /// `<prefix>/<line>/<device>/<tag>/set/result`.
    pub fn set_result(&self, line: &str, device: &str, tag: &str) -> String {
        format!("{}/{line}/{device}/{tag}/{SET}/{RESULT}", self.prefix)
    }

    /// `<prefix>/*/*/*/set`: the write subscription and queryable.
    pub fn set_pattern(&self) -> String {
        format!("{}/*/*/*/{SET}", self.prefix)
    }

    /// `<prefix>/<line>`: a line's liveliness token.
    pub fn line_token(&self, line: &str) -> String {
        format!("{}/{line}", self.prefix)
    }

    /// The gateway tokens of the fleet this gateway belongs to: its prefix with the last chunk
    /// a wildcard (`gw/*` for `gw/<name>`); `*` for a prefix of one chunk.
    pub fn fleet_pattern(&self) -> String {
        match self.prefix.rsplit_once('/') {
            Some((parent, _)) => format!("{parent}/*"),
            None => "*".to_owned(),
        }
    }

    /// `<prefix>/<line>/<device>`: a device's liveliness token.
    pub fn device_token(&self, line: &str, device: &str) -> String {
        format!("{}/{line}/{device}", self.prefix)
    }

    /// The chunks of `key` after the prefix, if `key` starts with the literal prefix.
    fn rest<'k>(&self, key: &'k str) -> Option<Vec<&'k str>> {
        let rest = key.strip_prefix(self.prefix.as_str())?.strip_prefix('/')?;
        Some(rest.split('/').collect())
    }

    /// The line of a concrete `<prefix>/<line>/tx` key; `None` for any other key, and for keys
    /// with wildcards (a command names exactly one line).
    pub fn parse_tx(&self, key: &str) -> Option<String> {
        match self.rest(key)?.as_slice() {
            [line, TX] if check_chunk("line", line).is_ok() => Some((*line).to_owned()),
            _ => None,
        }
    }

    /// Line, device and tag of a concrete `<prefix>/<line>/<device>/<tag>/set` key; `None` for
    /// any other key and for keys with wildcards.
    pub fn parse_set(&self, key: &str) -> Option<(String, String, String)> {
        match self.rest(key)?.as_slice() {
            [line, device, tag, SET]
                if check_chunk("line", line).is_ok()
                    && check_chunk("device", device).is_ok()
                    && check_chunk("tag", tag).is_ok() =>
            {
                Some(((*line).to_owned(), (*device).to_owned(), (*tag).to_owned()))
            }
            _ => None,
        }
    }

    /// The literal chunks of a tag query `query` (a key expression). Anything that is not exactly
    /// `<prefix>/<a>/<b>/<c>` with the literal prefix gives "any" for every part; a chunk with a
    /// wildcard gives "any" for that part.
    pub fn tag_filter(&self, query: &str) -> TagFilter {
        let literal = |c: &str| check_chunk("tag", c).is_ok().then(|| c.to_owned());
        match self.rest(query).as_deref() {
            Some([line, device, tag]) => TagFilter {
                line: literal(line),
                device: literal(device),
                tag: literal(tag),
            },
            _ => TagFilter::default(),
        }
    }
}

impl fmt::Debug for Keys {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("Keys").field(&self.prefix).finish()
    }
}

/// Whether the key expression `query` intersects the concrete key `key`. Either failing to
/// parse counts as no intersection.
pub fn intersects(query: &str, key: &str) -> bool {
    match (keyexpr::new(query), keyexpr::new(key)) {
        (Ok(q), Ok(k)) => q.intersects(k),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Checks a line name (for config validation).
    fn check_line_name(name: &str) -> Result<(), KeyError> {
        check_chunk("line", name)
    }

    /// Checks a device name (for config validation): one chunk and not reserved.
    fn check_device_name(name: &str) -> Result<(), KeyError> {
        check_chunk("device", name)?;
        if RESERVED_DEVICE_NAMES.contains(&name) {
            return Err(KeyError::Reserved(name.to_owned()));
        }
        Ok(())
    }

    /// Checks a tag name (for config validation).
    fn check_tag_name(name: &str) -> Result<(), KeyError> {
        check_chunk("tag", name)
    }

    fn keys() -> Keys {
        Keys::new("gw/demo").unwrap()
    }

    #[test]
    fn layout_of_every_key() {
        let k = keys();
        assert_eq!(k.gateway_token(), "gw/demo");
        assert_eq!(k.gateway_status(), "gw/demo/status");
        assert_eq!(k.line_status("drive"), "gw/demo/drive/status");
        assert_eq!(k.rx("r3964"), "gw/demo/r3964/rx");
        assert_eq!(k.tx_result("r3964"), "gw/demo/r3964/tx/result");
        assert_eq!(k.events("ascii"), "gw/demo/ascii/events");
        assert_eq!(k.frames("drive"), "gw/demo/drive/frames");
        assert_eq!(k.tag("drive", "atv", "eta"), "gw/demo/drive/atv/eta");
        assert_eq!(
            k.set_result("drive", "atv", "cmd"),
            "gw/demo/drive/atv/cmd/set/result"
        );
        assert_eq!(k.device_token("drive", "atv"), "gw/demo/drive/atv");
        assert_eq!(k.line_token("drive"), "gw/demo/drive");
        assert_eq!(k.fleet_pattern(), "gw/*");
        assert_eq!(
            Keys::new("plant/hall2/gw1").unwrap().fleet_pattern(),
            "plant/hall2/*"
        );
        assert_eq!(Keys::new("solo").unwrap().fleet_pattern(), "*");
        for pattern in [
            k.tx_pattern(),
            k.set_pattern(),
            k.tag_pattern(),
            k.line_status_pattern(),
        ] {
            assert!(keyexpr::new(pattern.as_str()).is_ok(), "{pattern}");
        }
    }

    #[test]
    fn every_concrete_key_is_a_canonical_key_expression() {
        let k = keys();
        for key in [
            k.gateway_status(),
            k.rx("a"),
            k.tx_result("a"),
            k.events("a"),
            k.tag("a", "b", "c"),
            k.set_result("a", "b", "c"),
            k.device_token("a", "b"),
        ] {
            let ke = keyexpr::new(key.as_str()).unwrap();
            assert!(!ke.is_wild(), "{key}");
        }
    }

    #[test]
    fn patterns_match_their_keys_and_not_the_others() {
        let k = keys();
        assert!(intersects(&k.tx_pattern(), "gw/demo/r3964/tx"));
        assert!(!intersects(&k.tx_pattern(), &k.tx_result("r3964")));
        assert!(intersects(&k.set_pattern(), "gw/demo/drive/atv/cmd/set"));
        assert!(!intersects(
            &k.set_pattern(),
            &k.set_result("drive", "atv", "cmd")
        ));
        assert!(intersects(&k.tag_pattern(), &k.tag("drive", "atv", "eta")));
        assert!(!intersects(&k.tag_pattern(), &k.rx("drive")));
        assert!(!intersects(&k.tag_pattern(), &k.line_status("drive")));
        assert!(!intersects(&k.tag_pattern(), &k.gateway_status()));
        assert!(intersects(&k.line_status_pattern(), &k.line_status("x")));
        assert!(!intersects(&k.line_status_pattern(), &k.gateway_status()));
    }

    #[test]
    fn names_must_be_one_plain_chunk() {
        assert!(check_line_name("r3964").is_ok());
        assert!(check_tag_name("speed-ref_1.5").is_ok());
        assert_eq!(check_line_name(""), Err(KeyError::Empty { what: "line" }));
        for (name, found) in [
            ("a/b", '/'),
            ("a*", '*'),
            ("$x", '$'),
            ("a?b", '?'),
            ("#", '#'),
        ] {
            assert_eq!(
                check_tag_name(name),
                Err(KeyError::BadChar {
                    what: "tag",
                    name: name.to_owned(),
                    found
                })
            );
        }
        assert_eq!(
            check_device_name("tx"),
            Err(KeyError::Reserved("tx".to_owned()))
        );
        assert!(check_device_name("rx").is_ok());
    }

    #[test]
    fn prefix_checks() {
        assert_eq!(default_prefix("demo").unwrap(), "gw/demo");
        assert!(default_prefix("a/b").is_err());
        assert!(Keys::new("plant/hall2/gw1").is_ok());
        for bad in ["", "gw/*", "gw/**", "gw//x", "/gw", "gw/", "gw/a$*"] {
            assert!(Keys::new(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn commands_parse_only_concrete_keys_under_the_prefix() {
        let k = keys();
        assert_eq!(k.parse_tx("gw/demo/r3964/tx").as_deref(), Some("r3964"));
        assert_eq!(k.parse_tx("gw/demo/*/tx"), None);
        assert_eq!(k.parse_tx("gw/demo/**/tx"), None);
        assert_eq!(k.parse_tx("gw/demo/r3964/tx/result"), None);
        assert_eq!(k.parse_tx("gw/other/r3964/tx"), None);
        assert_eq!(k.parse_tx("gw/demox/r3964/tx"), None);
        assert_eq!(k.parse_tx("gw/*/r3964/tx"), None);
        assert_eq!(k.parse_ack("gw/demo/r3964/ack").as_deref(), Some("r3964"));
        assert_eq!(k.parse_ack("gw/demo/*/ack"), None);
        assert_eq!(k.parse_ack("gw/demo/r3964/tx"), None);
        assert!(intersects(&k.ack_pattern(), "gw/demo/r3964/ack"));
        assert!(!intersects(&k.ack_pattern(), &k.tag("r3964", "ack", "x")));
        assert_eq!(
            k.parse_set("gw/demo/drive/atv/cmd/set"),
            Some(("drive".into(), "atv".into(), "cmd".into()))
        );
        assert_eq!(k.parse_set("gw/demo/drive/*/cmd/set"), None);
        assert_eq!(k.parse_set("gw/demo/drive/atv/cmd/set/result"), None);
        assert_eq!(k.parse_set("gw/demo/drive/atv/set"), None);
    }

    #[test]
    fn history_queries_name_the_tags_before_the_adv_chunk() {
        let k = keys();
        assert_eq!(k.history_pattern(), "gw/demo/*/*/*/@adv/**");
        assert_eq!(
            Keys::history_subject("gw/demo/ksvario/ksvario/*/@adv/**"),
            Some("gw/demo/ksvario/ksvario/*")
        );
        assert_eq!(Keys::history_subject("gw/demo/**/@adv"), Some("gw/demo/**"));
        assert_eq!(Keys::history_subject("gw/demo/**"), None);
        // The subscriber's query reaches the history queryable, not the tag queryable.
        assert!(intersects("gw/demo/**/@adv/**", &k.history_pattern()));
        assert!(!intersects("gw/demo/**/@adv/**", &k.tag_pattern()));
        assert!(!intersects("gw/demo/**", &k.history_pattern()));
    }

    #[test]
    fn tag_filter_takes_literal_chunks_only() {
        let k = keys();
        assert_eq!(
            k.tag_filter("gw/demo/drive/atv/eta"),
            TagFilter {
                line: Some("drive".into()),
                device: Some("atv".into()),
                tag: Some("eta".into())
            }
        );
        assert_eq!(
            k.tag_filter("gw/demo/drive/*/eta"),
            TagFilter {
                line: Some("drive".into()),
                device: None,
                tag: Some("eta".into())
            }
        );
        assert_eq!(k.tag_filter("gw/demo/drive/**"), TagFilter::default());
        assert_eq!(k.tag_filter("gw/*/drive/atv/eta"), TagFilter::default());
        assert_eq!(k.tag_filter("**"), TagFilter::default());
        assert_eq!(
            k.tag_filter("gw/demo/dr$*/atv/eta"),
            TagFilter {
                line: None,
                device: Some("atv".into()),
                tag: Some("eta".into())
            }
        );
    }

    #[test]
    fn wildcard_queries_intersect_tag_keys() {
        let k = keys();
        let key = k.tag("drive", "atv", "eta");
        for q in [
            "gw/demo/**",
            "gw/*/drive/*/eta",
            "**/eta",
            "gw/demo/dr$*/atv/*",
        ] {
            assert!(intersects(q, &key), "{q}");
        }
        for q in [
            "gw/demo/ksvario/**",
            "gw/demo/drive/atv/eta/set",
            "not a key//",
        ] {
            assert!(!intersects(q, &key), "{q}");
        }
    }
}
