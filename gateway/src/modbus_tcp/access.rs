//! Authorization by role (MODBUS/TCP Security): what a client holding a role may ask.
//!
//! A plain Modbus TCP connection has no identity: its requests pass to the server-wide write
//! policy only ([`WritePolicy`](crate::unit::write_policy::WritePolicy)). A Modbus/TCP Security connection carries
//! the role of its client certificate, and every request is checked against that role's rights
//! before anything else of the server sees it.
//!
//! MODBUS/TCP Security Protocol Specification (MB-TCP-Security-v21, 2018), "Authorization": the
//! server decides from the role and the request (function code, unit, addresses) whether to serve
//! it, and a request that is not authorized is answered with exception code 01 (Illegal
//! Function). That is the answer for every refusal here, a unit or an address outside the role's
//! rights included, so a client without rights learns nothing about the units and tables behind.

use std::collections::BTreeMap;
use std::sync::Arc;

use proto_core::modbus::pdu::Request;

use crate::unit::write_policy::{covered, written, WriteRange};

/// Classes of function codes a role is granted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FunctionClass {
    /// FC 01, 02, 03, 04, 43/14 (read device identification), and the read half of FC 23.
    Read,
    /// FC 05, 06, 15, 16, and the write half of FC 23.
    Write,
    /// FC 07, 08, 11, 12, 17: the serial-line diagnostics and server identification.
    Diagnostics,
}

/// What one role may do.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RoleRights {
    /// Unit ids the role may address; `None`: every unit.
    pub units: Option<Vec<u8>>,
    /// Read requests allowed.
    pub read: bool,
    /// Write requests allowed.
    pub write: bool,
    /// Diagnostics requests allowed.
    pub diagnostics: bool,
    /// When set, table writes only inside these ranges (the unit id is part of each range).
    pub write_ranges: Option<Vec<WriteRange>>,
}

/// Why a request was refused by role.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// The connection's certificate has no role, or a role that is not configured.
    NoRights,
    /// The role may not address this unit.
    Unit,
    /// The role is not granted the function's class.
    Function(FunctionClass),
    /// A write outside the role's write ranges.
    Range,
}

// === impl RoleRights ===

impl RoleRights {
    /// Every right: every unit, every function class, no range limit.
    pub fn all() -> Self {
        Self {
            units: None,
            read: true,
            write: true,
            diagnostics: true,
            write_ranges: None,
        }
    }

    /// Whether the role may ask `request` of `unit`; `Err` says why not.
    pub fn check(&self, unit: u8, request: &Request) -> Result<(), Refusal> {
        if self
            .units
            .as_ref()
            .is_some_and(|units| !units.contains(&unit))
        {
            return Err(Refusal::Unit);
        }
        let (reads, writes) = classes(request);
        for class in [reads, writes].into_iter().flatten() {
            let granted = match class {
                FunctionClass::Read => self.read,
                FunctionClass::Write => self.write,
                FunctionClass::Diagnostics => self.diagnostics,
            };
            if !granted {
                return Err(Refusal::Function(class));
            }
        }
        if let (Some(ranges), Some((table, address, count))) =
            (&self.write_ranges, written(request))
        {
            if !covered(ranges, unit, table, address, count) {
                return Err(Refusal::Range);
            }
        }
        Ok(())
    }
}

/// The classes a request needs: (its read or diagnostics class, its write class).
fn classes(request: &Request) -> (Option<FunctionClass>, Option<FunctionClass>) {
    use FunctionClass::{Diagnostics, Read, Write};
    match request {
        Request::ReadCoils { .. }
        | Request::ReadDiscreteInputs { .. }
        | Request::ReadHoldingRegisters { .. }
        | Request::ReadInputRegisters { .. }
        | Request::ReadDeviceIdentification { .. } => (Some(Read), None),
        Request::WriteSingleCoil { .. }
        | Request::WriteSingleRegister { .. }
        | Request::WriteMultipleCoils { .. }
        | Request::WriteMultipleRegisters { .. } => (None, Some(Write)),
        Request::ReadWriteMultipleRegisters { .. } => (Some(Read), Some(Write)),
        Request::ReadExceptionStatus
        | Request::Diagnostics { .. }
        | Request::GetCommEventCounter
        | Request::GetCommEventLog
        | Request::ReportServerId => (Some(Diagnostics), None),
    }
}

/// The configured roles by name.
pub type Roles = BTreeMap<String, RoleRights>;

