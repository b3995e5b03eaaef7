//! The Altivar 61/71 communication scanner on a Modbus master line: one FC 23 exchange per cycle
//! that writes the scanner's output words NC1..NCn and reads its input words NM1..NMm (002
//! "Kommunikationsscanner": the drive copies up to eight scattered parameters into NM1..NM8,
//! W12741..W12748, and NC1..NC8, W12761..W12768, writes through to the words NCA1..NCA8 name;
//! "Mit der Funktion 23 ... ist auch die Durchführung nur eines Vorgangs möglich").
//!
//! The output words written each cycle are the image's holding registers at NC1..NCn: what
//! SCADA, REST or zenoh wrote there (a write goes to the drive at once as a command, and the
//! confirmed value refreshes the image, so the next exchange carries it again). Before the first
//! exchange, and again whenever the device came back or the port was reopened, the output words
//! are read from the drive with one FC 03 ("priming"): the first exchange writes what the drive
//! already holds, never zeros over CMD (NC1's factory assignment, 002). The input words land in
//! the image like a poll (quality, age), and the exchange is counted under function 23.
//!
//! The schedule is the adapter's, beside the poll scheduler: a due exchange goes before the polls,
//! but never twice in a row while another job waits.

use std::time::Duration;

use proto_core::modbus::pdu::{FunctionCode, Request, Response};
use proto_core::profiles::altivar::{NC, NM};
use tokio::time::Instant;

use super::{AddrRange, DeviceSettings};
use crate::image::{ProcessImage, Table};

/// The scanner words one device exchanges each cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScannerSettings {
    /// Input words read: NM1..NM`inputs` (1..8).
    pub inputs: u16,
    /// Output words written: NC1..NC`outputs` (1..8; FC 23 writes at least one word).
    pub outputs: u16,
    /// One exchange every `period`.
    pub period: Duration,
}

/// The most scanner words in each direction (002: NM1..NM8, NC1..NC8).
pub const SCANNER_WORDS: u16 = 8;

// === impl ScannerSettings ===

impl ScannerSettings {
    /// The input words NM1.. read each cycle.
    pub fn input_range(&self) -> AddrRange {
        AddrRange::new(NM[0], self.inputs)
    }

    /// The output words NC1.. written each cycle.
    pub fn output_range(&self) -> AddrRange {
        AddrRange::new(NC[0], self.outputs)
    }

    /// What is wrong with the settings of device `name` (empty: valid).
    pub fn validate(&self, name: &str) -> Vec<String> {
        let mut issues = Vec::new();
        for (what, n) in [("inputs", self.inputs), ("outputs", self.outputs)] {
            if !(1..=SCANNER_WORDS).contains(&n) {
                issues.push(format!(
                    "device {name}: scanner {what} {n} is outside 1..{SCANNER_WORDS}"
                ));
            }
        }
        if self.period.is_zero() {
            issues.push(format!("device {name}: scanner period is zero"));
        }
        issues
    }
}

/// Which request of the scanner is in flight.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ScanStep {
    /// FC 03 of the output words: what the drive holds, before the first exchange.
    Prime,
    /// FC 23: the output words written, the input words read.
    Exchange,
}

// === impl ScanStep ===

impl ScanStep {
    /// The function code of the request (the function its metrics count under).
    pub(crate) fn function(self) -> FunctionCode {
        match self {
            Self::Prime => FunctionCode::READ_HOLDING_REGISTERS,
            Self::Exchange => FunctionCode::READ_WRITE_MULTIPLE_REGISTERS,
        }
    }
}

/// One scanner request of one device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ScanJob {
    /// Index of the device.
    pub(crate) device: usize,
    /// Which request.
    pub(crate) step: ScanStep,
}

#[derive(Debug)]
struct ScanState {
    settings: ScannerSettings,
    unit: u8,
    next_due: Instant,
    /// The output words were read from the drive since it (last) came back.
    primed: bool,
}

/// The scanners of a line's devices.
#[derive(Debug)]
pub(crate) struct Scanners {
    devices: Vec<Option<ScanState>>,
    /// The last job started was a scanner's: the next turn goes to the other jobs first.
    last_was_scan: bool,
}

// === impl Scanners ===

