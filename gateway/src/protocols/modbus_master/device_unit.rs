//! A polled device as a Modbus TCP unit: its registers are republished under its unit id.
//!
//! - reads of polled ranges come from the process image while the values are fresh and the device
//!   answers; a stale value or an offline device gives exception 0x0B;
//! - reads of addresses nobody polls (and ranges not read yet) go to the device on demand;
//! - writes (FC 05, 06, 15, 16, 23) and every other function go through to the device and answer
//!   with the device's answer, its exception passed through; the line updates the image of the
//!   written registers after the device confirmed the write;
//! - a full command queue gives 0x06, no answer within the deadline 0x0B.

use std::sync::Arc;

use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use proto_core::profiles::BitUpdate;

use super::command::LineClient;
use super::{AddrRange, DeviceSettings};
use crate::image::{ImageError, ProcessImage, Quality, Table};
use crate::line::status::Shared;
use crate::unit::{UnitFuture, UnitService};

/// One polled device served under its unit id; cheap to clone.
#[derive(Clone, Debug)]
pub struct DeviceUnit {
    device: Arc<DeviceSettings>,
    /// What the device's poll groups cover, for the read of every request.
    polled: Arc<Polled>,
    /// Index of the device in its line's status.
    index: usize,
    shared: Arc<Shared>,
    client: LineClient,
    image: ProcessImage,
}

/// The addresses polled in each table, as sorted intervals `start..end` that neither overlap nor
/// touch: [`DeviceSettings::is_polled`] with one binary search instead of a walk over the groups
/// for every address.
#[derive(Debug, PartialEq)]
struct Polled {
    tables: [Vec<(u32, u32)>; 4],
}

// === impl Polled ===

impl Polled {
    fn new(device: &DeviceSettings) -> Self {
        let tables = Table::ALL.map(|table| {
            let mut ranges: Vec<(u32, u32)> = device
                .groups
                .iter()
                .filter(|g| g.table == table)
                .flat_map(|g| g.ranges.iter().copied())
                .chain(
                    device
                        .scanner_ranges()
                        .into_iter()
                        .filter(|_| table == Table::HoldingRegisters),
                )
                .filter(|r| r.count > 0)
                .map(|r| (u32::from(r.start), r.end()))
                .collect();
            ranges.sort_unstable();
            let mut merged: Vec<(u32, u32)> = Vec::with_capacity(ranges.len());
            for (start, end) in ranges {
                match merged.last_mut() {
                    Some(last) if start <= last.1 => last.1 = last.1.max(end),
                    _ => merged.push((start, end)),
                }
            }
            merged
        });
        Self { tables }
    }

    /// Whether every address of `range` in `table` is polled.
    fn covers(&self, table: Table, range: AddrRange) -> bool {
        let [coils, discrete_inputs, holding_registers, input_registers] = &self.tables;
        let intervals = match table {
            Table::Coils => coils,
            Table::DiscreteInputs => discrete_inputs,
            Table::HoldingRegisters => holding_registers,
            Table::InputRegisters => input_registers,
        };
        let start = u32::from(range.start);
        // The last interval starting at or before `start`.
        let at = intervals.partition_point(|&(first, _)| first <= start);
        at.checked_sub(1)
            .and_then(|i| intervals.get(i))
            .is_some_and(|&(_, end)| range.end() <= end)
    }
}

/// How a read of polled addresses is answered: decided once ([`Source::of`]) for both ways the
/// image answers (a [`Response`] for [`UnitService::call`], bytes for
/// [`UnitService::answer_now`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Source {
    /// From the image: the values are live and the device answers.
    Image,
    /// Not from the image: ask the device (the poll was answered with an exception, or the range
    /// has not been read yet, and the device answers).
    Device,
    /// The device is offline or the value stale: exception 0x0B.
    Fail,
}

// === impl Source ===

impl Source {
    /// The one freshness decision: what the image holds for the read (its quality, or why it has
    /// none) and whether the device answers.
    fn of(found: Result<Quality, &ImageError>, online: bool) -> Self {
        match found {
            Ok(quality) if online && quality.is_live() => Self::Image,
            // The poll of this range was answered with an exception: let the device answer.
            Ok(Quality::Rejected) if online => Self::Device,
            // Polled but not read yet: ask the device unless it is known to be offline.
            Err(ImageError::Missing { .. } | ImageError::UnknownUnit(_)) if online => Self::Device,
            Ok(_) | Err(_) => Self::Fail,
        }
    }
}

/// How a read is answered.
#[derive(Debug, PartialEq)]
enum ImageAnswer {
    /// From the image.
    Answer(Response),
    /// Not from the image: ask the device.
    OnDemand,
    /// The device is offline or the value stale.
    Fail(ExceptionCode),
}

// === impl DeviceUnit ===

impl DeviceUnit {
    pub(crate) fn new(
        device: Arc<DeviceSettings>,
        index: usize,
        shared: Arc<Shared>,
        client: LineClient,
        image: ProcessImage,
    ) -> Self {
        Self {
            polled: Arc::new(Polled::new(&device)),
            device,
            index,
            shared,
            client,
            image,
        }
    }

