//! What the API needs from the running gateway.
//!
//! The service implements [`ApiBackend`] over its supervisor, lines, process image and servers;
//! the tests implement it over an in-memory gateway. Methods that read a snapshot are plain
//! functions and must not block; methods that wait for a device or restart tasks return a boxed
//! future. A method answers [`ApiError`]s made by its constructors (`not_found`, `conflict`,
//! `busy`, `device_timeout`, `device_exception`), which the API sends as they are.

use std::fmt::Display;
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;

use super::auth::Caller;
use super::error::ApiError;
use super::model::{
    ApplyReport, ConfigOverride, DiagSnapshot, GatewayStatus, LineStatusView, Readiness,
    ScalarValue, SendResult, Signals, SignalsPatch, TagValue, TelegramQueue,
};
use crate::audit::{WritePath, WriteResult};
use crate::config::ConfigIssue;
use crate::plant::Config;

/// A boxed future that can move between threads.
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// The running gateway as the API sees it.
pub trait ApiBackend: Send + Sync + 'static {
    /// The configuration in force (shared: it is not copied for a reader).
    fn config(&self) -> Arc<Config>;

    /// Settings given on the command line that are in force in place of keys of the
    /// configuration (listeners), shown by `GET /config` beside it.
    fn overrides(&self) -> Vec<ConfigOverride> {
        Vec::new()
    }

    /// Checks that need the running system on a configuration the parser already accepted
    /// (e.g. a serial port that does not exist); every problem with its path. The parser's own
    /// rules have run before this is called.
    fn validate(&self, config: &Config) -> Result<(), Vec<ConfigIssue>> {
        let _ = config;
        Ok(())
    }

    /// Checks that need another part of the gateway but not the running system (e.g. whether
    /// the CP memory can serve a slave line exactly). They run with the parser's own rules on
    /// every configuration the API reads, on the config as read (a bad value replaced by its
    /// default), and their issues are answered with the parser's; `found` is what the parser
    /// found so far.
    fn config_issues(&self, config: &Config, found: &[ConfigIssue]) -> Vec<ConfigIssue> {
        let _ = (config, found);
        Vec::new()
    }

    /// Puts `config` in force, restarting only the lines, devices and servers that changed.
    /// Called one change at a time, after the configuration was validated and persisted.
    fn apply(&self, config: Arc<Config>) -> BoxFuture<'_, Result<ApplyReport, ApiError>>;

    /// The whole gateway.
    fn gateway_status(&self) -> GatewayStatus;

    /// One line; `not_found` for an unknown line.
    fn line_status(&self, line: &str) -> Result<LineStatusView, ApiError>;

    /// A line's diagnostic buffer, newest first.
    fn diag(&self, line: &str) -> Result<DiagSnapshot, ApiError>;

    /// Empties a line's diagnostic buffer.
    fn clear_diag(&self, line: &str) -> Result<(), ApiError>;

    /// A line's received telegrams waiting for acknowledgement, oldest first; `conflict` for a
    /// line without telegrams (a Modbus line).
    fn telegrams(&self, line: &str) -> Result<TelegramQueue, ApiError>;

    /// Acknowledges (removes) the oldest queued telegram, which must have sequence number `seq`:
    /// `not_found` when no queued telegram has it, `conflict` when it is not the oldest.
    fn ack_telegram(&self, line: &str, seq: u32) -> Result<(), ApiError>;

    /// Sends a telegram and waits for its outcome.
    fn send_telegram(
        &self,
        line: &str,
        data: Vec<u8>,
    ) -> BoxFuture<'_, Result<SendResult, ApiError>>;

    /// Every tag, or those of one line and/or devices of one name; `not_found` for an unknown
    /// line.
    fn tags(&self, line: Option<&str>, device: Option<&str>) -> Result<Vec<TagValue>, ApiError>;

    /// One tag (from the image, or read on demand when nobody polls it).
    fn tag(&self, line: &str, device: &str, tag: &str)
        -> BoxFuture<'_, Result<TagValue, ApiError>>;

    /// Writes one tag through to the device and answers with the value after the write;
    /// `conflict` for a tag that is not writable.
    fn write_tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: ScalarValue,
    ) -> BoxFuture<'_, Result<TagValue, ApiError>>;

    /// The RS232 signals of a line (read from the port by the line's task); `conflict` for a
    /// line without them (RS422/RS485, a pseudo-terminal).
    fn signals(&self, line: &str) -> BoxFuture<'_, Result<Signals, ApiError>>;

    /// Sets DTR and/or RTS and answers with the signals after the change.
    fn set_signals(
        &self,
        line: &str,
        patch: SignalsPatch,
    ) -> BoxFuture<'_, Result<Signals, ApiError>>;

    /// What `/readyz` checks.
    fn readiness(&self) -> Readiness;

    /// The other gateways seen on the zenoh fabric (`GET /fleet`); none without zenoh.
    fn fleet(&self) -> Vec<super::model::FleetEntry> {
        Vec::new()
    }

    /// Records one change made through the API (a tag write, a telegram send, a signal
    /// change, a configuration change, or a refused one) in the audit trail; the service
    /// counts it in its metrics too.
    fn audit(
        &self,
        caller: &Caller,
        target: &dyn Display,
        result: WriteResult,
        detail: &dyn Display,
    ) {
        crate::audit::record(None, WritePath::Rest, caller, target, result, detail);
    }

    /// A line's frame monitor; `not_found` for an unknown line, `conflict` when its monitor is
    /// off.
    fn monitor(&self, line: &str) -> Result<Arc<crate::line::FrameMonitor>, ApiError> {
        Err(ApiError::not_found("line", line))
    }
}