/// What the requests of one connection may do.
#[derive(Clone, Debug)]
pub enum Authority {
    /// A plain Modbus TCP connection: only the server-wide write policy applies.
    Open,
    /// A Modbus/TCP Security connection with its certificate's role (`None`: the certificate has
    /// no role extension) and that role's rights (`None`: the role is not configured, no rights).
    Role {
        name: Option<String>,
        rights: Option<Arc<RoleRights>>,
    },
}

// === impl Authority ===

impl Authority {
    /// The authority of a certificate carrying `role`, under `roles`.
    pub fn of_role(role: Option<String>, roles: &Roles) -> Self {
        let rights = role
            .as_ref()
            .and_then(|name| roles.get(name))
            .map(|rights| Arc::new(rights.clone()));
        Self::Role { name: role, rights }
    }

    /// Whether a request passes the role check (always on a plain connection).
    pub fn check(&self, unit: u8, request: &Request) -> Result<(), Refusal> {
        match self {
            Self::Open => Ok(()),
            Self::Role { rights: None, .. } => Err(Refusal::NoRights),
            Self::Role {
                rights: Some(rights),
                ..
            } => rights.check(unit, request),
        }
    }

    /// The role label of the refusal counter: the configured role's name, `none` for a
    /// certificate without a role, `unknown` for a role that is not configured (a name taken
    /// from a certificate is not a label: the label set stays bounded by the configuration).
    pub fn label(&self) -> &str {
        match self {
            Self::Open => "plain",
            Self::Role { name: None, .. } => "none",
            Self::Role { rights: None, .. } => "unknown",
            Self::Role {
                name: Some(name), ..
            } => name,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::unit::write_policy::WriteTable;

    fn viewer() -> RoleRights {
        RoleRights {
            units: Some(vec![2]),
            read: true,
            ..RoleRights::default()
        }
    }

    #[test]
    fn a_viewer_reads_its_unit_and_writes_nothing() {
        let read = Request::ReadHoldingRegisters {
            address: 0,
            quantity: 4,
        };
        let write = Request::WriteSingleRegister {
            address: 9001,
            value: 13,
        };
        assert_eq!(viewer().check(2, &read), Ok(()));
        assert_eq!(viewer().check(17, &read), Err(Refusal::Unit));
        assert_eq!(
            viewer().check(2, &write),
            Err(Refusal::Function(FunctionClass::Write))
        );
        let fc23 = Request::ReadWriteMultipleRegisters {
            read_address: 0,
            read_quantity: 1,
            write_address: 0,
            values: vec![1],
        };
        assert_eq!(
            viewer().check(2, &fc23),
            Err(Refusal::Function(FunctionClass::Write))
        );
        assert_eq!(
            viewer().check(2, &Request::ReportServerId),
            Err(Refusal::Function(FunctionClass::Diagnostics))
        );
    }

    #[test]
    fn an_operator_writes_inside_its_ranges_only() {
        let operator = RoleRights {
            write_ranges: Some(vec![WriteRange {
                unit: 2,
                table: WriteTable::HoldingRegisters,
                first: 9001,
                last: 9002,
            }]),
            ..RoleRights::all()
        };
        let write = |address, n| Request::WriteMultipleRegisters {
            address,
            values: vec![0; n],
        };
        assert_eq!(operator.check(2, &write(9001, 2)), Ok(()));
        assert_eq!(operator.check(2, &write(9001, 3)), Err(Refusal::Range));
        assert_eq!(operator.check(3, &write(9001, 1)), Err(Refusal::Range));
        let coil = Request::WriteSingleCoil {
            address: 9001,
            value: true,
        };
        assert_eq!(operator.check(2, &coil), Err(Refusal::Range));
    }

    #[test]
    fn a_certificate_without_a_configured_role_has_no_rights() {
        let roles = Roles::from([("operator".to_owned(), RoleRights::all())]);
        let read = Request::ReadCoils {
            address: 0,
            quantity: 1,
        };
        let none = Authority::of_role(None, &roles);
        assert_eq!(none.check(1, &read), Err(Refusal::NoRights));
        assert_eq!(none.label(), "none");
        let other = Authority::of_role(Some("admin".into()), &roles);
        assert_eq!(other.check(1, &read), Err(Refusal::NoRights));
        assert_eq!(other.label(), "unknown");
        let operator = Authority::of_role(Some("operator".into()), &roles);
        assert_eq!(operator.check(1, &read), Ok(()));
        assert_eq!(operator.label(), "operator");
        assert_eq!(Authority::Open.check(1, &read), Ok(()));
    }
}
