//! Commands from the fabric: telegrams to send (`<line>/tx`) and tag writes
//! (`<line>/<device>/<tag>/set`), as puts (subscriptions) or as queries with a payload.
//!
//! ```text
//! zenoh callback --parse, try_send--> command queue --dispatcher--> one worker per line
//!   (never waits; a full queue            (bounded)      (known lines     (in order: the
//!    is answered "busy")                                  only)            backend's future)
//!                                                                            |
//!                 <line>/tx/result, <line>/<device>/<tag>/set/result  <------+  (+ the reply
//!                                                                               of a query)
//! ```
//!
//! The bridge checks only the shape of a command (key, payload). The backend sends the telegram
//! or writes the tag on the same path and with the same checks as a Modbus TCP write, and its
//! answer (or refusal) becomes the result.
//!
//! Result payload (JSON): `{"ok": true, "line": .., "len": N, "result": <backend>}` for a send,
//! `{"ok": true, "line": .., "device": .., "tag": .., "value": <requested>, "result": <backend>}`
//! for a write, with `"ok": false` and `"error": "<text>"` instead of `result` on failure. The
//! attachment of the command, if any, is copied to its result, to correlate the two.

use std::collections::HashMap;
use std::sync::Arc;

use serde_json::{json, Value};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;
use zenoh::query::Query;
use zenoh::sample::Sample;
use zenoh::Wait;

use super::keys::Keys;
use super::publish::{Message, Outbox};
use super::stats::{BridgeStats, CommandKind, CommandOutcome, PublicationKind};
use super::BridgeBackend;

/// What a command asks for.
#[derive(Debug)]
pub(crate) enum Op {
    /// Send these bytes as one telegram.
    Tx(Vec<u8>),
    /// Write this value to a tag.
    Set {
        device: String,
        tag: String,
        value: Value,
    },
    /// Acknowledge the received telegram with this sequence number.
    Ack(u16),
}

/// One command, from a put or a query.
pub(crate) struct Command {
    line: String,
    op: Op,
    attachment: Option<Vec<u8>>,
    /// The query to reply to, when the command came as a query.
    query: Option<Query>,
}

impl Command {
    fn kind(&self) -> CommandKind {
        match self.op {
            Op::Tx(_) => CommandKind::Tx,
            Op::Set { .. } => CommandKind::Set,
            Op::Ack(_) => CommandKind::Ack,
        }
    }
}

/// A key that is ours but not usable as a command: answered on the result key if it names a
/// line (and tag), otherwise only logged.
#[derive(Debug)]
enum Parsed {
    Command(Command),
    Rejected(Command, String),
    NotACommand,
}

/// Parses a command from its key, payload and attachment. `query` is kept for the reply.
fn parse(
    keys: &Keys,
    key: &str,
    payload: Option<Vec<u8>>,
    attachment: Option<Vec<u8>>,
    query: Option<Query>,
) -> Parsed {
    if let Some(line) = keys.parse_tx(key) {
        let bytes = payload.unwrap_or_default();
        let cmd = Command {
            line,
            op: Op::Tx(Vec::new()),
            attachment,
            query,
        };
        if bytes.is_empty() {
            return Parsed::Rejected(cmd, "empty telegram".to_owned());
        }
        return Parsed::Command(Command {
            op: Op::Tx(bytes),
            ..cmd
        });
    }
    if let Some(line) = keys.parse_ack(key) {
        // The sequence number as text ("17"), as the Modbus register and the REST path take it.
        let seq = payload
            .as_deref()
            .and_then(|p| std::str::from_utf8(p).ok())
            .and_then(|t| t.trim().parse::<u16>().ok())
            .filter(|&seq| seq != 0);
        let cmd = Command {
            line,
            op: Op::Ack(seq.unwrap_or(0)),
            attachment,
            query,
        };
        return match seq {
            Some(_) => Parsed::Command(cmd),
            None => Parsed::Rejected(
                cmd,
                "payload is not a sequence number 1..65535 (send it as text, e.g. \"17\")"
                    .to_owned(),
            ),
        };
    }
    if let Some((line, device, tag)) = keys.parse_set(key) {
        let parsed = payload
            .as_deref()
            .ok_or_else(|| "no value".to_owned())
            .and_then(|p| serde_json::from_slice::<Value>(p).map_err(|e| e.to_string()));
        let (value, error) = match parsed {
            Ok(v) => (v, None),
            Err(e) => (
                Value::Null,
                Some(format!("payload is not a JSON value: {e}")),
            ),
        };
        let cmd = Command {
            line,
            op: Op::Set { device, tag, value },
            attachment,
            query,
        };
        return match error {
            None => Parsed::Command(cmd),
            Some(e) => Parsed::Rejected(cmd, e),
        };
    }
    Parsed::NotACommand
}

/// Where commands go: shared by the zenoh callbacks, the dispatcher and the line workers.
pub(crate) struct Commands {
    keys: Arc<Keys>,
    outbox: Arc<Outbox>,
    stats: Arc<BridgeStats>,
    queue: mpsc::Sender<Command>,
    per_line: usize,
    /// The gateway's runtime: replies are sent from its blocking pool (callbacks run on zenoh's
    /// threads, which have no runtime of ours).
    runtime: tokio::runtime::Handle,
}