    /// The device's settings.
    pub fn device(&self) -> &DeviceSettings {
        &self.device
    }

    /// The unit id it is served under.
    pub fn unit_id(&self) -> u8 {
        self.device.unit_id
    }

    /// The table and range of a read of polled addresses; `None` for anything else (it goes to
    /// the device).
    fn polled_read(&self, request: &Request) -> Option<(Table, u16, u16)> {
        let (table, address, quantity) = request.read_range()?;
        (quantity > 0 && self.polled.covers(table, AddrRange::new(address, quantity)))
            .then_some((table, address, quantity))
    }

    fn answer_from_image(&self, request: &Request) -> ImageAnswer {
        let Some((table, address, quantity)) = self.polled_read(request) else {
            return ImageAnswer::OnDemand;
        };
        let unit = self.device.unit_id;
        let online = self.shared.device_online(self.index);
        let read = if table.is_bits() {
            self.image
                .read_bits(unit, table, address, quantity)
                .map(|r| {
                    let quality = r.quality;
                    let response = match table {
                        Table::Coils => Response::ReadCoils(r.values),
                        _ => Response::ReadDiscreteInputs(r.values),
                    };
                    (response, quality)
                })
        } else {
            self.image
                .read_words(unit, table, address, quantity)
                .map(|r| {
                    let quality = r.quality;
                    let response = match table {
                        Table::HoldingRegisters => Response::ReadHoldingRegisters(r.values),
                        _ => Response::ReadInputRegisters(r.values),
                    };
                    (response, quality)
                })
        };
        match (Source::of(read.as_ref().map(|r| r.1), online), read) {
            (Source::Image, Ok((response, _))) => ImageAnswer::Answer(response),
            (Source::Device, _) => ImageAnswer::OnDemand,
            (Source::Image | Source::Fail, _) => {
                ImageAnswer::Fail(ExceptionCode::GatewayTargetFailedToRespond)
            }
        }
    }
}

impl UnitService for DeviceUnit {
    /// A read of polled addresses encoded straight from the image, with the same answers as
    /// [`Self::call`]: the values while live and the device online, 0x0B when stale or offline;
    /// `None` (the device answers) when the poll was refused or has not been read yet, and for
    /// everything that is not such a read.
    fn answer_now(
        &self,
        request: &Request,
        out: &mut Vec<u8>,
    ) -> Option<Result<(), ExceptionCode>> {
        let (table, address, quantity) = self.polled_read(request)?;
        let online = self.shared.device_online(self.index);
        let mark = out.len();
        out.push(request.function().0);
        let found = self
            .image
            .encode_read(self.device.unit_id, table, address, quantity, out);
        let answer = match found {
            // Past the address space or the byte count of one answer: `call` decides.
            Err(ImageError::InvalidRange { .. }) => None,
            found => match Source::of(found.as_ref().copied(), online) {
                Source::Image => return Some(Ok(())),
                Source::Device => None,
                Source::Fail => Some(Err(ExceptionCode::GatewayTargetFailedToRespond)),
            },
        };
        out.truncate(mark);
        answer
    }

    fn mask_write(&self, update: BitUpdate) -> UnitFuture {
        let client = self.client.clone();
        let slave = self.device.slave;
        Box::pin(async move { client.mask_write(slave, update).await })
    }

    fn call(&self, request: Request) -> UnitFuture {
        match self.answer_from_image(&request) {
            ImageAnswer::Answer(response) => Box::pin(std::future::ready(Ok(response))),
            ImageAnswer::Fail(code) => Box::pin(std::future::ready(Err(code))),
            ImageAnswer::OnDemand => {
                let client = self.client.clone();
                let slave = self.device.slave;
                Box::pin(async move { client.request(slave, request).await })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::protocols::PollGroup;

    #[test]
    fn polled_intervals_answer_as_the_poll_groups_do() {
        let group = |ms, table, ranges: &[(u16, u16)]| PollGroup {
            period: Duration::from_millis(ms),
            table,
            ranges: ranges.iter().map(|&(s, c)| AddrRange::new(s, c)).collect(),
        };
        let mut device = DeviceSettings::new("d", 1, 1);
        device.groups = vec![
            group(100, Table::HoldingRegisters, &[(0, 10), (10, 10), (30, 5)]),
            group(500, Table::HoldingRegisters, &[(32, 8), (100, 100)]),
            group(100, Table::InputRegisters, &[(5, 1)]),
            group(100, Table::Coils, &[(65_500, 36)]),
        ];
        let polled = Polled::new(&device);
        for table in Table::ALL {
            for start in (0..=210).chain(65_490..=65_535) {
                for count in [1, 2, 5, 10, 20, 36, 125] {
                    let range = AddrRange::new(start, count);
                    assert_eq!(
                        polled.covers(table, range),
                        device.is_polled(table, range),
                        "{table} {start}+{count}"
                    );
                }
            }
        }
    }
}
