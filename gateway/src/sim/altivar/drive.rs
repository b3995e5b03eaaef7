//! A plausible motor behind the simulated drive: the Drivecom state machine, ramps, current,
//! torque, thermal states and the Modbus time-out fault.
//!
//! Not a motor model: enough that ETA and RFRD follow CMD and LFRD the way a drive's do, and that
//! the measured values move. The state machine is the Drivecom profile (CiA 402) the seed shows
//! (002: CMD 16#000F = "operation enabled", ETA 16#8637 = operation enabled, reverse, reference
//! reached); in the I/O profile (CHCF = 3) bit 0 of CMD is the run command (002 "Konfiguration
//! der Steuerungsfunktionen": "Der Startbefehl wird im Bit 0 des Steuerwortes übertragen").

use std::time::Duration;

use proto_core::profiles::altivar::{cmd, eta, DriveState, COMMUNICATION_TIMEOUT};

/// CHCF value of the I/O profile (002: "16#0003 (I/O-Modus)").
pub(crate) const CHCF_IO: u16 = 3;
/// The LFT code the simulator reports for its Modbus time-out fault SLF. The seeds do not give
/// the fault code table; this value is the simulator's own.
pub(crate) const LFT_SLF: u16 = 17;
/// Motor speed at nominal frequency (a four-pole motor at 50 Hz): the ramps ACC and DEC run
/// from 0 to this speed (ATV61/71: ramp times refer to the nominal frequency FrS).
const NOMINAL_RPM: f64 = 1500.0;
/// rpm per 0.1 Hz for the four-pole motor (1500 rpm at 500 x 0.1 Hz).
const RPM_PER_DECIHERTZ: f64 = 3.0;
/// Motor current at standstill with flux, and at nominal speed, in 0.1 A (a 1.5 kW motor, the
/// power of the manual's ATV71HU15M3).
const MAGNETISING_CURRENT: f64 = 20.0;
const NOMINAL_CURRENT: f64 = 68.0;
/// Mains voltage in 0.1 V (230 V, the ATV71..M3's supply) and its slow wander.
const MAINS: f64 = 2300.0;
const MAINS_WANDER: f64 = 6.0;

/// What the drive reads from its parameters each step.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Inputs {
    pub(crate) cmd: u16,
    pub(crate) lfrd: i16,
    pub(crate) acc: u16,
    pub(crate) dec: u16,
    pub(crate) hsp: u16,
    pub(crate) chcf: u16,
    pub(crate) since_request: Duration,
}

/// What the drive writes back to its parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Outputs {
    pub(crate) eta: u16,
    pub(crate) rfrd: i16,
    pub(crate) lcr: u16,
    pub(crate) otr: i16,
    pub(crate) uln: u16,
    pub(crate) thd: u16,
    pub(crate) thr: u16,
    pub(crate) lft: u16,
}

/// The motor and the drive's state.
#[derive(Clone, Debug)]
pub(crate) struct Drive {
    state: DriveState,
    speed: f64,
    target: f64,
    acceleration: f64,
    last_cmd: u16,
    thd: f64,
    thr: f64,
    lft: u16,
    clock: f64,
}

// === impl Drive ===

impl Drive {
    /// A drive at rest after power-up in profile `chcf`.
    pub(crate) fn new(chcf: u16) -> Self {
        Self {
            state: idle_state(chcf),
            speed: 0.0,
            target: 0.0,
            acceleration: 0.0,
            last_cmd: 0,
            thd: 0.0,
            thr: 0.0,
            lft: 0,
            clock: 0.0,
        }
    }

    /// Advances the drive by `dt`.
    pub(crate) fn step(&mut self, dt: Duration, inputs: &Inputs) {
        let seconds = dt.as_secs_f64();
        if seconds <= 0.0 {
            return;
        }
        self.clock += seconds;
        self.update_state(inputs);
        self.ramp(seconds, inputs);
        if self.state == DriveState::QuickStopActive && self.speed == 0.0 {
            self.state = DriveState::SwitchOnDisabled;
        }
        let load = self.current() / NOMINAL_CURRENT;
        // First-order heating: the drive in about a minute, the motor in about five.
        approach(&mut self.thd, 20.0 + 60.0 * load, seconds / 60.0);
        approach(&mut self.thr, 100.0 * load * load, seconds / 300.0);
    }