// === impl Commands ===

impl Commands {
    /// The command entry and the receiving end for [`dispatch`].
    pub(crate) fn new(
        keys: Arc<Keys>,
        outbox: Arc<Outbox>,
        stats: Arc<BridgeStats>,
        capacity: usize,
        runtime: tokio::runtime::Handle,
    ) -> (Arc<Self>, mpsc::Receiver<Command>) {
        let (queue, rx) = mpsc::channel(capacity);
        let this = Self {
            keys,
            outbox,
            stats,
            queue,
            per_line: capacity,
            runtime,
        };
        (Arc::new(this), rx)
    }

    /// The subscriber callback: parse, then queue without waiting.
    pub(crate) fn on_sample(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let payload = Some(sample.payload().to_bytes().into_owned());
        let attachment = sample.attachment().map(|a| a.to_bytes().into_owned());
        self.accept(key, parse(&self.keys, key, payload, attachment, None));
    }

    /// The queryable callback: as a sample, but the result is also the reply. Queries that do
    /// not name one line (wildcards) are not commands and get no reply.
    pub(crate) fn on_query(&self, query: Query) {
        let key = query.key_expr().as_str().to_owned();
        let payload = query.payload().map(|p| p.to_bytes().into_owned());
        let attachment = query.attachment().map(|a| a.to_bytes().into_owned());
        self.accept(
            &key,
            parse(&self.keys, &key, payload, attachment, Some(query)),
        );
    }

    fn accept(&self, key: &str, parsed: Parsed) {
        match parsed {
            Parsed::Command(cmd) => {
                if let Err(e) = self.queue.try_send(cmd) {
                    let cmd = match e {
                        mpsc::error::TrySendError::Full(c)
                        | mpsc::error::TrySendError::Closed(c) => c,
                    };
                    self.busy(cmd);
                }
            }
            Parsed::Rejected(cmd, error) => {
                tracing::debug!(%key, %error, "zenoh command rejected");
                self.finish(cmd, CommandOutcome::Rejected, Err(error));
            }
            Parsed::NotACommand => {}
        }
    }

    fn busy(&self, cmd: Command) {
        self.stats
            .dropped(super::stats::DropReason::CommandQueueFull);
        tracing::warn!(line = %cmd.line, "zenoh command queue full, command answered busy");
        self.finish(
            cmd,
            CommandOutcome::Busy,
            Err("busy: command queue full".to_owned()),
        );
    }

    /// Publishes the result of `cmd` (and replies to its query).
    fn finish(&self, cmd: Command, result: CommandOutcome, outcome: Result<Value, String>) {
        let Command {
            line,
            op,
            attachment,
            query,
        } = cmd;
        let kind = match op {
            Op::Tx(_) => CommandKind::Tx,
            Op::Set { .. } => CommandKind::Set,
            Op::Ack(_) => CommandKind::Ack,
        };
        self.stats.command(kind, result);
        let mut body = match &op {
            Op::Tx(bytes) => json!({"line": line, "len": bytes.len()}),
            Op::Set { device, tag, value } => {
                json!({"line": line, "device": device, "tag": tag, "value": value})
            }
            Op::Ack(seq) => json!({"line": line, "seq": seq}),
        };
        match outcome {
            Ok(v) => {
                body["ok"] = Value::Bool(true);
                body["result"] = v;
            }
            Err(e) => {
                body["ok"] = Value::Bool(false);
                body["error"] = Value::String(e);
            }
        }
        let payload = body.to_string().into_bytes();
        let target = match &op {
            Op::Tx(_) => Some((self.keys.tx_result(&line), PublicationKind::TxResult)),
            Op::Set { device, tag, .. } => Some((
                self.keys.set_result(&line, device, tag),
                PublicationKind::SetResult,
            )),
            // No result key (`<line>/ack/result` could be a tag's key): a query gets the
            // result as its reply, a refused put is logged.
            Op::Ack(seq) => {
                if body["ok"] == Value::Bool(false) {
                    crate::warn_limited!(
                        format!("zenoh ack {line}"),
                        %line,
                        seq,
                        error = %body["error"],
                        "zenoh acknowledgement refused"
                    );
                }
                None
            }
        };
        if let Some(query) = query {
            let payload = payload.clone();
            let attachment = attachment.clone();
            // A reply may wait under congestion (it takes the query's QoS): not on a runtime
            // worker.
            self.runtime.spawn_blocking(move || {
                let key = query.key_expr().clone();
                let reply = query
                    .reply(key, payload)
                    .encoding(zenoh::bytes::Encoding::APPLICATION_JSON)
                    .attachment(attachment);
                if let Err(e) = reply.wait() {
                    tracing::debug!(error = %e, "zenoh command reply failed");
                }
            });
        }
        let Some((key, pkind)) = target else {
            return;
        };
        let _ = self.outbox.push(Message {
            kind: pkind,
            key,
            payload,
            json: true,
            attachment,
            done: None,
        });
    }
}

