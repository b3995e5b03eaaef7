//! The checks of a request at submit time (003 7.2, 0E 41h..0E 4Ah).

use proto_core::event::ids;
use proto_core::modbus::master::{
    JobError, Master, MasterConfig, MasterEvent, Outcome, SubmitError,
};
use proto_core::modbus::pdu::Request;

use super::support::*;

#[test]
fn broadcast_only_for_writes() {
    let mut line = Line::new(rtu_config());
    let refused = line.master.submit(line.now, 0, atv_read());
    assert_eq!(
        refused,
        Err(SubmitError::Invalid(JobError::BroadcastNotPermitted {
            function: 0x03
        }))
    );
    line.drain();
    assert_eq!(
        line.events,
        [MasterEvent::Raised {
            id: ids::MASTER_BROADCAST_NOT_PERMITTED,
            slave: 0
        }]
    );
    assert!(line.master.is_idle());
    for request in [
        Request::WriteSingleCoil {
            address: 1,
            value: true,
        },
        Request::WriteMultipleCoils {
            address: 1,
            values: vec![true],
        },
        Request::WriteMultipleRegisters {
            address: 1,
            values: vec![1],
        },
    ] {
        let mut line = Line::new(rtu_config());
        line.submit(0, request);
        line.transmit();
        assert_eq!(line.outcomes(), [Outcome::Broadcast]);
    }
}

#[test]
fn submit_checks_the_cp_limits() {
    let rtu = |request: Request| Master::new(rtu_config()).submit(START, 1, request);
    let ascii = |request: Request| Master::new(MasterConfig::ascii()).submit(START, 1, request);
    let read_bits = |quantity| Request::ReadCoils {
        address: 0,
        quantity,
    };
    let read_regs = |quantity| Request::ReadInputRegisters {
        address: 0,
        quantity,
    };
    let write_bits = |n| Request::WriteMultipleCoils {
        address: 0,
        values: vec![true; n],
    };
    let write_regs = |n| Request::WriteMultipleRegisters {
        address: 0,
        values: vec![0; n],
    };
    assert!(rtu(read_bits(2040)).is_ok());
    assert_eq!(
        rtu(read_bits(2041)),
        Err(SubmitError::Invalid(JobError::BitCount {
            quantity: 2041,
            max: 2040
        }))
    );
    assert_eq!(
        rtu(read_bits(0)),
        Err(SubmitError::Invalid(JobError::BitCount {
            quantity: 0,
            max: 2040
        }))
    );
    assert!(ascii(read_bits(2009)).is_err());
    assert!(rtu(read_regs(127)).is_ok());
    assert_eq!(
        rtu(read_regs(128)),
        Err(SubmitError::Invalid(JobError::RegisterCount {
            quantity: 128,
            max: 127
        }))
    );
    assert!(ascii(read_regs(126)).is_err());
    assert!(rtu(write_bits(2040)).is_ok());
    assert_eq!(
        rtu(write_bits(2041)),
        Err(SubmitError::Invalid(JobError::WriteCount {
            quantity: 2041,
            max: 2040
        }))
    );
    assert!(ascii(write_bits(1977)).is_err());
    assert!(rtu(write_regs(127)).is_ok());
    assert!(rtu(write_regs(128)).is_err());
    assert!(rtu(write_regs(0)).is_err());
    assert!(ascii(write_regs(124)).is_err());
    assert!(ascii(write_regs(123)).is_ok());
    let events = [
        (
            JobError::BitCount {
                quantity: 0,
                max: 1,
            },
            ids::MASTER_BIT_COUNT_OUT_OF_RANGE,
        ),
        (
            JobError::RegisterCount {
                quantity: 0,
                max: 1,
            },
            ids::MASTER_REGISTER_COUNT_OUT_OF_RANGE,
        ),
        (
            JobError::WriteCount {
                quantity: 0,
                max: 1,
            },
            ids::MASTER_WRITE_COUNT_OUT_OF_RANGE,
        ),
    ];
    for (error, event) in events {
        assert_eq!(error.event(), event);
    }
    // FC 08: the diagnostic code and the data length; FC 17 is not a CP function.
    let diag = |sub_function, data: &[u8]| Request::Diagnostics {
        sub_function,
        data: data.to_vec(),
    };
    assert!(rtu(diag(0, &[0x31, 0x32])).is_ok());
    assert_eq!(
        rtu(diag(4, &[0, 0])),
        Err(SubmitError::Invalid(JobError::DiagnosticCode {
            sub_function: 4
        }))
    );
    assert_eq!(
        JobError::DiagnosticCode { sub_function: 4 }.event(),
        ids::MASTER_DIAGNOSTIC_CODE_INVALID
    );
    assert_eq!(
        rtu(diag(0, &[1])),
        Err(SubmitError::Invalid(JobError::DiagnosticDataTooShort {
            len: 1
        }))
    );
    assert_eq!(
        JobError::DiagnosticDataTooShort { len: 1 }.event(),
        ids::MASTER_LEN_TOO_SMALL_FOR_FUNCTION
    );
    assert_eq!(
        rtu(Request::ReportServerId),
        Err(SubmitError::Invalid(JobError::IllegalFunction {
            function: 0x11
        }))
    );
    assert_eq!(
        JobError::IllegalFunction { function: 0x11 }.event(),
        ids::MASTER_ILLEGAL_FUNCTION
    );
}