    fn update_state(&mut self, inputs: &Inputs) {
        let reset_edge =
            inputs.cmd & cmd::FAULT_RESET != 0 && self.last_cmd & cmd::FAULT_RESET == 0;
        self.last_cmd = inputs.cmd;
        let running = matches!(
            self.state,
            DriveState::OperationEnabled | DriveState::QuickStopActive
        );
        // 002 "Konfiguration Management Kommunikationsfehler": no request for the time-out while
        // the drive is controlled over Modbus raises SLF (factory reaction: freewheel stop).
        if running && inputs.since_request >= COMMUNICATION_TIMEOUT {
            self.state = DriveState::Fault;
            self.lft = LFT_SLF;
            return;
        }
        self.state = match self.state {
            DriveState::Fault | DriveState::FaultReactionActive => {
                if reset_edge {
                    idle_state(inputs.chcf)
                } else {
                    DriveState::Fault
                }
            }
            _ if inputs.chcf == CHCF_IO => {
                if inputs.cmd & cmd::SWITCH_ON != 0 {
                    DriveState::OperationEnabled
                } else {
                    DriveState::SwitchedOn
                }
            }
            state => drivecom(state, inputs.cmd),
        };
    }

    fn ramp(&mut self, seconds: f64, inputs: &Inputs) {
        let max = f64::from(inputs.hsp) * RPM_PER_DECIHERTZ;
        let sign = if inputs.cmd & cmd::REVERSE != 0 {
            -1.0
        } else {
            1.0
        };
        let mut target = (f64::from(inputs.lfrd) * sign).clamp(-max, max);
        if self.state != DriveState::OperationEnabled || inputs.cmd & cmd::HALT != 0 {
            target = 0.0;
        }
        self.target = target;
        if self.state == DriveState::Fault {
            // Freewheel: the motor coasts down on its own, slower than any ramp here.
            let coast = NOMINAL_RPM / 5.0 * seconds;
            self.speed = toward(self.speed, 0.0, coast);
            self.acceleration = 0.0;
            return;
        }
        let accelerating = target.abs() > self.speed.abs() && target * self.speed >= 0.0;
        let mut ramp = if accelerating { inputs.acc } else { inputs.dec };
        if self.state == DriveState::QuickStopActive {
            ramp /= 4;
        }
        // ACC / DEC in 0.1 s from 0 to the nominal speed; at least 0.1 s.
        let rate = NOMINAL_RPM / (f64::from(ramp.max(1)) / 10.0);
        let before = self.speed;
        self.speed = toward(self.speed, target, rate * seconds);
        self.acceleration = (self.speed - before) / seconds;
    }

    /// Motor current in 0.1 A.
    fn current(&self) -> f64 {
        if !self.energised() {
            return 0.0;
        }
        let speed = self.speed.abs() / NOMINAL_RPM;
        let accel = self.acceleration.abs() / NOMINAL_RPM;
        (MAGNETISING_CURRENT + (NOMINAL_CURRENT - MAGNETISING_CURRENT) * speed * 0.7 + 15.0 * accel)
            .min(2.0 * NOMINAL_CURRENT)
    }

    fn energised(&self) -> bool {
        matches!(
            self.state,
            DriveState::OperationEnabled | DriveState::QuickStopActive
        )
    }

    /// The values the drive reports.
    pub(crate) fn outputs(&self) -> Outputs {
        let mut status = self.state.eta_bits() | eta::VOLTAGE_ENABLED | eta::REMOTE;
        if self.state == DriveState::OperationEnabled && (self.speed - self.target).abs() < 0.5 {
            status |= eta::TARGET_REACHED;
        }
        if self.speed < 0.0 || (self.speed == 0.0 && self.target < 0.0) {
            status |= eta::REVERSE;
        }
        let torque = if self.energised() {
            let speed = self.speed / NOMINAL_RPM;
            30.0 * speed * speed.abs() + 40.0 * self.acceleration / NOMINAL_RPM
        } else {
            0.0
        };
        let wander = MAINS_WANDER * (self.clock * core::f64::consts::TAU / 7.0).sin();
        Outputs {
            eta: status,
            rfrd: clamp_i16(self.speed),
            lcr: clamp_u16(self.current()),
            otr: clamp_i16(torque),
            uln: clamp_u16(MAINS + wander),
            thd: clamp_u16(self.thd),
            thr: clamp_u16(self.thr),
            lft: self.lft,
        }
    }
}

/// The state after power-up or a fault reset: "switch on disabled" in the Drivecom profile,
/// "switched on" (ready, waiting for the run bit) in the I/O profile.
fn idle_state(chcf: u16) -> DriveState {
    if chcf == CHCF_IO {
        DriveState::SwitchedOn
    } else {
        DriveState::SwitchOnDisabled
    }
}