impl std::fmt::Debug for Command {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Command")
            .field("line", &self.line)
            .field("op", &self.op)
            .field("query", &self.query.is_some())
            .finish()
    }
}

/// Routes commands to one worker per line, creating workers for known lines only.
pub(crate) async fn dispatch(
    commands: Arc<Commands>,
    mut rx: mpsc::Receiver<Command>,
    backend: Arc<dyn BridgeBackend>,
    shutdown: CancellationToken,
) {
    let mut workers: HashMap<String, mpsc::Sender<Command>> = HashMap::new();
    loop {
        let cmd = tokio::select! {
            cmd = rx.recv() => match cmd { Some(c) => c, None => break },
            () = shutdown.cancelled() => break,
        };
        let worker = match workers.get(&cmd.line) {
            Some(w) if !w.is_closed() => w,
            _ => {
                if !backend.lines().contains(&cmd.line) {
                    let error = format!("unknown line {:?}", cmd.line);
                    commands.finish(cmd, CommandOutcome::Rejected, Err(error));
                    continue;
                }
                let (tx, wrx) = mpsc::channel(commands.per_line);
                tokio::spawn(line_worker(
                    commands.clone(),
                    wrx,
                    backend.clone(),
                    shutdown.clone(),
                ));
                workers.entry(cmd.line.clone()).insert_entry(tx).into_mut()
            }
        };
        if let Err(e) = worker.try_send(cmd) {
            let cmd = match e {
                mpsc::error::TrySendError::Full(c) | mpsc::error::TrySendError::Closed(c) => c,
            };
            commands.busy(cmd);
        }
    }
}

/// Serves the commands of one line in order.
async fn line_worker(
    commands: Arc<Commands>,
    mut rx: mpsc::Receiver<Command>,
    backend: Arc<dyn BridgeBackend>,
    shutdown: CancellationToken,
) {
    while let Some(mut cmd) = rx.recv().await {
        let fut = match &mut cmd.op {
            Op::Tx(bytes) => backend.send_telegram(&cmd.line, bytes.clone()),
            Op::Set { device, tag, value } => {
                backend.write_tag(&cmd.line, device, tag, value.clone())
            }
            Op::Ack(seq) => backend.ack_telegram(&cmd.line, *seq),
        };
        let outcome = tokio::select! {
            r = fut => r,
            () = shutdown.cancelled() => return,
        };
        let result = if outcome.is_ok() {
            CommandOutcome::Ok
        } else {
            CommandOutcome::Failed
        };
        tracing::debug!(line = %cmd.line, kind = cmd.kind().as_str(), ok = outcome.is_ok(), "zenoh command done");
        commands.finish(cmd, result, outcome);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys() -> Keys {
        Keys::new("gw/demo").unwrap()
    }

    #[test]
    fn tx_needs_bytes() {
        match parse(&keys(), "gw/demo/r3964/tx", Some(vec![1, 2]), None, None) {
            Parsed::Command(c) => {
                assert_eq!(c.line, "r3964");
                assert!(matches!(c.op, Op::Tx(ref b) if b == &[1, 2]));
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            parse(&keys(), "gw/demo/r3964/tx", Some(vec![]), None, None),
            Parsed::Rejected(..)
        ));
    }

    #[test]
    fn set_needs_a_json_value() {
        match parse(
            &keys(),
            "gw/demo/drive/atv/cmd/set",
            Some(b"15".to_vec()),
            None,
            None,
        ) {
            Parsed::Command(c) => {
                assert!(matches!(c.op, Op::Set { ref value, .. } if value == &json!(15)));
            }
            other => panic!("{other:?}"),
        }
        for bad in [&b"on"[..], b"", b"\xff"] {
            assert!(matches!(
                parse(
                    &keys(),
                    "gw/demo/drive/atv/cmd/set",
                    Some(bad.to_vec()),
                    None,
                    None
                ),
                Parsed::Rejected(..)
            ));
        }
    }

    #[test]
    fn ack_needs_a_sequence_number() {
        match parse(
            &keys(),
            "gw/demo/r3964/ack",
            Some(b" 17\n".to_vec()),
            None,
            None,
        ) {
            Parsed::Command(c) => {
                assert_eq!(c.line, "r3964");
                assert!(matches!(c.op, Op::Ack(17)));
            }
            other => panic!("{other:?}"),
        }
        for bad in [&b"0"[..], b"", b"65536", b"x", b"\xff"] {
            assert!(matches!(
                parse(&keys(), "gw/demo/r3964/ack", Some(bad.to_vec()), None, None),
                Parsed::Rejected(..)
            ));
        }
    }

    #[test]
    fn other_keys_are_not_commands() {
        for key in ["gw/demo/*/tx", "gw/demo/**", "gw/demo/drive/atv/cmd", "x/y"] {
            assert!(matches!(
                parse(&keys(), key, Some(b"1".to_vec()), None, None),
                Parsed::NotACommand
            ));
        }
    }
}