impl Scanners {
    /// Every configured scanner due at `now`, none primed.
    pub(crate) fn new<'a>(
        devices: impl IntoIterator<Item = &'a DeviceSettings>,
        now: Instant,
    ) -> Self {
        let devices = devices
            .into_iter()
            .map(|d| {
                d.scanner.map(|settings| ScanState {
                    settings,
                    unit: d.unit_id,
                    next_due: now,
                    primed: false,
                })
            })
            .collect();
        Self {
            devices,
            last_was_scan: false,
        }
    }

    /// Whether the scanner should yield this turn to the other jobs (it just had one).
    pub(crate) fn yields(&self) -> bool {
        self.last_was_scan
    }

    /// Records whether the job just started was a scanner's.
    pub(crate) fn started(&mut self, scan: bool) {
        self.last_was_scan = scan;
    }

    /// The scanner job due longest at `now` among the devices `online` accepts. A due scanner
    /// of a device not accepted now (offline, its back-off running) skips this cycle, so that the
    /// line does not wake for it again before its next period.
    pub(crate) fn next_job(
        &mut self,
        now: Instant,
        mut online: impl FnMut(usize) -> bool,
    ) -> Option<ScanJob> {
        for (i, s) in self.devices.iter_mut().enumerate() {
            if let Some(s) = s.as_mut().filter(|s| s.next_due <= now) {
                if !online(i) {
                    s.next_due = now + s.settings.period;
                }
            }
        }
        self.devices
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.as_ref().map(|s| (i, s)))
            .filter(|(_, s)| s.next_due <= now)
            .min_by_key(|(_, s)| s.next_due)
            .map(|(device, s)| ScanJob {
                device,
                step: if s.primed {
                    ScanStep::Exchange
                } else {
                    ScanStep::Prime
                },
            })
    }

    /// When the next exchange falls due (`None`: no scanner).
    pub(crate) fn next_wake(&self) -> Option<Instant> {
        self.devices.iter().flatten().map(|s| s.next_due).min()
    }

    /// The request of `job`: FC 03 of the output words to prime, or FC 23 writing the image's
    /// output words; `None` when the device has no scanner. An exchange whose output words are
    /// not in the image (cannot happen after priming) primes instead.
    pub(crate) fn request(&mut self, job: &mut ScanJob, image: &ProcessImage) -> Option<Request> {
        let s = self.devices.get(job.device)?.as_ref()?;
        let out = s.settings.output_range();
        let input = s.settings.input_range();
        if job.step == ScanStep::Exchange {
            if let Ok(read) =
                image.read_words(s.unit, Table::HoldingRegisters, out.start, out.count)
            {
                return Some(Request::ReadWriteMultipleRegisters {
                    read_address: input.start,
                    read_quantity: input.count,
                    write_address: out.start,
                    values: read.values,
                });
            }
            job.step = ScanStep::Prime;
        }
        Some(Request::ReadHoldingRegisters {
            address: out.start,
            quantity: out.count,
        })
    }

    /// The end of `job` at `now`: with `response` (the device answered normally) its words go to
    /// the image and a prime counts as done; the next exchange is due one period after this one
    /// was, or now if the line has fallen behind. Returns false when the answer did not fit.
    pub(crate) fn done(
        &mut self,
        job: ScanJob,
        request: &Request,
        response: Option<Response>,
        image: &ProcessImage,
        now: Instant,
    ) -> bool {
        let Some(s) = self.devices.get_mut(job.device).and_then(Option::as_mut) else {
            return false;
        };
        let period = Some(s.settings.period);
        let stored = match (job.step, request, response) {
            (ScanStep::Prime, _, Some(Response::ReadHoldingRegisters(words)))
                if words.len() >= usize::from(s.settings.outputs) =>
            {
                let out = s.settings.output_range();
                let words = words.get(..usize::from(out.count)).unwrap_or(&words);
                image.store_words(s.unit, Table::HoldingRegisters, out.start, words, period);
                s.primed = true;
                // The exchange follows at once: the prime is not a cycle of its own.
                return true;
            }
            (
                ScanStep::Exchange,
                Request::ReadWriteMultipleRegisters {
                    read_address,
                    write_address,
                    values,
                    ..
                },
                Some(Response::ReadWriteMultipleRegisters(words)),
            ) if words.len() >= usize::from(s.settings.inputs) => {
                let words = words
                    .get(..usize::from(s.settings.inputs))
                    .unwrap_or(&words);
                // The drive confirmed the output words: they are as fresh as the input words.
                image.store_words(
                    s.unit,
                    Table::HoldingRegisters,
                    *write_address,
                    values,
                    period,
                );
                image.store_words(
                    s.unit,
                    Table::HoldingRegisters,
                    *read_address,
                    words,
                    period,
                );
                true
            }
            _ => false,
        };
        s.next_due = (s.next_due + s.settings.period).max(now);
        stored
    }

    /// A request of `job` that was not sent or not answered normally: the next try one period
    /// after this one was due (or now if the line has fallen behind).
    pub(crate) fn postpone(&mut self, job: ScanJob, now: Instant) {
        if let Some(Some(s)) = self.devices.get_mut(job.device) {
            s.next_due = (s.next_due + s.settings.period).max(now);
        }
    }

    /// The output words must be read from the drive again before the next exchange (the device
    /// was offline or the port was reopened: the drive may hold other values now).
    pub(crate) fn unprime(&mut self, device: usize) {
        if let Some(Some(s)) = self.devices.get_mut(device) {
            s.primed = false;
        }
    }

    /// [`Self::unprime`] for every device.
    pub(crate) fn unprime_all(&mut self) {
        for s in self.devices.iter_mut().flatten() {
            s.primed = false;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drive(scanner: Option<ScannerSettings>) -> DeviceSettings {
        let mut d = DeviceSettings::new("atv", 2, 2);
        d.scanner = scanner;
        d
    }

    const SCAN: ScannerSettings = ScannerSettings {
        inputs: 2,
        outputs: 2,
        period: Duration::from_millis(100),
    };

    #[test]
    fn primes_with_fc03_then_exchanges_the_image_values_with_fc23() {
        let now = Instant::now();
        let image = ProcessImage::default();
        let devices = [drive(None), drive(Some(SCAN))];
        let mut scanners = Scanners::new(&devices, now);
        let mut job = scanners.next_job(now, |_| true).expect("due");
        assert_eq!(
            job,
            ScanJob {
                device: 1,
                step: ScanStep::Prime
            }
        );
        let request = scanners.request(&mut job, &image).expect("request");
        assert_eq!(
            request,
            Request::ReadHoldingRegisters {
                address: 12761,
                quantity: 2
            }
        );
        // The drive holds CMD = 000Fh, LFRD = 1388h: the exchange writes them back, not zeros.
        let response = Response::ReadHoldingRegisters(vec![0x000F, 0x1388]);
        assert!(scanners.done(job, &request, Some(response), &image, now));
        let mut job = scanners.next_job(now, |_| true).expect("due at once");
        assert_eq!(job.step, ScanStep::Exchange);
        let request = scanners.request(&mut job, &image).expect("request");
        assert_eq!(
            request,
            Request::ReadWriteMultipleRegisters {
                read_address: 12741,
                read_quantity: 2,
                write_address: 12761,
                values: vec![0x000F, 0x1388],
            }
        );
        let response = Response::ReadWriteMultipleRegisters(vec![0x0637, 0x1388]);
        assert!(scanners.done(job, &request, Some(response), &image, now));
        assert_eq!(
            image
                .read_words(2, Table::HoldingRegisters, 12741, 2)
                .map(|r| r.values),
            Ok(vec![0x0637, 0x1388])
        );
        // Next cycle one period later; after the device was away it primes again.
        assert_eq!(scanners.next_job(now, |_| true), None);
        assert_eq!(scanners.next_wake(), Some(now + SCAN.period));
        scanners.unprime(1);
        let later = now + SCAN.period;
        assert_eq!(
            scanners.next_job(later, |_| true).map(|j| j.step),
            Some(ScanStep::Prime)
        );
    }

    #[test]
    fn an_offline_device_skips_its_cycles_instead_of_waking_the_line() {
        let now = Instant::now();
        let devices = [drive(Some(SCAN))];
        let mut scanners = Scanners::new(&devices, now);
        assert_eq!(scanners.next_job(now, |_| false), None);
        assert_eq!(scanners.next_wake(), Some(now + SCAN.period));
        let later = now + SCAN.period;
        assert_eq!(
            scanners.next_job(later, |_| true).map(|j| j.step),
            Some(ScanStep::Prime)
        );
    }

    #[test]
    fn a_short_answer_is_not_taken() {
        let now = Instant::now();
        let image = ProcessImage::default();
        let devices = [drive(Some(SCAN))];
        let mut scanners = Scanners::new(&devices, now);
        let mut job = scanners.next_job(now, |_| true).expect("due");
        let request = scanners.request(&mut job, &image).expect("request");
        let response = Response::ReadHoldingRegisters(vec![0x000F]);
        assert!(!scanners.done(job, &request, Some(response), &image, now));
        assert!(image
            .read_words(2, Table::HoldingRegisters, 12761, 2)
            .is_err());
        assert_eq!(
            scanners
                .next_job(now + SCAN.period, |_| true)
                .map(|j| j.step),
            Some(ScanStep::Prime)
        );
    }

    #[test]
    fn settings_outside_the_scanner_are_refused() {
        let bad = ScannerSettings {
            inputs: 0,
            outputs: 9,
            period: Duration::ZERO,
        };
        assert_eq!(bad.validate("atv").len(), 3);
        assert!(SCAN.validate("atv").is_empty());
    }
}