/// The Drivecom (CiA 402) transitions on a control word.
fn drivecom(state: DriveState, control: u16) -> DriveState {
    let disable_voltage = control & cmd::ENABLE_VOLTAGE == 0;
    let quick_stop = control & (cmd::ENABLE_VOLTAGE | cmd::QUICK_STOP) == cmd::ENABLE_VOLTAGE;
    let low = control & 0x000F;
    let shutdown = control & 0x0007 == cmd::SHUTDOWN;
    let switch_on = low == cmd::SWITCH_ON_COMMAND;
    let enable = low == cmd::ENABLE_OPERATION_COMMAND;
    match state {
        DriveState::NotReadyToSwitchOn => DriveState::SwitchOnDisabled,
        DriveState::SwitchOnDisabled if shutdown => DriveState::ReadyToSwitchOn,
        DriveState::SwitchOnDisabled => DriveState::SwitchOnDisabled,
        DriveState::ReadyToSwitchOn | DriveState::SwitchedOn if disable_voltage || quick_stop => {
            DriveState::SwitchOnDisabled
        }
        DriveState::ReadyToSwitchOn | DriveState::SwitchedOn if enable => {
            DriveState::OperationEnabled
        }
        DriveState::ReadyToSwitchOn | DriveState::SwitchedOn if switch_on => DriveState::SwitchedOn,
        DriveState::ReadyToSwitchOn | DriveState::SwitchedOn if shutdown => {
            DriveState::ReadyToSwitchOn
        }
        DriveState::OperationEnabled if disable_voltage => DriveState::SwitchOnDisabled,
        DriveState::OperationEnabled if quick_stop => DriveState::QuickStopActive,
        DriveState::OperationEnabled if shutdown => DriveState::ReadyToSwitchOn,
        DriveState::OperationEnabled if switch_on => DriveState::SwitchedOn,
        DriveState::QuickStopActive if disable_voltage => DriveState::SwitchOnDisabled,
        other => other,
    }
}

fn toward(value: f64, target: f64, step: f64) -> f64 {
    if (target - value).abs() <= step {
        target
    } else {
        value + step.copysign(target - value)
    }
}

fn approach(value: &mut f64, target: f64, fraction: f64) {
    *value += (target - *value) * fraction.clamp(0.0, 1.0);
}

fn clamp_u16(value: f64) -> u16 {
    value.round().clamp(0.0, f64::from(u16::MAX)) as u16
}

fn clamp_i16(value: f64) -> i16 {
    value
        .round()
        .clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs(control: u16, lfrd: i16) -> Inputs {
        Inputs {
            cmd: control,
            lfrd,
            acc: 30,
            dec: 30,
            hsp: 500,
            chcf: 1,
            since_request: Duration::ZERO,
        }
    }

    fn run(drive: &mut Drive, inputs: &Inputs, seconds: u64) {
        for _ in 0..seconds * 10 {
            drive.step(Duration::from_millis(100), inputs);
        }
    }

    #[test]
    fn drivecom_start_ramps_to_the_reference() {
        let mut drive = Drive::new(1);
        assert_eq!(drive.outputs().eta, 0x0250);
        run(&mut drive, &inputs(cmd::SHUTDOWN, 0), 1);
        assert_eq!(
            DriveState::from_eta(drive.outputs().eta),
            DriveState::ReadyToSwitchOn
        );
        run(&mut drive, &inputs(cmd::SWITCH_ON_COMMAND, 0), 1);
        run(&mut drive, &inputs(cmd::ENABLE_OPERATION_COMMAND, 1200), 1);
        // ACC 3.0 s to 1500 rpm: after 1 s about 500 rpm.
        let out = drive.outputs();
        assert!(out.rfrd > 400 && out.rfrd < 600, "{out:?}");
        assert_eq!(out.eta & eta::TARGET_REACHED, 0);
        run(&mut drive, &inputs(cmd::ENABLE_OPERATION_COMMAND, 1200), 5);
        let out = drive.outputs();
        assert_eq!(out.rfrd, 1200);
        assert_eq!(out.eta, 0x0637);
        assert!(out.lcr > 20 && out.thd > 0);
        run(
            &mut drive,
            &inputs(cmd::ENABLE_OPERATION_COMMAND | cmd::REVERSE, 600),
            10,
        );
        assert_eq!(drive.outputs().rfrd, -600);
        assert_eq!(drive.outputs().eta, 0x8637);
    }

    #[test]
    fn communication_timeout_faults_and_reset_recovers() {
        let mut drive = Drive::new(CHCF_IO);
        run(&mut drive, &inputs(cmd::ENABLE_OPERATION_COMMAND, 900), 1);
        let mut idle = inputs(cmd::ENABLE_OPERATION_COMMAND, 900);
        idle.chcf = CHCF_IO;
        idle.since_request = COMMUNICATION_TIMEOUT;
        drive.step(Duration::from_millis(100), &idle);
        assert_eq!(DriveState::from_eta(drive.outputs().eta), DriveState::Fault);
        assert_eq!(drive.outputs().lft, LFT_SLF);
        let mut reset = inputs(cmd::FAULT_RESET, 0);
        reset.chcf = CHCF_IO;
        drive.step(Duration::from_millis(100), &reset);
        assert_eq!(
            DriveState::from_eta(drive.outputs().eta),
            DriveState::SwitchedOn
        );
    }
}
