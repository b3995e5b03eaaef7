//! What a command's answer does besides going back to the requester: the image refresh after a
//! write the device confirmed (or an on-demand read), and the echo for a broadcast write.

use proto_core::modbus::pdu::{Request, Response};

use crate::image::{ProcessImage, Table};

/// Updates the image after the device confirmed a write (or answered an on-demand read): only
/// values already in the image are refreshed.
pub(crate) fn refresh_image(
    image: &ProcessImage,
    unit: u8,
    request: &Request,
    response: &Response,
) {
    match (request, response) {
        (Request::WriteSingleRegister { address, value }, _) => {
            image.refresh_words(unit, Table::HoldingRegisters, *address, &[*value]);
        }
        (Request::WriteMultipleRegisters { address, values }, _) => {
            image.refresh_words(unit, Table::HoldingRegisters, *address, values);
        }
        (Request::WriteSingleCoil { address, value }, _) => {
            image.refresh_bits(unit, Table::Coils, *address, &[*value])
        }
        (Request::WriteMultipleCoils { address, values }, _) => {
            image.refresh_bits(unit, Table::Coils, *address, values)
        }
        (
            Request::ReadWriteMultipleRegisters {
                read_address,
                write_address,
                values,
                ..
            },
            Response::ReadWriteMultipleRegisters(read),
        ) => {
            // FC 23 writes before it reads (Modbus spec 6.17): the read part is the newer value.
            image.refresh_words(unit, Table::HoldingRegisters, *write_address, values);
            image.refresh_words(unit, Table::HoldingRegisters, *read_address, read);
        }
        (Request::ReadHoldingRegisters { address, .. }, Response::ReadHoldingRegisters(words)) => {
            image.refresh_words(unit, Table::HoldingRegisters, *address, words);
        }
        (Request::ReadInputRegisters { address, .. }, Response::ReadInputRegisters(words)) => {
            image.refresh_words(unit, Table::InputRegisters, *address, words);
        }
        (Request::ReadCoils { address, quantity }, Response::ReadCoils(bits)) => {
            image.refresh_bits(
                unit,
                Table::Coils,
                *address,
                bits.get(..usize::from(*quantity)).unwrap_or(bits),
            );
        }
        (Request::ReadDiscreteInputs { address, quantity }, Response::ReadDiscreteInputs(bits)) => {
            image.refresh_bits(
                unit,
                Table::DiscreteInputs,
                *address,
                bits.get(..usize::from(*quantity)).unwrap_or(bits),
            );
        }
        _ => {}
    }
}

/// The answer a client gets for a broadcast write, which no device answers (003 6.4.3 "ADDR"):
/// the echo a device would have sent.
pub(crate) fn broadcast_echo(request: &Request) -> Option<Response> {
    match request {
        Request::WriteSingleCoil { address, value } => Some(Response::WriteSingleCoil {
            address: *address,
            value: *value,
        }),
        Request::WriteSingleRegister { address, value } => Some(Response::WriteSingleRegister {
            address: *address,
            value: *value,
        }),
        Request::WriteMultipleCoils { address, values } => Some(Response::WriteMultipleCoils {
            address: *address,
            quantity: u16::try_from(values.len()).unwrap_or(u16::MAX),
        }),
        Request::WriteMultipleRegisters { address, values } => {
            Some(Response::WriteMultipleRegisters {
                address: *address,
                quantity: u16::try_from(values.len()).unwrap_or(u16::MAX),
            })
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_broadcast_write_is_answered_with_its_echo_and_a_read_is_not() {
        let req = Request::WriteMultipleRegisters {
            address: 9001,
            values: vec![20, 30],
        };
        assert_eq!(
            broadcast_echo(&req),
            Some(Response::WriteMultipleRegisters {
                address: 9001,
                quantity: 2
            })
        );
        assert_eq!(
            broadcast_echo(&Request::ReadHoldingRegisters {
                address: 0,
                quantity: 1
            }),
            None
        );
    }

    #[test]
    fn writes_refresh_only_polled_values() {
        let image = ProcessImage::default();
        image.store_words(2, Table::HoldingRegisters, 9001, &[0, 0], None);
        let req = Request::WriteMultipleRegisters {
            address: 9001,
            values: vec![20, 30],
        };
        refresh_image(
            &image,
            2,
            &req,
            &Response::WriteMultipleRegisters {
                address: 9001,
                quantity: 2,
            },
        );
        assert_eq!(
            image
                .read_words(2, Table::HoldingRegisters, 9001, 2)
                .unwrap()
                .values,
            vec![20, 30]
        );
        let req = Request::ReadWriteMultipleRegisters {
            read_address: 9002,
            read_quantity: 1,
            write_address: 9001,
            values: vec![13],
        };
        refresh_image(
            &image,
            2,
            &req,
            &Response::ReadWriteMultipleRegisters(vec![31]),
        );
        assert_eq!(
            image
                .read_words(2, Table::HoldingRegisters, 9001, 2)
                .unwrap()
                .values,
            vec![13, 31]
        );
        refresh_image(
            &image,
            2,
            &Request::WriteSingleRegister {
                address: 1,
                value: 5,
            },
            &Response::ReadCoils(vec![]),
        );
        assert!(image.read_words(2, Table::HoldingRegisters, 1, 1).is_err());
    }
}
