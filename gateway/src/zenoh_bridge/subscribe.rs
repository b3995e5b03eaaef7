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
//! The bridge checks the shape of a command in its callback, cheapest first: its key, its size
//! (`[zenoh] max_payload`, before the payload is copied), whether writes are on (the backend
//! says), its payload; then the line (in the dispatcher). The backend sends the telegram or
//! writes the tag on the same path and with the same checks as a Modbus TCP write, and its answer
//! (or refusal) becomes the result. Every refusal, wherever it happens, is counted and audited
//! through [`super::accounting`] and answered on the result key; nothing here logs at WARN per
//! command (a full queue warns through the rate limiter).
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
use zenoh::bytes::ZBytes;
use zenoh::query::Query;
use zenoh::sample::Sample;
use zenoh::Wait;

use super::accounting::{self, WriteReason};
use super::keys::Keys;
use super::metrics::{BridgeStats, CommandKind, CommandOutcome, PublicationKind};
use super::publish::{Message, Outbox};
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

    /// What the command asks for, as the audit names it: `<line>/tx (<n> bytes)`,
    /// `<line>/<device>/<tag> = <value>` (without the value when there is none).
    fn target(&self) -> String {
        match &self.op {
            Op::Tx(bytes) => format!("{}/tx ({} bytes)", self.line, bytes.len()),
            Op::Set { device, tag, value } if value.is_null() => {
                format!("{}/{device}/{tag}", self.line)
            }
            Op::Set { device, tag, value } => format!("{}/{device}/{tag} = {value}", self.line),
            Op::Ack(0) => format!("{}/ack", self.line),
            Op::Ack(seq) => format!("{}/telegrams/{seq} ack", self.line),
        }
    }
}

/// A command's key, before its payload is looked at: `Op::Tx` with no bytes yet, `Op::Set`
/// with a null value.
fn parse_key(keys: &Keys, key: &str) -> Option<(String, Op)> {
    if let Some(line) = keys.parse_tx(key) {
        return Some((line, Op::Tx(Vec::new())));
    }
    if let Some(line) = keys.parse_ack(key) {
        return Some((line, Op::Ack(0)));
    }
    let (line, device, tag) = keys.parse_set(key)?;
    Some((
        line,
        Op::Set {
            device,
            tag,
            value: Value::Null,
        },
    ))
}

/// Fills the command's payload in: the telegram's bytes, or the JSON value to write; else why
/// the payload does not do.
fn parse_payload(op: &mut Op, payload: Option<&ZBytes>) -> Result<(), String> {
    match op {
        Op::Tx(bytes) => {
            *bytes = payload
                .map(|p| p.to_bytes().into_owned())
                .unwrap_or_default();
            if bytes.is_empty() {
                return Err("empty telegram".to_owned());
            }
        }
        Op::Set { value, .. } => {
            let payload = payload.ok_or_else(|| "no value".to_owned())?;
            *value = serde_json::from_slice::<Value>(&payload.to_bytes())
                .map_err(|e| format!("payload is not a JSON value: {e}"))?;
        }
        Op::Ack(seq) => {
            // The sequence number as text ("17"), as the Modbus register and the REST path
            // take it.
            *seq = payload
                .map(ZBytes::to_bytes)
                .and_then(|p| std::str::from_utf8(&p).ok().map(str::to_owned))
                .and_then(|t| t.trim().parse::<u16>().ok())
                .filter(|&seq| seq != 0)
                .ok_or_else(|| {
                    "payload is not a sequence number 1..65535 (send it as text, e.g. \"17\")"
                        .to_owned()
                })?;
        }
    }
    Ok(())
}

/// Where commands go: shared by the zenoh callbacks, the dispatcher and the line workers.
pub(crate) struct Commands {
    keys: Arc<Keys>,
    outbox: Arc<Outbox>,
    stats: Arc<BridgeStats>,
    queue: mpsc::Sender<Command>,
    per_line: usize,
    /// The largest payload taken (`[zenoh] max_payload`).
    max_payload: usize,
    /// Asked whether writes are on before a command is queued, so that a flood of refused
    /// commands never fills the queue.
    backend: Arc<dyn BridgeBackend>,
    /// The gateway's runtime: replies are sent from its blocking pool (callbacks run on zenoh's
    /// threads, which have no runtime of ours).
    runtime: tokio::runtime::Handle,
}

/// How the command entry is set up.
pub(crate) struct CommandsConfig {
    /// Commands waiting, in total and per line.
    pub(crate) capacity: usize,
    /// The largest payload taken.
    pub(crate) max_payload: usize,
}

// === impl Commands ===

impl Commands {
    /// The command entry and the receiving end for [`dispatch`].
    pub(crate) fn new(
        keys: Arc<Keys>,
        outbox: Arc<Outbox>,
        stats: Arc<BridgeStats>,
        backend: Arc<dyn BridgeBackend>,
        config: &CommandsConfig,
        runtime: tokio::runtime::Handle,
    ) -> (Arc<Self>, mpsc::Receiver<Command>) {
        let (queue, rx) = mpsc::channel(config.capacity);
        let this = Self {
            keys,
            outbox,
            stats,
            queue,
            per_line: config.capacity,
            max_payload: config.max_payload,
            backend,
            runtime,
        };
        (Arc::new(this), rx)
    }

    /// The subscriber callback: check, then queue without waiting.
    pub(crate) fn on_sample(&self, sample: &Sample) {
        let attachment = sample.attachment().map(|a| a.to_bytes().into_owned());
        self.take(
            sample.key_expr().as_str(),
            Some(sample.payload()),
            attachment,
            None,
        );
    }

    /// The queryable callback: as a sample, but the result is also the reply. Queries that do
    /// not name one line (wildcards) are not commands and get no reply.
    pub(crate) fn on_query(&self, query: Query) {
        let key = query.key_expr().as_str().to_owned();
        let payload = query.payload().cloned();
        let attachment = query.attachment().map(|a| a.to_bytes().into_owned());
        self.take(&key, payload.as_ref(), attachment, Some(query));
    }

    /// Checks a command in the order that costs least under a flood: its key, its size (before
    /// the payload is copied), whether writes are on, its payload; then queues it. Each refusal
    /// goes through [`Self::refuse`].
    fn take(
        &self,
        key: &str,
        payload: Option<&ZBytes>,
        attachment: Option<Vec<u8>>,
        query: Option<Query>,
    ) {
        let Some((line, op)) = parse_key(&self.keys, key) else {
            return;
        };
        let mut cmd = Command {
            line,
            op,
            attachment,
            query,
        };
        let len = payload.map_or(0, ZBytes::len);
        if len > self.max_payload {
            let error = format!(
                "payload of {len} bytes is larger than [zenoh] max_payload = {}",
                self.max_payload
            );
            return self.refuse(cmd, WriteReason::TooLarge, error);
        }
        if let Err(error) = self.backend.writes_allowed() {
            return self.refuse(cmd, WriteReason::WritesOff, error);
        }
        if let Err(error) = parse_payload(&mut cmd.op, payload) {
            return self.refuse(cmd, WriteReason::BadPayload, error);
        }
        if let Err(e) = self.queue.try_send(cmd) {
            let cmd = match e {
                mpsc::error::TrySendError::Full(c) | mpsc::error::TrySendError::Closed(c) => c,
            };
            self.busy(cmd);
        }
    }

    /// A command that found its queue full: answered `busy`.
    fn busy(&self, cmd: Command) {
        self.stats
            .dropped(super::metrics::DropReason::CommandQueueFull);
        crate::warn_limited!(
            "zenoh command queue full",
            "zenoh command queue full, commands answered busy"
        );
        self.refuse(
            cmd,
            WriteReason::QueueFull,
            "busy: command queue full".to_owned(),
        );
    }

    /// Refuses `cmd`: counted and audited ([`accounting::refused`]), answered on its result key
    /// (and to its query) with `error`. Every command the bridge itself refuses ends here.
    pub(crate) fn refuse(&self, cmd: Command, reason: WriteReason, error: String) {
        accounting::refused(self.stats.audit(), &cmd.target(), reason, &error);
        let outcome = if reason == WriteReason::QueueFull {
            CommandOutcome::Busy
        } else {
            CommandOutcome::Rejected
        };
        self.finish(cmd, outcome, Err(error));
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
                    commands.refuse(cmd, WriteReason::UnknownTarget, error);
                    continue;
                }
                let (tx, wrx) = mpsc::channel(commands.per_line);
                crate::task::spawn(
                    "zenoh line worker",
                    line_worker(commands.clone(), wrx, backend.clone(), shutdown.clone()),
                );
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

    fn command(key: &str, payload: &[u8]) -> Result<(String, Op), String> {
        let (line, mut op) = parse_key(&keys(), key).expect("a command key");
        parse_payload(&mut op, Some(&ZBytes::from(payload.to_vec()))).map(|()| (line, op))
    }

    #[test]
    fn tx_needs_bytes() {
        let (line, op) = command("gw/demo/r3964/tx", &[1, 2]).unwrap();
        assert_eq!(line, "r3964");
        assert!(matches!(op, Op::Tx(ref b) if b == &[1, 2]));
        assert_eq!(
            command("gw/demo/r3964/tx", &[]).unwrap_err(),
            "empty telegram"
        );
        let (line, mut op) = parse_key(&keys(), "gw/demo/r3964/tx").unwrap();
        assert!(parse_payload(&mut op, None).is_err());
        let cmd = Command {
            line,
            op: Op::Tx(vec![0; 5]),
            attachment: None,
            query: None,
        };
        assert_eq!(cmd.target(), "r3964/tx (5 bytes)");
    }

    #[test]
    fn set_needs_a_json_value() {
        let (line, op) = command("gw/demo/drive/atv/cmd/set", b"15").unwrap();
        assert!(matches!(op, Op::Set { ref value, .. } if value == &json!(15)));
        let cmd = Command {
            line,
            op,
            attachment: None,
            query: None,
        };
        assert_eq!(cmd.target(), "drive/atv/cmd = 15");
        for bad in [&b"on"[..], b"", b"\xff"] {
            let error = command("gw/demo/drive/atv/cmd/set", bad).unwrap_err();
            assert!(error.starts_with("payload is not a JSON value"), "{error}");
        }
        let (line, op) = parse_key(&keys(), "gw/demo/drive/atv/cmd/set").unwrap();
        let cmd = Command {
            line,
            op,
            attachment: None,
            query: None,
        };
        assert_eq!(cmd.target(), "drive/atv/cmd", "no value yet");
    }

    #[test]
    fn ack_needs_a_sequence_number() {
        let (line, op) = command("gw/demo/r3964/ack", b" 17\n").unwrap();
        assert_eq!(line, "r3964");
        assert!(matches!(op, Op::Ack(17)));
        for bad in [&b"0"[..], b"", b"65536", b"x", b"\xff"] {
            let error = command("gw/demo/r3964/ack", bad).unwrap_err();
            assert!(
                error.starts_with("payload is not a sequence number"),
                "{error}"
            );
        }
    }

    #[test]
    fn other_keys_are_not_commands() {
        for key in ["gw/demo/*/tx", "gw/demo/**", "gw/demo/drive/atv/cmd", "x/y"] {
            assert!(parse_key(&keys(), key).is_none(), "{key}");
        }
    }
}
